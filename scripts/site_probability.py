"""What a landing site's P(safe) means on flights: the footprint's figure against its truth.

A landing site's ``p_safe`` claims P(every tile under the footprint safe)
(:mod:`landing_zone.judging.sites`). This scores that claim on simulated flights with ground
truth, the per-tile results ``scripts/guard_eval.py`` keeps in its WORKDIR (one JSON per flight:
every judged tile's final P(safe) and label): every footprint of ``--radius`` centred on a tile
whose tiles are all judged, its truth being "every tile under it safe". Three estimates:

* ``product``: the product of the tiles' P(safe), what independent tiles would give;
* ``product^k``: the product raised to a power fitted (maximum likelihood) on the flights of the
  other conditions, one condition held out at a time, the dependence between tiles soaked up
  (k = 1: independent; the smaller k, the fewer independent tiles the footprint is worth);
* ``least``: the least tile P(safe) under the footprint (what ``judging.sites`` reports).

Per estimate: reliability bins (mean P against the share of footprints all safe), the expected
calibration error, the log loss, the ranking's AUC, and per threshold the share of all-safe
footprints kept and the unsafe footprints passed::

    python scripts/site_probability.py runs/guard_eval [MORE_WORKDIRS...] [--radius 1.5]
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from scipy.optimize import minimize_scalar
from sklearn.metrics import roc_auc_score

from landing_zone.judging.sites import footprint_mask, site_probabilities
from landing_zone.tools.evaluate.flights import footprint_truth

BINS = (0.0, 0.1, 0.3, 0.5, 0.7, 0.8, 0.9, 0.95, 1.0)
THRESHOLDS = (0.5, 0.6, 0.7, 0.8, 0.9)


def footprints(workdir: Path, radius: float) -> list[tuple[str, np.ndarray, np.ndarray,
                                                           np.ndarray]]:
    """Per flight: condition, log product, log least P and truth of every judged footprint."""
    out = []
    files = sorted(f for f in workdir.glob('*.json') if not f.name.endswith('.labels.json'))
    if not files:
        sys.exit(f'site_probability: no flight results (*.json) in {workdir}')
    for f in files:
        with open(f, encoding='utf-8') as fh:
            flight = json.load(fh)
        tiles, ts = flight['tiles'], float(flight['tile_size'])
        ix = {x: i for i, x in enumerate(sorted({t['x'] for t in tiles}))}
        iy = {y: i for i, y in enumerate(sorted({t['y'] for t in tiles}))}
        p = np.full((len(ix), len(iy)), np.nan)
        safe = np.zeros_like(p)
        for t in tiles:
            i, j = ix[t['x']], iy[t['y']]
            p[i, j] = np.nan if t['p_safe'] is None else t['p_safe']
            safe[i, j] = float(t['safe'])
        # the site figures as judging.sites computes them (NaN where a tile is not judged); a
        # tile's P floored at 1e-12 so that the fitted power sees a finite log product
        least, mean, _ = site_probabilities(np.clip(p, 1e-12, 1.0), np.ones_like(p), radius, ts)
        judged = np.isfinite(least)
        n_tiles = int(footprint_mask(radius, ts).sum())
        log_prod, log_min = n_tiles * np.log(mean[judged]), np.log(least[judged])
        truth = footprint_truth(safe.astype(np.int8), radius, ts)
        out.append((str(flight['condition']), log_prod, log_min, truth[judged]))
    return out


def log_loss(p: np.ndarray, t: np.ndarray) -> float:
    p = np.clip(p, 1e-9, 1 - 1e-9)
    return float(-(t * np.log(p) + (1 - t) * np.log(1 - p)).mean())


def fit_power(log_prod: np.ndarray, truth: np.ndarray) -> float:
    """The k in (0.01, 1] of least log loss for P = product^k."""
    res = minimize_scalar(lambda k: log_loss(np.exp(k * log_prod), truth), bounds=(0.01, 1.0),
                          method='bounded')
    return float(res.x)


def report(name: str, p: np.ndarray, t: np.ndarray) -> None:
    edges = np.digitize(p, BINS[1:-1])
    ece = sum(abs(p[edges == b].mean() - t[edges == b].mean()) * (edges == b).sum()
              for b in range(len(BINS) - 1) if (edges == b).any()) / len(p)
    auc = roc_auc_score(t, p) if 0 < t.sum() < len(t) else float('nan')
    print(f'{name}: ECE {ece:.3f}, log loss {log_loss(p, t):.3f}, AUC {auc:.4f}')
    for b in range(len(BINS) - 1):
        m = edges == b
        if m.any():
            print(f'  P in [{BINS[b]:.2f}, {BINS[b + 1]:.2f}): {m.sum():5d} footprints, mean P '
                  f'{p[m].mean():.3f}, all safe {t[m].mean():.3f}')
    pos = t == 1
    for th in THRESHOLDS:
        print(f'  P >= {th}: {(p[pos] >= th).mean():6.1%} of the all-safe footprints kept, '
              f'{int((p[~pos] >= th).sum())} of {int((~pos).sum())} unsafe passed')


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n', 1)[0])
    ap.add_argument('workdirs', nargs='+', type=Path, help='guard_eval.py workdirs')
    ap.add_argument('--radius', type=float, default=1.5, help='footprint radius [m]')
    args = ap.parse_args(argv)
    for wd in args.workdirs:
        if not wd.is_dir():
            sys.exit(f'site_probability: {wd} is not a directory')
        flights = footprints(wd, args.radius)
        conds = sorted({c for c, *_ in flights})
        prod, power, least, truth, ks = [], [], [], [], []
        for held in conds:
            train = [f for f in flights if f[0] != held]
            test = [f for f in flights if f[0] == held]
            k = fit_power(np.concatenate([f[1] for f in train]),
                          np.concatenate([f[3] for f in train])) if train else 1.0
            ks.append(k)
            lp = np.concatenate([f[1] for f in test])
            prod.append(np.exp(lp))
            power.append(np.exp(k * lp))
            least.append(np.exp(np.concatenate([f[2] for f in test])))
            truth.append(np.concatenate([f[3] for f in test]))
        t = np.concatenate(truth)
        print(f'== {wd}: {len(flights)} flights, {len(conds)} conditions, {len(t)} footprints, '
              f'{t.mean():.1%} all safe; k fitted without each condition '
              f'{min(ks):.3f}-{max(ks):.3f}')
        report('product', np.concatenate(prod), t)
        report('product^k (k fitted on the other conditions)', np.concatenate(power), t)
        report('least tile P (judging.sites)', np.concatenate(least), t)


if __name__ == '__main__':
    main()
