"""``landing-zone evaluate-flights``: replay recorded flights and score them against their labels.

Each flight is a bag with its ground truth beside it (``SITE.labels.json`` for ``SITE.mcap``,
as ``simulate-flight`` writes it; :func:`landing_zone.io.labels.labels_path_for`). It is
replayed through the node's pipeline (:func:`landing_zone.replay.replay`, no output
bag) and its final tiles are scored (:mod:`landing_zone.io.labels`), per flight and pooled over
every flight's labelled tiles.

The map is fixed on the labelled site: its region of interest is centred on the labels'
extent (:func:`landing_zone.io.labels.labels_center`), or on a ``center`` given. A map that
follows the sensor forgets the tiles that scroll out behind it, and their obstacles would drop
out of the score. Where the labels reach past the map, the tiles it covers are scored and the
others count as unjudged (``labels_outside_map``, ``note``).

Per tile:

* ``auc``: per-tile AUC of P(safe) (safe the positive class) over the judged labelled tiles;
  None when they hold one class only;
* ``ece``: expected calibration error of P(safe) on the same tiles (15 bins,
  :mod:`landing_zone.tools.learn.calibration`);
* ``obstacle_passed``: the share of judged obstacle tiles given P(safe) >= 0.5 (the dangerous
  error); None without obstacle tiles; ``obstacle_passed_0.9``: the same at P(safe) >= 0.9
  (:data:`CONFIDENT`, where a planner acts);
* ``safe_flagged``: the share of judged safe tiles given P(safe) < 0.5 (false alarms); None
  without safe tiles; ``safe_passed_0.9``: the share of judged safe tiles at P(safe) >= 0.9
  (the ground a planner acting on 0.9 may use);
* ``unjudged``: the share of labelled tiles left without a P(safe) (not observed enough, or
  outside the map).

And the landing sites a planner would have been given (:mod:`landing_zone.judging.sites`), a
footprint's truth being "every tile under it labelled safe" (unsafe: any tile under it labelled
unsafe; footprints with an unlabelled tile and no unsafe one are not scored):

* ``sites_listed``, ``sites_over_obstacle``: the sites the final assessment lists, and how many
  of them cover a tile labelled unsafe (the error a planner lands on);
* ``site_ece``: expected calibration error of every judged footprint's P(safe) (centred on
  each tile, listed or not) against its truth; ``footprints``, ``footprints_unsafe``.

Where the robot acts (:mod:`landing_zone.tools.evaluate.footprints`), every footprint centred
on a tile, judged with the shipped site limits
(:class:`landing_zone.config.SiteConfig`, the reasons of
:class:`landing_zone.judging.sites.Candidates`):

* ``clear_footprints``: clear footprints (every tile under them labelled safe), less those left
  out only for slope, step or clearance (``clear_footprints_geometry``: the ground, not the
  judgement, rules them out); ``clear_accepted``: how many of them have no reason to be left
  out, and ``clear_accepted_share`` their share (None without clear footprints);
* ``obstacle_footprints``: footprints over a tile labelled unsafe; ``obstacle_accepted``: how
  many of them have no reason to be left out (the error a planner lands on);
* ``operating_curve``: the least tile P(safe) as the only threshold (the footprints without a
  reason but ``obstacle``): for ``k`` in :data:`CURVE_ERRORS`, the lowest threshold at which at
  most ``k`` footprints over an obstacle are accepted, and the clear footprints accepted there
  (``{'k': {'threshold', 'clear_accepted', 'share'}}``).

Each flight is also named by what its labels say it holds: ``obstacles`` (its obstacles'
families or kinds, comma separated; ``none``) and ``vegetation`` (its vegetation family, else
its preset). ``groups`` pools the flights by each (``{'obstacles': {name: figures},
'vegetation': {...}}``): the per-family table of a flight set (:mod:`landing_zone.tools.sim.
flight_sets`).

Pooled figures are computed on the tiles (and footprints) of all flights together, not
averaged over flights: the operating curve is one threshold over every flight's footprints.
Flights are independent tasks (:mod:`landing_zone.tools.engines`): a process pool here or Ray
tasks on a cluster; replay is deterministic, so the figures do not depend on the engine, the
number of workers or the order in which flights finish. Only the seconds do.
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
from landing_zone.tools.evaluate.footprints import (footprint_figures, footprint_truth,
                                                    operating_curve)
from landing_zone.errors import BagError, ConfigError

__all__ = ['THRESHOLD', 'CONFIDENT', 'FIGURES', 'flight_task', 'score_flight', 'pooled_figures',
           'flight_groups', 'grouped_figures', 'evaluate_flights', 'markdown_flights']
GROUPS = ('obstacles', 'vegetation')

THRESHOLD = 0.5  # P(safe) from which an obstacle tile counts as passed (docs/INTERFACES.md §2)
CONFIDENT = 0.9  # ... counts as passed confidently: what a planner acting on 0.9 lands on
FIGURES = ('auc', 'ece', 'obstacle_passed', 'unjudged', 'site_ece', 'sites_over_obstacle',
           'clear_accepted_share', 'obstacle_accepted')
# Footprints over an obstacle a planner's threshold may accept: the points of the operating curve.


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
        'safe_passed_0.9': (float((p[~unsafe] >= CONFIDENT).mean()) if (~unsafe).any()
                            else None),
        'unjudged': 1.0 - len(p) / labelled if labelled else None,
    }


def _site_figures(fp: np.ndarray, fy: np.ndarray, listed: int, over: int) -> dict[str, Any]:
    """The site figures: footprints' P(safe) ``fp`` with truth ``fy``, sites listed and how
    many of them cover an obstacle."""
    from landing_zone.tools.learn.calibration import expected_calibration_error

    return {'sites_listed': int(listed), 'sites_over_obstacle': int(over),
            'footprints': int(len(fp)), 'footprints_unsafe': int((fy == 0).sum()),
            'site_ece': expected_calibration_error(fp, fy) if len(fp) else None}


def labels_task_center(labels: dict[str, Any], center: Sequence[float] | None
                       ) -> tuple[float, float]:
    """The region of interest's centre: ``center`` if given, else the labels' extent's."""
    from landing_zone.io.labels import labels_center

    if center is None:
        return labels_center(labels)
    c = [float(v) for v in center]
    if len(c) != 2 or not all(np.isfinite(c)):
        raise ConfigError(f'center must be two finite numbers, got {center!r}')
    return c[0], c[1]


def flight_task(bag: str | os.PathLike[str], *, model: str | os.PathLike[str] | None = None,
                points_topic: str = '/lidar/points', pose_topic: str = '/lidar/pose',
                center: Sequence[float] | None = None) -> dict[str, Any]:
    """The task of one flight, checked here before any work: the bag and its labels exist and
    the labels parse.

    Args:
        bag: the flight.
        model: model file; None the shipped one.
        points_topic, pose_topic: the topics of the clouds and poses.
        center: (x, y) of the region of interest; None: the centre of the labels' extent.

    Raises:
        BagError: the bag does not exist.
        ConfigError: its labels file is missing or is no labels file, or a bad ``center``.
    """
    from landing_zone.io.labels import labels_path_for, read_labels

    bag = Path(bag)
    if not bag.exists():
        raise BagError(f'flight {bag} does not exist')
    labels = labels_path_for(bag)
    if not labels.is_file():
        raise ConfigError(f'flight {bag} has no ground truth beside it: {labels} is missing '
                          '(simulate-flight writes it; insert-obstacles extends it)')
    doc = read_labels(labels)
    # absolute: a worker's working directory is not the caller's (on a cluster, the paths
    # must be where every worker mounts them)
    return {'bag': str(bag.resolve()), 'labels': str(labels.resolve()),
            'model': None if model is None else str(Path(model).resolve()),
            'points_topic': points_topic, 'pose_topic': pose_topic,
            'center': list(labels_task_center(doc, center)),
            'center_from': 'labels' if center is None else 'given'}


def flight_groups(labels: dict[str, Any]) -> dict[str, str]:
    """What a flight holds, from its labels: ``obstacles`` (families, else kinds, comma
    separated; ``none`` without obstacles) and ``vegetation`` (family, else preset; ``unknown``
    where the labels do not say)."""
    flight = labels.get('flight') or {}
    site = labels.get('site') or {}
    kinds = sorted({str(o.get('kind')) for o in labels.get('obstacles', [])})
    families = [str(f) for f in flight.get('families') or []]
    vegetation = (flight.get('vegetation_family')
                  or (site.get('vegetation') or {}).get('preset') or 'unknown')
    return {'obstacles': ','.join(families or kinds) or 'none', 'vegetation': str(vegetation)}


def score_flight(task: dict[str, Any]) -> dict[str, Any]:
    """Replay one flight (a :func:`flight_task`) with its map fixed on the task's centre and
    score its final tiles.

    Returns:
        The flight's figures (:data:`FIGURES`, tile counts, footprints, seconds) and, under
        names starting with ``_``, what the pooled figures need: the judged labelled tiles'
        P(safe) and truth, the footprints'.
    """
    from landing_zone.replay import replay
    from landing_zone.io.labels import labels_extent, read_labels, tile_truth

    t0 = time.perf_counter()
    labels = read_labels(task['labels'])
    center = task.get('center')
    if center is None:  # a task made before the centre was part of it
        center = list(labels_task_center(labels, None))
    res = replay(task['bag'], None, None, points_topic=task['points_topic'],
                 pose_topic=task['pose_topic'], model=task['model'], progress=False,
                 center=center)
    a = res.assessment
    truth = tile_truth(a.centers, a.tile_size, labels)
    p = np.asarray(a.p_safe, np.float64)
    judged = (truth >= 0) & np.isfinite(p)
    n_labelled = len(labels['tiles'])
    out: dict[str, Any] = {'bag': task['bag'], 'labels': task['labels'],
                           'center': [float(c) for c in center],
                           'center_from': task.get('center_from', 'labels'),
                           **flight_groups(labels)}
    outside = n_labelled - int((truth >= 0).sum())
    out['labels_outside_map'] = outside
    if outside:
        lo, hi = labels_extent(labels)
        size = np.asarray(a.shape, np.float64) * a.tile_size
        out['note'] = (f'{outside} of {n_labelled} labelled tiles lie outside the '
                       f'{size[0]:g} m x {size[1]:g} m map centred at '
                       f'({center[0]:g}, {center[1]:g}) (the labels span '
                       f'{hi[0] - lo[0]:g} m x {hi[1] - lo[1]:g} m): scored as unjudged')
    out.update(_figures(p[judged], truth[judged].astype(np.int64), n_labelled))
    # the footprints: truth on the candidates' grid (the tiles' x-major order)
    fp, fy, over = np.zeros(0), np.zeros(0, np.int8), 0
    feet: dict[str, Any] = footprint_figures(np.zeros((0, 0), np.uint8), np.zeros((0, 0)),
                                             np.zeros((0, 0), np.int8))
    if a.candidates is not None and len(a):
        ftruth = footprint_truth(a.grid(truth), a.footprint_radius, a.tile_size)
        scored = (ftruth >= 0) & np.isfinite(a.candidates.p_safe)
        fp, fy = a.candidates.p_safe[scored], ftruth[scored]
        origin = np.asarray(a.origin)
        over = sum(int(ftruth[tuple(np.asarray(s.index) - origin)] == 0) for s in a.sites)
        feet = footprint_figures(a.candidates.reasons, a.candidates.p_safe, ftruth)
    out.update(_site_figures(fp, fy, len(a.sites), over))
    out.update(feet)
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
    # the footprints: sums, and one threshold over every flight's footprints
    n_clear = sum(f.get('clear_footprints', 0) for f in flights)
    accepted = sum(f.get('clear_accepted', 0) for f in flights)
    cp = np.concatenate([np.asarray(f.get('_cp', []), np.float64) for f in flights]
                        + [np.zeros(0)])
    op = np.concatenate([np.asarray(f.get('_op', []), np.float64) for f in flights]
                        + [np.zeros(0)])
    out.update({
        'labels_outside_map': sum(f.get('labels_outside_map', 0) for f in flights),
        'clear_footprints': n_clear,
        'clear_footprints_geometry': sum(f.get('clear_footprints_geometry', 0)
                                         for f in flights),
        'clear_accepted': accepted,
        'clear_accepted_share': accepted / n_clear if n_clear else None,
        'obstacle_footprints': sum(f.get('obstacle_footprints', 0) for f in flights),
        'obstacle_accepted': sum(f.get('obstacle_accepted', 0) for f in flights),
        'operating_curve': operating_curve(cp, op, n_clear)})
    return out


def grouped_figures(flights: Sequence[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """:func:`pooled_figures` of the flights of each obstacle family and of each vegetation
    (:data:`GROUPS`), by name."""
    out: dict[str, dict[str, Any]] = {}
    for group in GROUPS:
        names = sorted({str(f.get(group, 'unknown')) for f in flights})
        out[group] = {n: {'flights': sum(f.get(group, 'unknown') == n for f in flights),
                          **pooled_figures([f for f in flights
                                            if f.get(group, 'unknown') == n])}
                      for n in names}
    return out


def evaluate_flights(bags: Sequence[str | os.PathLike[str]], *, engine: str = 'local',
                     address: str | None = None, workers: int | None = None,
                     model: str | os.PathLike[str] | None = None,
                     points_topic: str = '/lidar/points', pose_topic: str = '/lidar/pose',
                     json_path: str | os.PathLike[str] | None = None,
                     center: Sequence[float] | None = None) -> dict[str, Any]:
    """Replay and score every flight; the figures per flight (in the order given) and pooled.

    Args:
        bags: the flights, each with ``SITE.labels.json`` beside it.
        engine: ``local`` (a process pool) or ``ray`` (one Ray task per flight).
        address: the Ray cluster (:func:`landing_zone.tools.engines.run_tasks`); default a
            local one.
        workers: processes, or the CPUs of a local Ray cluster (default: one per core).
        model: model file; default the shipped one (it must be readable where the tasks run).
        points_topic, pose_topic: the topics of the clouds and poses.
        json_path: write the results document here.
        center: (x, y) of the region of interest of every flight; None: each flight's map is
            centred on its labels' extent.

    Returns:
        ``{'engine', 'model', 'threshold', 'flights': [...], 'pooled': {...}, 'seconds',
        'flights_per_s', 'workers'}``.

    Raises:
        ConfigError, BagError: no flight, a missing bag or labels file, a bad centre (before
            any work), or what replaying a flight raised.
        EngineError: an unknown engine, Ray missing, a worker that died.
    """
    check_engine(engine, address)
    if not bags:
        raise ConfigError('evaluate-flights needs at least one flight bag')
    if model is not None and not Path(model).is_file():
        raise ConfigError(f'model {model} does not exist')
    tasks = [flight_task(b, model=model, points_topic=points_topic, pose_topic=pose_topic,
                         center=center) for b in bags]
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
           'pooled': pooled_figures(flights), 'groups': grouped_figures(flights),
           'workers': n, 'seconds': round(seconds, 3),
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
    """The per-flight and pooled figures as markdown tables: the tiles, then the footprints
    (where the results carry them), then any flight's note."""
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
    if all('clear_footprints' in f for _, f in rows):
        ks = list(doc['pooled']['operating_curve'])
        lines += ['', '| flight | safe tiles at P(safe) >= 0.9 | clear footprints accepted | '
                  'footprints over an obstacle accepted | '
                  + ' | '.join(f'clear accepted at {k} over an obstacle' for k in ks) + ' |',
                  '|---|---:|---:|---:|' + '---:|' * len(ks)]
        for name, f in rows:
            curve = [f['operating_curve'][k] for k in ks]
            lines.append(
                f'| {name} | {num(f.get("safe_passed_0.9"), ".1%")} | '
                f'{num(f["clear_accepted_share"], ".1%")} ({f["clear_accepted"]} of '
                f'{f["clear_footprints"]}) | {f["obstacle_accepted"]} of '
                f'{f["obstacle_footprints"]} | '
                + ' | '.join(f'{num(c["share"], ".1%")} (P >= {num(c["threshold"], ".3f")})'
                             for c in curve) + ' |')
    for group, table in doc.get('groups', {}).items():
        if len(table) > 1:
            lines += [''] + _group_table(group, table, num)
    notes = [f'{Path(f["bag"]).name}: {f["note"]}' for f in doc['flights'] if f.get('note')]
    if notes:
        lines += [''] + notes
    return '\n'.join(lines) + '\n'


def _group_table(group: str, table: dict[str, Any], num: Any) -> list[str]:
    """The headline figures of each group of flights (an obstacle family, a vegetation)."""
    lines = [f'| {group} | flights | AUC | ECE | obstacle tiles at >= 0.9 | safe tiles at >= 0.9 '
             '| clear footprints accepted | footprints over an obstacle accepted | clear '
             'accepted at 0 over an obstacle |', '|---|---:|---:|---:|---:|---:|---:|---:|---:|']
    for name, f in table.items():
        zero = (f.get('operating_curve') or {}).get('0') or {}
        lines.append(f'| {name} | {f["flights"]} | {num(f["auc"], ".3f")} | '
                     f'{num(f["ece"], ".3f")} | {num(f["obstacle_passed_0.9"], ".1%")} | '
                     f'{num(f.get("safe_passed_0.9"), ".1%")} | '
                     f'{num(f.get("clear_accepted_share"), ".1%")} | '
                     f'{f.get("obstacle_accepted", 0)} of {f.get("obstacle_footprints", 0)} | '
                     f'{num(zero.get("share"), ".1%")} |')
    return lines
