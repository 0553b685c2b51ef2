"""A physically grounded guard beside the network: opaque structure standing above the ground.

The network judges a tile from its density cube and is calibrated on the simulator's world; on
shapes it never saw it can be confidently wrong (P(safe) near 1 over a 30 cm obstacle in plain
view). The guard checks a physical fact that does not depend on what an obstacle looks like:
**rays stop there, and nothing gets behind it**. Grass, even dense and 45 cm tall, is mostly
empty space: of the rays that reach a 5 cm voxel of canopy, the median share that end in it is
7 % (90th percentile 12-20 %), and the rays go on into the voxels below. On an obstacle's
surface the median share is a third, and the voxel beneath a surface voxel lies inside the
solid, where no ray gets (measured per voxel on simulated flights of five kinds of vegetation
with returns labelled by what they hit; experiments/2026-12-01_guard measures the guard itself).

For every tile, on the same hit / pass counts the tiler reads:

1. **Solid voxels** stand between ``min_height`` and ``max_height`` above the tile's ground
   estimate (the voxel's lower face above the centre of the ground voxel; on a tile with a
   ground plane, :mod:`landing_zone.judging.ground`, the band follows the plane from column
   to column, so the uphill side of a slope is ground, not structure), hold at least
   ``min_hits`` returns, end at least ``min_hit_ratio`` of the rays reaching them
   (``hits / (hits + passes)``) and cast a shadow: of the rays ending in the voxel or crossing
   the least crossed of its neighbours beneath and beside it, at most ``max_pass_behind``
   crossed (under a top surface and behind a wall no ray gets; under grass most go on).
2. **Clusters**: solid voxels connected face, edge or corner (26-neighbourhood) within the
   tile's column widened by ``margin`` on every side (so an object reaching a few centimetres
   into the tile is seen whole, with the returns on its part in the neighbour).
3. **Fires** when a cluster with at least ``min_cluster_hits`` returns has a voxel inside the
   tile's own column, or within ``reach`` of it (one voxel by default: an obstacle reaching
   into the tile by less than a voxel leaves its solid voxels beside the tile, where the map
   cannot tell it from one that stops at the edge). Its returns and the height of its top are
   the tile's evidence.

Where it fires, the assessor caps P(safe) at ``max_p_safe`` and records why; unknown tiles stay
unknown (the guard only lowers a judgement, it never makes one). What it cannot see: objects
lower than ``min_height``, thin ones (posts under about 10 cm across, board edges) whose
returns spread over voxels most rays cross, and the few centimetres of an obstacle that reach
into a tile from its neighbour without a solid voxel there.

The clusters are labelled by a flood fill inside one compiled kernel, parallel over tiles
(written by hand because :func:`scipy.ndimage.label` runs once per call from Python: 400 calls
per map cost more than the whole kernel, and it cannot run inside a numba ``prange``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numba as nb
import numpy as np

if TYPE_CHECKING:
    from landing_zone.config import GuardConfig
    from landing_zone.judging.ground import TileGround
    from landing_zone.judging.tiles import TileBatch

__all__ = ['GuardResult', 'solid_structure', 'guard_tiles', 'guard_p_safe', 'REASON_SOLID']

# The reason recorded on a tile the guard capped.
REASON_SOLID = 'solid structure above the ground'
_NO_GROUND = -(2 ** 62)


@dataclass
class GuardResult:
    """What the guard found on each of T tiles.

    Attributes:
        fired: (T,) bool, opaque structure stands in the tile.
        hits: (T,) int64 returns on the largest solid cluster reaching into the tile (0: none).
        voxels: (T,) int64 solid voxels of that cluster.
        height: (T,) float32 top of that cluster above the tile's ground [m]; NaN where none.
    """

    fired: np.ndarray
    hits: np.ndarray
    voxels: np.ndarray
    height: np.ndarray

    def __len__(self) -> int:
        return int(self.fired.shape[0])

    def __getitem__(self, sel: np.ndarray | slice) -> GuardResult:
        return GuardResult(self.fired[sel], self.hits[sel], self.voxels[sel], self.height[sel])


@nb.njit(cache=True, nogil=True)
def _neighbour_offsets():  # type: ignore[no-untyped-def]
    """(26, 3) the offsets of a voxel's 26 neighbours."""
    offsets = np.empty((26, 3), np.int64)
    n_off = 0
    for a in range(-1, 2):
        for b in range(-1, 2):
            for c in range(-1, 2):
                if a != 0 or b != 0 or c != 0:
                    offsets[n_off, 0] = a
                    offsets[n_off, 1] = b
                    offsets[n_off, 2] = c
                    n_off += 1
    return offsets


@nb.njit(cache=True, nogil=True, inline='always')
def _is_solid(hits, passes, xi, yj, zk, min_hits, ratio, shadow):  # type: ignore[no-untyped-def]
    """Whether box voxel (xi, yj, zk) is solid: hit often enough, mostly hit, and shading the
    least crossed of the voxel beneath and the four beside it."""
    nx, ny, _ = hits.shape
    h = hits[xi, yj, zk]
    if h < min_hits:
        return False
    hf = np.float64(h)
    # the least crossed of the voxel beneath and the four beside it: under a top surface, or
    # behind a wall seen from the side (thin walls of open crates and buckets leave the voxel
    # beneath crossed)
    shade = passes[xi, yj, zk - 1] if zk > 0 else 0
    if xi > 0:
        shade = min(shade, passes[xi - 1, yj, zk])
    if xi + 1 < nx:
        shade = min(shade, passes[xi + 1, yj, zk])
    if yj > 0:
        shade = min(shade, passes[xi, yj - 1, zk])
    if yj + 1 < ny:
        shade = min(shade, passes[xi, yj + 1, zk])
    behind = np.float64(shade)
    return (hf >= ratio * (hf + np.float64(passes[xi, yj, zk]))
            and behind <= shadow * (hf + behind))


@nb.njit(cache=True, nogil=True, inline='always')
def _flood(  # type: ignore[no-untyped-def]
        hits, label, stack, offsets, shift, i, j, k, n, x0, y0, z0, tv, margin, reach):
    """Number the cluster of solid voxel (i, j, k) ``n``; its returns, voxels, top (voxels
    above the band's floor) and whether it reaches into the tile (``reach`` voxels beyond)."""
    rx, _, rz = label.shape
    label[i, j, k] = n
    stack[0, 0] = i
    stack[0, 1] = j
    stack[0, 2] = k
    top = 1
    c_hits = 0
    c_vox = 0
    c_top = 0
    inner = False
    while top > 0:
        top -= 1
        a = stack[top, 0]
        b = stack[top, 1]
        c = stack[top, 2]
        c_hits += hits[x0 + a, y0 + b, z0 + shift[a, b] + c]
        c_vox += 1
        if c > c_top:
            c_top = c
        if (margin - reach <= a < margin + tv + reach
                and margin - reach <= b < margin + tv + reach):
            inner = True
        for o in range(offsets.shape[0]):
            a2 = a + offsets[o, 0]
            b2 = b + offsets[o, 1]
            c2 = c + offsets[o, 2]
            if (0 <= a2 < rx and 0 <= b2 < rx and 0 <= c2 < rz
                    and label[a2, b2, c2] == -1):
                label[a2, b2, c2] = n
                stack[top, 0] = a2
                stack[top, 1] = b2
                stack[top, 2] = c2
                top += 1
    return c_hits, c_vox, c_top, inner


@nb.njit(cache=True, parallel=True)
def _guard_kernel(  # type: ignore[no-untyped-def]
        hits, passes, lo, tiles, ground_k, grad, tv, margin, reach, k_lo, k_hi, min_hits,
        ratio, shadow, out_hits, out_vox, out_top):
    """Largest solid cluster reaching into each tile's column (see the module docstring).

    ``ground_k[t]`` is the tile's ground voxel in box z coordinates (``_NO_GROUND``: none);
    solid voxels are those ``k_lo .. k_hi`` voxels above it, the band sheared column by column
    along the ground's gradient ``grad[t]`` (dz/dx, dz/dy; zero: level), so cluster
    coordinates are heights above the ground plane. Outputs per tile: the cluster's returns,
    voxels and top (voxels above the ground; -1 without a cluster).
    """
    nx, ny, nz = hits.shape
    rx = tv + 2 * margin
    rz = k_hi - k_lo + 1
    offsets = _neighbour_offsets()
    for t in nb.prange(tiles.shape[0]):
        out_hits[t] = 0
        out_vox[t] = 0
        out_top[t] = -1
        if ground_k[t] == _NO_GROUND:
            continue
        x0 = tiles[t, 0] * tv - lo[0] - margin
        y0 = tiles[t, 1] * tv - lo[1] - margin
        z0 = ground_k[t] + k_lo
        # the band's shift per column [voxels]: the ground plane's height there over its
        # height at the tile's centre
        shift = np.empty((rx, rx), np.int64)
        centre = margin + 0.5 * tv - 0.5
        for i in range(rx):
            for j in range(rx):
                shift[i, j] = int(np.round((i - centre) * grad[t, 0] + (j - centre) * grad[t, 1]))
        # label: 0 not solid, -1 solid and not yet visited, c > 0 the cluster's number
        label = np.zeros((rx, rx, rz), np.int32)
        any_solid = False
        for i in range(rx):
            xi = x0 + i
            if xi < 0 or xi >= nx:
                continue
            for j in range(rx):
                yj = y0 + j
                if yj < 0 or yj >= ny:
                    continue
                for k in range(rz):
                    zk = z0 + shift[i, j] + k
                    if 0 <= zk < nz and _is_solid(hits, passes, xi, yj, zk, min_hits, ratio,
                                                  shadow):
                        label[i, j, k] = -1
                        any_solid = True
        if not any_solid:
            continue
        # the clusters, flooded one by one: the one with the most returns that reaches in
        stack = np.empty((rx * rx * rz, 3), np.int64)
        n_clusters = 0
        for i in range(rx):
            for j in range(rx):
                for k in range(rz):
                    if label[i, j, k] != -1:
                        continue
                    n_clusters += 1
                    c_hits, c_vox, c_top, inner = _flood(hits, label, stack, offsets, shift,
                                                         i, j, k, n_clusters, x0, y0, z0, tv,
                                                         margin, reach)
                    if inner and c_hits > out_hits[t]:
                        out_hits[t] = c_hits
                        out_vox[t] = c_vox
                        out_top[t] = c_top + k_lo


def solid_structure(hits: np.ndarray, passes: np.ndarray, lo: np.ndarray, voxel_size: float,
                    tiles: np.ndarray, ground_z: np.ndarray, tile_vox: int,
                    config: GuardConfig, grad: np.ndarray | None = None) -> GuardResult:
    """Opaque structure standing above each tile's ground (see the module docstring).

    Args:
        hits: (X, Y, Z) hit counts of a box of the global voxel lattice (as
            :meth:`~landing_zone.mapping.density_map.DensityMap.counts` returns them).
        passes: same shape, the pass counts.
        lo: (3,) global voxel index of the box's lower corner.
        voxel_size: edge of a voxel [m].
        tiles: (T, 2) global tile indices.
        ground_z: (T,) the tiles' ground estimates [m] (centre of the ground voxel, as
            :class:`~landing_zone.judging.tiles.TileBatch` gives them); NaN: no ground, never
            fires.
        tile_vox: voxels per tile side.
        config: the guard's thresholds.
        grad: (T, 2) the tiles' ground gradients (dz/dx, dz/dy), with ``ground_z`` the
            plane's height at the tile centre; None or NaN: level ground.

    Returns:
        A :class:`GuardResult` of the T tiles, in their order.
    """
    idx = np.ascontiguousarray(tiles, np.int64).reshape(-1, 2)
    n = idx.shape[0]
    gz = np.asarray(ground_z, np.float64).reshape(-1)
    if gz.shape[0] != n:
        raise ValueError(f'ground_z has {gz.shape[0]} entries for {n} tiles')
    lo_arr = np.asarray(lo, np.int64).reshape(3)
    finite = np.isfinite(gz)
    ground_k = np.full(n, _NO_GROUND, np.int64)
    ground_k[finite] = np.floor(gz[finite] / voxel_size).astype(np.int64) - lo_arr[2]
    # a voxel counts when its lower face is at least min_height above the ground voxel's centre
    k_lo = max(1, int(math.ceil(config.min_height / voxel_size + 0.5 - 1e-9)))
    k_hi = max(k_lo, int(math.floor(config.max_height / voxel_size - 0.5 + 1e-9)))
    margin = int(round(config.margin / voxel_size))
    reach = min(margin, int(round(config.reach / voxel_size)))  # validate() keeps it <= margin
    out_hits = np.zeros(n, np.int64)
    out_vox = np.zeros(n, np.int64)
    out_top = np.full(n, -1, np.int64)
    g = np.zeros((n, 2)) if grad is None else np.asarray(grad, np.float64).reshape(n, 2)
    g = np.ascontiguousarray(np.where(np.isfinite(g), g, 0.0))
    if n:
        _guard_kernel(np.ascontiguousarray(hits, np.uint32),
                      np.ascontiguousarray(passes, np.uint32), lo_arr, idx, ground_k, g,
                      int(tile_vox), margin, reach, k_lo, k_hi, int(config.min_hits),
                      float(config.min_hit_ratio), float(config.max_pass_behind), out_hits,
                      out_vox, out_top)
    fired = out_hits >= int(config.min_cluster_hits)
    height = np.where(out_top >= 0, (out_top + 0.5) * voxel_size, np.nan).astype(np.float32)
    return GuardResult(fired=fired, hits=out_hits, voxels=out_vox, height=height)


def guard_tiles(counts: tuple[np.ndarray, np.ndarray, np.ndarray], voxel_size: float,
                batch: TileBatch, ground: TileGround, tile_vox: int, config: GuardConfig
                ) -> GuardResult:
    """:func:`solid_structure` on the tiles of a cut, as the assessor runs it: on the counts
    ``(hits, passes, lo)`` the tiles were cut from, above each tile's ground plane where it has
    one (a slope's uphill side is ground), else above the tiler's ground, valid tiles only."""
    gz = np.where(np.isfinite(ground.plane_z), ground.plane_z, batch.ground_z)
    return solid_structure(*counts, voxel_size, batch.index, np.where(batch.valid, gz, np.nan),
                           tile_vox, config, grad=ground.grad)


def guard_p_safe(p_safe: np.ndarray, result: GuardResult, config: GuardConfig) -> np.ndarray:
    """P(safe) with the guard applied: capped at ``config.max_p_safe`` where it fired.

    NaN (unknown) stays NaN: the guard lowers judgements, it never makes one.
    """
    p = np.asarray(p_safe, np.float32).copy()
    cap = result.fired & np.isfinite(p)
    p[cap] = np.minimum(p[cap], np.float32(config.max_p_safe))
    return np.asarray(p)
