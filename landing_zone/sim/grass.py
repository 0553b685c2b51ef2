"""Grass: blades as strips of three triangles, placed by a spatial Poisson process.

A blade rises from its base on the ground in two segments, the upper one leaning further than
the lower (a slight curve), and narrows to a tip::

        tip
        /\\
     m-/__\\m+        3 triangles: (b-, b+, m-), (b+, m+, m-), (m-, m+, tip)
      |\\  |
      | \\ |
     b-----b+

The blade's flat side faces the direction it leans in. Heights are normally distributed
(truncated at +-3 standard deviations and at 20% of the mean), inclinations from the vertical
are normally distributed around zero with a uniformly random azimuth.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Callable

import numpy as np

from landing_zone.errors import SimulationError
from landing_zone.sim.mesh import GRASS, Mesh
from landing_zone.sim.terrain import Terrain

__all__ = ['GrassConfig', 'grass_mesh', 'points_in_polygon']

# Blade bases sit this far below the ground surface so that no gap opens under a blade.
_SINK = 0.005  # [m]
_MAX_INCLINATION = 75.0  # [deg]; beyond that a blade lies on the ground
_STRIP = np.array([[0, 1, 2], [1, 3, 2], [2, 3, 4]], dtype=np.uint32)

ScaleField = Callable[[np.ndarray, np.ndarray], np.ndarray]


@dataclass(frozen=True)
class GrassConfig:
    """Blades of one kind of grass."""

    density: float = 600.0  # blades per m^2: intensity of the homogeneous Poisson process
    blade_width: float = 0.005  # width at the base [m]; the paper's 3, 5 or 8 mm
    height_mean: float = 0.2  # mean blade height above its base [m]
    height_cv: float = 0.25  # standard deviation of the height / mean
    inclination_std: float = 15.0  # standard deviation of the lean from the vertical [deg]

    def validate(self) -> None:
        checks = (('density', 0.0, 1.0e5), ('blade_width', 1.0e-4, 0.1),
                  ('height_mean', 0.0, 3.0), ('height_cv', 0.0, 1.0),
                  ('inclination_std', 0.0, 90.0))
        for name, low, high in checks:
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value)
                    and low <= value <= high):
                raise SimulationError(f'grass {name} must lie in [{low:g}, {high:g}], '
                                      f'got {value!r}')

    @property
    def max_height(self) -> float:
        """No blade is taller than this [m]."""
        return self.height_mean * (1.0 + 3.0 * self.height_cv)

    def to_dict(self) -> dict:
        return asdict(self)


def points_in_polygon(xy: np.ndarray, polygon: np.ndarray) -> np.ndarray:
    """Which of the (N, 2) points lie inside a convex, counter-clockwise (K, 2) polygon."""
    inside = np.ones(len(xy), dtype=bool)
    for a, b in zip(polygon, np.roll(polygon, -1, axis=0)):
        edge = b - a
        inside &= edge[0] * (xy[:, 1] - a[1]) - edge[1] * (xy[:, 0] - a[0]) >= 0.0
    return inside


def _polygon_area(polygon: np.ndarray) -> float:
    x, y = polygon[:, 0], polygon[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def grass_mesh(config: GrassConfig, terrain: Terrain, rng: np.random.Generator,
               polygon: np.ndarray, density_scale: ScaleField | None = None,
               height_scale: ScaleField | None = None) -> Mesh:
    """Grass blades over a convex region of the ground.

    Args:
        config: the grass.
        terrain: the ground the blades stand on.
        rng: randomness of positions and shapes.
        polygon: (K, 2) convex counter-clockwise region where blade bases lie.
        density_scale: optional field in [0, 1] thinning the Poisson process (patchy grass:
            the intensity at (x, y) is ``config.density * density_scale(x, y)``).
        height_scale: optional positive field multiplying the mean height at (x, y).

    Returns:
        A mesh of 3 triangles per blade, labelled GRASS.
    """
    config.validate()
    polygon = np.asarray(polygon, dtype=float)
    if config.density == 0 or config.height_mean == 0 or _polygon_area(polygon) <= 0:
        return Mesh.empty()
    lo, hi = polygon.min(axis=0), polygon.max(axis=0)
    # Homogeneous Poisson process on the bounding box, restricted to the polygon.
    n = rng.poisson(config.density * float(np.prod(hi - lo)))
    xy = lo + (hi - lo) * rng.random((n, 2))
    keep = points_in_polygon(xy, polygon)
    if density_scale is not None:
        keep &= rng.random(n) < np.clip(density_scale(xy[:, 0], xy[:, 1]), 0.0, 1.0)
    xy = xy[keep]
    n = len(xy)
    if n == 0:
        return Mesh.empty()

    z = np.clip(rng.standard_normal(n), -3.0, 3.0)
    height = config.height_mean * np.maximum(1.0 + config.height_cv * z, 0.2)
    if height_scale is not None:
        height *= np.maximum(height_scale(xy[:, 0], xy[:, 1]), 0.0)
    incl = np.radians(np.minimum(np.abs(config.inclination_std * rng.standard_normal(n)),
                                 _MAX_INCLINATION))
    azimuth = rng.uniform(0.0, 2.0 * np.pi, n)
    ca, sa = np.cos(azimuth), np.sin(azimuth)
    # Lower segment leans half as much as the upper; both the same length, and the tip ends at
    # the blade's height above its base.
    i1, i2 = 0.5 * incl, incl
    seg = height / (np.cos(i1) + np.cos(i2))
    base = np.column_stack([xy, terrain.height(xy[:, 0], xy[:, 1]) - _SINK])
    lean1 = np.column_stack([np.sin(i1) * ca, np.sin(i1) * sa, np.cos(i1)])
    lean2 = np.column_stack([np.sin(i2) * ca, np.sin(i2) * sa, np.cos(i2)])
    across = np.column_stack([-sa, ca, np.zeros(n)]) * (0.5 * config.blade_width)
    mid = base + lean1 * seg[:, None]
    vertices = np.empty((n, 5, 3))
    vertices[:, 0] = base - across
    vertices[:, 1] = base + across
    vertices[:, 2] = mid - 0.7 * across
    vertices[:, 3] = mid + 0.7 * across
    vertices[:, 4] = mid + lean2 * seg[:, None]
    faces = (np.arange(n, dtype=np.uint32)[:, None, None] * 5 + _STRIP[None]).reshape(-1, 3)
    return Mesh.from_arrays(vertices.reshape(-1, 3), faces, GRASS)
