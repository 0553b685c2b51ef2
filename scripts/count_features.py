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

    python scripts/count_features.py data/synth3_test --families coil [--split test]
    python scripts/count_features.py data/synth3_test --families all --scores S.json [--method M]
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
from sklearn.metrics import roc_auc_score

from landing_zone.config import MapConfig, TileConfig
from landing_zone.judging.patches import (PatchVoxelizer, patch_columns, patch_counts,
                                          patch_ground)
from landing_zone.sim.shards import SceneDataset

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


def auc(y: np.ndarray, x: np.ndarray) -> str:
    return f'{roc_auc_score(y, x):.3f}' if len(set(y.tolist())) == 2 else '  -  '


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('data')
    ap.add_argument('--families', required=True,
                    help="obstacle families, comma separated, or 'all'")
    ap.add_argument('--split', default='test')
    ap.add_argument('--scores', help='landing-zone evaluate --scores of the same split')
    ap.add_argument('--method', help='the scores of this method (default: the first)')
    args = ap.parse_args()
    families = None if args.families == 'all' else set(args.families.split(','))
    ds = SceneDataset(args.data, args.split)
    mcfg, tcfg, vox = MapConfig(), TileConfig(), PatchVoxelizer()
    index, labels, vegetation, rows = [], [], [], []
    for i in range(len(ds)):
        params = ds.params(i)
        if families is not None and params.get('family') not in families:
            continue
        scene = ds[i]
        counts = patch_counts(scene.points, scene.origins, mcfg, tcfg, voxelizer=vox)
        g = patch_ground(counts, mcfg, tcfg)
        plane_z = float(g.plane_z[0])
        if not np.isfinite(plane_z):
            continue  # no ground fitted: the assessor calls such a tile unknown
        rows.append(features(*patch_columns(counts, mcfg, tcfg, plane_z, g.grad[0])))
        labels.append(1 - int(scene.label))  # 1: an obstacle in the tile
        veg = params.get('vegetation')
        vegetation.append(veg.get('family', '?') if isinstance(veg, dict) else str(veg))
        index.append(i)
    if not rows or len(set(labels)) < 2:
        raise SystemExit(f'count_features: no obstacle scenes and safe twins of '
                         f'{args.families} in {args.data} ({args.split})')
    y, veg_of = np.asarray(labels), np.asarray(vegetation)
    names = sorted(set(vegetation))
    print(f'{args.families}: {len(y)} scenes, {int(y.sum())} with an obstacle; AUC of each '
          f'feature ({BAND[0] * 100:.0f}-{BAND[1] * 100:.0f} cm above the plane), all and '
          f'per vegetation family ({", ".join(names)})')
    for name in rows[0]:
        x = np.asarray([r[name] for r in rows])
        per = ' '.join(auc(y[veg_of == v], x[veg_of == v]) for v in names)
        print(f'  {name:46s} {auc(y, x)}   {per}')
    if args.scores:
        doc = json.loads(Path(args.scores).read_text(encoding='utf-8'))
        method = args.method or next(iter(doc['methods']))
        score = dict(zip(doc['scenes'], doc['methods'][method]))
        p = np.asarray([score[i] for i in index], np.float64)
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
