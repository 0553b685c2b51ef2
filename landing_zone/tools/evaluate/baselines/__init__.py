"""The baselines of the paper's Table II, against which the CNN is evaluated.

Each method is a small object with a ``name``, an optional ``fit(train_inputs, train_labels)``
and ``score(inputs) -> (T,)`` (higher = safer), reading the same inputs as the CNN:
float32 volumes ``(T, 1, S, S, S)`` of ``2 * density - 1`` (see :mod:`.volumes`).

- "Plane residuals" (:class:`PlaneResiduals`): robust plane fit, clipped residual sum; no
  training.
- "Raw RF" (:class:`RawForest`): random forest on the flattened volume.
- "BoW RF" (:class:`BowForest`): per-voxel hand-crafted features, soft bag of words, random
  forest.
"""
from __future__ import annotations

from typing import Any, Protocol, runtime_checkable

import numpy as np

from landing_zone.tools.evaluate.baselines.bow import BowForest
from landing_zone.tools.evaluate.baselines.features import FEATURE_NAMES, VoxelFeatures, \
    voxel_features
from landing_zone.tools.evaluate.baselines.plane import PlaneResiduals, fit_plane, \
    plane_residual_sum
from landing_zone.tools.evaluate.baselines.raw_forest import RawForest
from landing_zone.tools.evaluate.baselines.volumes import VolumeGeometry, as_volumes

__all__ = [
    'Baseline',
    'BowForest',
    'FEATURE_NAMES',
    'PlaneResiduals',
    'RawForest',
    'VolumeGeometry',
    'VoxelFeatures',
    'as_volumes',
    'fit_plane',
    'make_baselines',
    'plane_residual_sum',
    'voxel_features',
]


@runtime_checkable
class Baseline(Protocol):
    """What evaluation needs of a method (``fit`` is present only on learned ones)."""

    name: str

    def score(self, inputs: Any) -> np.ndarray:
        """Safety score per volume, higher = safer."""
        ...


def make_baselines(seed: int = 0,
                   geometry: VolumeGeometry | None = None) -> list[Baseline]:
    """The paper's three baselines, in its order, seeded with ``seed``.

    Args:
        seed: seed of every random process in the methods.
        geometry: voxel size and tile size of the inputs; default 5 cm voxels, 1 m tiles.
    """
    return [PlaneResiduals(geometry, seed=seed), RawForest(seed=seed),
            BowForest(seed=seed, geometry=geometry)]
