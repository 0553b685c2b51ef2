"""Leave one family out: training without a family, and the figures per family.

synth3 (:mod:`landing_zone.tools.sim.synth3`) records, for every scene, the family it was drawn
from on four axes: ``obstacle`` (the pair's obstacle family; a safe scene names its twin's),
``vegetation``, ``terrain`` and ``sensor``. Two things use them:

* **Training without a family**: ``landing-zone train --data data/synth3 --hold-out
  obstacle:log`` trains on the train split minus every scene of that family (both scenes of
  each pair, so the classes stay balanced); several ``--hold-out`` drop all of them. The model
  records what it left out (``training.hold_out`` in its metadata). One synth3 directory thus
  serves every leave-one-family-out (LOFO) model: nothing is regenerated per family.
* **Figures per family**: ``landing-zone evaluate --data data/synth3 --by-family`` reports for
  every family on every axis of the test split (test instances of train families; test
  families entirely) and every model: AUC, ECE, the shares of obstacle scenes given
  P(safe) >= 0.5 and >= 0.9, and the share of safe scenes flagged (P(safe) < 0.5). The LOFO
  table then gives, for each family, the figures of the model that did not see it: a model
  that held it out, or, for the test families, any model trained on synth3's train split.

A scene is one tile: "obstacle tiles at P(safe) >= 0.5" are the unsafe scenes of the family so
judged; ECE uses the 15 bins of :mod:`landing_zone.tools.evaluate.methods`.
"""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from landing_zone.errors import ConfigError, DatasetError
from landing_zone.tools.evaluate.methods import ECE_BINS
from landing_zone.tools.learn.calibration import expected_calibration_error
from landing_zone.tools.sim.families import FAMILIES, TEST_FAMILIES
from landing_zone.tools.sim.synth3 import SENSOR_FAMILIES, TERRAIN_FAMILIES, families_of, \
    synth3_train_families
from landing_zone.tools.sim.vegetation import SYNTH3_VEGETATION, VEGETATION_FAMILIES

__all__ = ['AXES', 'parse_hold_out', 'scene_families', 'SceneSubset', 'hold_out',
           'dataset_names', 'family_folds', 'family_figures', 'family_report',
           'family_report_for', 'lofo_scores', 'markdown_families']

AXES = ('obstacle', 'vegetation', 'terrain', 'sensor')


def _known(axis: str) -> tuple[str, ...]:
    return {'obstacle': tuple(FAMILIES), 'vegetation': VEGETATION_FAMILIES,
            'terrain': tuple(TERRAIN_FAMILIES), 'sensor': tuple(SENSOR_FAMILIES)}[axis]


def parse_hold_out(specs: Sequence[str]) -> list[tuple[str, str]]:
    """``AXIS:FAMILY`` strings (``obstacle:log``, ``vegetation:lodged``) as pairs.

    Raises:
        ConfigError: a malformed spec, an unknown axis or family.
    """
    out = []
    for spec in specs:
        axis, sep, family = str(spec).partition(':')
        if not sep or not family:
            raise ConfigError(f'--hold-out wants AXIS:FAMILY (e.g. obstacle:log, '
                              f'vegetation:lodged), got {spec!r}')
        if axis not in AXES:
            raise ConfigError(f'--hold-out {spec!r}: unknown axis {axis!r}; choose from '
                              f'{", ".join(AXES)}')
        if family not in _known(axis):
            raise ConfigError(f'--hold-out {spec!r}: unknown {axis} family {family!r}; choose '
                              f'from {", ".join(_known(axis))}')
        if (axis, family) not in out:
            out.append((axis, family))
    return out


def family_folds(folds: int, seed: int = 0,
                 axes: Sequence[str] = ('obstacle', 'vegetation')) -> list[list[str]]:
    """The train families of ``axes`` dealt into ``folds`` groups, as ``AXIS:FAMILY`` specs
    (obstacles: synth3's, :func:`~landing_zone.tools.sim.synth3.synth3_train_families`, so that the
    folds stay what they were as families are added).

    Leaving a group out instead of one family costs ``folds`` models instead of one per
    family (19 on synth3), and judges each family by a model that saw fewer families than a
    one-family-out model would: the figures err on the pessimistic side. Each axis is
    shuffled with its own stream of ``seed`` and dealt round-robin from a rotating start, so
    every fold holds out families of every axis and the groups differ by at most one.

    Raises:
        ConfigError: ``folds`` < 2 or more than an axis has families.
    """
    train = {'obstacle': synth3_train_families(), 'vegetation': SYNTH3_VEGETATION}
    out: list[list[str]] = [[] for _ in range(folds)]
    for k, axis in enumerate(axes):
        names = train.get(axis)
        if names is None:
            raise ConfigError(f'folds over {axis!r}: only obstacle and vegetation have train '
                              'families')
        if not 2 <= folds <= len(names):
            raise ConfigError(f'{folds} folds: want 2 to {len(names)} ({axis} has '
                              f'{len(names)} train families)')
        order = np.random.default_rng([seed, k]).permutation(len(names))
        start = (k * len(names)) % folds  # the larger groups go to different folds per axis
        for i, j in enumerate(order):
            out[(start + i) % folds].append(f'{axis}:{names[j]}')
    return out


def scene_families(ds: Any) -> dict[str, np.ndarray]:
    """Per scene of a :class:`~landing_zone.tools.sim.dataset.SceneDataset` (in its order), the
    family on each axis, from ``meta.json`` alone (no shard is read).

    Raises:
        DatasetError: the directory records no families (only synth3 does).
    """
    shards = ds.meta.get('shards', [])
    if not shards or any('families' not in s for s in shards):
        raise DatasetError(f'{ds.root} records no families ({ds.meta.get("dataset")}; only '
                           'synth3 does): leaving a family out needs a synth3 dataset')
    return {a: np.array([shards[k]['families'][a][j] for k, j in ds._index], dtype=object)
            for a in AXES}


class SceneSubset:
    """Some scenes of a source (``len``, ``[i] -> Scene``, ``labels``), in the source's order."""

    def __init__(self, source: Any, positions: np.ndarray, name: str = '') -> None:
        self.source = source
        self.positions = np.asarray(positions, dtype=np.int64)
        labels = getattr(source, 'labels', None)
        self.labels = (np.asarray(labels, np.int64)[self.positions] if labels is not None
                       else np.array([int(source[int(i)].label) for i in self.positions]))
        self.name = name

    def __len__(self) -> int:
        return len(self.positions)

    def __getitem__(self, i: int) -> Any:
        if not -len(self) <= i < len(self):
            raise IndexError(f'scene {i} out of range ({len(self)} scenes)')
        return self.source[int(self.positions[i])]


def hold_out(source: Any, specs: Sequence[str]) -> SceneSubset | Any:
    """``source`` without the scenes of the held-out families.

    Args:
        source: a SceneDataset, or a :class:`landing_zone.tools.learn.scenes.ConcatScenes` of them.
        specs: ``AXIS:FAMILY`` strings.

    Raises:
        ConfigError: a bad spec.
        DatasetError: a source that records no families, or nothing left.
    """
    pairs = parse_hold_out(specs)
    if not pairs:
        return source
    parts = getattr(source, 'sources', None)
    if parts is not None:  # several directories, one after the other
        from landing_zone.tools.learn.scenes import ConcatScenes
        return ConcatScenes([hold_out(p, specs) for p in parts], getattr(source, 'names', None))
    fams = scene_families(source)
    keep = np.ones(len(source), dtype=bool)
    for axis, family in pairs:
        keep &= fams[axis] != family
    if not keep.any():
        raise DatasetError(f'{getattr(source, "root", "the data")}: no scene left after '
                           f'holding out {", ".join(specs)}')
    return SceneSubset(source, np.flatnonzero(keep),
                       f'{getattr(source, "root", "")} without {", ".join(specs)}')


def dataset_names(source: Any) -> list[str]:
    """The datasets (``meta.json``'s ``dataset``) a training source is made of."""
    parts = getattr(source, 'sources', None)
    if parts is not None:
        return [n for p in parts for n in dataset_names(p)]
    inner = getattr(source, 'source', None)
    if isinstance(source, SceneSubset) and inner is not None:
        return dataset_names(inner)
    meta = getattr(source, 'meta', None)
    return [str(meta.get('dataset'))] if isinstance(meta, dict) else []


# --- figures per family ------------------------------------------------------------------------

def family_figures(p_safe: np.ndarray, labels: np.ndarray, probabilistic: bool = True
                   ) -> dict[str, Any]:
    """AUC, ECE and the shares that matter for landing, of one family's scenes."""
    from sklearn.metrics import roc_auc_score
    p = np.asarray(p_safe, np.float64)
    y = np.asarray(labels, np.int64)
    unsafe, safe = y == 0, y == 1

    def share(mask: np.ndarray, sel: np.ndarray) -> float | None:
        return float(np.mean(mask[sel])) if sel.any() and probabilistic else None

    return {
        'n': int(len(y)), 'n_unsafe': int(unsafe.sum()),
        'auc': float(roc_auc_score(y, p)) if unsafe.any() and safe.any() else None,
        'ece': (expected_calibration_error(p, y, ECE_BINS) if probabilistic and len(y)
                else None),
        'unsafe_ge_0.5': share(p >= 0.5, unsafe), 'unsafe_ge_0.9': share(p >= 0.9, unsafe),
        'safe_lt_0.5': share(p < 0.5, safe)}


def lofo_scores(rows: dict[str, dict[str, Any]], families: np.ndarray,
                scores: dict[str, Any]) -> np.ndarray:
    """Every scene's score by the model that never saw its family: ``rows`` an axis of the
    LOFO table (family -> its row, naming the ``model``), ``families`` the scenes' families on
    that axis, ``scores`` per method name the scenes' scores. NaN where no row has the family."""
    out = np.full(len(families), np.nan)
    for family, row in rows.items():
        at = families == family
        out[at] = np.asarray(scores[row['model']], np.float64)[at]
    return out


def _families_of_params(params: Sequence[dict]) -> dict[str, np.ndarray]:
    try:
        rows = [families_of(p) for p in params]
    except (KeyError, TypeError) as err:
        raise DatasetError('the scenes record no families (only synth3 scenes do): '
                           '--by-family needs a synth3 dataset') from err
    return {a: np.array([r[a] for r in rows], dtype=object) for a in AXES}


def family_report(results: Sequence[Any], params: Sequence[dict], labels: np.ndarray,
                  held_out: dict[str, list[tuple[str, str]]] | None = None,
                  trained_on_synth3: dict[str, bool] | None = None,
                  probabilistic: dict[str, bool] | None = None) -> dict[str, Any]:
    """Figures per family for every method, and the leave-one-family-out table.

    Args:
        results: per method, an object with ``name`` and ``scores`` (aligned with ``params``).
        params: the evaluated scenes' parameters (they name their families).
        labels: (T,) 1 safe, 0 unsafe.
        held_out: per method name, the (axis, family) pairs its training left out.
        trained_on_synth3: per method name, whether it was trained on synth3's train split
            (then the test families, never in that split, count as held out).
        probabilistic: per method name, whether its scores are P(safe) (default: yes).

    Returns:
        ``{'methods': {name: {axis: {family: figures}}}, 'lofo': {axis: {family: figures +
        'model' + 'in_family'}}, 'lofo_pooled': {axis: figures + 'families'}}``. Families
        without a method that left them out are missing from 'lofo'. ``in_family`` is the same
        family judged by the first method trained on it (on synth3, without holding it out:
        other instances of a family it saw), with its 'model', or None: beside the held-out
        figures it says what leaving the family out cost. 'lofo_pooled' scores every scene of
        an axis whose family has a 'lofo' row by that row's model, so the shares pool the
        families (each scene judged by a model that never saw its family).
    """
    fams = _families_of_params(params)
    y = np.asarray(labels, np.int64)
    held_out = held_out or {}
    trained_on_synth3 = trained_on_synth3 or {}
    probabilistic = probabilistic or {}
    methods: dict[str, Any] = {}
    lofo: dict[str, dict[str, Any]] = {a: {} for a in AXES}
    seen: dict[tuple[str, str], dict[str, Any]] = {}  # (axis, family) -> first trained on it
    scores = {r.name: np.asarray(r.scores, np.float64) for r in results}
    for r in results:
        prob = probabilistic.get(r.name, True)
        per: dict[str, Any] = {}
        unseen = set(held_out.get(r.name, []))
        if trained_on_synth3.get(r.name):
            unseen |= {('obstacle', f) for f in TEST_FAMILIES}
        for axis in AXES:
            per[axis] = {}
            for family in sorted(set(fams[axis])):
                sel = fams[axis] == family
                fig = family_figures(scores[r.name][sel], y[sel], prob)
                per[axis][family] = fig
                if not prob:
                    continue
                if (axis, family) in unseen:
                    lofo[axis].setdefault(family, {**fig, 'model': r.name})
                elif trained_on_synth3.get(r.name):
                    seen.setdefault((axis, family), {**fig, 'model': r.name})
        methods[r.name] = per
    pooled: dict[str, Any] = {}
    for axis, rows in lofo.items():
        for family, row in rows.items():
            row['in_family'] = seen.get((axis, family))
        if rows:
            p = lofo_scores(rows, fams[axis], scores)
            sel = ~np.isnan(p)
            pooled[axis] = {**family_figures(p[sel], y[sel]), 'families': len(rows)}
    return {'methods': methods, 'lofo': {a: v for a, v in lofo.items() if v},
            'lofo_pooled': pooled}


def _fmt(v: float | None, pct: bool = False) -> str:
    if v is None or (isinstance(v, float) and not math.isfinite(v)):
        return '-'
    return f'{100 * v:.1f}%' if pct else f'{v:.3f}'


def markdown_families(report: dict[str, Any], axes: Sequence[str] = AXES) -> str:
    """The report as markdown: the LOFO table first (when there is one), then per method one
    table per axis."""
    lines: list[str] = []
    head = ('| family | scenes (unsafe) | AUC | ECE | obstacle tiles P>=0.5 | P>=0.9 | '
            'safe tiles P<0.5 |')
    rule = '|---|---:|---:|---:|---:|---:|---:|'

    def row(family: str, f: dict[str, Any]) -> str:
        return (f'| {family} | {f["n"]} ({f["n_unsafe"]}) | {_fmt(f["auc"])} | '
                f'{_fmt(f["ece"])} | {_fmt(f["unsafe_ge_0.5"], True)} | '
                f'{_fmt(f["unsafe_ge_0.9"], True)} | {_fmt(f["safe_lt_0.5"], True)} |')

    def in_family(f: dict[str, Any]) -> str:
        s = f.get('in_family')
        return (' - |' if not s else f' {_fmt(s["auc"])} / {_fmt(s["unsafe_ge_0.5"], True)} / '
                f'{_fmt(s["unsafe_ge_0.9"], True)} |')

    if report.get('lofo'):
        lines += ['Leave one family out: each family judged by a model that never saw it; '
                  'beside it, the same family by a model trained on other instances of it.', '',
                  head + ' model | trained on it: AUC / P>=0.5 / P>=0.9 |', rule + '---|---|']
        pooled = report.get('lofo_pooled', {})
        for axis in axes:
            for family, f in sorted(report['lofo'].get(axis, {}).items()):
                lines.append(row(f'{axis}:{family}', f) + f' {f["model"]} |' + in_family(f))
            if axis in pooled:
                lines.append(row(f'{axis}: all {pooled[axis]["families"]} families pooled',
                                 pooled[axis]) + ' each family by its own | |')
        lines.append('')
    for name, per in report['methods'].items():
        for axis in axes:
            if axis not in per:
                continue
            lines += [f'{name}, by {axis} family:', '', head, rule]
            lines += [row(family, f) for family, f in per[axis].items()]
            lines.append('')
    return '\n'.join(lines)


def family_report_for(results: Sequence[Any], params: Sequence[dict], labels: np.ndarray,
                      metas: Sequence[dict]) -> dict[str, Any]:
    """:func:`family_report` of an evaluation: the first ``len(metas)`` results are the CNNs
    whose model metadata are ``metas`` (what they held out, what they were trained on); a
    method is probabilistic where its result carries a reliability diagram."""
    held, synth3 = {}, {}
    for r, meta in zip(results, metas):
        training = meta.get('training', {}) or {}
        held[r.name] = parse_hold_out(training.get('hold_out', []) or [])
        synth3[r.name] = 'synth3' in (meta.get('datasets') or [])
    prob = {r.name: getattr(r, 'reliability', None) is not None for r in results}
    return family_report(results, params, labels, held, synth3, prob)
