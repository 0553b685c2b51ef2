"""The scenes a net learns from: packed in memory, split, several sources as one.

A :class:`ScenePack` holds the returns of many scenes in a few flat tensors (cheap to hand to
loader processes); :func:`split_scenes` holds out validation scenes by label; a dataset
directory, a list of them (:class:`ConcatScenes`) or any sequence of scenes opens with
:func:`open_source`.
"""
from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from landing_zone.errors import DatasetError

__all__ = ['ScenePack', 'split_scenes', 'ConcatScenes', 'open_source', 'labels_of',
           'part_of']


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
        self.origin_index = origin_index  # (N,) int32 (int64 past 2^31 runs), row in `origins`
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
        bar = tqdm(total=len(idx), desc=desc, unit='scene', leave=False, file=sys.stderr,
                   disable=not progress)
        for i in idx:
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
            oidx.append((run + n_orig).astype(np.int32 if n_orig + len(table) < 2 ** 31
                                              else np.int64))
            orgs.append(table)
            n_orig += len(table)
            offsets.append(offsets[-1] + len(p))
            labels.append(int(s.label))
            params.append(dict(getattr(s, 'params', {}) or {}))
        bar.close()
        cat = (lambda a, shape, dt: torch.from_numpy(np.concatenate(a).astype(dt, copy=False))
               if a else torch.zeros(shape, dtype=torch.from_numpy(np.zeros(0, dt)).dtype))
        # int32 rows where they fit: 4 bytes less per return (a fifth of a training set's memory)
        idx_dt = np.int32 if n_orig < 2 ** 31 else np.int64
        return cls(cat(pts, (0, 3), np.float32), torch.tensor(offsets, dtype=torch.int64),
                   cat(oidx, (0,), idx_dt), cat(orgs, (0, 3), np.float32),
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


class ConcatScenes:
    """Several scene sources as one (``len``, ``[i] -> Scene``, ``labels``), in order: e.g. a
    site's hybrid set with some synth2 scenes, so fine-tuning does not forget what it knew."""

    def __init__(self, sources: Sequence[Any], names: Sequence[str] | None = None) -> None:
        self.sources = list(sources)
        self.names = list(names) if names is not None else \
            [type(s).__name__ for s in self.sources]
        if len(self.names) != len(self.sources):
            raise ValueError(f'{len(self.names)} names for {len(self.sources)} sources')
        self.labels = np.concatenate([labels_of(s) for s in self.sources]) \
            if self.sources else np.zeros(0, np.int64)
        self._ends = np.cumsum([len(s) for s in self.sources])

    def __len__(self) -> int:
        return int(self._ends[-1]) if len(self._ends) else 0

    def __getitem__(self, i: int) -> Any:
        if not 0 <= i < len(self):
            raise IndexError(f'scene {i} out of range ({len(self)} scenes)')
        k = int(np.searchsorted(self._ends, i, side='right'))
        return self.sources[k][i - (int(self._ends[k - 1]) if k else 0)]


def part_of(source: Any, positions: np.ndarray) -> np.ndarray:
    """Which of a :class:`ConcatScenes`' sources each position comes from, also through a
    subset of one (``.source``, ``.positions``); all 0 for any other source."""
    positions = np.asarray(positions, np.int64)
    inner, picked = getattr(source, 'source', None), getattr(source, 'positions', None)
    if inner is not None and picked is not None:
        return part_of(inner, np.asarray(picked, np.int64)[positions])
    if isinstance(source, ConcatScenes):
        return np.searchsorted(source._ends, positions, side='right').astype(np.int64)
    return np.zeros(positions.size, np.int64)


def part_names(source: Any, fallback: str) -> list[str]:
    """The name of each part :func:`part_of` numbers: a :class:`ConcatScenes`' source names,
    also through a subset of one; ``[fallback]`` for any other source."""
    inner, picked = getattr(source, 'source', None), getattr(source, 'positions', None)
    if inner is not None and picked is not None:
        return part_names(inner, fallback)
    if isinstance(source, ConcatScenes):
        return list(source.names)
    return [fallback]


def open_source(data: Any) -> tuple[Any, str]:
    if isinstance(data, (str, os.PathLike)):
        from landing_zone.tools.sim.shards import SceneDataset
        return SceneDataset(data, 'train'), str(data)
    if isinstance(data, (list, tuple)) and data and all(
            isinstance(d, (str, os.PathLike)) for d in data):
        if len(data) == 1:
            return open_source(data[0])
        opened = [open_source(d) for d in data]
        return (ConcatScenes([o[0] for o in opened], [o[1] for o in opened]),
                ' + '.join(o[1] for o in opened))
    if not hasattr(data, '__len__') or not hasattr(data, '__getitem__'):
        raise DatasetError('data must be a dataset directory (or a list of them) or a sequence '
                           'of scenes')
    return data, type(data).__name__


def labels_of(source: Any) -> np.ndarray:
    labels = getattr(source, 'labels', None)
    if labels is not None and len(labels) == len(source):
        return np.asarray(labels, np.int64)
    return np.array([int(source[i].label) for i in range(len(source))], np.int64)
