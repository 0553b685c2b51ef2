"""Grass: blades as strips of three triangles, placed by a spatial Poisson process; and other
vegetation for flights (clumped, taller curving blades, shrubs: :class:`VegetationConfig`).

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
from dataclasses import asdict, dataclass, replace
from typing import Callable

import numpy as np

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.mesh import GRASS, Mesh
from landing_zone.tools.sim.terrain import Terrain

__all__ = ['GrassConfig', 'grass_mesh', 'points_in_polygon', 'scatter', 'VEGETATION_PRESETS',
           'VegetationConfig', 'Bush', 'clumped_bases', 'blade_strips', 'vegetation_blades',
           'place_bushes', 'bush_mesh']

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


def scatter(rate: float, polygon: np.ndarray, rng: np.random.Generator,
            count: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Points of a homogeneous Poisson process of ``rate`` per m^2 over the bounding box of a
    convex (K, 2) polygon (or ``count`` uniform points there), and which of them lie inside it.

    Draws the number of points, then the points, nothing else: the vegetation's meshes depend on
    that order for same-seed-same-bytes (what a caller draws per point comes after).

    Returns:
        (n, 2) points and an (n,) mask of those inside the polygon.
    """
    lo, hi = polygon.min(axis=0), polygon.max(axis=0)
    n = rng.poisson(rate * float(np.prod(hi - lo))) if count is None else count
    xy = lo + (hi - lo) * rng.random((n, 2))
    return xy, points_in_polygon(xy, polygon)


def _polygon_area(polygon: np.ndarray) -> float:
    x, y = polygon[:, 0], polygon[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def _poisson_blades(config: GrassConfig, rng: np.random.Generator, polygon: np.ndarray,
                    density_scale: ScaleField | None, height_scale: ScaleField | None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None:
    """Bases (n, 2), heights, inclinations [rad] and lean azimuths of Poisson-placed blades.

    None where there are none. The draws happen in a fixed order: :func:`grass_mesh` depends on
    it for same-seed-same-bytes, and a flight with other vegetation replays it to keep the rest
    of its site (obstacles, noise) the same.
    """
    xy, keep = scatter(config.density, polygon, rng)
    if density_scale is not None:
        keep &= rng.random(len(xy)) < np.clip(density_scale(xy[:, 0], xy[:, 1]), 0.0, 1.0)
    xy = xy[keep]
    n = len(xy)
    if n == 0:
        return None

    z = np.clip(rng.standard_normal(n), -3.0, 3.0)
    height = config.height_mean * np.maximum(1.0 + config.height_cv * z, 0.2)
    if height_scale is not None:
        height *= np.maximum(height_scale(xy[:, 0], xy[:, 1]), 0.0)
    incl = np.radians(np.minimum(np.abs(config.inclination_std * rng.standard_normal(n)),
                                 _MAX_INCLINATION))
    azimuth = rng.uniform(0.0, 2.0 * np.pi, n)
    return xy, height, incl, azimuth


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
    blades = _poisson_blades(config, rng, polygon, density_scale, height_scale)
    if blades is None:
        return Mesh.empty()
    xy, height, incl, azimuth = blades
    n = len(xy)
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


# --- other vegetation (flights that differ from the training sets) ----------------------------

VEGETATION_PRESETS = ('default', 'clumped', 'tall', 'bushy', 'mixed')


@dataclass(frozen=True)
class VegetationConfig:
    """How a flight's vegetation differs from the default blades (all defaults: it does not).

    The blade count and the patches of the site stay as they are (``FlightConfig.grass_density``
    and ``grass_height`` and the site's noise fields); these parameters change how blades are
    arranged and shaped, and add shrubs.

    * Clumps (``clump_size`` > 0): a Thomas cluster process instead of independent (Poisson)
      blades. Clump centres are Poisson (thinned by the site's patches) with intensity
      ``density / clump_size``, each holds a Poisson(``clump_size``) number of blades offset
      from it by isotropic Gaussians of standard deviation ``clump_radius``, and its blades lean
      away from its centre (a tussock splaying out).
    * Blade shape: ``segments`` straight pieces per blade; piece k of n leans
      ``incl * (k / n) ** bend`` from the vertical (the default blade: 2 pieces, bend 1; more
      pieces and bend > 1 curve it over like a drooping leaf). A blade's height is the height of
      its tip above its base (leaning blades are longer), drawn as for the default blades, with
      the site's patch-to-patch variation scaled by ``height_variation`` and capped at
      ``max_height``.
    * Shrubs (``bush_density`` > 0): low bushes of leaves and twigs. Each has a height and a
      diameter drawn uniformly from the given ranges, a half-ellipsoid canopy from 20 % of its
      height up filled with ``leaf_density`` m^2 of small triangular leaves per m^3 at random
      orientations (a ray crossing a canopy is stopped with probability about
      ``1 - exp(-0.5 * leaf_density * path)``, so many pass through), and a few thin twigs from
      the base into the canopy. They are vegetation (class GRASS), not obstacles: a shrub lower
      than about 0.45 m is what a landing skid pushes aside like tall grass, so it leaves its
      tiles safe. Bushes keep clear of the obstacles' footprints.
    """

    preset: str = 'default'  # name recorded with the flight (one of VEGETATION_PRESETS)
    clump_size: float = 0.0  # mean blades per clump; 0: independent (Poisson) blades
    clump_radius: float = 0.06  # standard deviation of a blade's offset from its clump [m]
    blade_width: float = 0.005  # [m]
    height_cv: float = 0.25  # standard deviation of a blade's height / its mean
    height_variation: float = 0.8  # amplitude of the site's patch-to-patch height field
    max_height: float | None = None  # no blade tip higher than this above its base [m]
    inclination_std: float = 15.0  # lean of a blade's tip piece from the vertical [deg]
    segments: int = 2  # straight pieces per blade
    bend: float = 1.0  # piece k of n leans incl * (k / n) ** bend
    bush_density: float = 0.0  # shrubs per m^2
    bush_height: tuple[float, float] = (0.2, 0.4)  # range of shrub heights [m]
    bush_diameter: tuple[float, float] = (0.3, 0.6)  # range of shrub diameters [m]
    leaf_density: float = 6.0  # leaf area per canopy volume [m^2 / m^3]
    leaf_size: float = 0.05  # edge of a (triangular) leaf [m]

    def validate(self) -> None:
        """Raise :class:`SimulationError` naming the first nonsensical parameter."""
        if self.preset not in VEGETATION_PRESETS:
            raise SimulationError(f'unknown vegetation {self.preset!r}; choose from '
                                  f'{", ".join(VEGETATION_PRESETS)}')
        checks = (('clump_size', 0.0, 1.0e4), ('clump_radius', 0.005, 1.0),
                  ('blade_width', 1.0e-4, 0.1), ('height_cv', 0.0, 1.0),
                  ('height_variation', 0.0, 2.0), ('inclination_std', 0.0, 90.0),
                  ('bend', 0.2, 5.0), ('bush_density', 0.0, 2.0), ('leaf_density', 0.1, 100.0),
                  ('leaf_size', 0.005, 0.3))
        for name, low, high in checks:
            _check_range('vegetation', name, getattr(self, name), low, high)
        if self.max_height is not None:
            _check_range('vegetation', 'max_height', self.max_height, 0.01, 3.0)
        if not (isinstance(self.segments, int) and 2 <= self.segments <= 12):
            raise SimulationError(f'vegetation segments must be an integer in [2, 12], got '
                                  f'{self.segments!r}')
        for name, low, high in (('bush_height', 0.05, 1.5), ('bush_diameter', 0.05, 3.0)):
            value = getattr(self, name)
            if not (isinstance(value, (tuple, list)) and len(value) == 2):
                raise SimulationError(f'vegetation {name} must be a (min, max) pair, got '
                                      f'{value!r}')
            for v in value:
                _check_range('vegetation', name, v, low, high)
            if value[0] > value[1]:
                raise SimulationError(f'vegetation {name} must be (min, max) with min <= max, '
                                      f'got {tuple(value)!r}')

    @property
    def plain(self) -> bool:
        """Whether this is the default vegetation (whatever its preset name)."""
        return replace(self, preset='default') == VegetationConfig()

    def to_dict(self) -> dict:
        out = asdict(self)
        out['bush_height'], out['bush_diameter'] = list(self.bush_height), list(
            self.bush_diameter)
        return out


def _check_range(what: str, name: str, value: object, low: float, high: float) -> None:
    if not (isinstance(value, (int, float)) and not isinstance(value, bool)
            and math.isfinite(value) and low <= value <= high):
        raise SimulationError(f'{what} {name} must lie in [{low:g}, {high:g}], got {value!r}')


def clumped_bases(density: float, clump_size: float, clump_radius: float,
                  rng: np.random.Generator, polygon: np.ndarray,
                  density_scale: ScaleField | None = None
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Blade bases of a Thomas cluster process over a convex region.

    Args:
        density: mean blades per m^2 (before ``density_scale`` thins the clumps).
        clump_size: mean blades per clump.
        clump_radius: standard deviation of a blade's offset from its clump centre [m].
        rng: randomness.
        polygon: (K, 2) convex counter-clockwise region where bases lie.
        density_scale: optional field in [0, 1]: the probability a clump centred there exists.

    Returns:
        ``(xy, centre)``: (n, 2) bases inside the polygon and (n, 2) their clump's centre.
    """
    lo, hi = polygon.min(axis=0), polygon.max(axis=0)
    # Centres within 3 sigma of the region can put blades into it.
    lo, hi = lo - 3.0 * clump_radius, hi + 3.0 * clump_radius
    n_c = rng.poisson(density / clump_size * float(np.prod(hi - lo)))
    centres = lo + (hi - lo) * rng.random((n_c, 2))
    if density_scale is not None:
        p = np.clip(density_scale(centres[:, 0], centres[:, 1]), 0.0, 1.0)
        centres = centres[rng.random(n_c) < p]
    counts = rng.poisson(clump_size, len(centres))
    centre = np.repeat(centres, counts, axis=0)
    xy = centre + clump_radius * rng.standard_normal((len(centre), 2))
    keep = points_in_polygon(xy, polygon)
    return xy[keep], centre[keep]


def blade_strips(base: np.ndarray, height: np.ndarray, incl: np.ndarray, azimuth: np.ndarray,
                 width: float, segments: int = 2, bend: float = 1.0) -> Mesh:
    """Blades of ``segments`` straight pieces narrowing to a tip (2 segments - 1 triangles).

    Piece k of n (k = 1..n) leans ``incl * (k / n) ** bend`` from the vertical towards
    ``azimuth``; all pieces are equally long and the tip ends ``height`` above the base. The
    width falls from ``width`` at the base to 0.7 of it at the last joint, then to the tip.

    Args:
        base: (n, 3) blade bases.
        height: (n,) tip heights above the bases [m].
        incl: (n,) inclinations of the tip piece [rad].
        azimuth: (n,) directions of the lean [rad].
        width: blade width at the base [m].
        segments: pieces per blade.
        bend: curvature exponent (1: the inclination grows linearly along the blade).

    Returns:
        The blades as a GRASS mesh.
    """
    n = len(base)
    if n == 0:
        return Mesh.empty()
    k = np.arange(1, segments + 1) / segments
    tilt = incl[:, None] * k[None, :] ** bend  # (n, segments)
    seg = height / np.cos(tilt).sum(axis=1)
    ca, sa = np.cos(azimuth), np.sin(azimuth)
    step = np.stack([np.sin(tilt) * ca[:, None], np.sin(tilt) * sa[:, None], np.cos(tilt)],
                    axis=-1) * seg[:, None, None]
    joints = base[:, None, :] + np.concatenate([np.zeros((n, 1, 3)),
                                                np.cumsum(step, axis=1)], axis=1)
    across = np.column_stack([-sa, ca, np.zeros(n)]) * (0.5 * width)
    # Joints 0 .. segments-1 carry two vertices each (the blade's edges), the tip one.
    scale = 1.0 - 0.3 * np.arange(segments) / max(segments - 1, 1)
    edges = scale[None, :, None, None] * np.array([-1.0, 1.0])[None, None, :, None] * \
        across[:, None, None, :]
    vertices = np.concatenate([(joints[:, :segments, None, :] + edges).reshape(n, -1, 3),
                               joints[:, segments:, :]], axis=1)  # (n, 2 * segments + 1, 3)
    faces = []
    for j in range(segments - 1):
        a = 2 * j
        faces += [[a, a + 1, a + 2], [a + 1, a + 3, a + 2]]
    a = 2 * (segments - 1)
    faces.append([a, a + 1, a + 2])
    faces = np.array(faces, dtype=np.uint32)
    per = 2 * segments + 1
    faces = (np.arange(n, dtype=np.uint32)[:, None, None] * per + faces[None]).reshape(-1, 3)
    return Mesh.from_arrays(vertices.reshape(-1, 3), faces, GRASS)


def vegetation_blades(config: VegetationConfig, density: float, height_mean: float,
                      terrain: Terrain, rng: np.random.Generator, polygon: np.ndarray,
                      density_scale: ScaleField | None = None,
                      height_scale: ScaleField | None = None) -> Mesh:
    """Grass blades of a :class:`VegetationConfig` (clumped or not, of its blade shape).

    Args:
        config: the vegetation.
        density: blades per m^2 where ``density_scale`` is 1.
        height_mean: mean tip height [m] where ``height_scale`` is 1.
        terrain: the ground.
        rng: randomness.
        polygon: (K, 2) convex counter-clockwise region where blade bases lie.
        density_scale: optional field in [0, 1] thinning the blades (or clumps).
        height_scale: optional positive field multiplying the mean height.

    Returns:
        A GRASS mesh.
    """
    config.validate()
    polygon = np.asarray(polygon, dtype=float)
    if density == 0 or height_mean == 0 or _polygon_area(polygon) <= 0:
        return Mesh.empty()
    if config.clump_size > 0:
        xy, centre = clumped_bases(density, config.clump_size, config.clump_radius, rng,
                                   polygon, density_scale)
    else:
        xy, keep = scatter(density, polygon, rng)
        if density_scale is not None:
            keep &= rng.random(len(xy)) < np.clip(density_scale(xy[:, 0], xy[:, 1]), 0.0, 1.0)
        xy, centre = xy[keep], None
    n = len(xy)
    if n == 0:
        return Mesh.empty()
    z = np.clip(rng.standard_normal(n), -3.0, 3.0)
    height = height_mean * np.maximum(1.0 + config.height_cv * z, 0.2)
    if height_scale is not None:
        height *= np.maximum(height_scale(xy[:, 0], xy[:, 1]), 0.0)
    if config.max_height is not None:
        height = np.minimum(height, config.max_height)
    incl = np.radians(np.minimum(np.abs(config.inclination_std * rng.standard_normal(n)),
                                 _MAX_INCLINATION))
    if centre is None:
        azimuth = rng.uniform(0.0, 2.0 * np.pi, n)
    else:
        # Away from the clump's centre, give or take 30 degrees.
        off = xy - centre
        azimuth = np.arctan2(off[:, 1], off[:, 0]) + np.radians(30.0) * rng.standard_normal(n)
    base = np.column_stack([xy, terrain.height(xy[:, 0], xy[:, 1]) - _SINK])
    return blade_strips(base, height, incl, azimuth, config.blade_width, config.segments,
                        config.bend)


@dataclass(frozen=True)
class Bush:
    """One shrub: where it stands and how big it is."""

    x: float
    y: float
    z: float  # ground height at its base [m]
    height: float  # [m]
    diameter: float  # [m]

    def to_json(self) -> dict:
        return {k: round(v, 4) for k, v in asdict(self).items()}


_TWIGS = 7  # twigs per bush
_TWIG_WIDTH = 0.008  # [m]


def place_bushes(config: VegetationConfig, terrain: Terrain, rng: np.random.Generator,
                 polygon: np.ndarray, keep_out: list[tuple[float, float, float]] = ()
                 ) -> list[Bush]:
    """Shrubs placed by a Poisson process over a convex region, clear of ``keep_out`` discs.

    Args:
        config: the vegetation (``bush_density``, ``bush_height``, ``bush_diameter``).
        terrain: the ground.
        rng: randomness.
        polygon: (K, 2) convex counter-clockwise region where bush centres lie.
        keep_out: (x, y, radius) discs no canopy reaches into (the obstacles).
    """
    xy, keep = scatter(config.bush_density, np.asarray(polygon, dtype=float), rng)
    height = rng.uniform(*config.bush_height, len(xy))
    diameter = rng.uniform(*config.bush_diameter, len(xy))
    for x, y, r in keep_out:
        keep &= np.hypot(xy[:, 0] - x, xy[:, 1] - y) > r + 0.5 * diameter
    xy, height, diameter = xy[keep], height[keep], diameter[keep]
    z = terrain.height(xy[:, 0], xy[:, 1]) if len(xy) else np.zeros(0)
    return [Bush(float(a), float(b), float(c), float(h), float(d))
            for (a, b), c, h, d in zip(xy, z, height, diameter)]


def bush_mesh(config: VegetationConfig, bushes: list[Bush], rng: np.random.Generator) -> Mesh:
    """Leaves and twigs of the shrubs, labelled GRASS (vegetation).

    The canopy of a bush is the upper half of an ellipsoid (semi-axes diameter / 2 across,
    0.8 height up) whose base lies at 20 % of its height; leaves are equilateral triangles of
    edge ``leaf_size`` with random orientations, centred uniformly in the canopy, as many as
    ``leaf_density`` asks for. Twigs are thin strips from the base to points in the canopy.
    """
    if not bushes:
        return Mesh.empty()
    b = np.array([[k.x, k.y, k.z, k.height, k.diameter] for k in bushes])
    r_xy, r_z = 0.5 * b[:, 4], 0.8 * b[:, 3]
    volume = 2.0 / 3.0 * np.pi * r_xy ** 2 * r_z
    leaf_area = 0.25 * math.sqrt(3.0) * config.leaf_size ** 2
    counts = np.maximum(np.round(config.leaf_density * volume / leaf_area), 1).astype(int)
    owner = np.repeat(np.arange(len(b)), counts)
    n = len(owner)
    # Uniform in the unit half-ball (z >= 0), then scaled to the canopy.
    u = rng.standard_normal((n, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    u[:, 2] = np.abs(u[:, 2])
    u *= rng.random(n)[:, None] ** (1.0 / 3.0)
    centre = np.column_stack([b[owner, 0] + r_xy[owner] * u[:, 0],
                              b[owner, 1] + r_xy[owner] * u[:, 1],
                              b[owner, 2] + 0.2 * b[owner, 3] + r_z[owner] * u[:, 2]])
    normal = rng.standard_normal((n, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    helper = rng.standard_normal((n, 3))
    e1 = np.cross(normal, helper)
    e1 /= np.maximum(np.linalg.norm(e1, axis=1, keepdims=True), 1e-12)
    e2 = np.cross(normal, e1)
    circum = config.leaf_size / math.sqrt(3.0)
    ang = 2.0 * np.pi * np.arange(3) / 3.0
    leaves = centre[:, None, :] + circum * (np.cos(ang)[None, :, None] * e1[:, None, :]
                                            + np.sin(ang)[None, :, None] * e2[:, None, :])
    leaf_mesh = Mesh.from_arrays(leaves.reshape(-1, 3),
                                 np.arange(3 * n, dtype=np.uint32).reshape(-1, 3), GRASS)
    # Twigs: from the base (slightly sunk) to random points of the lower canopy.
    t_owner = np.repeat(np.arange(len(b)), _TWIGS)
    m = len(t_owner)
    ang = rng.uniform(0.0, 2.0 * np.pi, m)
    rad = 0.8 * r_xy[t_owner] * np.sqrt(rng.random(m))
    top = np.column_stack([b[t_owner, 0] + rad * np.cos(ang), b[t_owner, 1] + rad * np.sin(ang),
                           b[t_owner, 2] + b[t_owner, 3] * rng.uniform(0.3, 0.7, m)])
    base = np.column_stack([b[t_owner, 0] + 0.02 * np.cos(ang),
                            b[t_owner, 1] + 0.02 * np.sin(ang), b[t_owner, 2] - _SINK])
    d = top - base
    twig_height = d[:, 2]
    incl = np.arctan2(np.hypot(d[:, 0], d[:, 1]), d[:, 2])
    twig_mesh = blade_strips(base, twig_height, incl, np.arctan2(d[:, 1], d[:, 0]),
                             _TWIG_WIDTH, segments=2, bend=1.0)
    return Mesh.concat([leaf_mesh, twig_mesh])
