"""A simulated patch re-voxelized as the deployed map would: the training data's tile inputs.

:func:`scene_to_input` integrates one patch (returns and their sensor origins, tile centred at
the origin, ground near z = 0) into a small density map of 3 x 3 tiles, so the padding sees real
neighbours, fits the tile's ground plane and cuts the centre tile with
:func:`~landing_zone.judging.tiles.tiles_from_counts`, aligned to that plane where
``tiles.align_to_ground`` says so (the default): the same kernels and steps as the assessor's, so
the network is trained and judged on what it sees onboard. :func:`patch_counts`
gives the counts it cuts from (for what else reads a patch, the guard); a
:class:`PatchVoxelizer` keeps the small maps between patches; :func:`patch_ground` and
:func:`cut_patch` are its two steps after the counts, for callers that read those counts too.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

from landing_zone.config import MapConfig, TileConfig
from landing_zone.errors import ConfigError
from landing_zone.judging.ground import TileGround, fit_ground
from landing_zone.judging.tiles import TileBatch, tile_voxels, tiles_from_counts

if TYPE_CHECKING:
    from landing_zone.mapping.density_map import DensityMap

__all__ = ['scene_to_input', 'patch_counts', 'patch_ground', 'cut_patch', 'patch_columns',
           'centre_columns', 'PatchVoxelizer', 'PATCH_Z_MARGIN']

# Extra height [m] the patch map of scene_to_input keeps above and below the cube's reach, for
# ground that is not exactly at z = 0 (slopes, bumps) in a simulated patch.
PATCH_Z_MARGIN = 0.5


class PatchVoxelizer:
    """Re-voxelizes simulated patches (:func:`scene_to_input`) into small maps it owns.

    One 3 x 3-tile map per voxel size and height, cleared and reused across patches, because
    building one costs as much as a fifth of integrating a patch. Not thread-safe: one per
    thread or process (a training set makes its own in each loader worker).
    """

    def __init__(self) -> None:
        self._maps: dict[tuple[float, int, int], DensityMap] = {}

    def _map(self, voxel_size: float, tile_vox: int, nz: int) -> DensityMap:
        from landing_zone.mapping.density_map import DensityMap

        key = (voxel_size, tile_vox, nz)
        dmap = self._maps.get(key)
        if dmap is None:
            cfg = MapConfig(voxel_size=voxel_size, size_xy=3 * tile_vox * voxel_size,
                            size_z=nz * voxel_size, z_below=0.0, recenter_distance=0.0)
            # one patch is too small to be worth the map's two-thread split
            dmap = DensityMap(cfg, parallel=False, tile_vox=tile_vox)
            self._maps[key] = dmap
        else:
            dmap.clear()
        return dmap

    def __call__(self, points: np.ndarray, origins: np.ndarray,
                 map_cfg: MapConfig | None = None, tile_cfg: TileConfig | None = None,
                 yaw: float = 0.0, z_shift: float = 0.0) -> TileBatch:
        """:func:`scene_to_input` on this voxelizer's maps."""
        return scene_to_input(points, origins, map_cfg, tile_cfg, yaw, z_shift, voxelizer=self)


def scene_to_input(points: np.ndarray, origins: np.ndarray, map_cfg: MapConfig | None = None,
                   tile_cfg: TileConfig | None = None, yaw: float = 0.0,
                   z_shift: float = 0.0, voxelizer: PatchVoxelizer | None = None) -> TileBatch:
    """Re-voxelize one simulated patch and extract its centre tile, as the deployed map would.

    The patch frame has the tile centred at (0, 0) with the ground near z = 0. Points and
    origins are rotated by ``yaw`` about the z axis through the tile centre, raised by
    ``z_shift``, moved by half a tile in x and y onto global tile (0, 0), integrated into a
    small density map of 3 x 3 tiles (so the padding sees real neighbours), and tile (0, 0) is
    extracted with :func:`tiles_from_counts`, its cube aligned to the tile's ground plane
    (:func:`~landing_zone.judging.ground.fit_ground`) with ``tile_cfg.align_to_ground``, as
    the assessor cuts it.

    Args:
        points: (N, 3) returns in the patch frame [m].
        origins: (3,) or (N, 3) sensor origins of the returns [m].
        map_cfg: voxel size of the map (only ``voxel_size`` is used); default MapConfig().
        tile_cfg: tiling parameters; default TileConfig().
        yaw: rotation about the tile's vertical axis [rad] (augmentation).
        z_shift: vertical shift [m] (augmentation).
        voxelizer: whose small map to reuse (callers that voxelize many patches); default a
            fresh map.

    Returns:
        A :class:`TileBatch` with one tile; ``index`` is (0, 0), ``centers`` (0, 0) and
        ``ground_z`` is in the patch frame (the shift undone).

    Raises:
        InvalidCloudError: malformed points or origins.
        ConfigError: bad configuration or non-finite yaw / z_shift.
    """
    mcfg = map_cfg if map_cfg is not None else MapConfig()
    tcfg = tile_cfg if tile_cfg is not None else TileConfig()
    counts = patch_counts(points, origins, mcfg, tcfg, yaw, z_shift, voxelizer)
    # the cube aligned to the tile's ground plane where the assessor aligns it
    ground = patch_ground(counts, mcfg, tcfg) if tcfg.align_to_ground else None
    return cut_patch(counts, mcfg, tcfg, ground, z_shift)


def patch_ground(counts: tuple[np.ndarray, ...], map_cfg: MapConfig, tile_cfg: TileConfig
                 ) -> TileGround:
    """The ground plane of a patch's centre tile from its counts (:func:`patch_counts`), as
    the assessor fits a map's (:func:`~landing_zone.judging.ground.fit_ground`)."""
    h, p, lo = counts
    vs = float(map_cfg.voxel_size)
    return fit_ground(h, p, lo, vs, np.zeros((1, 2), np.int64), tile_voxels(vs, tile_cfg),
                      tile_cfg.occupied_density)


def cut_patch(counts: tuple[np.ndarray, ...], map_cfg: MapConfig, tile_cfg: TileConfig,
              ground: TileGround | None = None, z_shift: float = 0.0) -> TileBatch:
    """The centre tile of a patch's counts (:func:`patch_counts` with ``z_shift``), cut as
    :func:`scene_to_input` cuts it: its cube aligned to ``ground`` (:func:`patch_ground`)
    where ``tile_cfg.align_to_ground`` says so, ``ground_z`` in the patch frame."""
    h, p, lo = counts
    # the centre tile is global tile (0, 0)
    batch = tiles_from_counts(h, p, lo, float(map_cfg.voxel_size), tile_cfg,
                              np.zeros((1, 2), np.int64), ground)
    batch.centers = np.zeros((1, 2))
    batch.ground_z = batch.ground_z - z_shift
    return batch


def patch_columns(counts: tuple[np.ndarray, ...], map_cfg: MapConfig, tile_cfg: TileConfig,
                  ground_z: float, grad: np.ndarray) -> tuple[np.ndarray, ...]:
    """Every voxel column of a patch's counts (:func:`patch_counts`): ``(hits, passes, above,
    centre)``, the first three (X, Y, Z), ``above`` every voxel centre's height [m] over the
    centre tile's plane (through ``ground_z`` at the tile's centre with gradient ``grad``,
    dz/dx and dz/dy) carried across the patch, ``centre`` the (X, Y) mask of the centre tile's
    columns (global tile (0, 0))."""
    h, p, lo = counts
    vs = float(map_cfg.voxel_size)
    tv = tile_voxels(vs, tile_cfg)
    # voxel centres relative to the centre tile's centre; the tile is box columns -lo .. -lo + tv
    x = (np.arange(h.shape[0]) + lo[0] + 0.5) * vs - 0.5 * tile_cfg.tile_size
    y = (np.arange(h.shape[1]) + lo[1] + 0.5) * vs - 0.5 * tile_cfg.tile_size
    plane = ground_z + grad[0] * x[:, None] + grad[1] * y[None, :]  # (X, Y)
    z = (lo[2] + np.arange(h.shape[2]) + 0.5) * vs
    centre = np.zeros(h.shape[:2], bool)
    centre[-lo[0]:-lo[0] + tv, -lo[1]:-lo[1] + tv] = True
    return h, p, z[None, None, :] - plane[:, :, None], centre


def centre_columns(counts: tuple[np.ndarray, ...], map_cfg: MapConfig, tile_cfg: TileConfig,
                   ground_z: float, grad: np.ndarray) -> tuple[np.ndarray, ...]:
    """The centre tile's voxel columns of a patch's counts (:func:`patch_counts`): ``(hits,
    passes, above)``, each (tv, tv, Z), as :func:`patch_columns` gives them."""
    lo = counts[2]
    tv = tile_voxels(float(map_cfg.voxel_size), tile_cfg)
    sl = (slice(-lo[0], -lo[0] + tv), slice(-lo[1], -lo[1] + tv))
    h, p, above, _ = patch_columns(counts, map_cfg, tile_cfg, ground_z, grad)
    return h[sl], p[sl], above[sl]


def patch_counts(points: np.ndarray, origins: np.ndarray, map_cfg: MapConfig | None = None,
                 tile_cfg: TileConfig | None = None, yaw: float = 0.0, z_shift: float = 0.0,
                 voxelizer: PatchVoxelizer | None = None) -> tuple[np.ndarray, ...]:
    """The counts :func:`scene_to_input` cuts its tile from (same arguments), for what else
    reads a patch's counts (the guard): ``(hits, passes, lo)`` of the 3 x 3 tiles around global
    tile (0, 0), as :meth:`DensityMap.counts` gives them, z raised by ``z_shift``."""
    mcfg = map_cfg if map_cfg is not None else MapConfig()
    tcfg = tile_cfg if tile_cfg is not None else TileConfig()
    if not (math.isfinite(yaw) and math.isfinite(z_shift)):
        raise ConfigError(f'yaw and z_shift must be finite, got {yaw!r} and {z_shift!r}')
    vs = float(mcfg.voxel_size)
    tv = tile_voxels(vs, tcfg)
    # Vertical reach: the cube (one tile high around the ground), its padding and a margin for
    # ground that is off z = 0; the window moves with z_shift so its size (and the cached map)
    # stays the same. Rays outside the window cannot change the extracted cube.
    reach = tcfg.tile_size / 2 + (tcfg.padding + 1) * vs + PATCH_Z_MARGIN
    kz = int(math.ceil(reach / vs))
    dmap = (voxelizer if voxelizer is not None else PatchVoxelizer())._map(vs, tv, 2 * kz)
    dmap.set_lo(np.array([-tv, -tv, -kz + int(round(z_shift / vs))], np.int64))
    c, s = math.cos(yaw), math.sin(yaw)
    offset = np.array([tcfg.tile_size / 2, tcfg.tile_size / 2, z_shift])
    rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])

    def place(a: np.ndarray) -> np.ndarray:
        arr = np.asarray(a, np.float64)
        if arr.ndim == 0 or arr.shape[-1] != 3:
            return arr  # let DensityMap.integrate name the problem
        placed: np.ndarray = arr @ rot.T + offset
        return placed

    dmap.integrate(place(points), place(origins))
    return (*dmap.counts(), np.asarray(dmap.lo, np.int64).copy())
