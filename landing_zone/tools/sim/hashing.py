"""The integer hash that splits scenes and pairs: train or test, which twin holds the obstacle.

Every synthetic dataset (the sweeps of synth1 and synth2, synth3, the hybrid sets) decides these
by hashing an index, not by drawing from a generator, so a scene's split and label do not depend
on which other scenes are made or in which order.
"""
from __future__ import annotations

import numpy as np

__all__ = ['mix']


def mix(x: np.ndarray | int) -> np.ndarray:
    """splitmix64 finaliser: a well-spread 64-bit hash of integers."""
    z = (np.asarray(x, dtype=np.uint64) + np.uint64(0x9E3779B97F4A7C15))
    with np.errstate(over='ignore'):
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))
