"""Re-fit a model's calibration temperature on the validation scenes it was trained beside.

Used once for the shipped model, which was trained on a lent GPU machine before the
temperature fit got its prior (landing_zone.tools.learn.calibration.fit_temperature): the weights stay
bit-for-bit, only the temperature and the validation figures in the metadata change.

    python scripts/recalibrate.py MODEL DATA_DIR OUT [--val-fraction 0.1] [--seed 0]

DATA_DIR must be the dataset the model was trained on (same `simulate` arguments), so that
split_scenes() picks the same held-out scenes as training did.
"""
from __future__ import annotations

import argparse

import numpy as np

from landing_zone.tools.learn.calibration import binary_nll, expected_calibration_error, fit_temperature
from landing_zone.config import MapConfig, TileConfig
from landing_zone.judging.checkpoint import load_model, read_metadata, save_model
from landing_zone.judging.inference import predict
from landing_zone.tools.sim.shards import SceneDataset
from landing_zone.tools.learn.samples import voxelize
from landing_zone.tools.learn.scenes import ScenePack, split_scenes
from landing_zone.tools.learn.train import roc_auc


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument('model')
    ap.add_argument('data')
    ap.add_argument('out')
    ap.add_argument('--val-fraction', type=float, default=0.1)
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--workers', type=int, default=2)
    args = ap.parse_args()

    meta = read_metadata(args.model)
    model, _ = load_model(args.model)
    ds = SceneDataset(args.data, 'train')
    _, val_idx = split_scenes(np.asarray(ds.labels), args.val_fraction, args.seed)
    pack = ScenePack.from_scenes(ds, val_idx, True, 'loading val scenes')
    inputs, labels = voxelize(pack, MapConfig(), TileConfig(), args.workers, True)
    model.temperature = 1.0
    logits = predict(model, inputs.numpy(), precision='fp32', logits=True).astype(np.float64)
    y = labels.numpy()
    t = fit_temperature(logits, y)
    model.temperature = t
    p_cal = 1.0 / (1.0 + np.exp(-logits / t))
    metrics = dict(meta.get('metrics', {}))
    metrics.update(val_auc=roc_auc(y, logits), val_nll_calibrated=binary_nll(logits, y, t),
                   val_ece=expected_calibration_error(p_cal, y), val_scenes=int(len(y)))
    keep = {k: v for k, v in meta.items() if k not in ('format', 'model', 'temperature',
                                                       'metrics', 'weights_sha256')}
    save_model(args.out, model, {**keep, 'metrics': metrics})
    print(f'{args.out}: temperature {meta.get("temperature")} -> {t:.3f}; '
          f'val AUC {metrics["val_auc"]:.4f}, ECE {metrics["val_ece"]:.4f} on {len(y)} scenes')


if __name__ == '__main__':
    main()
