"""What P(safe) means on fresh flights: its reliability table and ECE, tiles of every flight.

Reads the per-flight results ``scripts/guard_eval.py`` keeps in its WORKDIRs (every tile's
P(safe) from the network alone, ``p_net``; with the guard, ``p_guard``; and as the assessor
publishes it, ``p_safe``, guard and OOD applied) with the flights' ground truth, and pools the
judged tiles of all of them, clear sites included, as a planner meets them: per bin of P(safe),
how many tiles, their mean P(safe) and the share of them that is safe; the ECE over those bins
(:func:`landing_zone.tools.learn.calibration.reliability`, 10 bins); and the share of safe tiles on
the flights, which the model's calibration does not know (it is calibrated as if half the tiles
held an obstacle, the training base rate)::

    python scripts/flight_reliability.py runs/ge runs/gv [--key p_safe] [--json OUT.json]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from guard_eval import workdir_tiles  # scripts/ is this script's first import path

from landing_zone.tools.learn.calibration import reliability

BINS = 10


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('workdirs', type=Path, nargs='+', help='guard_eval.py WORKDIRs')
    ap.add_argument('--key', default='p_safe', choices=('p_net', 'p_guard', 'p_safe'))
    ap.add_argument('--json', type=Path, default=None, help='write the figures here')
    args = ap.parse_args()
    try:
        tiles = [workdir_tiles(wd, args.key) for wd in args.workdirs]
    except (OSError, ValueError, KeyError) as err:
        print(f'flight_reliability: {err}', file=sys.stderr)
        return 2
    p, y = (np.concatenate(parts) for parts in zip(*tiles))
    rel = reliability(p, y, BINS)
    print(f'{len(p)} tiles judged ({args.key}), {y.mean():.1%} of them safe; mean P(safe) '
          f'{p.mean():.3f}; ECE {rel.ece:.3f}')
    print('| P(safe) | tiles | mean P(safe) | safe |')
    print('|---|---:|---:|---:|')
    for k in range(BINS):
        if rel.count[k]:
            print(f'| {rel.edges[k]:.1f}-{rel.edges[k + 1]:.1f} | {int(rel.count[k])} | '
                  f'{rel.confidence[k]:.3f} | {rel.frequency[k]:.2%} |')
    if args.json is not None:
        args.json.write_text(json.dumps({
            'key': args.key, 'tiles': len(p), 'safe_share': float(y.mean()),
            'ece': rel.ece, 'edges': rel.edges.tolist(), 'count': rel.count.tolist(),
            'confidence': [None if np.isnan(c) else float(c) for c in rel.confidence],
            'frequency': [None if np.isnan(f) else float(f) for f in rel.frequency]},
            indent=1) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
