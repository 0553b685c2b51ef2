"""Probe: supervise every 10 cm column, not the tile, and judge the tile from its columns.

    python dense.py TRAIN_DIR VALID_DIR TEST_DUMP OUT.pt [--loss dense|tile] [--epochs N]

TRAIN_DIR and VALID_DIR hold ``dump.py`` grids of development flights (or links to them);
TEST_DUMP the held-out set's. Each flight's labels are read beside its bag (``X_dump`` ->
``X/NAME.labels.json``). The input is the tile's cube exactly as the shipped net reads it
(max-pooled to 10 cm, 16^3, z centred on the tile's ground); its 16 height cells are the
channels of a small 2D fully convolutional net that gives an obstacle logit per 10 cm column.
A column is an obstacle where it overlaps an obstacle's labelled footprint (rectangle, size and
yaw), unlabelled outside the labelled site. The tile's obstacle logit is the largest of its
central 10 x 10 columns' (the 30 cm rim is context).

``--loss dense``: per-column cross-entropy plus the tile's; ``--loss tile``: the tile's only
(the same net and pooling, so the difference is the supervision). Tiles are drawn half obstacle,
half safe; quarter turns and mirror images augment them. At the end the tile logit is
calibrated (temperature and offset at an even prior, on VALID) and the held-out set is scored
as ``analyse.py`` scores the shipped model: the shipped judgement's unknowns stay unknown and the
guard's cap holds.
"""
import argparse
import sys
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from scipy.special import expit
from sklearn.metrics import roc_auc_score
from torch import nn

from landing_zone.io.labels import labels_extent, obstacle_footprints, read_labels

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / '2026-12-06_site_normalisation'))
from analyse import as_judged, figures, show  # noqa: E402

PAD, COL = 0.3, 0.1          # the cube's context each side and its pooled column [m]
SIDE = 16
INNER = slice(3, 13)         # the tile's own columns
GROW = 0.02                  # the rectangle grown so that a sliver of overlap counts


def column_labels(labels, cube_index):
    """(T, 16, 16) int8: 1 obstacle, 0 clear, -1 unlabelled, per pooled column of each cube."""
    c = (np.arange(SIDE) + 0.5) * COL - PAD
    gx = cube_index[:, 0, None, None] + c[None, :, None] + 0 * c[None, None, :]
    gy = cube_index[:, 1, None, None] + 0 * c[None, :, None] + c[None, None, :]
    out = np.zeros(gx.shape, np.int8)
    for poly in obstacle_footprints(labels):
        # a column is an obstacle when its centre lies within the (slightly grown) rectangle
        ctr = poly.mean(axis=0)
        e1, e2 = poly[1] - poly[0], poly[3] - poly[0]
        l1, l2 = np.linalg.norm(e1), np.linalg.norm(e2)
        u = ((gx - ctr[0]) * e1[0] + (gy - ctr[1]) * e1[1]) / l1
        v = ((gx - ctr[0]) * e2[0] + (gy - ctr[1]) * e2[1]) / l2
        out[(np.abs(u) <= l1 / 2 + GROW) & (np.abs(v) <= l2 / 2 + GROW)] = 1
    lo, hi = labels_extent(labels)
    outside = (gx < lo[0]) | (gx >= hi[0]) | (gy < lo[1]) | (gy >= hi[1])
    out[outside] = -1
    return out


def load(d):
    d = Path(d)
    xs, cols, ys, flights = [], [], [], []
    for p in sorted(d.glob('*.npz')):
        src = p.resolve()
        name = src.stem
        labels = read_labels(src.parent.parent / src.parent.name.replace('_dump2', '').replace(
            '_dump', '') / f'{name}.labels.json')
        z = dict(np.load(src))
        z['meta'] = {'name': str(p)}
        keep = z['cube_truth'] >= 0
        xs.append(z['cubes'][keep])
        cols.append(column_labels(labels, z['cube_index'][keep]))
        ys.append(z['cube_truth'][keep])
        flights.append(z)
    return np.concatenate(xs), np.concatenate(cols), np.concatenate(ys).astype(np.float32), flights


class ColumnNet(nn.Module):
    """Height cells as channels; 3x3 convolutions over 10 cm columns; an obstacle logit each."""

    def __init__(self, width=48):
        super().__init__()
        layers, c = [], SIDE
        for dil in (1, 1, 2, 1):
            layers += [nn.Conv2d(c, width, 3, padding=dil, dilation=dil), nn.BatchNorm2d(width),
                       nn.ReLU()]
            c = width
        self.body = nn.Sequential(*layers, nn.Conv2d(width, 1, 1))

    def forward(self, cube):             # (B, 16x, 16y, 16z) in [-1, 1]
        return self.body(cube.permute(0, 3, 1, 2))[:, 0]   # (B, 16, 16) obstacle logits


def tile_logit(col):
    return col[:, INNER, INNER].flatten(1).amax(1)


def to_x(a):
    return torch.from_numpy(a.astype(np.float32) / 127.0)


def predict(net, x, bs=1024):
    net.eval()
    out = []
    with torch.no_grad():
        for i in range(0, len(x), bs):
            out.append(tile_logit(net(to_x(x[i:i + bs]))).numpy())
    return np.concatenate(out)


def augment(x, c, rng):
    k = int(rng.integers(4))
    x, c = torch.rot90(x, k, dims=(1, 2)), torch.rot90(c, k, dims=(1, 2))
    if rng.random() < 0.5:
        x, c = torch.flip(x, dims=(1,)), torch.flip(c, dims=(1,))
    return x, c


def main():
    ap = argparse.ArgumentParser()
    for name in ('train', 'valid', 'test', 'out'):
        ap.add_argument(name)
    ap.add_argument('--loss', choices=('dense', 'tile'), default='dense')
    ap.add_argument('--epochs', type=float, default=6.0)
    ap.add_argument('--lr', type=float, default=3e-3)
    ap.add_argument('--batch', type=int, default=64)
    ap.add_argument('--width', type=int, default=48)
    ap.add_argument('--seed', type=int, default=0)
    a = ap.parse_args()
    torch.manual_seed(a.seed)
    rng = np.random.default_rng(a.seed)
    torch.set_num_threads(2)
    t0 = time.time()
    xt, ct, yt, _ = load(a.train)
    xv, _, yv, _ = load(a.valid)
    print(f'train {len(yt)} tiles ({int((yt == 0).sum())} obstacle; '
          f'{(ct == 1).mean():.4f} of columns obstacle), valid {len(yv)} '
          f'({int((yv == 0).sum())} obstacle); loaded in {time.time() - t0:.0f} s', flush=True)
    net = ColumnNet(a.width)
    pos, neg = np.flatnonzero(yt == 1), np.flatnonzero(yt == 0)
    steps = int(a.epochs * 2 * len(neg) / a.batch)
    opt = torch.optim.AdamW(net.parameters(), lr=a.lr, weight_decay=1e-4)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=a.lr, total_steps=steps)
    w_col = float((ct == 0).sum() / max((ct == 1).sum(), 1)) ** 0.5
    t0 = time.time()
    for s in range(steps):
        net.train()
        idx = np.concatenate([rng.choice(pos, a.batch // 2), rng.choice(neg, a.batch // 2)])
        xb, cb = augment(to_x(xt[idx]), torch.from_numpy(ct[idx]), rng)
        col = net(xb)
        # obstacle = 1 in the loss (the logit is of an obstacle; P(safe) is its complement)
        loss = F.binary_cross_entropy_with_logits(tile_logit(col), torch.from_numpy(1 - yt[idx]))
        if a.loss == 'dense':
            m = cb >= 0
            wt = torch.where(cb == 1, w_col, 1.0)[m]
            loss = loss + F.binary_cross_entropy_with_logits(col[m], cb[m].float(), weight=wt)
        opt.zero_grad()
        loss.backward()
        opt.step()
        sched.step()
        if (s + 1) % max(1, steps // 6) == 0 or s == steps - 1:
            lv = predict(net, xv)
            print(f'step {s + 1}/{steps} loss {loss.item():.3f} valid AUC '
                  f'{roc_auc_score(yv, -lv):.4f} ({(s + 1) * a.batch / (time.time() - t0):.0f} '
                  'samples/s)', flush=True)
    lv = -predict(net, xv)    # safe logit
    wv = np.where(yv == 1, 0.5 / (yv == 1).mean(), 0.5 / (yv == 0).mean())
    best = None
    for T in np.linspace(0.3, 4.0, 75):
        for b in np.linspace(-4, 4, 81):
            p = expit(lv / T + b)
            nll = -np.sum(wv * (yv * np.log(p + 1e-9) + (1 - yv) * np.log(1 - p + 1e-9)))
            if best is None or nll < best[0]:
                best = (nll, T, b)
    _, T, b = best
    print(f'calibrated at an even prior on valid: T {T:.3f} b {b:.3f}', flush=True)
    torch.save({'state': net.state_dict(), 'T': T, 'b': b, 'args': vars(a)}, a.out)

    _, _, _, test = load(a.test)
    cache = {}

    def rule(f):
        key = f['meta']['name']
        if key not in cache:
            grid = np.full(f['p_safe'].shape, np.nan)
            ij = f['cube_index'] - f['origin']
            grid[ij[:, 0], ij[:, 1]] = expit(-predict(net, f['cubes']) / T + b)
            cache[key] = grid
        return as_judged(f, cache[key])

    print(f'{len(test)} held-out flights')
    show('shipped', figures(test, lambda f: f['p_safe'].astype(np.float64)))
    show(f'columns ({a.loss})', figures(test, rule))
    np.savez_compressed(Path(a.out).with_suffix('.grids.npz'),
                        **{Path(k).stem: v for k, v in cache.items()})


if __name__ == '__main__':
    main()
