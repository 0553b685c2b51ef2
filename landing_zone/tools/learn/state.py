"""A training run's files beside its model: the resumable state and the CSV log.

``OUT.train.safetensors`` holds the weights, the optimizer's momentum, every RNG state and the
position in the epoch (safetensors, no pickle), so ``--resume`` continues exactly where an
interrupted run stopped; ``OUT.log.csv`` has one row per epoch.
"""
from __future__ import annotations

import csv
import os
from pathlib import Path
from typing import Any

import torch

from landing_zone.errors import ModelError
from landing_zone.judging.checkpoint import load_model, save_model
from landing_zone.judging.ensemble import AnyNet

__all__ = ['state_path', 'log_path', 'LOG_FIELDS', 'write_log', 'save_state', 'load_state']


def state_path(out: str | os.PathLike) -> Path:
    """The training state beside a model file (``m.safetensors`` -> ``m.train.safetensors``)."""
    p = Path(out)
    return p.with_name(p.name[:-len('.safetensors')] + '.train.safetensors'
                       if p.name.endswith('.safetensors') else p.name + '.train.safetensors')


def log_path(out: str | os.PathLike) -> Path:
    """The CSV log beside a model file (``m.safetensors`` -> ``m.log.csv``)."""
    p = Path(out)
    stem = p.name[:-len('.safetensors')] if p.name.endswith('.safetensors') else p.name
    return p.with_name(stem + '.log.csv')


LOG_FIELDS = ('epoch', 'samples', 'train_loss', 'val_loss', 'val_auc', 'seconds',
              'samples_per_s', 'data_wait_s')


def write_log(path: Path, rows: list[dict]) -> None:
    tmp = path.with_name(path.name + '.tmp')
    with open(tmp, 'w', newline='', encoding='utf-8') as f:
        w = csv.DictWriter(f, fieldnames=LOG_FIELDS)
        w.writeheader()
        for r in rows:
            w.writerow({k: r.get(k, '') for k in LOG_FIELDS})
    os.replace(tmp, path)


def _rng_tensors(device: torch.device) -> dict[str, torch.Tensor]:
    out = {'rng.torch': torch.get_rng_state()}
    if device.type == 'cuda':
        out['rng.cuda'] = torch.cuda.get_rng_state(device)
    return out


def save_state(path: Path, model: AnyNet, opt: torch.optim.Optimizer, device: torch.device,
               meta: dict[str, Any]) -> None:
    extra = _rng_tensors(device)
    names = {id(p): n for n, p in model.named_parameters()}
    for group in opt.param_groups:
        for p in group['params']:
            buf = opt.state.get(p, {}).get('momentum_buffer')
            if buf is not None:
                extra[f'optim.{names[id(p)]}'] = buf
    save_model(path, model, {'train_state': meta}, extra_tensors=extra)


def load_state(path: Path, model: AnyNet, opt: torch.optim.Optimizer,
               device: torch.device) -> dict[str, Any]:
    saved, meta, extra = load_model(path, device, with_extra=True)
    state = meta.get('train_state')
    if not isinstance(state, dict):
        raise ModelError(f'{path}: not a training state (no train_state in its metadata)')
    model.load_state_dict(saved.state_dict())
    params = dict(model.named_parameters())
    for name, buf in extra.items():
        if name.startswith('optim.'):
            p = params.get(name[len('optim.'):])
            if p is None or p.shape != buf.shape:
                raise ModelError(f'{path}: optimizer state {name!r} does not fit the model')
            opt.state[p]['momentum_buffer'] = buf.to(device)
    if 'rng.torch' in extra:
        torch.set_rng_state(extra['rng.torch'])
    if 'rng.cuda' in extra and device.type == 'cuda':
        torch.cuda.set_rng_state(extra['rng.cuda'], device)
    return state
