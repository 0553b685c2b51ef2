"""The assessor's network and its OOD reference, loaded and checked against the tiler.

A model that reads other volumes than the tiler makes (another cube side or voxel size) is
refused here, at start-up, rather than judged wrongly later. The network's own modules import
torch, so they are imported when a model is loaded, not with this module.
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING, Any

from landing_zone.config import AssessorConfig
from landing_zone.errors import ModelError

if TYPE_CHECKING:
    from landing_zone.judging.ood import FeatureReference

__all__ = ['load_net', 'load_ood']


def load_net(model: Any, path: Path | None, config: AssessorConfig, tile_vox: int
             ) -> tuple[Any, dict[str, Any], Path | None]:
    """The network: ``model`` if it is one (a SafetyNet or a SafetyEnsemble), else the
    checkpoint at ``path``. Returns it, its metadata and the file it came from.

    Raises:
        ModelError: ``model`` is neither a net nor a path, the file is missing or corrupt, or
            the net reads other volumes than the tiler makes.
    """
    from landing_zone.judging.checkpoint import load_model
    from landing_zone.judging.ensemble import SafetyEnsemble
    from landing_zone.judging.net import SafetyNet

    if isinstance(model, (SafetyNet, SafetyEnsemble)):
        net, meta, path = model.eval(), {}, None
    elif model is not None and not isinstance(model, (str, os.PathLike)):
        raise ModelError(f'model must be a SafetyNet, a SafetyEnsemble or a path, got '
                         f'{type(model).__name__}')
    else:
        assert path is not None
        net, meta = load_model(path, device=config.model.device)
    side = tile_vox + 2 * config.tiles.padding
    if int(net.config.input_size) != side:
        raise ModelError(
            f'model {path or "(given)"} reads {net.config.input_size}^3 volumes but '
            f'tiles.tile_size / map.voxel_size + 2 * tiles.padding gives {side}^3')
    _check_voxel_size(meta, path, config.map.voxel_size)
    return net, meta, path


def _check_voxel_size(meta: dict[str, Any], path: Path | None, voxel_size: float) -> None:
    trained = None
    for holder in (meta, meta.get('map'), meta.get('inputs')):
        if isinstance(holder, dict) and isinstance(holder.get('voxel_size'), (int, float)):
            trained = float(holder['voxel_size'])
            break
    if trained is not None and abs(trained - voxel_size) > 1e-9:
        raise ModelError(f'model {path} was trained on {trained} m voxels but '
                         f'map.voxel_size is {voxel_size} m')


def load_ood(config: AssessorConfig, net: Any, meta: dict[str, Any], model_path: Path | None
             ) -> tuple[FeatureReference | None, Path | None]:
    """The OOD reference: ``ood.path``, else the one beside the model file, if there.

    Raises:
        ModelError: the reference named is missing, bad or of another model.
    """
    from landing_zone.judging.checkpoint import weights_sha256
    from landing_zone.judging.ood import load_reference, reference_path_for

    cfg = config.ood
    if not cfg.enabled:
        return None, None
    if cfg.path:
        path = Path(cfg.path)
    elif model_path is not None and reference_path_for(model_path).is_file():
        path = reference_path_for(model_path)
    else:
        return None, None  # this model has no reference: judged without the signal
    # bound to the weights as loaded (a net passed in memory has no metadata to ask)
    sha = meta.get('weights_sha256') or weights_sha256(net)
    return load_reference(path, sha, dim=net.head.in_features), path
