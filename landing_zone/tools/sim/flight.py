"""A simulated flight over a vegetated landing site, written as a ROS 2 bag with ground truth.

The site (default 20 m x 20 m, centred at the origin of the ``map`` frame) has Perlin-noise
ground, grass in patches of varying density and height with clearings of open ground, and
obstacles of mixed kinds at least 1.5 m apart. The helicopter flies a lawnmower pattern of
straight passes along x at constant height and speed; its scanner's plane is tilted forward by
``tilt`` (45 degrees: the ground line lies ``height`` metres ahead, seen at the depression
angles of the training patches) and it scans every line while on a pass. Unless given, the
speed is chosen so that the passes together put the target density onto the site (on flat
ground the density is inversely proportional to the speed; the constant follows from the scan
geometry, see :func:`~landing_zone.tools.sim.flight_path.density_constant`), up to ``max_speed``.

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
footprint on flat ground (sampled over a second of pulses, see
:func:`~landing_zone.tools.sim.flight_path.pattern_footprint`).

rosbags is imported only when the bag is written.
"""
from __future__ import annotations

import math
import os
import time
from dataclasses import asdict, dataclass, fields, replace
from pathlib import Path
from typing import Any

import numpy as np

from landing_zone.errors import BagError, SimulationError
from landing_zone.io.labels import labels_path_for, write_labels
from landing_zone.tools.sim.flight_settings import SCAN, VEGETATION, FlightConfig
from landing_zone.tools.sim.grass import VegetationConfig
from landing_zone.tools.sim.flight_path import Lawnmower, density_constant, \
    footprint_density_constant, pass_offsets, pattern_footprint, quaternion
from landing_zone.tools.sim.flight_site import build_site, tile_labels
from landing_zone.tools.sim.sensor import BrownianWalk, Returns, ScanPattern, SensorConfig, \
    path_scan
from landing_zone.tools.sim.vegetation import VEGETATION_FAMILIES

__all__ = ['FlightResult', 'simulate_flight', 'flight_config', 'START_TIME_NS']

START_TIME_NS = 1_735_689_600 * 1_000_000_000  # 2025-01-01T00:00:00Z: stamps of every flight
_TURN_POSE_RATE = 50.0  # [Hz] poses while turning between passes


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
        passes = pass_offsets(config)
        k = density_constant(config, passes)
        reach = None
    else:
        foot = pattern_footprint(config)
        passes = pass_offsets(config, foot.swath_half)
        k = footprint_density_constant(config, passes, foot)
        reach = foot.reach
    speed = config.speed
    if speed is None:
        speed = min(k / config.sensor.target_density, config.max_speed)
    speed = float(speed)
    path = Lawnmower(config, passes, speed, reach)
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
               path: Lawnmower, overwrite: bool) -> tuple[int, int, int]:
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
                for t, p, q in zip(times, pos, quaternion(heading, tilt)):
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
                quats = quaternion(heading, tilt)
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
