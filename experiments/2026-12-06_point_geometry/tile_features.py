"""Probe: do per-point geometry features separate obstacles from vegetation where density cannot?

Simulates flights (one obstacle family each, cycling vegetation, scan pattern and height),
replays each through the shipped pipeline with the map fixed on the site, and writes per-tile
features: density summaries (what the map keeps), local point geometry (eigenvalue features
of 16-point neighbourhoods, in height bands), and the network's own P(safe).
"""
import argparse
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

FAMILIES = ('rock slab rubble log stump brush box crate bucket pipe tire cinder_block post cone '
            'coil pallet sack frame mesh hoop assembly').split()
VEGETATION = ('default clumped tall bushy mixed uniform tussock lodged layered bare shrub meadow '
              'forb canopy').split()
SCANS = ('line', 'spinning', 'rosette', 'elliptical')
BANDS = (-0.05, 0.05, 0.15, 0.30, 0.45, 0.60, 1.0)
GEO_BANDS = ((0.05, 0.20), (0.20, 0.45), (0.45, 1.5))


def plan(n_per_family):
    out = []
    k = 0
    for r in range(n_per_family):
        for fam in FAMILIES:
            out.append(dict(i=k, family=fam, vegetation=VEGETATION[(k * 5 + r) % len(VEGETATION)],
                            scan=SCANS[(k + r) % len(SCANS)], height=6.0 + (k * 7 % 9), seed=100 + k))
            k += 1
    return out


def simulate(p, d):
    bag = d / f"f{p['i']:03d}.mcap"
    subprocess.run([sys.executable, '-m', 'landing_zone', 'simulate-flight', '--out', str(bag),
                    '--families', p['family'], '--obstacles', '12', '--vegetation',
                    p['vegetation'], '--scan-pattern', p['scan'], '--height', str(p['height']),
                    '--seed', str(p['seed']), '--overwrite'], check=True, capture_output=True)
    return bag


def points_of(bag):
    from landing_zone.io.bags import read_messages
    from msg_adapters.pointcloud import cloud_to_xyz
    xyz = [cloud_to_xyz(m.msg)[0] for m in read_messages(bag, ['/lidar/points'])]
    return np.concatenate(xyz).astype(np.float64)


def eig_features(pts, tree, k=16):
    _, idx = tree.query(pts, k=k)
    nb = tree.data[idx]                                   # (N, k, 3)
    c = nb - nb.mean(axis=1, keepdims=True)
    cov = np.einsum('nki,nkj->nij', c, c) / k
    w, v = np.linalg.eigh(cov)                            # ascending
    l3, l2, l1 = (np.maximum(w[:, i], 1e-12) for i in range(3))
    lin, pla, sca = (l1 - l2) / l1, (l2 - l3) / l1, l3 / l1
    nz = np.abs(v[:, 2, 0])                               # normal's z
    dz = np.abs(v[:, 2, 2])                               # principal direction's z
    spread = np.sqrt(l1)
    return np.stack([lin, pla, sca, nz, dz, spread], axis=1)


def tile_rows(bag, labels, rng):
    from landing_zone.replay import replay
    res = replay(bag, center=(0.0, 0.0), progress=False)
    a = res.assessment
    pts = points_of(bag)
    ts = a.tile_size
    key = np.floor(pts[:, :2] / ts).astype(np.int64)
    safe = {(round(t['x'] - ts / 2), round(t['y'] - ts / 2)): t['safe'] for t in labels['tiles']}
    rows = []
    # height above each tile's ground plane
    tile_of = {tuple(ix): k for k, ix in enumerate(a.index.tolist())}
    order = np.lexsort((key[:, 1], key[:, 0]))
    key, pts = key[order], pts[order]
    bounds = np.flatnonzero(np.any(np.diff(key, axis=0) != 0, axis=1)) + 1
    starts = np.r_[0, bounds]
    ends = np.r_[bounds, len(key)]
    per_tile = {}
    for s, e in zip(starts, ends):
        ix = tuple(key[s])
        k = tile_of.get(ix)
        if k is None or ix not in safe or not np.isfinite(a.ground_z[k]):
            continue
        p = pts[s:e]
        g = a.ground_z[k] + (p[:, 0] - a.centers[k, 0]) * a.grad[k, 0] + \
            (p[:, 1] - a.centers[k, 1]) * a.grad[k, 1]
        h = p[:, 2] - g
        per_tile[k] = (ix, p, h)
    tree = cKDTree(pts[::2])
    for k, (ix, p, h) in per_tile.items():
        dens = [len(h), float(np.max(h)), float(np.percentile(h, 99)), float(np.percentile(h, 95))]
        dens += [float(np.mean((h >= lo) & (h < hi))) for lo, hi in zip(BANDS[:-1], BANDS[1:])]
        dens += [float(np.mean(h >= BANDS[-1]))]
        dens += [float(a.observed_fraction[k]), float(a.guard_hits[k]) if a.guard_hits is not None else 0.0,
                 float(np.nan_to_num(a.guard_height[k])) if a.guard_height is not None else 0.0,
                 float(np.nan_to_num(a.roughness[k]))]
        geo = []
        for lo, hi in GEO_BANDS:
            sel = np.flatnonzero((h >= lo) & (h < hi))
            if len(sel) > 400:
                sel = rng.choice(sel, 400, replace=False)
            if len(sel) >= 8:
                f = eig_features(p[sel], tree)
                geo += list(f.mean(axis=0)) + [float(np.mean(f[:, 1] > 0.5)), float(np.mean(f[:, 0] > 0.7)),
                                               float(np.mean((f[:, 1] > 0.5) & (f[:, 3] > 0.8)))]
                geo += [float(np.percentile(f[:, 1], 90))]
            else:
                geo += [np.nan] * 10
        pnet = float(a.p_net[k]) if a.p_net is not None else np.nan
        rows.append(dict(ix=[int(ix[0]), int(ix[1])], safe=bool(safe[ix]), p_safe=float(a.p_safe[k]), p_net=pnet,
                         density=dens, geometry=geo))
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('out', type=Path)
    ap.add_argument('--per-family', type=int, default=2)
    ap.add_argument('--only', type=int, nargs='*')
    args = ap.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    for p in plan(args.per_family):
        if args.only and p['i'] not in args.only:
            continue
        dest = args.out / f"f{p['i']:03d}.json"
        if dest.exists():
            continue
        bag = simulate(p, args.out)
        labels = json.loads((args.out / f"f{p['i']:03d}.labels.json").read_text())
        rows = tile_rows(bag, labels, np.random.default_rng(p['seed']))
        dest.write_text(json.dumps(dict(plan=p, rows=rows)))
        bag.unlink()
        print(p['i'], p['family'], p['vegetation'], p['scan'], len(rows),
              sum(not r['safe'] for r in rows), flush=True)


if __name__ == '__main__':
    main()
