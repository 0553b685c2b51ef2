"""The map's record of changed tiles: which tiles' voxels changed since the assessor last asked.

A tile ``k`` covers voxels ``[k * tile_vox, (k + 1) * tile_vox)`` in x and y. The record is a
superset: every tile in the XY box of the cells a ray visited (the walk marks them in its part's
own record, merged after the batch) and every tile that scrolling cut or filled.
"""
from __future__ import annotations

import numpy as np

__all__ = ['DirtyTiles']


def _part_records(nparts: int, shape: tuple[int, ...]) -> np.ndarray:
    """One dirty-tile record per part, 64 bytes apart so the threads never share a line."""
    pad = 64 // max(shape[1], 1) + 1
    return np.zeros((nparts, shape[0] + pad, shape[1]), np.uint8)


class DirtyTiles:
    """Changed tiles of a window, one byte per tile, and one record per part of the walk.

    Attributes:
        tile_vox: tile edge [voxels] (0 until :meth:`resize` is first called).
        lo: (2,) global index of the window's first tile.
        grid: (KX, KY) uint8, 1 where the tile changed.
        parts: (parts, KX + pad, KY) uint8, what each part of a walk marked.
    """

    def __init__(self, nparts: int) -> None:
        self.nparts = nparts
        self.tile_vox = 0
        self.lo = np.zeros(2, np.int64)
        self.grid = np.zeros((0, 0), np.uint8)
        self.parts = _part_records(nparts, self.grid.shape)

    def resize(self, lo: np.ndarray, n: np.ndarray, tile_vox: int, value: int) -> None:
        """Cover the window ``[lo, lo + n)`` (voxels) with tiles of ``tile_vox``, every tile
        set to ``value``."""
        self.tile_vox = tile_vox
        self.lo = lo[:2] // tile_vox
        klast = (lo[:2] + n[:2] - 1) // tile_vox
        self.grid = np.full(tuple(int(v) for v in klast - self.lo + 1), value, np.uint8)
        self.parts = _part_records(self.nparts, self.grid.shape)

    @property
    def nbytes(self) -> int:
        return int(self.grid.nbytes + self.parts.nbytes)

    def tiles(self) -> np.ndarray:
        """(K, 2) int64 global indices of the changed tiles, sorted by x then y."""
        idx = np.argwhere(self.grid != 0).astype(np.int64)
        out: np.ndarray = idx + self.lo
        return out

    def pop(self) -> np.ndarray:
        """:meth:`tiles`, and forget them."""
        out = self.tiles()
        self.grid[:] = 0
        return out

    def mark(self, tiles: np.ndarray) -> None:
        """Mark the global tiles ``tiles`` ((K, 2)) that lie in the window."""
        rel = tiles - self.lo
        keep = np.all((rel >= 0) & (rel < self.grid.shape), axis=1)
        self.grid[rel[keep, 0], rel[keep, 1]] = 1

    def merge_parts(self) -> None:
        """Take in what the parts of a walk marked, and clear their records."""
        kx, _ = self.grid.shape
        self.grid |= np.bitwise_or.reduce(self.parts[:, :kx], axis=0)
        self.parts[:] = 0

    def scrolled(self, delta: np.ndarray, old_lo: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                 n: np.ndarray) -> None:
        """Mark the tiles a move of the window by ``delta`` (from ``old_lo`` to ``lo``; ``hi``
        one past its last voxel, ``n`` its shape) cut or filled."""
        if delta[2] != 0:
            self.grid[:] = 1  # cells entered or left in every column
            return
        tv = self.tile_vox
        for axis in range(2):
            if delta[axis] == 0:
                continue
            if delta[axis] > 0:
                # entering: [old_hi, new_hi); the tile of the new first column lost cells
                cols = (old_lo[axis] + n[axis], hi[axis] - 1, lo[axis])
            else:
                cols = (lo[axis], old_lo[axis] - 1, hi[axis] - 1)
            k0 = cols[0] // tv - self.lo[axis]
            k1 = cols[1] // tv - self.lo[axis]
            kb = cols[2] // tv - self.lo[axis]
            sel = [slice(None), slice(None)]
            sel[axis] = slice(int(k0), int(k1) + 1)
            self.grid[tuple(sel)] = 1
            sel[axis] = slice(int(kb), int(kb) + 1)
            self.grid[tuple(sel)] = 1
