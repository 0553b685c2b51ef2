"""Footprints where the robot acts: which are clear, which the judgement accepts, and what a
threshold on their least tile P(safe) could accept (:mod:`landing_zone.tools.evaluate.flights`
names the figures).

A footprint is centred on every tile (:mod:`landing_zone.judging.sites`); its truth is "every
tile under it labelled safe" (unsafe: any tile under it labelled unsafe; footprints with an
unlabelled tile and no unsafe one are not scored).
"""
from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ['CURVE_ERRORS', 'footprint_truth', 'footprint_figures', 'operating_curve']

CURVE_ERRORS = (0, 1, 5)  # footprints over an obstacle the operating curve allows


def footprint_truth(truth: np.ndarray, radius: float, tile_size: float) -> np.ndarray:
    """Per footprint centred on each tile of a (X, Y) truth grid (1 safe, 0 unsafe, -1 not
    labelled): 1 every tile under it safe, 0 any unsafe, -1 neither (an unlabelled tile, or
    off the grid)."""
    from scipy import ndimage

    from landing_zone.judging.sites import footprint_mask

    mask = footprint_mask(radius, tile_size).astype(np.int32)
    unsafe = ndimage.correlate((truth == 0).astype(np.int32), mask, mode='constant', cval=0)
    unlabelled = ndimage.correlate((truth < 0).astype(np.int32), mask, mode='constant', cval=1)
    return np.where(unsafe > 0, 0, np.where(unlabelled > 0, -1, 1)).astype(np.int8)


def footprint_figures(reasons: np.ndarray, p_least: np.ndarray, truth: np.ndarray
                      ) -> dict[str, Any]:
    """The footprint figures of one grid of candidates (module docstring).

    Args:
        reasons: (X, Y) the candidates' reasons to be left out (bits of
            :data:`landing_zone.judging.sites.REASONS`; 0: accepted).
        p_least: (X, Y) their least tile P(safe) (NaN where a tile is unknown).
        truth: (X, Y) :func:`footprint_truth` on the same grid.

    Returns:
        ``clear_footprints``, ``clear_footprints_geometry``, ``clear_accepted``,
        ``clear_accepted_share``, ``obstacle_footprints``, ``obstacle_accepted``,
        ``operating_curve``; and, for pooling, ``_cp`` and ``_op``: the least P(safe) of the
        clear footprints and of those over an obstacle that only a threshold on it decides.
    """
    from landing_zone.judging.sites import CLEARANCE, OBSTACLE, SLOPE, STEP

    reasons = np.asarray(reasons, np.int64)
    p_least = np.asarray(p_least, np.float64)
    truth = np.asarray(truth)
    geometry = SLOPE | STEP | CLEARANCE
    geometry_only = (reasons != 0) & ((reasons & ~geometry) == 0)
    clear, over = truth == 1, truth == 0
    accepted = reasons == 0
    # the footprints a threshold on the least P(safe) decides: no reason but the judgement's
    decided = ((reasons & ~OBSTACLE) == 0) & np.isfinite(p_least)
    n_clear = int((clear & ~geometry_only).sum())
    cp, op = p_least[clear & decided], p_least[over & decided]
    out: dict[str, Any] = {
        'clear_footprints': n_clear,
        'clear_footprints_geometry': int((clear & geometry_only).sum()),
        'clear_accepted': int((clear & accepted).sum()),
        'clear_accepted_share': (int((clear & accepted).sum()) / n_clear if n_clear
                                 else None),
        'obstacle_footprints': int(over.sum()),
        'obstacle_accepted': int((over & accepted).sum()),
        'operating_curve': operating_curve(cp, op, n_clear)}
    out['_cp'], out['_op'] = cp, op
    return out


def operating_curve(clear_p: np.ndarray, obstacle_p: np.ndarray, n_clear: int,
                    errors: Sequence[int] = CURVE_ERRORS) -> dict[str, dict[str, Any]]:
    """Clear footprints accepted by a threshold on the least tile P(safe) that accepts at most
    ``k`` footprints over an obstacle, for each ``k`` of ``errors``.

    A footprint is accepted at threshold ``t`` when its least P(safe) >= ``t``. The lowest
    threshold that keeps to ``k`` lies just above the ``k + 1``-th highest P(safe) over an
    obstacle: a clear footprint tied with it is not accepted.

    Args:
        clear_p: least P(safe) of the clear footprints a threshold decides.
        obstacle_p: the same of the footprints over an obstacle.
        n_clear: clear footprints of the share's denominator (those a threshold cannot
            accept, an unknown tile under them, included).
        errors: the footprints over an obstacle allowed.

    Returns:
        ``{str(k): {'threshold', 'clear_accepted', 'share'}}``; ``threshold`` is the least
        P(safe) accepted (None: none is), ``share`` None without clear footprints.
    """
    cp = np.asarray(clear_p, np.float64)
    op = np.sort(np.asarray(obstacle_p, np.float64))[::-1]
    out = {}
    for k in errors:
        bar = op[k] if len(op) > k else -np.inf
        above = np.concatenate([cp[cp > bar], op[op > bar]])
        n = int((cp > bar).sum())
        out[str(k)] = {'threshold': float(above.min()) if len(above) else None,
                       'clear_accepted': n, 'share': n / n_clear if n_clear else None}
    return out
