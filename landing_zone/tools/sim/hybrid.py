"""The hybrid dataset: patches cut from recorded flights, half of them with an inserted obstacle.

Usage::

    landing-zone simulate --dataset hybrid --from a.mcap --from b.mcap --out data/hybrid

Real grass, ground and sensor noise come from the flights; the obstacles come from the
simulator's library and are put in by cutting short the rays that would have hit them
(:func:`landing_zone.tools.sim.alteration.alter_returns`), so the set is labelled exactly, like
synth1/2, but its clutter is the flights'. The result has the synth datasets' format
(``meta.json`` and ``shards/*.npz``, see :mod:`landing_zone.tools.sim.shards`), so
:class:`SceneDataset`, ``landing-zone train`` and ``landing-zone evaluate`` (and the
augmentation) read it unchanged.

**Patches.** For each flight, every return and its sensor origin (the pose interpolated at the
cloud's stamp, :func:`landing_zone.tools.sim.recorded.read_flight`). Candidate patches are the 1 m
tiles of the global lattice (centres at x.5) in the flight's clear region: the safe tiles of
``BAG.labels.json`` whose eight neighbours are safe too (no labelled obstacle reaches the tile's
context), within ``region`` if one is given; or, for a flight without labels, the tiles of
``region``. A candidate must hold ``MIN_PATCH_RETURNS`` returns and its neighbours half that
(the context around the tile was scanned). Up to ``patches`` of them are drawn per flight.

**A patch** keeps what a synth scene keeps: every ray that passes through the tile's padded
column (the tile and 0.3 m around it, from 1 m below to 2 m above its ground; see
:class:`~landing_zone.tools.sim.scene.PatchConfig`), found for all patches at once by a compiled
ray/box pass over the flight. Its ground is :func:`landing_zone.tools.sim.placement.ground_height`
at the
tile centre; the patch frame puts the tile centre at (0, 0) and that ground at z = 0. Half the
patches (a seeded draw) get one obstacle, placed as synth2 places them
(:func:`~landing_zone.tools.sim.scene.simulate_patch`): half of those wholly inside the tile, half
straddling its edge; its model drawn as synth2 draws them (rocks, tires, cinder blocks) from
the split's obstacle group; standing on the ground estimated around it, sunk by
``landing_zone.tools.sim.insert.SINK`` (and the model's embedding). The altered returns get hit
class 2
(obstacle); the others keep the flight's ``label`` field (0 ground, 1 grass, 2 obstacle), or
255 (unknown) for flights without one.

**Splits.** By flight: the ``test_flights`` (``--test-from``) form the test split; without
them and with more than one flight, the last flight does. A single flight is split by tile (a
hash puts a fifth of its tiles into the test split; neighbouring tiles share rays, so that test
split is optimistic). Test patches take their obstacles from the library's test group, train
patches from its train group; ``meta.json`` records which flight went where.

**Determinism.** Patch ``i`` of flight ``f`` draws from ``SeedSequence([seed, 3, f, i])``; the
draw of patches from ``SeedSequence([seed, 3, f])``: the same seed and flights give the same
bytes. Shards hold the patches of one flight each and are written atomically; a rerun with the
same arguments reads the flights again and skips the shards already there.
"""
from __future__ import annotations

import math
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numba as nb
import numpy as np
from scipy.spatial import cKDTree

from landing_zone.errors import BagError, ConfigError, DatasetError, SimulationError
from landing_zone.io.labels import labels_path_for, read_labels
from landing_zone.tools.sim.alteration import RANGE_SIGMA, alter_returns, segment_meets_box
from landing_zone.tools.sim.dataset import progress_bar
from landing_zone.tools.sim.hashing import mix
from landing_zone.tools.sim.library import get_model, models
from landing_zone.tools.sim.mesh import OBSTACLE
from landing_zone.tools.sim.obstacles import Obstacle
from landing_zone.tools.sim.placement import SINK, ground_height, ground_radius
from landing_zone.tools.sim.recorded import read_flight
from landing_zone.tools.sim.scene import PatchConfig
from landing_zone.tools.sim.shards import FORMAT_VERSION, prepare_output, shard_arrays, \
    shard_complete, shard_name, write_json, write_npz
from landing_zone.tools.sim.sweeps import SWEEPS, TEST_FRACTION, choose_model

__all__ = ['simulate_hybrid', 'plan_flight', 'column_rays', 'MIN_PATCH_RETURNS']

HYBRID_CODE = 3  # after synth1 (1) and synth2 (2) in the seed sequences
MIN_PATCH_RETURNS = 500  # a candidate tile holds this many returns, its neighbours half
UNKNOWN_CLASS = 255  # hit class of returns of flights without a label field


@nb.njit(cache=True)
def _column_pass(o: np.ndarray, p: np.ndarray, cloud: np.ndarray, boxes: np.ndarray,
                 pid: np.ndarray, k0: np.ndarray, tile: float, pad: float, zlo: float,
                 zhi: float, counts: np.ndarray, offsets: np.ndarray, out: np.ndarray,
                 fill: bool) -> None:
    """Count (or, with ``fill``, list) the rays meeting each patch's column box.

    A ray is clipped to the band [zlo, zhi] every column lies in; the tiles its clipped part
    can reach (its xy bounding box widened by the columns' padding) are looked up in ``pid``
    (tile -> patch, -1 none) and the segment is tested against each such patch's box exactly
    (slab method). Rays come in order, so each patch's list is in bag order.
    """
    nx, ny = pid.shape
    for i in range(p.shape[0]):
        c = cloud[i]
        ox, oy, oz = o[c, 0], o[c, 1], o[c, 2]
        if ox != ox:
            continue  # no origin: the cloud had no pose at its stamp
        dx, dy, dz = p[i, 0] - ox, p[i, 1] - oy, p[i, 2] - oz
        # the part of the segment within the band
        if dz == 0.0:
            if oz < zlo or oz > zhi:
                continue
            ta, tb = 0.0, 1.0
        else:
            ta, tb = (zlo - oz) / dz, (zhi - oz) / dz
            if ta > tb:
                ta, tb = tb, ta
            ta, tb = max(ta, 0.0), min(tb, 1.0)
            if ta > tb:
                continue
        xa, xb = ox + ta * dx, ox + tb * dx
        ya, yb = oy + ta * dy, oy + tb * dy
        kx0 = int(math.floor((min(xa, xb) - pad) / tile)) - k0[0]
        kx1 = int(math.floor((max(xa, xb) + pad) / tile)) - k0[0]
        ky0 = int(math.floor((min(ya, yb) - pad) / tile)) - k0[1]
        ky1 = int(math.floor((max(ya, yb) + pad) / tile)) - k0[1]
        for kx in range(max(kx0, 0), min(kx1, nx - 1) + 1):
            for ky in range(max(ky0, 0), min(ky1, ny - 1) + 1):
                q = pid[kx, ky]
                if q < 0:
                    continue
                if segment_meets_box(o, c, p, i, boxes, q):
                    if fill:
                        out[offsets[q] + counts[q]] = i
                    counts[q] += 1


def column_rays(points: np.ndarray, cloud: np.ndarray, origins: np.ndarray,
                tiles: np.ndarray, boxes: np.ndarray, tile_size: float = 1.0,
                padding: float = 0.3) -> list[np.ndarray]:
    """The rays (origin -> return) that pass through each patch's column.

    Args:
        points: (N, 3) returns.
        cloud: (N,) index of each return's origin in ``origins``.
        origins: (C, 3) sensor origins (NaN rows: rays left out).
        tiles: (P, 2) int tile index of each patch (distinct).
        boxes: (P, 2, 3) each patch's column, reaching at most ``padding`` beyond its tile.
        tile_size: of the lattice [m].
        padding: how far a column reaches beyond its tile [m].

    Returns:
        One int64 array of return indices per patch, ascending.
    """
    tiles = np.asarray(tiles, np.int64).reshape(-1, 2)
    n_p = len(tiles)
    if not n_p:
        return []
    k0 = tiles.min(axis=0)
    shape = tiles.max(axis=0) - k0 + 1
    pid = np.full(shape, -1, np.int64)
    pid[tiles[:, 0] - k0[0], tiles[:, 1] - k0[1]] = np.arange(n_p)
    b = np.ascontiguousarray(boxes, np.float64)
    zlo, zhi = float(b[:, 0, 2].min()), float(b[:, 1, 2].max())
    args = (np.ascontiguousarray(origins, np.float64), np.ascontiguousarray(points, np.float64),
            np.ascontiguousarray(cloud, np.int64), b, pid, k0, float(tile_size),
            float(padding), zlo, zhi)
    counts = np.zeros(n_p, np.int64)
    _column_pass(*args, counts, np.zeros(n_p, np.int64), np.zeros(0, np.int64), False)
    offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    out = np.empty(int(offsets[-1]), np.int64)
    counts[:] = 0
    _column_pass(*args, counts, offsets, out, True)
    return [out[offsets[q]:offsets[q + 1]] for q in range(n_p)]


def _tile_split(tiles: np.ndarray) -> np.ndarray:
    """A fifth of the tiles (by a hash of their index) are test tiles."""
    keys = (tiles[:, 0].astype(np.int64) & 0xFFFFFFFF) << 32 | (tiles[:, 1] & 0xFFFFFFFF)
    h = mix(keys.astype(np.uint64) + np.uint64(0x4B1D << 32)) % np.uint64(1000)
    return h < np.uint64(int(1000 * TEST_FRACTION))


def plan_flight(points: np.ndarray, labels: dict[str, Any] | None,
                region: Sequence[float] | None, patches: int, rng: np.random.Generator
                ) -> tuple[np.ndarray, int]:
    """The tiles a flight's patches are cut from.

    Args:
        points: (N, 3) the flight's returns.
        labels: its SITE.labels.json document, or None.
        region: ``(x0, y0, x1, y1)``: only tiles whose centre lies inside.
        patches: at most this many.
        rng: draws the tiles.

    Returns:
        ``(tiles (P, 2) int64 sorted, candidates)``.

    Raises:
        ConfigError: neither labels nor region, or a bad region.
    """
    if labels is None and region is None:
        raise ConfigError('a flight without BAG.labels.json needs --region X0 Y0 X1 Y1 (its '
                          'clear area)')
    k = np.floor(np.asarray(points, np.float64)[:, :2]).astype(np.int64)
    keys, n = np.unique(k, axis=0, return_counts=True)
    count = dict(zip(map(tuple, keys.tolist()), n.tolist()))
    ring = [(dx, dy) for dx in (-1, 0, 1) for dy in (-1, 0, 1) if dx or dy]
    ok = set()
    for (kx, ky), c in count.items():
        if c >= MIN_PATCH_RETURNS and all(
                count.get((kx + dx, ky + dy), 0) >= MIN_PATCH_RETURNS // 2 for dx, dy in ring):
            ok.add((kx, ky))
    if labels is not None:
        ts = float(labels.get('tile_size', 1.0))
        if abs(ts - 1.0) > 1e-9:
            raise ConfigError(f'the labels file has {ts:g} m tiles; the hybrid set needs 1 m')
        safe = {(int(math.floor(t['x'])), int(math.floor(t['y']))): bool(t['safe'])
                for t in labels.get('tiles', [])}
        ok = {t for t in ok if safe.get(t) and all(
            safe.get((t[0] + dx, t[1] + dy), False) for dx, dy in ring)}
    if region is not None:
        r = np.asarray(region, np.float64)
        if r.shape != (4,) or not np.isfinite(r).all() or r[2] <= r[0] or r[3] <= r[1]:
            raise ConfigError(f'region must be X0 Y0 X1 Y1 with X0 < X1 and Y0 < Y1, got '
                              f'{list(region)}')
        ok = {t for t in ok if r[0] <= t[0] + 0.5 <= r[2] and r[1] <= t[1] + 0.5 <= r[3]}
    cand = np.array(sorted(ok), np.int64).reshape(-1, 2)
    if len(cand) > patches:
        cand = cand[np.sort(rng.choice(len(cand), patches, replace=False))]
    return cand, len(ok)


def _flight_plan(index: int, bag: Path, split: str, args: dict[str, Any]) -> dict[str, Any]:
    """Read a flight and decide its patches: tiles, grounds, columns, labels, splits."""
    fr = read_flight(bag, args['points_topic'], args['pose_topic'], args['frame_id'])
    lp = labels_path_for(bag)
    labels = read_labels(lp) if lp.exists() else None
    rng = np.random.default_rng(np.random.SeedSequence([args['seed'], HYBRID_CODE, index]))
    tiles, n_cand = plan_flight(fr.points, labels, args['region'], args['patches'], rng)
    tree = cKDTree(fr.points[:, :2])
    centres = (tiles + 0.5).astype(np.float64)
    grounds = np.full(len(tiles), np.nan)
    for t, c in enumerate(centres):
        near = tree.query_ball_point(c, 0.5)
        g = ground_height(fr.points[near], c[0], c[1], 0.5) if near else None
        grounds[t] = np.nan if g is None else g
    keep = np.isfinite(grounds)
    tiles, centres, grounds = tiles[keep], centres[keep], grounds[keep]
    if split == 'tile':
        splits = np.where(_tile_split(tiles), 'test', 'train')
    else:
        splits = np.full(len(tiles), split)
    unsafe = np.zeros(len(tiles), bool)
    unsafe[rng.permutation(len(tiles))[:len(tiles) // 2]] = True
    pc = PatchConfig()
    h = 0.5 * pc.tile_size + pc.padding
    boxes = np.stack([np.column_stack([centres - h, grounds - pc.column_below]),
                      np.column_stack([centres + h, grounds + pc.column_above])], axis=1)
    return {'tiles': tiles, 'centres': centres, 'grounds': grounds, 'splits': splits,
            'unsafe': unsafe, 'boxes': boxes, 'candidates': n_cand, 'labels': labels is not None,
            'returns': int(len(fr.points)), 'index': index, 'bag': bag}


def _patch_record(plan: dict[str, Any], fr: Any, tree: Any, t: int, rays: np.ndarray,
                  scene_index: int, seed: int) -> dict[str, Any]:
    """One scene: the column's rays in the patch frame, with an obstacle if it is unsafe."""
    split = str(plan['splits'][t])
    rng = np.random.default_rng(np.random.SeedSequence([seed, HYBRID_CODE, plan['index'], t]))
    cx, cy = plan['centres'][t]
    g = float(plan['grounds'][t])
    pts = fr.points[rays]
    org = fr.ray_origins(rays)
    hit = fr.labels[rays].copy()
    obstacle = None
    altered = 0
    if plan['unsafe'][t]:
        model = get_model(choose_model(SWEEPS['synth2'], split, rng))
        # as simulate_patch: half inside the tile for any yaw, half straddling its edge
        if rng.uniform() < 0.5:
            free = 0.5 - model.radius
        else:
            free = 0.5 + 0.5 * model.radius
        x, y = rng.uniform(-free, free, 2) + (cx, cy)
        yaw = float(rng.uniform(0.0, 2.0 * np.pi))
        radius = ground_radius(model)
        near = tree.query_ball_point((x, y), radius)
        gz = ground_height(fr.points[near], x, y, radius) if near else None
        z = (g if gz is None else gz) - model.embed - SINK
        placed = Obstacle(model, float(x), float(y), float(z), yaw)
        pts, mask = alter_returns(pts, org, [placed], rng, RANGE_SIGMA)
        hit[mask] = OBSTACLE
        altered = int(mask.sum())
        obstacle = Obstacle(model, float(x - cx), float(y - cy), float(z - g), yaw)
    shift = np.array([cx, cy, g])
    mm = np.rint((pts - shift) * 1000.0)
    if np.any(np.abs(mm) > np.iinfo(np.int16).max):
        far = np.any(np.abs(mm) > np.iinfo(np.int16).max, axis=1)
        mm, hit, org, rays = mm[~far], hit[~far], org[~far], rays[~far]
    clouds, inverse = np.unique(fr.cloud[rays], return_inverse=True)
    if len(clouds) > np.iinfo(np.uint16).max:
        raise SimulationError(f'patch at ({cx}, {cy}): rays of more than 65535 clouds')
    label = 0 if obstacle is not None else 1
    params = {'dataset': 'hybrid', 'index': int(scene_index), 'split': split, 'label': label,
              'flight': plan['bag'].name, 'flight_index': plan['index'],
              'tile': [float(cx), float(cy)], 'ground_z': round(g, 4),
              'obstacle': obstacle.to_json() if obstacle is not None else None,
              'n_returns': int(len(mm)), 'altered': altered, 'seed': int(seed)}
    t0 = fr.stamps[0]
    return {'points_mm': mm.astype(np.int16), 'hit_class': hit.astype(np.uint8),
            'origin_index': inverse.astype(np.uint16).reshape(-1),
            'origins': (fr.origins[clouds] - shift).astype(np.float32),
            'origin_times': ((fr.stamps[clouds] - t0) / 1e9).astype(np.float32),
            'label': label, 'split': split, 'params': params}


def _hybrid_meta(flights: list[dict[str, Any]], shards: list[dict[str, Any]],
                 args: dict[str, Any], split_by: str, n_scenes: int,
                 counts: dict[str, dict[str, int]]) -> dict[str, Any]:

    kinds = SWEEPS['synth2'].kinds
    patch = PatchConfig()
    return {
        'format': 'landing_zone.tools.sim.dataset', 'format_version': FORMAT_VERSION,
        'dataset': 'hybrid', 'seed': int(args['seed']), 'split': 'both',
        'scenes_requested': None, 'n_scenes': n_scenes, 'shard_size': args['shard_size'],
        'patches_per_flight': args['patches'],
        'region': list(map(float, args['region'])) if args['region'] is not None else None,
        'split_by': split_by, 'flights': flights, 'counts': counts,
        'obstacle_split': {'train': sorted(m.name for m in models(kinds, 'train')),
                           'test': sorted(m.name for m in models(kinds, 'test'))},
        'patch': {'tile_size': patch.tile_size, 'padding': patch.padding,
                  'column_below': patch.column_below, 'column_above': patch.column_above,
                  'frame': 'tile centre at (0, 0), estimated ground at z = 0',
                  'points_unit': 'mm (int16)',
                  'hit_class': "the flight's label field (0 ground, 1 grass, 2 obstacle), "
                               '255 unknown; inserted obstacle: 2'},
        'shards': shards,
    }


def _plan_key(meta: dict[str, Any]) -> tuple:
    return (meta.get('format_version'), meta.get('dataset'), meta.get('seed'),
            meta.get('n_scenes'), meta.get('shard_size'), meta.get('region'),
            tuple((f['bag'], f['split'], f['patches']) for f in meta.get('flights', [])),
            tuple(s['first_index'] for s in meta.get('shards', [])))


def simulate_hybrid(flights: Sequence[str | os.PathLike[str]], out: str | os.PathLike[str], *,
                    test_flights: Sequence[str | os.PathLike[str]] = (), patches: int = 1000,
                    seed: int = 0, region: Sequence[float] | None = None,
                    points_topic: str = '/lidar/points', pose_topic: str = '/lidar/pose',
                    frame_id: str = 'map', shard_size: int = 32, progress: bool = True
                    ) -> dict[str, Any]:
    """Write (or finish writing) a hybrid dataset directory.

    Args:
        flights: bags to cut patches from (each with ``BAG.labels.json`` beside it, or give
            ``region``).
        out: dataset directory (created; a rerun with the same arguments resumes).
        test_flights: bags whose patches form the test split (default: the last of
            ``flights`` when there are several; a single flight is split by tile).
        patches: at most this many patches per flight.
        seed: of the patch draw, the obstacles and the range noise.
        region: ``(x0, y0, x1, y1)`` the clear area patches come from (with labels: within
            their safe tiles).
        points_topic, pose_topic, frame_id: as ``landing-zone replay`` reads the bags.
        shard_size: scenes per shard file.
        progress: a progress bar on stderr.

    Returns:
        Summary: scenes, generated and skipped, seconds, bytes, counts by split.

    Raises:
        ConfigError: no flight, bad region, a flight without labels or region.
        BagError: a bag is unreadable or lacks poses or clouds.
        DatasetError: ``out`` holds another dataset, or no flight gave a patch.
    """
    # the flights and the options, checked
    train, test, split_by = _flights(flights, test_flights, patches, seed, shard_size)
    args = {'seed': int(seed), 'patches': int(patches), 'region': region,
            'points_topic': points_topic, 'pose_topic': pose_topic, 'frame_id': frame_id,
            'shard_size': int(shard_size)}
    out = Path(out)
    t_start = time.perf_counter()
    # plan every flight (reading it): the plan decides the shards, so a rerun can check it
    jobs = [(b, 'tile' if split_by == 'tile' else 'train') for b in train] + \
        [(b, 'test') for b in test]
    plans, flights_meta, shards, counts, scene = _plan_flights(jobs, args, shard_size)
    meta = _hybrid_meta(flights_meta, shards, args, split_by, scene, counts)
    meta_path = out / 'meta.json'
    prepare_output(out, meta, _plan_key)
    # the shards not yet written, one flight read at a time
    done = generated = 0
    bar = progress_bar(scene, 0, progress, f'hybrid -> {out}')
    try:
        for plan in plans:
            mine = [s for s in shards if s['flight'] == plan['index']]
            todo = [s for s in mine if not shard_complete(
                out / s['file'], list(range(s['first_index'], s['first_index'] + s['scenes'])))]
            done += sum(s['scenes'] for s in mine) - sum(s['scenes'] for s in todo)
            bar.update(sum(s['scenes'] for s in mine) - sum(s['scenes'] for s in todo))
            if todo:
                generated += _write_flight_shards(plan, todo, out, args, bar)
    finally:
        bar.close()
    meta['complete'] = True
    write_json(meta_path, meta)
    seconds = time.perf_counter() - t_start
    nbytes = sum(f.stat().st_size for f in (out / 'shards').glob('*.npz'))
    return {'dataset': 'hybrid', 'out': str(out), 'scenes': scene, 'generated': generated,
            'skipped': done, 'shards': len(shards), 'seconds': seconds,
            'scenes_per_s': generated / seconds if seconds > 0 else 0.0, 'bytes': nbytes,
            'workers': 1, 'counts': counts, 'flights': flights_meta, 'split_by': split_by}


def _flights(flights: Sequence[str | os.PathLike[str]],
             test_flights: Sequence[str | os.PathLike[str]], patches: int, seed: int,
             shard_size: int) -> tuple[list[Path], list[Path], str]:
    """The train and test flights and how the split is made ('flight' or 'tile'), checked."""
    train = [Path(f) for f in flights]
    test = [Path(f) for f in test_flights]
    if not train and not test:
        raise ConfigError('give the flights to cut patches from (--from BAG)')
    if not isinstance(patches, (int, np.integer)) or patches < 1:
        raise ConfigError(f'--patches must be a positive integer, got {patches!r}')
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f'seed must be a non-negative integer, got {seed!r}')
    if not isinstance(shard_size, (int, np.integer)) or shard_size < 1:
        raise ConfigError(f'shard_size must be a positive integer, got {shard_size!r}')
    if test:
        split_by = 'flight'
    elif len(train) > 1:
        train, test = train[:-1], train[-1:]
        split_by = 'flight'
    else:
        split_by = 'tile'
    missing = [str(b) for b in train + test if not b.exists()]
    if missing:
        raise BagError(f'bag not found: {missing[0]}')
    return train, test, split_by


def _plan_flights(jobs: list[tuple[Path, str]], args: dict[str, Any], shard_size: int
                  ) -> tuple[list[dict[str, Any]], list[dict[str, Any]], list[dict[str, Any]],
                             dict[str, dict[str, int]], int]:
    """Every flight's plan, its meta.json entry, the shards, the counts by split and label,
    and the number of scenes."""
    flights_meta: list[dict[str, Any]] = []
    shards: list[dict[str, Any]] = []
    plans = []
    scene = 0
    counts = {s: {'safe': 0, 'unsafe': 0} for s in ('train', 'test')}
    for f, (bag, split) in enumerate(jobs):
        plan = _flight_plan(f, bag, split, args)
        n = len(plan['tiles'])
        flights_meta.append({'bag': bag.name, 'split': split if split != 'tile' else 'by tile',
                             'patches': n, 'candidates': plan['candidates'],
                             'returns': plan['returns'], 'labels': plan['labels']})
        for k in range(0, n, shard_size):
            sel = range(k, min(k + shard_size, n))
            shards.append({'file': shard_name(len(shards)), 'scenes': len(sel),
                           'first_index': scene + k, 'flight': f,
                           'test': ''.join('1' if plan['splits'][t] == 'test' else '0'
                                           for t in sel),
                           'labels': ''.join('0' if plan['unsafe'][t] else '1' for t in sel)})
        for t in range(n):
            counts[str(plan['splits'][t])]['unsafe' if plan['unsafe'][t] else 'safe'] += 1
        plan['first_scene'] = scene
        scene += n
        plans.append(plan)
    if scene == 0:
        raise DatasetError('no flight gave a patch: no clear, well-covered 1 m tile found '
                           f'(each needs {MIN_PATCH_RETURNS} returns and scanned neighbours)')
    return plans, flights_meta, shards, counts, scene


def _write_flight_shards(plan: dict[str, Any], todo: list[dict[str, Any]], out: Path,
                         args: dict[str, Any], bar: Any) -> int:
    """Write the shards ``todo`` of one flight (read again: plans keep no returns, so memory
    stays one flight's); returns the scenes written."""
    fr = read_flight(plan['bag'], args['points_topic'], args['pose_topic'], args['frame_id'])
    tree = cKDTree(fr.points[:, :2])
    rays = column_rays(fr.points, fr.cloud, fr.origins, plan['tiles'], plan['boxes'])
    generated = 0
    for s in todo:
        records = []
        for idx in range(s['first_index'], s['first_index'] + s['scenes']):
            t = idx - plan['first_scene']
            records.append(_patch_record(plan, fr, tree, t, rays[t], idx, args['seed']))
        write_npz(out / s['file'], shard_arrays(records))
        generated += len(records)
        bar.update(len(records))
    return generated
