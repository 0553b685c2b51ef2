"""Per-tile ground planes and what stands over them: slope, roughness, overhead clearance.

On the same hit / pass counts the tiler reads, for every tile:

1. **Ground evidence.** In each of the tile's voxel columns the lowest *occupied* voxel (hit
   and at least ``occupied_density`` dense, as the tiler's ground) is that column's candidate
   ground point, at the voxel's centre.
2. **Plane.** A least-squares plane ``z = c + gx * u + gy * v`` (``u``, ``v`` from the tile's
   centre) through those points, then refitted on the **lower envelope**: points more than
   ``tau`` above the plane are dropped, ``tau`` halving from 8 voxels to 2 (grass, stems and
   the tops of low clutter stand above the ground and occlude it in some columns; only noise
   lies below it), and a last fit on the points within 2 voxels of the plane either way (which
   drops the rare return below the ground too). A tile with fewer than
   :data:`MIN_GROUND_COLUMNS` of its columns on the final plane has no plane (NaN).
3. **Slope** ``atan(hypot(gx, gy))`` in degrees, **roughness** the RMS distance of the final
   points from the plane [m] (5 cm voxels alone give about 1.4 cm on a perfect plane), and the
   **ground height** the plane's height at the tile's centre.
4. **Clearance**: in each column, the height above the plane of the lower face of the lowest
   occupied voxel at least ``clutter_height`` above it (below that, grass and obstacles are the
   network's and the guard's business); the tile's clearance is the least over its columns.
   A column with nothing above the clutter is clear up to the top of the counts (the map's
   window): clearance is "free height within the map", never more than the map can see, and
   ``overhead`` keeps apart the height of structure actually seen (inf: none), so a site can
   tell "something is there" from "the map does not reach that high".

The fit is written by hand in one compiled kernel, parallel over tiles, because it runs on
every assessment pass: 400 tiles of up to 400 points each take a few milliseconds here, where
one call of scikit-learn's RANSACRegressor or HuberRegressor costs about a millisecond of
Python overhead alone (0.4 s a map, against a 0.5 s budget for the whole pass).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from landing_zone.judging.occupancy import is_occupied

__all__ = ['TileGround', 'fit_ground', 'slope_deg', 'MIN_GROUND_COLUMNS']

# Share of a tile's voxel columns that must lie on its final plane for the plane to count: a
# tile that shows its ground in fewer columns (dense cover, shadow) has no slope, and a site
# over it is unknown, never assumed level.
MIN_GROUND_COLUMNS = 0.1
# Upper trimming bands of the lower-envelope refits [voxels], then the final symmetric band.
_TAUS = (8.0, 4.0, 2.0)
_FINAL_BAND = 2.0


@dataclass
class TileGround:
    """The ground planes and clearances of T tiles.

    Attributes:
        plane_z: (T,) float64 height of the plane at the tile's centre [m]; NaN: no plane.
        grad: (T, 2) float64 the plane's gradient (dz/dx, dz/dy); NaN: no plane.
        roughness: (T,) float32 RMS residual of the ground points about the plane [m].
        clearance: (T,) float32 least free height above the plane over the tile's columns,
            within the counts' window [m]; NaN: no plane.
        overhead: (T,) float32 height above the plane of the lowest structure seen above the
            clutter [m]; inf: none within the window; NaN: no plane.
        columns: (T,) int64 columns on the final plane.
    """

    plane_z: np.ndarray
    grad: np.ndarray
    roughness: np.ndarray
    clearance: np.ndarray
    overhead: np.ndarray
    columns: np.ndarray

    def __len__(self) -> int:
        return int(self.plane_z.shape[0])

    def __getitem__(self, sel: np.ndarray | slice) -> TileGround:
        """The planes of a subset of the tiles (a mask or an index array)."""
        return TileGround(self.plane_z[sel], self.grad[sel], self.roughness[sel],
                          self.clearance[sel], self.overhead[sel], self.columns[sel])

    @property
    def slope_deg(self) -> np.ndarray:
        """(T,) float32 slope of each plane [deg]; NaN: no plane."""
        return slope_deg(self.grad)


def slope_deg(grad: np.ndarray) -> np.ndarray:
    """Slope [deg] of planes with gradients ``grad`` (..., 2); NaN stays NaN."""
    g = np.asarray(grad, np.float64)
    out: np.ndarray = np.degrees(np.arctan(np.hypot(g[..., 0], g[..., 1]))).astype(np.float32)
    return out


@nb.njit(cache=True, nogil=True)
def _fit_plane(u, v, z, keep, n):  # type: ignore[no-untyped-def]
    """Least squares z = c + a u + b v over the kept points: (c, a, b, count); NaN if
    degenerate (fewer than 3 points, or all on a line)."""
    s1 = su = sv = suu = suv = svv = sz = suz = svz = 0.0
    for t in range(n):
        if keep[t]:
            s1 += 1.0
            su += u[t]
            sv += v[t]
            suu += u[t] * u[t]
            suv += u[t] * v[t]
            svv += v[t] * v[t]
            sz += z[t]
            suz += u[t] * z[t]
            svz += v[t] * z[t]
    if s1 < 3.0:
        return math.nan, math.nan, math.nan, s1
    # centred normal equations: the intercept decouples
    mu, mv, mz = su / s1, sv / s1, sz / s1
    cuu = suu - s1 * mu * mu
    cuv = suv - s1 * mu * mv
    cvv = svv - s1 * mv * mv
    cuz = suz - s1 * mu * mz
    cvz = svz - s1 * mv * mz
    det = cuu * cvv - cuv * cuv
    # points on a line (one row of columns): no plane
    if det <= 1e-9 * (cuu + cvv) * (cuu + cvv) or det <= 0.0:
        return math.nan, math.nan, math.nan, s1
    a = (cuz * cvv - cvz * cuv) / det
    b = (cvz * cuu - cuz * cuv) / det
    return mz - a * mu - b * mv, a, b, s1


@nb.njit(cache=True, parallel=True, nogil=True)
def _ground_kernel(hits, passes, lo, tiles, tv, vs, occupied, clutter, min_cols,  # type: ignore
                   taus, band, plane, rough, clear, over, ncols):
    nx, ny, nz = hits.shape
    half = 0.5 * tv * vs
    for t in nb.prange(tiles.shape[0]):
        x0 = tiles[t, 0] * tv - lo[0]
        y0 = tiles[t, 1] * tv - lo[1]
        u = np.empty(tv * tv)
        v = np.empty(tv * tv)
        z = np.empty(tv * tv)
        ci = np.empty(tv * tv, np.int64)
        keep = np.ones(tv * tv, np.bool_)
        n = 0
        for i in range(tv):
            xi = x0 + i
            if xi < 0 or xi >= nx:
                continue
            for j in range(tv):
                yj = y0 + j
                if yj < 0 or yj >= ny:
                    continue
                for k in range(nz):
                    if is_occupied(hits[xi, yj, k], passes[xi, yj, k], occupied):
                        u[n] = (i + 0.5) * vs - half
                        v[n] = (j + 0.5) * vs - half
                        z[n] = (k + 0.5) * vs
                        ci[n] = i * tv + j
                        n += 1
                        break
        plane[t, 0] = plane[t, 1] = plane[t, 2] = math.nan
        rough[t] = math.nan
        clear[t] = math.nan
        over[t] = math.nan
        ncols[t] = 0
        c, a, b, m = _fit_plane(u, v, z, keep, n)
        if not math.isfinite(c):
            continue
        # the lower envelope: drop what stands above the plane, tighter each time
        for tau in taus:
            for s in range(n):
                keep[s] = z[s] - (c + a * u[s] + b * v[s]) <= tau * vs
            c2, a2, b2, m = _fit_plane(u, v, z, keep, n)
            if not math.isfinite(c2):
                break
            c, a, b = c2, a2, b2
        for s in range(n):
            keep[s] = abs(z[s] - (c + a * u[s] + b * v[s])) <= band * vs
        c2, a2, b2, m = _fit_plane(u, v, z, keep, n)
        if math.isfinite(c2):
            c, a, b = c2, a2, b2
        used = 0
        ss = 0.0
        for s in range(n):
            r = z[s] - (c + a * u[s] + b * v[s])
            if abs(r) <= band * vs:
                used += 1
                ss += r * r
        ncols[t] = used
        if used < min_cols or used < 3:
            continue
        plane[t, 0] = c
        plane[t, 1] = a
        plane[t, 2] = b
        rough[t] = math.sqrt(ss / used)
        # clearance: the lowest occupied voxel above the clutter band, per column
        best = math.inf
        seen = math.inf
        for i in range(tv):
            xi = x0 + i
            if xi < 0 or xi >= nx:
                continue
            for j in range(tv):
                yj = y0 + j
                if yj < 0 or yj >= ny:
                    continue
                zc = c + a * ((i + 0.5) * vs - half) + b * ((j + 0.5) * vs - half)
                # first voxel whose lower face is at least the clutter height above the plane
                k0 = max(int(math.ceil((zc + clutter) / vs - 1e-9)), 0)
                free = nz * vs - zc
                for k in range(k0, nz):
                    if is_occupied(hits[xi, yj, k], passes[xi, yj, k], occupied):
                        free = k * vs - zc
                        if free < seen:
                            seen = free
                        break
                if free < best:
                    best = free
        clear[t] = best
        over[t] = seen


def fit_ground(hits: np.ndarray, passes: np.ndarray, lo: np.ndarray, voxel_size: float,
               tiles: np.ndarray, tile_vox: int, occupied_density: float = 0.6,
               clutter_height: float = 0.5) -> TileGround:
    """Ground plane, roughness and clearance of each tile (see the module docstring).

    Args:
        hits: (X, Y, Z) hit counts of a box of the global voxel lattice (as the tiler reads).
        passes: same shape, the pass counts.
        lo: (3,) global voxel index of the box's lower corner.
        voxel_size: voxel edge [m].
        tiles: (T, 2) global tile indices.
        tile_vox: voxels per tile side.
        occupied_density: density from which a voxel counts as occupied.
        clutter_height: clearance is measured from this height above the plane up [m].

    Returns:
        A :class:`TileGround` of the T tiles, heights in the fixed frame.
    """
    idx = np.ascontiguousarray(np.asarray(tiles, np.int64).reshape(-1, 2))
    n = idx.shape[0]
    plane = np.full((n, 3), np.nan)
    rough = np.full(n, np.nan)
    clear = np.full(n, np.nan)
    over = np.full(n, np.nan)
    ncols = np.zeros(n, np.int64)
    lo_arr = np.asarray(lo, np.int64).reshape(3)
    h = np.asarray(hits)
    if n and h.size:
        _ground_kernel(np.ascontiguousarray(h, np.uint32),
                       np.ascontiguousarray(passes, np.uint32), lo_arr, idx, int(tile_vox),
                       float(voxel_size), float(occupied_density), float(clutter_height),
                       int(math.ceil(MIN_GROUND_COLUMNS * tile_vox * tile_vox)),
                       np.array(_TAUS), float(_FINAL_BAND), plane, rough, clear, over, ncols)
    z0 = lo_arr[2] * float(voxel_size)
    return TileGround(plane_z=plane[:, 0] + z0, grad=plane[:, 1:].copy(),
                      roughness=rough.astype(np.float32), clearance=clear.astype(np.float32),
                      overhead=over.astype(np.float32), columns=ncols)
