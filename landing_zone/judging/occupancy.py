"""The one test of an occupied voxel, shared by the tiler's ground and the ground planes.

A voxel of ``h`` hits and ``p`` passes is occupied when it was hit at least once and its density
``(h + 1) / (h + p + 2)`` is at least ``occupied`` (``TileConfig.occupied_density``). It lives
apart from both of its users so that neither imports the other for it.
"""
from __future__ import annotations

import numba as nb
import numpy as np

__all__ = ['is_occupied']


@nb.njit(cache=True, nogil=True, inline='always')
def is_occupied(h, p, occupied):  # type: ignore[no-untyped-def]
    """Whether a voxel of ``h`` hits and ``p`` passes is occupied: hit at least once and its
    density (h + 1) / (h + p + 2) at least ``occupied`` (the tiler's and the ground planes'
    test)."""
    if h == 0:
        return False
    hf = np.float64(h)
    return (hf + 1.0) >= occupied * (hf + np.float64(p) + 2.0)
