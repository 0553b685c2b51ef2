"""Bag of words over hand-crafted voxel features, then a random forest.

The paper's strongest baseline, the classic point-cloud classification pipeline: describe every
occupied voxel of the tile by local features
(:mod:`landing_zone.tools.evaluate.baselines.features`), learn a codebook of 512 feature "words"
by k-means on a quarter of the training volumes, describe each volume by its soft histogram over
the words, and classify the histograms with a random forest.

Soft quantisation: each voxel spreads a unit of weight over its ``neighbours`` nearest words
with a Gaussian kernel ``exp(-d^2 / (2 sigma^2))``, sigma^2 being the median squared distance
of a codebook-sample voxel to its nearest word; the histogram is divided by the number of
voxels so volumes with more returns are not simply "bigger".
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np
from sklearn.cluster import MiniBatchKMeans
from sklearn.ensemble import RandomForestClassifier

from landing_zone.tools.evaluate.baselines.features import VoxelFeatures, voxel_features
from landing_zone.tools.evaluate.baselines.raw_forest import make_forest, safe_probability
from landing_zone.tools.evaluate.baselines.volumes import VolumeGeometry, as_labels, as_volumes
from landing_zone.errors import ConfigError, DatasetError, ModelError

__all__ = ['BowForest']


class BowForest:
    """The "BoW RF" baseline: soft bag-of-words histograms into a random forest.

    Attributes:
        name: the paper's name of the method.
        probabilistic: whether scores are P(safe) (evaluation reports an ECE only then).
        words: (K, F) float32 codebook in standardised feature units (None before fit).
        forest: the fitted scikit-learn forest (None before fit).
    """

    name = 'BoW RF'
    probabilistic = True  # scores are the forest's P(safe) (vote shares, uncalibrated)

    def __init__(self, seed: int = 0, words: int = 512, neighbours: int = 5,
                 codebook_fraction: float = 0.25, max_codebook_voxels: int = 500_000,
                 trees: int = 20, geometry: VolumeGeometry | None = None, radius: int = 1,
                 column_radius: int = 2, chunk: int = 32) -> None:
        """Set up an unfitted model.

        Args:
            seed: seed of the codebook sample, k-means and the forest.
            words: codebook size (the paper's 512); fewer if the sample has fewer voxels.
            neighbours: nearest words each voxel's weight is spread over.
            codebook_fraction: share of the training volumes the codebook is learned on.
            max_codebook_voxels: at most this many voxels (drawn at random from those volumes)
                feed k-means, which bounds its memory and time on large datasets.
            trees: trees of the forest.
            geometry: voxel size, tile core and thresholds of the inputs.
            radius: neighbourhood half-width of the voxel features [voxels].
            column_radius: half-width of the column block of the height features [voxels].
            chunk: volumes featurised at once (bounds memory).

        Raises:
            ConfigError: a parameter out of range.
        """
        if words < 1 or neighbours < 1 or max_codebook_voxels < 1 or trees < 1 or chunk < 1:
            raise ConfigError('words, neighbours, max_codebook_voxels, trees and chunk must be '
                              '>= 1')
        if not 0.0 < codebook_fraction <= 1.0:
            raise ConfigError(f'codebook_fraction must lie in (0, 1], got {codebook_fraction!r}')
        self.seed = int(seed)
        self.n_words = int(words)
        self.neighbours = int(neighbours)
        self.codebook_fraction = float(codebook_fraction)
        self.max_codebook_voxels = int(max_codebook_voxels)
        self.trees = int(trees)
        self.geometry = geometry if geometry is not None else VolumeGeometry()
        self.geometry.validate()
        self.radius = int(radius)
        self.column_radius = int(column_radius)
        self.chunk = int(chunk)
        self.words: np.ndarray | None = None
        self.forest: RandomForestClassifier | None = None
        self._mean: np.ndarray | None = None
        self._scale: np.ndarray | None = None
        self._sigma2 = 1.0

    # -- fitting ----------------------------------------------------------------------------

    def fit(self, train_inputs: Any, train_labels: Any) -> 'BowForest':
        """Learn the codebook and the forest from volumes (T, 1, S, S, S) and labels (T,).

        Raises:
            DatasetError: malformed volumes or labels, a single class, or no occupied voxel in
                the codebook sample.
        """
        vol = as_volumes(train_inputs)
        labels = as_labels(train_labels, vol.shape[0])
        self.fit_codebook(vol)
        forest = make_forest(self.seed, self.trees)
        forest.fit(self.histograms(vol), labels)
        self.forest = forest
        return self

    def fit_codebook(self, inputs: Any) -> np.ndarray:
        """Learn the feature standardisation and the codebook; return the words (K, F).

        Raises:
            DatasetError: malformed volumes or no occupied voxel in the sample.
        """
        vol = as_volumes(inputs)
        rng = np.random.default_rng(self.seed)
        n_pick = max(1, math.ceil(self.codebook_fraction * vol.shape[0]))
        pick = np.sort(rng.choice(vol.shape[0], size=n_pick, replace=False))
        feats = self._features(vol[pick]).values
        if feats.shape[0] == 0:
            raise DatasetError('the codebook sample has no occupied voxel in any tile core')
        if feats.shape[0] > self.max_codebook_voxels:
            keep = np.sort(rng.choice(feats.shape[0], self.max_codebook_voxels, replace=False))
            feats = feats[keep]
        mean = feats.mean(axis=0, dtype=np.float64)
        std = feats.std(axis=0, dtype=np.float64)
        self._mean = mean.astype(np.float32)
        # A feature constant over the sample carries nothing; scale 1 keeps it finite.
        self._scale = np.where(std > 1e-9, std, 1.0).astype(np.float32)
        z = (feats - self._mean) / self._scale
        k = min(self.n_words, z.shape[0])
        km = MiniBatchKMeans(n_clusters=k, random_state=self.seed, n_init=3, batch_size=4096)
        km.fit(z)
        self.words = km.cluster_centers_.astype(np.float32)
        # Blocks keep the (P, K) distance matrix small on a large sample.
        nearest = np.concatenate([self._sq_distances(z[s:s + 65536]).min(axis=1)
                                  for s in range(0, z.shape[0], 65536)])
        median = float(np.median(nearest))
        self._sigma2 = median if median > 1e-12 else 1.0
        return self.words

    # -- histograms and scores ----------------------------------------------------------------

    def histograms(self, inputs: Any) -> np.ndarray:
        """Soft bag-of-words histogram of each volume, (T, K) float32, rows sum to 1 (0 if empty).

        Raises:
            ModelError: the codebook is not learned yet.
            DatasetError: malformed volumes.
        """
        if self.words is None:
            raise ModelError(f'{self.name} must be fitted before it can describe volumes')
        vol = as_volumes(inputs)
        n_words = self.words.shape[0]
        out = np.zeros((vol.shape[0], n_words), np.float64)
        for start in range(0, vol.shape[0], self.chunk):
            f = self._features(vol[start:start + self.chunk])
            if f.values.shape[0] == 0:
                continue
            d2 = self._sq_distances((f.values - self._mean) / self._scale)
            near, dn = _nearest(d2, min(self.neighbours, n_words))
            # Subtracting each row's minimum keeps the nearest word's weight at 1 however far
            # the voxel lies from the codebook; the row normalisation removes the factor.
            w = np.exp(-(dn - dn[:, :1]) / (2.0 * self._sigma2))
            w /= w.sum(axis=1, keepdims=True)
            rows = f.volume[:, None] * n_words + near
            block = np.bincount(rows.ravel(), weights=w.ravel(),
                                minlength=(min(self.chunk, vol.shape[0] - start)) * n_words)
            out[start:start + self.chunk] = block.reshape(-1, n_words)
        counts = out.sum(axis=1, keepdims=True)
        np.divide(out, counts, out=out, where=counts > 0)
        return out.astype(np.float32)

    def score(self, inputs: Any) -> np.ndarray:
        """P(safe) of each volume, shape (T,).

        Raises:
            ModelError: not fitted yet.
            DatasetError: malformed volumes.
        """
        if self.forest is None:
            raise ModelError(f'{self.name} must be fitted before it can score')
        return safe_probability(self.forest, self.histograms(inputs))

    # -- helpers ----------------------------------------------------------------------------

    def _features(self, vol: np.ndarray) -> VoxelFeatures:
        return voxel_features(vol, self.geometry, radius=self.radius,
                              column_radius=self.column_radius, chunk=self.chunk)

    def _sq_distances(self, z: np.ndarray) -> np.ndarray:
        """Squared distances (P, K) of standardised features to the words."""
        assert self.words is not None
        w = self.words
        d2 = (np.einsum('pf,pf->p', z, z)[:, None] - 2.0 * (z @ w.T)
              + np.einsum('kf,kf->k', w, w)[None, :])
        return np.maximum(d2, 0.0)


def _nearest(d2: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Indices and squared distances (P, k) of each row's k smallest entries, nearest first.

    For the few neighbours used, k passes of argmin are five times faster than
    ``np.argpartition`` over 512 words (which sorts a partition per row).
    """
    d = d2.copy()
    rows = np.arange(d.shape[0])
    idx = np.empty((d.shape[0], k), np.int64)
    dist = np.empty((d.shape[0], k), np.float64)
    for m in range(k):
        best = d.argmin(axis=1)
        idx[:, m] = best
        dist[:, m] = d[rows, best]
        d[rows, best] = np.inf
    return idx, dist
