"""Physics of the simulated scanner: density, range noise, occlusion, wander, scan geometry."""
from __future__ import annotations

import math

import numpy as np
import pytest

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.grass import GrassConfig
from landing_zone.tools.sim.mesh import GRASS, GROUND, OBSTACLE
from landing_zone.tools.sim.library import get_model
from landing_zone.tools.sim.obstacles import place
from landing_zone.tools.sim.scene import PatchConfig, World, simulate_patch
from landing_zone.tools.sim.hover import hover_scan
from landing_zone.tools.sim.sensor import (BrownianWalk, SensorConfig, direction_angles, path_scan,
                                           ray_box_interval, scan_directions)
from landing_zone.tools.sim.terrain import Terrain, TerrainConfig

AOI = (np.array([-0.5, -0.5]), np.array([0.5, 0.5]))
COLUMN = (np.array([-0.8, -0.8, -1.0]), np.array([0.8, 0.8, 2.0]))


def flat_world(rng, obstacles=(), lo=(-8.0, -8.0), hi=(25.0, 8.0)):
    terrain = Terrain(TerrainConfig(amplitude=0.0), rng, lo, hi)
    from landing_zone.tools.sim.mesh import Mesh
    return World(terrain, Mesh.empty(), list(obstacles))


def test_directions_round_trip(rng):
    theta = rng.uniform(-0.8, 0.8, 100)
    phi = rng.uniform(-1.2, 1.2, 100)
    for heading in (0.0, 0.7, -2.5):
        d = scan_directions(theta, phi, heading)
        np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, atol=1e-12)
        t2, p2 = direction_angles(d, heading)
        np.testing.assert_allclose(t2, theta, atol=1e-12)
        np.testing.assert_allclose(p2, phi, atol=1e-12)
    # phi = 0 is the nadir plane; positive phi leans forward (+x at heading 0).
    np.testing.assert_allclose(scan_directions(0.0, 0.0), [0.0, 0.0, -1.0], atol=1e-15)
    assert scan_directions(0.0, 0.3)[0] > 0


def test_ray_box_interval_matches_brute_force(rng):
    lo, hi = np.array([-1.0, -0.5, 0.0]), np.array([1.0, 0.5, 2.0])
    o = rng.uniform(-4, 4, (2000, 3))
    d = rng.standard_normal((2000, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    t_in, t_out = ray_box_interval(o, d, lo, hi)
    ts = np.linspace(0, 12, 6001)
    pts = o[:, None] + ts[None, :, None] * d[:, None]
    inside = np.all((pts >= lo) & (pts <= hi), axis=2)
    brute = inside.any(axis=1)
    analytic = t_in <= t_out
    # Sampling misses only grazing rays shorter than a step: compare away from those.
    assert np.mean(brute == analytic) > 0.995
    first = np.where(brute, ts[np.argmax(inside, axis=1)], np.nan)
    ok = brute & analytic
    assert np.all(np.abs(first[ok] - t_in[ok]) <= 2.5e-3)


def test_density_reaches_target_uniformly(rng):
    world = flat_world(rng)
    sensor = SensorConfig(target_density=2000.0)
    scan = hover_scan(world.caster(1), sensor, np.array([-5.0, 0.0, 4.0]), *AOI, *COLUMN, rng)
    pts = scan.returns.points
    in_aoi = np.all((pts[:, :2] >= -0.5) & (pts[:, :2] < 0.5), axis=1)
    density = in_aoi.sum() / 1.0
    assert abs(density - 2000.0) / 2000.0 < 0.10
    assert scan.density == pytest.approx(density)
    # The whole tile is covered: every 10 cm cell holds returns, none holds a multiple of
    # the mean (no holes, no stripe of doubled density).
    cells = np.floor((pts[in_aoi, :2] + 0.5) / 0.1).astype(int)
    counts = np.bincount(cells[:, 0] * 10 + cells[:, 1], minlength=100)
    assert counts.min() > 0.5 * counts.mean()
    assert counts.max() < 1.6 * counts.mean()
    # Scanning took several nod sweeps, as configured.
    assert scan.sweeps >= sensor.sweeps_per_target


def test_density_holds_for_other_targets_and_resolutions(rng):
    world = flat_world(rng)
    for target, res, pos in ((1000.0, 0.41, (-10.0, 0.0, 8.0)), (4000.0, 0.05, (-5.0, 0, 8.0))):
        sensor = SensorConfig(target_density=target, angular_resolution=res)
        scan = hover_scan(world.caster(1), sensor, np.array(pos), *AOI, *COLUMN, rng)
        assert abs(scan.density - target) / target < 0.10


def test_range_noise_statistics(rng):
    world = flat_world(rng)
    sensor = SensorConfig(target_density=3000.0)
    scan = hover_scan(world.caster(1), sensor, np.array([-5.0, 0.0, 4.0]), *AOI, *COLUMN, rng)
    r = scan.returns
    assert np.all(r.labels == GROUND)
    o = r.origins
    v = r.points - o
    measured = np.linalg.norm(v, axis=1)
    d = v / measured[:, None]
    true = (0.0 - o[:, 2]) / d[:, 2]  # the flat ground is the plane z = 0
    err = measured - true
    assert len(err) > 5000
    assert abs(err.mean()) < 0.002
    assert err.std() == pytest.approx(0.025, rel=0.06)
    # Noise lies along the ray: the measured point is exactly on the pulse's line.
    assert np.all(np.isfinite(err))


def test_box_occludes_the_ground_behind_it(rng):
    terrain_rng = np.random.default_rng(1)
    world = flat_world(terrain_rng)
    box = place(get_model('box'), 0.0, 0.0, 0.0, world.terrain)
    world_box = flat_world(np.random.default_rng(1), [box])
    sensor = SensorConfig(target_density=3000.0, wander_sigma=0.0)
    pos = np.array([-5.0, 0.0, 4.0])
    scan = hover_scan(world_box.caster(1), sensor, pos, *AOI, *COLUMN, rng)
    r = scan.returns
    hit_box = r.labels == OBSTACLE
    assert hit_box.sum() > 100
    # Each box return lies (within the range noise) where its ray first enters the box, and
    # that is on a face the sensor sees: the front (x = -0.075) or the top (z = 0.15).
    o, v = r.origins[hit_box], r.points[hit_box] - r.origins[hit_box]
    rng_meas = np.linalg.norm(v, axis=1)
    d = v / rng_meas[:, None]
    t_in, t_out = ray_box_interval(o, d, np.array([-0.075, -0.075, 0.0]),
                                   np.array([0.075, 0.075, 0.15]))
    assert np.all(t_in <= t_out)
    assert np.all(np.abs(rng_meas - t_in) < 4 * 0.025)
    entry = o + t_in[:, None] * d
    on_front = np.abs(entry[:, 0] + 0.075) < 1e-6
    on_top = np.abs(entry[:, 2] - 0.15) < 1e-6
    assert np.all(on_front | on_top)
    assert on_front.sum() > 20 and on_top.sum() > 20
    # No ground return's ray passes through the box (shrunk by the range noise margin).
    ground = r.labels == GROUND
    o, p = r.origins[ground], r.points[ground]
    seg = p - o
    length = np.linalg.norm(seg, axis=1)
    t_in, t_out = ray_box_interval(o, seg / length[:, None],
                                   np.array([-0.065, -0.065, 0.0]),
                                   np.array([0.065, 0.065, 0.14]))
    assert not np.any((t_in <= t_out) & (t_in < length - 0.1))
    # ... while without the box the same sensor puts plenty of returns in that shadow.
    open_scan = hover_scan(world.caster(1), sensor, pos, *AOI, *COLUMN,
                           np.random.default_rng(5))
    q = open_scan.returns.points
    o2 = open_scan.returns.origins
    v2 = q - o2
    l2 = np.linalg.norm(v2, axis=1)
    t_in, t_out = ray_box_interval(o2, v2 / l2[:, None], np.array([-0.065, -0.065, 0.0]),
                                   np.array([0.065, 0.065, 0.14]))
    shadowed = (t_in <= t_out) & (t_in < l2 - 0.1)
    assert shadowed.sum() > 50


def test_grass_raises_the_share_of_returns_above_ground():
    shares = []
    for density in (100.0, 600.0, 1500.0):
        cfg = PatchConfig(grass=GrassConfig(density=density, height_mean=0.2),
                          sensor=SensorConfig(target_density=1000.0))
        patch = simulate_patch(cfg, np.random.default_rng(7))
        r = patch.scan.returns
        tile = np.all(np.abs(r.points[:, :2]) < 0.5, axis=1)
        ground = patch.world.terrain.height(r.points[tile, 0], r.points[tile, 1])
        above = r.points[tile, 2] - ground > 0.05
        shares.append(above.mean())
        # The labels agree with the heights: grass returns are mostly above the ground.
        assert np.mean(r.labels[tile][above] == GRASS) > 0.8
    assert shares[0] < shares[1] < shares[2]
    assert shares[2] > 3 * shares[0]


def test_origin_wanders_like_brownian_motion():
    rng = np.random.default_rng(3)
    finals = []
    for _ in range(400):
        walk = BrownianWalk(0.02, rng)
        finals.append(walk.at(np.linspace(0.1, 4.0, 40))[-1])
    finals = np.array(finals)
    # After 4 s the per-axis standard deviation is 2 cm * sqrt(4) = 4 cm.
    assert finals.std(axis=0) == pytest.approx([0.04] * 3, rel=0.15)
    assert np.all(np.abs(finals.mean(axis=0)) < 0.01)
    bounded = BrownianWalk(0.5, rng, bound=0.1).at(np.linspace(0.1, 20, 200))
    assert np.abs(bounded).max() <= 0.1


def test_returns_keep_origin_and_time(rng):
    world = flat_world(rng)
    sensor = SensorConfig(target_density=500.0)
    scan = hover_scan(world.caster(1), sensor, np.array([-5.0, 0.0, 4.0]), *AOI, *COLUMN, rng)
    r = scan.returns
    assert len(r.line_origins) == len(r.line_times) == r.line.max() + 1
    # Time order, and every pulse within its line's period.
    assert np.all(np.diff(r.times) >= 0)
    dt = r.times - r.line_times[r.line]
    assert np.all((dt >= 0) & (dt < sensor.line_period))
    # Origins wander near the nominal position.
    assert np.all(np.linalg.norm(r.line_origins - [-5.0, 0.0, 4.0], axis=1) < 0.5)
    assert scan.duration > 0


def test_path_scan_covers_the_swath(rng):
    world = flat_world(rng, lo=(-10.0, -15.0), hi=(15.0, 15.0))
    sensor = SensorConfig(angular_resolution=0.5, prr=50_000.0)

    def trajectory(t):
        pos = np.stack([-5.0 + 4.0 * t, np.zeros_like(t), np.full_like(t, 8.0)], axis=1)
        return pos, np.zeros_like(t)

    parts = path_scan(world.caster(1), sensor, trajectory, 0.0, 1.0, math.radians(30.0), rng,
                      lines_per_chunk=50)
    pts = np.concatenate([p.points for p in parts])
    # Scan lines cross the flight direction: the swath spans +-8 tan(50 deg) / cos(30 deg)
    # metres in y; each line lands 8 tan(30 deg) m ahead of the sensor.
    half = 8.0 / math.cos(math.radians(30.0)) * math.tan(math.radians(50.0))
    assert pts[:, 1].max() == pytest.approx(half, rel=0.05)
    assert pts[:, 1].min() == pytest.approx(-half, rel=0.05)
    x_expected = -5.0 + 8.0 * math.tan(math.radians(30.0))
    centre = np.abs(pts[:, 1]) < 0.1
    assert pts[centre, 0].min() == pytest.approx(x_expected, abs=0.1)
    intensity = np.concatenate([p.intensity for p in parts])
    assert intensity.min() >= 0 and intensity.max() <= 1 and intensity.mean() > 0.1


@pytest.mark.parametrize('field,value', [
    ('angular_resolution', 0.0), ('angular_resolution', -0.1), ('prr', 0.0),
    ('fov_horizontal', 120.0), ('fov_vertical', 101.0), ('range_sigma', -0.01),
    ('target_density', -5.0), ('target_density', float('nan')), ('nod_rate', 0.0),
    ('sweeps_per_target', 0)])
def test_bad_sensor_parameters_raise(field, value):
    with pytest.raises(SimulationError, match=field):
        SensorConfig(**{field: value}).validate()


def test_hover_scan_needs_the_nodding_mount(rng):
    world = flat_world(rng)
    with pytest.raises(SimulationError, match='fov_vertical'):
        hover_scan(world.caster(1), SensorConfig(fov_vertical=0.0), np.array([-5.0, 0.0, 4.0]),
                   *AOI, *COLUMN, rng)


def test_hidden_area_is_an_error(rng):
    world = flat_world(rng)
    # Looking at the tile from below the ground: nothing in view.
    with pytest.raises(SimulationError):
        hover_scan(world.caster(1), SensorConfig(), np.array([-5.0, 0.0, -4.0]), *AOI,
                   *COLUMN, rng)
