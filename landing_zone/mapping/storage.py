"""The map's count storage: a ring buffer of hot bytes in bricks, cold blocks for large counts.

Every voxel has one ``uint8`` of hits and one of passes (the hot bytes), stored in 4 x 4 x 4
bricks of 64 bytes (one cache line) with storage index ``g mod M`` per axis, so moving the
window clears only the slabs that enter it. A brick whose counts went past 255 gets a 128-byte
cold block (the high bytes of its hits, then of its passes) from its part's pool, named by the
brick's entry of the cold-block index (-1: none). These are the compiled operations on that
layout: reading a box, clearing slabs, compacting the pools; the walk that writes the counts is
:mod:`landing_zone.mapping.raytrace`'s.
"""
from __future__ import annotations

import numba as nb
import numpy as np
from typing import Any

from numpy.typing import ArrayLike, DTypeLike

from landing_zone.errors import ConfigError
from landing_zone.mapping.raytrace import BRICK

__all__ = ['BRICK_VOX', 'COLD_BYTES', 'READ_COUNTS', 'READ_DENSITY', 'READ_OBSERVED',
           'round_up', 'aligned_zeros', 'window_tables', 'read_hot', 'gather_cold', 'clear_hot',
           'clear_cold', 'compact_cold', 'offset_tables', 'ring_ranges', 'box_query',
           'read_chunks', 'state_array', 'cold_state']

BRICK_VOX = BRICK ** 3
COLD_BYTES = 2 * BRICK_VOX  # high bytes of the hits, then of the passes, of one brick


def round_up(n: int, m: int) -> int:
    return (n + m - 1) // m * m


def aligned_zeros(n: int, dtype: DTypeLike, align: int = 64) -> np.ndarray:
    """Zeroed 1-D array whose data starts on a cache-line boundary (bricks = whole lines).

    The zeros are written, not just mapped: the pages are committed now rather than faulted in
    one by one while the first clouds are integrated.
    """
    itemsize = np.dtype(dtype).itemsize
    raw = np.empty(n * itemsize + align, np.uint8)
    raw.fill(0)
    start = (-raw.ctypes.data) % align
    return raw[start:start + n * itemsize].view(dtype)


@nb.njit(cache=True, nogil=True)
def window_tables(dims, wlo, wn, qlo, qn):  # type: ignore[no-untyped-def]
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


# what read_hot writes
READ_COUNTS = 0  # the hot bytes of hits and passes (out_a, out_b)
READ_DENSITY = 1  # (h + 1) / (h + p + 2) as float32 (out_a)
READ_OBSERVED = 2  # h + p > 0 (out_a)


@nb.njit(cache=True, nogil=True)
def read_hot(  # type: ignore[no-untyped-def]
        chunk, nchunks, hits, passes, dims, wlo, wn, qlo, qn, what, out_a, out_b):
    """Read the hot bytes of the requested box (global indices) in logical order: the counts
    into ``out_a`` / ``out_b``, or the density or observed flags computed from them into
    ``out_a`` (valid while no cold block exists). Chunk ``chunk`` of ``nchunks`` along x.

    One walk over the storage layout for the three reads; ``what`` is constant per call, so
    the compiler takes the branch out of the inner loop."""
    r0, r1, offy, offz, sx_stride = window_tables(dims, wlo, wn, qlo, qn)
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
                if what == READ_COUNTS:
                    out_a[i, j, k] = h
                    out_b[i, j, k] = p
                elif what == READ_DENSITY:
                    hf = np.float64(h)
                    out_a[i, j, k] = np.float32((hf + 1.0) / (hf + np.float64(p) + 2.0))
                else:
                    out_a[i, j, k] = (h | p) != 0


@nb.njit(cache=True)
def gather_cold(  # type: ignore[no-untyped-def]
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


def clear_hot(arr: np.ndarray, dims: np.ndarray, axis: int, s0: int, s1: int) -> None:
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
def clear_cold(cdir, pool, row_part, dims, s0, s1):  # type: ignore[no-untyped-def]
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
def compact_cold(cdir, pool, used, row_part, dims):  # type: ignore[no-untyped-def]
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


def offset_tables(lo: np.ndarray, n: np.ndarray, dims: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per axis, the linear storage offset of window index ``lo + i`` (ring, brick, cell)."""
    sz_stride = BRICK_VOX
    sy_stride = int(dims[2] // BRICK) * sz_stride
    sx_stride = int(dims[1] // BRICK) * sy_stride
    out = []
    for axis, (stride, inner) in enumerate(((sx_stride, 16), (sy_stride, 4), (sz_stride, 1))):
        s = (lo[axis] + np.arange(n[axis], dtype=np.int64)) % dims[axis]
        out.append((s >> 2) * stride + (s & 3) * inner)
    return out[0], out[1], out[2]


def ring_ranges(g0: int, g1: int, m: int) -> list[tuple[int, int]]:
    """Storage ranges (no wrap) of the global range [g0, g1) in a ring of m (g1 - g0 <= m)."""
    if g1 <= g0:
        return []
    s0 = g0 % m
    length = g1 - g0
    if s0 + length <= m:
        return [(s0, s0 + length)]
    return [(s0, m), (0, s0 + length - m)]


def box_query(lo: ArrayLike | None, shape: ArrayLike | None, window_lo: np.ndarray,
              window_n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A box to read, checked: its lower corner and shape (default the window's), int64."""
    q_lo = window_lo.copy() if lo is None else np.asarray(lo).reshape(-1)
    q_n = window_n.copy() if shape is None else np.asarray(shape).reshape(-1)
    if q_lo.shape != (3,) or not np.issubdtype(q_lo.dtype, np.integer):
        raise ConfigError(f'lo must be three integers, got {lo!r}')
    if q_n.shape != (3,) or not np.issubdtype(q_n.dtype, np.integer) or np.any(q_n < 0):
        raise ConfigError(f'shape must be three non-negative integers, got {shape!r}')
    return q_lo.astype(np.int64), q_n.astype(np.int64)


def read_chunks(size: int) -> int:
    """Parts a read of ``size`` voxels is split into: threads only pay for themselves on large
    reads (the tiler's full-map reads)."""
    return 8 if size >= 1 << 20 else 1


def state_array(state: dict[str, np.ndarray], name: str, dtype: Any,
                shape: tuple[int, ...] | None) -> np.ndarray:
    """``state[name]``, checked to be an array of ``dtype`` (and ``shape``, if given).

    Raises:
        ConfigError: missing, or of another dtype or shape.
    """
    a = state.get(name)
    if not isinstance(a, np.ndarray) or a.dtype != np.dtype(dtype) or (
            shape is not None and a.shape != shape):
        got = 'missing' if a is None else f'{getattr(a, "dtype", "?")} ' \
                                          f'{getattr(a, "shape", "?")}'
        raise ConfigError(f'map state {name!r}: expected {np.dtype(dtype)} '
                          f'{shape if shape is not None else ""}, got {got}')
    return a


def cold_state(state: dict[str, np.ndarray], cdir_shape: tuple[int, ...],
               used_shape: tuple[int, ...], pool_limit: int
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The cold-block index, pools and their fill of a saved state, checked against a storage
    of ``cdir_shape``, ``used_shape`` (one entry per part) and ``pool_limit`` blocks a part.

    Raises:
        ConfigError: they do not fit, or the index points past the pools.
    """
    cdir = state_array(state, 'cdir', np.int32, cdir_shape)
    used = state_array(state, 'used', np.int64, used_shape)
    pool = state_array(state, 'pool', np.uint8, None)
    if pool.ndim != 3 or pool.shape[0] != used_shape[0] or pool.shape[2] != COLD_BYTES \
            or int(used.max(initial=0)) > pool.shape[1] or pool.shape[1] > pool_limit:
        raise ConfigError(f'map state pool of shape {pool.shape} does not fit this map')
    if int(cdir.max(initial=-1)) >= max(pool.shape[1], 1):
        raise ConfigError('map state cold-block index points past its pool')
    return cdir, pool, used
