"""Evaluation on a dataset's test split: ROC / AUC, calibration, timings, and a look inside.

Run::

    landing-zone evaluate --data data/synth2 --model model.safetensors --out-dir eval/
    landing-zone evaluate --data data/synth2 --baselines --json results.json

Every method (:mod:`landing_zone.tools.evaluate.methods`: the CNN, the baselines of
:mod:`landing_zone.tools.evaluate.baselines` or any object with a ``name`` and a ``score``) reads
the same inputs, the test scenes re-voxelized by
:func:`landing_zone.judging.patches.scene_to_input` without augmentation.

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
from dataclasses import asdict
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from landing_zone.assessor import default_model_path
from landing_zone.config import GuardConfig, MapConfig, TileConfig
from landing_zone.errors import ConfigError, ModelError
from landing_zone.judging.checkpoint import load_model
from landing_zone.judging.guard import guard_p_safe
from landing_zone.tools.evaluate.baselines import VolumeGeometry, make_baselines
from landing_zone.tools.evaluate.figures import look_inside, plot_reliability, plot_roc
from landing_zone.tools.evaluate.lofo import family_report_for, markdown_families
from landing_zone.tools.evaluate.methods import ECE_BINS, CNNMethod, MethodResult, \
    evaluate_methods, measure
from landing_zone.tools.evaluate.scene_guard import voxelize_guarded
from landing_zone.tools.learn.samples import voxelize
from landing_zone.tools.learn.scenes import ScenePack
from landing_zone.tools.sim.shards import SceneDataset

__all__ = ['markdown_table', 'results_json', 'scores_json', 'evaluate', 'evaluate_scenes']


def _guarded(results: list[MethodResult], found: Any, y: np.ndarray) -> list[MethodResult]:
    """The CNN results with the assessor's guard (its findings ``found`` on the same scenes)
    applied to their P(safe), as on the robot: named '... + guard'. ms / volume stays the
    network's (what the guard costs on the robot: ``landing-zone bench assess``)."""
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
        baselines: also evaluate
            :func:`landing_zone.tools.evaluate.baselines.make_baselines`, fitted on up to
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
            (:mod:`landing_zone.tools.evaluate.lofo`; synth3 data): RESULTS.json gains
            'families', the table the family tables.
        scores_path: write every scene's score by every method here (:func:`scores_json`).
        guard: judge every CNN as the assessor does, its P(safe) capped where the guard
            (:mod:`landing_zone.judging.guard`, default configuration) finds opaque structure
            above the tile's ground plane; the CNNs' rows are named '... + guard'.

    Returns:
        The RESULTS.json dictionary, plus 'table' (markdown).
    """
    if split not in ('test', 'train'):
        raise ConfigError(f"split must be 'test' or 'train', got {split!r}")
    if model is None or (not isinstance(model, (str, os.PathLike)) and not list(model)):
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
        extra_methods: more methods (see :class:`~landing_zone.tools.evaluate.methods.Method`)
            to evaluate after these.
        Others: see :func:`evaluate`.
    """
    # the methods: one CNN per model file, then the baselines and the extra methods
    cnns, metas = _load_cnns(model, precision)
    key0 = cnns[0][1] if cnns else _voxel_key({})
    mcfg, tcfg = _configs(key0)
    others = _other_methods(baselines, extra_methods, mcfg, tcfg, seed)
    if not cnns and not others:
        raise ConfigError('nothing to evaluate: give --model or --baselines')
    # the scenes, re-voxelized once per voxelization the models ask for
    pack = ScenePack.from_scenes(source, _even_subset(len(source), max_scenes), progress,
                                 f'loading {split} scenes')
    if workers:
        pack.share_memory()
    volumes = _Volumes(pack, split, guard, workers, progress)
    inputs, labels, _ = volumes.get(key0)
    x = inputs.numpy()
    y = labels.numpy().astype(np.int64)
    # fit the fittable methods on the train scenes
    train_x, train_y = _train_volumes(train_source, others, fit_scenes, mcfg, tcfg, workers,
                                      progress)
    # score every method on the same volumes
    results = []
    for cnn, key in cnns:
        res = evaluate_methods([cnn], volumes.get(key)[0].numpy(), y, progress=progress)
        results += _guarded(res, volumes.get(key)[2], y) if guard else res
    results += evaluate_methods(others, x, y, train_x, train_y, progress) if others else []
    # the table and RESULTS.json, per family on request
    n, n_unsafe = len(y), int((y == 0).sum())
    table = markdown_table(results, dataset, split, n, n_unsafe)
    out = results_json(results, dataset, split, n, n_unsafe)
    if by_family:
        out['families'] = family_report_for(results, pack.params, y, metas)
        table += '\n' + markdown_families(out['families'])
    # write what was asked for
    if json_path is not None:
        _write_text(json_path, json.dumps(out, indent=1) + '\n')
    if scores_path is not None:
        doc = scores_json(results, pack.scene_ids.numpy(), y, dataset, split)
        _write_text(scores_path, json.dumps(doc) + '\n')
    if out_dir is not None:
        _write_figures(Path(out_dir), table, results, cnns[0][0] if cnns else None, x, y, pack,
                       mcfg, tcfg, f'{dataset} {split}: {n} volumes, {n_unsafe} unsafe')
    return {**out, 'table': table}


def _load_cnns(model: str | os.PathLike | Sequence[str | os.PathLike] | None, precision: str
               ) -> tuple[list[tuple[CNNMethod, tuple]], list[dict[str, Any]]]:
    """One CNN method per model file, each with the key of its voxelization, and the models'
    metadata."""
    paths = [] if model is None else [model] if isinstance(model, (str, os.PathLike)) \
        else list(model)
    cnns: list[tuple[CNNMethod, tuple]] = []
    metas: list[dict[str, Any]] = []
    for path in paths:
        net, meta = load_model(path, 'cpu')
        cnns.append((CNNMethod(net, precision=precision), _voxel_key(meta)))
        metas.append(meta)
    _unique_names([c for c, _ in cnns], paths)
    return cnns, metas


def _other_methods(baselines: bool, extra: list[Any] | None, mcfg: MapConfig,
                   tcfg: TileConfig, seed: int) -> list[Any]:
    """The baselines (on request) and the caller's extra methods."""
    others: list[Any] = []
    if baselines:
        geometry = VolumeGeometry(voxel_size=mcfg.voxel_size, tile_size=tcfg.tile_size,
                                  occupied_density=tcfg.occupied_density)
        others.extend(make_baselines(seed=seed, geometry=geometry))
    others.extend(extra or [])
    return others


class _Volumes:
    """The scenes' input volumes, labels and (with ``guard``) the guard's findings, voxelized
    once per voxelization key."""

    def __init__(self, pack: ScenePack, split: str, guard: bool, workers: int,
                 progress: bool) -> None:
        self.pack, self.split, self.guard = pack, split, guard
        self.workers, self.progress = workers, progress
        self.cache: dict[tuple, Any] = {}

    def get(self, key: tuple) -> Any:
        if key not in self.cache:
            m, t = _configs(key)
            desc = f'voxelizing {self.split}'
            if self.guard:  # the guard's findings from the same read of each patch
                self.cache[key] = voxelize_guarded(self.pack, m, t, GuardConfig(), self.workers,
                                                   self.progress, desc + ' and guarding')
            else:
                self.cache[key] = (*voxelize(self.pack, m, t, self.workers, self.progress,
                                             desc), None)
        return self.cache[key]


def _train_volumes(train_source: Any, others: list[Any], fit_scenes: int, mcfg: MapConfig,
                   tcfg: TileConfig, workers: int, progress: bool
                   ) -> tuple[np.ndarray | None, np.ndarray | None]:
    """Volumes and labels of up to ``fit_scenes`` train scenes, where a method can be fitted."""
    if train_source is None or not any(hasattr(m, 'fit') for m in others):
        return None, None
    tpack = ScenePack.from_scenes(train_source, _even_subset(len(train_source), fit_scenes),
                                  progress, 'loading train scenes')
    if workers:
        tpack.share_memory()
    ti, tl = voxelize(tpack, mcfg, tcfg, workers, progress, 'voxelizing train')
    return ti.numpy(), tl.numpy().astype(np.int64)


def _write_text(path: str | os.PathLike, text: str) -> None:
    p = Path(path)
    p.parent.mkdir(parents=True, exist_ok=True)
    p.write_text(text, encoding='utf-8')


def _write_figures(d: Path, table: str, results: list[MethodResult], cnn: CNNMethod | None,
                   x: np.ndarray, y: np.ndarray, pack: ScenePack, mcfg: MapConfig,
                   tcfg: TileConfig, title: str) -> None:
    """table.md, the ROC and reliability plots and, for the first CNN, the look inside."""
    d.mkdir(parents=True, exist_ok=True)
    (d / 'table.md').write_text(table, encoding='utf-8')
    plot_roc(results, d / 'roc.png', title)
    if any(r.reliability is not None for r in results):
        plot_reliability(results, d / 'reliability.png')
    if cnn is not None:
        tile_vox = int(round(tcfg.tile_size / mcfg.voxel_size))
        look_inside(cnn.model, results[0].scores, y, x, pack, d, mcfg.voxel_size,
                    tcfg.padding, tile_vox)


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
