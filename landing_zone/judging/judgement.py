"""One assessment pass's judgement of the tiles it was given, stage by stage.

From a copy of the map's counts around the tiles to judge: the ground planes, the tiles' cubes,
the network's P(safe) (and its features' distance from the training tiles), the guard's cap,
the distrust of an unfamiliar "safe" and of a tile seen only at grazing angles. Nothing here
holds the map's lock or the tiles' state: the assessor copies the counts in, and stores what
comes out.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from landing_zone.config import AssessorConfig
from landing_zone.judging.ground import TileGround, fit_ground
from landing_zone.judging.guard import GuardResult, guard_p_safe, guard_tiles
from landing_zone.judging.tiles import TileBatch, tiles_from_counts

if TYPE_CHECKING:
    from landing_zone.judging.inference import Predictor
    from landing_zone.judging.ood import FeatureReference

__all__ = ['Judgement', 'judge_tiles', 'REASON_GRAZING']

# why a tile the tiler found observed enough is unknown all the same
REASON_GRAZING = 'seen only at grazing angles'

Counts = tuple[np.ndarray, np.ndarray, np.ndarray]  # hits, passes, the box's low corner


@dataclass
class Judgement:
    """What one pass found on the K tiles it judged (rows in ``batch.index`` order).

    Attributes:
        batch: the tiler's output (None: no counts, nothing judged).
        ground: the tiles' ground planes (None with ``batch``).
        p_net: (K,) float32 the network's P(safe); NaN where the tile is not valid.
        p_safe: (K,) float32 the judgement: ``p_net`` capped by the guard, NaN where an
            unfamiliar tile was called safe.
        guard: the guard's findings (None: guard disabled or nothing judged).
        ood: (K,) float32 distance of the tile's features over the OOD threshold; NaN where not
            measured.
        grazing: (K,) bool valid tiles made unknown for too few returns from steep rays
            (``tiles.min_ray_depression_deg``).
    """

    batch: TileBatch | None
    ground: TileGround | None
    p_net: np.ndarray
    p_safe: np.ndarray
    guard: GuardResult | None
    ood: np.ndarray
    grazing: np.ndarray


def judge_tiles(counts: Counts | None, todo: np.ndarray, config: AssessorConfig, tile_vox: int,
                predictor: Predictor, reference: FeatureReference | None,
                steep: np.ndarray | None = None) -> Judgement:
    """Judge the tiles ``todo`` ((K, 2) global indices) on ``counts``, the map's counts around
    them (None when there are no tiles); ``steep``: (K,) each tile's returns from rays at least
    ``tiles.min_ray_depression_deg`` down (None: not counted, the rule is not applied)."""
    if counts is None:
        empty = np.full(len(todo), np.nan, np.float32)
        return Judgement(None, None, empty, empty.copy(), None, empty.copy(),
                         np.zeros(len(todo), np.bool_))
    # the ground planes first: the cubes may be aligned to them (tiles.align_to_ground)
    ground = fit_ground(*counts, config.map.voxel_size, todo, tile_vox,
                        config.tiles.occupied_density, config.landing_sites.clutter_height)
    # the cubes of the tiles that can be valid, pooled as the network's first layer reads them
    batch, pool = _cut_tiles(counts, todo, config, ground, predictor)
    # P(safe) and, from the same forward pass, how unlike the training tiles each tile is
    p_net, ood = _predict(batch, pool, config, predictor, reference)
    # the guard on the same counts: opaque structure above the ground caps P(safe)
    p, guard = p_net, None
    if config.guard.enabled:
        guard = guard_tiles(counts, config.map.voxel_size, batch, ground, tile_vox, config.guard)
        p = guard_p_safe(p_net, guard, config.guard)
    # after the guard: a "safe" the network gives a tile unlike its training data is not
    # trusted (NaN ratios, tiles not judged or no reference, compare False)
    p = np.where((ood > 1.0) & (p >= 0.5), np.float32(np.nan), p).astype(np.float32)
    # a tile seen only from the side (a ground vehicle's view) is not the view the network
    # was trained on: unknown, whatever it and the guard said
    grazing = np.zeros(len(todo), np.bool_)
    if steep is not None and config.tiles.min_ray_depression_deg > 0:
        grazing = batch.valid & (np.asarray(steep) < config.tiles.min_returns)
        p = np.where(grazing, np.float32(np.nan), p).astype(np.float32)
    return Judgement(batch, ground, p_net, p, guard, ood, grazing)


def _cut_tiles(counts: Counts, todo: np.ndarray, config: AssessorConfig, ground: TileGround,
               predictor: Predictor) -> tuple[TileBatch, int]:
    """The tiler's batch and the pooling its inputs come with.

    The cubes of tiles that cannot be valid are not built: no network reads them; those that
    are come max-pooled by the net's opening pool (the tiler writes an eighth of the cube, the
    network skips that pass over it; the same numbers)."""
    model = predictor.model
    pool = int(model.input_pool)
    if model.config.input_size % pool:
        pool = 1
    batch = tiles_from_counts(*counts, config.map.voxel_size, config.tiles, todo, ground,
                              invalid_inputs=False, pool=pool)
    return batch, pool


def _predict(batch: TileBatch, pool: int, config: AssessorConfig, predictor: Predictor,
             reference: FeatureReference | None) -> tuple[np.ndarray, np.ndarray]:
    """The network's P(safe) of the valid tiles and their OOD ratio (NaN elsewhere)."""
    p_net = np.full(len(batch.index), np.nan, np.float32)
    ood = np.full(len(batch.index), np.nan, np.float32)
    if not batch.valid.any():
        return p_net, ood
    # the tiler writes 2 * density - 1: finite by construction, no check
    x, bs = batch.inputs[batch.valid], config.model.batch_size
    if reference is not None:
        p_net[batch.valid], feats = predictor.with_features(
            x, batch_size=bs, check_finite=False, pooled=pool > 1)
        ood[batch.valid] = reference.ratio(feats)
    else:
        p_net[batch.valid] = predictor(x, batch_size=bs, check_finite=False, pooled=pool > 1)
    return p_net, ood
