"""Calibration of P(safe): temperature scaling, expected calibration error, reliability bins.

A net trained with dropout and weight decay ranks tiles well but its probabilities need not
match frequencies. Temperature scaling (Guo et al., ICML 2017) divides the logits by one scalar
``T`` fitted on held-out data by maximum likelihood; it changes no ranking (so no AUC), only how
far from 0.5 the probabilities sit. Platt scaling adds an offset ``b`` (P(safe) =
sigmoid(logit / T + b)), which also moves where 0.5 falls: fitted on families a net never saw
(:mod:`landing_zone.tools.learn.recalibrate`), it says how much less safe an unfamiliar tile is
than
its logit claims. Everything here treats "safe" (label 1) as the event whose
probability is predicted.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.optimize import minimize_scalar
from scipy.special import expit, log_expit

from landing_zone.errors import ConfigError

__all__ = ['Reliability', 'reliability', 'expected_calibration_error', 'fit_temperature',
           'fit_platt', 'binary_nll']


@dataclass
class Reliability:
    """Equal-width bins of predicted P(safe) over [0, 1].

    Attributes:
        edges: (B + 1,) bin edges.
        count: (B,) predictions per bin.
        confidence: (B,) mean predicted P(safe) per bin (NaN where empty).
        frequency: (B,) observed share of safe tiles per bin (NaN where empty).
    """

    edges: np.ndarray
    count: np.ndarray
    confidence: np.ndarray
    frequency: np.ndarray

    @property
    def ece(self) -> float:
        """Expected calibration error: the count-weighted mean |frequency - confidence|."""
        n = self.count.sum()
        if n == 0:
            return float('nan')
        full = self.count > 0
        gap = np.abs(self.frequency[full] - self.confidence[full])
        return float((self.count[full] * gap).sum() / n)


def _check(p_safe, labels) -> tuple[np.ndarray, np.ndarray]:
    p = np.asarray(p_safe, np.float64).reshape(-1)
    y = np.asarray(labels).reshape(-1)
    if p.shape != y.shape:
        raise ConfigError(f'{p.size} probabilities for {y.size} labels')
    if not np.all(np.isfinite(p)) or np.any((p < 0) | (p > 1)):
        raise ConfigError('probabilities must be finite and lie in [0, 1]')
    if not np.all((y == 0) | (y == 1)):
        raise ConfigError('labels must be 0 (unsafe) or 1 (safe)')
    return p, y.astype(np.float64)


def reliability(p_safe, labels, bins: int = 15) -> Reliability:
    """Reliability diagram data: bin i holds ``edges[i] <= p < edges[i + 1]`` (the last bin
    includes 1).

    Args:
        p_safe: (N,) predicted P(safe).
        labels: (N,) 1 safe, 0 unsafe.
        bins: number of equal-width bins.
    """
    if bins < 1:
        raise ConfigError(f'bins must be >= 1, got {bins}')
    p, y = _check(p_safe, labels)
    edges = np.linspace(0.0, 1.0, bins + 1)
    which = np.clip(np.floor(p * bins).astype(np.int64), 0, bins - 1)
    count = np.bincount(which, minlength=bins).astype(np.int64)
    with np.errstate(invalid='ignore', divide='ignore'):
        confidence = np.bincount(which, weights=p, minlength=bins) / count
        frequency = np.bincount(which, weights=y, minlength=bins) / count
    return Reliability(edges, count, confidence, frequency)


def expected_calibration_error(p_safe, labels, bins: int = 15) -> float:
    """ECE of P(safe) with ``bins`` equal-width bins (see :class:`Reliability`)."""
    return reliability(p_safe, labels, bins).ece


def binary_nll(logits, labels, temperature: float = 1.0, bias: float = 0.0) -> float:
    """Mean negative log-likelihood of labels under sigmoid(logits / temperature + bias)."""
    z = np.asarray(logits, np.float64) / temperature + bias
    y = np.asarray(labels, np.float64)
    return float(-(y * log_expit(z) + (1.0 - y) * log_expit(-z)).mean())


def fit_temperature(logits, labels, bounds: tuple[float, float] = (0.05, 20.0),
                    prior_sigma: float | None = 1.0) -> float:
    """The temperature that best explains held-out labels (1.0 if it cannot be fit).

    Maximises the likelihood times a log-normal prior on T (``log T ~ N(0, prior_sigma^2)``).
    Without the prior, a held-out set the net separates perfectly (common on easy synthetic
    data) has no optimum: the likelihood keeps growing as T -> 0 and the fit would end on the
    lower bound with absurdly sharp probabilities; with it, such data yields a finite T < 1,
    while on large, imperfect sets the prior is negligible.

    Args:
        logits: (N,) uncalibrated logits of P(safe).
        labels: (N,) 1 safe, 0 unsafe.
        bounds: search range of the temperature.
        prior_sigma: width of the prior on log T; None for plain maximum likelihood.

    Returns:
        T > 0; calibrated P(safe) = sigmoid(logit / T).
    """
    z = np.asarray(logits, np.float64).reshape(-1)
    if not np.all(np.isfinite(z)):
        raise ConfigError('logits must be finite')
    _, y = _check(expit(z), labels)
    if z.size < 2 or y.min() == y.max():
        return 1.0  # one class (or nothing) held out: no information about the scale
    n = z.size

    def objective(log_t: float) -> float:
        penalty = 0.0 if prior_sigma is None else 0.5 * (log_t / prior_sigma) ** 2
        return n * binary_nll(z, y, float(np.exp(log_t))) + penalty

    res = minimize_scalar(objective, bounds=(np.log(bounds[0]), np.log(bounds[1])),
                          method='bounded', options={'xatol': 1e-4})
    t = float(np.exp(res.x))
    return t if np.isfinite(t) and objective(res.x) <= objective(0.0) else 1.0


def fit_platt(logits, labels, bounds: tuple[float, float] = (0.05, 20.0),
              prior_sigma: float | None = 1.0, bias_sigma: float | None = 4.0
              ) -> tuple[float, float]:
    """Temperature and offset that best explain held-out labels: P(safe) = sigmoid(logit / T + b).

    Maximum likelihood with the log-normal prior of :func:`fit_temperature` on ``T`` and a
    normal prior ``b ~ N(0, bias_sigma^2)`` (which only matters where the data say little).
    Returns ``(1.0, 0.0)`` where it cannot be fit (one class, fewer than two logits).

    Raises:
        ConfigError: non-finite logits or bad labels.
    """
    from scipy.optimize import minimize

    z = np.asarray(logits, np.float64).reshape(-1)
    if not np.all(np.isfinite(z)):
        raise ConfigError('logits must be finite')
    _, y = _check(expit(z), labels)
    if z.size < 2 or y.min() == y.max():
        return 1.0, 0.0
    n = z.size
    lo, hi = np.log(bounds[0]), np.log(bounds[1])

    def objective(v: np.ndarray) -> float:
        log_t, b = float(v[0]), float(v[1])
        pen = 0.0 if prior_sigma is None else 0.5 * (log_t / prior_sigma) ** 2
        pen += 0.0 if bias_sigma is None else 0.5 * (b / bias_sigma) ** 2
        return n * binary_nll(z, y, float(np.exp(log_t)), b) + pen

    res = minimize(objective, np.zeros(2), method='L-BFGS-B', bounds=[(lo, hi), (-20.0, 20.0)])
    t, b = float(np.exp(res.x[0])), float(res.x[1])
    if not (np.isfinite(t) and np.isfinite(b)) or objective(res.x) > objective(np.zeros(2)):
        return 1.0, 0.0
    return t, b
