"""The calibration of a fine-tuned model: the initial model's, anchored on reference obstacles.

``train`` fits the temperature on its validation scenes: right for a model trained from
scratch, wrong for one fine-tuned from a model whose calibration was fitted on families it never
saw (``landing-zone calibrate``): the refit keeps P(safe) honest on the training families only
and drops what the initial model knew about unfamiliar ones, so more obstacles of unseen
families pass. So a fine-tuned model keeps the initial model's ``T`` and ``b``, anchored: ``b``
is lowered (never raised) until, on reference obstacle tiles (the fine-tuning's validation scenes
with an obstacle, of
every training source apart), it passes no more at each threshold (0.5 and 0.9) than the initial
model did. Lowering ``b`` keeps the ranking (no AUC changes) and only ever makes tiles less safe.

The reference tiles are the training sources' (rehearsal and site data), never a test set: the
families held out of every training stay the check, untouched by any fit.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from landing_zone.errors import ConfigError

__all__ = ['THRESHOLDS', 'anchored_offset', 'passes']

THRESHOLDS = (0.5, 0.9)  # the P(safe) a planner acts on; the anchor holds at each


def passes(logits, temperature: float, offset: float, threshold: float) -> int:
    """How many of ``logits`` are given P(safe) = sigmoid(logit / T + b) >= ``threshold``."""
    z = np.asarray(logits, np.float64).reshape(-1) / temperature + offset
    return int((z >= np.log(threshold / (1.0 - threshold))).sum())


def anchored_offset(new_logits, init_logits, labels, temperature: float, offset: float,
                    groups=None, thresholds: Sequence[float] = THRESHOLDS
                    ) -> tuple[float, dict[str, Any]]:
    """The largest offset ``b' <= offset`` under which the fine-tuned net, at temperature ``T``,
    passes no more reference obstacle tiles at each threshold, in each group, than the initial
    net does at its own ``(T, offset)``.

    Args:
        new_logits: (N,) the fine-tuned net's logits on the reference tiles.
        init_logits: (N,) the initial net's logits on the same tiles.
        labels: (N,) 1 safe, 0 unsafe; only the unsafe tiles count.
        temperature, offset: the initial model's calibration (kept for the fine-tuned one,
            ``offset`` lowered where needed).
        groups: (N,) which training source each tile came from (default: one group); the anchor
            holds in each.
        thresholds: P(safe) levels, each in (0, 1).

    Returns:
        ``(b', report)``: the report gives, per group, the largest offset that group alone
        allows (``offset_limit``: the group with the lowest one set ``b'``) and, per threshold,
        the obstacle tiles passed by the initial model and by the fine-tuned one before and
        after the anchoring.

    Raises:
        ConfigError: mismatched lengths, non-finite logits, a bad temperature or threshold.
    """
    zn = np.asarray(new_logits, np.float64).reshape(-1)
    zi = np.asarray(init_logits, np.float64).reshape(-1)
    y = np.asarray(labels).reshape(-1)
    g = np.zeros(y.size, np.int64) if groups is None else np.asarray(groups).reshape(-1)
    if not (zn.size == zi.size == y.size == g.size):
        raise ConfigError(f'{zn.size} new logits, {zi.size} initial, {y.size} labels, {g.size} '
                          'groups: one of each per reference tile')
    if not (np.all(np.isfinite(zn)) and np.all(np.isfinite(zi))):
        raise ConfigError('logits must be finite')
    if not (np.isfinite(temperature) and temperature > 0 and np.isfinite(offset)):
        raise ConfigError(f'bad calibration T {temperature!r}, b {offset!r}')
    if any(not 0.0 < t < 1.0 for t in thresholds):
        raise ConfigError(f'thresholds must lie in (0, 1), got {list(thresholds)}')
    b = float(offset)
    report: dict[str, Any] = {'temperature': float(temperature), 'initial_offset': float(offset),
                              'n_reference': int(y.size),
                              'n_reference_unsafe': int((y == 0).sum()), 'groups': []}
    for group in np.unique(g[y == 0]):
        sel = (y == 0) & (g == group)
        s_new = np.sort(zn[sel] / temperature)[::-1]  # most lenient first
        limit = float(offset)  # the largest offset this group alone allows
        for t in thresholds:
            allowed = passes(zi[sel], temperature, offset, t)
            if allowed < s_new.size:
                # pass at most `allowed`: the (allowed+1)-th must fall below logit(t)
                cut = float(np.nextafter(_logit(t) - s_new[allowed], -np.inf))
                while passes(zn[sel], temperature, cut, t) > allowed:  # rounding
                    cut = float(np.nextafter(cut, -np.inf))
                limit = min(limit, cut)
        b = min(b, limit)
        report['groups'].append({'group': int(group), 'obstacles': int(sel.sum()),
                                 'offset_limit': limit})
    for entry in report['groups']:
        sel = (y == 0) & (g == entry['group'])
        entry['passed'] = {str(t): {'initial': passes(zi[sel], temperature, offset, t),
                                    'unanchored': passes(zn[sel], temperature, offset, t),
                                    'anchored': passes(zn[sel], temperature, b, t)}
                           for t in thresholds}
    report['offset'] = b
    return b, report


def _logit(p: float) -> float:
    return float(np.log(p / (1.0 - p)))
