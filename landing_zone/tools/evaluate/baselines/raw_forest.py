"""Raw volumetric random forest: the CNN's input, flattened, into a random forest.

The paper's second baseline asks how much of the CNN's accuracy comes from learning at all
rather than from convolution: a forest of 20 unpruned trees sees exactly the subvolume the
network sees, one feature per voxel, and no notion of which voxels are neighbours.
"""
from __future__ import annotations

from typing import Any

import numpy as np
from sklearn.ensemble import RandomForestClassifier

from landing_zone.tools.evaluate.baselines.volumes import as_labels, as_volumes
from landing_zone.errors import DatasetError, ModelError

__all__ = ['RawForest', 'make_forest', 'safe_probability']


def make_forest(seed: int, trees: int = 20) -> RandomForestClassifier:
    """The forest both learned baselines use: ``trees`` unpruned trees, all cores, seeded."""
    return RandomForestClassifier(n_estimators=trees, max_depth=None, n_jobs=-1,
                                  random_state=seed)


def safe_probability(forest: RandomForestClassifier, features: np.ndarray) -> np.ndarray:
    """The forest's P(safe) (label 1) for each row of ``features``, shape (T,)."""
    if features.shape[0] == 0:
        return np.zeros(0)
    proba = forest.predict_proba(features)
    return proba[:, int(np.flatnonzero(forest.classes_ == 1)[0])].astype(np.float64)


class RawForest:
    """The "Raw RF" baseline: a random forest on the flattened input volume.

    Attributes:
        name: the paper's name of the method.
        probabilistic: whether scores are P(safe) (evaluation reports an ECE only then).
        forest: the fitted scikit-learn forest (None before :meth:`fit`).
    """

    name = 'Raw RF'
    probabilistic = True  # scores are the forest's P(safe) (vote shares, uncalibrated)

    def __init__(self, seed: int = 0, trees: int = 20) -> None:
        """Set up an unfitted forest of ``trees`` trees seeded with ``seed``."""
        self.seed = int(seed)
        self.trees = int(trees)
        self.forest: RandomForestClassifier | None = None
        self._shape: tuple[int, ...] | None = None

    def fit(self, train_inputs: Any, train_labels: Any) -> 'RawForest':
        """Train on volumes (T, 1, S, S, S) and labels (T,) (1 safe, 0 unsafe).

        Raises:
            DatasetError: malformed volumes or labels, or a single class.
        """
        vol = as_volumes(train_inputs)
        labels = as_labels(train_labels, vol.shape[0])
        forest = make_forest(self.seed, self.trees)
        forest.fit(vol.reshape(vol.shape[0], -1), labels)
        self.forest, self._shape = forest, vol.shape[1:]
        return self

    def score(self, inputs: Any) -> np.ndarray:
        """P(safe) of each volume, shape (T,).

        Raises:
            ModelError: not fitted yet.
            DatasetError: volumes malformed or of another size than the training ones.
        """
        if self.forest is None:
            raise ModelError(f'{self.name} must be fitted before it can score')
        vol = as_volumes(inputs)
        if vol.shape[1:] != self._shape:
            raise DatasetError(f'{self.name} was trained on volumes of shape {self._shape}, '
                               f'got {vol.shape[1:]}')
        return safe_probability(self.forest, vol.reshape(vol.shape[0], -1))
