"""The guard on simulated patches: the network's inputs of a dataset and what the guard finds
on each scene, from one read of each patch.

:func:`landing_zone.judging.guard.solid_structure` reads a map's hit and pass counts. A synth3
scene is one tile with its neighbourhood. :class:`GuardedVolumes` integrates each patch once
(:func:`~landing_zone.judging.patches.patch_counts`), fits the tile's ground plane as the
assessor does (:func:`~landing_zone.judging.patches.patch_ground`), cuts the network's cube from
those counts as :func:`~landing_zone.judging.patches.scene_to_input` cuts it
(:func:`~landing_zone.judging.patches.cut_patch`) and runs the guard on the centre tile above
the plane, or above the tiler's ground where there is none, only where the tile is valid: what
:func:`landing_zone.judging.judgement.judge_tiles` does on a map. :func:`voxelize_guarded`
makes both for a whole pack, in loader workers.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import torch

from landing_zone.tools.learn.samples import AugmentedVolumes, collect

if TYPE_CHECKING:
    from landing_zone.config import GuardConfig, MapConfig, TileConfig
    from landing_zone.judging.guard import GuardResult
    from landing_zone.tools.learn.scenes import ScenePack

__all__ = ['GuardedVolumes', 'voxelize_guarded']


class GuardedVolumes(AugmentedVolumes):
    """Scene ``s`` -> (input (1, S, S, S) float32, label float32, the guard's finding (4,)
    float64: fired, hits, voxels, height), the input as :func:`voxelize` makes it without
    augmentation and the finding from the same counts."""

    def __init__(self, pack: ScenePack, map_cfg: MapConfig, tile_cfg: TileConfig,
                 guard_cfg: GuardConfig) -> None:
        super().__init__(pack, map_cfg, tile_cfg, seed=0, augment=False)
        self.guard_cfg = guard_cfg

    def __getitem__(self, key: tuple[int, int, int] | int  # type: ignore[override]
                    ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        from landing_zone.judging.guard import guard_tiles
        from landing_zone.judging.patches import (PatchVoxelizer, cut_patch, patch_counts,
                                                  patch_ground)
        from landing_zone.judging.tiles import tile_voxels

        scene = int(key) if isinstance(key, (int, np.integer)) else int(key[1])
        pts, org = self.pack.scene(scene)
        if self._voxelizer is None:
            self._voxelizer = PatchVoxelizer()
        mcfg, tcfg = self.map_cfg, self.tile_cfg
        counts = patch_counts(pts, org, mcfg, tcfg, voxelizer=self._voxelizer)
        ground = patch_ground(counts, mcfg, tcfg)
        batch = cut_patch(counts, mcfg, tcfg, ground if tcfg.align_to_ground else None)
        vs = float(mcfg.voxel_size)
        g = guard_tiles(counts, vs, batch, ground, tile_voxels(vs, tcfg), self.guard_cfg)
        finding = torch.tensor([float(g.fired[0]), float(g.hits[0]), float(g.voxels[0]),
                                float(g.height[0])], dtype=torch.float64)
        return (torch.from_numpy(batch.inputs[0]), torch.tensor(float(self.pack.labels[scene])),
                finding)


def voxelize_guarded(pack: ScenePack, map_cfg: MapConfig, tile_cfg: TileConfig,
                     guard_cfg: GuardConfig, workers: int = 0, progress: bool = False,
                     desc: str = 'voxelizing and guarding'
                     ) -> tuple[torch.Tensor, torch.Tensor, GuardResult]:
    """The network's inputs of every scene of ``pack`` (as :func:`voxelize` makes them, no
    augmentation) and the guard's finding on each, in scene order.

    Args:
        pack: the scenes (patch frame: the tile centred at (0, 0), the ground near z = 0).
        map_cfg: voxel size of the map (only ``voxel_size`` is used).
        tile_cfg: tiling parameters (as the model's inputs were made).
        guard_cfg: the guard's thresholds (the assessor's ``guard`` section).
        workers: loader processes (0: this one).
        progress: a progress bar on stderr.

    Returns:
        inputs (S, 1, side, side, side) float32, labels (S,) float32, and a
        :class:`~landing_zone.judging.guard.GuardResult` of the scenes; the guard never fires
        on a tile that is not valid (too few returns or observed voxels, no ground).
    """
    from landing_zone.judging.guard import GuardResult
    from landing_zone.judging.tiles import tile_voxels

    side = tile_voxels(map_cfg.voxel_size, tile_cfg) + 2 * tile_cfg.padding
    ds = GuardedVolumes(pack, map_cfg, tile_cfg, guard_cfg)
    x, y, (f,) = collect(ds, list(range(len(pack))), side, workers, progress, desc)
    f = f.numpy()
    found = GuardResult(fired=f[:, 0] > 0, hits=f[:, 1].astype(np.int64),
                        voxels=f[:, 2].astype(np.int64), height=f[:, 3].astype(np.float32))
    return x, y, found
