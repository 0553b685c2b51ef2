"""Per obstacle family, vegetation, scan pattern, height and slope: tile AUC and the shares at
P(safe) >= 0.9 and unknown, from dump.py's grids.

    python by_family.py DUMP_DIR
"""
import json, sys
from pathlib import Path
import numpy as np
from sklearn.metrics import roc_auc_score
d = Path(sys.argv[1])
plan = json.loads((d / 'flights.json').read_text())
rows = {}
for f in plan['flights']:
    p = d / f"{f['name']}.npz"
    if not p.exists(): continue
    z = np.load(p)
    t, ps, pn = z['truth'], z['p_safe'], z['p_net']
    j = (t >= 0) & np.isfinite(ps)
    for key in (f['family'], f['vegetation'], f['scan_pattern'], 'h>15' if f['height'] > 15 else 'h<=15', 'slope%d' % f['slope']):
        r = rows.setdefault(key, [[], [], [], 0, 0])
        r[0].append(ps[j]); r[1].append(t[j]); r[2].append(pn[j])
        r[3] += int(((t >= 0) & ~np.isfinite(ps)).sum()); r[4] += int((t >= 0).sum())
for k, (ps, ts, pn, unk, lab) in rows.items():
    p, y, n = np.concatenate(ps), np.concatenate(ts), np.concatenate(pn)
    auc = roc_auc_score(y, p) if len(set(y)) > 1 else float('nan')
    print(f'{k:14s} n_obst {int((y==0).sum()):5d} auc {auc:.3f} net-auc {roc_auc_score(y, n) if len(set(y))>1 else 0:.3f} obst>=.9 {(p[y==0]>=.9).mean():.3f} safe>=.9 {(p[y==1]>=.9).mean():.3f} unknown {unk/lab:.3f}')
