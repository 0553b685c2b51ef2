"""What a simulated flight is: its site, vegetation, obstacles, scanner and path, as one config.

:class:`FlightConfig` holds every parameter of a flight
(:func:`landing_zone.tools.sim.flight.flight_config` builds one from the named presets of
vegetation and scan pattern, :data:`VEGETATION` and :data:`SCAN`);
:mod:`landing_zone.tools.sim.flight_site`
builds its world, :mod:`landing_zone.tools.sim.flight_path` its path and
:func:`landing_zone.tools.sim.flight.simulate_flight` flies it.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.families import parse_families
from landing_zone.tools.sim.grass import VEGETATION_PRESETS, VegetationConfig
from landing_zone.tools.sim.library import models
from landing_zone.tools.sim.sensor import SCAN_PATTERNS, ScanPattern, SensorConfig
from landing_zone.tools.sim.terrain import TerrainConfig
from landing_zone.tools.sim.vegetation import VEGETATION_FAMILIES

__all__ = ['FlightConfig', 'VEGETATION', 'SCAN', 'MIN_SEPARATION']

MIN_SEPARATION = 1.5  # [m] between obstacle centres

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
    # a vegetation family of the datasets (landing_zone.tools.sim.vegetation) instead of the
    # preset's blades: its parameters drawn from the seed, thinned by the site's patches
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
        capacity = int((inner / MIN_SEPARATION + 1) ** 2 * 0.5)
        if self.obstacles > capacity:
            raise SimulationError(f'{self.obstacles} obstacles do not fit {MIN_SEPARATION} m '
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
