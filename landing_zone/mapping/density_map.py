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

import numpy as np
from numpy.typing import ArrayLike

from landing_zone.config import MapConfig
from landing_zone.errors import ConfigError, InvalidCloudError
from landing_zone.mapping.dirty import DirtyTiles
from landing_zone.mapping.parts import PartRunner, run_parts
from landing_zone.mapping.raytrace import BRICK, PARTS, trace_rays
from landing_zone.mapping.rays import SORT_TILE, IntegrationStats, as_points, prepare_rays
from landing_zone.mapping.storage import (BRICK_VOX, COLD_BYTES, READ_COUNTS, READ_DENSITY,
                                          READ_OBSERVED, aligned_zeros, clear_cold, clear_hot,
                                          box_query, compact_cold, gather_cold, offset_tables,
                                          read_chunks, read_hot, ring_ranges, round_up,
                                          cold_state, state_array)

__all__ = ['DensityMap']

# Below this many rays a batch is walked on the calling thread alone: waking a helper costs
# more than it saves.
_PARALLEL_MIN_RAYS = 2048
_NOTHING = 2 ** 62  # the z floor of a map no ray has touched


class DensityMap:
    """Scrolling voxel map of hit and pass counts, the input of the tiler.

    Memory (:mod:`landing_zone.mapping.storage`): 2.07 bytes per voxel (26.5 MB for the default
    400 x 400 x 80) until counts grow past 255, at most 4.07 should every brick overflow.

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
        self._dims = np.array([round_up(v, BRICK) for v in self.shape], np.int64)
        # Storage brick rows along y are dealt out to the parts in contiguous slabs.
        rows = int(self._dims[1] // BRICK)
        self._nparts = min(PARTS, rows)
        self._row_start = np.array([k * rows // self._nparts for k in range(self._nparts + 1)],
                                   np.int64)
        self._row_part = np.repeat(np.arange(self._nparts, dtype=np.int64),
                                   np.diff(self._row_start))
        nvox = int(np.prod(self._dims))
        self._hits = aligned_zeros(nvox, np.uint8)
        self._passes = aligned_zeros(nvox, np.uint8)
        self._cdir = np.full(nvox // BRICK_VOX, -1, np.int32)
        # the most cold blocks one ray can claim in one part (see raytrace._trace_part)
        self._worst = int(self._dims.sum() // BRICK + 6)
        # a part never needs more cold blocks than it has bricks
        self._pool_limit = int(np.diff(self._row_start).max() * (self._dims[0] // BRICK)
                               * (self._dims[2] // BRICK))
        self._pool = np.zeros((self._nparts, min(self._worst, self._pool_limit), COLD_BYTES),
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
        self._dirty = DirtyTiles(self._nparts)
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
                   + self._pool.nbytes + self._used.nbytes + self._dirty.nbytes)

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
        pts = as_points(points, 'points')
        n = pts.shape[0]
        org = as_points(origins, 'origins', allow_single=True)
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
                       self._dirty.parts, self._dirty.lo, self.tile_vox, counters,
                       runner=self._runner if nvalid >= _PARALLEL_MIN_RAYS else None)
            if np.all(resume >= 2 * nvalid):
                break
            # a part stopped before a ray that might not find a free cold block: grow, resume
            self._grow_pool()
        self._dirty.merge_parts()
        stats.voxels = int(counters[:, 1].sum())
        return stats

    def _grow_pool(self) -> None:
        cap = self._pool.shape[1]
        pool = np.zeros((self._nparts, min(2 * cap, self._pool_limit), COLD_BYTES), np.uint8)
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
            self._dirty.grid[:] = 1
            return int(np.prod(n))
        for axis in range(3):
            if delta[axis] == 0:
                continue
            if delta[axis] > 0:
                g0, g1 = old_lo[axis] + n[axis], new[axis] + n[axis]
            else:
                g0, g1 = new[axis], old_lo[axis]
            for s0, s1 in ring_ranges(g0, g1, int(self._dims[axis])):
                clear_hot(self._hits, self._dims, axis, s0, s1)
                clear_hot(self._passes, self._dims, axis, s0, s1)
                if self._used.any():
                    a = np.zeros(3, np.int64)
                    b = self._dims.copy()
                    a[axis], b[axis] = s0, s1
                    clear_cold(self._cdir, self._pool, self._row_part, self._dims, a, b)
        if self._used.any():
            compact_cold(self._cdir, self._pool, self._used, self._row_part, self._dims)
        self._place(new, delta=delta, old_lo=old_lo)
        entered = int(np.prod(n)) - int(np.prod(n - np.abs(delta)))
        return entered

    def _place(self, lo: np.ndarray, delta: np.ndarray | None = None,
               old_lo: np.ndarray | None = None) -> None:
        """Set ``lo`` and everything derived from it; carry the dirty record over."""
        old_dirty = self._dirty.tiles() if delta is not None else None
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
        self._tables = offset_tables(self.lo, self._n, self._dims)
        self._dirty.resize(self.lo, self._n, self.tile_vox, 0)
        if old_dirty is not None and len(old_dirty):
            self._dirty.mark(old_dirty)
        if delta is None:
            return
        assert old_lo is not None  # a move passes both
        self._dirty.scrolled(delta, old_lo, self.lo, self.hi, self._n)

    # -- dirty tiles ------------------------------------------------------------------------

    @property
    def tile_vox(self) -> int:
        """Voxels per side of the tiles whose changes :meth:`pop_dirty` reports."""
        return self._dirty.tile_vox

    def mark_tile_size(self, tile_vox: int) -> None:
        """Set the tile edge (voxels) of the dirty record; every tile becomes dirty."""
        tile_vox = int(tile_vox)
        if tile_vox < 1:
            raise ConfigError(f'tile_vox must be a positive number of voxels, got {tile_vox}')
        first = self._dirty.tile_vox == 0
        self._dirty.resize(self.lo, self._n, tile_vox, 0 if first else 1)

    def pop_dirty(self) -> np.ndarray:
        """Tiles whose voxels changed since the last call, and forget them.

        A tile ``k`` covers voxels ``[k * tile_vox, (k + 1) * tile_vox)`` in x and y. The
        record is a superset: every tile in the XY box of the cells a ray visited, and every
        tile that scrolling cut or filled. Only tiles (partly) in the window are reported.
        Consumers whose inputs reach beyond a tile (padding) must widen the set themselves.

        Returns:
            (K, 2) int64 global tile indices, sorted by x then y.
        """
        return self._dirty.pop()

    # -- reading ----------------------------------------------------------------------------

    def _query(self, lo: ArrayLike | None, shape: ArrayLike | None
               ) -> tuple[np.ndarray, np.ndarray]:
        return box_query(lo, shape, self.lo, self._n)

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
            chunks = read_chunks(out_h.size)
            run_parts(read_hot, chunks, (chunks, self._hits, self._passes, self._dims, self.lo,
                                         self._n, q_lo, q_n, READ_COUNTS, out_h, out_p),
                      self._runner)
            if self._used.any():
                gather_cold(self._cdir, self._pool, self._row_part, self._dims, self.lo,
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
            chunks = read_chunks(out.size)
            run_parts(read_hot, chunks, (chunks, self._hits, self._passes, self._dims, self.lo,
                                         self._n, q_lo, q_n, READ_DENSITY, out, out),
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
            chunks = read_chunks(out.size)
            run_parts(read_hot, chunks, (chunks, self._hits, self._passes, self._dims, self.lo,
                                         self._n, q_lo, q_n, READ_OBSERVED, out, out),
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
                'dirty': self._dirty.tiles()}

    def import_state(self, state: dict[str, np.ndarray]) -> None:
        """Restore what :meth:`export_state` gave, on a map of the same configuration.

        Raises:
            ConfigError: the arrays do not fit this map (another shape or layout).
        """
        lo = state_array(state, 'lo', np.int64, (3,))
        tile_vox = state_array(state, 'tile_vox', np.int64, (1,))
        if int(tile_vox[0]) != self.tile_vox:
            raise ConfigError(f'map state has tiles of {int(tile_vox[0])} voxels, this map '
                              f'{self.tile_vox}')
        hits = state_array(state, 'hits', np.uint8, self._hits.shape)
        passes = state_array(state, 'passes', np.uint8, self._passes.shape)
        cdir, pool, used = cold_state(state, self._cdir.shape, self._used.shape,
                                      self._pool_limit)
        dirty = state_array(state, 'dirty', np.int64, None)
        if dirty.ndim != 2 or dirty.shape[1] != 2:
            raise ConfigError(f'map state dirty tiles of shape {dirty.shape}, expected (K, 2)')
        self._place(np.asarray(lo, np.int64))
        self._hits[:] = hits
        self._passes[:] = passes
        self._cdir[:] = cdir
        cap = max(self._pool.shape[1], pool.shape[1])
        self._pool = np.zeros((self._nparts, cap, COLD_BYTES), np.uint8)
        self._pool[:, :pool.shape[1]] = pool
        self._used[:] = used
        self._z_floor = int(self.lo[2])  # not recorded: any level may hold counts
        self._dirty.grid[:] = 0
        self._dirty.mark(dirty)

    def clear(self) -> None:
        """Forget every count (the window stays where it is)."""
        self._z_floor = _NOTHING
        self._hits.fill(0)
        self._passes.fill(0)
        self._cdir.fill(-1)
        self._pool.fill(0)
        self._used.fill(0)
        self._dirty.grid[:] = 1

    def __repr__(self) -> str:
        lo_m, hi_m = self.bounds
        return (f'DensityMap(shape={self.shape}, voxel_size={self.voxel_size}, '
                f'lo={self.lo.tolist()}, box=[{lo_m.round(3).tolist()}, '
                f'{hi_m.round(3).tolist()}] m, {self.nbytes / 1e6:.1f} MB)')
