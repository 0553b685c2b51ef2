"""Where the map's window sits, which of its tiles changed, and the box of counts they read.

In follow mode (no fixed centre) the window's XY sits on whole tiles around the sensor's ground
projection and scrolls when the sensor moves more than ``map.recenter_distance`` from its
centre; vertically it sits around the ground under the sensor (the median height of the
cloud's returns) and moves when that drifts past half the margin to the nearer window face. In
fixed mode the XY never moves; the height is placed from the first cloud, then follows the
ground at the region's centre (the median height of the returns within :data:`CENTRAL` of the
window's edge of it, once :data:`CENTRAL_RETURNS` of a cloud fall there) the same way. On a
sloped site the first cloud, often flown beyond the region's edge, may stand metres above or
below its centre; placed there, the far side of the region would leave the window.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy.ndimage import binary_dilation

from landing_zone.config import MapConfig
from landing_zone.mapping.density_map import DensityMap

__all__ = ['Window', 'CENTRAL', 'CENTRAL_RETURNS']

CENTRAL = 0.25  # share of the window's edge around a fixed centre whose returns place its height
CENTRAL_RETURNS = 200  # returns a cloud must have there to move the height


def _median_within(z: np.ndarray, lo: float, hi: float) -> bool:
    """Whether the median of ``z`` (non-empty, finite) lies in ``[lo, hi]``, by counting: it
    does when both middle order statistics do, i.e. when at most ``(n - 1) // 2`` values lie
    below ``lo`` and at most as many above ``hi`` (then the median, their mean, lies between).
    False may also mean "not sure" (a middle value outside): the caller takes the median then.
    Two counts cost a fifth of the partial sort a median takes, on every cloud."""
    n = z.shape[0]
    k = (n - 1) // 2
    return bool(np.count_nonzero(z < lo) <= k and np.count_nonzero(z > hi) <= k)


class Window:
    """The placement of ``dmap``'s window on the tile lattice (``n_tiles`` tiles of
    ``tile_vox`` voxels a side), following the sensor or fixed at ``center``.

    Attributes:
        placed_z: whether the window's height has been placed from a cloud yet.
    """

    def __init__(self, dmap: DensityMap, config: MapConfig, tile_vox: int, tile_size: float,
                 n_tiles: tuple[int, int], center: Sequence[float] | None) -> None:
        self.map = dmap
        self.config = config
        self.tile_vox = tile_vox
        self.tile_size = tile_size
        self.n_tiles = n_tiles
        self.fixed = None if center is None else (float(center[0]), float(center[1]))
        self.placed_z = False
        start = (0.0, 0.0) if self.fixed is None else self.fixed
        self.place(start[0], start[1], 0.0)

    @property
    def follow(self) -> bool:
        """Whether the window follows the sensor (no fixed centre)."""
        return self.fixed is None

    def tile_origin(self) -> np.ndarray:
        """(2,) global index of the window's first tile."""
        out: np.ndarray = self.map.lo[:2] // self.tile_vox
        return out

    def place(self, x: float, y: float, ground_z: float) -> None:
        """Put the window's XY on whole tiles around (x, y) and its z around ``ground_z``."""
        nt = np.array(self.n_tiles, np.int64)
        k = np.array([round(x / self.tile_size), round(y / self.tile_size)], np.int64)
        lo_xy = (k - nt // 2) * self.tile_vox
        vs = self.config.voxel_size
        lo_z = math.floor(ground_z / vs) - int(round(self.config.z_below / vs))
        self.map.set_lo(np.array([lo_xy[0], lo_xy[1], lo_z], np.int64))

    @property
    def center(self) -> np.ndarray:
        """(3,) world position [m] of the window's XY centre and its ground level."""
        lo_m, hi_m = self.map.bounds
        return np.array([(lo_m[0] + hi_m[0]) / 2, (lo_m[1] + hi_m[1]) / 2,
                         lo_m[2] + self.config.z_below])

    def follow_cloud(self, points: np.ndarray, origin: np.ndarray) -> None:
        """Move the window, if need be, for a cloud of ``points`` seen from ``origin``."""
        mc = self.config
        c = self.center
        z_margin = min(mc.z_below, mc.size_z - mc.z_below)
        tol = max(z_margin / 2, mc.voxel_size)
        if self.fixed is not None and self.placed_z:
            # fixed and placed: only the ground at the region's centre moves the height
            centre = self._central_ground(points, c, tol)
            if centre is not None:
                self.place(self.fixed[0], self.fixed[1], centre)
            return
        z = points[:, 2]
        z = z[np.isfinite(z)]
        # the ground under the sensor: the median height of the returns (most hit the ground);
        # a cloud without finite returns says nothing about it
        ground = None
        if z.size and self.placed_z and _median_within(z, c[2] - tol, c[2] + tol):
            ground = float(c[2])  # stands in for the median: it moves nothing
        elif z.size:
            ground = float(np.median(z))
        z_moved = ground is not None and (not self.placed_z or abs(ground - c[2]) > tol)
        if self.fixed is None:
            xy_moved = math.hypot(origin[0] - c[0], origin[1] - c[1]) > mc.recenter_distance
            if xy_moved or z_moved:
                self.place(float(origin[0]), float(origin[1]),
                           ground if z_moved and ground is not None else float(c[2]))
        elif ground is not None:  # fixed, the first cloud with returns: placed from it
            self.place(self.fixed[0], self.fixed[1], ground)
        self.placed_z = self.placed_z or ground is not None

    def _central_ground(self, points: np.ndarray, c: np.ndarray, tol: float) -> float | None:
        """Fixed mode: the ground at the region's centre where this cloud shows it standing more
        than ``tol`` from the window's ground level (None: it does not, or it shows too little
        of the centre)."""
        half = CENTRAL * self.config.size_xy / 2
        near = (np.abs(points[:, 0] - c[0]) <= half) & (np.abs(points[:, 1] - c[1]) <= half)
        z = points[near, 2]
        z = z[np.isfinite(z)]
        if z.size < CENTRAL_RETURNS or _median_within(z, c[2] - tol, c[2] + tol):
            return None
        return float(np.median(z))

    def dirty_tiles(self, reach: int) -> np.ndarray:
        """(K, 2) global indices of the tiles to re-extract: the window's changed ones and the
        neighbours whose padding (``reach`` tiles) reaches them."""
        dirty = self.map.pop_dirty()
        origin = self.tile_origin()
        shape = np.array(self.n_tiles)
        grid = np.zeros(self.n_tiles, bool)
        rel = dirty - origin
        keep = np.all((rel >= 0) & (rel < shape), axis=1)
        grid[rel[keep, 0], rel[keep, 1]] = True
        if reach and grid.any():
            grid = binary_dilation(grid, np.ones((2 * reach + 1,) * 2, bool))
        out: np.ndarray = np.argwhere(grid).astype(np.int64) + origin
        return out

    def box_around(self, tiles: np.ndarray, padding: int) -> tuple[np.ndarray, np.ndarray]:
        """The box of counts the inputs of ``tiles`` read: their bounding box, ``padding``
        voxels included, clipped to the window. Returns its lower corner and size (voxels)."""
        lo = np.asarray(self.map.lo, np.int64)
        hi = np.asarray(self.map.hi, np.int64)
        # from the lowest level any ray reached: the levels below hold nothing, and every
        # reader (tiler, ground planes, guard) takes a box's outside for unobserved
        floor = np.array([self.map.floor_z], np.int64)
        box_lo = np.concatenate([tiles.min(axis=0) * self.tile_vox - padding, floor])
        box_hi = np.concatenate([(tiles.max(axis=0) + 1) * self.tile_vox + padding, hi[2:]])
        box_lo = np.clip(box_lo, lo, hi)
        box_hi = np.clip(box_hi, box_lo, hi)
        return box_lo, box_hi - box_lo
