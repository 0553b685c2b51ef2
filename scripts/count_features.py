"""Do the returns' counts alone tell an obstacle family from grass? A probe, not a detector.

For the scenes of the given obstacle families in a synth3 split (each family's obstacle scenes
and their safe twins, the same worlds without the obstacle; ``all``: every scene): the counts
the assessor cuts the tile from (:func:`~landing_zone.judging.patches.patch_counts`, the 3 x 3
tiles around it), the tile's ground plane as it fits it, and a few features of the centre
tile's voxels 15-65 cm above that plane (voxels with hits, the most hits in one voxel, dense
voxels, the highest hit), and one against its surroundings: how far the tile's highest hit
stands above the canopy of the eight tiles around it (the 99th percentile of their columns'
highest hits over the same plane). Printed: each feature's AUC for "obstacle" against the safe
scenes, overall and per vegetation family. A family the network ranks well (bucket) shows which
features carry it; a see-through one (coil) shows whether a hit-count input could help. With
``--scores`` (``landing-zone evaluate --scores`` of the same split) it also prints what a cap
where the tile stands more than TAU above its surroundings would flag among safe tiles and
catch among the obstacle tiles that method passes (docs/EXPERIMENTS.md, "Looped wire in
training").

With ``--flights`` the tiles are those of ``scripts/guard_eval.py --keep-maps`` flights instead
(every labelled tile of every kept map in the folder, the counts cut from the flight's final
map, the ground plane fitted as the assessor fits it; ``--families`` is then ignored), and the
cap is scored on the P(safe) the product gave them (network, guard and OOD signal): whether
what the synth3 split showed holds on flights (docs/EXPERIMENTS.md, "The canopy cap on fresh
flights").

    python scripts/count_features.py data/synth3_test --families coil [--split test]
    python scripts/count_features.py data/synth3_test --families all --scores S.json [--method M]
    python scripts/count_features.py runs/ge --flights
"""
from __future__ import annotations

import argparse
import json
import math
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
from sklearn.metrics import roc_auc_score

from landing_zone.config import MapConfig, TileConfig
from landing_zone.judging.ground import fit_ground
from landing_zone.judging.patches import (PatchVoxelizer, patch_columns, patch_counts,
                                          patch_ground)
from landing_zone.judging.tiles import tile_voxels
from landing_zone.tools.sim.shards import SceneDataset

BAND = (0.15, 0.65)  # [m] above the fitted plane: where an obstacle stands out of short grass
TAUS = (0.05, 0.1, 0.15, 0.2, 0.3)  # [m] above the surroundings' canopy, for --scores


def features(h: np.ndarray, p: np.ndarray, above: np.ndarray, centre: np.ndarray
             ) -> dict[str, float]:
    """Count features of a patch's columns (hits, passes, height above the centre tile's plane,
    each (X, Y, Z)) for its ``centre`` tile ((X, Y) mask)."""
    h, p = h.astype(np.float64), p.astype(np.float64)
    hc, pc, ac = h[centre], p[centre], above[centre]  # (columns, Z)
    band = (ac >= BAND[0]) & (ac <= BAND[1])
    density = (hc + 1.0) / (hc + pc + 2.0)
    top = np.where(h >= 1, above, -np.inf).max(axis=-1)  # each column's highest hit
    around = top[~centre][np.isfinite(top[~centre])]
    canopy = float(np.percentile(around, 99)) if len(around) else 0.0
    highest = float(max(top[centre].max(), -1.0))
    return {
        'voxels with a hit': float(np.sum(band & (hc >= 1))),
        'voxels with 3 or more hits': float(np.sum(band & (hc >= 3))),
        'most hits in one voxel': float((hc * band).max()),
        'hits': float((hc * band).sum()),
        'dense voxels (density > 0.5, 2 or more hits)': float(np.sum(band & (density > 0.5)
                                                                     & (hc >= 2))),
        'highest hit above the plane': highest,
        'highest hit above the canopy around': highest - canopy,
    }


Tile = tuple[tuple[np.ndarray, ...], float, np.ndarray, int, str, Any]


def split_tiles(data: str, split: str, families: set[str] | None, mcfg: MapConfig,
                tcfg: TileConfig) -> Iterator[Tile]:
    """The scenes of a synth3 split: (patch counts, plane height, gradient, 1 if an obstacle
    is in the tile, vegetation family, scene index)."""
    ds = SceneDataset(data, split)
    vox = PatchVoxelizer()
    for i in range(len(ds)):
        params = ds.params(i)
        if families is not None and params.get('family') not in families:
            continue
        scene = ds[i]
        counts = patch_counts(scene.points, scene.origins, mcfg, tcfg, voxelizer=vox)
        g = patch_ground(counts, mcfg, tcfg)
        veg = params.get('vegetation')
        yield (counts, float(g.plane_z[0]), g.grad[0], 1 - int(scene.label),
               veg.get('family', '?') if isinstance(veg, dict) else str(veg), i)


def flight_tiles(workdir: Path, mcfg: MapConfig, tcfg: TileConfig) -> Iterator[Tile]:
    """The labelled tiles of guard_eval's kept flights: the 3 x 3 tiles' counts around each,
    cut from the final map and shifted so that the tile is global tile (0, 0), as
    :func:`patch_columns` takes them; the last item is the P(safe) the product gave it."""
    tv = tile_voxels(float(mcfg.voxel_size), tcfg)
    for path in sorted(workdir.glob('*.npz')):
        doc = json.loads(path.with_suffix('.json').read_text(encoding='utf-8'))
        with np.load(path) as z:
            hits, passes, lo = z['hits'], z['passes'], z['lo']
            vs, index = float(z['voxel_size']), z['index']
        if not math.isclose(vs, mcfg.voxel_size):
            raise SystemExit(f'count_features: {path} has {vs} m voxels, not '
                             f'{mcfg.voxel_size}')
        ground = fit_ground(hits, passes, lo, vs, index, tv, tcfg.occupied_density)
        row = {(int(i), int(j)): k for k, (i, j) in enumerate(index)}
        for t in doc['tiles']:
            i, j = math.floor(t['x'] / doc['tile_size']), math.floor(t['y'] / doc['tile_size'])
            x0, y0 = i * tv - tv - lo[0], j * tv - tv - lo[1]
            if x0 < 0 or y0 < 0 or x0 + 3 * tv > hits.shape[0] or y0 + 3 * tv > hits.shape[1]:
                continue
            box = (slice(x0, x0 + 3 * tv), slice(y0, y0 + 3 * tv))
            counts = (hits[box], passes[box], np.array([-tv, -tv, lo[2]]))
            k = row[(i, j)]
            yield (counts, float(ground.plane_z[k]), ground.grad[k], int(not t['safe']),
                   doc['condition'], t['p_safe'])


def auc(y: np.ndarray, x: np.ndarray) -> str:
    return f'{roc_auc_score(y, x):.3f}' if len(set(y.tolist())) == 2 else '  -  '


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('data')
    ap.add_argument('--families', default='all',
                    help="obstacle families, comma separated, or 'all' (the default)")
    ap.add_argument('--flights', action='store_true',
                    help='DATA is a guard_eval.py --keep-maps folder: its flights\' tiles')
    ap.add_argument('--split', default='test')
    ap.add_argument('--scores', help='landing-zone evaluate --scores of the same split')
    ap.add_argument('--method', help='the scores of this method (default: the first)')
    args = ap.parse_args()
    families = None if args.families == 'all' else set(args.families.split(','))
    mcfg, tcfg = MapConfig(), TileConfig()
    tiles = flight_tiles(Path(args.data), mcfg, tcfg) if args.flights else \
        split_tiles(args.data, args.split, families, mcfg, tcfg)
    keys, labels, vegetation, rows = [], [], [], []  # keys: scene index, or a flight's P(safe)
    for counts, plane_z, grad, label, veg, key in tiles:
        if not np.isfinite(plane_z):
            continue  # no ground fitted: the assessor calls such a tile unknown
        rows.append(features(*patch_columns(counts, mcfg, tcfg, plane_z, grad)))
        labels.append(label)
        vegetation.append(veg)
        keys.append(key)
    what = 'flight tiles' if args.flights else args.families
    if not rows or len(set(labels)) < 2:
        raise SystemExit(f'count_features: no obstacle tiles and safe tiles of {what} in '
                         f'{args.data}')
    y, veg_of = np.asarray(labels), np.asarray(vegetation)
    names = sorted(set(vegetation))
    group = 'condition' if args.flights else 'vegetation family'
    print(f'{what}: {len(y)} tiles, {int(y.sum())} with an obstacle; AUC of each feature '
          f'({BAND[0] * 100:.0f}-{BAND[1] * 100:.0f} cm above the plane), all and per {group} '
          f'({", ".join(names)})')
    for name in rows[0]:
        x = np.asarray([r[name] for r in rows])
        per = ' '.join(auc(y[veg_of == v], x[veg_of == v]) for v in names)
        print(f'  {name:46s} {auc(y, x)}   {per}')
    if args.scores or args.flights:
        if args.flights:  # unknown tiles (None) are never passed
            method = 'the product (network, guard, OOD)'
            p = np.asarray([-1.0 if v is None else v for v in keys], np.float64)
        else:
            doc = json.loads(Path(args.scores).read_text(encoding='utf-8'))
            method = args.method or next(iter(doc['methods']))
            score = dict(zip(doc['scenes'], doc['methods'][method]))
            p = np.asarray([score[i] for i in keys], np.float64)
        lift = np.asarray([r['highest hit above the canopy around'] for r in rows])
        print(f'a cap where the tile stands more than TAU above the canopy around, on {method}:')
        for tau in TAUS:
            cap = lift > tau
            out = [f'  TAU {tau:.2f} m: safe tiles flagged {np.mean(cap[y == 0]) * 100:.1f} %']
            for thr in (0.5, 0.9):
                passed = (y == 1) & (p >= thr)
                out.append(f'obstacle tiles passed at {thr} caught {int(np.sum(cap & passed))} '
                           f'of {int(passed.sum())}')
            print('; '.join(out))


if __name__ == '__main__':
    main()
