"""Training samples: scenes re-voxelized with augmentation, in a seeded order, by loaders.

Sample ``(epoch, scene, copy)`` is one scene's returns re-voxelized by
:class:`~landing_zone.judging.patches.PatchVoxelizer` after a random yaw about the tile centre, a
random vertical shift and, for some, the context cut beyond a line in the padding
(:class:`AugmentedVolumes`); its randomness comes from ``SeedSequence([seed, epoch, scene,
copy])``, not from the worker that makes it. :class:`EpochSampler` orders an epoch from
``(seed, epoch)``; :func:`voxelize` makes every input of a pack at once (evaluation, the voxel
cache), through :func:`collect`.
"""
from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from typing import Any, Iterator

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset, Sampler
from tqdm import tqdm

from landing_zone.config import MapConfig, TileConfig
from landing_zone.judging.patches import PatchVoxelizer
from landing_zone.judging.tiles import tile_voxels
from landing_zone.tools.learn.scenes import ScenePack

__all__ = ['AugmentedVolumes', 'at_the_edge', 'cut_context', 'EpochSampler', 'make_loader',
           'voxelize', 'collect', 'VoxelCache']


class AugmentedVolumes(Dataset):
    """Sample ``(epoch, scene, copy)`` -> (input (1, S, S, S) float32, label float32).

    With ``augment`` the scene is rotated by a yaw uniform in [0, 2 pi) and shifted by a z
    uniform in [-z_shift, z_shift] drawn from ``SeedSequence([seed, epoch, scene, copy])``
    before re-voxelization; without it the scene is used as it is. With ``edge_drop`` > 0 that
    share of the samples also loses every return beyond a random line in the padding (two lines
    in a third of them: a corner), so the net sees tiles at the edge of a scanned area, whose
    context is partly unobserved, as the deployed map shows them; the tile itself and so its
    label are untouched.

    A scene whose obstacle stands at the tile's edge (:func:`at_the_edge`) turns by a quarter
    turn only (the yaw drawn, rounded): any other yaw turns the square tile under it, which
    would bring a neighbour's obstacle standing just beyond the edge into a safe tile, or take
    one reaching in out of an unsafe one, and teach the wrong label. (Uniform yaws took the
    standing part of 6 % of synth3's straddling obstacles wholly out of the tile, still labelled
    unsafe.)
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
        self.quarter_turns = np.array([at_the_edge(p) for p in pack.params], bool)
        self._voxelizer: PatchVoxelizer | None = None  # made where the samples are drawn

    def __getstate__(self) -> dict[str, Any]:
        # a loader worker builds its own voxelizer; the maps are not worth pickling
        return {**self.__dict__, '_voxelizer': None}

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
        if self.quarter_turns[scene]:
            yaw = 0.5 * math.pi * (round(yaw / (0.5 * math.pi)) % 4)
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
        if self._voxelizer is None:
            self._voxelizer = PatchVoxelizer()
        batch = self._voxelizer(pts, org, self.map_cfg, self.tile_cfg, yaw=yaw, z_shift=dz)
        x = torch.from_numpy(batch.inputs[0])  # (1, S, S, S)
        return x, torch.tensor(float(self.pack.labels[scene]))


def at_the_edge(params: dict[str, Any]) -> bool:
    """Whether a scene's obstacle stands at the tile's edge (from its ``params``): a synth3
    ``--edge`` pair (beyond the edge or reaching in), or a synth3 obstacle placed straddling the
    edge (``inside`` false), whose turns by other than quarter turns can change the label."""
    return 'edge' in params or (params.get('dataset') == 'synth3' and params.get('inside') is False
                                and bool(params.get('obstacle')))


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
    out, labels, _ = collect(ds, keys, side, workers, progress, desc, dtype)
    return out, labels


def collect(dataset: Dataset, keys: list[Any], side: int, workers: int = 0,
            progress: bool = False, desc: str = 'voxelizing', dtype: torch.dtype = torch.float32
            ) -> tuple[torch.Tensor, torch.Tensor, list[torch.Tensor]]:
    """Samples ``keys`` of ``dataset`` (each ``(input (1, side, side, side), label, *more)``)
    made by a loader with ``workers``, in key order.

    Returns:
        inputs (K, 1, side, side, side) of ``dtype``, labels (K,) float32, and each further
        output of the samples stacked (K, ...) in a list.
    """
    out = torch.empty((len(keys), 1, side, side, side), dtype=dtype)
    labels = torch.empty(len(keys), dtype=torch.float32)
    more: list[list[torch.Tensor]] = []
    loader = make_loader(dataset, keys, 64, workers)
    bar = tqdm(total=len(keys), desc=desc, unit='vol', leave=False, file=sys.stderr,
               disable=not progress)
    pos = 0
    for x, y, *rest in loader:
        out[pos:pos + len(x)] = x.to(dtype)
        labels[pos:pos + len(x)] = y
        more = more or [[] for _ in rest]
        for acc, r in zip(more, rest):
            acc.append(r)
        pos += len(x)
        bar.update(len(x))
    bar.close()
    return out, labels, [torch.cat(acc) for acc in more]


@dataclass
class VoxelCache:
    """Pre-voxelized augmented copies: row ``scene * copies + c`` holds copy ``c`` of a scene;
    sample ``(epoch, scene, copy)`` reads copy ``copy mod copies``."""

    inputs: torch.Tensor  # (S * copies, 1, side, side, side) float16
    labels: torch.Tensor  # (S * copies,) float32
    copies: int

    def rows(self, keys: np.ndarray) -> np.ndarray:
        return keys[:, 1] * self.copies + keys[:, 2] % self.copies
