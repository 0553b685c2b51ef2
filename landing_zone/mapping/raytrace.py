"""Exact 3D voxel traversal of LiDAR rays into hit / pass counts (the compiled hot loop).

Each return is a segment from its sensor origin ``o`` to the return ``p``. In lattice units
(``u = p / voxel_size``, computed in float64) voxel ``g`` is the half-open cell ``[g, g + 1)``
per axis (the floor convention of docs/ARCHITECTURE.md). The return's voxel ``floor(p)`` gets a
hit; every other cell the closed segment meets gets a pass. That one rule settles every tie:

* a point exactly on a face belongs to the cell above it (``floor``);
* a ray through an edge or a corner passes the cells that hold the crossing point itself, so
  where all tied axes move the same way (all up or all down) no zero-length cell is added, and
  where one moves up and another down at the same instant, the cell holding the crossing point
  (up-axes already stepped, down-axes not yet) is passed;
* a ray along a face (``x == 3.0`` exactly) lies in the cells above that face.

The walk is Amanatides & Woo's, made exact in its order of events: the parameter of every plane
crossing is computed afresh as ``(plane - o) / d`` (a correctly rounded division, never an
accumulated sum), so crossings that coincide compare equal whenever the coordinates are exact in
binary (a dyadic voxel size and points, as in the tests), and a ray clipped to any box visits
exactly the cells the unclipped walk would visit there. Distinct crossings closer than float64
rounding (1e-16 relative) may be ordered either way. Each ray is first clipped to the map's box
(only the part inside it costs anything), then to each part of the map in turn.

Why by hand: no library walks rays through a scrolling voxel grid with hit/pass counts; OctoMap
(the closest) is 100x slower here (`landing-zone bench integrate`) and keeps log-odds in an octree.

Storage (owned by :class:`landing_zone.mapping.density_map.DensityMap`): a ring buffer indexed by
``g mod M`` per axis, laid out in 4 x 4 x 4 bricks of 64 consecutive bytes (one cache line per
brick), so a ray's consecutive voxels and the voxels of neighbouring rays share cache lines.
Counts are a hot ``uint8`` array per kind (hits, passes) plus a sparse cold array of high bytes:
a brick gets a 128-byte cold block (64 high bytes for hits, 64 for passes) from its thread's pool
only when one of its counters first wraps past 255. Totals saturate at 65535.

The map is split into ``PARTS`` slabs along storage y (whole brick rows each). A part walks the
piece of every ray inside its slab and touches only its own bricks and its own cold pool, so
parts can run on different threads with no atomics and no races (numba has no atomics); they
run on a :class:`~landing_zone.mapping.parts.PartRunner`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numba as nb
import numpy as np

from landing_zone.mapping.parts import PartRunner, run_parts

__all__ = [
    'IntegrationStats',
    'PARTS',
    'BRICK',
    'COUNT_MAX',
    'MAX_LATTICE_COORD',
    'SORT_TILE',
    'prepare_rays',
    'trace_rays',
]

PARTS = 4  # storage slabs along y; threads take them one at a time (NUMBA_NUM_THREADS=1 too)
BRICK = 4  # edge of a storage brick in voxels; 4^3 uint8 = one 64-byte cache line
COUNT_MAX = 65535  # hits and passes saturate here (hot low byte + cold high byte)
# Rays with a coordinate beyond this many voxels from the lattice origin (5e10 m at 5 cm) are
# dropped as non-finite: their lattice indices would not fit the integer arithmetic.
MAX_LATTICE_COORD = float(2 ** 40)
SORT_TILE = 16  # voxels per side of the XY cells the batch is counting-sorted by

_INF = np.inf


@dataclass
class IntegrationStats:
    """What happened to the returns of one or more batches.

    ``returns = integrated + nonfinite + degenerate + missed``.

    Attributes:
        returns: rows given.
        integrated: rays that touched at least one voxel of the map.
        nonfinite: rows dropped because the point or its origin was NaN/Inf (or absurdly far).
        degenerate: rows dropped because the point equals its origin (a zero-length ray).
        missed: rays whose whole segment lies outside the map.
        outside_hits: integrated rays whose return lies outside the map (passes only, no hit).
        voxels: voxel updates made (passes plus hits), the cost of the batch.
    """

    returns: int = 0
    integrated: int = 0
    nonfinite: int = 0
    degenerate: int = 0
    missed: int = 0
    outside_hits: int = 0
    voxels: int = 0

    def __add__(self, other: IntegrationStats) -> IntegrationStats:
        if not isinstance(other, IntegrationStats):
            return NotImplemented
        return IntegrationStats(*(getattr(self, f.name) + getattr(other, f.name)
                                  for f in fields(self)))

    @property
    def dropped(self) -> int:
        """Rows that could not be used at all (non-finite or zero-length)."""
        return self.nonfinite + self.degenerate


# --- per-axis pieces of the clip (scalars only: numba inlines them without array overhead) ---

@nb.njit(cache=True, inline='always', error_model='numpy')
def _axis_entry(o: float, d: float, g0: int, g1: int, blo: int, bhi: int
                ) -> tuple[float, int, bool]:
    """The event that brings one axis into [blo, bhi): (t, class, possible).

    Class 0: an up-step (the new cell holds the crossing point); class 1: a down-step (the
    new cell starts just after it). Events order by (t, class).
    """
    if blo <= g0 < bhi:
        return -_INF, 0, True
    if g0 < blo:
        if g1 < blo:
            return _INF, 0, False
        return (blo - o) / d, 0, True
    if g1 >= bhi:
        return _INF, 0, False
    return (bhi - o) / d, 1, True


@nb.njit(cache=True, inline='always', error_model='numpy')
def _axis_state(o: float, d: float, g0: int, g1: int, te: float, ce: int) -> int:
    """Cell of one axis once all its events up to (te, ce) in (t, class) order have happened."""
    if g1 == g0 or te == -_INF:
        return g0
    est = o + te * d
    if not (est > -MAX_LATTICE_COORD and est < MAX_LATTICE_COORD):
        est = o
    c = int(math.floor(est))
    lo = min(g0, g1)
    hi = max(g0, g1)
    # Fast path: the position at te is far (beyond any rounding of est or of the crossing
    # parameters) from every plane, so the cell is floor(est) whatever the direction.
    frac = est - c
    margin = 1e-9 * (abs(o) + abs(d) + 1.0)
    if margin < frac < 1.0 - margin:
        return min(max(c, lo), hi)
    c = min(max(c, lo), hi)
    # Near a plane: count the events exactly with the walk's own formula for their parameter.
    if g1 > g0:
        # up: the event into cell c + 1 is at plane c + 1, class 0 (counted when t <= te)
        while c < g1 and (c + 1 - o) / d <= te:
            c += 1
        while c > g0 and (c - o) / d > te:
            c -= 1
    else:
        # down: the event out of cell c is at plane c, class 1 (counted when (t, 1) <= (te, ce))
        while c > g1:
            t = (c - o) / d
            if t < te or (t == te and ce == 1):
                c -= 1
            else:
                break
        while c < g0:
            t = (c + 1 - o) / d
            if t < te or (t == te and ce == 1):
                break
            c += 1
    return c


@nb.njit(cache=True, inline='always', error_model='numpy')
def _first_cell(  # type: ignore[no-untyped-def]
        ox, oy, oz, dx, dy, dz, g0x, g0y, g0z, g1x, g1y, g1z,
        blx, bly, blz, bhx, bhy, bhz):
    """First cell of the segment inside the box [bl, bh): (inside, cx, cy, cz)."""
    tx, kx, okx = _axis_entry(ox, dx, g0x, g1x, blx, bhx)
    ty, ky, oky = _axis_entry(oy, dy, g0y, g1y, bly, bhy)
    tz, kz, okz = _axis_entry(oz, dz, g0z, g1z, blz, bhz)
    if not (okx and oky and okz):
        return False, 0, 0, 0
    # the last axis to come in decides the entry event; its own cell is the box's face cell
    te, ce, axis = tx, kx, 0
    if ty > te or (ty == te and ky > ce):
        te, ce, axis = ty, ky, 1
    if tz > te or (tz == te and kz > ce):
        te, ce, axis = tz, kz, 2
    if te == -_INF:
        return True, g0x, g0y, g0z  # the origin is inside
    if axis == 0:
        cx = blx if kx == 0 else bhx - 1
    else:
        cx = _axis_state(ox, dx, g0x, g1x, te, ce)
    if axis == 1:
        cy = bly if ky == 0 else bhy - 1
    else:
        cy = _axis_state(oy, dy, g0y, g1y, te, ce)
    if axis == 2:
        cz = blz if kz == 0 else bhz - 1
    else:
        cz = _axis_state(oz, dz, g0z, g1z, te, ce)
    # another axis may already have left the box by then: the segment only grazes past it
    inside = blx <= cx < bhx and bly <= cy < bhy and blz <= cz < bhz
    return inside, cx, cy, cz


# --- batch preparation -------------------------------------------------------------------------

# nogil: the node's executor thread takes messages while a cloud is prepared here
@nb.njit(cache=True, nogil=True, error_model='numpy')
def _prepare(  # type: ignore[no-untyped-def]
        points, origins, voxel_size, blo, bhi, sort_tile, uo, up, order, key):
    n = points.shape[0]
    single = origins.shape[0] == 1
    nonfinite = 0
    degenerate = 0
    missed = 0
    outside = 0
    nvalid = 0
    kx_n = (bhi[0] - blo[0] + sort_tile - 1) // sort_tile
    ky_n = (bhi[1] - blo[1] + sort_tile - 1) // sort_tile
    counts = np.zeros(kx_n * ky_n + 1, np.int64)
    lim = MAX_LATTICE_COORD
    for i in range(n):
        j = 0 if single else i
        # the same correctly rounded division as the reference: u = p / voxel_size
        ax = points[i, 0] / voxel_size
        ay = points[i, 1] / voxel_size
        az = points[i, 2] / voxel_size
        bx = origins[j, 0] / voxel_size
        by = origins[j, 1] / voxel_size
        bz = origins[j, 2] / voxel_size
        ok = True
        for v in (ax, ay, az, bx, by, bz):
            if not (v > -lim and v < lim):  # False for NaN too
                ok = False
        if not ok:
            nonfinite += 1
            key[i] = -1
            continue
        if ax == bx and ay == by and az == bz:
            degenerate += 1
            key[i] = -1
            continue
        g0x = int(math.floor(bx))
        g0y = int(math.floor(by))
        g0z = int(math.floor(bz))
        g1x = int(math.floor(ax))
        g1y = int(math.floor(ay))
        g1z = int(math.floor(az))
        inside, cx, cy, cz = _first_cell(bx, by, bz, ax - bx, ay - by, az - bz,
                                         g0x, g0y, g0z, g1x, g1y, g1z,
                                         blo[0], blo[1], blo[2], bhi[0], bhi[1], bhi[2])
        if not inside:
            missed += 1
            key[i] = -1
            continue
        if not (blo[0] <= g1x < bhi[0] and blo[1] <= g1y < bhi[1] and blo[2] <= g1z < bhi[2]):
            outside += 1
        uo[i, 0] = bx
        uo[i, 1] = by
        uo[i, 2] = bz
        up[i, 0] = ax
        up[i, 1] = ay
        up[i, 2] = az
        # sort by the XY cell of the return, clamped into the map: rays that end close
        # together share most of their cache lines near the ground
        qx = min(max(g1x, blo[0]), bhi[0] - 1) - blo[0]
        qy = min(max(g1y, blo[1]), bhi[1] - 1) - blo[1]
        k = (qx // sort_tile) * ky_n + qy // sort_tile
        key[i] = k
        counts[k + 1] += 1
        nvalid += 1
    # counting sort of the valid rays by key (stable, O(n))
    for k in range(1, counts.shape[0]):
        counts[k] += counts[k - 1]
    for i in range(n):
        k = key[i]
        if k >= 0:
            order[counts[k]] = i
            counts[k] += 1
    return nvalid, nonfinite, degenerate, missed, outside


def prepare_rays(points: np.ndarray, origins: np.ndarray, voxel_size: float,
                 box_lo: np.ndarray, box_hi: np.ndarray, sort_tile: int = SORT_TILE
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, int, np.ndarray]:
    """Convert a batch to lattice units, drop what cannot be traced, sort the rest.

    Args:
        points: (N, 3) float32/float64 returns [m].
        origins: (N, 3) or (1, 3) sensor origins [m].
        voxel_size: lattice spacing [m].
        box_lo: (3,) int64, first voxel of the map window (global lattice index).
        box_hi: (3,) int64, one past the last voxel of the window.
        sort_tile: XY cell size (voxels) of the counting sort.

    Returns:
        ``(uo, up, order, nvalid, counts)``: origins and points in lattice units (N, 3)
        float64 (rows of dropped rays undefined), the indices of the traceable rays sorted by
        the XY cell of their return (first ``nvalid`` entries), and the tuple
        ``(nvalid, nonfinite, degenerate, missed, outside_hits)``.
    """
    n = points.shape[0]
    uo = np.empty((n, 3), np.float64)
    up = np.empty((n, 3), np.float64)
    order = np.empty(n, np.int64)
    key = np.empty(n, np.int64)
    res = _prepare(points, origins, float(voxel_size), box_lo, box_hi, int(sort_tile),
                   uo, up, order, key)
    return uo, up, order, res[0], res


# --- the walk ----------------------------------------------------------------------------------

@nb.njit(cache=True, nogil=True, error_model='numpy')
def _carry(hot, cold_at, idx, cdir, pool, used, part):  # type: ignore[no-untyped-def]
    """A hot byte at 255 gets one more count: carry into its brick's cold block.

    Rare (once per 256 counts of a voxel at most), so a call is fine here; the block is taken
    from the pool of the thread's own part, which the caller made sure has room.
    """
    brick = idx >> 6
    slot = cdir[brick]
    if slot < 0:
        slot = used[part]
        used[part] = slot + 1
        cdir[brick] = slot
    w = cold_at + (idx & 63)
    high = pool[part, slot, w]
    if high != 255:
        pool[part, slot, w] = high + 1
        hot[idx] = 0
    # else: 65535 reached, the count saturates


@nb.njit(cache=True, nogil=True, error_model='numpy')
def _trace_part(  # type: ignore[no-untyped-def]
        part, uo, up, order, nvalid, blo, bhi, yint, wlo, tabx, taby, tabz, hits,
        passes, cdir, pool, pool_limit, used, resume, dirty, dlo, tile_vox, counters):
    """Walk the part of every ray inside the storage slab ``part`` owns.

    ``tabx[g - wlo[0]]`` (and y, z) is the share of axis index ``g`` in the linear storage
    index (ring position, brick, place in the brick), so a step is one table load.

    One function on purpose: numba adds reference counting around calls that take arrays, and
    that per-voxel cost would dominate the walk.
    """
    # a ray can need at most one new cold block per brick it visits
    worst = (tabx.shape[0] + taby.shape[0] + tabz.shape[0]) // BRICK + 6
    cap = pool.shape[1]
    wx0 = wlo[0]
    wy0 = wlo[1]
    wz0 = wlo[2]
    nh = counters[part, 0]
    nv = counters[part, 1]
    pos = resume[part]
    total = 2 * nvalid
    while pos < total:
        iv = pos // nvalid
        jj = pos - iv * nvalid
        bly = yint[part, iv, 0]
        bhy = yint[part, iv, 1]
        if bly >= bhy:
            pos = (iv + 1) * nvalid
            continue
        if used[part] + min(worst, pool_limit - used[part]) > cap:
            break  # the caller grows the pool (up to pool_limit blocks) and resumes here
        pos += 1
        i = order[jj]
        ox = uo[i, 0]
        oy = uo[i, 1]
        oz = uo[i, 2]
        px = up[i, 0]
        py = up[i, 1]
        pz = up[i, 2]
        g0y = int(math.floor(oy))
        g1y = int(math.floor(py))
        # cheap reject: the ray's y-range misses this slab
        if (g0y < bly and g1y < bly) or (g0y >= bhy and g1y >= bhy):
            continue
        dx = px - ox
        dy = py - oy
        dz = pz - oz
        g0x = int(math.floor(ox))
        g0z = int(math.floor(oz))
        g1x = int(math.floor(px))
        g1z = int(math.floor(pz))
        inside, cx, cy, cz = _first_cell(ox, oy, oz, dx, dy, dz, g0x, g0y, g0z, g1x, g1y, g1z,
                                         blo[0], bly, blo[2], bhi[0], bhy, bhi[2])
        if not inside:
            continue
        startx = cx
        starty = cy
        # Per axis: step direction, the plane offset of the next event (1 up, 0 down), the last
        # cell of the walk in this box (the return's cell or the box's face cell), and the next
        # event's parameter (inf once the axis has reached the return's cell).
        if g1x > g0x:
            stx = 1
            upx = 1
            lastx = min(g1x, bhi[0] - 1)
        else:
            stx = -1
            upx = 0
            lastx = max(g1x, blo[0])
        if g1y > g0y:
            sty = 1
            upy = 1
            lasty = min(g1y, bhy - 1)
        else:
            sty = -1
            upy = 0
            lasty = max(g1y, bly)
        if g1z > g0z:
            stz = 1
            upz = 1
            lastz = min(g1z, bhi[2] - 1)
        else:
            stz = -1
            upz = 0
            lastz = max(g1z, blo[2])
        tx = (cx + upx - ox) / dx if cx != g1x else _INF
        ty = (cy + upy - oy) / dy if cy != g1y else _INF
        tz = (cz + upz - oz) / dz if cz != g1z else _INF
        offx = tabx[cx - wx0]
        offy = taby[cy - wy0]
        offz = tabz[cz - wz0]
        reached = False  # the walk arrived at the return's cell (inside this box)
        while True:
            idx = offx + offy + offz
            # next event: the smallest (t, class); a strict minimum is the common case and
            # each axis gets its own block so that one unpredictable branch decides it. An
            # axis at its last cell is either done (t = inf, never chosen) or about to leave.
            # (The blocks are alike on purpose. Measured on the demo flight's clouds: one step
            # indexed by axis was 1.36x slower, the state leaving the registers; the count
            # update hoisted above the branch, with a count of axes still to go, 1.06-1.10x.)
            if tx < ty and tx < tz:
                v = passes[idx]
                if v != 255:
                    passes[idx] = v + 1
                else:
                    _carry(passes, 64, idx, cdir, pool, used, part)
                nv += 1
                if cx == lastx:
                    break
                cx += stx
                offx = tabx[cx - wx0]
                tx = (cx + upx - ox) / dx
                if cx == g1x:
                    tx = _INF
            elif ty < tz and ty < tx:
                v = passes[idx]
                if v != 255:
                    passes[idx] = v + 1
                else:
                    _carry(passes, 64, idx, cdir, pool, used, part)
                nv += 1
                if cy == lasty:
                    break
                cy += sty
                offy = taby[cy - wy0]
                ty = (cy + upy - oy) / dy
                if cy == g1y:
                    ty = _INF
            elif tz < tx and tz < ty:
                v = passes[idx]
                if v != 255:
                    passes[idx] = v + 1
                else:
                    _carry(passes, 64, idx, cdir, pool, used, part)
                nv += 1
                if cz == lastz:
                    break
                cz += stz
                offz = tabz[cz - wz0]
                tz = (cz + upz - oz) / dz
                if cz == g1z:
                    tz = _INF
            else:
                # a tie (edge or corner) or the end of the ray
                tm = min(tx, min(ty, tz))
                if tm == _INF:
                    reached = True
                    break
                mvx = tx == tm
                mvy = ty == tm
                mvz = tz == tm
                # up-steps at t happen at t, down-steps just after it
                if (mvx and stx > 0) or (mvy and sty > 0) or (mvz and stz > 0):
                    mvx = mvx and stx > 0
                    mvy = mvy and sty > 0
                    mvz = mvz and stz > 0
                v = passes[idx]
                if v != 255:
                    passes[idx] = v + 1
                else:
                    _carry(passes, 64, idx, cdir, pool, used, part)
                nv += 1
                if (mvx and cx == lastx) or (mvy and cy == lasty) or (mvz and cz == lastz):
                    break  # the next cell is outside the box
                if mvx:
                    cx += stx
                    offx = tabx[cx - wx0]
                    tx = (cx + upx - ox) / dx if cx != g1x else _INF
                if mvy:
                    cy += sty
                    offy = taby[cy - wy0]
                    ty = (cy + upy - oy) / dy if cy != g1y else _INF
                if mvz:
                    cz += stz
                    offz = tabz[cz - wz0]
                    tz = (cz + upz - oz) / dz if cz != g1z else _INF
        if reached:
            idx = offx + offy + offz
            v = hits[idx]
            if v != 255:
                hits[idx] = v + 1
            else:
                _carry(hits, 0, idx, cdir, pool, used, part)
            nv += 1
            nh += 1
        # every cell visited lies in the XY box of the first and last one (monotone walk)
        kx0 = min(startx, cx) // tile_vox - dlo[0]
        kx1 = max(startx, cx) // tile_vox - dlo[0]
        ky0 = min(starty, cy) // tile_vox - dlo[1]
        ky1 = max(starty, cy) // tile_vox - dlo[1]
        # (each part has its own record: shared lines would bounce between the cores)
        for a in range(kx0, kx1 + 1):
            for b in range(ky0, ky1 + 1):
                if dirty[part, a, b] == 0:
                    dirty[part, a, b] = 1
    if pos >= total:
        pos = total
    resume[part] = pos
    counters[part, 0] = nh
    counters[part, 1] = nv


def trace_rays(uo: np.ndarray, up: np.ndarray, order: np.ndarray, nvalid: int,
               box_lo: np.ndarray, box_hi: np.ndarray, yint: np.ndarray,
               tables: tuple[np.ndarray, np.ndarray, np.ndarray], hits: np.ndarray,
               passes: np.ndarray, cdir: np.ndarray, pool: np.ndarray, pool_limit: int,
               used: np.ndarray, resume: np.ndarray, dirty: np.ndarray, dirty_lo: np.ndarray,
               tile_vox: int, counters: np.ndarray, runner: PartRunner | None = None) -> None:
    """Walk the prepared rays into the storage arrays (see :class:`DensityMap`).

    Each part stops before a ray that could exhaust its cold pool and leaves its position in
    ``resume``; the caller grows that pool and calls again. ``resume[k] == 2 * nvalid`` once
    part ``k`` is done. ``counters[k] += (hits, voxel updates)``.
    """
    if nvalid == 0:
        resume[:] = 0
        return
    args = (uo, up, order, nvalid, box_lo, box_hi, yint, box_lo, tables[0], tables[1],
            tables[2], hits, passes, cdir, pool, pool_limit, used, resume, dirty, dirty_lo,
            tile_vox, counters)
    run_parts(_trace_part, yint.shape[0], args, runner)
