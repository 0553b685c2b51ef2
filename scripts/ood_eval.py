"""Does an out-of-distribution signal tell where the network is wrong? (measured, not shipped)

Candidates, each a score per tile (higher: further from what the network was trained on),
fitted on the training distribution only (a subsample of synth2's train split, as the shipped
model saw it, no augmentation):

* ``mahalanobis``: distance of the network's penultimate features (the dense layer's output)
  to the nearer of the two class means under their shared covariance (Lee et al., NeurIPS
  2018), with a small ridge so the 128 x 128 covariance inverts;
* ``knn``: distance of the L2-normalised penultimate features to their k-th nearest training
  feature (Sun et al., ICML 2022), k = 10: what :mod:`landing_zone.judging.ood` ships;
* ``density``: Mahalanobis distance of simple input statistics (share of occupied, free and
  unobserved voxels of the cube, mean input, returns in the column, observed fraction) to the
  training ones: the statistics-of-the-input idea, no network involved.

They are scored on the tiles of flights unlike the training set: the final density maps of
``scripts/guard_eval.py --keep-maps`` flights saved as ``.npz`` (``hits``, ``passes``, ``lo``,
``index``, ``ground_z``, ``p_safe`` the network's P(safe)) with their ``.labels.json``. A
tile's network judgement is an *error* when an obstacle tile gets P(safe) >= 0.5 or a safe one
P(safe) < 0.5. Printed per score: the AUROC of the score for errors (0.5 = no signal), and what
making the top-scoring tiles unknown would do at the score's 95th and 99th percentile on the
training set (share of tiles made unknown; obstacle tiles at P(safe) >= 0.5 among those still
judged; false alarms)::

    python scripts/ood_eval.py --train data/synth2 --scenes 1500 runs/x/*.npz --json ood.json

The shipped reference is not fitted here but by ``landing-zone fit-ood``
(:mod:`landing_zone.tools.learn.ood_fit`); this script measures the choice of score.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np


def penultimate(model: Any, inputs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(T, D) penultimate features and (T,) P(safe), as the assessor computes them."""
    from landing_zone.judging.inference import Predictor

    with Predictor(model) as predictor:
        p, f = predictor.with_features(inputs)
    return f.astype(np.float64), p


def input_stats(inputs: np.ndarray, n_returns: np.ndarray, observed: np.ndarray) -> np.ndarray:
    """(T, 6) statistics of the cubes the network reads."""
    x = inputs.reshape(len(inputs), -1)
    return np.column_stack([(x > 0.2).mean(1), (x < -0.2).mean(1), (x == 0).mean(1), x.mean(1),
                            np.log1p(n_returns), observed])


class Gaussian:
    """Class-conditional means with a shared covariance (or one class: labels all equal)."""

    def __init__(self, x: np.ndarray, y: np.ndarray, ridge: float = 1e-3) -> None:
        self.means = [x[y == c].mean(0) for c in np.unique(y)]
        centred = np.concatenate([x[y == c] - m for c, m in zip(np.unique(y), self.means)])
        cov = np.cov(centred, rowvar=False)
        cov += ridge * np.trace(cov) / len(cov) * np.eye(len(cov))
        self.precision = np.linalg.inv(cov)

    def __call__(self, x: np.ndarray) -> np.ndarray:
        d = [np.einsum('ij,jk,ik->i', x - m, self.precision, x - m) for m in self.means]
        return np.sqrt(np.min(d, axis=0))


class KNN:
    """The shipped signal (:class:`landing_zone.judging.ood.FeatureReference`) on ``x``."""

    def __init__(self, x: np.ndarray, k: int = 10) -> None:
        from landing_zone.judging.ood import FeatureReference, unit_rows
        self.ref = FeatureReference(unit_rows(x), k, 1.0, 100.0, '')

    def __call__(self, x: np.ndarray) -> np.ndarray:
        return self.ref.distance(x).astype(np.float64)


def training_reference(root: Path, scenes: int, model: Any) -> dict[str, np.ndarray]:
    """Features, statistics and labels of up to ``scenes`` training scenes (evenly spread)."""
    from landing_zone.judging.patches import scene_to_input
    from landing_zone.tools.sim.shards import SceneDataset

    ds = SceneDataset(root, 'train')
    pick = np.unique(np.linspace(0, len(ds) - 1, min(scenes, len(ds))).astype(int))
    inputs, labels, nret, obs = [], [], [], []
    for i in pick:
        sc = ds[int(i)]
        b = scene_to_input(sc.points, sc.origins)
        if not b.valid[0]:
            continue
        inputs.append(b.inputs[0])
        labels.append(sc.label)
        nret.append(b.n_returns[0])
        obs.append(b.observed_fraction[0])
    x = np.stack(inputs)
    f, p = penultimate(model, x)
    return {'features': f, 'stats': input_stats(x, np.array(nret), np.array(obs)),
            'labels': np.array(labels), 'p': p}


def flight_tiles(path: Path, model: Any, guard: bool) -> dict[str, np.ndarray]:
    """Features, statistics, labels and P(safe) of the judged, labelled tiles of one map
    (with ``guard``, P(safe) capped where the shipped guard fires)."""
    from landing_zone.config import GuardConfig, MapConfig, TileConfig
    from landing_zone.judging.ground import fit_ground
    from landing_zone.judging.guard import guard_p_safe, guard_tiles
    from landing_zone.judging.tiles import tile_voxels, tiles_from_counts

    d = np.load(path)
    labels = json.loads(Path(str(path)[:-4] + '.labels.json').read_text())
    truth = {(round(t['x'], 3), round(t['y'], 3)): bool(t['safe']) for t in labels['tiles']}
    # as the assessor cuts them: the ground planes first, the cubes aligned to them
    # (tiles.align_to_ground) and the guard above them
    tcfg = TileConfig()
    # the map's voxel (saved with it since guard_eval.py stores it; the default map's before)
    vs = float(d['voxel_size']) if 'voxel_size' in d.files else MapConfig().voxel_size
    tv = tile_voxels(vs, tcfg)
    ground = fit_ground(d['hits'], d['passes'], d['lo'], vs, d['index'], tv,
                        tcfg.occupied_density)
    b = tiles_from_counts(d['hits'], d['passes'], d['lo'], vs, tcfg, d['index'], ground)
    keys = [(round(x, 3), round(y, 3)) for x, y in b.centers.tolist()]
    keep = b.valid & np.array([k in truth for k in keys])
    x = b.inputs[keep]
    f, p = penultimate(model, x)
    if guard:
        g = guard_tiles((d['hits'], d['passes'], d['lo']), vs, b, ground, tv, GuardConfig())
        p = guard_p_safe(p, g[keep], GuardConfig())
    return {'flight': np.full(len(p), path.stem), 'features': f,
            'stats': input_stats(x, b.n_returns[keep], b.observed_fraction[keep]),
            'safe': np.array([truth[k] for k, m in zip(keys, keep) if m], bool), 'p': p}


def evaluate(score_train: np.ndarray, score: np.ndarray, p: np.ndarray, safe: np.ndarray
             ) -> dict[str, Any]:
    from sklearn.metrics import roc_auc_score

    err = (safe & (p < 0.5)) | (~safe & (p >= 0.5))
    miss = ~safe & (p >= 0.5)
    out: dict[str, Any] = {
        'auroc_errors': float(roc_auc_score(err, score)) if err.any() and (~err).any() else None,
        'auroc_passed_obstacles': (float(roc_auc_score(miss[(p >= 0.5)], score[p >= 0.5]))
                                   if miss.any() and (~miss[p >= 0.5]).any() else None)}
    for q in (95, 99, 99.5, 99.9):
        th = float(np.percentile(score_train, q))
        for rule, far in (('all', score > th), ('safe_only', (score > th) & (p >= 0.5))):
            known = ~far
            out[f'p{q} {rule}'] = {
                'unknown': float(far.mean()),
                'obstacle_ge_0.5': float((p[known & ~safe] >= 0.5).mean())
                if (known & ~safe).any() else None,
                'obstacle_ge_0.9': float((p[known & ~safe] >= 0.9).mean())
                if (known & ~safe).any() else None,
                'false_alarms': float((p[known & safe] < 0.5).mean())
                if (known & safe).any() else None,
                'passed_obstacles_made_unknown': int((miss & far).sum()),
                'passed_obstacles': int(miss.sum()),
                'safe_made_unknown': float(far[safe].mean()) if safe.any() else None}
    return out


def main() -> int:
    from landing_zone.assessor import default_model_path
    from landing_zone.judging.checkpoint import load_model

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('maps', nargs='*', type=Path, help='final maps (.npz) with labels beside')
    ap.add_argument('--train', type=Path, required=True, help='synth2 dataset directory')
    ap.add_argument('--scenes', type=int, default=1500)
    ap.add_argument('--model', type=Path, default=None)
    ap.add_argument('--guard', action='store_true', help='the guard caps P(safe) first')
    ap.add_argument('--json', type=Path, default=None)
    args = ap.parse_args()
    model_path = args.model or default_model_path()
    model, _ = load_model(model_path)
    ref = training_reference(args.train, args.scenes, model)
    if not args.maps:
        return 0
    flights = [flight_tiles(m, model, args.guard) for m in args.maps]
    tiles = {k: np.concatenate([f[k] for f in flights]) for k in flights[0]}
    results: dict[str, Any] = {'train_scenes': int(len(ref['labels'])),
                               'tiles': int(len(tiles['safe'])),
                               'obstacle_tiles': int((~tiles['safe']).sum()),
                               'obstacle_ge_0.5': float((tiles['p'][~tiles['safe']] >= 0.5)
                                                        .mean()),
                               'false_alarms': float((tiles['p'][tiles['safe']] < 0.5).mean())}
    # every score is fitted on one half of the training reference and its thresholds are
    # taken on the other half, as unseen training-like tiles would score
    a = np.arange(len(ref['labels'])) % 2 == 0
    fitted = {'mahalanobis': (Gaussian(ref['features'][a], ref['labels'][a]), 'features'),
              'knn': (KNN(ref['features'][a]), 'features'),
              'density': (Gaussian(ref['stats'][a], np.zeros(int(a.sum()))), 'stats')}
    for name, (fn, key) in fitted.items():
        train_score, score = fn(ref[key][~a]), fn(tiles[key])
        results[name] = evaluate(train_score, score, tiles['p'], tiles['safe'])
        # per flight: the share of its tiles past the 99th percentile (unknown must stay rare
        # where the data is good)
        th = float(np.percentile(train_score, 99))
        results[name]['unknown_p99_by_flight'] = {
            str(f): float((score[tiles['flight'] == f] > th).mean())
            for f in np.unique(tiles['flight'])}
    print(json.dumps(results, indent=1))
    if args.json is not None:
        args.json.write_text(json.dumps(results, indent=1) + '\n')
    return 0


if __name__ == '__main__':
    sys.exit(main())
