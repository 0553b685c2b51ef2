"""A simulated flight over a vegetated landing site, written as a ROS 2 bag with ground truth.

The site (default 20 m x 20 m, centred at the origin of the ``map`` frame) has Perlin-noise
ground, grass in patches of varying density and height with clearings of open ground, and
obstacles of mixed kinds at least 1.5 m apart. The helicopter flies a lawnmower pattern of
straight passes along x at constant height and speed; its scanner's plane is tilted forward by
``tilt`` (45 degrees: the ground line lies ``height`` metres ahead, seen at the depression
angles of the training patches) and it scans every line while on a pass. Unless given, the
speed is chosen so that the passes together put the target density onto the site (on flat
ground the density is inversely proportional to the speed; the constant follows from the scan
geometry, see :func:`_density_constant`), up to ``max_speed``.

Outputs (``docs/INTERFACES.md``):

* ``SITE.mcap``: ``/lidar/points`` (sensor_msgs/PointCloud2, frame ``map``, a few scan lines
  per message, FLOAT32 ``x``, ``y``, ``z``, ``intensity``, plus UINT8 ``label``, the class of
  the surface hit: 0 ground, 1 grass, 2 obstacle) and ``/lidar/pose`` (geometry_msgs/PoseStamped
  of the sensor, one per cloud at the cloud's stamp, and at the same rate while turning);
* ``SITE.labels.json``: every 1 m tile of the site on the global lattice (centres at x.5),
  unsafe when an obstacle's footprint overlaps it, and the obstacles; ``site`` also names the
  vegetation and the scan pattern (with their parameters) and ``bushes`` lists the shrubs.

Other vegetation and scanners (:func:`flight_config`), to stand in for flights over vegetation
the model never trained on: ``vegetation`` presets (``clumped`` tussocks, ``tall`` curving
blades up to 0.45 m, ``bushy`` shrubs, ``mixed``; see :class:`VegetationConfig`) and scan
patterns (``spinning`` multi-beam, ``rosette``; see :class:`ScanPattern`). With other vegetation
the same seed still gives the same ground, patches, obstacles and flight noise as the default
vegetation (its blades and shrubs draw from a randomness of their own), so flights that differ
only in vegetation compare like with like. For a scan pattern other than the line scanner the
pass spacing, the run-in and the speed for the target density follow from the pattern's
footprint on flat ground (sampled over a second of pulses, see :func:`_pattern_footprint`).

rosbags is imported only when the bag is written.
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import asdict, dataclass, field, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from landing_zone.errors import BagError, SimulationError
from landing_zone.io.labels import labels_path_for, write_labels
from landing_zone.tools.sim.grass import (VEGETATION_PRESETS, Bush, GrassConfig, VegetationConfig,
                                    _poisson_blades, bush_mesh, grass_mesh, place_bushes,
                                    vegetation_blades)
from landing_zone.tools.sim.mesh import Mesh
from landing_zone.tools.sim.families import draw_instance, keep_visible, parse_families
from landing_zone.tools.sim.library import models
from landing_zone.tools.sim.obstacles import Obstacle, place
from landing_zone.tools.sim.scene import World
from landing_zone.tools.sim.sensor import (SCAN_PATTERNS, BrownianWalk, Returns, ScanPattern,
                                     SensorConfig, mount_frame, path_scan)
from landing_zone.tools.sim.terrain import PerlinNoise, SlopedTerrain, Terrain, TerrainConfig
from landing_zone.tools.sim.vegetation import VEGETATION_FAMILIES, build_vegetation, draw_vegetation

__all__ = ['FlightConfig', 'Site', 'FlightResult', 'build_site', 'simulate_flight',
           'tile_labels', 'polygon_overlaps_square', 'START_TIME_NS', 'flight_config',
           'VEGETATION', 'SCAN']

START_TIME_NS = 1_735_689_600 * 1_000_000_000  # 2025-01-01T00:00:00Z: stamps of every flight
_MIN_SEPARATION = 1.5  # [m] between obstacle centres
_SWATH_ANGLE = 40.0  # [deg] scan angle out to which a pass counts as covering the ground
_TURN_POSE_RATE = 50.0  # [Hz] poses while turning between passes

# Vegetation presets: fields of FlightConfig (grass_density, grass_height) or VegetationConfig.
VEGETATION: dict[str, dict[str, Any]] = {
    'default': {},
    # Tussocks of 100 blades (sigma 6 cm, about 25 cm across) splaying out, bare ground between.
    'clumped': {'clump_size': 100.0, 'clump_radius': 0.06, 'inclination_std': 25.0},
    # Blades of 0.3 - 0.45 m, curving over (4 pieces, bend 2) and leaning 30 degrees (std).
    'tall': {'grass_height': 0.38, 'height_cv': 0.15, 'height_variation': 0.35,
             'max_height': 0.45, 'inclination_std': 30.0, 'segments': 4, 'bend': 2.0,
             'blade_width': 0.006},
    # The default grass and shrubs of 0.2 - 0.4 m, 0.3 - 0.6 m across, 8 per 100 m^2.
    'bushy': {'bush_density': 0.08},
    # Clumped, taller, curving grass and some shrubs.
    'mixed': {'grass_height': 0.3, 'clump_size': 60.0, 'clump_radius': 0.07, 'height_cv': 0.2,
              'height_variation': 0.5, 'max_height': 0.45, 'inclination_std': 30.0,
              'segments': 4, 'bend': 2.0, 'bush_density': 0.05},
}
# Scan-pattern presets: fields of FlightConfig (tilt), ScanPattern or SensorConfig (prr).
SCAN: dict[str, dict[str, Any]] = {
    'line': {},
    # A 16-beam spinning scanner, its beams fanned +-15 degrees about the 45 degree plane.
    'spinning': {'beams': 16, 'beam_fov': 30.0, 'spin_rate': 10.0},
    # A 70 degree rosette looking 20 degrees ahead of the nadir, 100 000 points/s (its returns
    # crowd into a narrow swath: at the line scanner's rate the speed for the target density
    # would exceed max_speed).
    'rosette': {'tilt': 20.0, 'fov': 70.0, 'prr': 100_000.0},
    # A nutating-mirror scanner tracing a 40 degree cone 120 times a second, its axis 15
    # degrees ahead of the nadir: an ellipse on the ground, 100 000 points/s (at the speed for
    # 3000 returns/m^2 from 8 m its front arcs lie 5 cm apart).
    'elliptical': {'tilt': 15.0, 'fov': 40.0, 'spin_rate': 120.0, 'prr': 100_000.0},
}
assert tuple(VEGETATION) == VEGETATION_PRESETS and tuple(SCAN) == SCAN_PATTERNS


@dataclass(frozen=True)
class FlightConfig:
    """The site and the flight."""

    size: float = 20.0  # edge of the square site [m]
    obstacles: int = 6  # number of obstacles
    kinds: tuple[str, ...] = ('rock', 'tire', 'cinder_block', 'box')  # cycled through
    grass_density: float = 600.0  # blades/m^2 of a typical patch (patches: 0 to twice that)
    grass_height: float = 0.25  # mean blade height of a typical patch [m]
    height: float = 8.0  # flight height above the nominal ground [m]
    speed: float | None = None  # [m/s]; None: chosen to reach the sensor's target density ...
    max_speed: float = 10.0  # ... but no faster than this (the density then exceeds the target)
    seed: int = 0
    tilt: float = 45.0  # forward tilt of the scan plane from the nadir [deg]
    lines_per_cloud: int = 5  # scan lines per PointCloud2 message
    margin: float = 3.0  # ground (and grass) beyond the site's edge [m]
    frame_id: str = 'map'
    sensor: SensorConfig = field(default_factory=SensorConfig)
    terrain: TerrainConfig = field(default_factory=lambda: TerrainConfig(wavelength=3.0,
                                                                         octaves=3))
    vegetation: VegetationConfig = field(default_factory=VegetationConfig)
    scan: ScanPattern = field(default_factory=ScanPattern)
    line_spacing: float | None = None  # [m] between passes; None: from the scanner's swath
    # obstacle families (landing_zone.tools.sim.families), cycled through after the kinds: random
    # test instances
    families: tuple[str, ...] = ()
    slope: float = 0.0  # the site lies on a plane this steep [deg] ...
    slope_azimuth: float = 0.0  # ... rising towards this direction [rad]
    # a bank: from x = bank_from on, the ground rises towards +x at this slope [deg] (the
    # demo's area too steep to land on; 0: none)
    bank: float = 0.0
    bank_from: float = 5.0
    # a vegetation family of the datasets (landing_zone.tools.sim.vegetation) instead of the preset's
    # blades: its parameters drawn from the seed, thinned by the site's patches
    vegetation_family: str | None = None

    def validate(self) -> None:
        """Raise :class:`SimulationError` naming the first nonsensical parameter."""
        def finite(name: str, low: float, high: float) -> None:
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value)
                    and low <= value <= high):
                raise SimulationError(f'flight {name} must lie in [{low:g}, {high:g}], '
                                      f'got {value!r}')
        finite('size', 4.0, 200.0)
        finite('grass_density', 0.0, 5000.0)
        finite('grass_height', 0.0, 1.5)
        finite('height', 2.0, 100.0)
        finite('tilt', 0.0, 60.0)
        finite('margin', 0.0, 50.0)
        finite('max_speed', 0.5, 50.0)
        if self.speed is not None:
            finite('speed', 0.1, 50.0)
        if self.line_spacing is not None:
            finite('line_spacing', 0.5, 200.0)
        if not isinstance(self.obstacles, int) or self.obstacles < 0:
            raise SimulationError(f'flight obstacles must be a non-negative integer, got '
                                  f'{self.obstacles!r}')
        if not isinstance(self.lines_per_cloud, int) or self.lines_per_cloud < 1:
            raise SimulationError('flight lines_per_cloud must be a positive integer')
        if not isinstance(self.seed, int) or self.seed < 0:
            raise SimulationError(f'flight seed must be a non-negative integer, got '
                                  f'{self.seed!r}')
        if self.obstacles and not self.kinds and not self.families:
            raise SimulationError('flight kinds must name at least one obstacle kind or '
                                  'family')
        models(tuple(self.kinds))  # unknown kinds fail here
        parse_families(self.families)
        finite('slope', 0.0, 30.0)
        finite('slope_azimuth', -10.0, 10.0)
        finite('bank', 0.0, 30.0)
        finite('bank_from', -200.0, 200.0)
        if self.vegetation_family is not None and \
                self.vegetation_family not in VEGETATION_FAMILIES:
            raise SimulationError(f'unknown vegetation family {self.vegetation_family!r}; '
                                  f'choose from {", ".join(VEGETATION_FAMILIES)}')
        # Obstacles sit at least 1 m inside the site, 1.5 m apart: a loose packing bound.
        inner = self.size - 2.0
        capacity = int((inner / _MIN_SEPARATION + 1) ** 2 * 0.5)
        if self.obstacles > capacity:
            raise SimulationError(f'{self.obstacles} obstacles do not fit {_MIN_SEPARATION} m '
                                  f'apart on a {self.size:g} m site (at most about {capacity})')
        if not self.frame_id:
            raise SimulationError('flight frame_id must not be empty')
        self.sensor.validate()
        self.terrain.validate()
        self.vegetation.validate()
        self.scan.validate()

    def to_json(self) -> dict:
        out = asdict(self)
        out['kinds'] = list(self.kinds)
        out['families'] = list(self.families)
        out['vegetation'] = self.vegetation.to_dict()
        out['scan'] = self.scan.to_dict()
        return out


def flight_config(vegetation: str = 'default', scan_pattern: str = 'line',
                  density: float | None = None, **overrides: Any) -> FlightConfig:
    """A :class:`FlightConfig` from a vegetation and a scan-pattern preset, then overrides.

    Args:
        vegetation: one of :data:`VEGETATION` (``default`` is the training sets' kind of
            grass) or a vegetation family (:data:`VEGETATION_FAMILIES`: synth3's six and
            the meadow, forb and canopy priors).
        scan_pattern: one of :data:`SCAN`.
        density: target returns per m^2 (``SensorConfig.target_density``); None: the default.
        **overrides: fields of :class:`FlightConfig`, :class:`VegetationConfig`,
            :class:`ScanPattern` or :class:`SensorConfig`, or the terrain's ``amplitude`` and
            ``wavelength``; a value of None leaves the preset's (or the default) value.

    Returns:
        The configuration (not yet validated: :func:`simulate_flight` does that).

    Raises:
        SimulationError: an unknown preset or field.
    """
    family = None
    if vegetation in VEGETATION_FAMILIES and vegetation not in VEGETATION:
        family, vegetation = vegetation, 'default'
    if vegetation not in VEGETATION:
        raise SimulationError(f'unknown vegetation {vegetation!r}; choose from '
                              f'{", ".join(VEGETATION)} or a family: '
                              f'{", ".join(VEGETATION_FAMILIES)}')
    if scan_pattern not in SCAN:
        raise SimulationError(f'unknown scan pattern {scan_pattern!r}; choose from '
                              f'{", ".join(SCAN)}')
    flight_fields = {f.name for f in fields(FlightConfig)} - {'vegetation', 'scan'}
    veg_fields = {f.name for f in fields(VegetationConfig)} - {'preset'}
    scan_fields = {f.name for f in fields(ScanPattern)} - {'kind'}
    sensor_fields = {f.name for f in fields(SensorConfig)}
    terrain_fields = {'amplitude', 'wavelength'}  # roughness of the ground
    settings = {**VEGETATION[vegetation], **SCAN[scan_pattern],
                **{k: v for k, v in overrides.items() if v is not None}}
    if density is not None:
        settings['target_density'] = density
    if family is not None:
        settings['vegetation_family'] = family
    unknown = sorted(set(settings) - flight_fields - veg_fields - scan_fields - sensor_fields
                     - terrain_fields)
    if unknown:
        raise SimulationError(f'unknown flight setting {unknown[0]!r}')
    cfg = FlightConfig(
        vegetation=VegetationConfig(preset=vegetation, **{k: v for k, v in settings.items()
                                                          if k in veg_fields}),
        scan=ScanPattern(kind=scan_pattern, **{k: v for k, v in settings.items()
                                               if k in scan_fields}),
        **{k: v for k, v in settings.items() if k in flight_fields})
    sensor = {k: v for k, v in settings.items() if k in sensor_fields}
    terrain = {k: v for k, v in settings.items() if k in terrain_fields}
    if terrain:
        cfg = replace(cfg, terrain=replace(cfg.terrain, **terrain))
    return replace(cfg, sensor=replace(cfg.sensor, **sensor)) if sensor else cfg


@dataclass
class Site:
    """The world of a flight and its ground truth."""

    config: FlightConfig
    world: World
    lo: np.ndarray  # (2,) site corner [m]
    hi: np.ndarray  # (2,)
    bushes: list[Bush] = field(default_factory=list)
    vegetation_params: dict[str, Any] | None = None  # a vegetation family's drawn parameters

    @property
    def obstacles(self) -> list[Obstacle]:
        return self.world.obstacles


@dataclass
class FlightResult:
    """What :func:`simulate_flight` wrote and measured."""

    bag: Path
    labels: Path
    clouds: int
    points: int
    duration: float  # flight time covered by the bag [s]
    speed: float  # [m/s]
    passes: int
    density: float  # returns per m^2 over the site
    unsafe_tiles: int
    tiles: int
    timings: dict[str, float]

    def summary(self) -> dict[str, Any]:
        out = asdict(self)
        out['bag'], out['labels'] = str(self.bag), str(self.labels)
        out['timings'] = {k: round(v, 3) for k, v in self.timings.items()}
        for k in ('duration', 'speed', 'density'):
            out[k] = round(out[k], 3)
        return out


def polygon_overlaps_square(polygon: np.ndarray, lo: np.ndarray, hi: np.ndarray,
                            eps: float = 1e-9) -> bool:
    """Whether a convex polygon and an axis-aligned square overlap with positive area.

    Separating axis theorem: two convex shapes are disjoint exactly when, on one of their edge
    normals, their projections do not overlap (touching edges count as disjoint).
    """
    square = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    edges = np.concatenate([np.roll(polygon, -1, axis=0) - polygon, [[1.0, 0.0], [0.0, 1.0]]])
    for e in edges:
        n = np.array([-e[1], e[0]])
        a, b = polygon @ n, square @ n
        if a.max() <= b.min() + eps or b.max() <= a.min() + eps:
            return False
    return True


def tile_labels(obstacles: list[Obstacle], lo: np.ndarray, hi: np.ndarray,
                tile_size: float = 1.0) -> list[dict[str, Any]]:
    """Every tile of the global lattice that overlaps [lo, hi], safe unless a footprint overlaps.

    Tile ``k`` covers ``[k * tile_size, (k + 1) * tile_size)``; its centre is
    ``(k + 0.5) * tile_size``.
    """
    k0 = np.floor(np.asarray(lo) / tile_size + 1e-9).astype(int)
    k1 = np.ceil(np.asarray(hi) / tile_size - 1e-9).astype(int)
    footprints = [o.footprint() for o in obstacles]
    tiles = []
    for ky in range(k0[1], k1[1]):
        for kx in range(k0[0], k1[0]):
            t_lo = np.array([kx, ky], dtype=float) * tile_size
            t_hi = t_lo + tile_size
            safe = not any(polygon_overlaps_square(fp, t_lo, t_hi) for fp in footprints)
            tiles.append({'x': round((kx + 0.5) * tile_size, 6),
                          'y': round((ky + 0.5) * tile_size, 6), 'safe': safe})
    return tiles


def build_site(config: FlightConfig, rng: np.random.Generator, threads: int = 0) -> Site:
    """Ground, patchy grass (or other vegetation) and obstacles of a flight's site.

    Other vegetation than the default draws its blades and shrubs from a randomness of its own
    (``config.seed``'s) and replays the default blades' draws on ``rng``, so the ground, the
    patches, the obstacles and everything ``rng`` draws after this are the default's.
    """
    half = 0.5 * config.size
    lo, hi = np.array([-half, -half]), np.array([half, half])
    if config.slope > 0:
        terrain: Terrain = SlopedTerrain(config.terrain, rng, lo - config.margin,
                                         hi + config.margin, config.slope,
                                         config.slope_azimuth)
    else:
        terrain = Terrain(config.terrain, rng, lo - config.margin, hi + config.margin)
    if config.bank > 0:
        terrain.add_bank(config.bank, config.bank_from)
    # Patches: one noise field shapes where grass grows and how dense, another its height.
    patches = PerlinNoise(rng, wavelength=7.0, octaves=2)
    tallness = PerlinNoise(rng, wavelength=5.0, octaves=1)

    def density_scale(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        # Scale 1 is a typical patch; below -0.25 the noise leaves clearings of open ground.
        return np.clip((patches(x, y) + 0.25) / 0.5, 0.0, 2.0) / 2.0

    def height_scale(x: np.ndarray, y: np.ndarray) -> np.ndarray:
        return np.clip(1.0 + 0.8 * tallness(x, y), 0.4, 1.6)

    g = config.grass_height
    grass_cfg = GrassConfig(density=2.0 * config.grass_density, height_mean=g)
    region = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])
    region = region + np.sign(region) * min(config.margin, 1.0)
    veg = config.vegetation
    site_veg = None
    if veg.plain and config.vegetation_family is None:
        grass = grass_mesh(grass_cfg, terrain, rng, region, density_scale, height_scale)
        obstacles = _place_obstacles(config, terrain, rng, lo, hi)
        bushes: list[Bush] = []
    else:
        if grass_cfg.density > 0 and g > 0:
            _poisson_blades(grass_cfg, rng, region, density_scale, height_scale)  # the draws
        obstacles = _place_obstacles(config, terrain, rng, lo, hi)
        vrng = np.random.default_rng(np.random.SeedSequence([config.seed, 0xF11, 0x7E6]))

        def veg_height_scale(x: np.ndarray, y: np.ndarray) -> np.ndarray:
            return np.clip(1.0 + veg.height_variation * tallness(x, y), 0.4, 1.6)

        keep_out = [(o.x, o.y, o.model.radius + 0.1) for o in obstacles]
        if config.vegetation_family is not None:
            # The family's own densities and heights, in the site's patches and clearings
            # (its density field thins them: a typical patch keeps half, as the default's).
            params = draw_vegetation(config.vegetation_family, vrng)
            blades, cover, bushes = build_vegetation(
                params, terrain, vrng, region, keep_out,
                density_scale=lambda x, y: np.clip(2.0 * density_scale(x, y), 0.0, 1.0),
                height_scale=veg_height_scale)
            grass = Mesh.concat([blades, cover])
            site_veg = params
        else:
            blades = vegetation_blades(veg, 2.0 * config.grass_density, g, terrain, vrng,
                                       region, density_scale, veg_height_scale)
            bushes = (place_bushes(veg, terrain, vrng, region, keep_out)
                      if veg.bush_density > 0 else [])
            grass = Mesh.concat([blades, bush_mesh(veg, bushes, vrng)])
    world = World(terrain, grass, obstacles)
    world.caster(threads)
    return Site(config, world, lo, hi, bushes, site_veg)


def _place_obstacles(config: FlightConfig, terrain: Terrain, rng: np.random.Generator,
                     lo: np.ndarray, hi: np.ndarray) -> list[Obstacle]:
    out: list[Obstacle] = []
    centres: list[np.ndarray] = []
    entries = tuple(config.kinds) + parse_families(config.families)
    for i in range(config.obstacles):
        entry = entries[i % len(entries)]
        if i % len(entries) < len(config.kinds):
            choices = sorted(models((entry,)), key=lambda m: m.name)
            model = choices[int(rng.integers(len(choices)))]
        else:  # a family: a random test instance
            model = draw_instance(entry, None, rng).model
        for _ in range(10_000):
            c = rng.uniform(lo + 1.0, hi - 1.0)
            if all(np.hypot(*(c - o)) >= _MIN_SEPARATION for o in centres):
                break
        else:
            raise SimulationError(f'could not place {config.obstacles} obstacles '
                                  f'{_MIN_SEPARATION} m apart on the site')
        centres.append(c)
        ob = place(model, float(c[0]), float(c[1]), float(rng.uniform(0, 2 * np.pi)), terrain)
        out.append(keep_visible(ob, terrain) if config.slope or i % len(entries) >= len(
            config.kinds) else ob)
    return out


def _passes(config: FlightConfig, swath_half: float | None = None) -> np.ndarray:
    """Cross-track positions (y) of the passes: every site point within half a swath of one.

    ``swath_half`` defaults to the line scanner's; ``config.line_spacing``, when given, puts
    the passes that far apart, centred on the site (as many as it takes to span it).
    """
    if config.line_spacing is not None:
        n = max(1, math.ceil(config.size / config.line_spacing - 1e-9))
        return (np.arange(n) - 0.5 * (n - 1)) * config.line_spacing
    if swath_half is None:
        swath_half = config.height * math.tan(math.radians(_SWATH_ANGLE)) / math.cos(
            math.radians(config.tilt))
    n = max(1, math.ceil(config.size / (2.0 * swath_half)))
    return -0.5 * config.size + (np.arange(n) + 0.5) * config.size / n


@dataclass
class _Footprint:
    """Where a scan pattern's pulses meet flat ground, seen from the moving vehicle."""

    y: np.ndarray  # cross-track bin centres [m]
    rate: np.ndarray  # returns per second per metre of cross-track at y
    swath_half: float  # [m]
    reach: tuple[float, float]  # along-track extent of the returns (behind, ahead) [m]


def _pattern_footprint(config: FlightConfig, seconds: float = 1.0) -> _Footprint:
    """The footprint of ``config.scan`` on flat ground ``config.height`` below, sampled over
    ``seconds`` of pulses at heading 0.

    The swath is where the cross-track rate stays at or above 0.6 of its mean over the middle
    (a quarter of the height either side; the line scanner's 40 of 50 degrees keep about that
    share of its centre's density); the reach holds all but 0.5 % of the returns at either end
    among those that can fall on the site.
    """
    s, h = config.sensor, config.height
    n = max(int(round(seconds * s.prr)), 1000)
    idx = np.arange(n)
    local = config.scan.local_directions(idx / s.prr, idx)
    d = local @ mount_frame(math.radians(config.tilt), np.zeros(1))[0].T
    down = d[:, 2] < -1e-9
    t = np.full(n, np.inf)
    t[down] = h / -d[down, 2]
    ok = t <= s.max_range
    x, y = (t[ok, None] * d[ok, :2]).T
    span = 4.0 * h + config.size
    bin_w = max(0.01 * h, 0.02)
    edges = np.arange(-span, span + 0.5 * bin_w, bin_w)
    counts, _ = np.histogram(y, edges)
    rate = counts / (n / s.prr) / bin_w
    centres = 0.5 * (edges[1:] + edges[:-1])
    # Smooth over about 0.1 h so that the rosette's petals do not end the swath early.
    k = max(1, int(round(0.1 * h / bin_w)))
    smooth = np.convolve(rate, np.ones(2 * k + 1) / (2 * k + 1), mode='same')
    middle = np.abs(centres) <= 0.25 * h
    ref = float(smooth[middle].mean())
    if ref <= 0:
        raise SimulationError(f'the {config.scan.kind} scanner tilted {config.tilt:g} degrees '
                              f'puts no returns under the vehicle')
    covered = smooth >= 0.6 * ref
    right = np.flatnonzero(~covered & (centres > 0))
    left = np.flatnonzero(~covered & (centres < 0))
    w_r = centres[right[0]] if len(right) else span
    w_l = -centres[left[-1]] if len(left) else span
    near = np.abs(y) <= config.size  # the returns that can fall on the site
    lo_x, hi_x = np.quantile(x[near], [0.005, 0.995]) if near.any() else (0.0, 0.0)
    return _Footprint(centres, rate, float(min(w_r, w_l)), (float(lo_x), float(hi_x)))


def _footprint_density_constant(config: FlightConfig, passes: np.ndarray,
                                foot: _Footprint) -> float:
    """K such that the mean density over the site on flat ground is K / speed (any pattern):
    at cross-track offset y from a pass, the vehicle sweeps rate(y) returns per second over
    each metre across, spread along ``speed`` metres of track."""
    y = np.linspace(-0.5 * config.size, 0.5 * config.size, 2001)
    cover = np.interp(y[:, None] - passes[None, :], foot.y, foot.rate, left=0.0,
                      right=0.0).sum(axis=1)
    return float(cover.mean())


def _density_constant(config: FlightConfig, passes: np.ndarray) -> float:
    """K such that the mean density over the site on flat ground is K / speed [1/m^2 * m/s].

    A line lands ``height * tan(tilt)`` ahead; along it, at scan angle theta, consecutive
    pulses lie ``height * res / (cos(tilt) cos^2(theta))`` apart (y = h tan(theta) / cos(tilt)),
    and lines lie ``speed * line_period`` apart along x. Summed over the passes and averaged
    across the site.
    """
    s = config.sensor
    tilt = math.radians(config.tilt)
    res = math.radians(s.angular_resolution)
    half_fov = math.radians(0.5 * s.fov_horizontal)
    y = np.linspace(-0.5 * config.size, 0.5 * config.size, 2001)
    theta = np.arctan((y[:, None] - passes[None, :]) * math.cos(tilt) / config.height)
    cover = np.where(np.abs(theta) <= half_fov, np.cos(theta) ** 2, 0.0).sum(axis=1)
    return float(math.cos(tilt) / (s.line_period * res * config.height) * cover.mean())


def _quaternion(heading: np.ndarray, tilt: float) -> np.ndarray:
    """(n, 4) xyzw: yaw ``heading`` about z, then pitch so the sensor's x axis is the central
    beam (pitched down by 90 deg - tilt)."""
    pitch = 0.5 * math.pi - tilt
    cy, sy = np.cos(0.5 * heading), np.sin(0.5 * heading)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    # q_z(heading) * q_y(pitch)
    return np.stack([-sy * sp, cy * sp, sy * cp, cy * cp], axis=-1)


class _Lawnmower:
    """Passes along +x / -x (alternating) at constant speed, joined by straight turns."""

    def __init__(self, config: FlightConfig, passes: np.ndarray, speed: float,
                 reach: tuple[float, float] | None = None) -> None:
        half = 0.5 * config.size
        if reach is None:
            ahead = config.height * math.tan(math.radians(config.tilt))
            reach = (ahead, ahead)
        behind, ahead = reach  # along-track extent of the returns from the vehicle
        run = 1.0  # [m] scanned beyond the site's edge at both ends
        self.height = config.height
        self.speed = speed
        self.segments = []  # (t0, t1, start xy, end xy, heading, scanning)
        t = 0.0
        prev_end = None
        for k, y in enumerate(passes):
            sign = 1.0 if k % 2 == 0 else -1.0
            # The ground line lies `ahead` in front (for other scanners: the returns lie
            # `behind` .. `ahead` in front): the vehicle runs from before the site until all
            # of them have crossed it.
            x0 = sign * (-half - run - ahead)
            x1 = sign * (half + run - behind)
            start, end = np.array([x0, y]), np.array([x1, y])
            if prev_end is not None:
                dt = float(np.hypot(*(start - prev_end))) / speed
                heading = math.atan2(*(start - prev_end)[::-1])
                self.segments.append((t, t + dt, prev_end, start, heading, False))
                t += dt
            dt = abs(x1 - x0) / speed
            self.segments.append((t, t + dt, start, end, 0.0 if sign > 0 else math.pi, True))
            t += dt
            prev_end = end
        self.duration = t

    def __call__(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        times = np.asarray(times, dtype=float)
        pos = np.zeros((len(times), 3))
        heading = np.zeros(len(times))
        for t0, t1, a, b, h, _ in self.segments:
            m = (times >= t0) & (times <= t1)
            f = ((times[m] - t0) / (t1 - t0))[:, None]
            pos[m, :2] = a + f * (b - a)
            heading[m] = h
        pos[:, 2] = self.height
        return pos, heading


def simulate_flight(config: FlightConfig, out: str | os.PathLike, overwrite: bool = False,
                    threads: int = 0) -> FlightResult:
    """Simulate a flight and write ``out`` (.mcap) and ``out``'s ``.labels.json``.

    Args:
        config: site and flight.
        out: bag path (``SITE.mcap``); the labels go to ``SITE.labels.json`` beside it.
        overwrite: replace existing outputs.
        threads: Embree threads (0: all cores).

    Raises:
        SimulationError: nonsensical parameters (checked before any work).
        BagError: the bag cannot be written.
    """
    config.validate()
    out = Path(out)
    if out.suffix != '.mcap':
        raise SimulationError(f'the flight bag must be a .mcap file, got {out}')
    labels_path = labels_path_for(out)
    if not overwrite:
        for p in (out, labels_path):
            if p.exists():
                raise BagError(f'{p} exists already (not overwriting)')
    timings: dict[str, float] = {}
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, 0xF11]))
    t0 = time.perf_counter()
    site = build_site(config, rng, threads)
    timings['site'] = time.perf_counter() - t0

    if config.scan.kind == 'line':
        passes = _passes(config)
        k = _density_constant(config, passes)
        reach = None
    else:
        foot = _pattern_footprint(config)
        passes = _passes(config, foot.swath_half)
        k = _footprint_density_constant(config, passes, foot)
        reach = foot.reach
    speed = config.speed
    if speed is None:
        speed = min(k / config.sensor.target_density, config.max_speed)
    speed = float(speed)
    path = _Lawnmower(config, passes, speed, reach)
    tilt = math.radians(config.tilt)
    walk = BrownianWalk(config.sensor.wander_sigma, rng)
    caster = site.world.caster(threads)
    t0 = time.perf_counter()
    # Per segment of the path: the scanned chunks of a pass, None for a turn.
    scans: list[list[Returns] | None] = []
    per_chunk = 40 * config.lines_per_cloud
    for seg in path.segments:
        scans.append(path_scan(caster, config.sensor, path, seg[0], seg[1], tilt, rng,
                               walk=walk, lines_per_chunk=per_chunk, pattern=config.scan)
                     if seg[5] else None)
    timings['scan'] = time.perf_counter() - t0

    t0 = time.perf_counter()
    tiles = tile_labels(site.obstacles, site.lo, site.hi)
    n_clouds, n_points, on_site = _write_bag(out, config, scans, path, overwrite)
    labels = {'frame_id': config.frame_id, 'tile_size': 1.0, 'tiles': tiles,
              'obstacles': [o.to_json() for o in site.obstacles],
              'site': {'lo': site.lo.tolist(), 'hi': site.hi.tolist(),
                       'vegetation': config.vegetation.to_dict(),
                       'scan_pattern': config.scan.to_dict(),
                       **({'vegetation_family': site.vegetation_params}
                          if site.vegetation_params is not None else {}),
                       **({'slope': config.slope, 'slope_azimuth': config.slope_azimuth}
                          if config.slope else {}),
                       **({'bank': config.bank, 'bank_from': config.bank_from}
                          if config.bank else {})},
              'bushes': [b.to_json() for b in site.bushes],
              'flight': config.to_json() | {'speed': speed, 'passes': passes.tolist()}}
    write_labels(labels_path, labels)
    timings['write'] = time.perf_counter() - t0
    area = float(np.prod(site.hi - site.lo))
    return FlightResult(out, labels_path, n_clouds, n_points, path.duration, speed, len(passes),
                        on_site / area, sum(not t['safe'] for t in tiles), len(tiles), timings)


def _write_bag(out: Path, config: FlightConfig, scans: list[list[Returns] | None],
               path: _Lawnmower, overwrite: bool) -> tuple[int, int, int]:
    """Clouds of ``lines_per_cloud`` lines with a pose each; poses alone while turning.

    Messages go in stamp order (a pose just before the cloud of the same stamp).
    """
    from landing_zone.io.bags import BagWriter
    from msg_adapters import MessageTypes, jazzy_typestore, make_header
    from msg_adapters.pointcloud import make_cloud, points_to_structured
    from msg_adapters.pose import make_pose_stamped

    types = MessageTypes.rosbags(jazzy_typestore())
    tilt = math.radians(config.tilt)
    half = 0.5 * config.size
    n_clouds = n_points = on_site = 0
    with BagWriter(out, overwrite=overwrite) as bag:
        bag.add_topic('/lidar/points', 'sensor_msgs/msg/PointCloud2')
        bag.add_topic('/lidar/pose', 'geometry_msgs/msg/PoseStamped')
        for (t0, t1, _, _, _, _), chunks in zip(path.segments, scans):
            if chunks is None:
                times = np.arange(t0, t1, 1.0 / _TURN_POSE_RATE)
                pos, heading = path(times)
                for t, p, q in zip(times, pos, _quaternion(heading, tilt)):
                    stamp = START_TIME_NS + int(round(t * 1e9))
                    bag.write('/lidar/pose', stamp,
                              make_pose_stamped(stamp, config.frame_id, p, q, types))
                continue
            for chunk in chunks:
                n_lines = len(chunk.line_times)
                order = np.argsort(chunk.line, kind='stable')
                bounds = np.searchsorted(chunk.line[order], np.arange(
                    0, n_lines + config.lines_per_cloud, config.lines_per_cloud))
                _, heading = path(chunk.line_times)
                quats = _quaternion(heading, tilt)
                for c in range(len(bounds) - 1):
                    first = c * config.lines_per_cloud
                    if first >= n_lines:
                        break
                    # Stamp and pose: the middle line of the cloud (its origin exactly).
                    mid = min(first + config.lines_per_cloud // 2, n_lines - 1)
                    stamp = START_TIME_NS + int(round(chunk.line_times[mid] * 1e9))
                    sel = order[bounds[c]:bounds[c + 1]]
                    xyz = chunk.points[sel].astype(np.float32)
                    arr = points_to_structured(xyz, {'intensity': chunk.intensity[sel],
                                                     'label': chunk.labels[sel]})
                    bag.write('/lidar/pose', stamp,
                              make_pose_stamped(stamp, config.frame_id,
                                                chunk.line_origins[mid], quats[mid], types))
                    bag.write('/lidar/points', stamp,
                              make_cloud(arr, make_header(stamp, config.frame_id, types), types))
                    n_clouds += 1
                    n_points += len(sel)
                    on_site += int(np.count_nonzero(np.all(np.abs(xyz[:, :2]) < half,
                                                           axis=1)))
    return n_clouds, n_points, on_site
