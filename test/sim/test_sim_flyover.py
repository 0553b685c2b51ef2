"""Patches scanned in passing: every pattern meets the density, keeps only rays through the
column, culls exactly (nothing that reaches the column is dropped), same seed same returns."""
from __future__ import annotations

import numpy as np
import pytest

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.flyover import Flyover, _culled, flyover_scan, plan_flyover
from landing_zone.tools.sim.grass import GrassConfig, grass_mesh
from landing_zone.tools.sim.scene import World
from landing_zone.tools.sim.sensor import ScanPattern, SensorConfig, ray_box_interval
from landing_zone.tools.sim.terrain import Terrain, TerrainConfig

AOI = (np.array([-0.5, -0.5]), np.array([0.5, 0.5]))
BOX = (np.array([-0.8, -0.8, -1.0]), np.array([0.8, 0.8, 2.0]))
PASSES = [
    ('line', 45.0, 300_000.0, {}),
    ('spinning', 45.0, 600_000.0, {'beams': 16}),
    ('rosette', 20.0, 100_000.0, {}),
    ('elliptical', 15.0, 200_000.0, {'fov': 40.0, 'spin_rate': 25.0}),
]


@pytest.fixture(scope='module')
def caster():
    rng = np.random.default_rng(0)
    terrain = Terrain(TerrainConfig(), rng, (-14.0, -14.0), (14.0, 14.0))
    square = np.array([[-3.0, -3.0], [3.0, -3.0], [3.0, 3.0], [-3.0, 3.0]])
    grass = grass_mesh(GrassConfig(density=300, height_mean=0.2), terrain, rng, square)
    return World(terrain, grass).caster(1)


@pytest.mark.parametrize('kind,tilt,prr,extra', PASSES)
def test_every_pattern_meets_the_density_through_the_column(caster, kind, tilt, prr, extra):
    sensor = SensorConfig(prr=prr, target_density=2000.0)
    fly = Flyover(ScanPattern(kind, **extra), 6.0, tilt, cross=1.5, heading=0.6)
    plan = plan_flyover(sensor, fly, *AOI, *BOX)
    scan = flyover_scan(caster, sensor, fly, plan, *AOI, *BOX, np.random.default_rng(1))
    r = scan.returns
    assert abs(scan.density - 2000.0) / 2000.0 < 0.25, (kind, scan.density)
    # Every kept return's ray reaches the column before (or where) it ends.
    d = r.points - r.origins
    t_end = np.linalg.norm(d, axis=1)
    t_in, t_out = ray_box_interval(r.origins, d / t_end[:, None], *BOX)
    assert np.all(t_in <= np.minimum(t_out, t_end) + 1e-6)
    # The origins lie on the pass, height above the ground, `cross` to the tile's left.
    along = np.array([np.cos(0.6), np.sin(0.6)])
    left = np.array([-np.sin(0.6), np.cos(0.6)])
    np.testing.assert_allclose(r.line_origins[:, 2], 6.0, atol=plan.wander)  # its walk
    np.testing.assert_allclose(r.line_origins[:, :2] @ left, 1.5, atol=plan.wander)
    assert np.all(np.diff(r.line_origins[:, :2] @ along) > 0)  # flying forwards
    assert np.all(np.diff(r.times) >= 0) and scan.speed > 0
    again = flyover_scan(caster, sensor, fly, plan, *AOI, *BOX, np.random.default_rng(1))
    np.testing.assert_array_equal(again.returns.points, r.points)


@pytest.mark.parametrize('kind,tilt,prr,extra', PASSES)
def test_culling_keeps_every_pulse_that_reaches_the_column(kind, tilt, prr, extra):
    """Against every pulse of the window: the culled ones never pass through the box."""
    from landing_zone.tools.sim.flyover import _pattern_dirs
    sensor = SensorConfig(prr=prr, target_density=1500.0)
    fly = Flyover(ScanPattern(kind, **extra), 5.0, tilt, cross=-1.0, heading=2.0)
    plan = plan_flyover(sensor, fly, *AOI, *BOX)
    n = min(plan.n_pulses, 400_000)
    kept = _culled(fly, sensor, plan.start, plan.speed, n, *BOX, 0.0)
    every = np.arange(n)
    d = _pattern_dirs(fly, sensor, every / sensor.prr, every)
    along, _ = fly.axes()
    org = plan.start + (plan.speed * every / sensor.prr)[:, None] * along
    t_in, t_out = ray_box_interval(org, d, *BOX)
    through = np.flatnonzero(t_in <= t_out)
    assert len(through) > 100
    assert np.isin(through, kept).all()
    assert len(kept) < 0.7 * n or kind == 'line'  # and it does cull


def test_a_pass_that_cannot_see_the_patch_says_so():
    sensor = SensorConfig(prr=100_000.0, target_density=1000.0)
    fly = Flyover(ScanPattern('elliptical', fov=10.0), 5.0, 0.0, cross=30.0)
    with pytest.raises(SimulationError, match='puts no pulse through the patch'):
        plan_flyover(sensor, fly, *AOI, *BOX)
    with pytest.raises(SimulationError, match='flyover height'):
        plan_flyover(sensor, Flyover(ScanPattern('line'), 0.1, 45.0), *AOI, *BOX)
