"""A real labelled LiDAR scan through the product: how it judges ground it was never built for.

The scan is one frame in the KITTI / SemanticKITTI layout: ``FRAME.bin`` (float32 x, y, z,
intensity per return, in the sensor's frame) and ``FRAME.label`` (uint32 per return, the
semantic class in its lower 16 bits). The classes are RELLIS-3D's ontology (:data:`CLASSES`;
Jiang et al., "RELLIS-3D Dataset: Data, Benchmarks and Analysis", 2020), whose example frame
(``utils/example/000104.bin`` in github.com/unmannedlab/RELLIS-3D, an Ouster OS1-64 on a
Clearpath Warthog, a ground vehicle) is what this was written for. Its data are licensed CC
BY-NC-SA 3.0: none of it is in this repository; a user fetches it
(experiments/2026-12-06_real-scan says how, and what it measured).

What is done:

1. **Level.** A plane is fitted to the returns of ground classes (:data:`GROUND`) 2-15 m from
   the sensor; the scan is rotated so that plane is level and shifted so it lies at z = 0. The
   sensor then stands at its mounting height above the ground (``sensor_height``), as a
   registered cloud and its pose would place it. The height is the returns', not a
   parameter: RELLIS-3D's calibration gives the LiDAR's pose to the camera, not to the ground.
2. **Assess.** The returns go through :class:`landing_zone.Assessor` as one cloud from the
   sensor's origin, its map fixed on the ground ``ahead`` metres in front of the sensor
   (``forward_deg``: the heading of "forward" in the scan's frame; 180 for the RELLIS-3D
   Ouster frame, whose +x points back over the vehicle).
3. **Label tiles** from the returns' classes: a tile holding at least
   :data:`DENSE_STRUCTURE` returns of a structure class (:data:`STRUCTURE`) between
   :data:`BAND` above its ground is an **obstacle**; a tile whose returns are all of ground
   classes is **clear** (named by its commonest class, e.g. ``clear:grass``); any other is
   ``other`` (sparse or high structure, void).
4. **Report** P(safe) per label, judged and unknown tiles, and what must hold: no obstacle
   tile at P(safe) >= 0.9.
5. **The view.** Each return's ray comes down onto the ground at a depression angle (below the
   horizontal, at the sensor). A ground vehicle sees the ground past a few metres at a few
   degrees; a helicopter's scanner at tens of degrees. :func:`steep_counts` counts each
   tile's returns from rays at least :data:`DEPRESSIONS` degrees steep, so a rule "a tile
   with fewer than ``min_returns`` such returns is unknown" can be measured here and on a
   simulated flight (:func:`flight_view`) before the judging code changes.

Run: ``python -m landing_zone.tools.evaluate.real_scan FRAME.bin FRAME.label --json OUT.json``.
"""
from __future__ import annotations

import argparse
import json
import math
import os
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from landing_zone.errors import ConfigError

__all__ = ['CLASSES', 'GROUND', 'STRUCTURE', 'BAND', 'DENSE_STRUCTURE', 'DEPRESSIONS',
           'ALT_OBSERVED', 'ALT_RETURNS',
           'read_scan', 'level_scan', 'label_tiles', 'depression_deg', 'steep_counts',
           'assess_scan', 'flight_view', 'markdown_scan', 'main']

# RELLIS-3D's ontology (benchmarks/SalsaNext/.../labels/rellis.yaml in their repository).
CLASSES = {0: 'void', 1: 'dirt', 3: 'grass', 4: 'tree', 5: 'pole', 6: 'water', 7: 'sky',
           8: 'vehicle', 9: 'object', 10: 'asphalt', 12: 'building', 15: 'log', 17: 'person',
           18: 'fence', 19: 'bush', 23: 'concrete', 27: 'barrier', 31: 'puddle', 33: 'mud',
           34: 'rubble'}
# Surfaces one could set down on (water is not among them).
GROUND = frozenset({1, 3, 10, 23, 31, 33})
# Surfaces standing above the ground.
STRUCTURE = frozenset({4, 5, 8, 9, 12, 15, 17, 18, 19, 27, 34})
# Height above a tile's ground [m] where structure makes the tile an obstacle.
BAND = (0.25, 0.80)
# Returns of structure within BAND that make a tile an obstacle ("tens of returns").
DENSE_STRUCTURE = 20
# Depression angles [deg] at which the view rule is measured.
DEPRESSIONS = (5.0, 10.0, 15.0, 20.0, 25.0, 30.0)
# The tiler's own evidence rules at stricter limits, measured beside it.
ALT_OBSERVED = (0.3, 0.35, 0.4, 0.45)
ALT_RETURNS = (100, 300, 700)


def read_scan(bin_path: str | os.PathLike[str], label_path: str | os.PathLike[str] | None = None
              ) -> tuple[np.ndarray, np.ndarray | None]:
    """One KITTI-layout frame: the returns and, if given, their semantic classes.

    Rows at the origin (no return) and non-finite rows are dropped.

    Returns:
        ``(xyz, classes)``: (N, 3) float64 and (N,) uint16 (None without a label file).

    Raises:
        ConfigError: a file is unreadable, not a whole number of records, or the two differ in
            length.
    """
    try:
        data = Path(bin_path).read_bytes()
        labels = None if label_path is None else np.fromfile(label_path, np.uint32)
    except OSError as err:
        raise ConfigError(f'cannot read the scan: {err}') from err
    if len(data) % 16:
        raise ConfigError(f'{bin_path} is not float32 x, y, z, intensity records')
    raw = np.frombuffer(data, '<f4')
    pts = raw.reshape(-1, 4)[:, :3].astype(np.float64)
    if labels is not None and len(labels) != len(pts):
        raise ConfigError(f'{label_path} holds {len(labels)} labels for {len(pts)} returns')
    keep = np.all(np.isfinite(pts), axis=1) & np.any(pts != 0, axis=1)
    classes = None if labels is None else (labels[keep] & 0xFFFF).astype(np.uint16)
    return pts[keep], classes


def level_scan(xyz: np.ndarray, classes: np.ndarray, ring: tuple[float, float] = (2.0, 15.0)
               ) -> tuple[np.ndarray, np.ndarray, dict[str, float]]:
    """Rotate and shift a scan in the sensor's frame so its ground is level at z = 0.

    The plane is fitted by least squares to the ground-class returns within ``ring`` [m] of the
    sensor (horizontally), refitted twice without the returns more than 10 cm from it (grass
    tops, kerbs).

    Returns:
        ``(xyz, origin, info)``: the returns in the levelled frame, the sensor's origin there
        (x = y = 0, z its height above the ground plane) and ``height``, ``tilt_deg`` (of the
        sensor's z axis from the vertical), ``ground_returns`` (the fit's).

    Raises:
        ConfigError: fewer than 100 ground-class returns in the ring.
    """
    r = np.hypot(xyz[:, 0], xyz[:, 1])
    sel = np.isin(classes, list(GROUND)) & (r >= ring[0]) & (r <= ring[1])
    g = xyz[sel]
    if len(g) < 100:
        raise ConfigError(f'{len(g)} ground returns within {ring} m: too few to level the scan')
    keep = np.ones(len(g), bool)
    coef = np.zeros(3)
    for _ in range(3):
        a = np.column_stack([g[keep, 0], g[keep, 1], np.ones(keep.sum())])
        coef = np.linalg.lstsq(a, g[keep, 2], rcond=None)[0]
        keep = np.abs(g[:, 0] * coef[0] + g[:, 1] * coef[1] + coef[2] - g[:, 2]) < 0.10
    n = np.array([-coef[0], -coef[1], 1.0])
    n /= np.linalg.norm(n)
    # the shortest rotation taking n onto +z (Rodrigues)
    v = np.cross(n, [0.0, 0.0, 1.0])
    s, c = np.linalg.norm(v), float(n[2])
    k = np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])
    rot = np.eye(3) + k + k @ k * ((1 - c) / (s * s)) if s > 1e-12 else np.eye(3)
    # the plane passes through (0, 0, coef[2]); after the rotation it is z = its height there
    z0 = float((rot @ np.array([0.0, 0.0, coef[2]]))[2])
    out = xyz @ rot.T - [0.0, 0.0, z0]
    origin = np.array([0.0, 0.0, -z0])
    return out, origin, {'height': -z0, 'tilt_deg': math.degrees(math.acos(min(c, 1.0))),
                         'ground_returns': int(keep.sum())}


def _tile_keys(xy: np.ndarray, tile_size: float) -> np.ndarray:
    return np.floor(np.asarray(xy, np.float64) / tile_size).astype(np.int64)


def label_tiles(xyz: np.ndarray, classes: np.ndarray, tile_size: float = 1.0
                ) -> dict[tuple[int, int], dict[str, Any]]:
    """Per tile holding returns: its label from the returns' classes (module docstring).

    A tile's ground is the 10 % height quantile of the ground-class returns in it, or in it and
    its eight neighbours when it holds fewer than 5, else the levelled plane's 0.

    Returns:
        ``{(kx, ky): {'label', 'ground_z', 'structure_in_band', 'returns'}}``.
    """
    keys = _tile_keys(xyz[:, :2], tile_size)
    ground = np.isin(classes, list(GROUND))
    structure = np.isin(classes, list(STRUCTURE))
    cells: dict[tuple[int, int], list[int]] = {}
    for i, (a, b) in enumerate(keys.tolist()):
        cells.setdefault((a, b), []).append(i)
    ground_z: dict[tuple[int, int], float] = {}
    for key, idx in cells.items():
        gz = xyz[np.asarray(idx)[ground[idx]], 2]
        if len(gz) >= 5:
            ground_z[key] = float(np.quantile(gz, 0.1))
    out = {}
    for key, idx in cells.items():
        ix = np.asarray(idx)
        gz = ground_z.get(key)
        if gz is None:
            near = [cells.get((key[0] + da, key[1] + db), []) for da in (-1, 0, 1)
                    for db in (-1, 0, 1)]
            nz = xyz[[i for c in near for i in c if ground[i]], 2]
            gz = float(np.quantile(nz, 0.1)) if len(nz) >= 5 else 0.0
        h = xyz[ix, 2] - gz
        n_band = int((structure[ix] & (h >= BAND[0]) & (h <= BAND[1])).sum())
        cls = classes[ix]
        if n_band >= DENSE_STRUCTURE:
            label = 'obstacle'
        elif np.all(ground[ix]):
            values, counts = np.unique(cls, return_counts=True)
            label = 'clear:' + CLASSES.get(int(values[np.argmax(counts)]), 'ground')
        else:
            label = 'other'
        out[key] = {'label': label, 'ground_z': gz, 'structure_in_band': n_band,
                    'returns': len(ix)}
    return out


def depression_deg(xyz: np.ndarray, origin: np.ndarray) -> np.ndarray:
    """(N,) the angle [deg] below the horizontal at which each return's ray leaves the sensor
    (negative: the ray rises)."""
    d = np.asarray(xyz, np.float64) - np.asarray(origin, np.float64)
    return np.degrees(np.arctan2(-d[:, 2], np.hypot(d[:, 0], d[:, 1])))


def steep_counts(xyz: np.ndarray, depression: np.ndarray, tile_size: float = 1.0,
                 angles: Sequence[float] = DEPRESSIONS) -> dict[tuple[int, int], list[int]]:
    """Per tile, its returns from rays at least each of ``angles`` [deg] steep."""
    keys = _tile_keys(xyz[:, :2], tile_size)
    out: dict[tuple[int, int], list[int]] = {}
    uniq, inv = np.unique(keys, axis=0, return_inverse=True)
    inv = inv.reshape(-1)
    counts = np.stack([np.bincount(inv, weights=(depression >= a).astype(np.float64),
                                   minlength=len(uniq)) for a in angles], axis=1)
    for (a, b), row in zip(uniq.tolist(), counts.astype(np.int64).tolist()):
        out[(a, b)] = row
    return out


def _quantiles(v: np.ndarray) -> list[float] | None:
    """The 0, 5, 50, 95 and 100 % quantiles of ``v`` (NaN left out), rounded; None if empty."""
    v = np.asarray(v, np.float64)
    v = v[np.isfinite(v)]
    if not len(v):
        return None
    return [round(float(q), 3) for q in np.quantile(v, [0.0, 0.05, 0.5, 0.95, 1.0])]


def _summary(p: np.ndarray) -> dict[str, Any]:
    judged = p[np.isfinite(p)]
    q = np.quantile(judged, [0.0, 0.5, 1.0]).tolist() if len(judged) else [None] * 3
    return {'tiles': int(len(p)), 'judged': int(len(judged)),
            'unknown': int(len(p) - len(judged)),
            'p_min': q[0], 'p_median': q[1], 'p_max': q[2],
            'at_0.5': int((judged >= 0.5).sum()), 'at_0.9': int((judged >= 0.9).sum())}


def _rule(judged: np.ndarray, steep: np.ndarray, min_returns: int,
          angles: Sequence[float]) -> list[dict[str, Any]]:
    """What "unknown below ``min_returns`` returns from rays at least A degrees steep" does to
    the judged tiles, per angle A."""
    return [{'depression_deg': float(a), 'judged_now': int(judged.sum()),
             'would_be_unknown': int((judged & (steep[:, k] < min_returns)).sum()),
             'still_judged': int((judged & (steep[:, k] >= min_returns)).sum())}
            for k, a in enumerate(angles)]


def _alternatives(judged: np.ndarray, observed_fraction: np.ndarray, n_returns: np.ndarray
                  ) -> dict[str, dict[str, int]]:
    """Judged tiles that rules on the evidence the tiler has already would make unknown: a
    higher ``min_observed_fraction``, a higher ``min_returns``."""
    of = np.asarray(observed_fraction, np.float64)
    nr = np.asarray(n_returns, np.float64)
    return {'observed_fraction_below': {f'{t:g}': int((judged & (of < t)).sum())
                                        for t in ALT_OBSERVED},
            'returns_below': {f'{t:g}': int((judged & (nr < t)).sum()) for t in ALT_RETURNS}}


def assess_scan(bin_path: str | os.PathLike[str], label_path: str | os.PathLike[str], *,
                model: str | os.PathLike[str] | None = None, forward_deg: float = 180.0,
                ahead: float = 10.0, angles: Sequence[float] = DEPRESSIONS,
                grazing_rule: bool = True) -> dict[str, Any]:
    """Level, assess and score one labelled frame (module docstring).

    Args:
        bin_path, label_path: the frame's returns and classes.
        model: model file; default the shipped one (with its OOD reference).
        forward_deg: heading of the vehicle's forward direction in the scan's frame [deg].
        ahead: distance from the sensor to the map's centre along it [m].
        angles: depression angles [deg] at which the view rule is measured.
        grazing_rule: judge as the product does (``tiles.min_ray_depression_deg`` at its
            default); False turns the rule off, so the frame is judged as without it and the
            ``view_rule`` table shows what each angle would take.

    Returns:
        ``{'scan', 'level', 'center', 'classes', 'by_label', 'must_hold', 'view_rule',
        'tiles'}``: ``by_label`` maps each tile label to :func:`_summary`'s figures;
        ``must_hold`` counts obstacle tiles at P(safe) >= 0.9; ``view_rule`` lists, per angle,
        the judged tiles the rule would make unknown; ``tiles`` every tile of the map with its
        label, P(safe), the network's, OOD ratio, returns and steep counts.
    """
    from landing_zone.assessor import Assessor
    from landing_zone.config import AssessorConfig

    xyz, classes = read_scan(bin_path, label_path)
    if classes is None:
        raise ConfigError('assess_scan needs the label file')
    # the sensor's height above the ground is what its returns say: moving it would bend
    # every ray
    pts, origin, info = level_scan(xyz, classes)
    h = math.radians(forward_deg)
    center = (ahead * math.cos(h), ahead * math.sin(h))
    cfg = AssessorConfig()
    if not grazing_rule:
        cfg = replace(cfg, tiles=replace(cfg.tiles, min_ray_depression_deg=0.0))
    ts = cfg.tiles.tile_size
    assessor = Assessor(cfg, center=center, model=model)
    try:
        assessor.integrate(pts, origin)
        a = assessor.assess()
    finally:
        assessor.close()
    tiles = label_tiles(pts, classes, ts)
    steep = steep_counts(pts, depression_deg(pts, origin), ts, angles)
    keys = [tuple(k) for k in a.index.tolist()]
    p = np.asarray(a.p_safe, np.float64)
    labels = np.array([tiles[k]['label'] if k in tiles else 'empty' for k in keys])
    steep_grid = np.array([steep.get(k, [0] * len(angles)) for k in keys], np.int64).reshape(
        len(keys), len(angles))
    by_label = {lab: _summary(p[labels == lab]) for lab in sorted(set(labels.tolist()))}
    obstacle = labels == 'obstacle'
    judged = np.isfinite(p)
    uniq, counts = np.unique(classes, return_counts=True)
    ood = a.ood if a.ood is not None else np.full(len(p), np.nan)
    p_net = a.p_net if a.p_net is not None else p
    rows = []
    for i, k in enumerate(keys):
        t = tiles.get(k, {})
        rows.append({'x': float(a.centers[i, 0]), 'y': float(a.centers[i, 1]),
                     'label': str(labels[i]),
                     'p_safe': None if not judged[i] else round(float(p[i]), 4),
                     'p_net': None if not np.isfinite(p_net[i]) else round(float(p_net[i]), 4),
                     'ood': None if not np.isfinite(ood[i]) else round(float(ood[i]), 3),
                     'returns': int(a.n_returns[i]),
                     'observed_fraction': round(float(a.observed_fraction[i]), 3),
                     'structure_in_band': int(t.get('structure_in_band', 0)),
                     'steep': steep_grid[i].tolist()})
    dist = np.hypot(a.centers[:, 0], a.centers[:, 1])
    return {
        'scan': str(bin_path), 'returns': int(len(pts)),
        'level': {k: round(v, 4) if isinstance(v, float) else v for k, v in info.items()}
        | {'sensor_height': round(float(origin[2]), 4)},
        'center': [round(c, 4) for c in center], 'tile_size': ts,
        'classes': {CLASSES.get(int(c), str(int(c))): int(n) for c, n in zip(uniq, counts)},
        'judged': int(judged.sum()), 'unknown': int((~judged).sum()),
        'by_label': by_label,
        'must_hold': {'obstacle_tiles': int(obstacle.sum()),
                      'obstacle_judged': int((obstacle & judged).sum()),
                      'obstacle_at_0.9': int((obstacle & judged & (p >= 0.9)).sum())},
        'judged_observed_fraction': _quantiles(a.observed_fraction[judged]),
        'judged_returns': _quantiles(a.n_returns[judged]),
        'judged_ood': _quantiles(ood[judged]),
        'judged_range_m': ([round(float(dist[judged].min()), 2),
                            round(float(dist[judged].max()), 2)] if judged.any() else None),
        'view_rule': {'min_returns': cfg.tiles.min_returns,
                      'angles': _rule(judged, steep_grid, cfg.tiles.min_returns, angles)},
        'alternatives': _alternatives(judged, a.observed_fraction, a.n_returns),
        'tiles': rows}


def flight_view(bag: str | os.PathLike[str], *, model: str | os.PathLike[str] | None = None,
                angles: Sequence[float] = DEPRESSIONS, points_topic: str = '/lidar/points',
                pose_topic: str = '/lidar/pose') -> dict[str, Any]:
    """The view rule on a recorded flight: replayed with its map fixed on its labels (as
    ``evaluate-flights`` does), and each judged tile's returns counted by the depression of
    their rays (the sensor's position at the pose nearest each cloud's stamp).

    Returns:
        ``{'bag', 'judged', 'depression_quantiles', 'view_rule', 'obstacle_tiles_judged',
        'obstacle_would_be_unknown'}``; ``depression_quantiles`` are the 1, 5, 50 % quantiles
        of the depression of the returns on the judged tiles.
    """
    from landing_zone.io.bags import read_messages
    from landing_zone.io.labels import labels_center, labels_path_for, read_labels, tile_truth
    from landing_zone.replay import replay
    from msg_adapters.pointcloud import cloud_to_xyz
    from msg_adapters.pose import pose_stamped_to_arrays

    labels = read_labels(labels_path_for(bag))
    res = replay(bag, None, None, points_topic=points_topic, pose_topic=pose_topic,
                 model=model, progress=False, center=labels_center(labels))
    a = res.assessment
    ts = a.tile_size
    stamps, positions, clouds = [], [], []
    for m in read_messages(bag, [points_topic, pose_topic]):
        if m.topic == pose_topic:
            st, pos, _ = pose_stamped_to_arrays(m.msg)
            stamps.append(st)
            positions.append(pos)
        else:
            st = int(m.msg.header.stamp.sec) * 1_000_000_000 + int(m.msg.header.stamp.nanosec)
            clouds.append((st, cloud_to_xyz(m.msg)[0]))
    order = np.argsort(stamps)
    ps, pp = np.asarray(stamps, np.int64)[order], np.asarray(positions)[order]
    shape = a.shape
    steep = np.zeros((len(a), len(angles)), np.int64)
    hist = np.zeros(91, np.int64)  # returns on the map per whole degree of depression
    for st, xyz in clouds:
        j = int(np.clip(np.searchsorted(ps, st), 1, len(ps) - 1))
        j = j if abs(ps[j] - st) < abs(ps[j - 1] - st) else j - 1
        dep = depression_deg(xyz, pp[j])
        k = _tile_keys(xyz[:, :2], ts) - np.asarray(a.origin)
        inside = np.all((k >= 0) & (k < shape), axis=1)
        flat = k[inside, 0] * shape[1] + k[inside, 1]
        for n, ang in enumerate(angles):
            steep[:, n] += np.bincount(flat[dep[inside] >= ang], minlength=len(a))
        hist += np.bincount(np.clip(dep[inside], 0, 90).astype(np.int64), minlength=91)
    p = np.asarray(a.p_safe, np.float64)
    judged = np.isfinite(p)
    truth = tile_truth(a.centers, ts, labels)
    cdf = np.cumsum(hist) / max(int(hist.sum()), 1)
    from landing_zone.config import TileConfig
    min_returns = TileConfig().min_returns
    obstacle = judged & (truth == 0)
    return {'bag': str(bag), 'judged': int(judged.sum()),
            'depression_quantiles': {q: int(np.searchsorted(cdf, q)) for q in (0.01, 0.05, 0.5)},
            'observed_fraction': _quantiles(a.observed_fraction[judged]),
            'returns': _quantiles(a.n_returns[judged]),
            'ood': _quantiles(a.ood[judged] if a.ood is not None else np.zeros(0)),
            'view_rule': {'min_returns': min_returns,
                          'angles': _rule(judged, steep, min_returns, angles)},
            'alternatives': _alternatives(judged, a.observed_fraction, a.n_returns),
            'obstacle_tiles_judged': int(obstacle.sum()),
            'obstacle_would_be_unknown': [int((obstacle & (steep[:, k] < min_returns)).sum())
                                          for k in range(len(angles))]}


def markdown_scan(doc: dict[str, Any]) -> str:
    """The scan's figures: P(safe) per tile label, what must hold, the view rule."""
    def num(v: float | None) -> str:
        return '-' if v is None else f'{v:.2f}'

    lv = doc['level']
    lines = [f'{doc["returns"]} returns; sensor {lv["sensor_height"]:.2f} m above the ground '
             f'plane (tilted {lv["tilt_deg"]:.1f} deg); map centred at {doc["center"]}; '
             f'{doc["judged"]} tiles judged, {doc["unknown"]} unknown; judged tiles '
             f'{doc["judged_range_m"]} m from the sensor', '',
             '| tile label | tiles | judged | unknown | P(safe) min | median | max | '
             '>= 0.5 | >= 0.9 |', '|---|---:|---:|---:|---:|---:|---:|---:|---:|']
    for lab, s in doc['by_label'].items():
        lines.append(f'| {lab} | {s["tiles"]} | {s["judged"]} | {s["unknown"]} | '
                     f'{num(s["p_min"])} | {num(s["p_median"])} | {num(s["p_max"])} | '
                     f'{s["at_0.5"]} | {s["at_0.9"]} |')
    mh = doc['must_hold']
    lines += ['', f'obstacle tiles (>= {DENSE_STRUCTURE} structure returns {BAND[0]}-{BAND[1]} m '
              f'above the ground): {mh["obstacle_tiles"]}, judged {mh["obstacle_judged"]}, at '
              f'P(safe) >= 0.9: {mh["obstacle_at_0.9"]} (must be 0)', '',
              f'| unknown below {doc["view_rule"]["min_returns"]} returns from rays at least '
              '... steep | judged now | would be unknown | still judged |', '|---|---:|---:|---:|']
    for r in doc['view_rule']['angles']:
        lines.append(f'| {r["depression_deg"]:g} deg | {r["judged_now"]} | '
                     f'{r["would_be_unknown"]} | {r["still_judged"]} |')
    alt = doc['alternatives']
    lines += ['', 'judged tiles a stricter tiler would make unknown: observed fraction below '
              + ', '.join(f'{k}: {v}' for k, v in alt['observed_fraction_below'].items())
              + '; returns below '
              + ', '.join(f'{k}: {v}' for k, v in alt['returns_below'].items())]
    return '\n'.join(lines) + '\n'


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m landing_zone.tools.evaluate.real_scan FRAME.bin FRAME.label``."""
    ap = argparse.ArgumentParser(prog='python -m landing_zone.tools.evaluate.real_scan',
                                 description=__doc__.split('\n\n')[0] if __doc__ else None)
    ap.add_argument('bin', type=Path, help='FRAME.bin: float32 x, y, z, intensity per return')
    ap.add_argument('label', type=Path, help='FRAME.label: uint32 class per return')
    ap.add_argument('--model', type=Path, default=None, help='model file; default the shipped')
    ap.add_argument('--forward-deg', type=float, default=180.0,
                    help="heading of the vehicle's forward in the scan's frame [deg]")
    ap.add_argument('--ahead', type=float, default=10.0,
                    help="the map's centre, this far ahead of the sensor [m]")
    ap.add_argument('--flight', type=Path, action='append', default=[],
                    help='also measure the view rule on this flight bag (labels beside it)')
    ap.add_argument('--no-grazing-rule', action='store_true',
                    help='judge with tiles.min_ray_depression_deg at 0 (the rule off), to see '
                         'what each angle of the view rule would take')
    ap.add_argument('--json', type=Path, default=None, help='write the figures here')
    args = ap.parse_args(argv)
    doc = assess_scan(args.bin, args.label, model=args.model, forward_deg=args.forward_deg,
                      ahead=args.ahead, grazing_rule=not args.no_grazing_rule)
    print(markdown_scan(doc), end='')
    flights = [flight_view(b, model=args.model) for b in args.flight]
    for f in flights:
        print(f'\n{Path(f["bag"]).name}: {f["judged"]} tiles judged; depression of their '
              f'returns: 1 % below {f["depression_quantiles"][0.01]} deg, 5 % below '
              f'{f["depression_quantiles"][0.05]} deg, median {f["depression_quantiles"][0.5]} '
              'deg')
        print(f'  stricter tiler: {f["alternatives"]}')
        for r, ob in zip(f['view_rule']['angles'], f['obstacle_would_be_unknown']):
            print(f'  {r["depression_deg"]:g} deg: {r["would_be_unknown"]} of '
                  f'{r["judged_now"]} judged tiles would be unknown ({ob} of '
                  f'{f["obstacle_tiles_judged"]} obstacle tiles)')
    if args.json is not None:
        out = dict(doc, flights=flights)
        args.json.write_text(json.dumps(out, indent=1, default=str) + '\n', encoding='utf-8')
    return 0


if __name__ == '__main__':
    raise SystemExit(main())
