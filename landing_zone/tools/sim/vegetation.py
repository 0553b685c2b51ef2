"""Vegetation families for dataset patches: how the ground of a tile is covered.

Each family draws its parameters from a scene's plan (:func:`draw_vegetation`) and builds its
meshes with the blades and shrubs of :mod:`landing_zone.tools.sim.grass`
(:func:`build_vegetation`);
nothing here is a second grass model. All of them are safe ground: the label of a patch is the
presence of an obstacle only.

============  ===================================================================================
``uniform``   independent blades, 1500-5000 per m^2, 8-35 cm, 3-8 mm wide: the ground mostly
              hidden at the dense end
``tussock``   clumps (Thomas process) of 40-150 blades 4-9 cm across, 1500-5000 blades per m^2,
              15-45 cm, splaying out, bare ground between
``lodged``    flattened grass: long blades bent over at the base by 65-85 degrees, mostly
              towards one direction (rain or wind), tips 4-18 cm up, 2500-5500 per m^2
``layered``   a dense low layer (5-15 cm) under sparser tall curving blades (25-45 cm)
``bare``      bare ground with gravel (pebbles of 1-4 cm) and debris (bark chips, twigs) under
              5 cm, and a little short grass
``shrub``     low shrubs of leaves and twigs 15-35 cm high, 0.3-0.7 m across, over short grass;
              one stands in the tile more often than not
``meadow``    a prior rather than a kind of grass: one to three layers of blades, each with its
              own density, height (3-42 cm), width, lean, curvature and clumping (none, or
              clumps of 5-400 blades 1.5-25 cm in radius: tufts to porous bunches half a metre
              across), sometimes over a flattened mat; no leaves (see below)
``forb``      a prior of herbaceous broadleaf plants (:mod:`landing_zone.tools.sim.leafy`): one or
two
              kinds a patch, 2-40 plants per m^2, 5-40 cm, one to eight thin stems each with
              2-12 flat leaves of 2-10 cm along them or lying in a rosette at the foot, over
              sparse to dense short grass; no canopy, nothing woody (see below)
``canopy``    a prior of leafy crowns (:mod:`landing_zone.tools.sim.leafy`): 0.3-4 a m^2, 8-35 cm
              high, 10 cm to 1 m across, one to five lobes (domes, cushions, lumpy clusters,
              crowns lifted on bare stems), 2-12 m^2 of leaves per m^3 of 2-8 cm leaves over
              0-12 twigs of 2-8 mm, over short grass; one in the tile in half the scenes
============  ===================================================================================

synth3 draws from the first six (:data:`SYNTH3_VEGETATION`, fixed so that its scenes stay what
they were); the priors ``meadow``, ``forb`` and ``canopy`` came after it and are drawn only
when asked for (``simulate --dataset synth3 --vegetation meadow,forb``). Made of blades alone,
``meadow`` holds nothing of ``shrub`` (leafy canopies), so ``shrub`` held out stays unseen with
meadow in training; its clumped layers do cover ``tussock``'s clumps, so ``tussock`` held out
no longer is. ``forb`` is leaves on stems, not a canopy: it shares leaves with ``shrub`` but not
its shape (a rounded volume of leaves up to 70 cm across), so ``shrub`` held out with ``forb``
in training is a shape never seen made of a material seen. ``canopy`` spans ``shrub``'s shapes
(one dome 15-35 cm high, 0.3-0.7 m across) among many others: with it in training, ``shrub``
held out is covered, not unseen, as ``tussock`` is by ``meadow``.

**Which shrubs count as safe**: those of this family, at most :data:`SAFE_SHRUB_HEIGHT` high,
made of leaves and twigs no thicker than 8 mm, which a landing skid pushes aside like tall
grass. Woody shrubs, or anything taller, are not vegetation here; such things would be
obstacles, and no family makes them.

Gravel and debris are labelled ground (they are part of the surface a skid stands on).
"""
from __future__ import annotations

import math
from typing import Any, Callable, Sequence

import numpy as np

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.leafy import (CrownForm, ForbForm, crown_mesh, crown_top, forb_mesh,
                                          forb_top)
from landing_zone.tools.sim.grass import (Bush, ScaleField, VegetationConfig, blade_strips,
                                          bush_mesh, place_bushes, points_in_polygon, scatter,
                                          vegetation_blades)
from landing_zone.tools.sim.mesh import GROUND, Mesh
from landing_zone.tools.sim.terrain import Terrain

__all__ = ['VEGETATION_FAMILIES', 'SYNTH3_VEGETATION', 'SAFE_SHRUB_HEIGHT',
           'MAX_VEGETATION_HEIGHT', 'check_vegetation', 'draw_vegetation', 'vegetation_top',
           'hide_obstacle', 'build_vegetation']

SAFE_SHRUB_HEIGHT = 0.35  # [m]
_LODGED_LENGTH = 0.6  # [m] longest blade of lodged grass
MAX_VEGETATION_HEIGHT = 0.45  # [m] no blade tip or leaf higher above its base


def _u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return round(float(rng.uniform(lo, hi)), 4)


def _draw_uniform(rng: np.random.Generator) -> dict[str, Any]:
    return {'density': _u(rng, 1500, 5000), 'height': _u(rng, 0.08, 0.35),
            'width': _u(rng, 0.003, 0.008), 'lean': _u(rng, 10, 25)}


def _draw_tussock(rng: np.random.Generator) -> dict[str, Any]:
    return {'density': _u(rng, 1500, 5000), 'height': _u(rng, 0.15, 0.42),
            'width': _u(rng, 0.003, 0.007), 'lean': _u(rng, 20, 35),
            'clump_size': _u(rng, 40, 150), 'clump_radius': _u(rng, 0.04, 0.09)}


def _draw_lodged(rng: np.random.Generator) -> dict[str, Any]:
    return {'density': _u(rng, 2500, 5500), 'height': _u(rng, 0.04, 0.18),
            'width': _u(rng, 0.004, 0.008), 'lean': _u(rng, 65, 85),
            'azimuth': _u(rng, 0, 2 * math.pi), 'spread': _u(rng, 15, 45)}


def _draw_layered(rng: np.random.Generator) -> dict[str, Any]:
    return {'density': _u(rng, 1500, 4000), 'height': _u(rng, 0.05, 0.15),
            'width': _u(rng, 0.003, 0.006), 'tall_density': _u(rng, 250, 1000),
            'tall_height': _u(rng, 0.25, 0.42), 'tall_width': _u(rng, 0.004, 0.008)}


def _draw_bare(rng: np.random.Generator) -> dict[str, Any]:
    return {'density': _u(rng, 0, 300), 'height': _u(rng, 0.02, 0.06),
            'gravel': _u(rng, 50, 400), 'gravel_size': _u(rng, 0.015, 0.04),
            'debris': _u(rng, 5, 60)}


def _draw_shrub(rng: np.random.Generator) -> dict[str, Any]:
    lo = _u(rng, 0.15, 0.25)
    return {'density': _u(rng, 300, 1500), 'height': _u(rng, 0.05, 0.2),
            'width': _u(rng, 0.003, 0.006), 'bushes': _u(rng, 0.3, 1.0),
            'bush_height': [lo, _u(rng, lo, SAFE_SHRUB_HEIGHT)],
            'bush_diameter': [0.3, _u(rng, 0.4, 0.7)], 'leaf_density': _u(rng, 4, 10),
            'in_tile': bool(rng.uniform() < 0.7)}


def _log_u(rng: np.random.Generator, lo: float, hi: float) -> float:
    return float(np.exp(rng.uniform(math.log(lo), math.log(hi))))


def _draw_meadow(rng: np.random.Generator) -> dict[str, Any]:
    n = int(rng.integers(1, 4))
    total = _log_u(rng, 800.0, 6000.0)  # blades per m^2 over all layers
    share = rng.dirichlet(np.ones(n))
    layers = []
    for k in range(n):
        clumped = bool(rng.uniform() < 0.5)
        layers.append({
            'density': round(max(total * float(share[k]), 50.0), 1),
            'height': _u(rng, 0.03, 0.42), 'width': _u(rng, 0.002, 0.009),
            'lean': _u(rng, 5, 60), 'segments': int(rng.integers(2, 6)),
            'bend': _u(rng, 0.6, 3.0), 'height_cv': _u(rng, 0.1, 0.45),
            'clump_size': round(_log_u(rng, 5.0, 400.0), 1) if clumped else 0.0,
            'clump_radius': round(_log_u(rng, 0.015, 0.25), 4)})
    mat = None
    if rng.uniform() < 0.3:
        mat = {'density': _u(rng, 500, 4000), 'height': _u(rng, 0.04, 0.15),
               'width': _u(rng, 0.003, 0.008), 'lean': _u(rng, 60, 85),
               'azimuth': _u(rng, 0, 2 * math.pi), 'spread': _u(rng, 15, 90)}
    return {'layers': layers, 'mat': mat}


def _draw_forb(rng: np.random.Generator) -> dict[str, Any]:
    forms = []
    for _ in range(int(rng.integers(1, 3))):
        forms.append({
            'plants': round(_log_u(rng, 2.0, 40.0), 2), 'height': _u(rng, 0.05, 0.40),
            'height_cv': _u(rng, 0.1, 0.35), 'spread': round(_log_u(rng, 0.01, 0.2), 4),
            'stems': int(rng.integers(1, 9)), 'leaves': int(rng.integers(2, 13)),
            'leaf_size': _u(rng, 0.02, 0.10), 'leaf_tilt': _u(rng, -10.0, 70.0),
            'leaf_bias': round(_log_u(rng, 0.25, 4.0), 3),
            'rosette': _u(rng, 0.0, 1.0) if rng.uniform() < 0.5 else 0.0,
            'stem_lean': _u(rng, 0.0, 30.0), 'stem_width': _u(rng, 0.002, 0.006)})
    # The grass under the plants, sparse to dense.
    return {'density': round(_log_u(rng, 50.0, 2500.0), 1), 'height': _u(rng, 0.03, 0.15),
            'width': _u(rng, 0.003, 0.006), 'lean': _u(rng, 10, 30), 'forms': forms}


def _draw_canopy(rng: np.random.Generator) -> dict[str, Any]:
    lo = _u(rng, 0.08, 0.25)
    narrow = round(_log_u(rng, 0.1, 0.5), 3)
    return {'density': round(_log_u(rng, 50.0, 2500.0), 1), 'height': _u(rng, 0.03, 0.15),
            'width': _u(rng, 0.003, 0.006), 'lean': _u(rng, 10, 30),
            'crowns': round(_log_u(rng, 0.3, 4.0), 3),
            'crown_height': [lo, _u(rng, lo, SAFE_SHRUB_HEIGHT)],
            'crown_width': [narrow, round(_log_u(rng, narrow, 1.0), 3)],
            'lobes': int(rng.integers(1, 6)),
            'lift': _u(rng, 0.0, 0.5) if rng.uniform() < 0.3 else 0.0,
            'leaf_density': round(_log_u(rng, 2.0, 12.0), 2), 'leaf_size': _u(rng, 0.02, 0.08),
            'twigs': int(rng.integers(0, 13)), 'twig_width': _u(rng, 0.002, 0.008),
            'in_tile': bool(rng.uniform() < 0.5)}


_DRAW: dict[str, Callable[[np.random.Generator], dict[str, Any]]] = {
    'uniform': _draw_uniform, 'tussock': _draw_tussock, 'lodged': _draw_lodged,
    'layered': _draw_layered, 'bare': _draw_bare, 'shrub': _draw_shrub,
    'meadow': _draw_meadow, 'forb': _draw_forb, 'canopy': _draw_canopy}
VEGETATION_FAMILIES = tuple(_DRAW)
SYNTH3_VEGETATION = VEGETATION_FAMILIES[:6]  # what synth3 draws unless told (fixed)


def check_vegetation(vegetation: Sequence[str] | None) -> tuple[str, ...] | None:
    """``vegetation`` as synth3's plan takes it: None for synth3's own
    (:data:`SYNTH3_VEGETATION`, also when they are named in their order), else the names in the
    order given.

    Raises:
        SimulationError: an unknown or repeated vegetation family, or none.
    """
    if vegetation is None:
        return None
    names = tuple(str(f) for f in vegetation)
    if not names or len(set(names)) != len(names):
        raise SimulationError(f'synth3 vegetation families must be distinct names, got '
                              f'{list(names)}')
    unknown = [n for n in names if n not in VEGETATION_FAMILIES]
    if unknown:
        raise SimulationError(f'unknown vegetation family {unknown[0]!r}; choose from '
                              f'{", ".join(VEGETATION_FAMILIES)}')
    return None if names == SYNTH3_VEGETATION else names


def _check(family: str) -> None:
    if family not in _DRAW:
        raise SimulationError(f'unknown vegetation family {family!r}; choose from '
                              f'{", ".join(VEGETATION_FAMILIES)}')


def draw_vegetation(family: str, rng: np.random.Generator) -> dict[str, Any]:
    """The parameters of one patch's vegetation of ``family`` (JSON-ready)."""
    _check(family)
    return {'family': family, **_DRAW[family](rng)}


def vegetation_top(params: dict[str, Any]) -> float:
    """The highest any part of this vegetation can reach above the ground [m]."""
    fam = params['family']
    if fam == 'shrub':
        # A leaf centred at the canopy's top reaches its circumradius above it.
        return max(float(params['bush_height'][1]) + 0.03, _blade_top(params['height']))
    if fam == 'layered':
        return max(_blade_top(params['height']), _blade_top(params['tall_height']))
    if fam == 'bare':
        return max(_blade_top(params['height']), 0.05)
    if fam == 'lodged':
        return _blade_top(params['height'], 0.3)
    if fam == 'meadow':
        tops = [_blade_top(layer['height'], max(layer['height_cv'], 0.25))
                for layer in params['layers']]
        if params['mat'] is not None:
            tops.append(_blade_top(params['mat']['height'], 0.3))
        return max(tops)
    if fam == 'forb':
        return max([_blade_top(params['height'])]
                   + [forb_top(ForbForm(**f), MAX_VEGETATION_HEIGHT)
                      for f in params['forms']])
    if fam == 'canopy':
        return max(_blade_top(params['height']), crown_top(_crowns(params)))
    return _blade_top(params['height'])


def _blade_top(mean: float, spread: float = 0.25) -> float:
    return min(mean * (1.0 + 3.0 * spread), MAX_VEGETATION_HEIGHT)  # +3 sigma, capped


def hide_obstacle(params: dict[str, Any], height: float) -> dict[str, Any]:
    """The same vegetation grown to hide an obstacle ``height`` high: its (tall) blades' mean
    height set to it, within the family's range (meadow: its tallest layer's; forb: its
    tallest plants'). Families that cannot hide anything (lodged, bare, shrub, canopy) are
    returned unchanged."""
    out = dict(params)
    # The priors' lists of parts (meadow's layers, forb's kinds of plant): the tallest grows.
    lists = {'meadow': ('layers', 0.42), 'forb': ('forms', 0.40)}
    if params['family'] in lists:
        parts, top = lists[params['family']]
        grown = [dict(p) for p in params[parts]]
        tallest = max(range(len(grown)), key=lambda k: grown[k]['height'])
        grown[tallest]['height'] = round(float(np.clip(height, 0.08, top)), 4)
        out[parts] = grown
        return out
    key = {'uniform': 'height', 'tussock': 'height', 'layered': 'tall_height'}.get(
        params['family'])
    if key is not None:
        out[key] = round(float(np.clip(height, 0.08, 0.42)), 4)
    return out


def build_vegetation(params: dict[str, Any], terrain: Terrain, rng: np.random.Generator,
                     polygon: np.ndarray, keep_out: list[tuple[float, float, float]] = (),
                     tile: tuple[np.ndarray, np.ndarray] | None = None,
                     density_scale: ScaleField | None = None,
                     height_scale: ScaleField | None = None
                     ) -> tuple[Mesh, Mesh, list[Bush]]:
    """The meshes of a patch's vegetation.

    Args:
        params: from :func:`draw_vegetation` (maybe through :func:`hide_obstacle`).
        terrain: the ground.
        rng: randomness of placement and shapes.
        polygon: (K, 2) convex counter-clockwise region to cover.
        keep_out: (x, y, radius) discs no shrub reaches into (the obstacle).
        tile: the tile's corners (shrubs: where one stands more often than not).
        density_scale, height_scale: optional fields in [0, 1] and around 1 that thin the
            blades and scale their height (a flight site's patches and clearings).

    Returns:
        ``(vegetation, ground_cover, bushes)``: blades and shrubs (GRASS faces), gravel and
        debris (GROUND faces), the shrubs placed.
    """
    fam = params['family']
    _check(fam)
    polygon = np.asarray(polygon, dtype=float)
    parts: list[Mesh] = []
    cover = Mesh.empty()
    bushes: list[Bush] = []
    if fam in ('uniform', 'tussock', 'layered', 'bare', 'shrub', 'forb', 'canopy'):
        cfg = VegetationConfig(
            blade_width=params.get('width', 0.004), inclination_std=params.get('lean', 15.0),
            clump_size=params.get('clump_size', 0.0),
            clump_radius=params.get('clump_radius', 0.06),
            segments=3 if fam == 'tussock' else 2, bend=1.5 if fam == 'tussock' else 1.0,
            max_height=MAX_VEGETATION_HEIGHT)
        parts.append(vegetation_blades(cfg, params['density'], params['height'], terrain, rng,
                                       polygon, density_scale, height_scale))
    if fam == 'layered':
        tall = VegetationConfig(blade_width=params['tall_width'], inclination_std=30.0,
                                height_cv=0.2, segments=4, bend=2.0,
                                max_height=MAX_VEGETATION_HEIGHT)
        parts.append(vegetation_blades(tall, params['tall_density'], params['tall_height'],
                                       terrain, rng, polygon, density_scale, height_scale))
    if fam == 'lodged':
        parts.append(_lodged(params, terrain, rng, polygon, density_scale))
    if fam == 'meadow':
        for layer in params['layers']:
            cfg = VegetationConfig(
                blade_width=layer['width'], inclination_std=layer['lean'],
                clump_size=layer['clump_size'], clump_radius=layer['clump_radius'],
                height_cv=layer['height_cv'], segments=layer['segments'], bend=layer['bend'],
                max_height=MAX_VEGETATION_HEIGHT)
            parts.append(vegetation_blades(cfg, layer['density'], layer['height'], terrain,
                                           rng, polygon, density_scale, height_scale))
        if params['mat'] is not None:
            parts.append(_lodged(params['mat'], terrain, rng, polygon, density_scale))
    if fam == 'forb':
        for form in params['forms']:
            parts.append(forb_mesh(ForbForm(**form), terrain, rng, polygon,
                                   MAX_VEGETATION_HEIGHT, list(keep_out), density_scale,
                                   height_scale))
    if fam == 'canopy':
        crowns = _crowns(params)
        parts.append(crown_mesh(crowns, terrain, rng, polygon, list(keep_out), density_scale,
                                height_scale))
        if params.get('in_tile') and tile is not None:
            # One more whose centre lies in the tile, unless the obstacle leaves no room.
            parts.append(crown_mesh(crowns, terrain, rng, _square(tile), list(keep_out),
                                    count=1))
    if fam == 'bare':
        cover = Mesh.concat([_gravel(params, terrain, rng, polygon),
                             _debris(params, terrain, rng, polygon)])
    if fam == 'shrub':
        cfg = VegetationConfig(bush_density=params['bushes'],
                               bush_height=tuple(params['bush_height']),
                               bush_diameter=tuple(params['bush_diameter']),
                               leaf_density=params['leaf_density'])
        bushes = place_bushes(cfg, terrain, rng, polygon, list(keep_out))
        if params.get('in_tile') and tile is not None:
            # One more whose centre lies in the tile, unless the obstacle leaves no room.
            one = place_bushes(cfg, terrain, rng, _square(tile), list(keep_out))
            bushes += one[:1] if one else []
        parts.append(bush_mesh(cfg, bushes, rng))
    return Mesh.concat(parts), cover, bushes


def _square(tile: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """The tile's corners ``(lo, hi)`` as a counter-clockwise polygon."""
    lo, hi = (np.asarray(c, float) for c in tile)
    return np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]])


def _crowns(params: dict[str, Any]) -> CrownForm:
    return CrownForm(crowns=params['crowns'], height=tuple(params['crown_height']),
                     width=tuple(params['crown_width']), lobes=params['lobes'],
                     lift=params['lift'],
                     leaf_density=params['leaf_density'], leaf_size=params['leaf_size'],
                     twigs=params['twigs'], twig_width=params['twig_width'])


def _lodged(params: dict[str, Any], terrain: Terrain, rng: np.random.Generator,
            polygon: np.ndarray, density_scale: ScaleField | None = None) -> Mesh:
    """Blades bent over at the base, lying towards one direction (give or take a spread)."""
    lo, hi = polygon.min(axis=0), polygon.max(axis=0)
    # Bases up to a blade's length outside the region lean into it.
    lo, hi = lo - _LODGED_LENGTH - 0.05, hi + _LODGED_LENGTH + 0.05
    n = rng.poisson(params['density'] * float(np.prod(hi - lo)))
    xy = lo + (hi - lo) * rng.random((n, 2))
    if density_scale is not None:
        xy = xy[rng.random(n) < np.clip(density_scale(xy[:, 0], xy[:, 1]), 0.0, 1.0)]
        n = len(xy)
    if n == 0:
        return Mesh.empty()
    height = params['height'] * np.maximum(1.0 + 0.3 * np.clip(rng.standard_normal(n), -3, 3),
                                           0.3)
    incl = np.radians(np.clip(params['lean'] + 8.0 * rng.standard_normal(n), 45.0, 88.0))
    # bend < 1: the lean comes at the base, the blade lies over (bend > 1 would droop a tip).
    bend, pieces = 0.15, 3
    k = (np.arange(1, pieces + 1) / pieces) ** bend
    mean_cos = np.cos(incl[:, None] * k[None, :]).mean(axis=1)
    # No blade longer than _LODGED_LENGTH: a tip that low on a blade that flat comes down.
    height = np.minimum(height, _LODGED_LENGTH * mean_cos)
    azimuth = params['azimuth'] + np.radians(params['spread']) * rng.standard_normal(n)
    base = np.column_stack([xy, terrain.height(xy[:, 0], xy[:, 1]) - 0.005])
    mesh = blade_strips(base, height, incl, azimuth, params['width'], segments=pieces,
                        bend=bend)
    # Keep the blades whose tips come down inside the region (bases may lie outside it).
    tips = mesh.vertices.reshape(n, -1, 3)[:, -1, :2]
    keep = points_in_polygon(tips.astype(float), polygon) | points_in_polygon(xy, polygon)
    faces = mesh.faces.reshape(n, -1, 3)[keep].reshape(-1, 3)
    return Mesh(mesh.vertices, faces, np.full(len(faces), mesh.labels[0], np.uint8))


def _gravel(params: dict[str, Any], terrain: Terrain, rng: np.random.Generator,
            polygon: np.ndarray) -> Mesh:
    """Pebbles: eight random stone templates, scaled, turned and sunk a third into the ground."""
    import trimesh
    ico = trimesh.creation.icosphere(subdivisions=0)
    base_v, faces = np.asarray(ico.vertices), np.asarray(ico.faces, np.int64)
    templates = base_v[None] * rng.uniform(0.7, 1.2, (8, len(base_v), 1)) * np.array(
        [1.0, 0.8, 0.55])
    xy, inside = scatter(params['gravel'], polygon, rng)
    xy = xy[inside]
    n = len(xy)
    if n == 0:
        return Mesh.empty()
    size = params['gravel_size'] * rng.uniform(0.35, 1.0, n)
    yaw = rng.uniform(0, 2 * math.pi, n)
    c, s = np.cos(yaw), np.sin(yaw)
    tv = templates[rng.integers(0, 8, n)] * (0.5 * size)[:, None, None]  # (n, 12, 3)
    x = c[:, None] * tv[..., 0] - s[:, None] * tv[..., 1]
    y = s[:, None] * tv[..., 0] + c[:, None] * tv[..., 1]
    z0 = terrain.height(xy[:, 0], xy[:, 1]) + 0.15 * size
    v = np.stack([x + xy[:, :1], y + xy[:, 1:], tv[..., 2] + z0[:, None]], axis=-1)
    f = (np.arange(n)[:, None, None] * len(base_v) + faces[None]).reshape(-1, 3)
    return Mesh.from_arrays(v.reshape(-1, 3), f, GROUND)


def _debris(params: dict[str, Any], terrain: Terrain, rng: np.random.Generator,
            polygon: np.ndarray) -> Mesh:
    """Bark chips and twigs: thin boxes lying on the ground, under 3 cm high."""
    xy, inside = scatter(params['debris'], polygon, rng)
    xy = xy[inside]
    n = len(xy)
    if n == 0:
        return Mesh.empty()
    ext = np.column_stack([rng.uniform(0.03, 0.2, n), rng.uniform(0.008, 0.04, n),
                           rng.uniform(0.004, 0.02, n)])
    import trimesh
    unit = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    corners, faces = np.asarray(unit.vertices), np.asarray(unit.faces, np.int64)
    yaw = rng.uniform(0, 2 * math.pi, n)
    c, s = np.cos(yaw), np.sin(yaw)
    local = corners[None] * ext[:, None, :]
    x = c[:, None] * local[..., 0] - s[:, None] * local[..., 1]
    y = s[:, None] * local[..., 0] + c[:, None] * local[..., 1]
    z0 = terrain.height(xy[:, 0], xy[:, 1]) + 0.3 * ext[:, 2]
    v = np.stack([x + xy[:, :1], y + xy[:, 1:], local[..., 2] + z0[:, None]], axis=-1)
    f = (np.arange(n)[:, None, None] * 8 + faces[None]).reshape(-1, 3)
    return Mesh.from_arrays(v.reshape(-1, 3), f, GROUND)
