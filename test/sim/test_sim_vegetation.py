"""Vegetation families, sloped ground and the view region that follows it."""
from __future__ import annotations

import math

import numpy as np
import pytest

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.mesh import GRASS, GROUND, Mesh
from landing_zone.tools.sim.scene import World, view_region
from landing_zone.tools.sim.terrain import SlopedTerrain, Terrain, TerrainConfig
from landing_zone.tools.sim.vegetation import (MAX_VEGETATION_HEIGHT, SAFE_SHRUB_HEIGHT,
                                               VEGETATION_FAMILIES, build_vegetation,
                                               draw_vegetation, hide_obstacle, vegetation_top)

SQUARE = np.array([[-1.5, -1.5], [1.5, -1.5], [1.5, 1.5], [-1.5, 1.5]])
TILE = (np.array([-0.5, -0.5]), np.array([0.5, 0.5]))


def _ground_share(mesh: Mesh, terrain: Terrain, depression: float) -> float:
    """Share of parallel rays into the tile at ``depression`` [deg] that reach the ground."""
    caster = World(terrain, mesh).caster(1)
    xy = np.random.default_rng(5).uniform(-0.5, 0.5, (3000, 2))
    d = np.array([math.cos(math.radians(depression)), 0.0, -math.sin(math.radians(depression))])
    org = np.column_stack([xy, np.zeros(len(xy))]) - 2.0 * d
    return float(np.mean(caster.cast(org, np.tile(d, (len(xy), 1)), 10.0).label == GROUND))


@pytest.mark.parametrize('family', VEGETATION_FAMILIES)
def test_families_build_within_their_heights_and_same_seed_same_mesh(family):
    terrain = Terrain(TerrainConfig(amplitude=0.0), np.random.default_rng(0), (-2, -2), (2, 2))
    tops = []
    for k in range(3):
        params = draw_vegetation(family, np.random.default_rng(k))
        assert params['family'] == family
        veg, cover, bushes = build_vegetation(params, terrain, np.random.default_rng(k), SQUARE,
                                              tile=TILE)
        again = build_vegetation(params, terrain, np.random.default_rng(k), SQUARE, tile=TILE)
        np.testing.assert_array_equal(veg.vertices, again[0].vertices)
        assert np.all(veg.labels == GRASS) and np.all(cover.labels == GROUND)
        top = float(veg.vertices[:, 2].max()) if veg.n_faces else 0.0
        assert top <= vegetation_top(params) + 1e-6 <= MAX_VEGETATION_HEIGHT + 1e-6
        tops.append(top)
        if family == 'bare':  # gravel and debris under 5 cm
            assert cover.n_faces > 0 and cover.vertices[:, 2].max() < 0.05
        if family == 'shrub':
            assert bushes and max(b.height for b in bushes) <= SAFE_SHRUB_HEIGHT
        if family == 'lodged':  # flattened: long blades, low tips (18 cm mean at most)
            tips = veg.vertices.reshape(-1, 7, 3)[:, -1]
            bases = veg.vertices.reshape(-1, 7, 3)[:, 0]
            reach = np.hypot(*(tips - bases)[:, :2].T)
            assert top < 0.36 and np.median(reach) > 1.5 * np.median(tips[:, 2] - bases[:, 2])
    assert max(tops) > 0.03


def test_meadow_spans_layers_clumping_and_mats_of_blades_alone():
    """The meadow prior: one to three blade layers, clumped or not (tufts to bunches), heights
    3-42 cm, sometimes over a flattened mat; nothing but blades (no shrub, no leaf); hiding an
    obstacle grows its tallest layer and no other."""
    terrain = Terrain(TerrainConfig(amplitude=0.0), np.random.default_rng(0), (-2, -2), (2, 2))
    draws = [draw_vegetation('meadow', np.random.default_rng(k)) for k in range(60)]
    layers = [layer for d in draws for layer in d['layers']]
    assert {len(d['layers']) for d in draws} == {1, 2, 3}
    assert any(d['mat'] is not None for d in draws) and any(d['mat'] is None for d in draws)
    clumps = [layer['clump_size'] for layer in layers if layer['clump_size'] > 0]
    assert 0 < len(clumps) < len(layers) and min(clumps) < 20 and max(clumps) > 150
    assert all(0.03 <= layer['height'] <= 0.42 for layer in layers)
    assert max(layer['clump_radius'] for layer in layers) > 0.15
    for k in (0, 1, 2):
        veg, cover, bushes = build_vegetation(draws[k], terrain, np.random.default_rng(k),
                                              SQUARE, tile=TILE)
        assert veg.n_faces > 0 and cover.n_faces == 0 and bushes == []
    p = draws[0] if len(draws[0]['layers']) > 1 else next(
        d for d in draws if len(d['layers']) > 1)
    h = hide_obstacle(p, 0.3)
    tallest = max(range(len(p['layers'])), key=lambda k: p['layers'][k]['height'])
    assert h['layers'][tallest]['height'] == 0.3
    assert all(h['layers'][k] == p['layers'][k] for k in range(len(p['layers'])) if k != tallest)
    assert p['layers'][tallest]['height'] != 0.3  # (the draw itself is left as it was)


def test_forb_is_leafy_plants_on_thin_stems_within_its_ranges():
    """The forb prior: one or two kinds of plant a patch, each within its drawn ranges
    (5-40 cm, 1-8 stems of 2-12 leaves, rosettes in some), built as stems and flat leaves that
    stay under the family's top, stand clear of an obstacle's disc, and come out the same for
    the same seed; hiding an obstacle grows the tallest kind and no other."""
    terrain = Terrain(TerrainConfig(amplitude=0.0), np.random.default_rng(0), (-2, -2), (2, 2))
    draws = [draw_vegetation('forb', np.random.default_rng(k)) for k in range(60)]
    forms = [f for d in draws for f in d['forms']]
    assert {len(d['forms']) for d in draws} == {1, 2}
    assert all(0.05 <= f['height'] <= 0.40 and 1 <= f['stems'] <= 8 and 2 <= f['leaves'] <= 12
               and 0.02 <= f['leaf_size'] <= 0.10 and 0.002 <= f['stem_width'] <= 0.006
               for f in forms)
    assert any(f['rosette'] > 0.5 for f in forms) and any(f['rosette'] == 0 for f in forms)
    # Plants alone (no grass under them), tall and many, around an obstacle at the centre.
    p = {**draws[0], 'density': 0.0,
         'forms': [{**draws[0]['forms'][0], 'plants': 30.0, 'height': 0.3, 'rosette': 0.5}]}
    veg, cover, bushes = build_vegetation(p, terrain, np.random.default_rng(3), SQUARE,
                                          keep_out=[(0.0, 0.0, 0.4)])
    assert cover.n_faces == 0 and bushes == [] and np.all(veg.labels == GRASS)
    assert 0.2 < float(veg.vertices[:, 2].max()) <= vegetation_top(p) + 1e-6
    near_ground = veg.vertices[:, 2] < 0.1  # rosettes and stem feet
    assert near_ground.any() and (~near_ground).any()
    # No plant stands in the obstacle's disc: every stem's foot (sunk below the ground) lies
    # outside it by no more than the plant's spread around its centre.
    form = p['forms'][0]
    feet = veg.vertices[veg.vertices[:, 2] < -0.004, :2]
    assert len(feet) and np.hypot(*feet.T).min() > 0.4 - form['spread'] - form['stem_width']
    again = build_vegetation(p, terrain, np.random.default_rng(3), SQUARE,
                             keep_out=[(0.0, 0.0, 0.4)])[0]
    np.testing.assert_array_equal(veg.vertices, again.vertices)
    two = next(d for d in draws if len(d['forms']) == 2)
    h = hide_obstacle(two, 0.3)
    tallest = max((0, 1), key=lambda k: two['forms'][k]['height'])
    assert h['forms'][tallest]['height'] == 0.3 and h['forms'][1 - tallest] == two['forms'][
        1 - tallest]


def test_canopy_is_leafy_crowns_of_many_shapes_up_to_safe_shrub_height():
    """The canopy prior: crowns 10 cm to 1 m across of one to five lobes, never above the
    height a shrub counts as safe at, leaves over thin twigs, clear of an obstacle's disc, the
    same for the same seed; one stands in the tile when the draw says so."""
    terrain = Terrain(TerrainConfig(amplitude=0.0), np.random.default_rng(0), (-2, -2), (2, 2))
    draws = [draw_vegetation('canopy', np.random.default_rng(k)) for k in range(80)]
    assert min(d['crown_width'][0] for d in draws) < 0.15
    assert max(d['crown_width'][1] for d in draws) > 0.8
    assert {d['lobes'] for d in draws} == {1, 2, 3, 4, 5}
    assert all(d['crown_height'][1] <= SAFE_SHRUB_HEIGHT and d['twig_width'] <= 0.008
               for d in draws)
    assert any(d['lift'] > 0 for d in draws) and any(d['in_tile'] for d in draws)
    p = {**draws[0], 'density': 0.0, 'crowns': 3.0, 'crown_width': [0.3, 0.5],
         'crown_height': [0.25, 0.3], 'leaf_density': 8.0, 'in_tile': False}
    veg, cover, bushes = build_vegetation(p, terrain, np.random.default_rng(4), SQUARE,
                                          keep_out=[(0.0, 0.0, 0.3)])
    assert cover.n_faces == 0 and bushes == [] and np.all(veg.labels == GRASS)
    assert 0.2 < float(veg.vertices[:, 2].max()) <= vegetation_top(p) + 1e-6
    # Leaves and twigs stay out of the disc: a crown's centre is half its width clear of it,
    # and nothing of it reaches more than half its width from its centre.
    assert np.hypot(*veg.vertices[:, :2].T).min() > 0.3 - 0.5 * 0.1
    again = build_vegetation(p, terrain, np.random.default_rng(4), SQUARE,
                             keep_out=[(0.0, 0.0, 0.3)])[0]
    np.testing.assert_array_equal(veg.vertices, again.vertices)
    # Crowns too few to meet the tile, but one asked for in it: leaves there, every time.
    sparse = {**p, 'crowns': 0.001, 'in_tile': True}
    for k in range(5):
        m = build_vegetation(sparse, terrain, np.random.default_rng(k), SQUARE, tile=TILE)[0]
        assert m.n_faces > 0 and np.abs(m.vertices[:, :2]).max() < 0.5 + 0.25 + 0.05


def test_dense_families_mostly_hide_the_ground():
    """At a 30 degree depression, the dense end of the blade families lets less than half of
    the rays through to the ground (most often far less)."""
    terrain = Terrain(TerrainConfig(amplitude=0.0), np.random.default_rng(0), (-4, -2), (2, 2))
    region = np.array([[-4.0, -2.0], [2.0, -2.0], [2.0, 2.0], [-4.0, 2.0]])
    for family, dense in [('uniform', {'density': 4500, 'height': 0.3}),
                          ('tussock', {'density': 4500, 'height': 0.35}),
                          ('lodged', {'density': 5000, 'height': 0.15}),
                          ('layered', {'density': 3500, 'tall_density': 900})]:
        params = {**draw_vegetation(family, np.random.default_rng(1)), **dense}
        veg, _, _ = build_vegetation(params, terrain, np.random.default_rng(2), region)
        assert _ground_share(veg, terrain, 30.0) < 0.5, family


def test_hiding_grows_the_blades_to_the_obstacle():
    for family in ('uniform', 'tussock', 'layered'):
        p = draw_vegetation(family, np.random.default_rng(0))
        h = hide_obstacle(p, 0.3)
        assert h[{'layered': 'tall_height'}.get(family, 'height')] == 0.3
    p = draw_vegetation('bare', np.random.default_rng(0))
    assert hide_obstacle(p, 0.3) == p
    with pytest.raises(SimulationError, match='unknown vegetation family'):
        draw_vegetation('jungle', np.random.default_rng(0))


def test_sloped_terrain_is_the_noise_on_a_plane():
    cfg = TerrainConfig(amplitude=0.03)
    flat = Terrain(cfg, np.random.default_rng(3), (-5, -5), (5, 5))
    slope = SlopedTerrain(cfg, np.random.default_rng(3), (-5, -5), (5, 5), 10.0, 0.5)
    xy = np.random.default_rng(4).uniform(-4.5, 4.5, (500, 2))
    plane = math.tan(math.radians(10.0)) * (xy @ np.array([math.cos(0.5), math.sin(0.5)]))
    np.testing.assert_allclose(slope.height(xy[:, 0], xy[:, 1]),
                               flat.height(xy[:, 0], xy[:, 1]) + plane, atol=1e-9)
    lo, hi = slope.z_range
    assert hi - lo > 2 * 4.5 * math.tan(math.radians(10.0))
    with pytest.raises(SimulationError, match='slope'):
        SlopedTerrain(cfg, np.random.default_rng(0), (-1, -1), (1, 1), 60.0)


def test_the_view_region_follows_the_slope():
    """Rays from the sensor through the column, followed to a 12 degree slope: where they are
    within the layer above it lies inside the region, and the flat region would miss some."""
    sources = np.array([[-9.0, 0.0, 6.0]])
    lo, hi = np.array([-0.8, -0.8, -1.0]), np.array([0.8, 0.8, 2.0])
    g = math.tan(math.radians(12.0))
    grade = np.array([-g, 0.0])  # falling away from the sensor: long grazing paths
    region = view_region(sources, lo, hi, -0.06, 0.5, 0.0, grade=grade)
    flat = view_region(sources, lo, hi, -0.06, 0.5, 0.0)
    from landing_zone.tools.sim.grass import points_in_polygon
    rng = np.random.default_rng(0)
    target = rng.uniform(lo, hi, (20000, 3))
    d = target - sources[0]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t = np.linspace(0.0, 30.0, 3001)
    pts = sources[0] + t[None, :, None] * d[:, None, :]
    ground = pts[..., 0] * grade[0] + pts[..., 1] * grade[1]
    layer = (pts[..., 2] >= ground - 0.06) & (pts[..., 2] <= ground + 0.5)
    inside = pts[layer][:, :2]
    assert points_in_polygon(inside, region).mean() > 0.999
    assert points_in_polygon(inside, flat).mean() < 0.99
