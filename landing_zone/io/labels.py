"""Ground truth files, ``SITE.labels.json`` (docs/INTERFACES.md §3): read, write, score.

The simulator writes one beside every flight it simulates, ``insert-obstacles`` extends one,
and a replay's tiles are scored against one: per-tile AUC of P(safe), the unknown tiles, the
obstacle tiles judged safe (the dangerous error) and the false alarms. Every place that does
one of these does it here.

Tiles of a report and of a labels file are matched by their index on the global tile lattice
(``floor(x / tile_size)``), so centres that differ by rounding still meet.
"""
from __future__ import annotations

import json
import math
import os
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from landing_zone.errors import ConfigError

__all__ = ['labels_path_for', 'read_labels', 'write_labels', 'tile_truth', 'labels_extent',
           'labels_center', 'obstacle_footprints', 'LabelScores', 'score_tiles',
           'score_report']


def labels_path_for(bag: str | os.PathLike[str]) -> Path:
    """``SITE.labels.json`` beside ``SITE.mcap`` (or beside a bag directory ``SITE``)."""
    bag = Path(bag)
    return bag.with_name(bag.stem + '.labels.json')


def read_labels(path: str | os.PathLike[str]) -> dict[str, Any]:
    """A SITE.labels.json document, checked for the fields the tools use.

    Raises:
        ConfigError: unreadable, not JSON or not a labels file.
    """
    path = Path(path)
    try:
        doc = json.loads(path.read_text(encoding='utf-8'))
    except OSError as err:
        raise ConfigError(f'cannot read labels {path}: {err.strerror}') from err
    except ValueError as err:
        raise ConfigError(f'{path} is not JSON: {err}') from err
    ok = isinstance(doc, dict) and isinstance(doc.get('tiles'), list) and all(
        isinstance(t, dict) and {'x', 'y', 'safe'} <= set(t) for t in doc['tiles'])
    if not ok or not isinstance(doc.get('obstacles', []), list):
        raise ConfigError(f'{path} is not a labels file (tiles with x, y, safe; obstacles)')
    return doc


def write_labels(path: str | os.PathLike[str], doc: dict[str, Any]) -> None:
    """Write a labels document atomically (a temporary file beside it, then renamed).

    Raises:
        OSError: the file cannot be written (callers name it in their own error).
    """
    path = Path(path)
    tmp = path.with_name(path.name + '.tmp')
    try:
        tmp.write_text(json.dumps(doc, indent=1) + '\n', encoding='utf-8')
        os.replace(tmp, path)
    finally:
        tmp.unlink(missing_ok=True)


def _tile_keys(xy: np.ndarray, tile_size: float) -> list[tuple[int, int]]:
    k = np.floor(np.asarray(xy, np.float64).reshape(-1, 2) / tile_size).astype(np.int64)
    return [(int(a), int(b)) for a, b in k]


def tile_truth(centers: np.ndarray, tile_size: float, labels: dict[str, Any]) -> np.ndarray:
    """Per tile centre: 1 safe, 0 unsafe, -1 not labelled.

    Args:
        centers: (T, 2) tile centres [m].
        tile_size: tile edge [m] of the centres' tiling.
        labels: a labels document.
    """
    truth = {k: 1 if t['safe'] else 0 for k, t in zip(
        _tile_keys(np.array([[t['x'], t['y']] for t in labels.get('tiles', [])]).reshape(-1, 2),
                   tile_size), labels.get('tiles', []))}
    return np.array([truth.get(k, -1) for k in _tile_keys(centers, tile_size)], np.int8)


def labels_extent(labels: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """The (2,) lower and upper corners [m] of the squares of the labelled tiles.

    Raises:
        ConfigError: the document labels no tile.
    """
    tiles = labels.get('tiles', [])
    if not tiles:
        raise ConfigError('the labels hold no tile: no extent to centre on')
    ts = float(labels.get('tile_size', 1.0))
    k = np.array(_tile_keys(np.array([[t['x'], t['y']] for t in tiles]), ts), np.float64)
    return k.min(axis=0) * ts, (k.max(axis=0) + 1) * ts


def labels_center(labels: dict[str, Any]) -> tuple[float, float]:
    """The centre (x, y) [m] of the labelled tiles' extent (:func:`labels_extent`): where a
    map fixed on the labelled site is centred.

    Raises:
        ConfigError: the document labels no tile.
    """
    lo, hi = labels_extent(labels)
    c = (lo + hi) / 2
    return float(c[0]), float(c[1])


def obstacle_footprints(labels: dict[str, Any]) -> list[np.ndarray]:
    """Footprint rectangles (4, 2) of the obstacles of a labels document (size and yaw)."""
    out = []
    for ob in labels.get('obstacles', []):
        try:
            x, y, yaw = float(ob['x']), float(ob['y']), float(ob.get('yaw', 0.0))
            dx, dy = float(ob['size'][0]), float(ob['size'][1])
        except (KeyError, TypeError, ValueError, IndexError):
            continue
        c, s = math.cos(yaw), math.sin(yaw)
        corners = np.array([[-dx, -dy], [dx, -dy], [dx, dy], [-dx, dy]]) / 2
        out.append(corners @ np.array([[c, s], [-s, c]]) + [x, y])
    return out


@dataclass
class LabelScores:
    """How the judged tiles compare with the ground truth.

    Attributes:
        labelled: tiles of the labels file.
        judged: labelled tiles given a P(safe).
        unknown: labelled tiles of the assessment left unjudged.
        judged_fraction: ``judged / labelled``.
        auc: of P(safe) with safe as the positive class; None when the judged hold one class.
        unsafe: judged obstacle tiles; ``unsafe_judged_safe`` of them at P >= threshold.
        safe: judged clear tiles; ``false_alarms`` of them at P < threshold, of which
            ``false_alarms_edge`` on the outer ring of the labelled tiles (``safe_edge`` there).
    """

    labelled: int
    judged: int
    unknown: int
    judged_fraction: float
    auc: float | None
    unsafe: int
    unsafe_judged_safe: int
    safe: int
    false_alarms: int
    safe_edge: int
    false_alarms_edge: int
    threshold: float

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def score_tiles(centers: np.ndarray, p_safe: np.ndarray, tile_size: float,
                labels: dict[str, Any], threshold: float = 0.5) -> LabelScores:
    """Score per-tile P(safe) (NaN = unknown) against a labels document.

    Args:
        centers: (T, 2) tile centres [m].
        p_safe: (T,) P(safe), NaN where the tile was not judged.
        tile_size: tile edge [m].
        labels: the ground truth.
        threshold: P(safe) from which a tile counts as judged safe.
    """
    from sklearn.metrics import roc_auc_score

    p = np.asarray(p_safe, np.float64).reshape(-1)
    truth = tile_truth(centers, tile_size, labels)
    labelled = truth >= 0
    judged = labelled & np.isfinite(p)
    y, pj = truth[judged], p[judged]
    keys = _tile_keys(np.array([[t['x'], t['y']] for t in labels.get('tiles', [])]).reshape(
        -1, 2), tile_size)
    ks = np.array(keys, np.int64).reshape(-1, 2)
    mine = np.array(_tile_keys(centers, tile_size), np.int64).reshape(-1, 2)[judged]
    edge = (np.isin(mine[:, 0], [ks[:, 0].min(), ks[:, 0].max()])
            | np.isin(mine[:, 1], [ks[:, 1].min(), ks[:, 1].max()])) if len(ks) else \
        np.zeros(len(mine), bool)
    safe, unsafe = y == 1, y == 0
    n_labelled = len(labels.get('tiles', []))
    auc = (float(roc_auc_score(y, pj)) if safe.any() and unsafe.any() else None)
    return LabelScores(
        labelled=n_labelled, judged=int(judged.sum()), unknown=int((labelled & ~judged).sum()),
        judged_fraction=int(judged.sum()) / n_labelled if n_labelled else 0.0, auc=auc,
        unsafe=int(unsafe.sum()), unsafe_judged_safe=int((unsafe & (pj >= threshold)).sum()),
        safe=int(safe.sum()), false_alarms=int((safe & (pj < threshold)).sum()),
        safe_edge=int((safe & edge).sum()),
        false_alarms_edge=int((safe & edge & (pj < threshold)).sum()), threshold=threshold)


def score_report(report: dict[str, Any], labels: dict[str, Any], threshold: float = 0.5
                 ) -> LabelScores:
    """Score a replay's REPORT.json document (docs/INTERFACES.md §3) against its labels.

    Raises:
        ConfigError: the report has no tiles list.
    """
    tiles: Sequence[dict[str, Any]] | None = report.get('tiles') if isinstance(
        report, dict) else None
    if not isinstance(tiles, list):
        raise ConfigError('not a report: it has no "tiles" list')
    centers = np.array([[t['x'], t['y']] for t in tiles], np.float64).reshape(-1, 2)
    p = np.array([np.nan if t['p_safe'] is None else float(t['p_safe']) for t in tiles])
    return score_tiles(centers, p, float(report.get('tile_size', 1.0)), labels, threshold)
