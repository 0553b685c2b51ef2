"""What averaging models would do on families none of them trained on (a measurement, not shipped).

Reads ``landing-zone evaluate --scores`` (every scene's calibrated P(safe) by every ``--model``)
and scores combinations of the models on synth3's test families (never in any training): each
alone, the mean of their logits (a deep ensemble's rule) and the least P(safe) (the most
cautious member). Per family: AUC, ECE, obstacle tiles at P(safe) >= 0.5 and >= 0.9, safe tiles
flagged. The members here are the shipped model and the leave-groups-out fold models, which
each saw three quarters of the train families: a proxy for an ensemble of full models::

    landing-zone evaluate --data data/synth3_test --by-family \\
        --model models/landing_zone.safetensors --model runs/lofo/fold0_of_4_cal.safetensors \\
        ... --scores scores.json
    python scripts/ensemble_scores.py data/synth3_test scores.json
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def _row(p: np.ndarray, y: np.ndarray) -> str:
    from sklearn.metrics import roc_auc_score

    from landing_zone.learn.calibration import expected_calibration_error as ece

    ob, safe = p[y == 0], p[y == 1]
    return (f'{roc_auc_score(y, p):.3f} | {ece(p, y):.3f} | {100 * np.mean(ob >= 0.5):.1f} % | '
            f'{100 * np.mean(ob >= 0.9):.1f} % | {100 * np.mean(safe < 0.5):.1f} %')


def main() -> None:
    from landing_zone.sim.families import TEST_FAMILIES
    from landing_zone.sim.shards import SceneDataset

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('data', type=Path, help='the synth3 test directory the scores were made on')
    ap.add_argument('scores', type=Path, help='landing-zone evaluate --scores output')
    args = ap.parse_args()
    doc = json.loads(args.scores.read_text())
    ds = SceneDataset(args.data, doc['split'])
    labels = np.asarray(doc['labels'], np.int64)
    family = np.array([ds[int(i)].params['family'] for i in doc['scenes']])
    # 'CNN SPEC (file stem)' -> the stem
    short = {m: m.rsplit('(', 1)[-1].rstrip(')') for m in doc['methods']}
    names = list(short.values())
    prob = {short[m]: np.clip(np.asarray(v, np.float64), 1e-7, 1 - 1e-7)
            for m, v in doc['methods'].items()}
    logit = {n: np.log(p / (1 - p)) for n, p in prob.items()}
    combos = {names[0]: prob[names[0]]}
    if len(names) > 1:
        combos[f'mean logit of {names[0]} and {names[1]}'] = \
            1 / (1 + np.exp(-(logit[names[0]] + logit[names[1]]) / 2))
        combos[f'mean logit of all {len(names)}'] = \
            1 / (1 + np.exp(-np.mean([logit[n] for n in names], axis=0)))
        combos[f'least P(safe) of all {len(names)}'] = np.min([prob[n] for n in names], axis=0)
    print('| combination | family | AUC | ECE | obstacle tiles at >= 0.5 | >= 0.9 | '
          'safe flagged |')
    print('|---|---|---:|---:|---:|---:|---:|')
    for name, p in combos.items():
        for fam in (*TEST_FAMILIES, 'pooled'):
            m = np.isin(family, TEST_FAMILIES) if fam == 'pooled' else family == fam
            print(f'| {name} | {fam} | {_row(p[m], labels[m])} |')


if __name__ == '__main__':
    main()
