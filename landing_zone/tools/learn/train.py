"""Training the safety CNN on a simulated dataset, with augmentation on the fly.

Run::

    landing-zone train --data data/synth2 --out model.safetensors --epochs 6 --augment-copies 10 \
        --cache-voxels 5 --workers 2                         # the shipped model, on 2 CPU cores
    landing-zone train --data data/synth2 --arch C7-F32-P2-C5-F64-P2-D512 --out paper.safetensors
    landing-zone train --data data/synth2 --out model.safetensors --resume    # carry on
    landing-zone train --data data/synth2 --out m.safetensors --device cuda --workers 15 \\
        --cache-voxels 20                                                     # a GPU box

Every sample is one scene's returns re-voxelized by
:func:`landing_zone.judging.patches.scene_to_input` after a random yaw about the tile centre and a
random vertical shift, so the net sees exactly
what the deployed map would give it. The randomness of sample ``(epoch, scene, copy)`` comes
from ``SeedSequence([seed, epoch, scene, copy])``, not from the worker that makes it, and the
batch order of an epoch from ``(seed, epoch)``, so the same seed gives the same model on the
same machine and thread count, whatever the number of workers, and a resumed run continues
exactly where the interrupted one stopped.

Files beside ``--out`` (for ``model.safetensors``):

- ``model.safetensors``: the final model (weights, spec, configs, metrics, temperature).
- ``model.train.safetensors``: the training state (weights, momentum, RNG, position), written
  after every epoch and every ``checkpoint_minutes``; ``--resume`` continues from it.
- ``model.log.csv``: one row per epoch: train loss, validation loss and AUC, time.

Fine-tuning (``init``, e.g. to a site: docs/SITE_ADAPTATION.md) is conservative by default:
the loss penalises every obstacle sample the net judges safer than the initial net does
(:mod:`landing_zone.tools.learn.leniency`), and the model keeps the initial model's calibration
(fitted on families it never saw), its offset lowered where the validation obstacles need it
(:mod:`landing_zone.tools.learn.guarded_calibration`); a temperature refitted on the validation
scenes would hold on the training families only.
"""
from __future__ import annotations

import math
import os
import sys
import time
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from landing_zone.tools.learn.calibration import binary_nll, expected_calibration_error, fit_temperature
from landing_zone.config import MapConfig, TileConfig
from landing_zone.errors import ConfigError, DatasetError, ModelError
from landing_zone.judging.checkpoint import load_model, read_metadata, save_model
from landing_zone.judging.inference import bf16_supported, predict
from landing_zone.judging.ensemble import AnyNet, SafetyEnsemble
from landing_zone.judging.net import DEFAULT_SPEC, SafetyNet, SafetyNetConfig
from landing_zone.judging.tiles import tile_voxels
from landing_zone.tools.learn.guard_sets import check_held_out, guard_offset, load_guard_sets
from landing_zone.tools.learn.samples import (AugmentedVolumes, EpochSampler, VoxelCache, make_loader,
                                        voxelize)
from landing_zone.tools.learn.scenes import (ScenePack, labels_of, open_source, part_names, part_of,
                                       split_scenes)
from landing_zone.tools.learn.state import load_state, log_path, save_state, state_path, write_log

__all__ = ['TrainConfig', 'train', 'roc_auc', 'train_config_from', 'describe']

# -----------------------------------------------------------------------------------------------
# defaults (the paper's, Sec. IV-C, unless noted)


@dataclass
class TrainConfig:
    """How to train; stored in the checkpoint."""

    arch: str = field(default=DEFAULT_SPEC, metadata={'help': 'Network spec (judging.spec).'})
    epochs: int = field(default=6, metadata={'help': 'Passes over the augmented training set.'})
    lr: float = field(default=0.01, metadata={'help': 'SGD learning rate.'})
    lr_schedule: str = field(default='constant', metadata={
        'choices': ('constant', 'cosine'),
        'help': "constant (the paper's) or cosine (the rate falls to 0 over the run)."})
    momentum: float = field(default=0.9, metadata={'help': 'SGD momentum.'})
    weight_decay: float = field(default=5e-4, metadata={'help': 'L2 penalty.'})
    batch_size: int = field(default=20, metadata={'help': 'Samples per minibatch.'})
    augment_copies: int = field(default=20, metadata={
        'help': 'Augmented samples of every scene per epoch.'})
    max_samples: int = field(default=0, metadata={'help': 'Cap on samples per epoch (0: none).'})
    max_scenes: int = field(default=0, metadata={
        'help': 'An even subset of this many scenes, whole twin pairs (0: all): bounds memory.'})
    val_fraction: float = field(default=0.1, metadata={
        'help': 'Share of training scenes held out for validation and calibration.'})
    workers: int = field(default=0, metadata={'help': 'Data loader processes (0: in-process).'})
    seed: int = field(default=0, metadata={'help': 'Seed of init, split and augmentation.'})
    device: str = field(default='cpu', metadata={'choices': ('cpu', 'cuda'),
                                                 'help': 'Where to train.'})
    dropout: float = field(default=0.5, metadata={'help': 'Dropout after each layer.'})
    z_shift: float = 0.3  # augmentation: vertical shift uniform in [-z_shift, z_shift] [m]
    yaw: bool = True  # augmentation: yaw uniform in [0, 2 pi)
    edge_drop: float = field(default=0.3, metadata={
        'help': 'Share of samples cut off beyond a random line, as at the edge of a scan.'})
    checkpoint_minutes: float = field(default=10.0, metadata={
        'help': 'Also save the training state this often within an epoch.'})
    cache_voxels: int = field(default=0, metadata={
        'help': 'Pre-voxelize this many augmented copies per scene once (0: on the fly).'})
    precision: str = field(default='auto', metadata={'help': 'auto (bf16 on CUDA), fp32 or bf16.'})
    hold_out: list[str] = field(default_factory=list, metadata={
        'help': 'Leave a family out of training, AXIS:FAMILY (obstacle:log, vegetation:lodged, '
                'terrain:sloped, sensor:rosette; synth3 data); repeat for more.'})
    leniency_penalty: float = field(default=1.0, metadata={  # tools.learn.leniency
        'help': 'With --init: penalty on obstacles judged safer than by --init (0: none).'})
    calibration: str = field(default='auto', metadata={  # tools.learn.guarded_calibration
        'choices': ('auto', 'refit', 'guarded'),
        'help': "refit: T fitted on the validation scenes; guarded: the --init model's T and b, "
                'b lowered until no more validation obstacles pass; auto: guarded with --init.'})

    def validate(self) -> None:
        SafetyNetConfig(self.arch, dropout=self.dropout).validate()
        for name in ('epochs', 'batch_size', 'augment_copies'):
            if getattr(self, name) < 1:
                raise ConfigError(f'{name} must be >= 1, got {getattr(self, name)}')
        for name in ('max_samples', 'max_scenes', 'workers', 'seed', 'cache_voxels'):
            if getattr(self, name) < 0:
                raise ConfigError(f'{name} must be >= 0, got {getattr(self, name)}')
        for name in ('lr', 'momentum', 'weight_decay', 'z_shift', 'checkpoint_minutes',
                     'leniency_penalty'):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(f'{name} must be a non-negative number, got {v}')
        if self.lr <= 0:
            raise ConfigError(f'lr must be positive, got {self.lr}')
        if self.lr_schedule not in ('constant', 'cosine'):
            raise ConfigError(f"lr_schedule must be 'constant' or 'cosine', got "
                              f'{self.lr_schedule!r}')
        if not 0.0 <= self.edge_drop <= 1.0:
            raise ConfigError(f'edge_drop must lie in [0, 1], got {self.edge_drop}')
        if not 0.0 <= self.val_fraction < 1.0:
            raise ConfigError(f'val_fraction must lie in [0, 1), got {self.val_fraction}')
        if self.precision not in ('auto', 'fp32', 'bf16'):
            raise ConfigError(f"precision must be 'auto', 'fp32' or 'bf16', got "
                              f'{self.precision!r}')
        if self.calibration not in ('auto', 'refit', 'guarded'):
            raise ConfigError(f"calibration must be 'auto', 'refit' or 'guarded', got "
                              f'{self.calibration!r}')
        if not (self.device == 'cpu' or self.device.startswith('cuda')):
            raise ConfigError(f"device must be 'cpu' or 'cuda[:N]', got {self.device!r}")
        if self.device.startswith('cuda') and not torch.cuda.is_available():
            raise ConfigError(f'device {self.device!r} asked for, but CUDA is not available')
        from landing_zone.tools.evaluate.lofo import parse_hold_out
        parse_hold_out(self.hold_out)


# Fields that must match for --resume to continue a run (epochs may grow; workers, device,
# precision and checkpointing may change, though a different device or thread count changes
# the floating-point results).
_RESUME_KEYS = ('arch', 'lr', 'lr_schedule', 'momentum', 'weight_decay', 'batch_size',
                'augment_copies', 'max_samples', 'val_fraction', 'seed', 'dropout', 'z_shift',
                'yaw', 'cache_voxels', 'edge_drop', 'hold_out', 'max_scenes', 'leniency_penalty')

# -----------------------------------------------------------------------------------------------
# the loop


def roc_auc(labels: np.ndarray, scores: np.ndarray) -> float:
    """Area under the ROC curve with "safe" (label 1) as the positive class; NaN for one
    class."""
    y = np.asarray(labels).reshape(-1)
    if y.size == 0 or y.min() == y.max():
        return float('nan')
    from sklearn.metrics import roc_auc_score
    return float(roc_auc_score(y, np.asarray(scores, np.float64).reshape(-1)))


@dataclass
class _Data:
    train: ScenePack
    val: ScenePack
    source: str
    map_cfg: MapConfig
    tile_cfg: TileConfig
    val_inputs: torch.Tensor = field(default_factory=lambda: torch.zeros(0))
    val_labels: torch.Tensor = field(default_factory=lambda: torch.zeros(0))
    val_groups: np.ndarray = field(default_factory=lambda: np.zeros(0, np.int64))


def _autocast(device: torch.device, use_bf16: bool):
    if use_bf16:
        return torch.autocast(device_type=device.type, dtype=torch.bfloat16)
    return torch.autocast(device_type=device.type, enabled=False)


def _evaluate(model: AnyNet, inputs: torch.Tensor, labels: torch.Tensor, precision: str
              ) -> tuple[np.ndarray, float, float]:
    if len(inputs) == 0:
        return np.zeros(0), float('nan'), float('nan')
    model.eval()
    logits = predict(model, inputs, batch_size=128, precision=precision, logits=True)
    y = labels.numpy()
    return logits, binary_nll(logits, y), roc_auc(y, logits)


def train(data: Any, out: str | os.PathLike, config: TrainConfig | None = None,
          resume: bool = False, init: str | os.PathLike | None = None,
          map_cfg: MapConfig | None = None, tile_cfg: TileConfig | None = None,
          progress: bool = True, guard_data: Any = None) -> dict[str, Any]:
    """Train a net and write it (calibrated) to ``out``.

    Args:
        data: a dataset directory (its train split is used), a list of them (their train
            splits one after the other, see :class:`ConcatScenes`) or a sequence of scenes.
        out: the model file to write (``.safetensors``); the training state and the CSV log go
            beside it (:func:`state_path`, :func:`log_path`).
        config: training parameters; default :class:`TrainConfig()`.
        resume: continue from the training state beside ``out`` if there is one.
        init: start from the weights of this model (same spec; an ensemble is fine-tuned as
            one net) instead of random ones; then
            by default the loss penalises obstacle samples judged safer than this model judges
            them (``config.leniency_penalty``) and the model keeps its calibration, guarded on
            the validation obstacles (``config.calibration``).
        map_cfg: voxel size of the inputs (default MapConfig()).
        tile_cfg: tiling of the inputs (default TileConfig()).
        progress: show progress bars on stderr.
        guard_data: with the guarded calibration: a dataset directory, or a list of datasets
            (directories or scene sequences; a directory's train split), never trained on,
            whose obstacle scenes the guard also holds on, each set a group of its own:
            families the fine-tuning must not grow lenient on though it never sees them, e.g.
            thin open structure while adapting to a site's sparse grass.

    Returns:
        Summary: epochs, samples, seconds, the last validation figures, the temperature.

    Raises:
        ConfigError, DatasetError, ModelError: bad parameters, data or model files.
    """
    cfg = config if config is not None else TrainConfig()
    cfg.validate()
    calibration = cfg.calibration if cfg.calibration != 'auto' else \
        ('guarded' if init is not None else 'refit')
    if calibration == 'guarded' and init is None:
        raise ConfigError("calibration 'guarded' keeps the initial model's calibration: give "
                          'an initial model (--init)')
    if guard_data is not None and calibration != 'guarded':
        raise ConfigError('guard data serve the guarded calibration only: fine-tune with '
                          '--init and the guarded calibration')
    check_held_out(guard_data, data)
    mcfg = map_cfg if map_cfg is not None else MapConfig()
    mcfg.validate()
    tcfg = tile_cfg if tile_cfg is not None else TileConfig()
    side = tile_voxels(mcfg.voxel_size, tcfg) + 2 * tcfg.padding
    out = Path(out)
    spath, lpath = state_path(out), log_path(out)
    device = torch.device(cfg.device)
    # Measured on an H100 with the paper's net, channels-last, ms per sample for forward +
    # backward + SGD: batch 20 fp32 0.116, bf16 0.146; batch 128 fp32 0.094, bf16 0.080. On
    # CPUs bf16 was slower wherever measured (see judging.inference.Predictor).
    use_bf16 = cfg.precision == 'bf16' or (cfg.precision == 'auto' and device.type == 'cuda'
                                           and cfg.batch_size >= 64)
    eval_precision = 'bf16' if use_bf16 else 'fp32'
    if use_bf16 and device.type == 'cpu' and not bf16_supported():
        print('train: this CPU has no native bf16; bf16 will be slow', file=sys.stderr)

    # the data: validation scenes held out by scene, per class
    source, source_name = open_source(data)
    if cfg.hold_out:
        from landing_zone.tools.evaluate.lofo import hold_out
        source = hold_out(source, cfg.hold_out)
        source_name += f' without {", ".join(cfg.hold_out)}'
    if cfg.max_scenes and len(source) > cfg.max_scenes:
        from landing_zone.tools.evaluate.lofo import SceneSubset
        # twins (a safe scene and its unsafe copy) sit side by side: keep whole pairs
        keep = np.unique(np.linspace(0, len(source) // 2 - 1, max(cfg.max_scenes // 2, 1))
                         .round().astype(np.int64))
        source = SceneSubset(source, np.stack([2 * keep, 2 * keep + 1], 1).reshape(-1))
        source_name += f' ({len(source)} scenes of an even subset)'
    labels = labels_of(source)
    if len(labels) < 2:
        raise DatasetError(f'{source_name}: at least 2 training scenes needed, got '
                           f'{len(labels)}')
    train_idx, val_idx = split_scenes(labels, cfg.val_fraction, cfg.seed)
    if len(np.unique(labels[train_idx])) < 2:
        raise DatasetError(f'{source_name}: the training scenes must hold both classes')
    t_load = time.perf_counter()
    d = _Data(ScenePack.from_scenes(source, train_idx, progress, 'loading train scenes'),
              ScenePack.from_scenes(source, val_idx, progress, 'loading val scenes'),
              source_name, mcfg, tcfg, val_groups=part_of(source, val_idx))
    if cfg.workers:
        d.train.share_memory()
        d.val.share_memory()
    d.val_inputs, d.val_labels = voxelize(d.val, mcfg, tcfg, cfg.workers, progress,
                                          'voxelizing val')
    guard = load_guard_sets(guard_data, mcfg, tcfg, cfg.workers, progress) \
        if guard_data is not None else None
    load_seconds = time.perf_counter() - t_load

    # the net and the optimizer
    torch.manual_seed(cfg.seed)
    model: AnyNet = SafetyNet(SafetyNetConfig(cfg.arch, input_size=side, dropout=cfg.dropout))
    src = None
    if init is not None:
        src, _ = load_model(init, 'cpu')
        if src.spec != model.spec or src.config.input_size != side:
            raise ModelError(f'--init model {init} is {src.spec} on {src.config.input_size}^3 '
                             f'inputs, not {model.spec} on {side}^3')
        if isinstance(src, SafetyEnsemble):
            # an ensemble is fine-tuned as one net: the loss on its mean logit moves every
            # member (each keeps its own dropout)
            model = SafetyEnsemble([SafetyNet(SafetyNetConfig(cfg.arch, input_size=side,
                                                              dropout=cfg.dropout))
                                    for _ in range(src.size)])
        model.load_state_dict(src.state_dict())
    model = model.to(device=device, memory_format=torch.channels_last_3d)
    penalty = None
    if src is not None and cfg.leniency_penalty > 0:
        from landing_zone.tools.learn.leniency import LeniencyPenalty
        penalty = LeniencyPenalty(src, cfg.leniency_penalty, device)
    opt = torch.optim.SGD(model.parameters(), lr=cfg.lr, momentum=cfg.momentum,
                          weight_decay=cfg.weight_decay)

    run: dict[str, Any] = {'epoch': 0, 'step': 0, 'samples': 0, 'loss_sum': 0.0, 'loss_n': 0,
                           'seconds': 0.0, 'data_wait': 0.0, 'log': [],
                           'config': asdict(cfg), 'source': source_name}
    if resume and spath.exists():
        state = load_state(spath, model, opt, device)
        old = state.get('config', {})
        # the cosine schedule spans the run's epochs: another count would bend it
        keys = _RESUME_KEYS + (('epochs',) if cfg.lr_schedule == 'cosine' else ())
        for key in keys:
            if key in old and old[key] != getattr(cfg, key):
                raise ConfigError(f'--resume: {key} was {old[key]!r} in {spath}, now '
                                  f'{getattr(cfg, key)!r}; use the same value or another --out')
        run.update({k: state[k] for k in run if k in state and k != 'config'})
        if progress:
            print(f'train: resuming {spath} at epoch {run["epoch"] + 1}, batch {run["step"]}',
                  file=sys.stderr)
    elif resume and progress:
        print(f'train: nothing to resume at {spath}; starting afresh', file=sys.stderr)

    # the samples: on the fly, or from a cache of pre-voxelized augmented copies
    vol_ds = AugmentedVolumes(d.train, mcfg, tcfg, cfg.seed, True, cfg.z_shift, cfg.yaw,
                              cfg.edge_drop)
    positions = np.arange(len(d.train))
    sampler = EpochSampler(positions, cfg.augment_copies, cfg.seed, cfg.max_samples)
    cache = None
    if cfg.cache_voxels:
        t0 = time.perf_counter()
        ci, cl = voxelize(d.train, mcfg, tcfg, cfg.workers, progress, 'caching voxels',
                          seed=cfg.seed, augment=True, copies=cfg.cache_voxels,
                          dtype=torch.float16, z_shift=cfg.z_shift, yaw=cfg.yaw,
                          edge_drop=cfg.edge_drop)
        cache = VoxelCache(ci, cl, cfg.cache_voxels)
        load_seconds += time.perf_counter() - t0
    loader = None if cache is not None else make_loader(
        vol_ds, sampler, cfg.batch_size, cfg.workers, pin_memory=device.type == 'cuda')

    from landing_zone.tools.evaluate.lofo import dataset_names
    meta_common = {'voxel_size': mcfg.voxel_size, 'tiles': asdict(tcfg), 'training':
                   asdict(cfg), 'seed': cfg.seed, 'source': source_name,
                   'datasets': dataset_names(source),
                   'n_train_scenes': len(d.train), 'n_val_scenes': len(d.val)}
    last_ckpt = time.monotonic()

    def checkpoint() -> None:
        save_state(spath, model, opt, device, {**run, 'config': asdict(cfg)})
        write_log(lpath, run['log'])

    for epoch in range(run['epoch'], cfg.epochs):
        start = run['step'] * cfg.batch_size
        sampler.set_epoch(epoch, start)
        model.train()
        n_batches = math.ceil(len(sampler) / cfg.batch_size)
        # the schedule's clock: batches of whole epochs (a resumed epoch's sampler is shorter)
        per_epoch = math.ceil((len(sampler) + start) / cfg.batch_size)
        bar = tqdm(total=n_batches, desc=f'epoch {epoch + 1}/{cfg.epochs}', unit='batch',
                   file=sys.stderr, disable=not progress)
        t_epoch = time.perf_counter()
        seconds0, wait0, samples0 = run['seconds'], run['data_wait'], run['samples']
        if cache is not None:
            rows = cache.rows(sampler.keys()[start:])
            batches = ((cache.inputs[rows[i:i + cfg.batch_size]].float(),
                        cache.labels[rows[i:i + cfg.batch_size]])
                       for i in range(0, len(rows), cfg.batch_size))
        else:
            batches = iter(loader)
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
            with _autocast(device, use_bf16):
                logits_b, loss = model(x, y)
                assert loss is not None
                if penalty is not None:
                    loss = loss + penalty(x, y, logits_b)
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
            now = time.perf_counter()
            run['seconds'] = seconds0 + (now - t_epoch)
            bar.update(1)
            bar.set_postfix(loss=f'{run["loss_sum"] / run["loss_n"]:.4f}', refresh=False)
            if (cfg.checkpoint_minutes
                    and time.monotonic() - last_ckpt > 60 * cfg.checkpoint_minutes):
                checkpoint()
                last_ckpt = time.monotonic()
            t_wait = time.perf_counter()
        bar.close()
        _, val_loss, val_auc = _evaluate(model, d.val_inputs, d.val_labels, eval_precision)
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
        checkpoint()
        last_ckpt = time.monotonic()

    # calibration on the held-out scenes, then the final model
    logits, val_loss, val_auc = _evaluate(model, d.val_inputs, d.val_labels, eval_precision)
    y_val = d.val_labels.numpy()
    calibration_meta: dict[str, Any] = {}
    if calibration == 'guarded':
        assert src is not None
        init_net = src.to(device)
        init_logits, _, _ = _evaluate(init_net, d.val_inputs, d.val_labels, eval_precision)
        set_logits = None
        if guard is not None:  # the same two nets on the guard sets
            set_logits = (_evaluate(model, guard.inputs, guard.labels, eval_precision)[0],
                          _evaluate(init_net, guard.inputs, guard.labels, eval_precision)[0])
        temperature = float(src.temperature)
        offset, record = guard_offset(logits, init_logits, y_val, d.val_groups,
                                      part_names(source, source_name), temperature,
                                      float(src.offset), guard, set_logits)
        calibration_meta = {'calibration': {'method': 'guarded', 'initial_model': str(init),
                                            **record}}
        if progress:
            lowest = min(record['groups'], key=lambda e: e['offset_limit'], default=None)
            by = f' (set by {lowest["source"]})' if lowest is not None and offset < src.offset \
                else ''
            print(f'train: calibration of {init} kept (T {temperature:.3f}), offset '
                  f'{src.offset:+.3f} -> {offset:+.3f}{by} so that no more reference obstacles '
                  'pass at P(safe) >= 0.5 or 0.9 than under it', file=sys.stderr)
    else:
        temperature = fit_temperature(logits, y_val) if len(logits) else 1.0
        offset = 0.0
    model.temperature, model.offset = temperature, offset
    p_val = 1.0 / (1.0 + np.exp(-(np.asarray(logits, np.float64) / temperature + offset)))
    metrics = {'val_auc': val_auc, 'val_loss': val_loss,
               'val_nll_calibrated': binary_nll(logits, y_val, temperature, offset)
               if len(logits)
               else float('nan'),
               'val_ece': expected_calibration_error(p_val, y_val) if len(logits)
               else float('nan'),
               'epochs': run['epoch'], 'samples': run['samples'],
               'train_seconds': round(run['seconds'], 2),
               'load_seconds': round(load_seconds, 2)}
    metrics = {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
               for k, v in metrics.items()}
    model_cpu = model.to('cpu', memory_format=torch.contiguous_format)
    model_cpu.temperature, model_cpu.offset = temperature, offset
    save_model(out, model_cpu, {**meta_common, 'metrics': metrics, **calibration_meta})
    return {'out': str(out), 'state': str(spath), 'log': str(lpath), 'spec': model_cpu.spec,
            'temperature': temperature, 'offset': offset, 'calibration': calibration, **metrics}


def train_config_from(**kwargs: Any) -> TrainConfig:
    """A TrainConfig from keyword options (unknown names are a ConfigError)."""
    names = {f.name for f in fields(TrainConfig)}
    bad = sorted(set(kwargs) - names)
    if bad:
        raise ConfigError(f'unknown training option {bad[0]!r}')
    return TrainConfig(**kwargs)


def describe(path: str | os.PathLike) -> str:
    """One line naming a model file's spec, metrics and temperature."""
    meta = read_metadata(path)
    m = meta.get('metrics', {})
    return (f'{path}: {meta["model"]["spec"]}, val AUC {m.get("val_auc")}, temperature '
            f'{meta.get("temperature")}')
