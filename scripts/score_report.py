"""Score a replay REPORT.json against a SITE.labels.json (docs/INTERFACES.md section 3).

Prints the per-tile AUC of P(safe) over the judged labelled tiles, the unknown tiles, and the
tiles judged wrongly at a threshold: unsafe judged safe (the dangerous error) and safe judged
unsafe, split into the site's edge ring and its interior (landing_zone.io.labels does the
scoring, as for the demo):

    python scripts/score_report.py report.json site.labels.json [--threshold 0.5] [--json]
"""
from __future__ import annotations

import argparse
import json
import sys

from landing_zone.errors import LandingZoneError
from landing_zone.io.labels import read_labels, score_report


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
        s = score_report(report, read_labels(args.labels), args.threshold)
    except (OSError, ValueError, KeyError, TypeError, LandingZoneError) as err:
        print(f'score_report: {err}', file=sys.stderr)
        return 2
    if args.json:
        print(json.dumps(s.to_dict()))
        return 0
    auc = 'n/a' if s.auc is None else f'{s.auc:.3f}'
    print(f'{args.report}: {s.judged} tiles judged, {s.unknown} unknown; AUC {auc}; '
          f'unsafe judged safe {s.unsafe_judged_safe} of {s.unsafe}; safe judged unsafe '
          f'{s.false_alarms - s.false_alarms_edge} of {s.safe - s.safe_edge} inside, '
          f'{s.false_alarms_edge} of {s.safe_edge} on the edge')
    return 0


if __name__ == '__main__':
    sys.exit(main())
