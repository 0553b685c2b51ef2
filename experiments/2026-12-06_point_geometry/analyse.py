"""Leave-one-family-out (and -vegetation-out) gradient boosting on the probe's tile features."""
import json
import sys
from pathlib import Path

import numpy as np
from sklearn.ensemble import HistGradientBoostingClassifier
from sklearn.metrics import roc_auc_score


def load(d):
    X = {'D': [], 'G': [], 'N': []}
    y, fam, veg, flight = [], [], [], []
    for f in sorted(Path(d).glob('f[0-9][0-9][0-9].json')):
        doc = json.loads(f.read_text())
        p = doc['plan']
        for r in doc['rows']:
            if not np.isfinite(r['p_net']):
                continue
            pn = np.clip(r['p_net'], 1e-4, 1 - 1e-4)
            X['N'].append([np.log(pn / (1 - pn))])
            X['D'].append(r['density'])
            X['G'].append(r['geometry'])
            y.append(0 if r['safe'] else 1)   # 1 = obstacle
            fam.append(p['family']); veg.append(p['vegetation']); flight.append(p['i'])
    return {k: np.asarray(v, float) for k, v in X.items()}, np.asarray(y), np.asarray(fam), \
        np.asarray(veg), np.asarray(flight)


def oof(X, y, groups, seed=0):
    pred = np.zeros(len(y))
    for g in np.unique(groups):
        te = groups == g
        m = HistGradientBoostingClassifier(max_iter=300, learning_rate=0.05, max_leaf_nodes=31,
                                           l2_regularization=1.0, random_state=seed)
        m.fit(X[~te], y[~te])
        pred[te] = m.predict_proba(X[te])[:, 1]
    return pred


def at_keep(score_unsafe, y, keep=0.9):
    """Obstacle tiles passed where `keep` of the safe tiles pass (lower score = safer)."""
    thr = np.quantile(score_unsafe[y == 0], keep)
    return float(np.mean(score_unsafe[y == 1] <= thr))


def main(d):
    X, y, fam, veg, flight = load(d)
    print(f'{len(y)} tiles, {y.sum()} obstacle, {len(np.unique(flight))} flights')
    arms = {'N (network alone)': None, 'D': ['D'], 'D+G': ['D', 'G'], 'N+D': ['N', 'D'],
            'N+D+G': ['N', 'D', 'G'], 'N+G': ['N', 'G']}
    for split, groups in (('family', fam), ('vegetation', veg)):
        print(f'\nleave one {split} out')
        for name, parts in arms.items():
            s = -X['N'][:, 0] if parts is None else oof(np.hstack([X[p] for p in parts]), y, groups)
            per = []
            for g in np.unique(fam):
                m = (fam == g)
                if 0 < y[m].sum() < m.sum():
                    per.append(roc_auc_score(y[m], s[m]))
            print(f'  {name:18s} AUC {roc_auc_score(y, s):.4f}  passed@90%kept {at_keep(s, y, 0.9):.3f}'
                  f'  @75%kept {at_keep(s, y, 0.75):.3f}  per-family AUC min {min(per):.3f} '
                  f'median {np.median(per):.3f}')


if __name__ == '__main__':
    main(sys.argv[1])
