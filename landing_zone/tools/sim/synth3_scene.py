"""One synth3 scene drawn from its pair's plan: the world, the obstacle, the scan, the record.

The plan (:func:`landing_zone.tools.sim.synth3.scene_plan`) fixes everything a pair shares; this
module builds the scene's world from its own seed (``SeedSequence([seed, 3, i])`` and the
variant's key), places the obstacle (in the tile, straddling its edge or beyond it), scans it
with the plan's sensor and packs the returns as every synthetic dataset stores them
(:mod:`landing_zone.tools.sim.dataset`).
"""
from __future__ import annotations

import math
import time
from dataclasses import replace
from typing import Any, Sequence

import numpy as np

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.families import Instance, instance, keep_visible
from landing_zone.tools.sim.flyover import Flyover, flyover_scan, plan_flyover
from landing_zone.tools.sim.mesh import Mesh
from landing_zone.tools.sim.obstacles import Obstacle, at_edge, place
from landing_zone.tools.sim.scene import PatchConfig, World, hover_plan, view_region
from landing_zone.tools.sim.hover import hover_scan
from landing_zone.tools.sim.sensor import ScanPattern, SensorConfig
from landing_zone.tools.sim.synth3 import EDGE_TALL, SYNTH3_CODE, check_edge, check_families, \
    scene_plan, variant_key
from landing_zone.tools.sim.terrain import SlopedTerrain, Terrain, TerrainConfig
from landing_zone.tools.sim.vegetation import build_vegetation, check_vegetation, \
    hide_obstacle, vegetation_top

__all__ = ['generate_scene']

FAR = 32.0  # [m] returns farther from the tile centre (on any axis) are not stored


def generate_scene(index: int, seed: int = 0, threads: int = 1,
                   families: Sequence[str] | None = None, edge: float = 0.0,
                   vegetation: Sequence[str] | None = None) -> dict[str, Any]:
    """Simulate scene ``index`` of synth3 (drawing from ``families``, None: synth3's own;
    ``edge``: the share of pairs at the tile's edge; ``vegetation``: from these vegetation
    families, None: synth3's own): the record
    :func:`landing_zone.tools.sim.sweeps.generate_scene` returns (``points_mm``, ``hit_class``,
    ``origin_index``, ``origins``, ``origin_times``, ``label``, ``split``, ``params``,
    ``rays``, ``timings``)."""
    timings: dict[str, float] = {}
    # the pair's plan, the scene's own generator, the sensor and the region rays can reach
    t0 = time.perf_counter()
    fams = check_families(families)
    edge = check_edge(edge)
    vegs = check_vegetation(vegetation)
    plan = scene_plan(index, seed, fams, edge, vegs)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), SYNTH3_CODE, int(index)]
                                                       + variant_key(fams, edge, vegs)))
    patch = PatchConfig()
    aoi, box = patch.aoi, patch.column
    inst = instance(plan['family'], plan['instance'])
    veg = plan['vegetation']
    if plan['hide'] is not None:
        veg = hide_obstacle(veg, plan['hide'] * (inst.model.size[2] - inst.model.embed))
    top = vegetation_top(veg)
    tp = plan['terrain']
    sensor, sources, scan = _scanner(plan, aoi, box)
    region = _region(sources, box, tp['amplitude'], tp['slope'], tp['azimuth'], top)
    lo, hi = region.min(axis=0), region.max(axis=0)
    timings['plan'] = time.perf_counter() - t0
    # the world: terrain, the obstacle, the vegetation around it
    t0 = time.perf_counter()
    tcfg = TerrainConfig(amplitude=tp['amplitude'], wavelength=tp['wavelength'],
                         octaves=tp['octaves'], spacing=tp['spacing'])
    pad = 2.0 * tcfg.spacing
    terrain = SlopedTerrain(tcfg, rng, lo - pad, hi + pad, tp['slope'], tp['azimuth'])
    obstacle = _place_obstacle(plan, inst, patch.tile_size, terrain, rng)
    keep_out = ([(obstacle.x, obstacle.y, inst.model.radius + 0.05)] if obstacle is not None
                else [])
    cover, ground_cover, bushes = build_vegetation(veg, terrain, rng, region, keep_out, aoi)
    world = World(terrain, Mesh.concat([cover, ground_cover]),
                  [obstacle] if obstacle is not None else [])
    timings['world'] = time.perf_counter() - t0
    # the scan
    t0 = time.perf_counter()
    caster = world.caster(threads)
    timings['bvh'] = time.perf_counter() - t0
    t0 = time.perf_counter()
    if scan['kind'] == 'hover':
        result = hover_scan(caster, replace(sensor, nod_rate=scan['omega']), scan['position'],
                            *aoi, *box, rng, wander_bound=scan['wander'])
        how = {'nod_rate': round(result.nod_rate, 3), 'sweeps': result.sweeps}
    else:
        result = flyover_scan(caster, sensor, scan['fly'], scan['plan'], *aoi, *box, rng)
        how = {'speed': round(result.speed, 3)}
    timings['scan'] = time.perf_counter() - t0
    # the record
    ret, far = _near_returns(result.returns, index)
    params = dict(plan)
    params['vegetation'] = veg
    params.update({
        'obstacle': (dict(obstacle.to_json(), **inst.to_json()) if obstacle is not None
                     else None),
        'n_returns': int(len(ret)), 'density': round(result.density, 1),
        **({'far_dropped': far} if far else {}),
        'scan_time': round(result.duration, 4), 'n_faces': int(world.grass.n_faces),
        'bushes': len(bushes), 'region_m2': round(float(np.prod(hi - lo)), 2),
        'seed': int(seed), **how})
    return {'points_mm': np.rint(ret.points * 1000.0).astype(np.int16),
            'hit_class': ret.labels.astype(np.uint8),
            'origin_index': ret.line.astype(np.uint16),
            'origins': ret.line_origins.astype(np.float32),
            'origin_times': ret.line_times.astype(np.float32),
            'label': plan['label'], 'split': plan['split'], 'params': params,
            'rays': result.rays, 'timings': dict(timings, cast=result.cast_seconds)}


def _place_obstacle(plan: dict[str, Any], inst: Instance, tile_size: float, terrain: Terrain,
                    rng: np.random.Generator) -> Obstacle | None:
    """The scene's obstacle on the terrain, or None (a safe scene not at the edge)."""
    model = inst.model
    if 'edge' in plan:  # both scenes of the pair: reaching in, or beyond the edge
        e, unsafe = plan['edge'], plan['label'] == 0
        x, y = at_edge(model, e['yaw'], e['side'], e['along'], 0.5 * tile_size,
                       EDGE_TALL, reach=e['reach'] if unsafe else None,
                       gap=None if unsafe else e['gap'])
        return keep_visible(place(model, x, y, e['yaw'], terrain), terrain)
    if plan['label'] == 0:
        # Inside the tile for any yaw, or straddling its edge with half its radius inside (as
        # synth2 places them).
        free = (0.5 * tile_size - model.radius if plan['inside']
                else 0.5 * tile_size + 0.5 * model.radius)
        x, y = rng.uniform(-free, free, 2)
        obstacle = place(model, float(x), float(y), float(rng.uniform(0.0, 2.0 * np.pi)),
                         terrain)
        return keep_visible(obstacle, terrain)
    return None


def _near_returns(ret: Any, index: int) -> tuple[Any, int]:
    """The returns that fit the stored format, and how many were dropped.

    Returns are stored as int16 millimetres: a ray that crossed the column high up and came
    down more than 32 m away (a view grazing ground that falls away) is dropped; the column
    only loses a few pass-throughs near its top."""
    far = np.any(np.abs(ret.points) > FAR, axis=1)
    if far.any():
        keep = ~far
        ret = type(ret)(ret.points[keep], ret.labels[keep], ret.times[keep], ret.line[keep],
                        ret.line_origins, ret.line_times).compact_lines()
    if len(ret.line_times) > np.iinfo(np.uint16).max:
        raise SimulationError(f'synth3 scene {index}: more than 65535 scan lines')
    return ret, int(far.sum())


def _scanner(plan: dict[str, Any], aoi: tuple[np.ndarray, np.ndarray],
             box: tuple[np.ndarray, np.ndarray]) -> tuple[Any, np.ndarray, dict[str, Any]]:
    """The sensor of a plan: its configuration, the corners of where it can be, its scan's
    own settings."""
    s = plan['sensor']
    if s['family'] == 'nodding':
        sensor = SensorConfig(angular_resolution=s['resolution'], target_density=s['density'])
        position = np.array([s['offset'], 0.0, s['height']])
        omega, wander, sources = hover_plan(sensor, position, *aoi)
        return sensor, sources, {'kind': 'hover', 'position': position, 'omega': omega,
                                 'wander': wander}
    if s['family'] == 'line':
        sensor = SensorConfig(prr=s['prr'], angular_resolution=s['resolution'],
                              target_density=s['density'])
        pattern = ScanPattern('line')
    else:
        # Lines of 1001 pulses group the returns by origin, as in flights.
        sensor = SensorConfig(prr=s['prr'], target_density=s['density'])
        extra = {k: s[k] for k in ('beams', 'beam_fov', 'spin_rate', 'fov') if k in s}
        pattern = ScanPattern(s['family'], **extra)
    fly = Flyover(pattern, s['height'], s['tilt'], s['cross'], s['heading'])
    fplan = plan_flyover(sensor, fly, *aoi, *box)
    return sensor, fplan.sources(fly, sensor), {'kind': 'flyover', 'fly': fly, 'plan': fplan}


def _region(sources: np.ndarray, box: tuple[np.ndarray, np.ndarray], amplitude: float,
            slope: float, azimuth: float, top: float) -> np.ndarray:
    """Where rays through the column can be inside the ground-cover layer: the scene module's
    view region, its layer following the slope."""
    g = math.tan(math.radians(slope))
    grade = np.array([g * math.cos(azimuth), g * math.sin(azimuth)])
    return view_region(sources, box[0], box[1], -amplitude - 0.01, amplitude + top + 0.01, top,
                       grade=grade)
