"""Training the safety CNN on a simulated dataset, with augmentation on the fly.

Run::

    landing-zone train --data data/synth2 --out model.safetensors --epochs 6 --augment-copies 10 \
        --cache-voxels 5 --workers 2                         # the shipped model, on 2 CPU cores
    landing-zone train --data data/synth2 --arch C7-F32-P2-C5-F64-P2-D512 --out paper.safetensors
    landing-zone train --data data/synth2 --out model.safetensors --resume    # carry on
    landing-zone train --data data/synth2 --out m.safetensors --device cuda --workers 15 \\
        --cache-voxels 20                                                     # a GPU box

Every sample is one scene's returns re-voxelized by :func:`landing_zone.tiles.scene_to_input`
after a random yaw about the tile centre and a random vertical shift, so the net sees exactly
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
"""
from __future__ import annotations

import csv
import math
import os
import sys
import time
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, Iterator

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, Sampler

from landing_zone.calibration import binary_nll, expected_calibration_error, fit_temperature
from landing_zone.config import MapConfig, TileConfig
from landing_zone.errors import ConfigError, DatasetError, ModelError
from landing_zone.model import (DEFAULT_SPEC, SafetyNet, SafetyNetConfig, bf16_supported,
                                load_model, predict, read_metadata, save_model)
from landing_zone.tiles import scene_to_input, tile_voxels

__all__ = ['TrainConfig', 'ScenePack', 'AugmentedVolumes', 'EpochSampler', 'split_scenes',
           'voxelize', 'train', 'state_path', 'log_path', 'roc_auc']

# -----------------------------------------------------------------------------------------------
# defaults (the paper's, Sec. IV-C, unless noted)


@dataclass
class TrainConfig:
    """How to train; stored in the checkpoint."""

    arch: str = DEFAULT_SPEC  # network spec (model.parse_spec)
    epochs: int = 6
    lr: float = 0.01  # SGD learning rate
    momentum: float = 0.9
    weight_decay: float = 5e-4  # L2 penalty
    batch_size: int = 20
    augment_copies: int = 20  # augmented samples of every training scene per epoch
    max_samples: int = 0  # cap on training samples per epoch (0 = no cap)
    val_fraction: float = 0.1  # share of the training scenes held out (per class)
    workers: int = 0  # DataLoader worker processes (0 = in the training process)
    seed: int = 0
    device: str = 'cpu'
    dropout: float = 0.5  # after every conv / dense layer
    z_shift: float = 0.3  # augmentation: vertical shift uniform in [-z_shift, z_shift] [m]
    yaw: bool = True  # augmentation: yaw uniform in [0, 2 pi)
    # augmentation: share of samples whose context is cut off beyond a random line in the
    # padding (one side, or two: a corner), as at the edge of a scanned area
    edge_drop: float = 0.3
    checkpoint_minutes: float = 10.0  # training state also saved this often within an epoch
    cache_voxels: int = 0  # >0: pre-voxelize this many augmented copies per scene once
    # 'auto': bf16 autocast on CUDA for batches of 64 or more, else fp32; 'fp32'; 'bf16'
    precision: str = 'auto'
    # families left out of the training scenes, 'AXIS:FAMILY' (synth3; see landing_zone.lofo)
    hold_out: list[str] = field(default_factory=list)

    def validate(self) -> None:
        SafetyNetConfig(self.arch, dropout=self.dropout).validate()
        for name in ('epochs', 'batch_size', 'augment_copies'):
            if getattr(self, name) < 1:
                raise ConfigError(f'{name} must be >= 1, got {getattr(self, name)}')
        for name in ('max_samples', 'workers', 'seed', 'cache_voxels'):
            if getattr(self, name) < 0:
                raise ConfigError(f'{name} must be >= 0, got {getattr(self, name)}')
        for name in ('lr', 'momentum', 'weight_decay', 'z_shift', 'checkpoint_minutes'):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(f'{name} must be a non-negative number, got {v}')
        if self.lr <= 0:
            raise ConfigError(f'lr must be positive, got {self.lr}')
        if not 0.0 <= self.edge_drop <= 1.0:
            raise ConfigError(f'edge_drop must lie in [0, 1], got {self.edge_drop}')
        if not 0.0 <= self.val_fraction < 1.0:
            raise ConfigError(f'val_fraction must lie in [0, 1), got {self.val_fraction}')
        if self.precision not in ('auto', 'fp32', 'bf16'):
            raise ConfigError(f"precision must be 'auto', 'fp32' or 'bf16', got "
                              f'{self.precision!r}')
        if not (self.device == 'cpu' or self.device.startswith('cuda')):
            raise ConfigError(f"device must be 'cpu' or 'cuda[:N]', got {self.device!r}")
        if self.device.startswith('cuda') and not torch.cuda.is_available():
            raise ConfigError(f'device {self.device!r} asked for, but CUDA is not available')
        from landing_zone.lofo import parse_hold_out
        parse_hold_out(self.hold_out)


# Fields that must match for --resume to continue a run (epochs may grow; workers, device,
# precision and checkpointing may change, though a different device or thread count changes
# the floating-point results).
_RESUME_KEYS = ('arch', 'lr', 'momentum', 'weight_decay', 'batch_size', 'augment_copies',
                'max_samples', 'val_fraction', 'seed', 'dropout', 'z_shift', 'yaw',
                'cache_voxels', 'edge_drop', 'hold_out')

# -----------------------------------------------------------------------------------------------
# data


class ScenePack:
    """The returns of many scenes in a few flat tensors, shareable with worker processes.

    Torch tensors in shared memory travel to ``spawn``-ed DataLoader workers as file handles,
    not copies, so a large training set is held once. Origins are stored once per run of equal
    rows (a scan line), which makes the pack about 2/3 the size of the expanded arrays.
    """

    def __init__(self, points: torch.Tensor, point_offsets: torch.Tensor,
                 origin_index: torch.Tensor, origins: torch.Tensor, labels: torch.Tensor,
                 params: list[dict], scene_ids: torch.Tensor) -> None:
        self.points = points  # (N, 3) float32
        self.point_offsets = point_offsets  # (S + 1,) int64
        self.origin_index = origin_index  # (N,) int64, row in `origins` (global)
        self.origins = origins  # (M, 3) float32
        self.labels = labels  # (S,) int64
        self.params = params
        self.scene_ids = scene_ids  # (S,) int64, the scene's index in its source

    @classmethod
    def from_scenes(cls, source: Any, indices: Sequence[int] | None = None,
                    progress: bool = False, desc: str = 'loading scenes') -> ScenePack:
        """Read scenes ``indices`` (default all) of a source with ``len`` and ``[i] -> Scene``.

        Raises:
            DatasetError: a scene has malformed arrays or a label other than 0 / 1.
        """
        idx = np.arange(len(source)) if indices is None else np.asarray(indices, np.int64)
        pts, oidx, orgs, labels, params = [], [], [], [], []
        offsets = [0]
        n_orig = 0
        bar = _bar(progress, total=len(idx), desc=desc, unit='scene', leave=False)
        for i in idx:
            if bar is not None:
                bar.update(1)
            s = source[int(i)]
            p = np.asarray(s.points, np.float32)
            o = np.asarray(s.origins, np.float32)
            if o.shape == (3,):
                o = np.broadcast_to(o, p.shape)
            if p.ndim != 2 or p.shape[1] != 3 or o.shape != p.shape:
                raise DatasetError(f'scene {int(i)}: points {p.shape} and origins {o.shape} must '
                                   'both be (N, 3)')
            if int(s.label) not in (0, 1):
                raise DatasetError(f'scene {int(i)}: label must be 0 or 1, got {s.label!r}')
            if len(o):
                new_run = np.ones(len(o), bool)
                new_run[1:] = np.any(o[1:] != o[:-1], axis=1)
                table = o[new_run]
                run = np.cumsum(new_run) - 1
            else:
                table, run = np.zeros((0, 3), np.float32), np.zeros(0, np.int64)
            pts.append(p)
            oidx.append(run + n_orig)
            orgs.append(table)
            n_orig += len(table)
            offsets.append(offsets[-1] + len(p))
            labels.append(int(s.label))
            params.append(dict(getattr(s, 'params', {}) or {}))
        if bar is not None:
            bar.close()
        cat = (lambda a, shape, dt: torch.from_numpy(np.concatenate(a).astype(dt, copy=False))
               if a else torch.zeros(shape, dtype=torch.from_numpy(np.zeros(0, dt)).dtype))
        return cls(cat(pts, (0, 3), np.float32), torch.tensor(offsets, dtype=torch.int64),
                   cat(oidx, (0,), np.int64), cat(orgs, (0, 3), np.float32),
                   torch.tensor(labels, dtype=torch.int64), params,
                   torch.from_numpy(idx.astype(np.int64)))

    def __len__(self) -> int:
        return int(self.labels.shape[0])

    def scene(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """(points, origins) of scene ``i``, both (N, 3) float32."""
        p0, p1 = int(self.point_offsets[i]), int(self.point_offsets[i + 1])
        pts = self.points[p0:p1].numpy()
        org = self.origins.numpy()[self.origin_index[p0:p1].numpy()]
        return pts, org

    def share_memory(self) -> ScenePack:
        for t in (self.points, self.point_offsets, self.origin_index, self.origins,
                  self.labels, self.scene_ids):
            t.share_memory_()
        return self


def split_scenes(labels: np.ndarray, val_fraction: float, seed: int
                 ) -> tuple[np.ndarray, np.ndarray]:
    """Hold out ``val_fraction`` of the scenes of each class (at least one of each when the
    class has two or more), chosen by ``seed``; returns sorted (train, val) positions."""
    labels = np.asarray(labels)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), 0x5A1]))
    val = []
    for c in (0, 1):
        members = np.flatnonzero(labels == c)
        k = int(round(val_fraction * len(members)))
        if val_fraction > 0 and len(members) >= 2:
            k = min(max(k, 1), len(members) - 1)
        val.append(rng.permutation(members)[:k])
    val_idx = np.sort(np.concatenate(val)).astype(np.int64)
    train_idx = np.setdiff1d(np.arange(len(labels)), val_idx).astype(np.int64)
    return train_idx, val_idx


class AugmentedVolumes(Dataset):
    """Sample ``(epoch, scene, copy)`` -> (input (1, S, S, S) float32, label float32).

    With ``augment`` the scene is rotated by a yaw uniform in [0, 2 pi) and shifted by a z
    uniform in [-z_shift, z_shift] drawn from ``SeedSequence([seed, epoch, scene, copy])``
    before re-voxelization; without it the scene is used as it is. With ``edge_drop`` > 0 that
    share of the samples also loses every return beyond a random line in the padding (two lines
    in a third of them: a corner), so the net sees tiles at the edge of a scanned area, whose
    context is partly unobserved, as the deployed map shows them; the tile itself and so its
    label are untouched.
    """

    def __init__(self, pack: ScenePack, map_cfg: MapConfig, tile_cfg: TileConfig, seed: int,
                 augment: bool = True, z_shift: float = 0.3, yaw: bool = True,
                 edge_drop: float = 0.0) -> None:
        self.pack = pack
        self.map_cfg = map_cfg
        self.tile_cfg = tile_cfg
        self.seed = int(seed)
        self.augment = augment
        self.z_shift = float(z_shift)
        self.yaw = bool(yaw)
        self.edge_drop = float(edge_drop)

    def __len__(self) -> int:
        return len(self.pack)

    def draw(self, epoch: int, scene: int, copy: int
             ) -> tuple[float, float, list[tuple[float, float]]]:
        """The (yaw, z shift, edge cuts) of one sample; a cut (angle, distance) drops the
        returns whose xy projection on the direction ``angle`` exceeds ``distance``."""
        if not self.augment:
            return 0.0, 0.0, []
        rng = np.random.default_rng(np.random.SeedSequence(
            [self.seed, int(epoch) + 1, int(scene), int(copy)]))  # epoch -1 (cache) -> 0
        yaw = float(rng.uniform(0.0, 2.0 * math.pi)) if self.yaw else 0.0
        dz = float(rng.uniform(-self.z_shift, self.z_shift)) if self.z_shift > 0 else 0.0
        cuts: list[tuple[float, float]] = []
        if self.edge_drop > 0 and rng.uniform() < self.edge_drop:
            half = self.tile_cfg.tile_size / 2
            reach = self.tile_cfg.padding * self.map_cfg.voxel_size
            angle = float(rng.uniform(0.0, 2.0 * math.pi))
            for k in range(2 if rng.uniform() < 1 / 3 else 1):
                # a corner: the second line at a right angle to the first
                cuts.append((angle + k * math.pi / 2, half + float(rng.uniform(0.0, reach))))
        return yaw, dz, cuts

    def __getitem__(self, key: tuple[int, int, int] | int) -> tuple[torch.Tensor, torch.Tensor]:
        epoch, scene, copy = (0, int(key), 0) if isinstance(key, (int, np.integer)) else key
        yaw, dz, cuts = self.draw(epoch, scene, copy)
        pts, org = self.pack.scene(scene)
        if cuts:
            pts, org = cut_context(pts, org, cuts)
        batch = scene_to_input(pts, org, self.map_cfg, self.tile_cfg, yaw=yaw, z_shift=dz)
        x = torch.from_numpy(batch.inputs[0])  # (1, S, S, S)
        return x, torch.tensor(float(self.pack.labels[scene]))


def cut_context(points: np.ndarray, origins: np.ndarray, cuts: list[tuple[float, float]]
                ) -> tuple[np.ndarray, np.ndarray]:
    """Drop the returns (and their origins, when given per return) beyond any of the lines
    ``cuts`` = [(angle, distance)] in the patch frame: kept where
    ``x cos(angle) + y sin(angle) <= distance`` for every cut."""
    keep = np.ones(len(points), bool)
    for angle, dist in cuts:
        keep &= points[:, 0] * math.cos(angle) + points[:, 1] * math.sin(angle) <= dist
    if np.ndim(origins) == 2 and len(origins) == len(points):
        origins = origins[keep]
    return points[keep], origins


class EpochSampler(Sampler):
    """Keys ``(epoch, scene, copy)`` of one epoch in a seeded order, from position ``start``.

    An epoch is every (scene, copy) pair of ``scenes`` x ``copies`` in an order drawn from
    ``(seed, epoch)``, cut to ``max_samples`` if that is set. Call :meth:`set_epoch` before
    iterating (the DataLoader may keep the sampler across epochs).
    """

    def __init__(self, scenes: np.ndarray, copies: int, seed: int, max_samples: int = 0
                 ) -> None:
        self.scenes = np.asarray(scenes, np.int64)
        self.copies = int(copies)
        self.seed = int(seed)
        self.max_samples = int(max_samples)
        self.epoch = 0
        self.start = 0

    def set_epoch(self, epoch: int, start: int = 0) -> None:
        self.epoch = int(epoch)
        self.start = int(start)

    def keys(self) -> np.ndarray:
        """(K, 3) keys of the whole epoch, in order."""
        total = len(self.scenes) * self.copies
        rng = np.random.default_rng(np.random.SeedSequence([self.seed, self.epoch, 0x0D3]))
        order = rng.permutation(total)
        if self.max_samples:
            order = order[:self.max_samples]
        return np.column_stack([np.full(len(order), self.epoch), self.scenes[order // self.copies],
                                order % self.copies])

    def __len__(self) -> int:
        total = len(self.scenes) * self.copies
        if self.max_samples:
            total = min(total, self.max_samples)
        return max(total - self.start, 0)

    def __iter__(self) -> Iterator[tuple[int, int, int]]:
        for row in self.keys()[self.start:]:
            yield int(row[0]), int(row[1]), int(row[2])


def _worker_init(_: int) -> None:
    # Each worker makes one sample at a time: one thread for numba and torch, so that W workers
    # use W cores and the training process keeps its own.
    import numba
    numba.set_num_threads(1)
    torch.set_num_threads(1)


def make_loader(dataset: Dataset, sampler: Sampler, batch_size: int, workers: int,
                pin_memory: bool = False) -> DataLoader:
    """A DataLoader over ``dataset`` in ``sampler``'s order.

    Workers are spawned, not forked: a forked child may not start numba's OpenMP threads once
    the parent has (it aborts), and the scene pack reaches spawned workers through shared
    memory anyway. They persist across epochs, since starting one costs seconds.
    """
    # A generator of its own keeps the loader from drawing its workers' base seed from the
    # global RNG, which drives dropout: a resumed run then draws the same masks.
    gen = torch.Generator().manual_seed(0)
    if workers == 0:
        return DataLoader(dataset, batch_size=batch_size, sampler=sampler, num_workers=0,
                          pin_memory=pin_memory, generator=gen)
    return DataLoader(dataset, batch_size=batch_size, sampler=sampler, num_workers=workers,
                      multiprocessing_context='spawn', persistent_workers=True,
                      worker_init_fn=_worker_init, pin_memory=pin_memory, prefetch_factor=4,
                      generator=gen)


def voxelize(pack: ScenePack, map_cfg: MapConfig, tile_cfg: TileConfig, workers: int = 0,
             progress: bool = False, desc: str = 'voxelizing', seed: int = 0,
             augment: bool = False, copies: int = 1, dtype: torch.dtype = torch.float32,
             z_shift: float = 0.3, yaw: bool = True, edge_drop: float = 0.0,
             ) -> tuple[torch.Tensor, torch.Tensor]:
    """Network inputs of every scene of a pack (``copies`` per scene, in scene order).

    Without ``augment`` each scene is re-voxelized as it is (evaluation, validation); with it
    copy ``c`` of scene ``s`` is augmented as sample ``(-1, s, c)`` of :class:`AugmentedVolumes`
    (the voxel cache).

    Returns:
        inputs (S * copies, 1, side, side, side) of ``dtype``, labels (S * copies,) float32.
    """
    ds = AugmentedVolumes(pack, map_cfg, tile_cfg, seed, augment=augment, z_shift=z_shift,
                          yaw=yaw, edge_drop=edge_drop)
    keys = [(-1, s, c) for s in range(len(pack)) for c in range(copies)]
    side = tile_voxels(map_cfg.voxel_size, tile_cfg) + 2 * tile_cfg.padding
    out = torch.empty((len(keys), 1, side, side, side), dtype=dtype)
    labels = torch.empty(len(keys), dtype=torch.float32)
    loader = make_loader(ds, keys, 64, workers)
    bar = _bar(progress, total=len(keys), desc=desc, unit='vol', leave=False)
    pos = 0
    for x, y in loader:
        out[pos:pos + len(x)] = x.to(dtype)
        labels[pos:pos + len(x)] = y
        pos += len(x)
        if bar is not None:
            bar.update(len(x))
    if bar is not None:
        bar.close()
    return out, labels


@dataclass
class _VoxelCache:
    """Pre-voxelized augmented copies: row ``scene * copies + c`` holds copy ``c`` of a scene;
    sample ``(epoch, scene, copy)`` reads copy ``copy mod copies``."""

    inputs: torch.Tensor  # (S * copies, 1, side, side, side) float16
    labels: torch.Tensor  # (S * copies,) float32
    copies: int

    def rows(self, keys: np.ndarray) -> np.ndarray:
        return keys[:, 1] * self.copies + keys[:, 2] % self.copies


def roc_auc(labels: np.ndarray, scores: np.ndarray) -> float:
    """Area under the ROC curve with "safe" (label 1) as the positive class; NaN for one
    class."""
    y = np.asarray(labels).reshape(-1)
    if y.size == 0 or y.min() == y.max():
        return float('nan')
    from sklearn.metrics import roc_auc_score
    return float(roc_auc_score(y, np.asarray(scores, np.float64).reshape(-1)))


def _bar(enabled: bool, **kw: Any) -> Any:
    """A tqdm bar on stderr, or None when disabled or tqdm is not installed (training boxes
    may have only torch, numpy, numba, scipy and scikit-learn)."""
    if not enabled:
        return None
    try:
        from tqdm import tqdm
    except ImportError:
        return None
    return tqdm(file=sys.stderr, **kw)


# -----------------------------------------------------------------------------------------------
# files


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


_LOG_FIELDS = ('epoch', 'samples', 'train_loss', 'val_loss', 'val_auc', 'seconds',
               'samples_per_s', 'data_wait_s')


def _write_log(path: Path, rows: list[dict]) -> None:
    tmp = path.with_name(path.name + '.tmp')
    with open(tmp, 'w', newline='', encoding='utf-8') as f:
        w = csv.DictWriter(f, fieldnames=_LOG_FIELDS)
        w.writeheader()
        for r in rows:
            w.writerow({k: r.get(k, '') for k in _LOG_FIELDS})
    os.replace(tmp, path)


def _rng_tensors(device: torch.device) -> dict[str, torch.Tensor]:
    out = {'rng.torch': torch.get_rng_state()}
    if device.type == 'cuda':
        out['rng.cuda'] = torch.cuda.get_rng_state(device)
    return out


def _save_state(path: Path, model: SafetyNet, opt: torch.optim.Optimizer, device: torch.device,
                meta: dict[str, Any]) -> None:
    extra = _rng_tensors(device)
    names = {id(p): n for n, p in model.named_parameters()}
    for group in opt.param_groups:
        for p in group['params']:
            buf = opt.state.get(p, {}).get('momentum_buffer')
            if buf is not None:
                extra[f'optim.{names[id(p)]}'] = buf
    save_model(path, model, {'train_state': meta}, extra_tensors=extra)


def _load_state(path: Path, model: SafetyNet, opt: torch.optim.Optimizer,
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


class ConcatScenes:
    """Several scene sources as one (``len``, ``[i] -> Scene``, ``labels``), in order: e.g. a
    site's hybrid set with some synth2 scenes, so fine-tuning does not forget what it knew."""

    def __init__(self, sources: Sequence[Any]) -> None:
        self.sources = list(sources)
        self.labels = np.concatenate([_labels_of(s) for s in self.sources]) \
            if self.sources else np.zeros(0, np.int64)
        self._ends = np.cumsum([len(s) for s in self.sources])

    def __len__(self) -> int:
        return int(self._ends[-1]) if len(self._ends) else 0

    def __getitem__(self, i: int) -> Any:
        if not 0 <= i < len(self):
            raise IndexError(f'scene {i} out of range ({len(self)} scenes)')
        k = int(np.searchsorted(self._ends, i, side='right'))
        return self.sources[k][i - (int(self._ends[k - 1]) if k else 0)]


def _open_source(data: Any) -> tuple[Any, str]:
    if isinstance(data, (str, os.PathLike)):
        from landing_zone.sim.dataset import SceneDataset
        return SceneDataset(data, 'train'), str(data)
    if isinstance(data, (list, tuple)) and data and all(
            isinstance(d, (str, os.PathLike)) for d in data):
        if len(data) == 1:
            return _open_source(data[0])
        opened = [_open_source(d) for d in data]
        return ConcatScenes([o[0] for o in opened]), ' + '.join(o[1] for o in opened)
    if not hasattr(data, '__len__') or not hasattr(data, '__getitem__'):
        raise DatasetError('data must be a dataset directory (or a list of them) or a sequence '
                           'of scenes')
    return data, type(data).__name__


def _labels_of(source: Any) -> np.ndarray:
    labels = getattr(source, 'labels', None)
    if labels is not None and len(labels) == len(source):
        return np.asarray(labels, np.int64)
    return np.array([int(source[i].label) for i in range(len(source))], np.int64)


def _autocast(device: torch.device, use_bf16: bool):
    if use_bf16:
        return torch.autocast(device_type=device.type, dtype=torch.bfloat16)
    return torch.autocast(device_type=device.type, enabled=False)


def _evaluate(model: SafetyNet, inputs: torch.Tensor, labels: torch.Tensor, precision: str
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
          progress: bool = True) -> dict[str, Any]:
    """Train a net and write it (calibrated) to ``out``.

    Args:
        data: a dataset directory (its train split is used), a list of them (their train
            splits one after the other, see :class:`ConcatScenes`) or a sequence of scenes.
        out: the model file to write (``.safetensors``); the training state and the CSV log go
            beside it (:func:`state_path`, :func:`log_path`).
        config: training parameters; default :class:`TrainConfig()`.
        resume: continue from the training state beside ``out`` if there is one.
        init: start from the weights of this model (same spec) instead of random ones.
        map_cfg: voxel size of the inputs (default MapConfig()).
        tile_cfg: tiling of the inputs (default TileConfig()).
        progress: show progress bars on stderr.

    Returns:
        Summary: epochs, samples, seconds, the last validation figures, the temperature.

    Raises:
        ConfigError, DatasetError, ModelError: bad parameters, data or model files.
    """
    cfg = config if config is not None else TrainConfig()
    cfg.validate()
    mcfg = map_cfg if map_cfg is not None else MapConfig()
    mcfg.validate()
    tcfg = tile_cfg if tile_cfg is not None else TileConfig()
    side = tile_voxels(mcfg.voxel_size, tcfg) + 2 * tcfg.padding
    out = Path(out)
    spath, lpath = state_path(out), log_path(out)
    device = torch.device(cfg.device)
    # Measured on an H100 with the paper's net, channels-last, ms per sample for forward +
    # backward + SGD: batch 20 fp32 0.116, bf16 0.146; batch 128 fp32 0.094, bf16 0.080. On
    # CPUs bf16 was slower wherever measured (see model.predict).
    use_bf16 = cfg.precision == 'bf16' or (cfg.precision == 'auto' and device.type == 'cuda'
                                           and cfg.batch_size >= 64)
    eval_precision = 'bf16' if use_bf16 else 'fp32'
    if use_bf16 and device.type == 'cpu' and not bf16_supported():
        print('train: this CPU has no native bf16; bf16 will be slow', file=sys.stderr)

    # the data: validation scenes held out by scene, per class
    source, source_name = _open_source(data)
    if cfg.hold_out:
        from landing_zone.lofo import hold_out
        source = hold_out(source, cfg.hold_out)
        source_name += f' without {", ".join(cfg.hold_out)}'
    labels = _labels_of(source)
    if len(labels) < 2:
        raise DatasetError(f'{source_name}: at least 2 training scenes needed, got '
                           f'{len(labels)}')
    train_idx, val_idx = split_scenes(labels, cfg.val_fraction, cfg.seed)
    if len(np.unique(labels[train_idx])) < 2:
        raise DatasetError(f'{source_name}: the training scenes must hold both classes')
    t_load = time.perf_counter()
    d = _Data(ScenePack.from_scenes(source, train_idx, progress, 'loading train scenes'),
              ScenePack.from_scenes(source, val_idx, progress, 'loading val scenes'),
              source_name, mcfg, tcfg)
    if cfg.workers:
        d.train.share_memory()
        d.val.share_memory()
    d.val_inputs, d.val_labels = voxelize(d.val, mcfg, tcfg, cfg.workers, progress,
                                          'voxelizing val')
    load_seconds = time.perf_counter() - t_load

    # the net and the optimizer
    torch.manual_seed(cfg.seed)
    model = SafetyNet(SafetyNetConfig(cfg.arch, input_size=side, dropout=cfg.dropout))
    if init is not None:
        src, _ = load_model(init, 'cpu')
        if src.spec != model.spec or src.config.input_size != side:
            raise ModelError(f'--init model {init} is {src.spec} on {src.config.input_size}^3 '
                             f'inputs, not {model.spec} on {side}^3')
        model.load_state_dict(src.state_dict())
    model = model.to(device=device, memory_format=torch.channels_last_3d)
    opt = torch.optim.SGD(model.parameters(), lr=cfg.lr, momentum=cfg.momentum,
                          weight_decay=cfg.weight_decay)

    run: dict[str, Any] = {'epoch': 0, 'step': 0, 'samples': 0, 'loss_sum': 0.0, 'loss_n': 0,
                           'seconds': 0.0, 'data_wait': 0.0, 'log': [],
                           'config': asdict(cfg), 'source': source_name}
    if resume and spath.exists():
        state = _load_state(spath, model, opt, device)
        old = state.get('config', {})
        for key in _RESUME_KEYS:
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
        cache = _VoxelCache(ci, cl, cfg.cache_voxels)
        load_seconds += time.perf_counter() - t0
    loader = None if cache is not None else make_loader(
        vol_ds, sampler, cfg.batch_size, cfg.workers, pin_memory=device.type == 'cuda')

    from landing_zone.lofo import dataset_names
    meta_common = {'voxel_size': mcfg.voxel_size, 'tiles': asdict(tcfg), 'training':
                   asdict(cfg), 'seed': cfg.seed, 'source': source_name,
                   'datasets': dataset_names(source),
                   'n_train_scenes': len(d.train), 'n_val_scenes': len(d.val)}
    last_ckpt = time.monotonic()

    def checkpoint() -> None:
        _save_state(spath, model, opt, device, {**run, 'config': asdict(cfg)})
        _write_log(lpath, run['log'])

    for epoch in range(run['epoch'], cfg.epochs):
        start = run['step'] * cfg.batch_size
        sampler.set_epoch(epoch, start)
        model.train()
        n_batches = math.ceil(len(sampler) / cfg.batch_size)
        bar = _bar(progress, total=n_batches, desc=f'epoch {epoch + 1}/{cfg.epochs}',
                   unit='batch')
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
            with _autocast(device, use_bf16):
                _, loss = model(x, y)
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
            if bar is not None:
                bar.update(1)
                bar.set_postfix(loss=f'{run["loss_sum"] / run["loss_n"]:.4f}', refresh=False)
            if (cfg.checkpoint_minutes
                    and time.monotonic() - last_ckpt > 60 * cfg.checkpoint_minutes):
                checkpoint()
                last_ckpt = time.monotonic()
            t_wait = time.perf_counter()
        if bar is not None:
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
    temperature = fit_temperature(logits, y_val) if len(logits) else 1.0
    model.temperature = temperature
    p_val = 1.0 / (1.0 + np.exp(-np.asarray(logits, np.float64) / temperature))
    metrics = {'val_auc': val_auc, 'val_loss': val_loss,
               'val_nll_calibrated': binary_nll(logits, y_val, temperature) if len(logits)
               else float('nan'),
               'val_ece': expected_calibration_error(p_val, y_val) if len(logits)
               else float('nan'),
               'epochs': run['epoch'], 'samples': run['samples'],
               'train_seconds': round(run['seconds'], 2),
               'load_seconds': round(load_seconds, 2)}
    metrics = {k: (None if isinstance(v, float) and not math.isfinite(v) else v)
               for k, v in metrics.items()}
    model_cpu = model.to('cpu', memory_format=torch.contiguous_format)
    model_cpu.temperature = temperature
    save_model(out, model_cpu, {**meta_common, 'metrics': metrics})
    return {'out': str(out), 'state': str(spath), 'log': str(lpath), 'spec': model_cpu.spec,
            'temperature': temperature, **metrics}


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


# -----------------------------------------------------------------------------------------------
# a command line with the standard library only (``python -m landing_zone.train``), for training
# boxes without typer; ``landing-zone train`` takes the same options

_HELP = {
    'arch': 'network spec', 'epochs': 'passes over the augmented training set',
    'lr': 'SGD learning rate', 'momentum': 'SGD momentum', 'weight_decay': 'L2 penalty',
    'batch_size': 'samples per minibatch',
    'augment_copies': 'augmented samples of every scene per epoch',
    'max_samples': 'cap on samples per epoch (0: none)',
    'val_fraction': 'share of training scenes held out', 'workers': 'data loader processes',
    'seed': 'seed of initialisation, split and augmentation', 'device': 'cpu or cuda[:N]',
    'dropout': 'dropout after each layer', 'z_shift': 'largest vertical shift [m]',
    'yaw': 'random yaw (--no-yaw: none)',
    'edge_drop': 'share of samples with their context cut off beyond a line in the padding',
    'checkpoint_minutes': 'also save the state this often within an epoch',
    'cache_voxels': 'pre-voxelize this many augmented copies per scene (0: on the fly)',
    'precision': 'auto, fp32 or bf16'}


def main(argv: list[str] | None = None) -> int:
    """``python -m landing_zone.train --data DIR --out MODEL [options]``."""
    import argparse

    parser = argparse.ArgumentParser(
        prog='python -m landing_zone.train',
        description='Train the safety CNN (same options as `landing-zone train`).')
    parser.add_argument('--data', required=True, nargs='+', help='dataset directories')
    parser.add_argument('--out', required=True, help='model file to write (.safetensors)')
    parser.add_argument('--resume', action='store_true', help='continue from OUT.train')
    parser.add_argument('--init', default=None, help='start from this model (same spec)')
    parser.add_argument('--quiet', action='store_true', help='no progress bars')
    defaults = TrainConfig()
    for f in fields(TrainConfig):
        flag = '--' + f.name.replace('_', '-')
        value = getattr(defaults, f.name)
        if isinstance(value, bool):
            parser.add_argument(flag, action=argparse.BooleanOptionalAction, default=value,
                                help=_HELP.get(f.name, ''))
        else:
            parser.add_argument(flag, type=type(value), default=value,
                                help=f'{_HELP.get(f.name, "")} (default {value})')
    args = parser.parse_args(argv)
    cfg = TrainConfig(**{f.name: getattr(args, f.name) for f in fields(TrainConfig)})
    try:
        s = train(args.data, args.out, cfg, resume=args.resume, init=args.init,
                  progress=not args.quiet)
    except (ConfigError, DatasetError, ModelError) as err:
        print(f'train: error: {err}', file=sys.stderr)
        return 2
    print(f'wrote {s["out"]}: {s["spec"]}, {s["epochs"]} epochs, {s["samples"]:,} samples in '
          f'{s["train_seconds"]:.0f} s; validation AUC {s["val_auc"]}, ECE {s["val_ece"]} at '
          f'temperature {s["temperature"]:.3f}')
    return 0


if __name__ == '__main__':
    sys.exit(main())
