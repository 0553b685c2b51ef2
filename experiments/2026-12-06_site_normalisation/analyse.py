"""What comes after the network, tried offline on the grids ``dump.py`` kept.

    python analyse.py DUMP_DIR [DUMP_DIR ...]

For each rule: tile AUC, ECE, obstacle tiles and safe tiles at P(safe) >= 0.9, and the
footprints as the robot acts (clear footprints accepted at the shipped site threshold, those
over an obstacle accepted, the operating curve), pooled over every flight.
"""
import json
import sys
from pathlib import Path

import numpy as np
from scipy.special import expit, logit
from sklearn.metrics import roc_auc_score

from landing_zone.judging.sites import OBSTACLE, _footprint_min, site_probabilities
from landing_zone.tools.evaluate.footprints import footprint_figures, operating_curve
from landing_zone.tools.learn.calibration import expected_calibration_error

T = 0.9
RADIUS = 1.5


def load(dirs):
    out = []
    for d in dirs:
        plan = json.loads((Path(d) / 'flights.json').read_text())
        for f in plan['flights']:
            p = Path(d) / f"{f['name']}.npz"
            if p.exists():
                z = dict(np.load(p))
                z['meta'] = f
                out.append(z)
    return out


def figures(flights, rule, threshold=T):
    ps, ys, cps, ops = [], [], [], []
    n_clear = acc = n_over = acc_over = 0
    for f in flights:
        p = rule(f)
        t = f['truth']
        j = (t >= 0) & np.isfinite(p)
        ps.append(p[j]); ys.append(t[j])
        pmin = site_probabilities(p, np.ones_like(p), RADIUS, 1.0)[0]
        with np.errstate(invalid='ignore'):
            low = _footprint_min(p, RADIUS, 1.0) < threshold
        reasons = (f['reasons'].astype(np.int64) & ~OBSTACLE) | np.where(low, OBSTACLE, 0)
        ff = footprint_figures(reasons, pmin, f['ftruth'])
        n_clear += ff['clear_footprints']; acc += ff['clear_accepted']
        n_over += ff['obstacle_footprints']; acc_over += ff['obstacle_accepted']
        cps.append(ff['_cp']); ops.append(ff['_op'])
    p, y = np.concatenate(ps).astype(np.float64), np.concatenate(ys)
    curve = operating_curve(np.concatenate(cps), np.concatenate(ops), n_clear)
    return {'auc': roc_auc_score(y, p), 'ece': expected_calibration_error(p, y),
            'obst>=.9': (p[y == 0] >= threshold).mean(), 'safe>=.9': (p[y == 1] >= threshold).mean(),
            'clear acc': acc / n_clear, 'over acc': f'{acc_over}/{n_over}',
            'curve0': curve['0']['share'], 't0': curve['0']['threshold'],
            'curve5': curve['5']['share']}


def show(name, fig):
    print(f"{name:34s} " + ' '.join(f'{k} {v:.3f}' if isinstance(v, float) else f'{k} {v}'
                                    for k, v in fig.items()), flush=True)


def base(f):
    return f['p_safe'].astype(np.float64)


def shift(c):
    def rule(f):
        p = base(f)
        return expit(logit(np.clip(p, 1e-7, 1 - 1e-7)) + c)
    return rule


def model_rule(path):
    """P(safe) of another net on the same cubes: its own calibration, the guard's cap, and the
    tiles the shipped judgement left unknown kept unknown."""
    import torch
    from landing_zone.judging.checkpoint import load_model
    from landing_zone.judging.net import judge
    net, _ = load_model(path)
    cache = {}

    def rule(f):
        key = f['meta']['name']
        if key not in cache:
            x = torch.from_numpy(f['cubes'].astype(np.float32) / 127.0)[:, None]
            with torch.no_grad():
                lg = np.concatenate([judge(net, x[i:i + 512], None, pooled=True)[0].numpy()
                                     for i in range(0, len(x), 512)])
            grid = np.full(f['p_safe'].shape, np.nan)
            ij = f['cube_index'] - f['origin']
            grid[ij[:, 0], ij[:, 1]] = expit(lg / net.temperature + net.offset)
            cache[key] = grid
        return as_judged(f, cache[key])
    return rule


def as_judged(f, p):
    """A candidate's P(safe) grid ``p`` as the onboard judgement would give it: the tiles the
    shipped judgement left unknown stay unknown and the guard's cap holds."""
    p = np.where(np.isfinite(f['p_safe']), p, np.nan)
    g = f.get('guard')
    if g is not None:
        p = np.where(np.nan_to_num(g) > 0, np.minimum(p, 0.05), p)
    return p


def site_norm(q=50, ref=3.0, only_up=True, cap=None, src='p_safe'):
    """Shift a site's logits so that its q-th percentile tile sits at ``ref``."""
    def rule(f):
        p = base(f)
        lg = logit(np.clip(p, 1e-7, 1 - 1e-7))
        s = logit(np.clip(f[src].astype(np.float64), 1e-7, 1 - 1e-7))
        ok = np.isfinite(p) & np.isfinite(s)
        d = ref - np.percentile(s[ok], q)
        if only_up:
            d = max(d, 0.0)
        if cap is not None:
            d = min(d, cap)
        out = expit(lg + d)
        guarded = f.get('guard')
        if guarded is not None:   # the guard's cap holds whatever the site
            out = np.where(np.nan_to_num(guarded) > 0, np.minimum(out, p), out)
        return out
    return rule


if __name__ == '__main__':
    models = [a[len('--model='):] for a in sys.argv[1:] if a.startswith('--model=')]
    fl = load([a for a in sys.argv[1:] if not a.startswith('--')])
    print(len(fl), 'flights')
    show('shipped', figures(fl, base))
    for m in models:
        show(Path(m).name, figures(fl, model_rule(m)))
    if models:
        sys.exit(0)
    prior = [float(a[len('--prior='):]) for a in sys.argv[1:] if a.startswith('--prior=')]
    share = float(np.mean(np.concatenate([f['truth'][f['truth'] >= 0] == 0 for f in fl])))
    print(f'obstacle tiles: {share:.3f} of the labelled')
    for pi in prior + [share]:
        c = float(np.log((1 - pi) / pi))
        for t in (0.9, 0.95, 0.99):
            show(f'stated prior {pi:.3f} (logit {c:+.2f}), t {t}', figures(fl, shift(c), t))
    if prior:
        sys.exit(0)
    for q in (25, 50, 75):
        for ref in (2.0, 3.0, 4.0):
            show(f'site q{q} -> {ref}', figures(fl, site_norm(q, ref)))
