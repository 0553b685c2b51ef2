"""``landing-zone evaluate-flights``: replay recorded flights and score them against their labels.

Each flight is a bag with its ground truth beside it (``SITE.labels.json`` for ``SITE.mcap``,
as ``simulate-flight`` writes it; :func:`landing_zone.io.labels.labels_path_for`). It is
replayed through the node's pipeline (:func:`landing_zone.replay.replay`, no output
bag) and its final tiles are scored (:mod:`landing_zone.io.labels`), per flight and pooled over
every flight's labelled tiles:

* ``auc``: per-tile AUC of P(safe) (safe the positive class) over the judged labelled tiles;
  None when they hold one class only;
* ``ece``: expected calibration error of P(safe) on the same tiles (15 bins,
  :mod:`landing_zone.tools.learn.calibration`);
* ``obstacle_passed``: the share of judged obstacle tiles given P(safe) >= 0.5 (the dangerous
  error); None without obstacle tiles; ``obstacle_passed_0.9``: the same at P(safe) >= 0.9
  (:data:`CONFIDENT`, where a planner acts);
* ``safe_flagged``: the share of judged safe tiles given P(safe) < 0.5 (false alarms); None
  without safe tiles;
* ``unjudged``: the share of labelled tiles left without a P(safe) (not observed enough, or
  outside the map).

And the landing sites a planner would have been given (:mod:`landing_zone.judging.sites`), a
footprint's truth being "every tile under it labelled safe" (unsafe: any tile under it labelled
unsafe; footprints with an unlabelled tile and no unsafe one are not scored):

* ``sites_listed``, ``sites_over_obstacle``: the sites the final assessment lists, and how many
  of them cover a tile labelled unsafe (the error a planner lands on);
* ``site_ece``: expected calibration error of every judged footprint's P(safe) (centred on
  each tile, listed or not) against its truth; ``footprints``, ``footprints_unsafe``.

Pooled figures are computed on the tiles of all flights together, not averaged over flights.
Flights are independent tasks (:mod:`landing_zone.tools.engines`): a process pool here or Ray tasks on
a cluster; replay is deterministic, so the figures do not depend on the engine, the number of
workers or the order in which flights finish. Only the seconds do.
"""
from __future__ import annotations

import json
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from landing_zone.tools.engines import check_engine, run_tasks
from landing_zone.errors import BagError, ConfigError

__all__ = ['THRESHOLD', 'CONFIDENT', 'FIGURES', 'flight_task', 'score_flight', 'footprint_truth',
           'pooled_figures', 'evaluate_flights', 'markdown_flights']

THRESHOLD = 0.5  # P(safe) from which an obstacle tile counts as passed (docs/INTERFACES.md §2)
CONFIDENT = 0.9  # ... counts as passed confidently: what a planner acting on 0.9 lands on
FIGURES = ('auc', 'ece', 'obstacle_passed', 'unjudged', 'site_ece', 'sites_over_obstacle')


def _figures(p: np.ndarray, y: np.ndarray, labelled: int) -> dict[str, Any]:
    """The tile figures of judged tiles ``p`` with truth ``y`` out of ``labelled`` tiles."""
    from sklearn.metrics import roc_auc_score

    from landing_zone.tools.learn.calibration import expected_calibration_error

    unsafe = y == 0
    both = bool(unsafe.any() and (~unsafe).any())
    return {
        'tiles_labelled': int(labelled), 'tiles_judged': int(len(p)),
        'obstacle_tiles': int(unsafe.sum()),
        'obstacle_judged_safe': int((unsafe & (p >= THRESHOLD)).sum()),
        'auc': float(roc_auc_score(y, p)) if both else None,
        'ece': expected_calibration_error(p, y) if len(p) else None,
        'obstacle_passed': float((p[unsafe] >= THRESHOLD).mean()) if unsafe.any() else None,
        'obstacle_passed_0.9': (float((p[unsafe] >= CONFIDENT).mean()) if unsafe.any()
                                else None),
        'safe_flagged': float((p[~unsafe] < THRESHOLD).mean()) if (~unsafe).any() else None,
        'unjudged': 1.0 - len(p) / labelled if labelled else None,
    }


def _site_figures(fp: np.ndarray, fy: np.ndarray, listed: int, over: int) -> dict[str, Any]:
    """The site figures: footprints' P(safe) ``fp`` with truth ``fy``, sites listed and how
    many of them cover an obstacle."""
    from landing_zone.tools.learn.calibration import expected_calibration_error

    return {'sites_listed': int(listed), 'sites_over_obstacle': int(over),
            'footprints': int(len(fp)), 'footprints_unsafe': int((fy == 0).sum()),
            'site_ece': expected_calibration_error(fp, fy) if len(fp) else None}


def footprint_truth(truth: np.ndarray, radius: float, tile_size: float) -> np.ndarray:
    """Per footprint centred on each tile of a (X, Y) truth grid (1 safe, 0 unsafe, -1 not
    labelled): 1 every tile under it safe, 0 any unsafe, -1 neither (an unlabelled tile, or
    off the grid)."""
    from scipy import ndimage

    from landing_zone.judging.sites import footprint_mask

    mask = footprint_mask(radius, tile_size).astype(np.int32)
    unsafe = ndimage.correlate((truth == 0).astype(np.int32), mask, mode='constant', cval=0)
    unlabelled = ndimage.correlate((truth < 0).astype(np.int32), mask, mode='constant', cval=1)
    return np.where(unsafe > 0, 0, np.where(unlabelled > 0, -1, 1)).astype(np.int8)


def flight_task(bag: str | os.PathLike[str], *, model: str | os.PathLike[str] | None = None,
                points_topic: str = '/lidar/points', pose_topic: str = '/lidar/pose'
                ) -> dict[str, Any]:
    """The task of one flight, checked here before any work: the bag and its labels exist and
    the labels parse.

    Raises:
        BagError: the bag does not exist.
        ConfigError: its labels file is missing or is no labels file.
    """
    from landing_zone.io.labels import labels_path_for, read_labels

    bag = Path(bag)
    if not bag.exists():
        raise BagError(f'flight {bag} does not exist')
    labels = labels_path_for(bag)
    if not labels.is_file():
        raise ConfigError(f'flight {bag} has no ground truth beside it: {labels} is missing '
                          '(simulate-flight writes it; insert-obstacles extends it)')
    read_labels(labels)
    # absolute: a worker's working directory is not the caller's (on a cluster, the paths
    # must be where every worker mounts them)
    return {'bag': str(bag.resolve()), 'labels': str(labels.resolve()),
            'model': None if model is None else str(Path(model).resolve()),
            'points_topic': points_topic, 'pose_topic': pose_topic}


def score_flight(task: dict[str, Any]) -> dict[str, Any]:
    """Replay one flight (a :func:`flight_task`) and score its final tiles.

    Returns:
        The flight's figures (:data:`FIGURES`, tile counts, seconds) and, under ``_p`` and
        ``_y``, the judged labelled tiles' P(safe) and truth for the pooled figures.
    """
    from landing_zone.replay import replay
    from landing_zone.io.labels import read_labels, tile_truth

    t0 = time.perf_counter()
    labels = read_labels(task['labels'])
    res = replay(task['bag'], None, None, None, points_topic=task['points_topic'],
                 pose_topic=task['pose_topic'], model=task['model'], progress=False)
    a = res.assessment
    truth = tile_truth(a.centers, a.tile_size, labels)
    p = np.asarray(a.p_safe, np.float64)
    judged = (truth >= 0) & np.isfinite(p)
    out = {'bag': task['bag'], 'labels': task['labels']}
    out.update(_figures(p[judged], truth[judged].astype(np.int64), len(labels['tiles'])))
    # the footprints: truth on the candidates' grid (the tiles' x-major order)
    fp, fy, over = np.zeros(0), np.zeros(0, np.int8), 0
    if a.candidates is not None and len(a):
        ftruth = footprint_truth(a.grid(truth), a.footprint_radius, a.tile_size)
        scored = (ftruth >= 0) & np.isfinite(a.candidates.p_safe)
        fp, fy = a.candidates.p_safe[scored], ftruth[scored]
        origin = np.asarray(a.origin)
        over = sum(int(ftruth[tuple(np.asarray(s.index) - origin)] == 0) for s in a.sites)
    out.update(_site_figures(fp, fy, len(a.sites), over))
    out['clouds'] = int(res.stats.get('clouds', 0))
    out['seconds'] = round(time.perf_counter() - t0, 3)
    out['_p'] = p[judged].astype(np.float32)
    out['_y'] = truth[judged].astype(np.int8)
    out['_fp'], out['_fy'] = fp.astype(np.float32), fy
    return out


def pooled_figures(flights: Sequence[dict[str, Any]]) -> dict[str, Any]:
    """The figures of the tiles of every flight together (results of :func:`score_flight`)."""
    p = np.concatenate([np.asarray(f['_p'], np.float64) for f in flights]) if flights else \
        np.zeros(0)
    y = np.concatenate([np.asarray(f['_y'], np.int64) for f in flights]) if flights else \
        np.zeros(0, np.int64)
    out = _figures(p, y, sum(f['tiles_labelled'] for f in flights))
    fp = np.concatenate([np.asarray(f['_fp'], np.float64) for f in flights] + [np.zeros(0)])
    fy = np.concatenate([np.asarray(f['_fy'], np.int64) for f in flights] +
                        [np.zeros(0, np.int64)])
    out.update(_site_figures(fp, fy, sum(f['sites_listed'] for f in flights),
                             sum(f['sites_over_obstacle'] for f in flights)))
    return out


def evaluate_flights(bags: Sequence[str | os.PathLike[str]], *, engine: str = 'local',
                     address: str | None = None, workers: int | None = None,
                     model: str | os.PathLike[str] | None = None,
                     points_topic: str = '/lidar/points', pose_topic: str = '/lidar/pose',
                     json_path: str | os.PathLike[str] | None = None) -> dict[str, Any]:
    """Replay and score every flight; the figures per flight (in the order given) and pooled.

    Args:
        bags: the flights, each with ``SITE.labels.json`` beside it.
        engine: ``local`` (a process pool) or ``ray`` (one Ray task per flight).
        address: the Ray cluster (:func:`landing_zone.tools.engines.run_tasks`); default a local one.
        workers: processes, or the CPUs of a local Ray cluster (default: one per core).
        model: model file; default the shipped one (it must be readable where the tasks run).
        points_topic, pose_topic: the topics of the clouds and poses.
        json_path: write the results document here.

    Returns:
        ``{'engine', 'model', 'threshold', 'flights': [...], 'pooled': {...}, 'seconds',
        'flights_per_s', 'workers'}``.

    Raises:
        ConfigError, BagError: no flight, a missing bag or labels file (before any work), or
            what replaying a flight raised.
        EngineError: an unknown engine, Ray missing, a worker that died.
    """
    check_engine(engine, address)
    if not bags:
        raise ConfigError('evaluate-flights needs at least one flight bag')
    if model is not None and not Path(model).is_file():
        raise ConfigError(f'model {model} does not exist')
    tasks = [flight_task(b, model=model, points_topic=points_topic, pose_topic=pose_topic)
             for b in bags]
    n = min(workers or len(os.sched_getaffinity(0)), len(tasks))
    t0 = time.perf_counter()
    results: list[dict[str, Any] | None] = [None] * len(tasks)
    # spawn: the caller may already run threads (numba, torch, Embree) a fork would copy
    # half-alive; a fresh worker costs an import of the pipeline, paid once per worker.
    for i, r in run_tasks(score_flight, tasks, engine=engine, workers=n, address=address,
                          start_method='spawn'):
        results[i] = r
    seconds = time.perf_counter() - t0
    flights = [r for r in results if r is not None]
    assert len(flights) == len(tasks)
    doc = {'engine': engine, 'model': None if model is None else str(model),
           'threshold': THRESHOLD,
           'flights': [{k: v for k, v in f.items() if not k.startswith('_')} for f in flights],
           'pooled': pooled_figures(flights), 'workers': n, 'seconds': round(seconds, 3),
           'flights_per_s': round(len(flights) / seconds, 4) if seconds > 0 else None}
    if json_path is not None:
        path = Path(json_path)
        tmp = path.with_name(path.name + '.tmp')
        try:
            tmp.write_text(json.dumps(doc, indent=1) + '\n', encoding='utf-8')
            os.replace(tmp, path)
        except OSError as err:
            raise ConfigError(f'cannot write {path}: {err.strerror}') from None
    return doc


def markdown_flights(doc: dict[str, Any]) -> str:
    """The per-flight and pooled figures as a markdown table."""
    def num(v: float | None, fmt: str) -> str:
        return '-' if v is None else format(v, fmt)

    lines = ['| flight | tiles judged | AUC | ECE | obstacle tiles at P(safe) >= 0.5 | '
             'at >= 0.9 | safe tiles flagged | unjudged | sites listed over an obstacle | '
             'site ECE |',
             '|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|']
    rows = [(Path(f['bag']).name, f) for f in doc['flights']] + [('**pooled**', doc['pooled'])]
    for name, f in rows:
        passed = ('-' if f['obstacle_passed'] is None else
                  f'{f["obstacle_passed"]:.1%} ({f["obstacle_judged_safe"]} of '
                  f'{f["obstacle_tiles"]})')
        lines.append(f'| {name} | {f["tiles_judged"]} of {f["tiles_labelled"]} | '
                     f'{num(f["auc"], ".3f")} | {num(f["ece"], ".3f")} | {passed} | '
                     f'{num(f["obstacle_passed_0.9"], ".1%")} | '
                     f'{num(f["safe_flagged"], ".1%")} | '
                     f'{num(f["unjudged"], ".1%")} | {f["sites_over_obstacle"]} of '
                     f'{f["sites_listed"]} | {num(f["site_ece"], ".3f")} |')
    return '\n'.join(lines) + '\n'
