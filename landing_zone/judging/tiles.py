"""Map -> tiles: per-tile ground height and the padded subvolumes the network reads.

The XY plane is cut on the global tile lattice (tile ``k = floor(x / tile_size)``, centre
``(k + 0.5) * tile_size``; with 5 cm voxels a 1 m tile is 20 voxels and tile ``k`` covers voxels
``[20 k, 20 k + 20)``). For every tile:

1. **Ground.** For each of its voxel columns the lowest *occupied* voxel (hit at least once,
   density at least ``TileConfig.occupied_density``) is that column's candidate ground; the
   tile's ground is the ``ground_quantile`` (default 5 %) of those column minima. Taking one
   value per column keeps grass (many occupied voxels above the ground) from outvoting the few
   columns where the ground shows through, and the low quantile ignores a few columns with
   noise below the ground.
2. **Cube.** A ``tile_size``-high cube sits on the tile with the ground voxel at its vertical
   middle (index ``tile_vox // 2``); ``padding`` voxels of context are added on every side
   (20 + 2 * 6 = 32 at the defaults) and read as the network input ``x = 2 * density - 1 =
   (hits - passes) / (hits + passes + 2)``: unobserved voxels (and voxels outside the map) are 0,
   occupied ones positive, free ones negative.
3. **Validity.** A tile is judged only if it has a ground estimate, at least
   ``min_observed_fraction`` of its (unpadded) cube was observed and at least ``min_returns``
   returns fell into its column; other tiles are marked not valid (unknown), never guessed.

The core, :func:`tiles_from_counts`, works on plain count arrays so grids can be built by hand;
:func:`extract_tiles` reads them from a :class:`~landing_zone.mapping.density_map.DensityMap`
(:mod:`landing_zone.judging.patches` re-voxelizes one simulated patch exactly as the deployed map
would, so the network is trained on what it will see).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numba as nb
import numpy as np
from numpy.typing import ArrayLike

from landing_zone.config import TileConfig
from landing_zone.errors import ConfigError
from landing_zone.judging.occupancy import is_occupied

if TYPE_CHECKING:
    from landing_zone.judging.ground import TileGround
    from landing_zone.mapping.density_map import DensityMap

__all__ = [
    'TileBatch',
    'tile_voxels',
    'tiles_in_box',
    'widen_tiles',
    'tiles_from_counts',
    'extract_tiles',
    'CountBuffers',
]


@dataclass
class TileBatch:
    """Tiles and their network inputs (T tiles; S = tile voxels + 2 * padding).

    Attributes:
        index: (T, 2) int64 global tile indices (kx, ky).
        centers: (T, 2) float64 tile centres [m].
        ground_z: (T,) float64 estimated ground height [m] (centre of the ground voxel); NaN
            where no occupied voxel was found.
        inputs: (T, 1, S, S, S) float32 network inputs in [-1, 1], axes (x, y, z); (T, 1,
            S/p, S/p, S/p) when cut with ``pool=p`` (max-pooled).
        cube_lo: (T, 3) int64 global voxel index of each input's lower corner (padding
            included), so input voxel (a, b, c) is lattice voxel ``cube_lo + (a, b, c)``.
        observed_fraction: (T,) float32 share of the unpadded cube hit or passed at least once.
        n_returns: (T,) int64 hits in the tile's column (the whole height read).
        valid: (T,) bool, the tile may be judged (see the module docstring).
    """

    index: np.ndarray
    centers: np.ndarray
    ground_z: np.ndarray
    inputs: np.ndarray
    cube_lo: np.ndarray
    observed_fraction: np.ndarray
    n_returns: np.ndarray
    valid: np.ndarray

    def __len__(self) -> int:
        return int(self.index.shape[0])


def tile_voxels(voxel_size: float, config: TileConfig) -> int:
    """Voxels along one side of a tile; the tile must be a whole number of voxels.

    Raises:
        ConfigError: the tile size is not a whole multiple of the voxel size.
    """
    config.validate()
    if not (math.isfinite(voxel_size) and voxel_size > 0):
        raise ConfigError(f'voxel_size must be a positive number, got {voxel_size!r}')
    ratio = config.tile_size / voxel_size
    tv = int(round(ratio))
    if tv < 1 or abs(ratio - tv) > 1e-6:
        raise ConfigError(f'tiles.tile_size ({config.tile_size}) must be a whole multiple of '
                          f'the voxel size ({voxel_size})')
    return tv


def tiles_in_box(lo: ArrayLike, shape: ArrayLike, tile_vox: int) -> np.ndarray:
    """Global indices of the tiles whose XY footprint lies wholly inside a voxel box.

    Args:
        lo: global voxel index of the box's lower corner (x, y[, z]).
        shape: voxels of the box (x, y[, z]).
        tile_vox: voxels per tile side.

    Returns:
        (T, 2) int64, ordered by x then y.
    """
    lo_xy = np.asarray(lo, np.int64).reshape(-1)[:2]
    k0 = -(-lo_xy // tile_vox)  # ceil
    k1 = (lo_xy + np.asarray(shape, np.int64).reshape(-1)[:2]) // tile_vox
    kx = np.arange(k0[0], max(k1[0], k0[0]), dtype=np.int64)
    ky = np.arange(k0[1], max(k1[1], k0[1]), dtype=np.int64)
    gx, gy = np.meshgrid(kx, ky, indexing='ij')
    return np.column_stack([gx.ravel(), gy.ravel()])


def widen_tiles(tiles: np.ndarray, rings: int = 1) -> np.ndarray:
    """The tiles and their neighbours up to ``rings`` tiles away (sorted, unique).

    A tile's input reaches ``padding`` voxels into its neighbours, so when the voxels of some
    tiles change (the map's dirty tiles), the inputs of their neighbours change too.

    Args:
        tiles: (T, 2) integer tile indices.
        rings: how many tiles out to add (1 covers any padding up to a whole tile).
    """
    idx = _as_tiles(tiles)
    r = np.arange(-rings, rings + 1)
    ring = np.stack(np.meshgrid(r, r, indexing='ij'), axis=-1).reshape(-1, 2)
    return np.unique((idx[:, None, :] + ring[None]).reshape(-1, 2), axis=0)


# --- the compiled kernel -----------------------------------------------------------------------

@nb.njit(cache=True, nogil=True, inline='always')
def _column_values(hits, passes, xi, yj, z0, c0, c1, row):  # type: ignore[no-untyped-def]
    """One column of an input cube into ``row``: 2 * density - 1 of box voxels
    ``z0 + [c0, c1)`` of column (xi, yj), 0 (unobserved) elsewhere."""
    row[:c0] = 0.0
    row[c1:] = 0.0
    # branch-free so the compiler vectorizes it
    for c in range(c0, c1):
        h = np.float32(hits[xi, yj, z0 + c])
        p = np.float32(passes[xi, yj, z0 + c])
        row[c] = (h - p) / (h + p + np.float32(2.0))


@nb.njit(cache=True, nogil=True, inline='always')
def _column_z(z0t, plane, t, a, b, centre, side, nz):  # type: ignore[no-untyped-def]
    """Box z index of cube column (a, b)'s first voxel (sheared along ``plane[t]`` where it is
    finite) and the range [c0, c1) of the column that lies inside the box; the rest reads as
    unobserved."""
    z0 = z0t
    if math.isfinite(plane[t, 0]):
        z0 += int(np.round((a - centre) * plane[t, 1] + (b - centre) * plane[t, 2]))
    c0 = min(max(-z0, 0), side)
    return z0, c0, max(min(nz - z0, side), c0)


def _tile_kernel(  # type: ignore[no-untyped-def]
        hits, passes, lo, tiles, tv, pad, quantile, occupied, plane, skip_below, pool, out,
        ground_k, nobs, nret):
    """Ground voxel, input cube, observed voxels and returns of every tile (one per thread).

    ``ground_k[t]`` is the ground voxel's z index in box coordinates, or -2**62 when the tile
    has no occupied voxel (its input is then all zeros). Where ``plane[t]`` is finite (height of
    the ground plane at the tile centre in box voxels, gradient x, gradient y), the cube is
    aligned to it: the ground voxel is the plane's at the centre and every column of the cube
    is shifted by the plane's rise there, in whole voxels (a shear). ``skip_below`` = (returns,
    observed voxels): a tile with fewer of either gets an all-zero input instead of its cube (it
    is not valid, so no network reads it); (0, 0) builds every cube. ``pool`` > 1 writes each
    cube max-pooled by ``pool`` per axis (``out`` is then (T, 1, S/pool, S/pool, S/pool)), as
    the network's opening pool would.
    """
    nx, ny, nz = hits.shape
    side = tv + 2 * pad
    half = tv // 2
    for t in nb.prange(tiles.shape[0]):
        x0 = tiles[t, 0] * tv - lo[0]
        y0 = tiles[t, 1] * tv - lo[1]
        colmin = np.empty(tv * tv, np.int64)
        n = 0
        returns = 0
        for i in range(tv):
            xi = x0 + i
            if xi < 0 or xi >= nx:
                continue
            for j in range(tv):
                yj = y0 + j
                if yj < 0 or yj >= ny:
                    continue
                found = False
                for k in range(nz):
                    h = hits[xi, yj, k]
                    returns += h
                    if not found and is_occupied(h, passes[xi, yj, k], occupied):
                        colmin[n] = k
                        n += 1
                        found = True
        nret[t] = returns
        if n == 0:
            ground_k[t] = -(2 ** 62)
            nobs[t] = 0
            out[t, 0] = 0.0
            continue
        mins = np.sort(colmin[:n])
        kq = mins[int(math.floor(quantile * (n - 1)))]
        if math.isfinite(plane[t, 0]):  # aligned: the plane's height at the centre
            kq = int(math.floor(plane[t, 0]))
        ground_k[t] = kq
        z0t = kq - half - pad
        centre = pad + 0.5 * tv - 0.5
        # the observed voxels of the unpadded cube first: they tell whether the input is read
        seen = 0
        for a in range(pad, pad + tv):
            xi = x0 - pad + a
            if xi < 0 or xi >= nx:
                continue
            for b in range(pad, pad + tv):
                yj = y0 - pad + b
                if yj < 0 or yj >= ny:
                    continue
                z0, c0, c1 = _column_z(z0t, plane, t, a, b, centre, side, nz)
                for c in range(max(c0, pad), min(c1, pad + tv)):
                    seen += (hits[xi, yj, z0 + c] + passes[xi, yj, z0 + c]) > 0
        nobs[t] = seen
        if returns < skip_below[0] or seen < skip_below[1]:
            out[t, 0] = 0.0
            continue
        if pool > 1:
            _pooled_cube(hits, passes, t, x0, y0, z0t, plane, pad, side, centre, pool, out)
            continue
        for a in range(side):
            xi = x0 - pad + a
            for b in range(side):
                yj = y0 - pad + b
                row = out[t, 0, a, b]
                if xi < 0 or xi >= nx or yj < 0 or yj >= ny:
                    row[:] = 0.0
                    continue
                z0, c0, c1 = _column_z(z0t, plane, t, a, b, centre, side, nz)
                _column_values(hits, passes, xi, yj, z0, c0, c1, row)


@nb.njit(cache=True, nogil=True, inline='always')
def _pooled_cube(  # type: ignore[no-untyped-def]
        hits, passes, t, x0, y0, z0t, plane, pad, side, centre, pool, out):
    """Tile ``t``'s input cube max-pooled by ``pool``: each column's values (as the full cube
    has them, 0 outside the box) folded into the pooled cell's running maximum."""
    nx, ny, nz = hits.shape
    cube = out[t, 0]
    cube[:] = -np.inf
    col = np.empty(side, np.float32)
    for a in range(side):
        xi = x0 - pad + a
        for b in range(side):
            yj = y0 - pad + b
            if xi < 0 or xi >= nx or yj < 0 or yj >= ny:
                col[:] = 0.0
            else:
                z0, c0, c1 = _column_z(z0t, plane, t, a, b, centre, side, nz)
                _column_values(hits, passes, xi, yj, z0, c0, c1, col)
            row = cube[a // pool, b // pool]
            for q in range(side // pool):
                m = col[q * pool]
                for r in range(1, pool):
                    m = max(m, col[q * pool + r])
                row[q] = max(row[q], m)


# Parallel over tiles for maps; serial for a few tiles (a patch), where starting the thread pool
# costs more than the work and where DataLoader workers must not start one (see train.py).
# nogil: the node's other threads (taking messages, integrating) run while a map is cut.
_tile_kernel_parallel = nb.njit(cache=True, parallel=True, nogil=True)(_tile_kernel)
_tile_kernel_serial = nb.njit(cache=True, nogil=True)(_tile_kernel)
_SERIAL_TILES = 4


# --- public API --------------------------------------------------------------------------------

def _as_tiles(tiles: ArrayLike) -> np.ndarray:
    arr = np.asarray(tiles)
    if arr.ndim != 2 or arr.shape[1] != 2 or (arr.size and arr.dtype.kind not in 'iu'):
        raise ConfigError(f'tiles must be a (T, 2) integer array of tile indices, got shape '
                          f'{arr.shape} dtype {arr.dtype}')
    return np.ascontiguousarray(arr, np.int64)


def tiles_from_counts(hits: np.ndarray, passes: np.ndarray, lo: ArrayLike,
                      voxel_size: float, config: TileConfig | None = None,
                      tiles: np.ndarray | None = None,
                      ground: TileGround | None = None,
                      invalid_inputs: bool = True, pool: int = 1) -> TileBatch:
    """Cut a box of hit / pass counts into tiles: ground, network inputs, validity.

    Args:
        hits: (X, Y, Z) non-negative integer counts of a box of the global voxel lattice, in
            (x, y, z) order (as :meth:`DensityMap.counts` returns them).
        passes: same shape, the pass counts.
        lo: (3,) global voxel index of the box's lower corner.
        voxel_size: edge of a voxel [m].
        config: tiling parameters; default :class:`TileConfig()`.
        tiles: (T, 2) global tile indices to extract; default every tile whose footprint lies
            wholly inside the box. Voxels outside the box read as unobserved.
        ground: the tiles' ground planes (:func:`~landing_zone.judging.ground.fit_ground`);
            with ``config.align_to_ground`` the cube of a tile with a plane is aligned to it
            (ground voxel the plane's at the centre, columns sheared along its rise).
        invalid_inputs: build the input cube of tiles that are not valid too (training reads
            them); False leaves those with too few returns or observed voxels all zeros,
            which saves a map's assessment the cubes no network reads. Everything else
            (ground, observed fraction, returns, validity) is the same either way.
        pool: write each input max-pooled by this many voxels per axis, (T, 1, S/pool,
            S/pool, S/pool): what a net whose spec opens with that pool reads first
            (:attr:`SafetyNet.input_pool`), so the assessor neither writes nor pools the full
            cubes. 1: the cubes themselves.

    Returns:
        A :class:`TileBatch` of the tiles in the order given (x then y by default).

    Raises:
        ConfigError: inconsistent shapes or parameters.
    """
    cfg = config if config is not None else TileConfig()
    tv = tile_voxels(voxel_size, cfg)
    h = np.asarray(hits)
    p = np.asarray(passes)
    if h.ndim != 3 or h.shape != p.shape:
        raise ConfigError(f'hits and passes must be 3-D arrays of one shape, got {h.shape} '
                          f'and {p.shape}')
    if h.dtype.kind not in 'iu' or p.dtype.kind not in 'iu':
        raise ConfigError(f'hits and passes must be integer counts, got {h.dtype} and {p.dtype}')
    lo_arr = np.asarray(lo).reshape(-1)
    if lo_arr.shape != (3,) or lo_arr.dtype.kind not in 'iu':
        raise ConfigError(f'lo must be three integers, got {lo!r}')
    lo_arr = lo_arr.astype(np.int64)
    idx = tiles_in_box(lo_arr, h.shape, tv) if tiles is None else _as_tiles(tiles)
    side = tv + 2 * cfg.padding
    if pool < 1 or side % pool:
        raise ConfigError(f'pool must be a divisor of the input side {side}, got {pool}')
    n = idx.shape[0]
    cells = side // pool
    inputs = np.empty((n, 1, cells, cells, cells), np.float32)
    ground_k = np.empty(n, np.int64)
    nobs = np.empty(n, np.int64)
    nret = np.empty(n, np.int64)
    plane = np.full((n, 3), np.nan)
    if cfg.align_to_ground and ground is not None and n:
        # box voxel units: the plane's centre height, and its rise per voxel column
        plane[:, 0] = ground.plane_z / voxel_size - lo_arr[2]
        plane[:, 1:] = ground.grad
        plane[~np.all(np.isfinite(plane), axis=1)] = np.nan
    if n:
        # Counts are non-negative; uint32 keeps the kernel to one compiled signature.
        kernel = _tile_kernel_serial if n <= _SERIAL_TILES else _tile_kernel_parallel
        skip = np.zeros(2, np.int64)
        if not invalid_inputs:
            # surely not valid: fewer returns, or observed voxels a whole voxel short of the
            # fraction (the float32 fraction below cannot round across that)
            skip[0] = int(cfg.min_returns)
            skip[1] = max(int(math.ceil(cfg.min_observed_fraction * tv ** 3)) - 1, 0)
        kernel(np.ascontiguousarray(h, np.uint32), np.ascontiguousarray(p, np.uint32),
               lo_arr, idx, tv, int(cfg.padding), float(cfg.ground_quantile),
               float(cfg.occupied_density), plane, skip, int(pool), inputs, ground_k, nobs,
               nret)
    has_ground = ground_k > -(2 ** 62)
    gk = np.where(has_ground, ground_k, 0) + lo_arr[2]
    ground_z = np.where(has_ground, (gk + 0.5) * voxel_size, np.nan)
    cube_lo = np.column_stack([idx * tv - cfg.padding,
                               gk - tv // 2 - cfg.padding]).astype(np.int64)
    observed_fraction = (nobs / float(tv ** 3)).astype(np.float32)
    valid = (has_ground & (observed_fraction >= cfg.min_observed_fraction)
             & (nret >= cfg.min_returns))
    return TileBatch(index=idx, centers=(idx + 0.5) * cfg.tile_size, ground_z=ground_z,
                     inputs=inputs, cube_lo=cube_lo, observed_fraction=observed_fraction,
                     n_returns=nret, valid=valid)


class CountBuffers:
    """The hit and pass arrays one caller reads a map's counts into, reused from one read to the
    next: a full map is 2 x 51 MB, and fresh memory costs its page faults on every read. Any box
    up to the largest asked for so far is a view of the same memory. Not thread-safe: one per
    thread (or per assessor, whose passes come one at a time)."""

    def __init__(self) -> None:
        self._flat: tuple[np.ndarray, np.ndarray] | None = None

    def get(self, shape: tuple[int, int, int]) -> tuple[np.ndarray, np.ndarray]:
        """Two C-contiguous uint32 arrays of ``shape`` (views of the memory of the last call
        when it is large enough; their contents are left as they were)."""
        n = int(np.prod(shape))
        if self._flat is None or self._flat[0].size < n:
            self._flat = (np.empty(n, np.uint32), np.empty(n, np.uint32))
        return self._flat[0][:n].reshape(shape), self._flat[1][:n].reshape(shape)


def extract_tiles(dmap: DensityMap, config: TileConfig | None = None,
                  tiles: np.ndarray | None = None,
                  buffers: CountBuffers | None = None, pool: int = 1) -> TileBatch:
    """Tiles of a density map (see :func:`tiles_from_counts`; ``pool`` as there).

    Only the counts of the bounding box of the requested tiles (padding included, clipped to
    the map's window) are read, so re-assessing a few dirty tiles reads little. Into
    ``buffers`` when given (a caller that extracts again and again), else into fresh arrays.

    Args:
        dmap: the map.
        config: tiling parameters; default :class:`TileConfig()`.
        tiles: (T, 2) global tile indices; default every tile wholly inside the window.
    """
    cfg = config if config is not None else TileConfig()
    tv = tile_voxels(dmap.voxel_size, cfg)
    lo = np.asarray(dmap.lo, np.int64)
    hi = lo + np.asarray(dmap.shape, np.int64)
    idx = tiles_in_box(lo, dmap.shape, tv) if tiles is None else _as_tiles(tiles)
    if idx.shape[0] == 0:
        return tiles_from_counts(np.zeros((0, 0, 0), np.uint32), np.zeros((0, 0, 0), np.uint32),
                                 lo, dmap.voxel_size, cfg, idx, pool=pool)
    box_lo = np.concatenate([idx.min(axis=0) * tv - cfg.padding, lo[2:]])
    box_hi = np.concatenate([(idx.max(axis=0) + 1) * tv + cfg.padding, hi[2:]])
    box_lo = np.clip(box_lo, lo, hi)
    box_hi = np.clip(box_hi, box_lo, hi)
    sx, sy, sz = (int(v) for v in box_hi - box_lo)
    bufs = buffers.get((sx, sy, sz)) if buffers is not None else None
    h, p = dmap.counts(box_lo, box_hi - box_lo, out=bufs)
    return tiles_from_counts(h, p, box_lo, dmap.voxel_size, cfg, idx, pool=pool)
