"""Anchor sets: datasets never trained on whose obstacles a fine-tuned model's offset must hold on.

The anchored calibration (:mod:`landing_zone.tools.learn.anchored_calibration`) lowers the
offset until no reference group passes more obstacles than under the initial model. The training
sources' validation scenes show it only shapes the fine-tuning trains on; the leniency a site's
vegetation teaches shows on shapes it does not (a net that learns that tall sparse grass is safe
grows more lenient on see-through structure). An anchor set is such shapes, held out of the
fine-tuning: each dataset given to ``train`` as ``anchor_data`` (the command line's
``--anchor-data``) is a group of its own.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from landing_zone.config import MapConfig, TileConfig
from landing_zone.errors import ConfigError, DatasetError
from landing_zone.tools.learn.anchored_calibration import anchored_offset
from landing_zone.tools.learn.samples import voxelize
from landing_zone.tools.learn.scenes import ScenePack, open_source

__all__ = ['AnchorSets', 'check_held_out', 'anchor_offset', 'load_anchor_sets']


@dataclass
class AnchorSets:
    """Every train-split scene of the anchor sets, voxelized as validation scenes are."""

    inputs: torch.Tensor
    labels: torch.Tensor
    groups: np.ndarray  # 0.. per anchor set
    names: list[str]


def _paths(data: Any) -> list[Path]:
    if isinstance(data, (str, os.PathLike)):
        return [Path(data).resolve()]
    if isinstance(data, (list, tuple)) and all(isinstance(d, (str, os.PathLike)) for d in data):
        return [Path(d).resolve() for d in data]
    return []


def _sets(anchor_data: Any) -> list[Any]:
    """One dataset directory, or a list of datasets (directories or scene sequences)."""
    return [anchor_data] if isinstance(anchor_data, (str, os.PathLike)) else list(anchor_data)


def check_held_out(anchor_data: Any, data: Any) -> None:
    """A anchor set must be held out of the fine-tuning: the same directory in both is refused."""
    if anchor_data is None:
        return
    sets = _sets(anchor_data)
    if not sets:
        raise ConfigError('anchor data: give at least one dataset')
    anchor_paths = {str(Path(g).resolve()) for g in sets if isinstance(g, (str, os.PathLike))}
    both = sorted(anchor_paths & set(map(str, _paths(data))))
    if both:
        raise ConfigError(f'{both[0]} is both training data and anchor data: an anchor set must '
                          'hold scenes the fine-tuning never sees')


def load_anchor_sets(anchor_data: Any, map_cfg: MapConfig, tile_cfg: TileConfig, workers: int,
                     progress: bool) -> AnchorSets:
    """Load and voxelize every train-split scene of each anchor set (one group per set)."""
    inputs, labels, groups, names = [], [], [], []
    for k, one in enumerate(_sets(anchor_data)):
        source, name = open_source(one)
        if len(source) == 0:
            raise DatasetError(f'anchor data {name}: no scenes')
        pack = ScenePack.from_scenes(source, np.arange(len(source)), progress,
                                     'loading anchor scenes')
        x, y = voxelize(pack, map_cfg, tile_cfg, workers, progress, 'voxelizing anchor sets')
        if not (y == 0).any():
            raise DatasetError(f'anchor data {name}: no scene with an obstacle')
        inputs.append(x)
        labels.append(y)
        groups.append(np.full(len(y), k, np.int64))
        names.append(name)
    return AnchorSets(torch.cat(inputs), torch.cat(labels), np.concatenate(groups), names)


def anchor_offset(new_logits: np.ndarray, init_logits: np.ndarray, labels: np.ndarray,
                  groups: np.ndarray, names: list[str], temperature: float, offset: float,
                  sets: AnchorSets | None = None,
                  set_logits: tuple[np.ndarray, np.ndarray] | None = None
                  ) -> tuple[float, dict[str, Any]]:
    """The anchored offset over the validation tiles of each training source (``groups`` number
    them, ``names`` name them: :func:`~landing_zone.tools.learn.scenes.part_names`) and, when
    given,
    the anchor sets' tiles (``set_logits``: the fine-tuned and the initial net's logits on
    ``sets.inputs``), each group named by its source.

    Returns:
        ``(b', record)``: the record is :func:`anchored_offset`'s report with ``fitted_on`` and
        every group's ``source``.
    """
    fitted_on = 'validation scenes with an obstacle, per training source'
    if sets is not None:
        if set_logits is None:
            raise ConfigError('anchor sets given without their logits')
        new_logits = np.concatenate([new_logits, set_logits[0]])
        init_logits = np.concatenate([init_logits, set_logits[1]])
        labels = np.concatenate([labels, sets.labels.numpy()])
        groups = np.concatenate([groups, len(names) + sets.groups])
        names = names + sets.names
        fitted_on += ', and every obstacle scene of each anchor set (never trained on)'
    b, report = anchored_offset(new_logits, init_logits, labels, temperature, offset,
                                groups=groups)
    for entry in report['groups']:
        entry['source'] = names[entry['group']]
    return b, {'fitted_on': fitted_on, **report}
