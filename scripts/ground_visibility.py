"""Can the returns tell where an obstacle could hide? The share of a tile's columns no ray
reached low in, against what the network passed.

For every scene of a synth3 split: the counts its cube is cut from
(:func:`~landing_zone.judging.patches.patch_counts`), the tile's ground plane as the assessor
fits it (:func:`~landing_zone.judging.ground.fit_ground`), and per 5 cm column of the tile the
lowest voxel any ray reached (a hit or a pass) above that plane. A column no ray reached below
``h`` could hide an obstacle ``h`` high. Printed per group (safe / obstacle tiles, and those the
scores pass at P(safe) >= 0.9 or 0.5): quantiles of the hidden share of the tile, and what a cap
on P(safe) where that share is large would keep and remove. Measured on synth3's test split: the
obstacle tiles passed at 0.9 show *less* hidden ground than safe tiles (models/MODEL_CARD.md,
"What still passes, and three levers measured").

    python scripts/ground_visibility.py DATA SCORES.json [--split test] [--method NAME]
"""
from __future__ import annotations

import argparse
import json

import numpy as np

from landing_zone.config import MapConfig, TileConfig
from landing_zone.judging.patches import (PatchVoxelizer, centre_columns, patch_counts,
                                          patch_ground)
from landing_zone.judging.tiles import tile_voxels
from landing_zone.tools.sim.shards import SceneDataset

HEIGHTS = (0.05, 0.08, 0.12)  # [m] a column no ray reached below this could hide that much
CAPS = (0.02, 0.05, 0.1, 0.2)  # hidden shares of the tile to cap at


def lowest_reached(points: np.ndarray, origins: np.ndarray, map_cfg: MapConfig,
                   tile_cfg: TileConfig, voxelizer: PatchVoxelizer) -> np.ndarray:
    """(tv, tv) height above the tile's fitted ground plane of the lowest voxel any ray reached
    in each column of the centre tile [m]; inf where none was reached or no plane was fitted."""
    counts = patch_counts(points, origins, map_cfg, tile_cfg, voxelizer=voxelizer)
    g = patch_ground(counts, map_cfg, tile_cfg)
    plane_z = float(g.plane_z[0])
    if not np.isfinite(plane_z):
        tv = tile_voxels(float(map_cfg.voxel_size), tile_cfg)
        return np.full((tv, tv), np.inf)
    h, p, above = centre_columns(counts, map_cfg, tile_cfg, plane_z, g.grad[0])
    seen = (h.astype(np.int64) + p) > 0
    return np.where(seen, above, np.inf).min(axis=-1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('data')
    ap.add_argument('scores', help='landing-zone evaluate --scores of the same split')
    ap.add_argument('--split', default='test')
    ap.add_argument('--method', default=None, help='the scores of this method (default: first)')
    args = ap.parse_args()
    doc = json.loads(open(args.scores).read())
    p = np.asarray(doc['methods'][args.method or next(iter(doc['methods']))], np.float64)
    y = np.asarray(doc['labels'])
    ds = SceneDataset(args.data, args.split)
    mcfg, tcfg = MapConfig(), TileConfig()
    vox = PatchVoxelizer()
    reach = np.stack([lowest_reached(ds[int(i)].points, ds[int(i)].origins, mcfg, tcfg, vox)
                      for i in doc['scenes']])
    groups = {'safe': y == 1, 'obstacle': y == 0, 'obstacle at >= 0.9': (y == 0) & (p >= 0.9),
              'safe at >= 0.9': (y == 1) & (p >= 0.9), 'obstacle at >= 0.5': (y == 0) & (p >= 0.5)}
    for h in HEIGHTS:
        hidden = (reach >= h).mean(axis=(1, 2))
        print(f'no ray below {h * 100:.0f} cm above the plane: share of the tile\'s columns')
        for name, m in groups.items():
            q = np.quantile(hidden[m], [0.1, 0.5, 0.9]) if m.any() else [np.nan] * 3
            print(f'  {name:20s} {int(m.sum()):5d} tiles; 10 / 50 / 90 %: '
                  f'{q[0]:.3f} / {q[1]:.3f} / {q[2]:.3f}')
        for cap in CAPS:
            capped = hidden >= cap
            print(f'  capped where >= {cap}: obstacle tiles left at 0.9 '
                  f'{int(np.sum(groups["obstacle at >= 0.9"] & ~capped))} of '
                  f'{int(groups["obstacle at >= 0.9"].sum())}, safe tiles left at 0.9 '
                  f'{int(np.sum(groups["safe at >= 0.9"] & ~capped))} of '
                  f'{int(groups["safe at >= 0.9"].sum())}')


if __name__ == '__main__':
    main()
