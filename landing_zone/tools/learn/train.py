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

Fine-tuning (``init``, e.g. to a site) is conservative by default:
the loss penalises every obstacle sample the net judges safer than the initial net does
(:mod:`landing_zone.tools.learn.leniency`), and the model keeps the initial model's calibration
(fitted on families it never saw), its offset lowered where the validation obstacles need it
(:mod:`landing_zone.tools.learn.anchored_calibration`); a temperature refitted on the validation
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

from landing_zone.config import MapConfig, TileConfig
from landing_zone.errors import ConfigError, DatasetError, ModelError
from landing_zone.judging.checkpoint import load_model, read_metadata, save_model
from landing_zone.judging.ensemble import AnyNet, SafetyEnsemble
from landing_zone.judging.inference import bf16_supported
from landing_zone.judging.net import DEFAULT_SPEC, SafetyNet, SafetyNetConfig
from landing_zone.judging.tiles import tile_voxels
from landing_zone.tools.evaluate.lofo import SceneSubset, dataset_names, hold_out, \
    parse_hold_out
from landing_zone.tools.learn.calibration import binary_nll, expected_calibration_error, \
    fit_temperature
from landing_zone.tools.learn.fitting import Fit, evaluate_logits, run_epochs
from landing_zone.tools.learn.anchor_sets import AnchorSets, check_held_out, anchor_offset, \
    load_anchor_sets
from landing_zone.tools.learn.leniency import LeniencyPenalty
from landing_zone.tools.learn.samples import AugmentedVolumes, EpochSampler, VoxelCache, \
    make_loader, voxelize
from landing_zone.tools.learn.scenes import ScenePack, labels_of, open_source, part_names, \
    part_of, split_scenes
from landing_zone.tools.learn.state import load_state, log_path, save_state, state_path, \
    write_log

__all__ = ['TrainConfig', 'train', 'train_config_from', 'describe']

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
    calibration: str = field(default='auto', metadata={  # tools.learn.anchored_calibration
        'choices': ('auto', 'refit', 'anchored'),
        'help': "refit: T fitted on the validation scenes; anchored: the --init model's T and b, "
                'b lowered until no more validation obstacles pass; auto: anchored with --init.'})

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
        if self.calibration not in ('auto', 'refit', 'anchored'):
            raise ConfigError(f"calibration must be 'auto', 'refit' or 'anchored', got "
                              f'{self.calibration!r}')
        if not (self.device == 'cpu' or self.device.startswith('cuda')):
            raise ConfigError(f"device must be 'cpu' or 'cuda[:N]', got {self.device!r}")
        if self.device.startswith('cuda') and not torch.cuda.is_available():
            raise ConfigError(f'device {self.device!r} asked for, but CUDA is not available')
        parse_hold_out(self.hold_out)


# Fields that must match for --resume to continue a run (epochs may grow; workers, device,
# precision and checkpointing may change, though a different device or thread count changes
# the floating-point results).
_RESUME_KEYS = ('arch', 'lr', 'lr_schedule', 'momentum', 'weight_decay', 'batch_size',
                'augment_copies', 'max_samples', 'val_fraction', 'seed', 'dropout', 'z_shift',
                'yaw', 'cache_voxels', 'edge_drop', 'hold_out', 'max_scenes', 'leniency_penalty')

# -----------------------------------------------------------------------------------------------
# the loop


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


def train(data: Any, out: str | os.PathLike, config: TrainConfig | None = None,
          resume: bool = False, init: str | os.PathLike | None = None,
          map_cfg: MapConfig | None = None, tile_cfg: TileConfig | None = None,
          progress: bool = True, anchor_data: Any = None) -> dict[str, Any]:
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
            them (``config.leniency_penalty``) and the model keeps its calibration, anchored on
            the validation obstacles (``config.calibration``).
        map_cfg: voxel size of the inputs (default MapConfig()).
        tile_cfg: tiling of the inputs (default TileConfig()).
        progress: show progress bars on stderr.
        anchor_data: with the anchored calibration: a dataset directory, or a list of datasets
            (directories or scene sequences; a directory's train split), never trained on,
            whose obstacle scenes the anchor also holds on, each set a group of its own:
            families the fine-tuning must not grow lenient on though it never sees them, e.g.
            thin open structure while adapting to a site's sparse grass.

    Returns:
        Summary: epochs, samples, seconds, the last validation figures, the temperature.

    Raises:
        ConfigError, DatasetError, ModelError: bad parameters, data or model files.
    """
    # the settings: training, calibration, inputs, precision
    cfg = config if config is not None else TrainConfig()
    cfg.validate()
    calibration = _calibration_method(cfg, init, anchor_data, data)
    mcfg = map_cfg if map_cfg is not None else MapConfig()
    mcfg.validate()
    tcfg = tile_cfg if tile_cfg is not None else TileConfig()
    side = tile_voxels(mcfg.voxel_size, tcfg) + 2 * tcfg.padding
    out = Path(out)
    spath, lpath = state_path(out), log_path(out)
    device = torch.device(cfg.device)
    use_bf16, eval_precision = _precision(cfg, device)
    # the data: validation scenes held out by scene, per class
    t_load = time.perf_counter()
    source, source_name, d = _load_data(data, cfg, mcfg, tcfg, progress)
    anchors = load_anchor_sets(anchor_data, mcfg, tcfg, cfg.workers, progress) \
        if anchor_data is not None else None
    load_seconds = time.perf_counter() - t_load
    # the net and the optimizer, resumed where a run stopped
    model, src, penalty, opt = _make_model(cfg, side, init, device)
    run: dict[str, Any] = {'epoch': 0, 'step': 0, 'samples': 0, 'loss_sum': 0.0, 'loss_n': 0,
                           'seconds': 0.0, 'data_wait': 0.0, 'log': [],
                           'config': asdict(cfg), 'source': source_name}
    _resume(run, resume, spath, model, opt, device, cfg, progress)
    # the samples: on the fly, or from a cache of pre-voxelized augmented copies
    sampler, cache, loader, cache_seconds = _samples(d, cfg, device, progress)
    load_seconds += cache_seconds

    def checkpoint() -> None:
        save_state(spath, model, opt, device, {**run, 'config': asdict(cfg)})
        write_log(lpath, run['log'])

    # the epochs
    fit = Fit(model, opt, penalty, device, use_bf16, eval_precision, cfg, run, sampler, cache,
              loader, checkpoint)
    run_epochs(fit, d.val_inputs, d.val_labels, progress)
    # calibration on the held-out scenes, then the final model
    logits, val_loss, val_auc = evaluate_logits(model, d.val_inputs, d.val_labels,
                                                eval_precision)
    temperature, offset, calibration_meta = _calibrate(
        calibration, model, src, init, logits, d, anchors, part_names(source, source_name),
        device, eval_precision, progress)
    model.temperature, model.offset = temperature, offset
    metrics = _metrics(logits, d.val_labels.numpy(), val_loss, val_auc, temperature, offset,
                       run, load_seconds)
    model_cpu = model.to('cpu', memory_format=torch.contiguous_format)
    model_cpu.temperature, model_cpu.offset = temperature, offset
    meta_common = {'voxel_size': mcfg.voxel_size, 'tiles': asdict(tcfg), 'training':
                   asdict(cfg), 'seed': cfg.seed, 'source': source_name,
                   'datasets': dataset_names(source),
                   'n_train_scenes': len(d.train), 'n_val_scenes': len(d.val)}
    save_model(out, model_cpu, {**meta_common, 'metrics': metrics, **calibration_meta})
    return {'out': str(out), 'state': str(spath), 'log': str(lpath), 'spec': model_cpu.spec,
            'temperature': temperature, 'offset': offset, 'calibration': calibration, **metrics}


def _calibration_method(cfg: TrainConfig, init: Any, anchor_data: Any, data: Any) -> str:
    """'anchored' or 'refit' (``cfg.calibration``'s 'auto' resolved), checked against the
    initial model and the anchor data."""
    calibration = cfg.calibration if cfg.calibration != 'auto' else \
        ('anchored' if init is not None else 'refit')
    if calibration == 'anchored' and init is None:
        raise ConfigError("calibration 'anchored' keeps the initial model's calibration: give "
                          'an initial model (--init)')
    if anchor_data is not None and calibration != 'anchored':
        raise ConfigError('anchor data serve the anchored calibration only: fine-tune with '
                          '--init and the anchored calibration')
    check_held_out(anchor_data, data)
    return calibration


def _precision(cfg: TrainConfig, device: torch.device) -> tuple[bool, str]:
    """Whether to train in bf16 autocast, and the precision of the evaluations."""
    # bf16 pays on a GPU only for large batches (at the paper's batch of 20 it is slower than
    # fp32), and on CPUs without native bf16 it falls back to slow kernels
    use_bf16 = cfg.precision == 'bf16' or (cfg.precision == 'auto' and device.type == 'cuda'
                                           and cfg.batch_size >= 64)
    if use_bf16 and device.type == 'cpu' and not bf16_supported():
        print('train: this CPU has no native bf16; bf16 will be slow', file=sys.stderr)
    return use_bf16, 'bf16' if use_bf16 else 'fp32'


def _load_data(data: Any, cfg: TrainConfig, mcfg: MapConfig, tcfg: TileConfig, progress: bool
               ) -> tuple[Any, str, _Data]:
    """The training source (families held out, an even subset), its scenes split into train and
    validation, and the validation scenes voxelized."""
    source, source_name = open_source(data)
    if cfg.hold_out:
        source = hold_out(source, cfg.hold_out)
        source_name += f' without {", ".join(cfg.hold_out)}'
    if cfg.max_scenes and len(source) > cfg.max_scenes:
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
    d = _Data(ScenePack.from_scenes(source, train_idx, progress, 'loading train scenes'),
              ScenePack.from_scenes(source, val_idx, progress, 'loading val scenes'),
              source_name, mcfg, tcfg, val_groups=part_of(source, val_idx))
    if cfg.workers:
        d.train.share_memory()
        d.val.share_memory()
    d.val_inputs, d.val_labels = voxelize(d.val, mcfg, tcfg, cfg.workers, progress,
                                          'voxelizing val')
    return source, source_name, d


def _make_model(cfg: TrainConfig, side: int, init: Any, device: torch.device
                ) -> tuple[AnyNet, AnyNet | None, Any, torch.optim.Optimizer]:
    """The net (random, or the initial model's weights), the initial model, the leniency
    penalty against it (or None) and the optimizer."""
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
        penalty = LeniencyPenalty(src, cfg.leniency_penalty, device)
    opt = torch.optim.SGD(model.parameters(), lr=cfg.lr, momentum=cfg.momentum,
                          weight_decay=cfg.weight_decay)
    return model, src, penalty, opt


def _resume(run: dict[str, Any], resume: bool, spath: Path, model: AnyNet,
            opt: torch.optim.Optimizer, device: torch.device, cfg: TrainConfig,
            progress: bool) -> None:
    """With ``resume``, take the run's position and the net's state from ``spath``."""
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


def _samples(d: _Data, cfg: TrainConfig, device: torch.device, progress: bool
             ) -> tuple[EpochSampler, VoxelCache | None, Any, float]:
    """The epochs' sampler and where its samples come from: a cache of pre-voxelized copies
    (``cache_voxels``) or a loader voxelizing on the fly; and the seconds the cache took."""
    mcfg, tcfg = d.map_cfg, d.tile_cfg
    vol_ds = AugmentedVolumes(d.train, mcfg, tcfg, cfg.seed, True, cfg.z_shift, cfg.yaw,
                              cfg.edge_drop)
    positions = np.arange(len(d.train))
    sampler = EpochSampler(positions, cfg.augment_copies, cfg.seed, cfg.max_samples)
    cache, seconds = None, 0.0
    if cfg.cache_voxels:
        t0 = time.perf_counter()
        ci, cl = voxelize(d.train, mcfg, tcfg, cfg.workers, progress, 'caching voxels',
                          seed=cfg.seed, augment=True, copies=cfg.cache_voxels,
                          dtype=torch.float16, z_shift=cfg.z_shift, yaw=cfg.yaw,
                          edge_drop=cfg.edge_drop)
        cache = VoxelCache(ci, cl, cfg.cache_voxels)
        seconds = time.perf_counter() - t0
    loader = None if cache is not None else make_loader(
        vol_ds, sampler, cfg.batch_size, cfg.workers, pin_memory=device.type == 'cuda')
    return sampler, cache, loader, seconds


def _calibrate(calibration: str, model: AnyNet, src: AnyNet | None, init: Any,
               logits: np.ndarray, d: _Data, anchors: AnchorSets | None, names: list[str],
               device: torch.device, eval_precision: str, progress: bool
               ) -> tuple[float, float, dict[str, Any]]:
    """The final model's temperature and offset, and what the model file records of them."""
    y_val = d.val_labels.numpy()
    if calibration != 'anchored':
        return (fit_temperature(logits, y_val) if len(logits) else 1.0), 0.0, {}
    assert src is not None
    init_net = src.to(device)
    init_logits, _, _ = evaluate_logits(init_net, d.val_inputs, d.val_labels, eval_precision)
    set_logits = None
    if anchors is not None:  # the same two nets on the anchor sets
        set_logits = (evaluate_logits(model, anchors.inputs, anchors.labels, eval_precision)[0],
                      evaluate_logits(init_net, anchors.inputs, anchors.labels, eval_precision)[0])
    temperature = float(src.temperature)
    offset, record = anchor_offset(logits, init_logits, y_val, d.val_groups, names, temperature,
                                   float(src.offset), anchors, set_logits)
    if progress:
        lowest = min(record['groups'], key=lambda e: e['offset_limit'], default=None)
        by = f' (set by {lowest["source"]})' if lowest is not None and offset < src.offset \
            else ''
        print(f'train: calibration of {init} kept (T {temperature:.3f}), offset '
              f'{src.offset:+.3f} -> {offset:+.3f}{by} so that no more reference obstacles '
              'pass at P(safe) >= 0.5 or 0.9 than under it', file=sys.stderr)
    return temperature, offset, {'calibration': {'method': 'anchored', 'initial_model': str(init),
                                                 **record}}


def _metrics(logits: np.ndarray, y_val: np.ndarray, val_loss: float, val_auc: float,
             temperature: float, offset: float, run: dict[str, Any], load_seconds: float
             ) -> dict[str, Any]:
    """The final validation figures and the run's totals (None for a figure not defined)."""
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
    return {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
            for k, v in metrics.items()}


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
