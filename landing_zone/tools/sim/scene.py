"""Worlds to scan: ground, grass and obstacles as one labelled mesh; and simulated patches.

A *patch* is one dataset scene (the paper's Table I): a 1 m x 1 m tile centred at (0, 0) with
nominal ground at z = 0, scanned by a hovering sensor at ``(sensor_offset, 0, sensor_height)``
until the tile holds the target density. Only returns whose rays pass through the tile's padded
column (1.6 m x 1.6 m, from 1 m below to 2 m above the ground) are kept: that is all the
network's 32^3 input cube (and its augmentations) can see.

The world of a patch is built just large enough: ground and grass cover every place a ray that
passes through the column can reach while it is in the grass layer (before the column, where
grass hides it, or beyond, where a ray that crossed above the tile lands). The rays from a
sensor through a convex box form a convex cone; its part between the lowest ground and the
highest blade tip is the convex hull of the box's corners projected from the sensor onto
those two planes, so the region is that hull (for every corner of the sensor's wander range),
widened by the farthest a blade can lean.
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field, replace

import numpy as np

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.grass import GrassConfig, grass_mesh
from landing_zone.tools.sim.mesh import Mesh
from landing_zone.tools.sim.library import get_model
from landing_zone.tools.sim.obstacles import Obstacle, place
from landing_zone.tools.sim.raycast import RayCaster
from landing_zone.tools.sim.hover import HoverGeometry, HoverScan, estimate_nod_rate, hover_scan
from landing_zone.tools.sim.sensor import SensorConfig
from landing_zone.tools.sim.terrain import Terrain, TerrainConfig

__all__ = ['World', 'PatchConfig', 'Patch', 'simulate_patch', 'view_region', 'hover_plan']


@dataclass
class World:
    """Everything a ray can hit.

    Attributes:
        terrain: the ground.
        grass: grass blades (GRASS faces).
        obstacles: placed obstacles.
    """

    terrain: Terrain
    grass: Mesh
    obstacles: list[Obstacle] = field(default_factory=list)
    _caster: RayCaster | None = field(default=None, repr=False)

    def mesh(self) -> Mesh:
        """Ground, grass and obstacles as one mesh (faces labelled by class)."""
        return Mesh.concat([self.terrain.mesh(), self.grass]
                           + [o.mesh() for o in self.obstacles])

    def caster(self, threads: int = 0) -> RayCaster:
        """The Embree scene of :meth:`mesh` (built on first use)."""
        if self._caster is None:
            self._caster = RayCaster(self.mesh(), threads=threads)
        return self._caster

    @property
    def n_blades(self) -> int:
        return self.grass.n_faces // 3


@dataclass(frozen=True)
class PatchConfig:
    """All parameters of one patch (one dataset scene)."""

    grass: GrassConfig = field(default_factory=GrassConfig)
    terrain: TerrainConfig = field(default_factory=TerrainConfig)
    sensor: SensorConfig = field(default_factory=SensorConfig)
    sensor_offset: float = -5.0  # x of the hovering sensor, relative to the tile centre [m]
    sensor_height: float = 4.0  # height of the sensor above the nominal ground [m]
    obstacle: str | None = None  # obstacle model name (see library.library()); None: safe
    tile_size: float = 1.0  # edge of the tile (the area of interest) [m]
    padding: float = 0.3  # the column reaches this far beyond the tile on every side [m]
    column_below: float = 1.0  # the column reaches this far below the nominal ground [m]
    column_above: float = 2.0  # ... and this far above it [m]

    def validate(self) -> None:
        """Raise :class:`SimulationError` naming the first nonsensical parameter."""
        self.grass.validate()
        self.terrain.validate()
        self.sensor.validate()
        for name in ('sensor_offset', 'sensor_height', 'tile_size', 'padding', 'column_below',
                     'column_above'):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value)):
                raise SimulationError(f'patch {name} must be a finite number, got {value!r}')
        if self.tile_size <= 0 or self.padding < 0 or self.column_below < 0:
            raise SimulationError('patch tile_size must be positive and padding, column_below '
                                  'non-negative')
        if self.column_above <= self.grass.max_height:
            raise SimulationError(f'patch column_above ({self.column_above} m) must exceed the '
                                  f'tallest blade ({self.grass.max_height:.2f} m)')
        top = self.column_above + self.terrain.amplitude
        if self.sensor_height <= top + 0.5:
            raise SimulationError(f'sensor_height ({self.sensor_height} m) must be above the '
                                  f'column (top at {top:.2f} m) by at least 0.5 m')
        if self.obstacle is not None:
            model = get_model(self.obstacle)
            if 2.0 * model.radius >= self.tile_size:
                raise SimulationError(
                    f'obstacle {model.name!r} ({2 * model.radius:.2f} m across) does not fit '
                    f'inside the {self.tile_size:g} m tile')

    @property
    def position(self) -> np.ndarray:
        return np.array([self.sensor_offset, 0.0, self.sensor_height])

    @property
    def aoi(self) -> tuple[np.ndarray, np.ndarray]:
        h = 0.5 * self.tile_size
        return np.array([-h, -h]), np.array([h, h])

    @property
    def column(self) -> tuple[np.ndarray, np.ndarray]:
        h = 0.5 * self.tile_size + self.padding
        return (np.array([-h, -h, -self.column_below]), np.array([h, h, self.column_above]))

    def to_dict(self) -> dict:
        return asdict(self)


@dataclass
class Patch:
    """A simulated patch: the kept returns, the world they came from and the scan's figures."""

    config: PatchConfig
    scan: HoverScan
    world: World
    obstacle: Obstacle | None
    timings: dict[str, float]

    @property
    def label(self) -> int:
        """1 safe (no obstacle), 0 unsafe."""
        return 0 if self.obstacle is not None else 1


def view_region(sources: np.ndarray, box_lo: np.ndarray, box_hi: np.ndarray, z_lo: float,
                z_hi: float, reach: float = 0.0, grade: np.ndarray | None = None,
                limit: float = 15.0) -> np.ndarray:
    """Where rays from ``sources`` through a box can be between heights z_lo and z_hi.

    Args:
        sources: (S, 3) sensor positions, all above the box.
        box_lo, box_hi: (3,) box corners.
        z_lo, z_hi: the layer (lowest ground, highest blade tip).
        reach: widen the region by this much on every side (blades leaning in).
        grade: (2,) the layer's planes rise by ``grade . (x, y)`` (ground on a slope: the
            layer follows it, ``z_lo`` and ``z_hi`` are then its bounds at x = y = 0).
        limit: with ``grade``, the region ends this far from x = y = 0 [m]: a ray that grazes
            ground falling away from the sensor meets it far off, or never.

    Returns:
        (K, 2) convex polygon, counter-clockwise.
    """
    if grade is not None:
        return _tilted_view_region(sources, box_lo, box_hi, z_lo, z_hi, reach,
                                   np.asarray(grade, dtype=float), limit)
    from scipy.spatial import ConvexHull
    corners = np.array([[x, y, z] for x in (box_lo[0], box_hi[0]) for y in (box_lo[1], box_hi[1])
                        for z in (box_lo[2], box_hi[2])])
    s = np.asarray(sources, dtype=float).reshape(-1, 1, 1, 3)
    c = corners.reshape(1, -1, 1, 3)
    if np.any(s[..., 2] <= box_hi[2] + 1e-6) or max(z_lo, z_hi) >= float(s[..., 2].min()):
        raise SimulationError('the sensor must be above the region of interest')
    planes = np.array([z_lo, z_hi]).reshape(1, 1, -1)
    f = (planes - s[..., 2]) / (c[..., 2] - s[..., 2])
    pts = (s[..., :2] + f[..., None] * (c[..., :2] - s[..., :2])).reshape(-1, 2)
    if reach > 0:
        ang = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)
        # The 16-gon circumscribes the circle of radius reach.
        ring = reach / math.cos(math.pi / 16) * np.stack([np.cos(ang), np.sin(ang)], axis=1)
        pts = (pts[:, None, :] + ring[None]).reshape(-1, 2)
    return pts[ConvexHull(pts).vertices]


def _tilted_view_region(sources: np.ndarray, box_lo: np.ndarray, box_hi: np.ndarray,
                        z_lo: float, z_hi: float, reach: float, grade: np.ndarray,
                        limit: float) -> np.ndarray:
    """:func:`view_region` between the planes ``z = grade . xy + z_lo`` and ``... + z_hi``: the
    same argument (a convex cone cut by two parallel planes) with the ray parameter of each
    plane ``t = (z0 + g . s - s_z) / ((c_z - s_z) - g . (c - s))``; a ray that meets a plane
    only beyond ``limit`` from x = y = 0, or never, is cut where it leaves that disc (the cone
    cut by the disc's cylinder is still convex)."""
    from scipy.spatial import ConvexHull
    corners = np.array([[x, y, z] for x in (box_lo[0], box_hi[0]) for y in (box_lo[1], box_hi[1])
                        for z in (box_lo[2], box_hi[2])])
    s = np.asarray(sources, dtype=float).reshape(-1, 1, 1, 3)
    c = corners.reshape(1, -1, 1, 3)
    planes = np.array([z_lo, z_hi]).reshape(1, 1, -1)
    g_s = s[..., 0] * grade[0] + s[..., 1] * grade[1]
    if np.any(s[..., 2] - g_s <= max(z_lo, z_hi) + 1e-6):
        raise SimulationError('the sensor must be above the region of interest')
    dz = (c[..., 2] - s[..., 2]) - ((c[..., 0] - s[..., 0]) * grade[0]
                                    + (c[..., 1] - s[..., 1]) * grade[1])
    u = c[..., :2] - s[..., :2]
    # Where each ray leaves the disc of radius `limit`: |s + f u| = limit, the larger root.
    uu = np.sum(u * u, axis=-1)
    su = np.sum(s[..., :2] * u, axis=-1)
    ss = np.sum(s[..., :2] * s[..., :2], axis=-1)
    f_out = (-su + np.sqrt(np.maximum(su * su - uu * (ss - limit * limit), 0.0))) / uu
    with np.errstate(divide='ignore', invalid='ignore'):
        f = (planes + g_s - s[..., 2]) / dz
    f = np.where((dz < 0) & (f < f_out), f, f_out)
    pts = (s[..., :2] + f[..., None] * u).reshape(-1, 2)
    if reach > 0:
        ang = np.linspace(0.0, 2.0 * np.pi, 16, endpoint=False)
        ring = reach / math.cos(math.pi / 16) * np.stack([np.cos(ang), np.sin(ang)], axis=1)
        pts = (pts[:, None, :] + ring[None]).reshape(-1, 2)
    return pts[ConvexHull(pts).vertices]


def hover_plan(sensor: SensorConfig, position: np.ndarray, aoi_lo: np.ndarray,
               aoi_hi: np.ndarray) -> tuple[float, float, np.ndarray]:
    """What a hover scan will do before any world exists: its nod rate [deg/s], the bound of
    the sensor's wander [m] (how long the scan takes decides how far it may wander) and the
    (8, 3) corners of the box the sensor stays in."""
    omega = estimate_nod_rate(sensor, position, aoi_lo, aoi_hi, 0.0)
    geom = HoverGeometry.make(sensor, position, np.zeros(3), 0.0)
    t_scan = (sensor.sweeps_per_target + 1.5) * geom.span / math.radians(omega)
    wander = 5.0 * sensor.wander_sigma * math.sqrt(t_scan) + 0.01
    sources = position + wander * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1)
                                            for z in (-1, 1)])
    return omega, wander, sources


def simulate_patch(config: PatchConfig, rng: np.random.Generator, threads: int = 1) -> Patch:
    """Build a patch's world and scan it.

    Args:
        config: the patch.
        rng: all randomness (terrain, grass, obstacle placement, wander, range noise).
        threads: Embree threads (1 in dataset workers).

    Returns:
        The :class:`Patch`.
    """
    config.validate()
    timings = {}
    t0 = time.perf_counter()
    sensor = config.sensor
    position = config.position
    aoi_lo, aoi_hi = config.aoi
    box_lo, box_hi = config.column
    omega, wander, sources = hover_plan(sensor, position, aoi_lo, aoi_hi)
    amp = config.terrain.amplitude
    z_hi = amp + config.grass.max_height + 0.01
    reach = config.grass.max_height
    region = view_region(sources, box_lo, box_hi, -amp - 0.01, z_hi, reach)
    lo, hi = region.min(axis=0), region.max(axis=0)
    timings['plan'] = time.perf_counter() - t0

    t0 = time.perf_counter()
    pad = 2.0 * config.terrain.spacing
    terrain = Terrain(config.terrain, rng, lo - pad, hi + pad)
    grass = grass_mesh(config.grass, terrain, rng, region)
    obstacle = None
    if config.obstacle is not None:
        model = get_model(config.obstacle)
        # Half the unsafe patches hold the obstacle fully inside the tile (for any yaw the
        # centre keeps the model's radius from the edge); the other half let it straddle the
        # tile's edge with at least half its radius inside, as obstacles on a real site do
        # (a tile is unsafe when any obstacle's footprint overlaps it), so the net learns to
        # flag a rock that only reaches into the tile from its neighbour.
        if rng.uniform() < 0.5:
            free = 0.5 * config.tile_size - model.radius
        else:
            free = 0.5 * config.tile_size + 0.5 * model.radius
        x, y = rng.uniform(-free, free, 2)
        obstacle = place(model, float(x), float(y), float(rng.uniform(0.0, 2.0 * np.pi)),
                         terrain)
    world = World(terrain, grass, [obstacle] if obstacle is not None else [])
    timings['world'] = time.perf_counter() - t0
    t0 = time.perf_counter()
    caster = world.caster(threads)
    timings['bvh'] = time.perf_counter() - t0
    t0 = time.perf_counter()
    scan = hover_scan(caster, replace(sensor, nod_rate=omega),
                      position, aoi_lo, aoi_hi, box_lo, box_hi, rng, wander_bound=wander)
    timings['scan'] = time.perf_counter() - t0
    return Patch(config, scan, world, obstacle, timings)
