"""The network's input volumes as the baselines read them.

Every baseline takes the same inputs as the CNN: float32 arrays ``(T, 1, S, S, S)`` (or
``(T, S, S, S)``) in ``(x, y, z)`` order, each voxel ``2 * density - 1`` (so unobserved = 0,
occupied > 0, free < 0), the cube centred in x, y on the tile and in z on the tile's estimated
ground height. This module checks them and names the geometry they share.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from landing_zone.errors import ConfigError, DatasetError

__all__ = ['VolumeGeometry', 'as_volumes', 'as_labels']

# Rounding slack of the thresholds against float32 inputs.
_SLACK = 1e-6


@dataclass(frozen=True)
class VolumeGeometry:
    """How a baseline reads a volume: voxel size, tile core, occupancy thresholds."""

    voxel_size: float = 0.05  # edge of a voxel [m] (MapConfig.voxel_size)
    tile_size: float = 1.0  # edge of the tile at the cube's centre [m] (TileConfig.tile_size)
    # A voxel is occupied when its density is at least this (TileConfig.occupied_density) ...
    occupied_density: float = 0.6
    # ... and observed free when its density is at most this (one pass and no hit: 1/3).
    free_density: float = 0.4

    def validate(self) -> None:
        """Raise ConfigError when a field is out of range."""
        if not (np.isfinite(self.voxel_size) and self.voxel_size > 0):
            raise ConfigError(f'voxel_size must be positive, got {self.voxel_size!r}')
        if not (np.isfinite(self.tile_size) and self.tile_size >= self.voxel_size):
            raise ConfigError(f'tile_size must be at least one voxel, got {self.tile_size!r}')
        # Strictly apart from 0.5, the density of an unobserved voxel, which is neither.
        if not 0.5 < self.occupied_density < 1.0:
            raise ConfigError(f'occupied_density must lie in (0.5, 1), got '
                              f'{self.occupied_density!r}')
        if not 0.0 < self.free_density < 0.5:
            raise ConfigError(f'free_density must lie in (0, 0.5), got {self.free_density!r}')

    @property
    def occupied_value(self) -> float:
        """The occupancy threshold in input units: occupied where ``x >= occupied_value``.

        A hair below ``2 * occupied_density - 1`` so that a float32 input computed exactly at
        the threshold (e.g. 2 hits, 1 pass: 0.2) counts as occupied, as in tiles.py.
        """
        return 2.0 * self.occupied_density - 1.0 - _SLACK

    @property
    def free_value(self) -> float:
        """The free-space threshold in input units: free where ``x <= free_value``."""
        return 2.0 * self.free_density - 1.0 + _SLACK

    @property
    def tile_vox(self) -> int:
        """Voxels along one side of the tile core."""
        return int(round(self.tile_size / self.voxel_size))

    def core(self, side: int) -> slice:
        """The index range of the tile core along x or y of a cube ``side`` voxels wide.

        Raises:
            DatasetError: the cube is narrower than the tile or not centred on it.
        """
        pad2 = side - self.tile_vox
        if pad2 < 0 or pad2 % 2:
            raise DatasetError(f'input volumes {side} voxels wide cannot hold a centred tile of '
                               f'{self.tile_vox} voxels ({self.tile_size} m at '
                               f'{self.voxel_size} m)')
        return slice(pad2 // 2, pad2 // 2 + self.tile_vox)

    def centres(self, side: int) -> np.ndarray:
        """Voxel-centre coordinates [m] along one axis of ``side`` voxels, 0 at the centre."""
        return ((np.arange(side) + 0.5 - side / 2) * self.voxel_size).astype(np.float64)


def as_volumes(inputs: Any) -> np.ndarray:
    """Check network inputs and return them as a C-contiguous float32 ``(T, X, Y, Z)`` array.

    Non-finite voxels are read as unobserved (0): a NaN density carries no evidence either way,
    and one bad voxel should not cost a whole evaluation. Values are clipped to [-1, 1].

    Raises:
        DatasetError: the array is not ``(T, 1, X, Y, Z)`` or ``(T, X, Y, Z)`` with X == Y.
    """
    arr = np.asarray(inputs)
    if arr.ndim == 5:
        if arr.shape[1] != 1:
            raise DatasetError(f'input volumes must have one channel, got shape {arr.shape}')
        arr = arr[:, 0]
    if arr.ndim != 4 or arr.shape[1] != arr.shape[2] or min(arr.shape[1:]) < 1:
        raise DatasetError('input volumes must be (T, 1, S, S, Sz) or (T, S, S, Sz), got shape '
                           f'{np.shape(inputs)}')
    if not np.issubdtype(arr.dtype, np.number) or np.iscomplexobj(arr):
        raise DatasetError(f'input volumes must be real numbers, got dtype {arr.dtype}')
    out = np.ascontiguousarray(arr, dtype=np.float32)
    bad = ~np.isfinite(out)
    if out.size and (bad.any() or np.nanmin(out) < -1.0 or np.nanmax(out) > 1.0):
        if np.shares_memory(out, arr):  # never write into the caller's array
            out = out.copy()
        out[bad] = 0.0
        np.clip(out, -1.0, 1.0, out=out)
    return out


def as_labels(labels: Any, n: int) -> np.ndarray:
    """Check training labels (1 safe, 0 unsafe) for ``n`` volumes; return them as int64.

    Raises:
        DatasetError: wrong length, values other than 0 and 1, or only one class present.
    """
    lab = np.asarray(labels)
    if lab.ndim != 1 or lab.shape[0] != n:
        raise DatasetError(f'expected {n} labels, one per volume, got shape {lab.shape}')
    if lab.dtype == bool:
        lab = lab.astype(np.int64)
    if not np.issubdtype(lab.dtype, np.number) or not np.all(np.isin(lab, (0, 1))):
        raise DatasetError('labels must be 1 (safe) or 0 (unsafe)')
    lab = lab.astype(np.int64)
    if np.unique(lab).size < 2:
        raise DatasetError('training needs both safe (1) and unsafe (0) volumes, got only '
                           f'{int(lab[0]) if n else "none"}')
    return lab
