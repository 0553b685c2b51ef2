"""The site-adaptation check of issue 15: did adapting to a site's vegetation cut its false
alarms without passing more obstacles of shapes no model trained on?

Compares an initial and an adapted model on
- the held-out vegetation: safe tiles given P(safe) < 0.5 on a hybrid set's test split (a clear
  flight neither trained on, obstacles inserted) and on a replayed flight with obstacles
  (``landing-zone replay`` reports scored against the flight's labels);
- the obstacle families no model ever trained on: obstacle tiles of synth3's test families given
  P(safe) >= 0.5 and >= 0.9 (from ``landing-zone evaluate --by-family --json``, both models).
The check holds when the false alarms fall, in all and on neither set rise, and the test
families' passes rise at neither threshold. Prints one line per figure and the verdict; exits 1
when the check fails.

    python scripts/site_check.py --initial-model M0 --adapted-model M1 --hybrid HYBRID_DIR \
        --labels SITE.labels.json --initial-report R0.json --adapted-report R1.json \
        [--families FAMILIES.json]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

from landing_zone.io.labels import read_labels, score_report


def hybrid_counts(models: list[Path], data: Path) -> list[dict[str, int]]:
    """Per model: false alarms and obstacles passed (at 0.5) on the hybrid test split."""
    from landing_zone.judging.checkpoint import input_configs, load_model
    from landing_zone.judging.inference import Predictor
    from landing_zone.tools.learn.samples import voxelize
    from landing_zone.tools.learn.scenes import ScenePack
    from landing_zone.tools.sim.shards import SceneDataset

    ds = SceneDataset(data, 'test')
    pack = ScenePack.from_scenes(ds, np.arange(len(ds)))
    out, volumes = [], {}
    for path in models:
        net, meta = load_model(path, 'cpu')
        key = json.dumps(input_configs(meta), default=str)
        if key not in volumes:
            volumes[key] = voxelize(pack, *input_configs(meta), 0, False)
        x, y = volumes[key]
        with Predictor(net) as predict:
            p = predict(x)
        y = y.numpy()
        out.append({'safe': int((y == 1).sum()), 'false_alarms': int((p[y == 1] < 0.5).sum()),
                    'unsafe': int((y == 0).sum()), 'passed': int((p[y == 0] >= 0.5).sum())})
    return out


def test_family_passes(families_json: Path) -> list[dict[str, float]]:
    """Per model in the file (in its order): test-family obstacle tiles passed at 0.5, 0.9."""
    from landing_zone.tools.sim.families import TEST_FAMILIES

    with open(families_json, encoding='utf-8') as f:
        rep = json.load(f)['families']['methods']
    out = []
    for name, per in rep.items():
        obs = [per['obstacle'][f] for f in TEST_FAMILIES if f in per['obstacle']]
        n = sum(f['n_unsafe'] for f in obs)
        out.append({'name': name, 'n': n,
                    '0.5': round(sum(f['unsafe_ge_0.5'] * f['n_unsafe'] for f in obs)),
                    '0.9': round(sum(f['unsafe_ge_0.9'] * f['n_unsafe'] for f in obs)),
                    'safe_flagged': round(sum(f['safe_lt_0.5'] * (f['n'] - f['n_unsafe'])
                                              for f in obs))})
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('--initial-model', type=Path, required=True)
    ap.add_argument('--adapted-model', type=Path, required=True)
    ap.add_argument('--hybrid', type=Path, required=True, help='the hybrid set (test split)')
    ap.add_argument('--labels', type=Path, required=True, help='the replayed flight\'s labels')
    ap.add_argument('--initial-report', type=Path, required=True)
    ap.add_argument('--adapted-report', type=Path, required=True)
    ap.add_argument('--families', type=Path, help='evaluate --by-family --json of both models')
    args = ap.parse_args()

    ok = True
    h0, h1 = hybrid_counts([args.initial_model, args.adapted_model], args.hybrid)
    labels = read_labels(args.labels)
    flight = []
    for path in (args.initial_report, args.adapted_report):
        with open(path, encoding='utf-8') as f:
            flight.append(score_report(json.load(f), labels, 0.5))
    f0, f1 = flight
    print(f'held-out vegetation, hybrid test split: safe tiles flagged {h0["false_alarms"]} -> '
          f'{h1["false_alarms"]} of {h0["safe"]}; obstacle tiles passed {h0["passed"]} -> '
          f'{h1["passed"]} of {h0["unsafe"]}')
    print(f'held-out vegetation, flight {args.labels.name}: safe tiles flagged '
          f'{f0.false_alarms} -> {f1.false_alarms} of {f0.safe}; obstacle tiles passed '
          f'{f0.unsafe_judged_safe} -> {f1.unsafe_judged_safe} of {f0.unsafe}; AUC '
          f'{f0.auc if f0.auc is None else round(f0.auc, 3)} -> '
          f'{f1.auc if f1.auc is None else round(f1.auc, 3)}')
    alarms0, alarms1 = h0['false_alarms'] + f0.false_alarms, h1['false_alarms'] + f1.false_alarms
    if not (alarms1 < alarms0 and h1['false_alarms'] <= h0['false_alarms']
            and f1.false_alarms <= f0.false_alarms):
        print('  false alarms on the held-out vegetation not cut')
        ok = False
    if args.families is not None:
        fam = test_family_passes(args.families)
        if len(fam) != 2:
            print(f'{args.families}: {len(fam)} models, want the initial and the adapted one')
            return 2
        a, b = fam
        print(f'test obstacle families ({a["n"]} obstacle tiles): passed at P(safe) >= 0.5 '
              f'{a["0.5"]} -> {b["0.5"]}, at >= 0.9 {a["0.9"]} -> {b["0.9"]}; their safe tiles '
              f'flagged {a["safe_flagged"]} -> {b["safe_flagged"]}')
        if b['0.5'] > a['0.5'] or b['0.9'] > a['0.9']:
            print('  more test-family obstacle tiles passed')
            ok = False
    else:
        print('test obstacle families: not scored (no TEST_DATA)')
        ok = False
    print('site-adaptation check: ' + ('holds' if ok else 'FAILS'))
    return 0 if ok else 1


if __name__ == '__main__':
    sys.exit(main())
