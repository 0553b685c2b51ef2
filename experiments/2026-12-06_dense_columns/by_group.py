"""Tile AUC and shares at P(safe) >= 0.9 per obstacle family and vegetation, for the shipped
judgement and for a probe's grids (``dense.py`` writes OUT.grids.npz).

    python by_group.py TEST_DUMP OUT.grids.npz
"""
import sys
from pathlib import Path

import numpy as np
from sklearn.metrics import roc_auc_score

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / '2026-12-06_site_normalisation'))
from analyse import as_judged  # noqa: E402

test, grids = Path(sys.argv[1]), np.load(sys.argv[2])
rows = {}
for name in grids.files:
    z = np.load(test / f'{name}.npz')
    t, ship = z['truth'], z['p_safe'].astype(np.float64)
    new = as_judged(dict(z), grids[name])
    j = (t >= 0) & np.isfinite(ship)
    _, family, veg = name.split('_', 2)
    for key in (family, veg):
        r = rows.setdefault(key, [[], [], []])
        for column, values in zip(r, (t, ship, new)):
            column.append(values[j])
print(f"{'group':10s} {'obst':>5s} {'AUC ship':>8s} {'probe':>6s} {'obst>=.9 ship':>13s} "
      f"{'probe':>6s} {'safe>=.9 ship':>13s} {'probe':>6s}")
for k, (ts, a, b) in rows.items():
    y, a, b = np.concatenate(ts), np.concatenate(a), np.concatenate(b)
    print(f'{k:10s} {int((y == 0).sum()):5d} {roc_auc_score(y, a):8.3f} '
          f'{roc_auc_score(y, b):6.3f} '
          f'{(a[y == 0] >= .9).mean():13.3f} {(b[y == 0] >= .9).mean():6.3f} '
          f'{(a[y == 1] >= .9).mean():13.3f} {(b[y == 1] >= .9).mean():6.3f}')
