"""The site of a simulated flight: its ground, vegetation and obstacles, and their ground truth.

The site (default 20 m x 20 m, centred at the origin of the ``map`` frame) has Perlin-noise
ground, grass in patches of varying density and height with clearings of open ground (or other
vegetation), and obstacles of mixed kinds at least 1.5 m apart. A 1 m tile of the global lattice
is unsafe when an obstacle's footprint overlaps it (:func:`tile_labels`).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.families import draw_instance, keep_visible, parse_families
from landing_zone.tools.sim.flight_settings import MIN_SEPARATION, FlightConfig
from landing_zone.tools.sim.grass import Bush, GrassConfig, _poisson_blades, bush_mesh, \
    grass_mesh, place_bushes, vegetation_blades
from landing_zone.tools.sim.library import models
from landing_zone.tools.sim.mesh import Mesh
from landing_zone.tools.sim.obstacles import Obstacle, place
from landing_zone.tools.sim.scene import World
from landing_zone.tools.sim.terrain import PerlinNoise, SlopedTerrain, Terrain
from landing_zone.tools.sim.vegetation import build_vegetation, draw_vegetation

__all__ = ['Site', 'build_site', 'tile_labels', 'polygon_overlaps_square']


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
            if all(np.hypot(*(c - o)) >= MIN_SEPARATION for o in centres):
                break
        else:
            raise SimulationError(f'could not place {config.obstacles} obstacles '
                                  f'{MIN_SEPARATION} m apart on the site')
        centres.append(c)
        ob = place(model, float(c[0]), float(c[1]), float(rng.uniform(0, 2 * np.pi)), terrain)
        out.append(keep_visible(ob, terrain) if config.slope or i % len(entries) >= len(
            config.kinds) else ob)
    return out
