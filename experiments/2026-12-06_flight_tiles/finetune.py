"""Probe: fine-tune the shipped net on tiles of maps as the robot builds them.

    python finetune.py TRAIN_DUMP VALID_DUMP OUT.safetensors [--epochs N] [--seed S]

TRAIN_DUMP and VALID_DUMP hold ``dump.py``'s grids of two development flight sets (training
families and vegetation only). Every labelled tile of a flight is a sample: its max-pooled
16^3 cube exactly as the last pass judged it, labelled safe or not as the labels say (an
obstacle's footprint overlapping the tile makes it unsafe). Obstacle and safe tiles are drawn
evenly (the prior the calibration states); quarter turns and mirror images augment them.
"""
import argparse
import time
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from sklearn.metrics import roc_auc_score

from landing_zone.judging.checkpoint import load_model, save_model
from landing_zone.judging.net import judge
from landing_zone.tools.learn.calibration import expected_calibration_error


def tiles(dump):
    xs, ys, fl = [], [], []
    for k, p in enumerate(sorted(Path(dump).glob('*.npz'))):
        z = np.load(p)
        keep = z['cube_truth'] >= 0
        xs.append(z['cubes'][keep]); ys.append(z['cube_truth'][keep]); fl += [k] * int(keep.sum())
    return np.concatenate(xs), np.concatenate(ys).astype(np.float32), np.array(fl)


def logits(net, x, bs=512):
    out = []
    with torch.no_grad():
        for i in range(0, len(x), bs):
            xb = torch.from_numpy(x[i:i + bs].astype(np.float32) / 127.0)[:, None]
            out.append(judge(net, xb, None, pooled=True)[0].numpy())
    return np.concatenate(out)


def augment(xb, rng):
    k = int(rng.integers(4))
    xb = torch.rot90(xb, k, dims=(2, 3))
    if rng.random() < 0.5:
        xb = torch.flip(xb, dims=(2,))
    return xb


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument('train'); ap.add_argument('valid'); ap.add_argument('out')
    ap.add_argument('--model', default='models/landing_zone.safetensors')
    ap.add_argument('--epochs', type=float, default=3.0)
    ap.add_argument('--lr', type=float, default=1e-3)
    ap.add_argument('--batch', type=int, default=32)
    ap.add_argument('--seed', type=int, default=0)
    a = ap.parse_args()
    torch.manual_seed(a.seed)
    rng = np.random.default_rng(a.seed)
    torch.set_num_threads(2)
    net, meta = load_model(a.model)
    xt, yt, _ = tiles(a.train)
    xv, yv, _ = tiles(a.valid)
    print(f'train {len(yt)} tiles ({int((yt == 0).sum())} obstacle), valid {len(yv)} '
          f'({int((yv == 0).sum())} obstacle)', flush=True)
    lv = logits(net, xv)
    print(f'shipped net on valid: AUC {roc_auc_score(yv, lv):.4f}', flush=True)
    pos, neg = np.flatnonzero(yt == 1), np.flatnonzero(yt == 0)
    steps = int(a.epochs * 2 * len(neg) / a.batch)
    opt = torch.optim.SGD(net.parameters(), lr=a.lr, momentum=0.9, weight_decay=5e-4)
    sched = torch.optim.lr_scheduler.OneCycleLR(opt, max_lr=a.lr, total_steps=steps)
    net.train()
    t0 = time.time()
    for s in range(steps):
        idx = np.concatenate([rng.choice(pos, a.batch // 2), rng.choice(neg, a.batch // 2)])
        xb = augment(torch.from_numpy(xt[idx].astype(np.float32) / 127.0)[:, None], rng)
        yb = torch.from_numpy(yt[idx])
        lg, _ = judge(net, xb, None, pooled=True)
        loss = F.binary_cross_entropy_with_logits(lg, yb)
        opt.zero_grad(); loss.backward(); opt.step(); sched.step()
        if (s + 1) % max(1, steps // 6) == 0 or s == steps - 1:
            net.eval()
            lv = logits(net, xv)
            net.train()
            print(f'step {s + 1}/{steps} loss {loss.item():.3f} valid AUC '
                  f'{roc_auc_score(yv, lv):.4f} ({(s + 1) * a.batch / (time.time() - t0):.0f} '
                  'samples/s)', flush=True)
    net.eval()
    lv = logits(net, xv)
    # temperature and offset at an even prior (class-balanced), on the validation tiles
    w = np.where(yv == 1, 0.5 / (yv == 1).mean(), 0.5 / (yv == 0).mean())
    best = None
    for T in np.linspace(0.4, 3.0, 53):
        for b in np.linspace(-3, 3, 61):
            p = 1 / (1 + np.exp(-(lv / T + b)))
            nll = -np.sum(w * (yv * np.log(p + 1e-9) + (1 - yv) * np.log(1 - p + 1e-9)))
            if best is None or nll < best[0]:
                best = (nll, T, b)
    _, T, b = best
    net.temperature, net.offset = float(T), float(b)
    p = 1 / (1 + np.exp(-(lv / T + b)))
    print(f'calibrated T {T:.3f} b {b:.3f}: ECE {expected_calibration_error(p, yv):.3f}',
          flush=True)
    meta = {k: v for k, v in meta.items() if k not in ('format', 'model', 'temperature',
                                                       'calibration_offset', 'weights_sha256')}
    meta['finetune_flight_tiles'] = {'train': str(a.train), 'epochs': a.epochs, 'lr': a.lr,
                                     'seed': a.seed, 'tiles': int(len(yt))}
    save_model(a.out, net, meta)
    print('wrote', a.out, flush=True)


if __name__ == '__main__':
    main()
