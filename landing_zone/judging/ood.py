"""The out-of-distribution (OOD) signal: how unlike its training data a tile looks to the net.

The net's penultimate features (what its head reads: 128 numbers per tile for the shipped net)
place a tile among the tiles it was trained on. A tile whose features lie far from every
training tile's is one the net has no experience of, whatever P(safe) it gives it: its
judgement is extrapolation. The score is the Euclidean distance of the tile's L2-normalised
features to their ``k``-th nearest neighbour among a **reference** of training tiles' features
(Sun et al., "Out-of-distribution detection with deep nearest neighbors", ICML 2022); the
**threshold** is a quantile of the same distance for training-like tiles the reference does
not hold (held-out scenes), so about ``100 - quantile`` % of tiles like the training data lie
past it.

The assessor applies it after the guard (``ood.*`` parameters): a tile the net calls safe
(P(safe) >= 0.5) whose distance exceeds the threshold becomes **unknown** with the reason
:data:`REASON_OOD`; a tile judged unsafe stays unsafe (not landing needs no trust). Every
judged tile's confidence is scaled by ``min(1, threshold / distance)``: unchanged within the
threshold, lowered past it.

The reference is a safetensors file beside the model (``NAME.ood.safetensors`` for
``NAME.safetensors``: :func:`reference_path_for`) holding the features and, in its metadata, k,
the threshold, the quantile and the SHA-256 of the model's weights; :func:`load_reference`
refuses a file of another model, or one that is unreadable or malformed, with one line. Nothing
in it is executed (safetensors holds raw arrays; no pickle). ``landing-zone fit-ood`` fits one
(:mod:`landing_zone.tools.learn.ood_fit`).
"""
from __future__ import annotations

import hashlib
import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch

from landing_zone.errors import ModelError

__all__ = ['FeatureReference', 'fit_reference', 'save_reference', 'load_reference',
           'reference_path_for', 'unit_rows', 'REASON_OOD', 'FORMAT']

FORMAT = 'landing_zone.ood/1'  # reference format tag in the metadata
REASON_OOD = 'unlike the training data'
_META_KEY = 'landing_zone_ood'
_TENSOR = 'features'


def unit_rows(features: np.ndarray) -> np.ndarray:
    """(N, D) float32 rows scaled to unit length (all-zero rows stay zero)."""
    f = np.asarray(features, np.float32)
    norm = np.linalg.norm(f, axis=1, keepdims=True)
    out: np.ndarray = (f / np.maximum(norm, 1e-12)).astype(np.float32)
    return out


@dataclass
class FeatureReference:
    """Training features of one model and the threshold on their k-NN distance.

    Attributes:
        features: (N, D) float32 L2-normalised penultimate features of training tiles.
        k: the neighbour whose distance is the score (1 = the nearest).
        threshold: distance past which a tile counts as unlike the training data.
        quantile: the quantile [%] of held-out training tiles' distances ``threshold`` is.
        weights_sha256: the model's weights digest (its checkpoint metadata).
        meta: how it was fitted (data, scenes, seed, held-out tiles).
    """

    features: np.ndarray
    k: int
    threshold: float
    quantile: float
    weights_sha256: str
    meta: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        # a tensor view of the same memory, made once: the distance runs on every pass
        self._ref = torch.from_numpy(np.ascontiguousarray(self.features, np.float32))

    @property
    def digest(self) -> str:
        """SHA-256 of what decides the signal (features, k, threshold): the identity a map
        snapshot records, so tiles judged with another reference are judged again."""
        sha = hashlib.sha256(np.ascontiguousarray(self.features, np.float32).tobytes())
        sha.update(f'{self.k} {self.threshold!r}'.encode())
        return sha.hexdigest()

    @property
    def dim(self) -> int:
        """Feature width D."""
        return int(self.features.shape[1])

    def distance(self, features: np.ndarray | torch.Tensor, chunk: int = 1024) -> np.ndarray:
        """(T,) float32 distance of each tile's unit features to its k-th nearest reference.

        For unit vectors ``|a - b|^2 = 2 - 2 a.b``, so the k largest dot products give the k
        nearest. A torch matmul with top-k rather than scikit-learn's ``NearestNeighbors``:
        measured on the 2-core machine for 400 queries against 4k and 20k references of 128
        features, torch's matmul + top-k (36-70 ms, 96-190 ms, under load) was as fast as a
        numpy matmul + partition and faster than ``NearestNeighbors`` brute force (100-170
        ms, 155-350 ms; its trees were slower still at 128 dimensions), and torch is already
        what the onboard code runs on. Top-k on the dot products, not on the distances,
        saves a pass over the (T, N) matrix. ``chunk`` rows at a time bound its memory.

        Raises:
            ModelError: features of another width than the reference's.
        """
        q = torch.as_tensor(features, dtype=torch.float32)
        if q.dim() != 2 or q.shape[1] != self.dim:
            raise ModelError(f'OOD reference holds {self.dim} features per tile, got '
                             f'{tuple(q.shape)}')
        out = torch.empty(q.shape[0], dtype=torch.float32)
        with torch.inference_mode():
            for i in range(0, q.shape[0], chunk):
                qb = torch.nn.functional.normalize(q[i:i + chunk], dim=1, eps=1e-12)
                sim = torch.topk(qb @ self._ref.T, self.k, dim=1, sorted=True).values[:, -1]
                out[i:i + chunk] = (2.0 - 2.0 * sim).clamp_min_(0.0).sqrt_()
        result: np.ndarray = out.numpy()
        return result

    def ratio(self, features: np.ndarray | torch.Tensor) -> np.ndarray:
        """(T,) float32 distance over the threshold: past 1, unlike the training data."""
        out: np.ndarray = (self.distance(features) / np.float32(self.threshold)).astype(
            np.float32)
        return out


def fit_reference(reference: np.ndarray, held_out: np.ndarray, weights_sha256: str,
                  k: int = 10, quantile: float = 99.5,
                  meta: dict[str, Any] | None = None) -> FeatureReference:
    """A reference of training tiles' features, its threshold set on other training tiles.

    Args:
        reference: (N, D) penultimate features of the tiles the reference holds, N >= k.
        held_out: (M, D) features of training-like tiles not among them (M >= 1): the
            threshold is the ``quantile`` of their distances.
        weights_sha256: the model's weights digest.
        k: the neighbour whose distance is the score.
        quantile: [%] of the held-out tiles' distances taken as the threshold, in (0, 100].
        meta: recorded with the reference.

    Raises:
        ValueError: too few rows, mismatched widths, non-finite features or a bad quantile.
    """
    ref = np.asarray(reference, np.float32)
    out = np.asarray(held_out, np.float32)
    if ref.ndim != 2 or out.ndim != 2 or ref.shape[1] != out.shape[1]:
        raise ValueError(f'reference and held-out features must be (N, D) and (M, D), got '
                         f'{ref.shape} and {out.shape}')
    if not 1 <= k <= len(ref) or not len(out):
        raise ValueError(f'need at least k = {k} reference rows and one held-out row, got '
                         f'{len(ref)} and {len(out)}')
    if not (np.isfinite(ref).all() and np.isfinite(out).all()):
        raise ValueError('features contain NaN or Inf')
    if not 0.0 < quantile <= 100.0:
        raise ValueError(f'quantile must lie in (0, 100], got {quantile}')
    fitted = FeatureReference(unit_rows(ref), int(k), 1.0, float(quantile), str(weights_sha256),
                              dict(meta or {}))
    threshold = float(np.percentile(fitted.distance(out), quantile))
    # a held-out set identical to the reference would give 0: no tile could pass
    fitted.threshold = max(threshold, 1e-6)
    return fitted


def reference_path_for(model_path: str | os.PathLike[str]) -> Path:
    """``NAME.ood.safetensors`` beside ``NAME.safetensors``."""
    p = Path(model_path)
    return p.with_name(p.name.removesuffix('.safetensors') + '.ood.safetensors')


def save_reference(path: str | os.PathLike[str], ref: FeatureReference) -> None:
    """Write a reference as safetensors (the features; the rest in its metadata), atomically."""
    from safetensors.numpy import save_file

    meta = {'format': FORMAT, 'k': ref.k, 'threshold': ref.threshold, 'quantile': ref.quantile,
            'weights_sha256': ref.weights_sha256, 'meta': ref.meta}
    dest = Path(path)
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = dest.with_name(dest.name + '.tmp')
    try:
        save_file({_TENSOR: np.ascontiguousarray(ref.features, np.float32)}, str(tmp),
                  metadata={_META_KEY: json.dumps(meta, sort_keys=True, allow_nan=False)})
        os.replace(tmp, dest)
    finally:
        if tmp.exists():
            tmp.unlink()


def _first_line(err: BaseException) -> str:
    text = str(err).strip().splitlines()
    return text[0] if text else type(err).__name__


def load_reference(path: str | os.PathLike[str], weights_sha256: str,
                   dim: int | None = None) -> FeatureReference:
    """Read a reference and check that it belongs to the model (nothing in it is executed).

    Args:
        path: a file written by :func:`save_reference`.
        weights_sha256: the model's weights digest
            (:func:`~landing_zone.judging.checkpoint.weights_sha256`); the reference must
            record the same.
        dim: the model's feature width, if known; the reference must have it.

    Raises:
        ModelError: missing, unreadable, of another format, malformed, or of another model
            (one line naming the file and what is wrong).
    """
    from safetensors import safe_open

    p = Path(path)
    if not p.is_file():
        raise ModelError(f'OOD reference not found: {p}')
    try:
        with safe_open(str(p), framework='numpy') as f:
            raw = (f.metadata() or {}).get(_META_KEY)
            if raw is None:
                raise ModelError(f'{p}: safetensors file without OOD reference metadata')
            meta = json.loads(raw)
            features = np.asarray(f.get_tensor(_TENSOR), np.float32)
    except ModelError:
        raise
    except Exception as err:  # safetensors, JSON, key and OS errors all mean unreadable
        raise ModelError(f'{p}: not a readable OOD reference ({_first_line(err)})') from err
    if not isinstance(meta, dict) or meta.get('format') != FORMAT:
        found = meta.get('format') if isinstance(meta, dict) else None
        raise ModelError(f'{p}: unknown OOD reference format {found!r}, expected {FORMAT!r}')
    try:
        k, threshold = int(meta['k']), float(meta['threshold'])
        quantile, sha = float(meta['quantile']), str(meta['weights_sha256'])
        extra = dict(meta.get('meta') or {})
    except (KeyError, TypeError, ValueError) as err:
        raise ModelError(f'{p}: malformed OOD reference metadata ({_first_line(err)})') from err
    if (features.ndim != 2 or not 1 <= k <= len(features) or not math.isfinite(threshold)
            or threshold <= 0 or not np.isfinite(features).all()):
        raise ModelError(f'{p}: malformed OOD reference (features {features.shape}, k {k}, '
                         f'threshold {threshold})')
    if sha != weights_sha256:
        raise ModelError(f'{p} was fitted for another model (weights {sha[:12]}, the model '
                         f'has {weights_sha256[:12]}): refit it with landing-zone fit-ood or '
                         'set ood.enabled false')
    norms = np.linalg.norm(features, axis=1)
    if not np.allclose(norms, 1.0, atol=1e-4):
        # the distance assumes unit rows; a file with others was not written by save_reference
        raise ModelError(f'{p}: malformed OOD reference (feature rows not of unit length, '
                         f'{float(norms.min()):.3g} to {float(norms.max()):.3g})')
    if dim is not None and features.shape[1] != dim:
        raise ModelError(f'{p}: {features.shape[1]} features per tile, the model has {dim}')
    return FeatureReference(features, k, threshold, quantile, sha, extra)
