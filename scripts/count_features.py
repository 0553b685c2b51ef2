"""Do the returns' counts alone tell an obstacle family from grass? A probe, not a detector.

For the scenes of the given obstacle families in a synth3 split (each family's obstacle scenes
and their safe twins, the same worlds without the obstacle): the counts the assessor cuts the
tile from (:func:`~landing_zone.judging.patches.patch_counts`), the tile's ground plane as it
fits it, and a few features of the centre tile's voxels 15-65 cm above that plane (voxels with
hits, the most hits in one voxel, dense voxels, the highest hit). Printed: each feature's AUC
for "obstacle" against the safe twins. A family the network ranks well (bucket) shows which
features carry it; a see-through one (coil) shows whether a hit-count input could help
(docs/EXPERIMENTS.md, "Looped wire in training").

    python scripts/count_features.py data/synth3_test --families coil [--split test]
"""
from __future__ import annotations

import argparse

import numpy as np
from sklearn.metrics import roc_auc_score

from landing_zone.config import MapConfig, TileConfig
from landing_zone.judging.patches import (PatchVoxelizer, centre_columns, patch_counts,
                                          patch_ground)
from landing_zone.sim.shards import SceneDataset

BAND = (0.15, 0.65)  # [m] above the fitted plane: where an obstacle stands out of short grass


def features(h: np.ndarray, p: np.ndarray, above: np.ndarray) -> dict[str, float]:
    """Count features of one tile's columns (hits, passes, height above the plane)."""
    h, p = h.astype(np.float64), p.astype(np.float64)
    band = (above >= BAND[0]) & (above <= BAND[1])
    density = (h + 1.0) / (h + p + 2.0)
    return {
        'voxels with a hit': float(np.sum(band & (h >= 1))),
        'voxels with 3 or more hits': float(np.sum(band & (h >= 3))),
        'most hits in one voxel': float((h * band).max()),
        'hits': float((h * band).sum()),
        'dense voxels (density > 0.5, 2 or more hits)': float(np.sum(band & (density > 0.5)
                                                                     & (h >= 2))),
        'highest hit above the plane': float(np.where(h >= 1, above, -1.0).max()),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('data')
    ap.add_argument('--families', required=True, help='obstacle families, comma separated')
    ap.add_argument('--split', default='test')
    args = ap.parse_args()
    families = set(args.families.split(','))
    ds = SceneDataset(args.data, args.split)
    mcfg, tcfg, vox = MapConfig(), TileConfig(), PatchVoxelizer()
    labels, rows = [], []
    for i in range(len(ds)):
        if ds.params(i).get('family') not in families:
            continue
        scene = ds[i]
        counts = patch_counts(scene.points, scene.origins, mcfg, tcfg, voxelizer=vox)
        g = patch_ground(counts, mcfg, tcfg)
        plane_z = float(g.plane_z[0])
        if not np.isfinite(plane_z):
            continue  # no ground fitted: the assessor calls such a tile unknown
        rows.append(features(*centre_columns(counts, mcfg, tcfg, plane_z, g.grad[0])))
        labels.append(1 - int(scene.label))  # 1: an obstacle in the tile
    if not rows or len(set(labels)) < 2:
        raise SystemExit(f'count_features: no obstacle scenes and safe twins of '
                         f'{args.families} in {args.data} ({args.split})')
    y = np.asarray(labels)
    print(f'{args.families}: {len(y)} scenes, {int(y.sum())} with an obstacle; AUC of each '
          f'feature ({BAND[0] * 100:.0f}-{BAND[1] * 100:.0f} cm above the plane)')
    for name in rows[0]:
        x = np.asarray([r[name] for r in rows])
        print(f'  {name:48s} {roc_auc_score(y, x):.3f}')


if __name__ == '__main__':
    main()
