"""Worlds: terrain, grass, the obstacle library, ray casting and simulated patches."""
from __future__ import annotations

import math

import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.grass import GrassConfig, grass_mesh, points_in_polygon
from landing_zone.tools.sim.mesh import GRASS, GROUND, OBSTACLE, Mesh
from landing_zone.tools.sim.library import (MAX_ACROSS, MAX_HEIGHT, MIN_HEIGHT, get_model, library,
                                            models)
from landing_zone.tools.sim.obstacles import place
from landing_zone.tools.sim.raycast import RayCaster, embree_library_path
from landing_zone.tools.sim.scene import PatchConfig, simulate_patch, view_region
from landing_zone.tools.sim.sensor import SensorConfig, ray_box_interval
from landing_zone.tools.sim.terrain import PerlinNoise, Terrain, TerrainConfig


def test_perlin_noise_is_smooth_bounded_and_seeded():
    noise = PerlinNoise(np.random.default_rng(0), wavelength=2.0, octaves=3)
    x, y = np.meshgrid(np.linspace(-10, 10, 401), np.linspace(-10, 10, 401))
    n = noise(x, y)
    assert n.min() >= -1.0 and n.max() <= 1.0
    assert n.std() > 0.1  # not flat
    # Smooth: neighbours 5 cm apart differ by far less than the range.
    assert np.abs(np.diff(n, axis=1)).max() < 0.2
    again = PerlinNoise(np.random.default_rng(0), wavelength=2.0, octaves=3)(x, y)
    np.testing.assert_array_equal(n, again)
    other = PerlinNoise(np.random.default_rng(1), wavelength=2.0, octaves=3)(x, y)
    assert not np.allclose(n, other)


def test_terrain_heights_within_amplitude_and_on_the_mesh(rng):
    terrain = Terrain(TerrainConfig(amplitude=0.05), rng, (-3.0, -2.0), (3.0, 2.0))
    lo, hi = terrain.z_range
    assert -0.05 <= lo < 0 < hi <= 0.05
    assert hi - lo > 0.03  # uses the range
    # height() interpolates on the very triangles rays hit.
    caster = RayCaster(terrain.mesh(), threads=1)
    xy = rng.uniform([-2.9, -1.9], [2.9, 1.9], (500, 2))
    o = np.column_stack([xy, np.full(500, 5.0)])
    hits = caster.cast(o, np.tile([0.0, 0.0, -1.0], (500, 1)))
    assert np.all(hits.label == GROUND)
    np.testing.assert_allclose(5.0 - hits.t, terrain.height(xy[:, 0], xy[:, 1]), atol=2e-5)


def test_grass_blades_follow_their_distributions(rng):
    terrain = Terrain(TerrainConfig(amplitude=0.0), rng, (-3.0, -3.0), (3.0, 3.0))
    cfg = GrassConfig(density=800.0, blade_width=0.008, height_mean=0.3, height_cv=0.2,
                      inclination_std=10.0)
    square = np.array([[-2.0, -2.0], [2.0, -2.0], [2.0, 2.0], [-2.0, 2.0]])
    mesh = grass_mesh(cfg, terrain, rng, square)
    assert np.all(mesh.labels == GRASS)
    blades = mesh.vertices.reshape(-1, 5, 3).astype(float)
    n = len(blades)
    # Poisson count over 16 m^2: mean 12800, standard deviation 113.
    assert abs(n - 12800) < 5 * 113
    base = 0.5 * (blades[:, 0] + blades[:, 1])
    assert np.all(np.abs(base[:, :2]) <= 2.0)
    width = np.linalg.norm(blades[:, 1] - blades[:, 0], axis=1)
    np.testing.assert_allclose(width, 0.008, rtol=1e-4)  # float32 vertices
    height = blades[:, 4, 2] - base[:, 2]
    assert height.mean() == pytest.approx(0.3, rel=0.02)
    assert height.std() == pytest.approx(0.06, rel=0.1)
    lean = blades[:, 4] - blades[:, 2]
    incl = np.degrees(np.arccos(lean[:, 2] / np.linalg.norm(lean, axis=1)))
    # |N(0, 10 deg)| has mean 10 * sqrt(2 / pi) = 7.98 deg.
    assert incl.mean() == pytest.approx(7.98, rel=0.05)
    # Positions are homogeneous: each quadrant holds a quarter.
    quadrant = (base[:, 0] > 0).astype(int) * 2 + (base[:, 1] > 0)
    np.testing.assert_allclose(np.bincount(quadrant) / n, 0.25, atol=0.02)
    # Three triangles per blade, none degenerate.
    assert mesh.n_faces == 3 * n
    assert np.all(np.linalg.norm(mesh.face_normals(), axis=1) > 0.99)


def test_points_in_polygon(rng):
    tri = np.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]])
    p = rng.uniform(-0.5, 1.5, (1000, 2))
    inside = points_in_polygon(p, tri)
    np.testing.assert_array_equal(inside, (p[:, 0] >= 0) & (p[:, 1] >= 0)
                                  & (p[:, 0] + p[:, 1] <= 1))


def test_library_shapes_are_distinct_and_within_limits():
    lib = library()
    assert len([m for m in lib.values() if m.kind == 'rock']) >= 11
    assert {m.kind for m in lib.values()} == {'box', 'rock', 'tire', 'cinder_block'}
    synth2 = [m for m in lib.values() if m.kind != 'box']
    for m in lib.values():
        mesh = trimesh.Trimesh(m.vertices, m.faces, process=False)
        assert mesh.volume > 0, m.name  # closed, outward faces
        assert m.vertices[:, 2].min() == pytest.approx(0.0, abs=1e-9)
    for m in synth2:
        assert MIN_HEIGHT - 1e-9 <= m.size[2] <= MAX_HEIGHT + 1e-9, m.name
        assert m.across < MAX_ACROSS, m.name
    np.testing.assert_allclose(lib['box'].size, 0.15)
    # Distinct, also up to rotation: the principal extents of their surfaces (square roots
    # of the covariance eigenvalues) and their volumes differ by more than 5% for every pair;
    # and in their own frames the surfaces lie apart (mean nearest distance over 5% of the
    # size).
    shape, samples = {}, {}
    for m in synth2:
        mesh = trimesh.Trimesh(m.vertices, m.faces, process=False)
        pts = trimesh.sample.sample_surface_even(mesh, 800, seed=0)[0]
        samples[m.name] = pts
        axes = np.sqrt(np.sort(np.linalg.eigvalsh(np.cov(pts.T)))[::-1])
        shape[m.name] = np.append(axes, mesh.volume ** (1 / 3))
    names = list(shape)
    for i, a in enumerate(names):
        for b in names[i + 1:]:
            rel = np.abs(shape[a] - shape[b]) / np.maximum(shape[a], shape[b])
            assert rel.max() > 0.05, (a, b, rel)
            d_ab = cKDTree(samples[b]).query(samples[a])[0].mean()
            d_ba = cKDTree(samples[a]).query(samples[b])[0].mean()
            size = 0.5 * (lib[a].size[2] + lib[b].size[2])
            assert max(d_ab, d_ba) > 0.05 * size, (a, b)


def test_library_shapes_look_like_their_names():
    lib = library()
    # A cinder block is hollow: a vertical ray through a core of the standing block passes
    # through, one through its wall hits the top.
    block = lib['cinder_block_a']
    caster = RayCaster(Mesh.from_arrays(block.vertices, block.faces, OBSTACLE), threads=1)
    hits = caster.cast(np.array([[-0.09, 0.0, 1.0], [-0.18, 0.0, 1.0]]),
                       np.array([[0.0, 0.0, -1.0]] * 2))
    assert not hits.hit[0] and hits.hit[1]
    # A tire has a hole in the middle (seen along its axis) and a round outline.
    tire = lib['tire_b']
    caster = RayCaster(Mesh.from_arrays(tire.vertices, tire.faces, OBSTACLE), threads=1)
    hits = caster.cast(np.array([[0.0, 0.0, 1.0], [0.16, 0.0, 1.0]]),
                       np.array([[0.0, 0.0, -1.0]] * 2))
    assert not hits.hit[0] and hits.hit[1]
    r = np.hypot(tire.vertices[:, 0], tire.vertices[:, 1])
    assert r.max() == pytest.approx(0.235, abs=0.005)
    upright = lib['tire_a']
    assert upright.size[2] > 3 * upright.size[1]  # standing on its tread
    # Rocks are compact, closed and convex-ish: most of their hull's volume is rock.
    for m in models(('rock',)):
        mesh = trimesh.Trimesh(m.vertices, m.faces, process=False)
        assert 0.75 < mesh.volume / mesh.convex_hull.volume < 1.0


def test_obstacle_groups_are_disjoint():
    train = {m.name for m in models(('rock', 'tire', 'cinder_block'), 'train')}
    test = {m.name for m in models(('rock', 'tire', 'cinder_block'), 'test')}
    assert not train & test
    assert train | test == {m.name for m in library().values() if m.kind != 'box'}
    for group in (train, test):
        kinds = {get_model(n).kind for n in group}
        assert kinds == {'rock', 'tire', 'cinder_block'}
    with pytest.raises(SimulationError, match='unknown obstacle kind'):
        models(('boulder',))


def test_placed_obstacle_rests_on_the_ground(rng):
    terrain = Terrain(TerrainConfig(amplitude=0.05), rng, (-2.0, -2.0), (2.0, 2.0))
    m = get_model('cinder_block_a')
    ob = place(m, 0.3, -0.2, 0.7, terrain)
    v = ob.vertices()
    ground = terrain.height(v[:, 0], v[:, 1])
    bottom = v[:, 2] < v[:, 2].min() + 1e-9
    # Its base touches the ground and nowhere floats above it ...
    assert np.min(v[bottom, 2] - ground[bottom]) <= 1e-9
    assert np.all(v[bottom, 2] <= ground[bottom] + 1e-9)
    # ... and its footprint is turned by its yaw.
    fp = ob.footprint()
    assert fp.shape[1] == 2 and len(fp) >= 4
    extent = np.ptp(fp, axis=0)
    c, s = abs(math.cos(0.7)), abs(math.sin(0.7))
    np.testing.assert_allclose(extent, [0.39 * c + 0.19 * s, 0.39 * s + 0.19 * c], atol=1e-6)


@pytest.mark.skipif(embree_library_path() is None, reason='embreex ships no Embree library')
def test_embree_backends_agree(rng):
    terrain = Terrain(TerrainConfig(amplitude=0.05), rng, (-3.0, -3.0), (3.0, 3.0))
    grass = grass_mesh(GrassConfig(density=500.0), terrain, rng,
                       np.array([[-2.0, -2.0], [2.0, -2.0], [2.0, 2.0], [-2.0, 2.0]]))
    mesh = Mesh.concat([terrain.mesh(), grass])
    o = np.tile([-4.0, 0.0, 3.0], (3000, 1))
    target = np.column_stack([rng.uniform(-2, 2, (3000, 2)), np.zeros(3000)])
    d = target - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    a = RayCaster(mesh, threads=1, backend='embree')
    b = RayCaster(mesh, backend='embreex')
    assert a.backend == 'embree' and b.backend == 'embreex'
    ha, hb = a.cast(o, d), b.cast(o, d)
    np.testing.assert_array_equal(ha.face, hb.face)
    np.testing.assert_allclose(ha.t, hb.t, atol=1e-5)
    assert 0.05 < np.mean(ha.label == GRASS) < 0.95
    # t_max: nothing beyond the maximum range.
    short = a.cast(o, d, t_max=4.0)
    assert not np.any(short.hit & (ha.t > 4.0))


def test_raycast_exact_on_a_triangle():
    mesh = Mesh.from_arrays(np.array([[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0]]),
                            np.array([[0, 1, 2]]), GROUND)
    caster = RayCaster(mesh, threads=1)
    o = np.array([[0.5, 0.5, 3.0], [1.5, 1.5, 3.0], [0.2, 0.3, -1.0]])
    d = np.array([[0.0, 0.0, -1.0], [0.0, 0.0, -1.0], [0.0, 0.0, -1.0]])
    h = caster.cast(o, d)
    np.testing.assert_array_equal(h.face, [0, -1, -1])
    assert h.t[0] == pytest.approx(3.0, abs=1e-6)
    assert np.isinf(h.t[1]) and h.label[1] == 255
    empty = RayCaster(Mesh.empty()).cast(o, d)
    assert not empty.hit.any()


def test_view_region_contains_every_ray_through_the_column(rng):
    src = np.array([[-10.0, 0.0, 4.0]])
    lo, hi = np.array([-0.8, -0.8, -1.0]), np.array([0.8, 0.8, 2.0])
    poly = view_region(src, lo, hi, -0.05, 0.6)
    # Rays to random points of the box, followed into the layer -0.05 < z < 0.6.
    target = rng.uniform(lo, hi, (5000, 3))
    d = target - src
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    for z in (-0.05, 0.0, 0.3, 0.6):
        t = (z - src[0, 2]) / d[:, 2]
        p = src[0, :2] + t[:, None] * d[:, :2]
        assert np.all(points_in_polygon(p, poly + np.sign(poly) * 1e-9))


def test_patch_keeps_only_rays_through_the_column_and_labels_obstacles():
    cfg = PatchConfig(grass=GrassConfig(density=300.0), obstacle='rock_05',
                      sensor=SensorConfig(target_density=1500.0))
    patch = simulate_patch(cfg, np.random.default_rng(11))
    assert patch.label == 0
    r = patch.scan.returns
    lo, hi = cfg.column
    o, v = r.origins, r.points - r.origins
    length = np.linalg.norm(v, axis=1)
    t_in, t_out = ray_box_interval(o, v / length[:, None], lo, hi)
    assert np.all((t_in <= t_out) & (t_in <= length + 1e-9))
    # Some rays pass above the tile and land beyond the column: their returns are kept.
    assert np.any(r.points[:, 0] > hi[0] + 0.5)
    # The obstacle lies fully inside the tile, and its returns come from it.
    fp = patch.obstacle.footprint()
    assert np.all(np.abs(fp) < 0.5)
    ob = r.points[r.labels == OBSTACLE]
    assert len(ob) > 20
    # (within the range noise of the footprint: 3 sigma = 7.5 cm)
    assert np.all(points_in_polygon(ob[:, :2], _dilate(fp, 0.08)))
    safe = simulate_patch(PatchConfig(grass=GrassConfig(density=300.0),
                                      sensor=SensorConfig(target_density=500.0)),
                          np.random.default_rng(11))
    assert safe.label == 1 and not np.any(safe.scan.returns.labels == OBSTACLE)


def test_same_rng_same_patch():
    cfg = PatchConfig(grass=GrassConfig(density=400.0), obstacle='tire_a',
                      sensor=SensorConfig(target_density=800.0))
    a = simulate_patch(cfg, np.random.default_rng(4)).scan.returns
    b = simulate_patch(cfg, np.random.default_rng(4)).scan.returns
    np.testing.assert_array_equal(a.points, b.points)
    np.testing.assert_array_equal(a.line_origins, b.line_origins)
    c = simulate_patch(cfg, np.random.default_rng(5)).scan.returns
    assert len(c) != len(a) or not np.array_equal(c.points, a.points)


def _dilate(polygon, r):
    from scipy.spatial import ConvexHull
    ang = np.linspace(0, 2 * np.pi, 32, endpoint=False)
    pts = (polygon[:, None] + r * np.stack([np.cos(ang), np.sin(ang)], 1)[None]).reshape(-1, 2)
    return pts[ConvexHull(pts).vertices]


@pytest.mark.parametrize('kwargs,match', [
    ({'grass': GrassConfig(density=-10.0)}, 'density'),
    ({'grass': GrassConfig(blade_width=0.0)}, 'blade_width'),
    ({'sensor': SensorConfig(angular_resolution=0.0)}, 'angular_resolution'),
    ({'obstacle': 'boulder_9'}, 'unknown obstacle model'),
    ({'obstacle': 'rock_05', 'tile_size': 0.4}, 'does not fit'),
    ({'sensor_height': 1.0}, 'sensor_height'),
    ({'terrain': TerrainConfig(amplitude=float('nan'))}, 'amplitude'),
])
def test_nonsensical_patches_raise_before_any_work(kwargs, match, monkeypatch):
    import landing_zone.tools.sim.scene as scene
    calls = []
    monkeypatch.setattr(scene, 'Terrain', lambda *a, **k: calls.append(a))
    with pytest.raises(SimulationError, match=match):
        simulate_patch(PatchConfig(**kwargs), np.random.default_rng(0))
    assert not calls
