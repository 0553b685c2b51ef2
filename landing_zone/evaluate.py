"""Evaluation on a dataset's test split: ROC / AUC, calibration, timings, and a look inside.

Run::

    landing-zone evaluate --data data/synth2 --model model.safetensors --out-dir eval/
    landing-zone evaluate --data data/synth2 --baselines --json results.json

Every method reads the same inputs, the test scenes re-voxelized by
:func:`landing_zone.tiles.scene_to_input` without augmentation. A method is any object with a
``name``, ``score(inputs) -> (T,)`` (higher = safer) and optionally ``fit(train_inputs,
train_labels)`` and ``probabilistic`` (its scores are P(safe), so an ECE is reported; without
the attribute, scores that all lie in [0, 1] count as probabilities). The CNN and the baselines
of :mod:`landing_zone.baselines` plug in alike.

**Conventions.** "Safe" (label 1) is the positive class: the ROC plots the share of safe tiles
accepted against the share of unsafe tiles accepted as the threshold on the score moves, and
the AUC is the probability that a random safe tile scores above a random unsafe one. ECE uses
15 equal-width bins of P(safe). ``ms_per_volume`` is the wall time of ``score`` over the whole
split divided by its size (fitting excluded), on this process's threads.

Outputs of ``--out-dir``: ``table.md`` (like the paper's Table II), ``roc.png``,
``reliability.png``, and for the CNN the look inside of the paper's Figs. 11-13:
``false_positives.png`` / ``false_negatives.png`` (the most confident mistakes, as cross-sections
with the obstacle marked), ``filters.png`` (first-layer filters as z slices) and
``class_models.png`` (inputs that maximise the safe and the unsafe score, Simonyan et al. 2014).
"""
from __future__ import annotations

import json
import math
import os
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Protocol, Sequence, runtime_checkable

import numpy as np
import torch

from landing_zone.calibration import Reliability, reliability
from landing_zone.config import MapConfig, TileConfig
from landing_zone.errors import ConfigError, DatasetError
from landing_zone.model import SafetyNet, load_model, predict

__all__ = ['Method', 'CNNMethod', 'MethodResult', 'evaluate_methods', 'markdown_table',
           'results_json', 'class_models', 'evaluate', 'evaluate_scenes', 'confident_mistakes']

ECE_BINS = 15


@runtime_checkable
class Method(Protocol):
    """What evaluation needs of a method (``fit`` and ``probabilistic`` are optional)."""

    name: str

    def score(self, inputs: Any) -> np.ndarray:
        """Safety score per volume, higher = safer."""
        ...


class CNNMethod:
    """The safety CNN as an evaluation method: scores are calibrated P(safe)."""

    probabilistic = True

    def __init__(self, model: SafetyNet, batch_size: int = 256, precision: str = 'auto'
                 ) -> None:
        self.model = model.eval()
        self.name = f'CNN {model.spec}'
        self.batch_size = batch_size
        self.precision = precision

    def score(self, inputs: Any) -> np.ndarray:
        return predict(self.model, inputs, self.batch_size, self.precision)


@dataclass
class MethodResult:
    """One method's figures on one split."""

    name: str
    scores: np.ndarray
    auc: float
    ece: float | None
    ms_per_volume: float
    fpr: np.ndarray
    tpr: np.ndarray
    reliability: Reliability | None


def _is_probabilistic(method: Any, scores: np.ndarray) -> bool:
    flag = getattr(method, 'probabilistic', None)
    if flag is not None:
        return bool(flag)
    return bool(scores.size) and bool(np.all((scores >= 0) & (scores <= 1)))


def evaluate_methods(methods: list[Any], inputs: Any, labels: np.ndarray,
                     train_inputs: Any = None, train_labels: np.ndarray | None = None,
                     progress: bool = False) -> list[MethodResult]:
    """Fit (where a method can and training data is given), score and measure every method.

    Args:
        methods: objects with ``name`` and ``score`` (see :class:`Method`).
        inputs: (T, 1, S, S, S) float32 test volumes.
        labels: (T,) 1 safe, 0 unsafe.
        train_inputs, train_labels: data for methods with ``fit``.

    Raises:
        DatasetError: labels of one class only, or a method returned the wrong number of scores.
    """
    from sklearn.metrics import roc_curve

    y = np.asarray(labels).reshape(-1).astype(np.int64)
    if y.size == 0 or y.min() == y.max():
        raise DatasetError('evaluation needs safe and unsafe volumes')
    out = []
    for m in methods:
        if hasattr(m, 'fit') and train_inputs is not None:
            if progress:
                print(f'evaluate: fitting {m.name}', file=sys.stderr)
            m.fit(train_inputs, train_labels)
        if progress:
            print(f'evaluate: scoring {m.name}', file=sys.stderr)
        m.score(inputs[:2])  # warm up (compilation, inference copies) outside the timing
        t0 = time.perf_counter()
        scores = np.asarray(m.score(inputs), np.float64).reshape(-1)
        ms = (time.perf_counter() - t0) * 1000.0 / len(y)
        if scores.shape != y.shape or not np.all(np.isfinite(scores)):
            raise DatasetError(f'{m.name} returned {scores.size} scores (finite: '
                               f'{bool(np.all(np.isfinite(scores)))}) for {y.size} volumes')
        fpr, tpr, _ = roc_curve(y, scores, pos_label=1)
        from sklearn.metrics import roc_auc_score
        auc = float(roc_auc_score(y, scores))
        rel = reliability(scores, y, ECE_BINS) if _is_probabilistic(m, scores) else None
        out.append(MethodResult(m.name, scores, auc, None if rel is None else rel.ece, ms,
                                fpr, tpr, rel))
    return out


def markdown_table(results: list[MethodResult], dataset: str, split: str, n: int,
                   n_unsafe: int) -> str:
    """The paper's Table II layout: one row per method."""
    lines = [f'Dataset {dataset}, {split} split: {n} volumes, {n_unsafe} unsafe. '
             'AUC with "safe" as the positive class; ECE of P(safe) in '
             f'{ECE_BINS} bins.', '',
             '| Method | AUC | ECE | ms / volume |', '|---|---:|---:|---:|']
    for r in results:
        ece = '-' if r.ece is None else f'{r.ece:.3f}'
        lines.append(f'| {r.name} | {r.auc:.3f} | {ece} | {r.ms_per_volume:.2f} |')
    return '\n'.join(lines) + '\n'


def results_json(results: list[MethodResult], dataset: str, split: str, n: int,
                 n_unsafe: int) -> dict[str, Any]:
    """RESULTS.json of docs/INTERFACES.md §3."""
    def num(v: float | None, digits: int) -> float | None:
        return None if v is None or not math.isfinite(v) else round(float(v), digits)

    return {'dataset': dataset, 'split': split, 'n': int(n), 'n_unsafe': int(n_unsafe),
            'methods': {r.name: {'auc': num(r.auc, 4), 'ece': num(r.ece, 4),
                                 'ms_per_volume': num(r.ms_per_volume, 3)}
                        for r in results}}


# --- look inside -------------------------------------------------------------------------------

def confident_mistakes(p_safe: np.ndarray, labels: np.ndarray, k: int = 6
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Indices of the ``k`` unsafe tiles scored safest and the ``k`` safe tiles scored least
    safe, worst first: the most confident false positives and false negatives (those on the
    wrong side of 0.5 are mistakes at that threshold; the rest are the nearest misses)."""
    p = np.asarray(p_safe)
    y = np.asarray(labels)
    unsafe = np.flatnonzero(y == 0)
    safe = np.flatnonzero(y == 1)
    fp = unsafe[np.argsort(-p[unsafe], kind='stable')][:k]
    fn = safe[np.argsort(p[safe], kind='stable')][:k]
    return fp, fn


def class_models(model: SafetyNet, steps: int = 150, lr: float = 0.05, l2: float = 1e-3,
                 seed: int = 0) -> dict[str, np.ndarray]:
    """Inputs that maximise each class score under an L2 penalty (Simonyan et al., 2014).

    Gradient ascent (Adam) on ``s(x) - l2 * ||x||^2``, with ``s`` the logit of P(safe) for
    'safe' and its negative for 'unsafe', the input kept in [-1, 1] (the range the network ever
    sees). It starts from bare flat ground (an occupied layer at the cube's middle, free space
    above, unobserved below) plus a little noise: the all-zero start of the original, here an
    entirely unobserved cube, leaves a trained net's ReLUs silent and the gradient zero. Both
    are optimised as one batch of two: in eval mode the samples do not interact, and one pass
    over two volumes costs about what one over a single volume does.

    Returns:
        {'safe': (S, S, S), 'unsafe': (S, S, S)} float32 volumes.
    """
    side = model.config.input_size
    net = model.float().eval()
    gen = torch.Generator().manual_seed(seed)
    x = 0.05 * torch.randn((2, 1, side, side, side), generator=gen)  # (2, 1, D, H, W)
    x[..., side // 2] += 0.7  # the ground layer (tiles put it at the cube's middle)
    x[..., side // 2 + 1:] -= 0.6  # observed free space above it
    x = x.clamp(-1.0, 1.0).requires_grad_(True)
    sign = torch.tensor([1.0, -1.0])
    opt = torch.optim.Adam([x], lr=lr)
    flags = [p.requires_grad for p in net.parameters()]
    for p in net.parameters():
        p.requires_grad_(False)
    try:
        for _ in range(steps):
            opt.zero_grad()
            logit, _ = net(x)  # (2,)
            objective = (sign * logit).sum() - l2 * (x ** 2).sum()
            (-objective).backward()
            opt.step()
            with torch.no_grad():
                x.clamp_(-1.0, 1.0)
    finally:
        for p, f in zip(net.parameters(), flags):
            p.requires_grad_(f)
    vols = x.detach()[:, 0].numpy().astype(np.float32)
    return {'safe': vols[0], 'unsafe': vols[1]}


def _obstacle_patches(ax: Any, obstacle: dict | None, plane: str, vs: float, pad: int,
                      tile_vox: int) -> None:
    """Outline the obstacle (tile frame params) on an input cross-section in voxel units."""
    if not obstacle:
        return
    from matplotlib.patches import Polygon, Rectangle
    try:
        cx, cy = float(obstacle['x']), float(obstacle['y'])
        dx, dy, dz = (float(v) for v in obstacle['size'])
        yaw = float(obstacle.get('yaw', 0.0))
    except (KeyError, TypeError, ValueError):
        return

    # tile frame [m] -> input voxel index: the tile's core starts at -tile/2 at index pad
    def to_vox(v: np.ndarray) -> np.ndarray:
        return (v + tile_vox * vs / 2) / vs + pad
    c, s = math.cos(yaw), math.sin(yaw)
    corners = np.array([[sx * dx / 2, sy * dy / 2] for sx, sy in
                        ((-1, -1), (1, -1), (1, 1), (-1, 1))])
    world = corners @ np.array([[c, s], [-s, c]]) + [cx, cy]
    vox = to_vox(world)
    ground = pad + tile_vox // 2
    style = dict(fill=False, edgecolor='magenta', linewidth=1.2)
    if plane == 'xy':
        ax.add_patch(Polygon(vox[:, ::-1] - 0.5, closed=True, **style))  # imshow: rows = x
    else:
        axis = 0 if plane == 'xz' else 1
        lo, hi = vox[:, axis].min(), vox[:, axis].max()
        ax.add_patch(Rectangle((ground - 0.5, lo - 0.5), dz / vs, hi - lo, **style))


def _cross_sections(volumes: list[np.ndarray], titles: list[str], path: Path,
                    obstacles: list[dict | None] | None = None, vs: float = 0.05,
                    pad: int = 6, tile_vox: int = 20, suptitle: str = '') -> None:
    """One row per volume: x-z and y-z sections through the cube centre (or the obstacle) and
    an x-y section just above the ground voxel; colours are the input 2 * density - 1."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    n = max(len(volumes), 1)
    fig, axes = plt.subplots(n, 3, figsize=(9, 2.9 * n), squeeze=False)
    for row, vol in enumerate(volumes):
        side = vol.shape[0]
        ob = obstacles[row] if obstacles else None
        ix = iy = side // 2
        if ob:
            try:
                ix = int(np.clip(round((float(ob['x']) + tile_vox * vs / 2) / vs + pad), 0,
                                 side - 1))
                iy = int(np.clip(round((float(ob['y']) + tile_vox * vs / 2) / vs + pad), 0,
                                 side - 1))
            except (KeyError, TypeError, ValueError):
                pass
        kz = min(pad + tile_vox // 2 + 2, side - 1)
        sections = [(vol[:, iy, :], f'x-z at y={iy}', 'xz'),
                    (vol[ix, :, :], f'y-z at x={ix}', 'yz'),
                    (vol[:, :, kz], f'x-y at z={kz}', 'xy')]
        for col, (img, label, plane) in enumerate(sections):
            ax = axes[row, col]
            ax.imshow(img, cmap='RdBu_r', vmin=-1, vmax=1, origin='lower',
                      interpolation='nearest')
            ax.set_title(f'{titles[row]}\n{label}' if col == 0 else label, fontsize=8)
            ax.set_xlabel('z' if plane != 'xy' else 'y', fontsize=7)
            ax.set_ylabel('x' if plane != 'yz' else 'y', fontsize=7)
            ax.tick_params(labelsize=6)
            _obstacle_patches(ax, ob, plane, vs, pad, tile_vox)
    if not volumes:
        axes[0, 0].text(0.5, 0.5, 'none', ha='center', va='center')
    if suptitle:
        fig.suptitle(suptitle, fontsize=10)
    fig.tight_layout()
    fig.savefig(path, dpi=90)
    plt.close(fig)


def plot_filters(model: SafetyNet, path: Path, max_filters: int = 32) -> None:
    """First-layer 3D filters, one row each, as their z slices."""
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    conv = next((m for m in model.modules() if isinstance(m, torch.nn.Conv3d)), None)
    if conv is None:
        return
    w = conv.weight.detach().float().cpu().numpy()[:max_filters, 0]  # (F, k, k, k)
    f, k = w.shape[0], w.shape[-1]
    lim = float(np.abs(w).max()) or 1.0
    fig, axes = plt.subplots(f, k, figsize=(0.8 * k + 0.5, 0.8 * f + 0.5), squeeze=False)
    for i in range(f):
        for z in range(k):
            ax = axes[i, z]
            ax.imshow(w[i, :, :, z], cmap='RdBu_r', vmin=-lim, vmax=lim, origin='lower',
                      interpolation='nearest')
            ax.set_xticks([])
            ax.set_yticks([])
            if i == 0:
                ax.set_title(f'z={z}', fontsize=7)
        axes[i, 0].set_ylabel(f'{i}', fontsize=7, rotation=0, labelpad=8)
    fig.suptitle(f'first-layer filters of {model.spec} (x-y slices)', fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=80)
    plt.close(fig)


def plot_roc(results: list[MethodResult], path: Path, title: str) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5, 5))
    for r in results:
        ax.plot(r.fpr, r.tpr, label=f'{r.name} (AUC {r.auc:.3f})')
    ax.plot([0, 1], [0, 1], color='grey', linestyle=':', linewidth=1)
    ax.set_xlabel('unsafe tiles accepted (false positive rate)')
    ax.set_ylabel('safe tiles accepted (true positive rate)')
    ax.set_title(title, fontsize=9)
    ax.legend(fontsize=7, loc='lower right')
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


def plot_reliability(results: list[MethodResult], path: Path) -> None:
    import matplotlib
    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    rs = [r for r in results if r.reliability is not None]
    fig, (ax, axc) = plt.subplots(2, 1, figsize=(5, 6.5), sharex=True,
                                  gridspec_kw={'height_ratios': [3, 1]})
    ax.plot([0, 1], [0, 1], color='grey', linestyle=':', linewidth=1, label='perfect')
    width = 1.0 / ECE_BINS
    for r in rs:
        rel = r.reliability
        centres = 0.5 * (rel.edges[:-1] + rel.edges[1:])
        full = rel.count > 0
        ax.plot(rel.confidence[full], rel.frequency[full], marker='o', markersize=3,
                label=f'{r.name} (ECE {r.ece:.3f})')
        axc.bar(centres, rel.count, width=width, alpha=0.5, label=r.name)
    ax.set_ylabel('observed share of safe tiles')
    ax.set_title('reliability of P(safe)', fontsize=9)
    ax.legend(fontsize=7)
    axc.set_xlabel('predicted P(safe)')
    axc.set_ylabel('tiles')
    axc.set_yscale('log')
    ax.set_xlim(0, 1)
    ax.set_ylim(0, 1)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    plt.close(fig)


# --- the command -------------------------------------------------------------------------------

def _even_subset(n: int, k: int) -> np.ndarray:
    if k <= 0 or k >= n:
        return np.arange(n)
    return np.floor((np.arange(k) + 0.5) * n / k).astype(np.int64)


def evaluate(data: str | os.PathLike,
             model: str | os.PathLike | Sequence[str | os.PathLike] | None = None,
             baselines: bool = False, json_path: str | os.PathLike | None = None,
             out_dir: str | os.PathLike | None = None, split: str = 'test', workers: int = 0,
             fit_scenes: int = 2000, max_scenes: int = 0, seed: int = 0,
             precision: str = 'auto', progress: bool = True, by_family: bool = False
             ) -> dict[str, Any]:
    """Evaluate the CNN (and with ``baselines`` the paper's baselines) on a dataset split.

    Args:
        data: dataset directory (see :mod:`landing_zone.sim.dataset`).
        model: model file, or several (each its own row, e.g. both of the paper's nets, or a
            model before and after fine-tuning); default the shipped model (unless only
            baselines are asked for and none is shipped).
        baselines: also evaluate :func:`landing_zone.baselines.make_baselines`, fitted on up to
            ``fit_scenes`` scenes of the train split.
        json_path: write RESULTS.json (docs/INTERFACES.md §3) here.
        out_dir: write table.md, the plots and the look inside here.
        split: 'test' (obstacle models never seen in training) or 'train'.
        workers: processes re-voxelizing scenes.
        fit_scenes: train scenes the baselines are fitted on (an even subset).
        max_scenes: evaluate an even subset of this many scenes (0 = all).
        seed: seed of the baselines.
        precision: CNN inference precision ('auto', 'fp32', 'bf16').
        progress: progress and messages on stderr.
        by_family: also the figures per family and the leave-one-family-out table
            (:mod:`landing_zone.lofo`; synth3 data): RESULTS.json gains 'families', the table
            the family tables.

    Returns:
        The RESULTS.json dictionary, plus 'table' (markdown).
    """
    from landing_zone.sim.dataset import SceneDataset

    if split not in ('test', 'train'):
        raise ConfigError(f"split must be 'test' or 'train', got {split!r}")
    if model is None or (not isinstance(model, (str, os.PathLike)) and not list(model)):
        from landing_zone.assessor import default_model_path
        from landing_zone.errors import ModelError
        model = None
        try:
            model = default_model_path()
        except ModelError:
            if not baselines:
                raise
    ds = SceneDataset(data, split)
    name = str(ds.meta.get('dataset', Path(data).name))
    train_source = SceneDataset(data, 'train') if baselines else None
    return evaluate_scenes(ds, name, split, model, baselines, train_source, json_path, out_dir,
                           workers, fit_scenes, max_scenes, seed, precision, progress,
                           by_family=by_family)


def evaluate_scenes(source: Any, dataset: str, split: str,
                    model: str | os.PathLike | Sequence[str | os.PathLike] | None = None,
                    baselines: bool = False,
                    train_source: Any = None, json_path: str | os.PathLike | None = None,
                    out_dir: str | os.PathLike | None = None, workers: int = 0,
                    fit_scenes: int = 2000, max_scenes: int = 0, seed: int = 0,
                    precision: str = 'auto', progress: bool = False,
                    extra_methods: list[Any] | None = None, by_family: bool = False
                    ) -> dict[str, Any]:
    """:func:`evaluate` on any sequence of scenes (``len``, ``[i] -> Scene``).

    Args:
        source: the scenes to evaluate.
        dataset, split: names reported in the table and RESULTS.json.
        model: model file of the CNN, or several (None: no CNN). Models whose tiles or voxel
            size differ are each given volumes voxelized their way; the baselines see the
            first model's (or the default) voxelization.
        baselines: add the paper's baselines, fitted on ``train_source``.
        train_source: scenes the fittable methods are fitted on.
        extra_methods: more methods (see :class:`Method`) to evaluate after these.
        Others: see :func:`evaluate`.
    """
    from landing_zone.train import ScenePack, voxelize

    paths = [] if model is None else [model] if isinstance(model, (str, os.PathLike)) \
        else list(model)
    cnns: list[tuple[CNNMethod, tuple]] = []
    metas: list[dict[str, Any]] = []
    for path in paths:
        net, meta = load_model(path, 'cpu')
        cnns.append((CNNMethod(net, precision=precision), _voxel_key(meta)))
        metas.append(meta)
    _unique_names([c for c, _ in cnns], paths)
    key0 = cnns[0][1] if cnns else _voxel_key({})
    mcfg, tcfg = _configs(key0)
    tile_vox = int(round(tcfg.tile_size / mcfg.voxel_size))
    others: list[Any] = []
    if baselines:
        from landing_zone.baselines import VolumeGeometry, make_baselines
        geometry = VolumeGeometry(voxel_size=mcfg.voxel_size, tile_size=tcfg.tile_size,
                                  occupied_density=tcfg.occupied_density)
        others.extend(make_baselines(seed=seed, geometry=geometry))
    others.extend(extra_methods or [])
    if not cnns and not others:
        raise ConfigError('nothing to evaluate: give --model or --baselines')

    pack = ScenePack.from_scenes(source, _even_subset(len(source), max_scenes), progress,
                                 f'loading {split} scenes')
    if workers:
        pack.share_memory()
    volumes: dict[tuple, Any] = {}

    def volumes_for(key: tuple) -> Any:
        if key not in volumes:
            m, t = _configs(key)
            volumes[key] = voxelize(pack, m, t, workers, progress, f'voxelizing {split}')
        return volumes[key]

    inputs, labels = volumes_for(key0)
    x = inputs.numpy()
    y = labels.numpy().astype(np.int64)
    train_x = train_y = None
    if train_source is not None and any(hasattr(m, 'fit') for m in others):
        tpack = ScenePack.from_scenes(train_source, _even_subset(len(train_source), fit_scenes),
                                      progress, 'loading train scenes')
        if workers:
            tpack.share_memory()
        ti, tl = voxelize(tpack, mcfg, tcfg, workers, progress, 'voxelizing train')
        train_x, train_y = ti.numpy(), tl.numpy().astype(np.int64)

    results = []
    for cnn, key in cnns:
        results += evaluate_methods([cnn], volumes_for(key)[0].numpy(), y, progress=progress)
    results += evaluate_methods(others, x, y, train_x, train_y, progress) if others else []
    cnn = cnns[0][0] if cnns else None
    n, n_unsafe = len(y), int((y == 0).sum())
    table = markdown_table(results, dataset, split, n, n_unsafe)
    out = results_json(results, dataset, split, n, n_unsafe)
    if by_family:
        from landing_zone.lofo import family_report_for, markdown_families
        out['families'] = family_report_for(results, pack.params, y, metas)
        table += '\n' + markdown_families(out['families'])
    if json_path is not None:
        p = Path(json_path)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(json.dumps(out, indent=1) + '\n', encoding='utf-8')
    if out_dir is not None:
        d = Path(out_dir)
        d.mkdir(parents=True, exist_ok=True)
        (d / 'table.md').write_text(table, encoding='utf-8')
        plot_roc(results, d / 'roc.png', f'{dataset} {split}: {n} volumes, {n_unsafe} unsafe')
        if any(r.reliability is not None for r in results):
            plot_reliability(results, d / 'reliability.png')
        if cnn is not None:
            _look_inside(cnn.model, results[0].scores, y, x, pack, d, mcfg.voxel_size,
                         tcfg.padding, tile_vox)
    return {**out, 'table': table}


def _voxel_key(meta: dict[str, Any]) -> tuple:
    """What decides a model's input volumes: its voxel size and tile configuration."""
    vs = float(meta.get('voxel_size', MapConfig().voxel_size))
    tiles = meta['tiles'] if 'tiles' in meta else asdict(TileConfig())
    return vs, tuple(sorted(tiles.items()))


def _configs(key: tuple) -> tuple[MapConfig, TileConfig]:
    return MapConfig(voxel_size=key[0]), TileConfig(**dict(key[1]))


def _unique_names(cnns: list[CNNMethod], paths: list[Any]) -> None:
    """Rows of models with the same spec are told apart by their file names."""
    specs = [c.name for c in cnns]
    for c, p in zip(cnns, paths):
        if specs.count(c.name) > 1:
            c.name = f'{c.name} ({Path(p).stem})'
    names = [c.name for c in cnns]
    dup = next((n for n in names if names.count(n) > 1), None)
    if dup is not None:
        raise ConfigError(f'two models would share the row {dup!r}: give them different file '
                          f'names')


def _look_inside(model: SafetyNet, p_safe: np.ndarray, y: np.ndarray, x: np.ndarray,
                 pack: Any, out: Path, vs: float, pad: int, tile_vox: int, k: int = 6) -> None:
    fp, fn = confident_mistakes(p_safe, y, k)
    for idx, name, what in ((fp, 'false_positives.png', 'unsafe judged safe'),
                            (fn, 'false_negatives.png', 'safe judged unsafe')):
        vols = [x[i, 0] for i in idx]
        obstacles = [pack.params[i].get('obstacle') for i in idx]
        wrong = (p_safe[idx] >= 0.5) == (y[idx] == 0)
        titles = [f'scene {int(pack.scene_ids[i])}: P(safe) {p_safe[i]:.3f}'
                  + (' (mistake)' if w else '') for i, w in zip(idx, wrong)]
        _cross_sections(vols, titles, out / name, obstacles, vs, pad, tile_vox,
                        f'most confident mistakes: {what} (obstacle outlined)')
    plot_filters(model, out / 'filters.png')
    cm = class_models(model)
    _cross_sections([cm['safe'], cm['unsafe']], ['class model "safe"', 'class model "unsafe"'],
                    out / 'class_models.png', None, vs, pad, tile_vox,
                    'inputs that maximise each class score (L2-regularised)')
