"""The fitting loop: epochs of SGD over the augmented samples, checkpointed and logged.

An epoch walks the sampler's batches (from the voxel cache, or voxelized on the fly by the
loader), steps the optimizer on the loss (plus the leniency penalty when fine-tuning), and ends
with the validation loss and AUC; the training state is saved after every epoch and every
``checkpoint_minutes``, so a resumed run continues exactly where the interrupted one stopped.
"""
from __future__ import annotations

import math
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from landing_zone.errors import ModelError
from landing_zone.judging.ensemble import AnyNet
from landing_zone.judging.inference import predict
from landing_zone.tools.learn.calibration import binary_nll
from landing_zone.tools.learn.samples import EpochSampler, VoxelCache

__all__ = ['Fit', 'evaluate_logits', 'autocast', 'run_epochs', 'roc_auc']


def roc_auc(labels: np.ndarray, scores: np.ndarray) -> float:
    """Area under the ROC curve with "safe" (label 1) as the positive class; NaN for one
    class."""
    y = np.asarray(labels).reshape(-1)
    if y.size == 0 or y.min() == y.max():
        return float('nan')
    from sklearn.metrics import roc_auc_score
    return float(roc_auc_score(y, np.asarray(scores, np.float64).reshape(-1)))


def autocast(device: torch.device, use_bf16: bool):  # type: ignore[no-untyped-def]
    """bf16 autocast on ``device``, or none."""
    if use_bf16:
        return torch.autocast(device_type=device.type, dtype=torch.bfloat16)
    return torch.autocast(device_type=device.type, enabled=False)


def evaluate_logits(model: AnyNet, inputs: torch.Tensor, labels: torch.Tensor, precision: str
                    ) -> tuple[np.ndarray, float, float]:
    """The net's logits on ``inputs``, their loss and AUC (NaN without inputs)."""
    if len(inputs) == 0:
        return np.zeros(0), float('nan'), float('nan')
    model.eval()
    logits = predict(model, inputs, batch_size=128, precision=precision, logits=True)
    y = labels.numpy()
    return logits, binary_nll(logits, y), roc_auc(y, logits)


@dataclass
class Fit:
    """What the loop works on: the net, its optimizer, the run's counters and log (``run``,
    saved in the training state) and where the batches come from."""

    model: AnyNet
    opt: torch.optim.Optimizer
    penalty: Any  # the leniency penalty, or None
    device: torch.device
    use_bf16: bool
    eval_precision: str
    cfg: Any  # the TrainConfig
    run: dict[str, Any]
    sampler: EpochSampler
    cache: VoxelCache | None
    loader: Any
    checkpoint: Callable[[], None]


def run_epochs(fit: Fit, val_inputs: torch.Tensor, val_labels: torch.Tensor,
               progress: bool) -> None:
    """Train from the run's epoch to ``cfg.epochs``, checkpointing as configured."""
    cfg, run = fit.cfg, fit.run
    last_ckpt = time.monotonic()
    for epoch in range(run['epoch'], cfg.epochs):
        start = run['step'] * cfg.batch_size
        fit.sampler.set_epoch(epoch, start)
        fit.model.train()
        t_epoch = time.perf_counter()
        seconds0, wait0, samples0 = run['seconds'], run['data_wait'], run['samples']
        last_ckpt = _one_epoch(fit, epoch, start, t_epoch, seconds0, last_ckpt, progress)
        _, val_loss, val_auc = evaluate_logits(fit.model, val_inputs, val_labels,
                                               fit.eval_precision)
        run['seconds'] = seconds0 + (time.perf_counter() - t_epoch)
        done = run['samples'] - samples0
        spent = run['seconds'] - seconds0
        run['log'].append({
            'epoch': epoch + 1, 'samples': run['samples'],
            'train_loss': round(run['loss_sum'] / max(run['loss_n'], 1), 6),
            'val_loss': round(val_loss, 6), 'val_auc': round(val_auc, 6),
            'seconds': round(run['seconds'], 2),
            'samples_per_s': round(done / spent, 2) if spent > 0 else '',
            'data_wait_s': round(run['data_wait'] - wait0, 2)})
        if progress:
            r = run['log'][-1]
            print(f'epoch {epoch + 1}: train loss {r["train_loss"]:.4f}, val loss '
                  f'{val_loss:.4f}, val AUC {val_auc:.4f}, {r["samples_per_s"]} samples/s',
                  file=sys.stderr)
        run.update(epoch=epoch + 1, step=0, loss_sum=0.0, loss_n=0)
        fit.checkpoint()
        last_ckpt = time.monotonic()


def _one_epoch(fit: Fit, epoch: int, start: int, t_epoch: float, seconds0: float,
               last_ckpt: float, progress: bool) -> float:
    """The batches of one epoch from sample ``start`` on; returns the last checkpoint's time."""
    cfg, run, device, opt = fit.cfg, fit.run, fit.device, fit.opt
    n_batches = math.ceil(len(fit.sampler) / cfg.batch_size)
    # the schedule's clock: batches of whole epochs (a resumed epoch's sampler is shorter)
    per_epoch = math.ceil((len(fit.sampler) + start) / cfg.batch_size)
    bar = tqdm(total=n_batches, desc=f'epoch {epoch + 1}/{cfg.epochs}', unit='batch',
               file=sys.stderr, disable=not progress)
    cache = fit.cache
    if cache is not None:
        rows = cache.rows(fit.sampler.keys()[start:])
        batches = ((cache.inputs[rows[i:i + cfg.batch_size]].float(),
                    cache.labels[rows[i:i + cfg.batch_size]])
                   for i in range(0, len(rows), cfg.batch_size))
    else:
        batches = iter(fit.loader)
    t_wait = time.perf_counter()
    for x, y in batches:
        run['data_wait'] += time.perf_counter() - t_wait
        x = x.to(device, non_blocking=True).contiguous(
            memory_format=torch.channels_last_3d)  # (B, 1, D, H, W)
        y = y.to(device, non_blocking=True)
        if cfg.lr_schedule == 'cosine':
            t = (epoch * per_epoch + run['step']) / (per_epoch * cfg.epochs)
            for group in opt.param_groups:
                group['lr'] = cfg.lr * 0.5 * (1.0 + math.cos(math.pi * min(t, 1.0)))
        with autocast(device, fit.use_bf16):
            logits_b, loss = fit.model(x, y)
            assert loss is not None
            if fit.penalty is not None:
                loss = loss + fit.penalty(x, y, logits_b)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        lv = float(loss.detach())
        if not math.isfinite(lv):
            raise ModelError(f'training diverged (loss {lv}) at epoch {epoch + 1}, batch '
                             f'{run["step"] + 1}; lower --lr')
        run['loss_sum'] += lv * len(x)
        run['loss_n'] += len(x)
        run['samples'] += len(x)
        run['step'] += 1
        run['seconds'] = seconds0 + (time.perf_counter() - t_epoch)
        bar.update(1)
        bar.set_postfix(loss=f'{run["loss_sum"] / run["loss_n"]:.4f}', refresh=False)
        if cfg.checkpoint_minutes and time.monotonic() - last_ckpt > 60 * cfg.checkpoint_minutes:
            fit.checkpoint()
            last_ckpt = time.monotonic()
        t_wait = time.perf_counter()
    bar.close()
    return last_ckpt
