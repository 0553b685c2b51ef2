"""Evaluation on a dataset's test split: ROC / AUC, calibration, timings, and a look inside.

Run::

    landing-zone evaluate --data data/synth2 --model model.safetensors --out-dir eval/
    landing-zone evaluate --data data/synth2 --baselines --json results.json

Every method reads the same inputs, the test scenes re-voxelized by
:func:`landing_zone.judging.patches.scene_to_input` without augmentation. A method is any object
with a ``name``, ``score(inputs) -> (T,)`` (higher = safer) and optionally ``fit(train_inputs,
train_labels)`` and ``probabilistic`` (its scores are P(safe), so an ECE is reported; without
the attribute, scores that all lie in [0, 1] count as probabilities). The CNN and the baselines
of :mod:`landing_zone.tools.evaluate.baselines` plug in alike.

**Conventions.** "Safe" (label 1) is the positive class: the ROC plots the share of safe tiles
accepted against the share of unsafe tiles accepted as the threshold on the score moves, and
the AUC is the probability that a random safe tile scores above a random unsafe one. ECE uses
15 equal-width bins of P(safe). ``ms_per_volume`` is the wall time of ``score`` over the whole
split divided by its size (fitting excluded), on this process's threads.

Outputs of ``--out-dir``: ``table.md`` (like the paper's Table II), ``roc.png``,
``reliability.png``, and for the CNN the look inside of the paper's Figs. 11-13:
``false_positives.png`` / ``false_negatives.png`` (the most confident mistakes, as cross-sections
with the obstacle marked), ``filters.png`` (first-layer filters as z slices) and
``class_models.png`` (inputs that maximise the safe and the unsafe score, Simonyan et al. 2014),
drawn by :mod:`landing_zone.tools.evaluate.figures`.
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

from landing_zone.tools.learn.calibration import Reliability, reliability
from landing_zone.config import MapConfig, TileConfig
from landing_zone.errors import ConfigError, DatasetError
from landing_zone.judging.checkpoint import load_model
from landing_zone.judging.inference import predict
from landing_zone.judging.net import SafetyNet

__all__ = ['Method', 'CNNMethod', 'MethodResult', 'evaluate_methods', 'markdown_table',
           'results_json', 'scores_json', 'evaluate', 'evaluate_scenes']

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
    y = np.asarray(labels).reshape(-1).astype(np.int64)
    if y.size == 0 or y.min() == y.max():
        raise DatasetError('evaluation needs safe and unsafe volumes')
    out: list[MethodResult] = []
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
        out.append(measure(m.name, scores, y, ms, _is_probabilistic(m, scores)))
    return out


def measure(name: str, scores: np.ndarray, labels: np.ndarray, ms_per_volume: float,
            probabilistic: bool) -> MethodResult:
    """A method's figures from its scores: ROC, AUC and, for P(safe), the reliability
    diagram and ECE."""
    from sklearn.metrics import roc_auc_score, roc_curve

    fpr, tpr, _ = roc_curve(labels, scores, pos_label=1)
    auc = float(roc_auc_score(labels, scores))
    rel = reliability(scores, labels, ECE_BINS) if probabilistic else None
    return MethodResult(name, scores, auc, None if rel is None else rel.ece, ms_per_volume,
                        fpr, tpr, rel)


def _guarded(results: list[MethodResult], found: Any, y: np.ndarray) -> list[MethodResult]:
    """The CNN results with the assessor's guard (its findings ``found`` on the same scenes)
    applied to their P(safe), as on the robot: named '... + guard'. ms / volume stays the
    network's (what the guard costs on the robot: ``landing-zone bench assess``)."""
    from landing_zone.config import GuardConfig
    from landing_zone.judging.guard import guard_p_safe

    cfg = GuardConfig()
    return [measure(f'{r.name} + guard', guard_p_safe(r.scores, found, cfg).astype(np.float64),
                    y, r.ms_per_volume, True) for r in results]


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


def scores_json(results: list[MethodResult], scene_ids: np.ndarray, labels: np.ndarray,
                dataset: str, split: str) -> dict[str, Any]:
    """Every scene's score by every method, for breakdowns the tables do not make.

    ``scenes[i]`` is row i's index in its source (``SceneDataset[scenes[i]]`` gives the scene
    and its params), ``labels[i]`` its label (1 safe) and ``methods[name][i]`` the method's
    score (P(safe) for a probabilistic one).
    """
    return {'dataset': dataset, 'split': split,
            'scenes': [int(i) for i in np.asarray(scene_ids).reshape(-1)],
            'labels': [int(v) for v in np.asarray(labels).reshape(-1)],
            'methods': {r.name: [round(float(v), 6) for v in r.scores] for r in results}}


# --- look inside -------------------------------------------------------------------------------

def _even_subset(n: int, k: int) -> np.ndarray:
    if k <= 0 or k >= n:
        return np.arange(n)
    return np.floor((np.arange(k) + 0.5) * n / k).astype(np.int64)


def evaluate(data: str | os.PathLike,
             model: str | os.PathLike | Sequence[str | os.PathLike] | None = None,
             baselines: bool = False, json_path: str | os.PathLike | None = None,
             out_dir: str | os.PathLike | None = None, split: str = 'test', workers: int = 0,
             fit_scenes: int = 2000, max_scenes: int = 0, seed: int = 0,
             precision: str = 'auto', progress: bool = True, by_family: bool = False,
             scores_path: str | os.PathLike | None = None, guard: bool = False
             ) -> dict[str, Any]:
    """Evaluate the CNN (and with ``baselines`` the paper's baselines) on a dataset split.

    Args:
        data: dataset directory (see :mod:`landing_zone.tools.sim.shards`).
        model: model file, or several (each its own row, e.g. both of the paper's nets, or a
            model before and after fine-tuning); default the shipped model (unless only
            baselines are asked for and none is shipped).
        baselines: also evaluate :func:`landing_zone.tools.evaluate.baselines.make_baselines`, fitted on
            up to ``fit_scenes`` scenes of the train split.
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
            (:mod:`landing_zone.tools.evaluate.lofo`; synth3 data): RESULTS.json gains 'families', the table
            the family tables.
        scores_path: write every scene's score by every method here (:func:`scores_json`).
        guard: judge every CNN as the assessor does, its P(safe) capped where the guard
            (:mod:`landing_zone.judging.guard`, default configuration) finds opaque structure
            above the tile's ground plane; the CNNs' rows are named '... + guard'.

    Returns:
        The RESULTS.json dictionary, plus 'table' (markdown).
    """
    from landing_zone.tools.sim.shards import SceneDataset

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
                           by_family=by_family, scores_path=scores_path, guard=guard)


def evaluate_scenes(source: Any, dataset: str, split: str,
                    model: str | os.PathLike | Sequence[str | os.PathLike] | None = None,
                    baselines: bool = False,
                    train_source: Any = None, json_path: str | os.PathLike | None = None,
                    out_dir: str | os.PathLike | None = None, workers: int = 0,
                    fit_scenes: int = 2000, max_scenes: int = 0, seed: int = 0,
                    precision: str = 'auto', progress: bool = False,
                    extra_methods: list[Any] | None = None, by_family: bool = False,
                    scores_path: str | os.PathLike | None = None, guard: bool = False
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
    from landing_zone.tools.learn.samples import voxelize
    from landing_zone.tools.learn.scenes import ScenePack

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
        from landing_zone.tools.evaluate.baselines import VolumeGeometry, make_baselines
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

    def volumes_for(key: tuple) -> Any:  # (inputs, labels, the guard's findings or None)
        if key not in volumes:
            m, t = _configs(key)
            desc = f'voxelizing {split}'
            if guard:  # the guard's findings from the same read of each patch
                from landing_zone.config import GuardConfig
                from landing_zone.tools.evaluate.scene_guard import voxelize_guarded
                volumes[key] = voxelize_guarded(pack, m, t, GuardConfig(), workers, progress,
                                                desc + ' and guarding')
            else:
                volumes[key] = (*voxelize(pack, m, t, workers, progress, desc), None)
        return volumes[key]

    inputs, labels, _ = volumes_for(key0)
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
        res = evaluate_methods([cnn], volumes_for(key)[0].numpy(), y, progress=progress)
        results += _guarded(res, volumes_for(key)[2], y) if guard else res
    results += evaluate_methods(others, x, y, train_x, train_y, progress) if others else []
    cnn = cnns[0][0] if cnns else None
    n, n_unsafe = len(y), int((y == 0).sum())
    table = markdown_table(results, dataset, split, n, n_unsafe)
    out = results_json(results, dataset, split, n, n_unsafe)
    if by_family:
        from landing_zone.tools.evaluate.lofo import family_report_for, markdown_families
        out['families'] = family_report_for(results, pack.params, y, metas)
        table += '\n' + markdown_families(out['families'])
    if json_path is not None:
        p = Path(json_path)
        p.parent.mkdir(parents=True, exist_ok=True)
        p.write_text(json.dumps(out, indent=1) + '\n', encoding='utf-8')
    if scores_path is not None:
        p = Path(scores_path)
        p.parent.mkdir(parents=True, exist_ok=True)
        doc = scores_json(results, pack.scene_ids.numpy(), y, dataset, split)
        p.write_text(json.dumps(doc) + '\n', encoding='utf-8')
    if out_dir is not None:
        d = Path(out_dir)
        d.mkdir(parents=True, exist_ok=True)
        (d / 'table.md').write_text(table, encoding='utf-8')
        from landing_zone.tools.evaluate.figures import look_inside, plot_reliability, plot_roc

        plot_roc(results, d / 'roc.png', f'{dataset} {split}: {n} volumes, {n_unsafe} unsafe')
        if any(r.reliability is not None for r in results):
            plot_reliability(results, d / 'reliability.png')
        if cnn is not None:
            look_inside(cnn.model, results[0].scores, y, x, pack, d, mcfg.voxel_size,
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
