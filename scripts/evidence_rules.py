"""Could a simple rule on the evidence above the ground catch what the network passes?
(measured, not shipped)

For every scene of a synth3 dataset: the counts its cube is cut from
(:func:`~landing_zone.judging.patches.patch_counts`), the tile's ground plane
(:func:`~landing_zone.judging.patches.patch_ground`) and, inside the tile, the voxels hit at
10-30 cm above the plane (all of them, and those of density >= 0.4), the height of the highest
hit and the median and 90th percentile of the hit heights (the cover). Then, against the scores
of a run on the same data (``landing-zone evaluate --scores`` or ``scripts/ood_families.py
--scores``): for each rule "feature >= threshold", and for "the cover's 90th percentile below c
and a hit at least t above the plane" (a lone structure over short cover), how many of the
obstacle tiles passed at P(safe) >= 0.9 (and 0.5) it would catch, and what share of the safe
tiles the network passes it would flag. Rules flagging more than ``--max-flag`` are not printed::

    python scripts/evidence_rules.py data/assembly_test S.json --split test \\
        --method 'net + guard' [--features F.json]

``--features`` keeps the per-scene features (and reuses them on a rerun).
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

HEIGHTS = (0.10, 0.15, 0.20, 0.30)  # [m] above the ground plane
DENSE = 0.4  # density of a "dense" voxel


def scene_features(data: str, split: str) -> list[dict]:
    """The evidence features of every scene, in the dataset's order."""
    from landing_zone.config import MapConfig, TileConfig
    from landing_zone.judging.patches import (PatchVoxelizer, centre_columns, cut_patch,
                                              patch_counts, patch_ground)
    from landing_zone.tools.learn.scenes import ScenePack
    from landing_zone.tools.sim.shards import SceneDataset

    pack = ScenePack.from_scenes(SceneDataset(data, split))
    mcfg, tcfg = MapConfig(), TileConfig()
    vs = float(mcfg.voxel_size)
    voxelizer = PatchVoxelizer()
    rows = []
    for i in range(len(pack)):
        pts, org = pack.scene(i)
        counts = patch_counts(pts, org, mcfg, tcfg, voxelizer=voxelizer)
        ground = patch_ground(counts, mcfg, tcfg)
        batch = cut_patch(counts, mcfg, tcfg, ground)
        plane_z = float(ground.plane_z[0])
        grad = ground.grad[0] if np.isfinite(plane_z) else np.zeros(2)
        gz = plane_z if np.isfinite(plane_z) else float(batch.ground_z[0])
        h, p, above = centre_columns(counts, mcfg, tcfg, gz, grad)  # (tv, tv, Z) each
        hh, pp = h.astype(np.float64), p.astype(np.float64)
        hit = hh > 0
        dense = hit & ((hh + 1) / (hh + pp + 2) >= DENSE)
        row = {'label': int(pack.labels[i]), 'valid': bool(batch.valid[0])}
        for t in HEIGHTS:
            row[f'hit{round(t * 100)}'] = int((hit & (above >= t)).sum())
            row[f'dense{round(t * 100)}'] = int((dense & (above >= t)).sum())
        cover = above[hit & (above > -2 * vs)]
        row['top'] = float(cover.max()) if cover.size else 0.0
        row['p50'] = float(np.percentile(cover, 50)) if cover.size else 0.0
        row['p90'] = float(np.percentile(cover, 90)) if cover.size else 0.0
        rows.append(row)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('data')
    ap.add_argument('scores', type=Path)
    ap.add_argument('--split', default='test')
    ap.add_argument('--method', default=None, help='the scores of this method (default: last)')
    ap.add_argument('--features', type=Path, default=None)
    ap.add_argument('--max-flag', type=float, default=0.05,
                    help='print the rules flagging at most this share of the passed safe tiles')
    args = ap.parse_args()
    if args.features is not None and args.features.exists():
        rows = json.loads(args.features.read_text())
    else:
        rows = scene_features(args.data, args.split)
        if args.features is not None:
            args.features.write_text(json.dumps(rows))
    doc = json.loads(args.scores.read_text())
    method = args.method or list(doc['methods'])[-1]
    p = np.asarray(doc['methods'][method], np.float64)
    label = np.array([r['label'] for r in rows])
    if not np.array_equal(label, np.asarray(doc['labels'])):
        raise SystemExit('the scores are not of this dataset (labels differ)')
    feats = {k: np.array([r[k] for r in rows], np.float64) for k in rows[0]
             if k not in ('label', 'valid')}
    obstacle = label == 0
    passed9, passed5 = obstacle & (p >= 0.9), obstacle & (p >= 0.5)
    safe_passed = (label == 1) & (p >= 0.5)
    print(f'{method}: {obstacle.sum()} obstacle tiles, {passed5.sum()} at P(safe) >= 0.5, '
          f'{passed9.sum()} at >= 0.9; {safe_passed.sum()} safe tiles at >= 0.5')
    rules = []
    for k, v in feats.items():
        for q in ((0.15, 0.2, 0.25, 0.3) if k in ('top', 'p50', 'p90') else (1, 2, 3, 5, 8)):
            rules.append((f'{k} >= {q}', v >= q))
    for c in (0.08, 0.10, 0.12):
        for t in (0.20, 0.25, 0.30):
            rules.append((f'cover p90 < {c} and top >= {t}',
                          (feats['p90'] < c) & (feats['top'] >= t)))
    print('| rule | passed at 0.9 caught | passed at 0.5 caught | safe passed tiles flagged |')
    print('|---|---:|---:|---:|')
    for name, fire in rules:
        flag = (fire & safe_passed).sum() / max(1, safe_passed.sum())
        if flag <= args.max_flag:
            print(f'| {name} | {(fire & passed9).sum()} of {passed9.sum()} | '
                  f'{(fire & passed5).sum()} of {passed5.sum()} | {100 * flag:.1f} % |')


if __name__ == '__main__':
    main()
