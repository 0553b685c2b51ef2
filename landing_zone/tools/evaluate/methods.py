"""What an evaluation method is, and its figures on one split: ROC, AUC, ECE and timing.

A method is any object with a ``name``, ``score(inputs) -> (T,)`` (higher = safer) and optionally
``fit(train_inputs, train_labels)`` and ``probabilistic`` (its scores are P(safe), so an ECE is
reported; without the attribute, scores that all lie in [0, 1] count as probabilities). The CNN
(:class:`CNNMethod`) and the baselines of :mod:`landing_zone.tools.evaluate.baselines` plug in
alike. The tables, the per-family report and the figures all read :class:`MethodResult`.
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

import numpy as np

from landing_zone.errors import DatasetError
from landing_zone.judging.inference import predict
from landing_zone.judging.net import SafetyNet
from landing_zone.tools.learn.calibration import Reliability, reliability

__all__ = ['ECE_BINS', 'Method', 'CNNMethod', 'MethodResult', 'evaluate_methods', 'measure']

# ECE uses 15 equal-width bins of P(safe)
ECE_BINS = 15


@runtime_checkable
class Method(Protocol):
    """What evaluation needs of a method (``fit`` and ``probabilistic`` are optional)."""

    name: str

    def score(self, inputs: Any) -> np.ndarray:
        """Safety score per volume, higher = safer."""
        ...


class CNNMethod:
    """The safety CNN as an evaluation method: scores are calibrated P(safe)."""

    probabilistic = True

    def __init__(self, model: SafetyNet, batch_size: int = 256, precision: str = 'auto'
                 ) -> None:
        self.model = model.eval()
        self.name = f'CNN {model.spec}'
        self.batch_size = batch_size
        self.precision = precision

    def score(self, inputs: Any) -> np.ndarray:
        return predict(self.model, inputs, self.batch_size, self.precision)


@dataclass
class MethodResult:
    """One method's figures on one split."""

    name: str
    scores: np.ndarray
    auc: float
    ece: float | None
    ms_per_volume: float
    fpr: np.ndarray
    tpr: np.ndarray
    reliability: Reliability | None


def _is_probabilistic(method: Any, scores: np.ndarray) -> bool:
    flag = getattr(method, 'probabilistic', None)
    if flag is not None:
        return bool(flag)
    return bool(scores.size) and bool(np.all((scores >= 0) & (scores <= 1)))


def evaluate_methods(methods: list[Any], inputs: Any, labels: np.ndarray,
                     train_inputs: Any = None, train_labels: np.ndarray | None = None,
                     progress: bool = False) -> list[MethodResult]:
    """Fit (where a method can and training data is given), score and measure every method.

    Args:
        methods: objects with ``name`` and ``score`` (see :class:`Method`).
        inputs: (T, 1, S, S, S) float32 test volumes.
        labels: (T,) 1 safe, 0 unsafe.
        train_inputs, train_labels: data for methods with ``fit``.

    Raises:
        DatasetError: labels of one class only, or a method returned the wrong number of scores.
    """
    y = np.asarray(labels).reshape(-1).astype(np.int64)
    if y.size == 0 or y.min() == y.max():
        raise DatasetError('evaluation needs safe and unsafe volumes')
    out: list[MethodResult] = []
    for m in methods:
        if hasattr(m, 'fit') and train_inputs is not None:
            if progress:
                print(f'evaluate: fitting {m.name}', file=sys.stderr)
            m.fit(train_inputs, train_labels)
        if progress:
            print(f'evaluate: scoring {m.name}', file=sys.stderr)
        m.score(inputs[:2])  # warm up (compilation, inference copies) outside the timing
        t0 = time.perf_counter()
        scores = np.asarray(m.score(inputs), np.float64).reshape(-1)
        ms = (time.perf_counter() - t0) * 1000.0 / len(y)
        if scores.shape != y.shape or not np.all(np.isfinite(scores)):
            raise DatasetError(f'{m.name} returned {scores.size} scores (finite: '
                               f'{bool(np.all(np.isfinite(scores)))}) for {y.size} volumes')
        out.append(measure(m.name, scores, y, ms, _is_probabilistic(m, scores)))
    return out


def measure(name: str, scores: np.ndarray, labels: np.ndarray, ms_per_volume: float,
            probabilistic: bool) -> MethodResult:
    """A method's figures from its scores: ROC, AUC and, for P(safe), the reliability
    diagram and ECE."""
    from sklearn.metrics import roc_auc_score, roc_curve

    fpr, tpr, _ = roc_curve(labels, scores, pos_label=1)
    auc = float(roc_auc_score(labels, scores))
    rel = reliability(scores, labels, ECE_BINS) if probabilistic else None
    return MethodResult(name, scores, auc, None if rel is None else rel.ece, ms_per_volume,
                        fpr, tpr, rel)
