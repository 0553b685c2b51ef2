import numpy as np, sys
from sklearn.metrics import roc_auc_score
from analyse import load, oof
X, y, fam, veg, flight = load(sys.argv[1] if len(sys.argv) > 1 else 'out')
sN = -X['N'][:, 0]
sG = oof(np.hstack([X['N'], X['D'], X['G']]), y, fam)
sDG = oof(np.hstack([X['D'], X['G']]), y, fam)
print(f"{'family':14s} {'obst':>5s} {'N':>6s} {'N+D+G':>6s} {'D+G':>6s}")
for g in np.unique(fam):
    m = fam == g
    print(f"{g:14s} {y[m].sum():5d} {roc_auc_score(y[m], sN[m]):6.3f} {roc_auc_score(y[m], sG[m]):6.3f} {roc_auc_score(y[m], sDG[m]):6.3f}")
print('vegetation: safe tiles flagged at the threshold keeping 90% of all safe tiles (N / N+D+G)')
tN = np.quantile(sN[y == 0], 0.9); tG = np.quantile(sG[y == 0], 0.9)
for g in np.unique(veg):
    m = (veg == g) & (y == 0)
    print(f"{g:10s} {np.mean(sN[m] > tN):.3f} {np.mean(sG[m] > tG):.3f}")
