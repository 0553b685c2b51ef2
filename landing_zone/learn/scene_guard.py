"""The guard on simulated patches: what it would do to each scene of a dataset.

:func:`landing_zone.judging.guard.solid_structure` reads a map's hit and pass counts. A synth3
scene is one tile with its neighbourhood, and evaluation judges it from the cube
:func:`~landing_zone.judging.patches.scene_to_input` cuts. :func:`guard_scenes` reads the counts
that cube is cut from (:func:`~landing_zone.judging.patches.patch_counts`, no augmentation), fits
the tile's ground plane as the assessor does (:func:`~landing_zone.judging.ground.fit_ground`)
and runs the guard on the centre tile above the plane, or above the tiler's ground where there
is none, only where the tile is valid: what :meth:`landing_zone.assessor.Assessor.finish_assess`
does on a map. The network's cube of ``evaluate`` stays level (the dataset's voxelization);
only the guard follows the plane.
"""
from __future__ import annotations

import sys
from typing import TYPE_CHECKING

import numpy as np
from tqdm import tqdm

if TYPE_CHECKING:
    from landing_zone.config import GuardConfig, MapConfig, TileConfig
    from landing_zone.judging.guard import GuardResult
    from landing_zone.learn.scenes import ScenePack

__all__ = ['guard_scenes']


def guard_scenes(pack: ScenePack, map_cfg: MapConfig, tile_cfg: TileConfig,
                 guard_cfg: GuardConfig, progress: bool = False) -> GuardResult:
    """The guard's finding on the centre tile of every scene of ``pack``, in its order.

    Args:
        pack: the scenes (patch frame: the tile centred at (0, 0), the ground near z = 0).
        map_cfg: voxel size of the map (only ``voxel_size`` is used).
        tile_cfg: tiling parameters (as the model's inputs were made).
        guard_cfg: the guard's thresholds (the assessor's ``guard`` section).
        progress: a progress bar on stderr.

    Returns:
        A :class:`~landing_zone.judging.guard.GuardResult` of the scenes; it never fires on a
        tile that is not valid (too few returns or observed voxels, no ground).
    """
    from landing_zone.judging.ground import fit_ground
    from landing_zone.judging.guard import GuardResult, solid_structure
    from landing_zone.judging.patches import PatchVoxelizer, patch_counts
    from landing_zone.judging.tiles import tile_voxels, tiles_from_counts

    vs = float(map_cfg.voxel_size)
    tv = tile_voxels(vs, tile_cfg)
    tile = np.zeros((1, 2), np.int64)
    n = len(pack)
    fired = np.zeros(n, bool)
    hits = np.zeros(n, np.int64)
    voxels = np.zeros(n, np.int64)
    height = np.full(n, np.nan, np.float32)
    voxelizer = PatchVoxelizer()
    for i in tqdm(range(n), desc='guard', unit='scene', leave=False, file=sys.stderr,
                  disable=not progress):
        pts, org = pack.scene(i)
        h, p, lo = patch_counts(pts, org, map_cfg, tile_cfg, voxelizer=voxelizer)
        ground = fit_ground(h, p, lo, vs, tile, tv, tile_cfg.occupied_density)
        batch = tiles_from_counts(h, p, lo, vs, tile_cfg, tile, invalid_inputs=False)
        gz = np.where(np.isfinite(ground.plane_z), ground.plane_z, batch.ground_z)
        g = solid_structure(h, p, lo, vs, tile, np.where(batch.valid, gz, np.nan), tv,
                            guard_cfg, grad=ground.grad)
        fired[i], hits[i], voxels[i], height[i] = g.fired[0], g.hits[0], g.voxels[0], \
            g.height[0]
    return GuardResult(fired=fired, hits=hits, voxels=voxels, height=height)
