"""Score a replay REPORT.json against a SITE.labels.json (docs/INTERFACES.md section 3).

Prints the per-tile AUC of P(safe) over the judged labelled tiles, the unknown tiles, and the
tiles judged wrongly at a threshold: unsafe judged safe (the dangerous error) and safe judged
unsafe, split into the site's edge ring and its interior:

    python scripts/score_report.py report.json site.labels.json [--threshold 0.5] [--json]
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np


def score(report: dict, labels: dict, threshold: float = 0.5) -> dict:
    """The figures of one report against its labels (tiles matched by centre)."""
    from sklearn.metrics import roc_auc_score

    truth = {(round(t['x'], 3), round(t['y'], 3)): bool(t['safe']) for t in labels['tiles']}
    xs = [k[0] for k in truth]
    ys = [k[1] for k in truth]
    p, y, edge, unknown = [], [], [], 0
    for t in report['tiles']:
        key = (round(t['x'], 3), round(t['y'], 3))
        if key not in truth:
            continue
        if t['p_safe'] is None:
            unknown += 1
            continue
        p.append(float(t['p_safe']))
        y.append(int(truth[key]))
        edge.append(key[0] in (min(xs), max(xs)) or key[1] in (min(ys), max(ys)))
    p_arr, y_arr, e_arr = np.array(p), np.array(y), np.array(edge, bool)
    safe, unsafe = y_arr == 1, y_arr == 0
    auc = float(roc_auc_score(y_arr, p_arr)) if safe.any() and unsafe.any() else None
    return {'judged': int(len(y_arr)), 'unknown': unknown, 'auc': auc,
            'unsafe_judged_safe': int((unsafe & (p_arr >= threshold)).sum()),
            'unsafe': int(unsafe.sum()),
            'safe_judged_unsafe_interior': int((safe & ~e_arr & (p_arr < threshold)).sum()),
            'safe_interior': int((safe & ~e_arr).sum()),
            'safe_judged_unsafe_edge': int((safe & e_arr & (p_arr < threshold)).sum()),
            'safe_edge': int((safe & e_arr).sum())}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('report')
    ap.add_argument('labels')
    ap.add_argument('--threshold', type=float, default=0.5)
    ap.add_argument('--json', action='store_true', help='print the figures as JSON')
    args = ap.parse_args()
    try:
        with open(args.report, encoding='utf-8') as f:
            report = json.load(f)
        with open(args.labels, encoding='utf-8') as f:
            labels = json.load(f)
        s = score(report, labels, args.threshold)
    except (OSError, ValueError, KeyError, TypeError) as err:
        print(f'score_report: {err}', file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(s))
        return 0
    auc = 'n/a' if s['auc'] is None else f'{s["auc"]:.3f}'
    print(f'{args.report}: {s["judged"]} tiles judged, {s["unknown"]} unknown; AUC {auc}; '
          f'unsafe judged safe {s["unsafe_judged_safe"]} of {s["unsafe"]}; safe judged unsafe '
          f'{s["safe_judged_unsafe_interior"]} of {s["safe_interior"]} inside, '
          f'{s["safe_judged_unsafe_edge"]} of {s["safe_edge"]} on the edge')
    return 0


if __name__ == '__main__':
    sys.exit(main())
