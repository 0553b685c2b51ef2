"""``landing-zone fit-ood``: the OOD reference of a model, from scenes of its training data.

The reference (:mod:`landing_zone.judging.ood`) holds the penultimate features of tiles like
those the model was trained on, and a threshold on their k-NN distance. Both come from scenes
of the train split of the given dataset directories (pass the data the model was trained on,
or fresh scenes of the same sweep: ``simulate --seed`` other than the training seed):

1. ``scenes`` scenes are drawn from the pooled train splits with ``seed``; a share
   ``held_out`` of them (whole scenes) set the threshold, the others form the reference;
2. each scene is voxelized ``views`` times, as training augments it (a yaw uniform in
   [0, 2 pi) about the tile centre, drawn from ``SeedSequence([seed, scene])``), through
   :func:`~landing_zone.judging.patches.scene_to_input` with the model's voxel size and tiles;
3. the net's features of every valid view go through the same forward pass the assessor runs
   (:meth:`~landing_zone.judging.inference.Predictor.with_features`); the threshold is the
   ``quantile`` of the held-out views' distance to their ``k``-th nearest reference view.

Same model, data and seed: the same reference bytes on one machine.
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from landing_zone.config import MapConfig, TileConfig
from landing_zone.errors import ConfigError, DatasetError
from landing_zone.judging.checkpoint import input_configs, load_model
from landing_zone.judging.inference import Predictor
from landing_zone.judging.ood import FeatureReference, fit_reference, save_reference
from landing_zone.judging.patches import PatchVoxelizer

__all__ = ['OODFit', 'fit_ood']


@dataclass
class OODFit:
    """What :func:`fit_ood` wrote.

    Attributes:
        reference: the fitted reference.
        path: where it was written.
        scenes: scenes read (reference + held out).
        reference_tiles: valid views in the reference.
        held_out_tiles: valid views that set the threshold.
        held_out_past: share of the held-out views past the threshold.
        seconds: wall time.
    """

    reference: FeatureReference
    path: Path
    scenes: int
    reference_tiles: int
    held_out_tiles: int
    held_out_past: float
    seconds: float


def _features(predictor: Predictor, pick: list[tuple[int, Any, int]], views: int, seed: int,
              map_cfg: MapConfig, tile_cfg: TileConfig, batch: int = 256,
              progress: bool = True) -> np.ndarray:
    """(n, F) features of the valid views of the picked scenes (pooled index, dataset,
    index in it), in their order."""
    from tqdm import tqdm

    voxelizer = PatchVoxelizer()
    out: list[np.ndarray] = []
    pending: list[np.ndarray] = []

    def flush() -> None:
        if pending:
            out.append(predictor.with_features(np.stack(pending), batch_size=batch)[1])
            pending.clear()

    for j, ds, i in tqdm(pick, unit=' scene', disable=None if progress else True,
                         leave=False, mininterval=0.5, desc='fit-ood'):
        scene = ds[i]
        # the views' yaws hang on the scene's place in the pooled list: a scene gets the same
        # yaws whichever part (reference or held out) it lands in
        rng = np.random.default_rng(np.random.SeedSequence([seed, j]))
        for _ in range(views):
            yaw = float(rng.uniform(0.0, 2.0 * math.pi))
            b = voxelizer(scene.points, scene.origins, map_cfg, tile_cfg, yaw=yaw)
            if b.valid[0]:
                pending.append(b.inputs[0])
        if len(pending) >= batch:
            flush()
    flush()
    width = predictor.model.head.in_features
    return np.concatenate(out) if out else np.zeros((0, width), np.float32)


def fit_ood(model: str | os.PathLike[str], data: Sequence[str | os.PathLike[str]],
            out: str | os.PathLike[str], scenes: int = 1000, held_out: float = 0.25,
            views: int = 3, seed: int = 0, k: int = 10, quantile: float = 99.5,
            progress: bool = True) -> OODFit:
    """Fit and write the OOD reference of ``model`` (see the module docstring).

    Args:
        model: the model file.
        data: dataset directories; their train splits are pooled.
        out: the reference file (``NAME.ood.safetensors`` beside ``NAME.safetensors`` is
            where the assessor finds it).
        scenes: scenes to read, reference and held-out together (fewer if the data has
            fewer).
        held_out: share of them that set the threshold, in (0, 1).
        views: voxelizations of each scene at seeded yaws.
        seed: the draw of the scenes and the yaws.
        k: the neighbour whose distance is the score.
        quantile: [%] of the held-out views' distances taken as the threshold.
        progress: show a progress bar.

    Raises:
        DatasetError: a data directory is missing or its train split is empty.
        ConfigError: bad counts or shares.
        ModelError: the model file is missing or bad.
    """
    from landing_zone.judging.checkpoint import read_metadata
    from landing_zone.tools.sim.shards import SceneDataset

    t0 = time.perf_counter()
    if scenes < 2 or views < 1 or k < 1:
        raise ConfigError(f'need scenes >= 2, views >= 1 and k >= 1, got {scenes}, {views}, {k}')
    if not 0.0 < held_out < 1.0:
        raise ConfigError(f'held_out must lie in (0, 1), got {held_out}')
    if not 0.0 < quantile <= 100.0:
        raise ConfigError(f'quantile must lie in (0, 100], got {quantile}')
    if not data:
        raise ConfigError('give at least one dataset directory (--data)')
    net, meta = load_model(model)
    sha = read_metadata(model)['weights_sha256']
    sets = [SceneDataset(d, 'train') for d in data]
    pool = [(ds, i) for ds in sets for i in range(len(ds))]
    if len(pool) < 2:
        raise DatasetError(f'the train splits of {", ".join(map(str, data))} hold '
                           f'{len(pool)} scene(s); need at least 2')
    rng = np.random.default_rng(seed)
    order = rng.permutation(len(pool))[:min(int(scenes), len(pool))]
    n_held = min(max(1, int(round(held_out * len(order)))), len(order) - 1)
    # the held-out scenes first, then the reference's; each list in the data's order
    held_pick = [(int(j), *pool[j]) for j in np.sort(order[:n_held])]
    ref_pick = [(int(j), *pool[j]) for j in np.sort(order[n_held:])]
    map_cfg, tile_cfg = input_configs(meta)
    with Predictor(net) as predictor:
        ref = _features(predictor, ref_pick, views, seed, map_cfg, tile_cfg, progress=progress)
        held = _features(predictor, held_pick, views, seed, map_cfg, tile_cfg,
                         progress=progress)
    if len(ref) < k or not len(held):
        raise DatasetError(f'too few valid tiles: {len(ref)} for the reference (k = {k}) '
                           f'and {len(held)} held out')
    fitted = fit_reference(ref, held, sha, k=k, quantile=quantile, meta={
        'data': [str(d) for d in data], 'scenes': int(len(order)),
        'held_out_scenes': int(n_held), 'views': int(views), 'seed': int(seed),
        'held_out_tiles': int(len(held)), 'model': Path(model).name})
    path = Path(out)
    save_reference(path, fitted)
    past = float((fitted.ratio(held) > 1.0).mean())
    return OODFit(fitted, path, int(len(order)), int(len(ref)), int(len(held)), past,
                  time.perf_counter() - t0)
