"""A batch of returns made ready for the walk: checked, in lattice units, clipped, sorted.

Each return is a segment from its sensor origin ``o`` to the return ``p``, in lattice units
``u = p / voxel_size`` (float64, a correctly rounded division). Rows whose coordinates are not
finite (or absurdly far), whose point equals its origin, or whose whole segment misses the map's
box are dropped and counted (:class:`IntegrationStats`); the rest are counting-sorted by the XY
cell of their return, so rays that end close together share most of their cache lines near the
ground. The clip that finds a ray's first cell in a box is shared with the walk
(:mod:`landing_zone.mapping.raytrace`), which clips every ray again to each part of the map.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numba as nb
import numpy as np
from numpy.typing import ArrayLike

from landing_zone.errors import InvalidCloudError

__all__ = ['IntegrationStats', 'MAX_LATTICE_COORD', 'SORT_TILE', 'INF', 'first_cell',
           'prepare_rays', 'as_points']

# Rays with a coordinate beyond this many voxels from the lattice origin (5e10 m at 5 cm) are
# dropped as non-finite: their lattice indices would not fit the integer arithmetic.
MAX_LATTICE_COORD = float(2 ** 40)
SORT_TILE = 16  # voxels per side of the XY cells the batch is counting-sorted by

INF = np.inf


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
        return -INF, 0, True
    if g0 < blo:
        if g1 < blo:
            return INF, 0, False
        return (blo - o) / d, 0, True
    if g1 >= bhi:
        return INF, 0, False
    return (bhi - o) / d, 1, True


@nb.njit(cache=True, inline='always', error_model='numpy')
def _axis_state(o: float, d: float, g0: int, g1: int, te: float, ce: int) -> int:
    """Cell of one axis once all its events up to (te, ce) in (t, class) order have happened."""
    if g1 == g0 or te == -INF:
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
def first_cell(  # type: ignore[no-untyped-def]
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
    if te == -INF:
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
        inside, cx, cy, cz = first_cell(bx, by, bz, ax - bx, ay - by, az - bz,
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


def as_points(arr: ArrayLike, name: str, allow_single: bool = False) -> np.ndarray:
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
