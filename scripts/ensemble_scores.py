"""What averaging models would do on families they never trained on (a measurement, not shipped).

Two modes, both on ``landing-zone evaluate --scores`` output (every scene's calibrated P(safe)
by every ``--model``) of synth3's test split:

* **one run** (``SCORES``): combinations of its models on the test families, which none of them
  trained on: the first alone, the mean logit of the first two, of all, and the least P(safe);
* **members** (``--member SCORES LOFO ...``, one pair per ensemble member, e.g. per training
  seed): each member's run holds its final model and its fold models, and ``LOFO`` is that run's
  ``evaluate --by-family --json``, which names for every family the model that never saw it.
  Every scene is scored, per member, by that member's model that never saw the scene's obstacle
  family (obstacle axis) or vegetation family (vegetation axis); the ensemble is the mean logit
  over members. So each family's figure is the held-out figure of an ensemble none of whose
  members saw it: the leave-one-family-out yardstick.

Per family: AUC, ECE, obstacle tiles at P(safe) >= 0.5 and >= 0.9, safe tiles flagged::

    landing-zone evaluate --data data/synth3_test --by-family \\
        --model models/landing_zone.safetensors --model runs/lofo/fold0_of_4_cal.safetensors \\
        ... --scores scores.json --json lofo.json
    python scripts/ensemble_scores.py data/synth3_test scores.json
    python scripts/ensemble_scores.py data/synth3_test --member s0.json lofo0.json \\
        --member s1.json lofo1.json
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path
from typing import Any

import numpy as np


def _row(p: np.ndarray, y: np.ndarray) -> str:
    from sklearn.metrics import roc_auc_score

    from landing_zone.tools.learn.calibration import expected_calibration_error as ece

    ob, safe = p[y == 0], p[y == 1]
    return (f'{roc_auc_score(y, p):.3f} | {ece(p, y):.3f} | {100 * np.mean(ob >= 0.5):.1f} % | '
            f'{100 * np.mean(ob >= 0.9):.1f} % | {100 * np.mean(safe < 0.5):.1f} %')


def _logit(p: np.ndarray) -> np.ndarray:
    q = np.clip(np.asarray(p, np.float64), 1e-7, 1 - 1e-7)
    out: np.ndarray = np.log(q / (1 - q))
    return out


def _sigmoid(z: np.ndarray) -> np.ndarray:
    out: np.ndarray = 1 / (1 + np.exp(-z))
    return out


def _header() -> None:
    print('| combination | family | AUC | ECE | obstacle tiles at >= 0.5 | >= 0.9 | '
          'safe flagged |')
    print('|---|---|---:|---:|---:|---:|---:|')


def one_run(doc: dict[str, Any], family: np.ndarray) -> None:
    from landing_zone.tools.sim.families import TEST_FAMILIES

    labels = np.asarray(doc['labels'], np.int64)
    # 'CNN SPEC (file stem)' -> the stem
    short = {m: m.rsplit('(', 1)[-1].rstrip(')') for m in doc['methods']}
    names = list(short.values())
    prob = {short[m]: np.clip(np.asarray(v, np.float64), 1e-7, 1 - 1e-7)
            for m, v in doc['methods'].items()}
    logit = {n: _logit(p) for n, p in prob.items()}
    combos = {names[0]: prob[names[0]]}
    if len(names) > 1:
        combos[f'mean logit of {names[0]} and {names[1]}'] = \
            _sigmoid((logit[names[0]] + logit[names[1]]) / 2)
        combos[f'mean logit of all {len(names)}'] = \
            _sigmoid(np.mean([logit[n] for n in names], axis=0))
        combos[f'least P(safe) of all {len(names)}'] = np.min([prob[n] for n in names], axis=0)
    _header()
    for name, p in combos.items():
        for fam in (*TEST_FAMILIES, 'pooled'):
            m = np.isin(family, TEST_FAMILIES) if fam == 'pooled' else family == fam
            print(f'| {name} | {fam} | {_row(p[m], labels[m])} |')


def members(data: Path, pairs: list[tuple[Path, Path]]) -> None:
    from landing_zone.tools.sim.shards import SceneDataset

    docs = [(json.loads(s.read_text()), json.loads(j.read_text())['families']['lofo'])
            for s, j in pairs]
    scenes = docs[0][0]['scenes']
    if any(d['scenes'] != scenes for d, _ in docs):
        raise SystemExit('the members were scored on different scenes')
    labels = np.asarray(docs[0][0]['labels'], np.int64)
    ds = SceneDataset(data, docs[0][0]['split'])
    params = [ds[int(i)].params for i in scenes]
    axes = {'obstacle': np.array([q['family'] for q in params]),
            'vegetation': np.array([q['vegetation']['family'] for q in params])}
    _header()
    for axis, family in axes.items():
        for fam in sorted(docs[0][1][axis]):
            m = family == fam
            held = []  # per member: each scene of the family by its model that never saw it
            for doc, lofo in docs:
                model = lofo[axis][fam]['model']
                held.append(np.asarray(doc['methods'][model], np.float64)[m])
            for k, p in enumerate(held):
                print(f'| member {k} | {axis}: {fam} | {_row(p, labels[m])} |')
            mean = _sigmoid(np.mean([_logit(p) for p in held], axis=0))
            print(f'| mean logit of {len(held)} | {axis}: {fam} | {_row(mean, labels[m])} |')


def main() -> None:
    from landing_zone.tools.sim.shards import SceneDataset

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('data', type=Path, help='the synth3 test directory the scores were made on')
    ap.add_argument('scores', type=Path, nargs='?', help='landing-zone evaluate --scores output')
    ap.add_argument('--member', nargs=2, type=Path, action='append', default=[],
                    metavar=('SCORES', 'LOFO'),
                    help='one ensemble member: its run\'s --scores and --json (repeat)')
    args = ap.parse_args()
    if args.member:
        members(args.data, [tuple(m) for m in args.member])
        return
    if args.scores is None:
        ap.error('give SCORES or --member pairs')
    doc = json.loads(args.scores.read_text())
    ds = SceneDataset(args.data, doc['split'])
    family = np.array([ds[int(i)].params['family'] for i in doc['scenes']])
    one_run(doc, family)


if __name__ == '__main__':
    main()
