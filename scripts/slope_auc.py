"""Sloped ground judged as flat ground is: per-tile AUC on a site tilted vs the same site flat.

For each seed, the default flight site (20 x 20 m, patchy grass, six obstacles of the library)
is simulated twice with the same seed, so the same grass patches and obstacles: once flat and
once on a plane tilted ``--slope`` degrees (rising towards ``--azimuth``). Both are replayed with
the same pipeline (the map fixed on the site, 8 m tall so the tilted site's 3.5 m of relief
fits in it) and scored against their labels: AUC of P(safe) over the judged tiles, false alarms
(safe tiles below 0.5) and obstacle tiles judged safe; for the guarded output and the network
alone. Then the pooled figures and the difference tilted - flat.

    python scripts/slope_auc.py [--seeds 0 1 2] [--slope 10] [--model M] [--align]
                                [--json OUT.json]

Deterministic for a seed and a machine (the simulator and the pipeline are seeded); about 25 s
per seed and slope on two cores.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
from dataclasses import replace
from pathlib import Path

import numpy as np


def score(assessment, labels, p):
    from landing_zone.io.labels import score_tiles

    s = score_tiles(assessment.centers, p, assessment.tile_size, labels)
    return {'auc': s.auc, 'judged': s.judged, 'unknown': s.unknown,
            'false_alarms': s.false_alarms, 'safe': s.safe,
            'unsafe_judged_safe': s.unsafe_judged_safe, 'unsafe': s.unsafe}


def pooled(rows, key):
    from sklearn.metrics import roc_auc_score

    y = np.concatenate([r['_y'] for r in rows])
    p = np.concatenate([r[key] for r in rows])
    ok = np.isfinite(p)
    return float(roc_auc_score(y[ok], p[ok])) if len(set(y[ok].tolist())) == 2 else None


def run_one(seed, slope, azimuth, model, work, align=False):
    from landing_zone.config import AssessorConfig, MapConfig
    from landing_zone.replay import replay
    from landing_zone.io.labels import read_labels, tile_truth
    from landing_zone.tools.sim.flight import FlightConfig, simulate_flight

    cfg = FlightConfig(seed=seed, slope=slope, slope_azimuth=azimuth)
    bag = Path(work) / f'site_{seed}_{slope:g}.mcap'
    flight = simulate_flight(cfg, bag, overwrite=True)
    labels = read_labels(flight.labels)
    acfg = AssessorConfig()
    acfg.map = replace(acfg.map, size_z=8.0, z_below=4.0) if isinstance(acfg.map, MapConfig) \
        else acfg.map
    acfg.tiles = replace(acfg.tiles, align_to_ground=align)
    res = replay(flight.bag, center=(0.0, 0.0), model=model, config=acfg, progress=False)
    a = res.assessment
    truth = tile_truth(a.centers, a.tile_size, labels)
    have = truth >= 0
    out = {'seed': seed, 'slope': slope,
           'guarded': score(a, labels, a.p_safe), 'network': score(a, labels, a.p_net),
           'slope_deg_median': float(np.nanmedian(a.slope_deg[have & (truth == 1)])),
           '_y': truth[have], 'p': a.p_safe[have].astype(float),
           'p_net': a.p_net[have].astype(float)}
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--seeds', type=int, nargs='+', default=[0, 1, 2])
    ap.add_argument('--slope', type=float, default=10.0, help='tilt of the sloped site [deg]')
    ap.add_argument('--azimuth', type=float, default=30.0, help='direction of ascent [deg]')
    ap.add_argument('--model', default=None, help='model file; default the shipped one')
    ap.add_argument('--json', default=None, help='write the figures here')
    ap.add_argument('--align', action='store_true',
                    help='cut the cubes aligned to the ground plane (tiles.align_to_ground)')
    args = ap.parse_args()
    rows = {0.0: [], args.slope: []}
    with tempfile.TemporaryDirectory() as work:
        for seed in args.seeds:
            for slope in rows:
                r = run_one(seed, slope, math.radians(args.azimuth), args.model, work,
                            args.align)
                rows[slope].append(r)
                g, n = r['guarded'], r['network']
                print(f'seed {seed} slope {slope:4.1f}: AUC {g["auc"]:.3f} (net alone '
                      f'{n["auc"]:.3f}); false alarms {g["false_alarms"]} of {g["safe"]}; '
                      f'obstacle tiles judged safe {g["unsafe_judged_safe"]} of {g["unsafe"]}; '
                      f'unknown {g["unknown"]}; median slope of the safe tiles '
                      f'{r["slope_deg_median"]:.1f} deg', flush=True)
    summary = {}
    for slope, rs in rows.items():
        summary[f'{slope:g}'] = {
            'auc': pooled(rs, 'p'), 'auc_network': pooled(rs, 'p_net'),
            'false_alarms': sum(r['guarded']['false_alarms'] for r in rs),
            'safe': sum(r['guarded']['safe'] for r in rs),
            'unsafe_judged_safe': sum(r['guarded']['unsafe_judged_safe'] for r in rs),
            'unsafe': sum(r['guarded']['unsafe'] for r in rs)}
    flat, tilted = summary['0'], summary[f'{args.slope:g}']
    for name, s in (('flat', flat), (f'tilted {args.slope:g} deg', tilted)):
        print(f'pooled {name}: AUC {s["auc"]:.3f} (net alone {s["auc_network"]:.3f}); false '
              f'alarms {s["false_alarms"]} of {s["safe"]}; obstacle tiles judged safe '
              f'{s["unsafe_judged_safe"]} of {s["unsafe"]}')
    d = tilted['auc'] - flat['auc']
    print(f'AUC tilted - flat: {d:+.3f} (goal: within 0.02)')
    if args.json:
        doc = {'seeds': args.seeds, 'slope': args.slope, 'azimuth_deg': args.azimuth,
               'align_to_ground': args.align,
               'model': args.model, 'pooled': summary,
               'runs': [{k: v for k, v in r.items() if not k.startswith('_') and k not in
                         ('p', 'p_net')} for rs in rows.values() for r in rs]}
        Path(args.json).write_text(json.dumps(doc, indent=1) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
