"""The scrolling volumetric density map: per-voxel hit and pass counts on the global lattice.

The map is a window ``[lo, lo + shape)`` of the global voxel lattice (voxel ``g`` covers
``[g * vs, (g + 1) * vs)``). Each voxel keeps how many returns fell in it (hits) and how many
rays went through it (passes); its density is the Beta(1, 1) posterior mean of the chance that
a ray stops there, ``(hits + 1) / (hits + passes + 2)``, and it is observed once
``hits + passes > 0``.

Scrolling is a ring buffer (storage index ``g mod M`` per axis): moving the window clears only
the slabs that enter it, so its cost is proportional to what moves. Storage layout, threads and
the walk itself are described in :mod:`landing_zone.mapping.raytrace`.
"""
from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numba as nb
import numpy as np
from numpy.typing import ArrayLike, DTypeLike

from landing_zone.config import MapConfig
from landing_zone.errors import ConfigError, InvalidCloudError
from landing_zone.mapping.parts import PartRunner, run_parts
from landing_zone.mapping.raytrace import (BRICK, COUNT_MAX, PARTS, SORT_TILE, IntegrationStats,
                                           prepare_rays, trace_rays)

__all__ = ['DensityMap', 'IntegrationStats', 'COUNT_MAX']

_BRICK_VOX = BRICK ** 3
_COLD_BYTES = 2 * _BRICK_VOX  # high bytes of the hits, then of the passes, of one brick
# Below this many rays a batch is walked on the calling thread alone: waking a helper costs
# more than it saves.
_PARALLEL_MIN_RAYS = 2048
_NOTHING = 2 ** 62  # the z floor of a map no ray has touched


def _round_up(n: int, m: int) -> int:
    return (n + m - 1) // m * m


def _aligned_zeros(n: int, dtype: DTypeLike, align: int = 64) -> np.ndarray:
    """Zeroed 1-D array whose data starts on a cache-line boundary (bricks = whole lines).

    The zeros are written, not just mapped: the pages are committed now rather than faulted in
    one by one while the first clouds are integrated.
    """
    itemsize = np.dtype(dtype).itemsize
    raw = np.empty(n * itemsize + align, np.uint8)
    raw.fill(0)
    start = (-raw.ctypes.data) % align
    return raw[start:start + n * itemsize].view(dtype)


# --- compiled storage operations ---------------------------------------------------------------

@nb.njit(cache=True, nogil=True)
def _window_tables(dims, wlo, wn, qlo, qn):  # type: ignore[no-untyped-def]
    """What every read of a box (global indices) needs: the part of the box inside the window
    ([r0, r1) in box coordinates), the brick-layout offsets of its y and z positions and the
    x stride. Called once per read, so passing arrays costs nothing per voxel."""
    r0 = np.empty(3, np.int64)
    r1 = np.empty(3, np.int64)
    for a in range(3):
        r0[a] = min(max(wlo[a] - qlo[a], 0), qn[a])
        r1[a] = max(min(wlo[a] + wn[a] - qlo[a], qn[a]), r0[a])
    sy_stride = (dims[2] // BRICK) * 64
    sx_stride = (dims[1] // BRICK) * sy_stride
    offy = np.empty(qn[1], np.int64)
    offz = np.empty(qn[2], np.int64)
    for j in range(r0[1], r1[1]):
        s = (qlo[1] + j) % dims[1]
        offy[j] = (s >> 2) * sy_stride + (s & 3) * 4
    for k in range(r0[2], r1[2]):
        s = (qlo[2] + k) % dims[2]
        offz[k] = (s >> 2) * 64 + (s & 3)
    return r0, r1, offy, offz, sx_stride


# what _read_hot writes
_READ_COUNTS = 0  # the hot bytes of hits and passes (out_a, out_b)
_READ_DENSITY = 1  # (h + 1) / (h + p + 2) as float32 (out_a)
_READ_OBSERVED = 2  # h + p > 0 (out_a)


@nb.njit(cache=True, nogil=True)
def _read_hot(  # type: ignore[no-untyped-def]
        chunk, nchunks, hits, passes, dims, wlo, wn, qlo, qn, what, out_a, out_b):
    """Read the hot bytes of the requested box (global indices) in logical order: the counts
    into ``out_a`` / ``out_b``, or the density or observed flags computed from them into
    ``out_a`` (valid while no cold block exists). Chunk ``chunk`` of ``nchunks`` along x.

    One walk over the storage layout for the three reads; ``what`` is constant per call, so
    the compiler takes the branch out of the inner loop."""
    r0, r1, offy, offz, sx_stride = _window_tables(dims, wlo, wn, qlo, qn)
    z0 = r0[2]
    z1 = r1[2]
    span = r1[0] - r0[0]
    for i in range(r0[0] + chunk * span // nchunks, r0[0] + (chunk + 1) * span // nchunks):
        s = (qlo[0] + i) % dims[0]
        offx = (s >> 2) * sx_stride + (s & 3) * 16
        for j in range(r0[1], r1[1]):
            base = offx + offy[j]
            for k in range(z0, z1):
                idx = base + offz[k]
                h = hits[idx]
                p = passes[idx]
                if what == _READ_COUNTS:
                    out_a[i, j, k] = h
                    out_b[i, j, k] = p
                elif what == _READ_DENSITY:
                    hf = np.float64(h)
                    out_a[i, j, k] = np.float32((hf + 1.0) / (hf + np.float64(p) + 2.0))
                else:
                    out_a[i, j, k] = (h | p) != 0


@nb.njit(cache=True)
def _gather_cold(  # type: ignore[no-untyped-def]
        cdir, pool, row_part, dims, wlo, wn, qlo, qn, out_h, out_p):
    """Add 256 x the cold high bytes of every brick that has them (rare) to the output."""
    byn = dims[1] // BRICK
    bzn = dims[2] // BRICK
    for brick in range(cdir.shape[0]):
        slot = cdir[brick]
        if slot < 0:
            continue
        bz = brick % bzn
        by = (brick // bzn) % byn
        bx = brick // (bzn * byn)
        part = row_part[by]
        for w in range(64):
            hi_h = pool[part, slot, w]
            hi_p = pool[part, slot, 64 + w]
            if hi_h == 0 and hi_p == 0:
                continue
            s0 = bx * 4 + (w >> 4)
            s1 = by * 4 + ((w >> 2) & 3)
            s2 = bz * 4 + (w & 3)
            # the one global index in the window stored at this storage index
            g0 = wlo[0] + (s0 - wlo[0]) % dims[0]
            g1 = wlo[1] + (s1 - wlo[1]) % dims[1]
            g2 = wlo[2] + (s2 - wlo[2]) % dims[2]
            if g0 >= wlo[0] + wn[0] or g1 >= wlo[1] + wn[1] or g2 >= wlo[2] + wn[2]:
                continue  # padding of the ring, not in the window
            i = g0 - qlo[0]
            j = g1 - qlo[1]
            k = g2 - qlo[2]
            if 0 <= i < qn[0] and 0 <= j < qn[1] and 0 <= k < qn[2]:
                out_h[i, j, k] += np.uint32(hi_h) << 8
                out_p[i, j, k] += np.uint32(hi_p) << 8


def _clear_hot(arr: np.ndarray, dims: np.ndarray, axis: int, s0: int, s1: int) -> None:
    """Zero the storage slab [s0, s1) (no wrap) of one axis in a hot array, by brick views.

    Whole bricks go as contiguous runs, the partial bricks at either end plane by plane; numpy's
    strided fill does the rest, so a 1 m shift costs a fraction of a millisecond.
    """
    b = dims // BRICK
    v = arr.reshape(int(b[0]), int(b[1]), int(b[2]), BRICK, BRICK, BRICK)
    full0 = -(-s0 // BRICK)
    full1 = s1 // BRICK
    planes = list(range(s0, min(s1, full0 * BRICK))) + list(range(max(full1 * BRICK, s0), s1))
    sel: list[slice | int]
    if full1 > full0:
        sel = [slice(None)] * 6
        sel[axis] = slice(full0, full1)
        v[tuple(sel)] = 0
    else:
        planes = list(range(s0, s1))
    for s in planes:
        sel = [slice(None)] * 6  # (one axis's bricks and its voxel in the brick)
        sel[axis] = s // BRICK
        sel[3 + axis] = s % BRICK
        v[tuple(sel)] = 0


@nb.njit(cache=True)
def _clear_cold(cdir, pool, row_part, dims, s0, s1):  # type: ignore[no-untyped-def]
    """Zero the cold high bytes of the storage box [s0, s1) (no wrap)."""
    sy_stride = (dims[2] // BRICK) * 64
    sx_stride = (dims[1] // BRICK) * sy_stride
    for sx in range(s0[0], s1[0]):
        offx = (sx >> 2) * sx_stride + (sx & 3) * 16
        for sy in range(s0[1], s1[1]):
            base = offx + (sy >> 2) * sy_stride + (sy & 3) * 4
            part = row_part[sy >> 2]
            for sz in range(s0[2], s1[2]):
                idx = base + (sz >> 2) * 64 + (sz & 3)
                slot = cdir[idx >> 6]
                if slot >= 0:
                    pool[part, slot, idx & 63] = 0
                    pool[part, slot, 64 + (idx & 63)] = 0


@nb.njit(cache=True)
def _compact_cold(cdir, pool, used, row_part, dims):  # type: ignore[no-untyped-def]
    """Give back cold blocks that scrolling left all zero, keeping each part's pool dense."""
    byn = dims[1] // BRICK
    bzn = dims[2] // BRICK
    nparts = pool.shape[0]
    new_slot = np.full((nparts, pool.shape[1]), -1, np.int64)
    fill = np.zeros(nparts, np.int64)
    for brick in range(cdir.shape[0]):
        slot = cdir[brick]
        if slot < 0:
            continue
        part = row_part[(brick // bzn) % byn]
        empty = True
        for w in range(128):
            if pool[part, slot, w] != 0:
                empty = False
                break
        if empty:
            cdir[brick] = -1
        else:
            new_slot[part, slot] = 1
    # renumber the live slots of each part in increasing order (moves only go down)
    for part in range(nparts):
        n = 0
        for slot in range(used[part]):
            if new_slot[part, slot] >= 0:
                new_slot[part, slot] = n
                if n != slot:
                    pool[part, n, :] = pool[part, slot, :]
                n += 1
        for slot in range(n, used[part]):
            pool[part, slot, :] = 0
        fill[part] = n
        used[part] = n
    for brick in range(cdir.shape[0]):
        slot = cdir[brick]
        if slot >= 0:
            part = row_part[(brick // bzn) % byn]
            cdir[brick] = new_slot[part, slot]


# --- the map -----------------------------------------------------------------------------------

class DensityMap:
    """Scrolling voxel map of hit and pass counts, the input of the tiler.

    Memory: one ``uint8`` for the hits and one for the passes of every voxel (2 bytes), a 4-byte
    cold-block index per 4 x 4 x 4 brick (0.06 bytes per voxel), and 128-byte cold blocks that
    hold the high bytes of a brick's counts, allocated only for bricks where some count went
    past 255. So a map costs 2.07 bytes per voxel (26.5 MB for the default 400 x 400 x 80)
    until counts grow large, and at most 4.07 bytes per voxel should every brick overflow.

    Saturation: hits and passes are exact up to 65535 each; a count that reaches 65535 stays
    there (it never wraps) while the other goes on counting, so the density of such a voxel is
    that of the clamped counts. (At 20k returns per second spread over a 20 m map, a ground
    voxel needs hours of hover to get there.)

    Threads: a batch is walked in ``raytrace.PARTS`` slabs of storage, taken by up to
    ``numba.get_num_threads()`` threads (``NUMBA_NUM_THREADS=1``: in turn on the caller's
    thread); batches under 2048 rays stay on the caller's thread. Counts are the same bytes
    whichever way they ran.

    Attributes:
        voxel_size: edge of a voxel [m].
        shape: voxels of the window along x, y, z.
        lo: (3,) int64, global lattice index of the window's lower corner.
        config: the :class:`MapConfig` it was built from.
        tile_vox: voxels per side of the tiles whose changes :meth:`pop_dirty` reports.
    """

    def __init__(self, config: MapConfig | None = None,
                 center: Sequence[float] = (0.0, 0.0, 0.0), tile_vox: int | None = None,
                 parallel: bool = True) -> None:
        """Build an empty map centred on ``center``.

        Args:
            config: voxel size and extent; default :class:`MapConfig()` (20 x 20 x 4 m, 5 cm).
            center: world position [m] the window is placed around (see :meth:`recenter`).
            tile_vox: tile edge in voxels for the dirty record; default the voxels in 1 m.
            parallel: run the parts of each batch on numba's threads.

        Raises:
            ConfigError: the configuration is invalid.
        """
        self.config = config if config is not None else MapConfig()
        self.config.validate()
        self.voxel_size = float(self.config.voxel_size)
        self.shape: tuple[int, int, int] = self.config.shape
        if min(self.shape) < 1:
            raise ConfigError(f'map shape must be at least one voxel per axis, got {self.shape}')
        self._n = np.array(self.shape, np.int64)
        self._z_below_vox = int(round(self.config.z_below / self.voxel_size))
        # Ring dimensions: whole bricks, and y in whole bricks per part so no brick is shared.
        self._dims = np.array([_round_up(v, BRICK) for v in self.shape], np.int64)
        # Storage brick rows along y are dealt out to the parts in contiguous slabs.
        rows = int(self._dims[1] // BRICK)
        self._nparts = min(PARTS, rows)
        self._row_start = np.array([k * rows // self._nparts for k in range(self._nparts + 1)],
                                   np.int64)
        self._row_part = np.repeat(np.arange(self._nparts, dtype=np.int64),
                                   np.diff(self._row_start))
        nvox = int(np.prod(self._dims))
        self._hits = _aligned_zeros(nvox, np.uint8)
        self._passes = _aligned_zeros(nvox, np.uint8)
        self._cdir = np.full(nvox // _BRICK_VOX, -1, np.int32)
        # the most cold blocks one ray can claim in one part (see raytrace._trace_part)
        self._worst = int(self._dims.sum() // BRICK + 6)
        # a part never needs more cold blocks than it has bricks
        self._pool_limit = int(np.diff(self._row_start).max() * (self._dims[0] // BRICK)
                               * (self._dims[2] // BRICK))
        self._pool = np.zeros((self._nparts, min(self._worst, self._pool_limit), _COLD_BYTES),
                              np.uint8)
        self._used = np.zeros(self._nparts, np.int64)
        self.parallel = bool(parallel)
        # the helper threads of the parallel parts, ended by close()
        self._runner: PartRunner | None = PartRunner() if self.parallel else None
        # XY cell (voxels) the batch is counting-sorted by before the walk; 0 keeps input order
        self.sort_tile = SORT_TILE
        self.lo = np.zeros(3, np.int64)
        # global z index below which no voxel holds a count (see floor_z)
        self._z_floor = _NOTHING
        if tile_vox is None:
            tile_vox = max(1, int(round(1.0 / self.voxel_size)))
        self.tile_vox = 0
        self.mark_tile_size(tile_vox)
        self._place(self._lo_for(center))

    # -- geometry ---------------------------------------------------------------------------

    @property
    def hi(self) -> np.ndarray:
        """(3,) int64, one past the window's last voxel (global lattice index)."""
        return self.lo + self._n

    @property
    def floor_z(self) -> int:
        """Global z index below which every voxel of the window holds no count: the lowest
        level any ray touched since the map was empty (the window's floor at the least, one
        level under its top at the most). A reader of the counts may start its box here (the
        assessor does: on a site flown from above, the levels under the ground are a third to
        a half of the map, and every kernel reads whole columns)."""
        return int(min(max(self._z_floor, self.lo[2]), self.hi[2] - 1))

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """World box [m] of the window: (lower corner, upper corner)."""
        return self.lo * self.voxel_size, self.hi * self.voxel_size

    @property
    def nbytes(self) -> int:
        """Bytes of count storage (hot arrays, cold-block index and pools, dirty record)."""
        return int(self._hits.nbytes + self._passes.nbytes + self._cdir.nbytes
                   + self._pool.nbytes + self._used.nbytes + self._dirty.nbytes
                   + self._dirty_parts.nbytes)

    @property
    def cold_blocks(self) -> int:
        """Bricks that currently hold counts above 255 (each has a 128-byte cold block)."""
        return int(self._used.sum())

    def _lo_for(self, center: Sequence[float]) -> np.ndarray:
        c = np.asarray(center, np.float64).reshape(-1)
        if c.shape != (3,) or not np.all(np.isfinite(c)):
            raise ConfigError(f'map center must be three finite numbers, got {center!r}')
        g = np.floor(c / self.voxel_size).astype(np.int64)
        return g - np.array([self.shape[0] // 2, self.shape[1] // 2, self._z_below_vox],
                            np.int64)

    def world_to_index(self, xyz: np.ndarray) -> np.ndarray:
        """Global lattice indices ``floor(p / voxel_size)`` of world points (..., 3)."""
        return np.floor(np.asarray(xyz, np.float64) / self.voxel_size).astype(np.int64)

    def contains_index(self, g: np.ndarray) -> np.ndarray:
        """Whether global lattice indices (..., 3) lie in the window."""
        g = np.asarray(g)
        inside: np.ndarray = np.all((g >= self.lo) & (g < self.hi), axis=-1)
        return inside

    # -- integration ------------------------------------------------------------------------

    def integrate(self, points: np.ndarray, origins: np.ndarray) -> IntegrationStats:
        """Ray-trace a batch of returns into the map.

        Args:
            points: (N, 3) returns in the fixed frame [m], float32 or float64.
            origins: the sensor origin of every return, (3,) for all or (N, 3) one per row.

        Returns:
            What happened to the returns (rows with NaN/Inf or zero length are dropped and
            counted, never raised).

        Raises:
            InvalidCloudError: an array has the wrong shape or type.
        """
        pts = _as_points(points, 'points')
        n = pts.shape[0]
        org = _as_points(origins, 'origins', allow_single=True)
        if org.shape[0] not in (1, n):
            raise InvalidCloudError(
                f'origins must be (3,) or (N, 3) with N = {n} rows like points, got '
                f'{org.shape[0]} rows')
        stats = IntegrationStats(returns=n)
        if n == 0:
            return stats
        lo = self.lo
        hi = self.hi
        uo, up, order, nvalid, (_, nonfinite, degenerate, missed, outside) = prepare_rays(
            pts, org, self.voxel_size, lo, hi, self.sort_tile or int(self._dims.max()))
        stats.nonfinite = int(nonfinite)
        stats.degenerate = int(degenerate)
        stats.missed = int(missed)
        stats.outside_hits = int(outside)
        stats.integrated = int(nvalid)
        if nvalid == 0:
            return stats
        # every cell a ray walks lies between its origin's and its return's levels
        rays = order[:nvalid]
        low = math.floor(min(float(uo[rays, 2].min()), float(up[rays, 2].min())))
        self._z_floor = min(self._z_floor, max(low, int(lo[2])))
        resume = np.zeros(self._nparts, np.int64)
        counters = np.zeros((self._nparts, 2), np.int64)
        while True:
            trace_rays(uo, up, order, nvalid, lo, hi, self._yint, self._tables, self._hits,
                       self._passes, self._cdir, self._pool, self._pool_limit, self._used, resume,
                       self._dirty_parts, self._dirty_lo, self.tile_vox, counters,
                       runner=self._runner if nvalid >= _PARALLEL_MIN_RAYS else None)
            if np.all(resume >= 2 * nvalid):
                break
            # a part stopped before a ray that might not find a free cold block: grow, resume
            self._grow_pool()
        kx, ky = self._dirty.shape
        self._dirty |= np.bitwise_or.reduce(self._dirty_parts[:, :kx], axis=0)
        self._dirty_parts[:] = 0
        stats.voxels = int(counters[:, 1].sum())
        return stats

    def _grow_pool(self) -> None:
        cap = self._pool.shape[1]
        pool = np.zeros((self._nparts, min(2 * cap, self._pool_limit), _COLD_BYTES), np.uint8)
        pool[:, :cap] = self._pool
        self._pool = pool

    # -- scrolling --------------------------------------------------------------------------

    def recenter(self, center: Sequence[float]) -> int:
        """Move the window so that it is placed around the world point ``center``.

        The window's lower corner becomes ``floor(center / vs) - (nx // 2, ny // 2,
        round(z_below / vs))``; it moves in whole voxels.

        Args:
            center: world position (x, y, z) [m].

        Returns:
            The number of voxels that entered the window (and start unobserved).
        """
        return self.set_lo(self._lo_for(center))

    def set_lo(self, lo: ArrayLike) -> int:
        """Move the window so that its lower corner is the global lattice index ``lo``.

        Cells that leave are discarded; cells that enter start unobserved. Only the entering
        slabs are cleared, so the cost is proportional to the shift.

        Args:
            lo: (3,) integer global lattice index.

        Returns:
            The number of voxels that entered the window.
        """
        new = np.asarray(lo).reshape(-1)
        if new.shape != (3,) or not np.issubdtype(new.dtype, np.integer):
            raise ConfigError(f'map lo must be three integers, got {lo!r}')
        new = new.astype(np.int64)
        delta = new - self.lo
        if not delta.any():
            return 0
        n = self._n
        old_lo = self.lo.copy()
        if np.any(np.abs(delta) >= n):
            self._hits.fill(0)
            self._passes.fill(0)
            self._cdir.fill(-1)
            self._pool.fill(0)
            self._used.fill(0)
            self._place(new)
            self._dirty[:] = 1
            return int(np.prod(n))
        for axis in range(3):
            if delta[axis] == 0:
                continue
            if delta[axis] > 0:
                g0, g1 = old_lo[axis] + n[axis], new[axis] + n[axis]
            else:
                g0, g1 = new[axis], old_lo[axis]
            for s0, s1 in _ring_ranges(g0, g1, int(self._dims[axis])):
                _clear_hot(self._hits, self._dims, axis, s0, s1)
                _clear_hot(self._passes, self._dims, axis, s0, s1)
                if self._used.any():
                    a = np.zeros(3, np.int64)
                    b = self._dims.copy()
                    a[axis], b[axis] = s0, s1
                    _clear_cold(self._cdir, self._pool, self._row_part, self._dims, a, b)
        if self._used.any():
            _compact_cold(self._cdir, self._pool, self._used, self._row_part, self._dims)
        self._place(new, delta=delta, old_lo=old_lo)
        entered = int(np.prod(n)) - int(np.prod(n - np.abs(delta)))
        return entered

    def _place(self, lo: np.ndarray, delta: np.ndarray | None = None,
               old_lo: np.ndarray | None = None) -> None:
        """Set ``lo`` and everything derived from it; carry the dirty record over."""
        old_dirty = self._dirty_tiles() if delta is not None else np.zeros((0, 2), np.int64)
        self.lo = np.asarray(lo, np.int64).copy()
        # each part's storage y-range as (at most two) global y intervals inside the window
        self._yint = np.zeros((self._nparts, 2, 2), np.int64)
        my = int(self._dims[1])
        base = int(self.lo[1]) - int(self.lo[1]) % my
        wy0, wy1 = int(self.lo[1]), int(self.lo[1] + self._n[1])
        for part in range(self._nparts):
            for rep in range(2):
                a = base + rep * my + int(self._row_start[part]) * BRICK
                b = base + rep * my + int(self._row_start[part + 1]) * BRICK
                self._yint[part, rep] = (max(a, wy0), max(min(b, wy1), max(a, wy0)))
        # the linear-storage share of every window index per axis (see raytrace._trace_part)
        self._tables = _offset_tables(self.lo, self._n, self._dims)
        tv = self.tile_vox
        self._dirty_lo = self.lo[:2] // tv
        klast = (self.hi[:2] - 1) // tv
        self._dirty = np.zeros(tuple(int(v) for v in klast - self._dirty_lo + 1), np.uint8)
        self._dirty_parts = _part_records(self._nparts, self._dirty.shape)
        if len(old_dirty):
            rel = old_dirty - self._dirty_lo
            keep = np.all((rel >= 0) & (rel < self._dirty.shape), axis=1)
            self._dirty[rel[keep, 0], rel[keep, 1]] = 1
        if delta is None:
            return
        assert old_lo is not None  # a move passes both
        if delta[2] != 0:
            self._dirty[:] = 1  # cells entered or left in every column
            return
        for axis in range(2):
            if delta[axis] == 0:
                continue
            if delta[axis] > 0:
                # entering: [old_hi, new_hi); the tile of the new first column lost cells
                cols = (old_lo[axis] + self._n[axis], self.hi[axis] - 1, self.lo[axis])
            else:
                cols = (self.lo[axis], old_lo[axis] - 1, self.hi[axis] - 1)
            k0 = cols[0] // tv - self._dirty_lo[axis]
            k1 = cols[1] // tv - self._dirty_lo[axis]
            kb = cols[2] // tv - self._dirty_lo[axis]
            sel = [slice(None), slice(None)]
            sel[axis] = slice(int(k0), int(k1) + 1)
            self._dirty[tuple(sel)] = 1
            sel[axis] = slice(int(kb), int(kb) + 1)
            self._dirty[tuple(sel)] = 1

    # -- dirty tiles ------------------------------------------------------------------------

    def mark_tile_size(self, tile_vox: int) -> None:
        """Set the tile edge (voxels) of the dirty record; every tile becomes dirty."""
        tile_vox = int(tile_vox)
        if tile_vox < 1:
            raise ConfigError(f'tile_vox must be a positive number of voxels, got {tile_vox}')
        first = self.tile_vox == 0
        self.tile_vox = tile_vox
        self._dirty_lo = self.lo[:2] // tile_vox
        klast = (self.lo[:2] + self._n[:2] - 1) // tile_vox
        self._dirty = np.full(tuple(int(v) for v in klast - self._dirty_lo + 1),
                              0 if first else 1, np.uint8)
        self._dirty_parts = _part_records(self._nparts, self._dirty.shape)

    def _dirty_tiles(self) -> np.ndarray:
        idx = np.argwhere(self._dirty != 0).astype(np.int64)
        return idx + self._dirty_lo

    def pop_dirty(self) -> np.ndarray:
        """Tiles whose voxels changed since the last call, and forget them.

        A tile ``k`` covers voxels ``[k * tile_vox, (k + 1) * tile_vox)`` in x and y. The
        record is a superset: every tile in the XY box of the cells a ray visited, and every
        tile that scrolling cut or filled. Only tiles (partly) in the window are reported.
        Consumers whose inputs reach beyond a tile (padding) must widen the set themselves.

        Returns:
            (K, 2) int64 global tile indices, sorted by x then y.
        """
        out = self._dirty_tiles()
        self._dirty[:] = 0
        return out

    # -- reading ----------------------------------------------------------------------------

    def _query(self, lo: ArrayLike | None, shape: ArrayLike | None
               ) -> tuple[np.ndarray, np.ndarray]:
        q_lo = self.lo.copy() if lo is None else np.asarray(lo).reshape(-1)
        q_n = self._n.copy() if shape is None else np.asarray(shape).reshape(-1)
        if q_lo.shape != (3,) or not np.issubdtype(q_lo.dtype, np.integer):
            raise ConfigError(f'lo must be three integers, got {lo!r}')
        if q_n.shape != (3,) or not np.issubdtype(q_n.dtype, np.integer) or np.any(q_n < 0):
            raise ConfigError(f'shape must be three non-negative integers, got {shape!r}')
        return q_lo.astype(np.int64), q_n.astype(np.int64)

    @staticmethod
    def _read_chunks(size: int) -> int:
        # threads only pay for themselves on large reads (the tiler's full-map reads)
        return 8 if size >= 1 << 20 else 1

    def counts(self, lo: ArrayLike | None = None, shape: ArrayLike | None = None,
               out: tuple[np.ndarray, np.ndarray] | None = None
               ) -> tuple[np.ndarray, np.ndarray]:
        """Hit and pass counts of a box of the global lattice, in world (x, y, z) order.

        Args:
            lo: global index of the box's lower corner; default the window's.
            shape: voxels of the box per axis; default the window's shape.
            out: two C-contiguous uint32 arrays of ``shape`` to fill instead of new ones;
                reusing them saves the page faults of 100 MB of fresh memory per full read.

        Returns:
            ``(hits, passes)``, uint32 arrays of ``shape``; voxels outside the window read 0.
        """
        q_lo, q_n = self._query(lo, shape)
        if out is None:
            out_h = np.zeros(tuple(q_n), np.uint32)
            out_p = np.zeros(tuple(q_n), np.uint32)
        else:
            out_h, out_p = out
            for a in (out_h, out_p):
                if (a.shape != tuple(q_n) or a.dtype != np.uint32
                        or not a.flags.c_contiguous or not a.flags.writeable):
                    raise ConfigError(f'out must be two writeable C-contiguous uint32 arrays of '
                                      f'shape {tuple(int(v) for v in q_n)}, got {a.dtype} '
                                      f'{a.shape}')
            if np.any(q_lo < self.lo) or np.any(q_lo + q_n > self.hi):
                # only voxels outside the window are left unwritten by the read below
                out_h.fill(0)
                out_p.fill(0)
        if out_h.size:
            chunks = self._read_chunks(out_h.size)
            run_parts(_read_hot, chunks, (chunks, self._hits, self._passes, self._dims, self.lo,
                                          self._n, q_lo, q_n, _READ_COUNTS, out_h, out_p),
                      self._runner)
            if self._used.any():
                _gather_cold(self._cdir, self._pool, self._row_part, self._dims, self.lo,
                             self._n, q_lo, q_n, out_h, out_p)
        return out_h, out_p

    def density(self, lo: ArrayLike | None = None,
                shape: ArrayLike | None = None) -> np.ndarray:
        """Posterior mean density ``(hits + 1) / (hits + passes + 2)`` of a box, float32.

        Voxels outside the window (and unobserved ones) read 0.5.
        """
        q_lo, q_n = self._query(lo, shape)
        if self._used.any():
            h, p = self.counts(q_lo, q_n)
            hf = h.astype(np.float64)
            dens: np.ndarray = ((hf + 1.0) / (hf + p + 2.0)).astype(np.float32)
            return dens
        out = np.full(tuple(q_n), 0.5, np.float32)
        if out.size:
            chunks = self._read_chunks(out.size)
            run_parts(_read_hot, chunks, (chunks, self._hits, self._passes, self._dims, self.lo,
                                          self._n, q_lo, q_n, _READ_DENSITY, out, out),
                      self._runner)
        return out

    def observed(self, lo: ArrayLike | None = None,
                 shape: ArrayLike | None = None) -> np.ndarray:
        """Whether each voxel of a box was hit or passed at least once (bool)."""
        q_lo, q_n = self._query(lo, shape)
        if self._used.any():
            h, p = self.counts(q_lo, q_n)
            seen: np.ndarray = (h | p) != 0
            return seen
        out = np.zeros(tuple(q_n), bool)
        if out.size:
            chunks = self._read_chunks(out.size)
            run_parts(_read_hot, chunks, (chunks, self._hits, self._passes, self._dims, self.lo,
                                          self._n, q_lo, q_n, _READ_OBSERVED, out, out),
                      self._runner)
        return out

    def close(self) -> None:
        """End the helper threads; the map still works after this, on the caller's thread until
        a parallel step starts them again."""
        if self._runner is not None:
            self._runner.close()

    # -- state (snapshots) -------------------------------------------------------------------

    def export_state(self) -> dict[str, np.ndarray]:
        """Copies of everything the counts and the dirty record are made of (for
        :mod:`landing_zone.runtime.snapshot`): the window, the hot bytes in storage order, the cold
        blocks and the dirty tiles. :meth:`import_state` on a map of the same configuration
        restores the same counts byte for byte."""
        used = self._used.copy()
        cap = max(int(used.max()) if used.size else 0, 1)
        return {'lo': self.lo.copy(), 'tile_vox': np.array([self.tile_vox], np.int64),
                'hits': self._hits.copy(), 'passes': self._passes.copy(),
                'cdir': self._cdir.copy(), 'pool': self._pool[:, :cap].copy(), 'used': used,
                'dirty': self._dirty_tiles()}

    def import_state(self, state: dict[str, np.ndarray]) -> None:
        """Restore what :meth:`export_state` gave, on a map of the same configuration.

        Raises:
            ConfigError: the arrays do not fit this map (another shape or layout).
        """
        def arr(name: str, dtype: Any, shape: tuple[int, ...] | None) -> np.ndarray:
            a = state.get(name)
            if not isinstance(a, np.ndarray) or a.dtype != np.dtype(dtype) or (
                    shape is not None and a.shape != shape):
                got = 'missing' if a is None else f'{getattr(a, "dtype", "?")} ' \
                                                  f'{getattr(a, "shape", "?")}'
                raise ConfigError(f'map state {name!r}: expected {np.dtype(dtype)} '
                                  f'{shape if shape is not None else ""}, got {got}')
            return a

        lo = arr('lo', np.int64, (3,))
        tile_vox = arr('tile_vox', np.int64, (1,))
        if int(tile_vox[0]) != self.tile_vox:
            raise ConfigError(f'map state has tiles of {int(tile_vox[0])} voxels, this map '
                              f'{self.tile_vox}')
        hits = arr('hits', np.uint8, self._hits.shape)
        passes = arr('passes', np.uint8, self._passes.shape)
        cdir = arr('cdir', np.int32, self._cdir.shape)
        used = arr('used', np.int64, self._used.shape)
        pool = arr('pool', np.uint8, None)
        if pool.ndim != 3 or pool.shape[0] != self._nparts or pool.shape[2] != _COLD_BYTES \
                or int(used.max(initial=0)) > pool.shape[1] \
                or pool.shape[1] > self._pool_limit:
            raise ConfigError(f'map state pool of shape {pool.shape} does not fit this map')
        if int(cdir.max(initial=-1)) >= max(pool.shape[1], 1):
            raise ConfigError('map state cold-block index points past its pool')
        dirty = arr('dirty', np.int64, None)
        if dirty.ndim != 2 or dirty.shape[1] != 2:
            raise ConfigError(f'map state dirty tiles of shape {dirty.shape}, expected (K, 2)')
        self._place(np.asarray(lo, np.int64))
        self._hits[:] = hits
        self._passes[:] = passes
        self._cdir[:] = cdir
        cap = max(self._pool.shape[1], pool.shape[1])
        self._pool = np.zeros((self._nparts, cap, _COLD_BYTES), np.uint8)
        self._pool[:, :pool.shape[1]] = pool
        self._used[:] = used
        self._z_floor = int(self.lo[2])  # not recorded: any level may hold counts
        self._dirty[:] = 0
        rel = dirty - self._dirty_lo
        keep = np.all((rel >= 0) & (rel < self._dirty.shape), axis=1)
        self._dirty[rel[keep, 0], rel[keep, 1]] = 1

    def clear(self) -> None:
        """Forget every count (the window stays where it is)."""
        self._z_floor = _NOTHING
        self._hits.fill(0)
        self._passes.fill(0)
        self._cdir.fill(-1)
        self._pool.fill(0)
        self._used.fill(0)
        self._dirty[:] = 1

    def __repr__(self) -> str:
        lo_m, hi_m = self.bounds
        return (f'DensityMap(shape={self.shape}, voxel_size={self.voxel_size}, '
                f'lo={self.lo.tolist()}, box=[{lo_m.round(3).tolist()}, '
                f'{hi_m.round(3).tolist()}] m, {self.nbytes / 1e6:.1f} MB)')


def _part_records(nparts: int, shape: tuple[int, ...]) -> np.ndarray:
    """One dirty-tile record per part, 64 bytes apart so the threads never share a line."""
    pad = 64 // max(shape[1], 1) + 1
    return np.zeros((nparts, shape[0] + pad, shape[1]), np.uint8)


def _offset_tables(lo: np.ndarray, n: np.ndarray, dims: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per axis, the linear storage offset of window index ``lo + i`` (ring, brick, cell)."""
    sz_stride = _BRICK_VOX
    sy_stride = int(dims[2] // BRICK) * sz_stride
    sx_stride = int(dims[1] // BRICK) * sy_stride
    out = []
    for axis, (stride, inner) in enumerate(((sx_stride, 16), (sy_stride, 4), (sz_stride, 1))):
        s = (lo[axis] + np.arange(n[axis], dtype=np.int64)) % dims[axis]
        out.append((s >> 2) * stride + (s & 3) * inner)
    return out[0], out[1], out[2]


def _ring_ranges(g0: int, g1: int, m: int) -> list[tuple[int, int]]:
    """Storage ranges (no wrap) of the global range [g0, g1) in a ring of m (g1 - g0 <= m)."""
    if g1 <= g0:
        return []
    s0 = g0 % m
    length = g1 - g0
    if s0 + length <= m:
        return [(s0, s0 + length)]
    return [(s0, m), (0, s0 + length - m)]


def _as_points(arr: ArrayLike, name: str, allow_single: bool = False) -> np.ndarray:
    """Validate an (N, 3) (or (3,)) numeric array; C-contiguous float64 out."""
    try:
        a = np.asarray(arr)
    except (TypeError, ValueError) as err:
        raise InvalidCloudError(f'{name} must be a numeric array, got {type(arr).__name__}') \
            from err
    if a.dtype.kind not in 'fiu':
        raise InvalidCloudError(f'{name} must be numeric, got dtype {a.dtype}')
    if allow_single and a.shape == (3,):
        a = a.reshape(1, 3)
    if a.ndim != 2 or a.shape[1] != 3:
        want = '(3,) or (N, 3)' if allow_single else '(N, 3)'
        raise InvalidCloudError(f'{name} must have shape {want}, got {a.shape}')
    # one compiled specialisation: float32 clouds are widened here (exactly; a 10k-point
    # copy costs microseconds), and the kernel divides float64 by float64 either way
    return np.ascontiguousarray(a, dtype=np.float64)
