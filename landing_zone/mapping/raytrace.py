"""Exact 3D voxel traversal of LiDAR rays into hit / pass counts (the compiled hot loop).

Each return is a segment from its sensor origin ``o`` to the return ``p``. In lattice units
(``u = p / voxel_size``, computed in float64) voxel ``g`` is the half-open cell ``[g, g + 1)``
per axis (the floor convention). The return's voxel ``floor(p)`` gets a
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
import numba as nb
import numpy as np

from landing_zone.mapping.parts import PartRunner, run_parts
from landing_zone.mapping.rays import INF, first_cell

__all__ = ['PARTS', 'BRICK', 'COUNT_MAX', 'trace_rays']

PARTS = 4  # storage slabs along y; threads take them one at a time (NUMBA_NUM_THREADS=1 too)
BRICK = 4  # edge of a storage brick in voxels; 4^3 uint8 = one 64-byte cache line
COUNT_MAX = 65535  # hits and passes saturate here (hot low byte + cold high byte)


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


@nb.njit(cache=True, nogil=True, error_model='numpy', inline='always')
def _axis(g0, g1, lo, hi):  # type: ignore[no-untyped-def]
    """An axis of the walk in the box ``[lo, hi)``: its step direction, the plane offset of the
    next event (1 up, 0 down) and its last cell (the return's cell or the box's face cell)."""
    if g1 > g0:
        return 1, 1, min(g1, hi - 1)
    return -1, 0, max(g1, lo)


@nb.njit(cache=True, nogil=True, error_model='numpy', inline='always')
def _tie_moves(tx, ty, tz, tm, stx, sty, stz):  # type: ignore[no-untyped-def]
    """Which axes step at a tie at ``tm``: up-steps at t happen at t, down-steps just after
    it, so where some tied axis steps up only those do."""
    mvx = tx == tm
    mvy = ty == tm
    mvz = tz == tm
    if (mvx and stx > 0) or (mvy and sty > 0) or (mvz and stz > 0):
        return mvx and stx > 0, mvy and sty > 0, mvz and stz > 0
    return mvx, mvy, mvz


@nb.njit(cache=True, nogil=True, error_model='numpy', inline='always')
def _walk(  # type: ignore[no-untyped-def]
        passes, cdir, pool, used, part, tabs, wlo, ox, oy, oz, dx, dy, dz, cx, cy, cz, g1x,
        g1y, g1z, stx, sty, stz, upx, upy, upz, lastx, lasty, lastz, nv):
    """Pass every cell of one ray from (cx, cy, cz) to its return's cell or the box's face,
    in the order of its plane crossings (``tabs``: the axes' offset tables, ``wlo`` their
    first index). Returns whether it reached the return's cell, that cell's storage index, the
    last cell's x and y, and the voxel updates counted. (At most 30 arguments: past that
    Python passes them as a tuple, which numba does not inline.)"""
    tabx, taby, tabz = tabs
    wx0 = wlo[0]
    wy0 = wlo[1]
    wz0 = wlo[2]
    # the next event's parameter per axis (inf once the axis has reached the return's cell)
    tx = (cx + upx - ox) / dx if cx != g1x else INF
    ty = (cy + upy - oy) / dy if cy != g1y else INF
    tz = (cz + upz - oz) / dz if cz != g1z else INF
    offx = tabx[cx - wx0]
    offy = taby[cy - wy0]
    offz = tabz[cz - wz0]
    reached = False  # the walk arrived at the return's cell (inside this box)
    while True:
        idx = offx + offy + offz
        # next event: the smallest (t, class); a strict minimum is the common case and
        # each axis gets its own block so that one unpredictable branch decides it. An
        # axis at its last cell is either done (t = inf, never chosen) or about to leave.
        # (The blocks are alike on purpose: one step indexed by axis keeps the state out of
        # the registers.)
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
                tx = INF
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
                ty = INF
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
                tz = INF
        else:
            # a tie (edge or corner) or the end of the ray
            tm = min(tx, min(ty, tz))
            if tm == INF:
                reached = True
                break
            mvx, mvy, mvz = _tie_moves(tx, ty, tz, tm, stx, sty, stz)
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
                tx = (cx + upx - ox) / dx if cx != g1x else INF
            if mvy:
                cy += sty
                offy = taby[cy - wy0]
                ty = (cy + upy - oy) / dy if cy != g1y else INF
            if mvz:
                cz += stz
                offz = tabz[cz - wz0]
                tz = (cz + upz - oz) / dz if cz != g1z else INF
    return reached, offx + offy + offz, cx, cy, nv


@nb.njit(cache=True, nogil=True, error_model='numpy')
def _trace_part(  # type: ignore[no-untyped-def]
        part, uo, up, order, nvalid, blo, bhi, yint, wlo, tabx, taby, tabz, hits,
        passes, cdir, pool, pool_limit, used, resume, dirty, dlo, tile_vox, counters):
    """Walk the part of every ray inside the storage slab ``part`` owns.

    ``tabx[g - wlo[0]]`` (and y, z) is the share of axis index ``g`` in the linear storage
    index (ring position, brick, place in the brick), so a step is one table load.

    The walk of one ray is inlined (numba adds reference counting around calls that take
    arrays): one call per ray at most, never one per voxel, whose cost would dominate.
    """
    # a ray can need at most one new cold block per brick it visits
    worst = (tabx.shape[0] + taby.shape[0] + tabz.shape[0]) // BRICK + 6
    cap = pool.shape[1]
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
        inside, cx, cy, cz = first_cell(ox, oy, oz, dx, dy, dz, g0x, g0y, g0z, g1x, g1y, g1z,
                                        blo[0], bly, blo[2], bhi[0], bhy, bhi[2])
        if not inside:
            continue
        startx = cx
        starty = cy
        stx, upx, lastx = _axis(g0x, g1x, blo[0], bhi[0])
        sty, upy, lasty = _axis(g0y, g1y, bly, bhy)
        stz, upz, lastz = _axis(g0z, g1z, blo[2], bhi[2])
        reached, idx, cx, cy, nv = _walk(
            passes, cdir, pool, used, part, (tabx, taby, tabz), wlo, ox, oy, oz, dx, dy, dz,
            cx, cy, cz, g1x, g1y, g1z, stx, sty, stz, upx, upy, upz, lastx, lasty, lastz, nv)
        if reached:
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
