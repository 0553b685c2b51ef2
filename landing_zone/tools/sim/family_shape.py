"""What an obstacle family's generator returns, and the bounds every instance is fitted to.

The generators (:mod:`~landing_zone.tools.sim.family_natural`,
:mod:`~landing_zone.tools.sim.family_manmade`, :mod:`~landing_zone.tools.sim.family_open`,
:mod:`~landing_zone.tools.sim.assembly`) make a :class:`Shape` at its true size;
:func:`landing_zone.tools.sim.families.instance` fits it into these bounds.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ['Shape', 'MAX_ACROSS', 'MAX_RADIUS', 'MIN_VISIBLE', 'MAX_HEIGHT']

MAX_ACROSS = 0.70  # [m] largest horizontal extent of an instance
MAX_RADIUS = 0.48  # [m] no vertex farther from the footprint's centre (fits a 1 m tile)
MIN_VISIBLE = 0.10  # [m] an instance stands at least this high above the ground when placed
MAX_HEIGHT = 0.60  # [m]


@dataclass
class Shape:
    """What a generator returns: the mesh at its true size and how it came out."""

    vertices: np.ndarray
    faces: np.ndarray
    pose: str
    arrangement: str = 'single'
    open: bool = False  # a cavity or gaps reachable by rays from outside in this pose
    params: dict = field(default_factory=dict)
