"""Flights over other vegetation and with other scanners (stand-ins for real flights).

Each option changes the cloud as it should (clumps cluster the grass returns, tall blades reach
higher and lean, shrubs stand on the site as vegetation that rays partly pass through, other
scan patterns spread the view angles and still meet the target density), the defaults still
give what they gave before the options existed, and the same seed gives the same bytes.
"""
from __future__ import annotations

import json
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.flight import flight_config, simulate_flight
from landing_zone.tools.sim.flight_settings import SCAN, VEGETATION, FlightConfig
from landing_zone.tools.sim.flight_path import quaternion
from landing_zone.tools.sim.grass import (GrassConfig, VegetationConfig, bush_mesh, clumped_bases,
                                          grass_mesh, place_bushes, vegetation_blades)
from landing_zone.tools.sim.scene import PatchConfig, simulate_patch
from landing_zone.tools.sim.sensor import ScanPattern, SensorConfig, mount_frame
from landing_zone.tools.sim.terrain import Terrain, TerrainConfig

REPO = Path(__file__).resolve().parents[2]
# A small site and a cheap scanner: a flight takes about a second.
SMALL = dict(size=6.0, obstacles=2, height=5.0, seed=3, target_density=600.0,
             angular_resolution=0.2, prr=50_000.0)
SQUARE = np.array([[-2.0, -2.0], [2.0, -2.0], [2.0, 2.0], [-2.0, 2.0]])


@pytest.fixture(scope='module')
def flights(tmp_path_factory):
    """flights(vegetation, scan_pattern, **more) -> (bag, labels dict, points, labels, origins),
    each simulated once per module."""
    root = tmp_path_factory.mktemp('veg')
    cache = {}

    def get(vegetation='default', scan_pattern='line', **more):
        key = (vegetation, scan_pattern, tuple(sorted(more.items())))
        if key not in cache:
            cfg = flight_config(vegetation, scan_pattern, **{**SMALL, **more})
            out = root / f'{vegetation}_{scan_pattern}_{len(cache)}.mcap'
            result = simulate_flight(cfg, out)
            cache[key] = (result, json.loads(result.labels.read_text()), *_load(out))
        return cache[key]
    return get


def _load(bag: Path) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Points (N, 3), labels (N,) and the sensor origin of each point's cloud (N, 3)."""
    from landing_zone.io.bags import read_messages
    from msg_adapters.pointcloud import cloud_to_structured
    from msg_adapters.pose import pose_stamped_to_arrays
    poses, pts, lab, org = {}, [], [], []
    for m in read_messages(bag):
        if m.topic == '/lidar/pose':
            poses[m.stamp_ns] = pose_stamped_to_arrays(m.msg)[1]
        else:
            a = cloud_to_structured(m.msg)
            pts.append(np.stack([a['x'], a['y'], a['z']], axis=1).astype(float))
            lab.append(a['label'])
            org.append(np.repeat(poses[m.stamp_ns][None], len(a), axis=0))
    return np.concatenate(pts), np.concatenate(lab), np.concatenate(org)


def _on_site(points: np.ndarray, half: float = 3.0) -> np.ndarray:
    return np.all(np.abs(points[:, :2]) < half, axis=1)


def _variance_to_mean(xy: np.ndarray, half: float, cell: float) -> float:
    """Variance-to-mean ratio of the counts of points in square cells (1 for Poisson)."""
    n = int(round(2 * half / cell))
    k = np.floor((xy + half) / cell).astype(int)
    ok = np.all((k >= 0) & (k < n), axis=1)
    counts = np.bincount(k[ok, 0] * n + k[ok, 1], minlength=n * n)
    return float(counts.var() / counts.mean())


def _above_ground(points: np.ndarray, labels: np.ndarray, cell: float = 0.5) -> np.ndarray:
    """Height of each point above the median of the ground returns in its cell (nan: none)."""
    k = np.floor(points[:, :2] / cell).astype(np.int64)
    _, cell_of = np.unique(k[:, 0] * 100_000 + k[:, 1], return_inverse=True)
    ground = labels == 0
    med = np.full(cell_of.max() + 1, np.nan)
    order = np.argsort(cell_of[ground], kind='stable')
    gc, gz = cell_of[ground][order], points[ground, 2][order]
    bounds = np.flatnonzero(np.diff(gc)) + 1
    for ids, zs in zip(np.split(gc, bounds), np.split(gz, bounds)):
        med[ids[0]] = np.median(zs)
    return points[:, 2] - med[cell_of]


# --- defaults: what they gave before the options existed ---------------------------------------

def _default_flight(tmp_path: Path, name: str, **options):
    """The small default flight the figures below were taken from, with `options` spelled out."""
    cfg = flight_config(size=5.0, obstacles=1, height=5.0, seed=7, target_density=300.0,
                        angular_resolution=0.3, prr=30_000.0, **options)
    (tmp_path / name).mkdir()
    return simulate_flight(cfg, tmp_path / name / 'pin.mcap')


def test_defaults_are_what_they_were_before_the_options(tmp_path):
    """The vegetation and scan options left the defaults alone.

    On one machine: spelling the defaults out gives the very bytes of leaving them out. Across
    machines the bytes of float output differ (numpy's and Embree's SIMD paths round
    differently from one CPU to the next), so what is compared there is what the code before the
    options produced and any CPU must reproduce: the message counts, the ground truth, the
    blade mesh's topology and the return counts. A grazing ray may hit on one CPU and miss on
    another, so return counts get 0.5 % (about a hundred of 20,620 returns); the rest is exact.
    """
    cfg = FlightConfig(size=5.0, obstacles=1, height=5.0, seed=7,
                       sensor=SensorConfig(target_density=300.0, angular_resolution=0.3,
                                           prr=30_000.0))
    assert cfg == flight_config(size=5.0, obstacles=1, height=5.0, seed=7, target_density=300.0,
                                angular_resolution=0.3, prr=30_000.0)
    r = _default_flight(tmp_path, 'implicit')
    spelled = _default_flight(tmp_path, 'explicit', vegetation='default', scan_pattern='line')
    assert spelled.bag.read_bytes() == r.bag.read_bytes()
    assert spelled.labels.read_bytes() == r.labels.read_bytes()

    labels = json.loads(r.labels.read_text())
    assert labels['site']['vegetation'] == VegetationConfig().to_dict()
    assert labels['site']['scan_pattern']['kind'] == 'line' and labels['bushes'] == []
    assert len(labels['tiles']) == 36
    assert [(t['x'], t['y']) for t in labels['tiles'] if not t['safe']] == [(-0.5, -0.5)]
    (ob,) = labels['obstacles']
    assert (ob['kind'], ob['model']) == ('rock', 'rock_08')
    assert [ob['x'], ob['y'], ob['yaw']] == pytest.approx([-0.6106, -0.4069, 2.8655], abs=2e-4)
    assert ob['size'] == pytest.approx([0.2721, 0.2683, 0.17], abs=2e-4)
    pts, lab, _ = _load(r.bag)
    from landing_zone.io.bags import read_messages
    topics = [m.topic for m in read_messages(r.bag)]
    assert topics.count('/lidar/points') == topics.count('/lidar/pose') == 17
    counts = np.bincount(lab, minlength=3)
    assert len(pts) == pytest.approx(20_620, rel=0.005)
    assert counts[:2] == pytest.approx([18_774, 1_829], rel=0.005)
    assert 10 <= counts[2] <= 25  # 17 here: the rock is small and seen from one side

    rng = np.random.default_rng(3)
    terrain = Terrain(TerrainConfig(), rng, np.array([-1.0, -1.0]), np.array([1.0, 1.0]))
    m = grass_mesh(GrassConfig(density=300), terrain, rng, SQUARE / 2)
    assert m.vertices.shape == (6125, 3) and m.faces.shape == (3675, 3)
    assert int(m.faces.astype(np.int64).sum()) == 33_758_550  # the topology, exactly
    p = simulate_patch(PatchConfig(grass=GrassConfig(density=300),
                                   sensor=SensorConfig(target_density=500)),
                       np.random.default_rng(4))
    assert p.label == 1
    assert len(p.scan.returns.points) == pytest.approx(4_494, rel=0.005)
    labels_of_returns = np.bincount(p.scan.returns.labels, minlength=2)[:2]
    assert labels_of_returns == pytest.approx([3_729, 765], rel=0.005)


def test_same_seed_same_bytes_with_the_new_options(flights, tmp_path):
    result, _, _, _, _ = flights('mixed', 'spinning')
    cfg = flight_config('mixed', 'spinning', **SMALL)
    # Same file name: the bag's embedded metadata names its file.
    again = simulate_flight(cfg, tmp_path / result.bag.name)
    assert again.bag.read_bytes() == result.bag.read_bytes()
    assert again.labels.read_bytes() == result.labels.read_bytes()
    (tmp_path / 'other').mkdir()
    other = simulate_flight(replace(cfg, seed=4), tmp_path / 'other' / result.bag.name)
    assert other.bag.read_bytes() != result.bag.read_bytes()


def test_vegetation_changes_nothing_but_the_vegetation(flights):
    """Same seed: the same obstacles and tiles (and terrain) whatever the vegetation."""
    base = flights()[1]
    for name in ('clumped', 'tall', 'bushy'):
        labels = flights(name)[1]
        assert labels['obstacles'] == base['obstacles'] and labels['tiles'] == base['tiles']
        assert labels['site']['vegetation']['preset'] == name
        assert labels['flight']['vegetation'] == labels['site']['vegetation']


# --- vegetation -------------------------------------------------------------------------------

def test_clumps_cluster_the_blades_and_the_returns(flights):
    # The blade bases: a Thomas process is overdispersed, a Poisson one is not.
    rng = np.random.default_rng(0)
    xy, centre = clumped_bases(600.0, 100.0, 0.06, rng, SQUARE)
    assert len(xy) == pytest.approx(600 * 16, rel=0.15)
    assert np.all(np.abs(xy) <= 2.0)
    assert np.std(xy - centre) == pytest.approx(0.06, rel=0.1)
    assert _variance_to_mean(xy, 2.0, 0.2) > 20.0
    poisson = rng.uniform(-2.0, 2.0, (len(xy), 2))
    assert _variance_to_mean(poisson, 2.0, 0.2) == pytest.approx(1.0, abs=0.15)
    # The returns from grass: far more clustered than over the default grass of the same site.
    vmr = {}
    for name in ('default', 'clumped'):
        _, _, pts, lab, _ = flights(name)
        grass = _on_site(pts) & (lab == 1)
        vmr[name] = _variance_to_mean(pts[grass, :2], 3.0, 0.2)
    assert vmr['clumped'] > 2.0 * vmr['default'] and vmr['clumped'] > 5.0


def test_tall_blades_reach_higher_lean_and_curve(flights):
    q = {}
    for name in ('default', 'tall'):
        _, _, pts, lab, _ = flights(name)
        grass = _on_site(pts) & (lab == 1)
        h = _above_ground(pts, lab)[grass]
        q[name] = np.nanquantile(h, [0.5, 0.9, 1.0])
    assert q['tall'][2] > 0.35 and q['tall'][1] > q['default'][1] + 0.07
    assert q['tall'][0] > q['default'][0] + 0.05
    # The blades themselves: tips at most 0.45 m above their bases, leaning about 30 degrees
    # (half-normal: mean 30 * sqrt(2 / pi)), the tip piece leaning more than the lowest one.
    veg = VegetationConfig(**{k: v for k, v in VEGETATION['tall'].items()
                              if k != 'grass_height'})
    rng = np.random.default_rng(1)
    terrain = Terrain(TerrainConfig(amplitude=0.0), rng, np.array([-3.0, -3.0]),
                      np.array([3.0, 3.0]))
    mesh = vegetation_blades(veg, 400.0, 0.38, terrain, rng, SQUARE)
    per = 2 * veg.segments + 1
    v = mesh.vertices.astype(float).reshape(-1, per, 3)
    joints = np.concatenate([0.5 * (v[:, 0:-1:2] + v[:, 1::2]), v[:, -1:]], axis=1)
    pieces = np.diff(joints, axis=1)
    incl = np.degrees(np.arccos(pieces[..., 2] / np.linalg.norm(pieces, axis=-1)))
    assert np.all(joints[:, -1, 2] - joints[:, 0, 2] <= 0.45 + 1e-5)
    assert np.mean(incl[:, -1]) == pytest.approx(30.0 * np.sqrt(2 / np.pi), rel=0.1)
    assert np.all(incl[:, -1] >= incl[:, 0] - 1e-3)
    assert np.mean(incl[:, -1] - incl[:, 0]) > 15.0


def test_bushes_are_soft_vegetation_on_safe_tiles(flights, tmp_path):
    result, labels, pts, lab, _ = flights('bushy')
    base = flights()[1]
    bushes = labels['bushes']
    assert len(bushes) >= 2
    assert labels['tiles'] == base['tiles']  # shrubs leave their tiles safe
    for b in bushes:
        assert 0.2 <= b['height'] <= 0.4 and 0.3 <= b['diameter'] <= 0.6
        for ob in labels['obstacles']:  # clear of the obstacles
            assert np.hypot(b['x'] - ob['x'], b['y'] - ob['y']) > 0.5 * b['diameter']
    h = _above_ground(pts, lab)
    seen = 0
    for b in bushes:
        inside = np.hypot(pts[:, 0] - b['x'], pts[:, 1] - b['y']) < 0.3 * b['diameter']
        if inside.sum() < 30:
            continue  # at the edge of the scanned area
        seen += 1
        assert not np.any(lab[inside] == 2)
        high = inside & (h > 0.1)  # well above the range noise of the ground returns
        assert np.mean(lab[high] == 1) > 0.95 and high.sum() > 10  # the canopy: vegetation
        assert np.nanmax(h[inside]) < b['height'] + 0.1
        # Rays pass partly through: the ground under the canopy is still seen.
        assert 0.03 < np.mean(lab[inside] == 0) < 0.9
    assert seen >= 2
    # The mesh of one bush: leaves in its canopy, as many as the leaf density asks for.
    veg = VegetationConfig(bush_density=1.0)
    rng = np.random.default_rng(2)
    terrain = Terrain(TerrainConfig(amplitude=0.0), rng, np.array([-3.0, -3.0]),
                      np.array([3.0, 3.0]))
    placed = place_bushes(veg, terrain, rng, SQUARE, keep_out=[(0.0, 0.0, 0.5)])
    assert len(placed) > 5
    assert all(np.hypot(b.x, b.y) > 0.5 + b.diameter / 2 for b in placed)
    mesh = bush_mesh(veg, placed[:1], rng)
    b = placed[0]
    tri = mesh.triangles()
    assert np.all(tri[..., 2] <= b.height + veg.leaf_size) and np.all(mesh.labels == 1)
    assert np.all(np.hypot(tri[..., 0] - b.x, tri[..., 1] - b.y) < b.diameter / 2 + 0.05)
    # A picture of the flight.
    from landing_zone.tools.sim.render import render
    png = render(result.bag, tmp_path / 'bushy.png')
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'


# --- scan patterns ----------------------------------------------------------------------------

@pytest.mark.parametrize('pattern,more', [('spinning', {}), ('rosette', {'max_speed': 30.0}),
                                          ('elliptical', {'max_speed': 30.0})])
def test_other_scanners_meet_the_density_and_look_differently(flights, pattern, more):
    result, labels, pts, lab, org = flights('default', pattern, **more)
    _, _, pts0, _, org0 = flights()
    assert labels['site']['scan_pattern']['kind'] == pattern
    on = _on_site(pts)
    density = on.sum() / 36.0
    assert density == pytest.approx(result.density)
    assert abs(density - 600.0) / 600.0 < 0.15
    # Every tile of the site seen.
    k = np.floor(pts[on, :2] + 3.0).astype(int)
    counts = np.bincount(k[:, 0] * 6 + k[:, 1], minlength=36)
    assert counts.min() > 0.3 * counts.mean()
    assert set(np.unique(lab)) == {0, 1, 2}

    # Along-track view angle from the nadir: the line scanner sees every return at its tilt,
    # the spinning one fans its beams +-15 degrees about it, the rosette spreads about 20.
    def along(p, o):
        d = p - o
        return np.degrees(np.arctan2(np.abs(d[:, 0]), -d[:, 2]))
    a0 = along(pts0, org0)[_on_site(pts0)]
    a = along(pts, org)[on]
    assert np.std(a0) < 2.0 and np.median(a0) == pytest.approx(45.0, abs=1.0)
    if pattern == 'spinning':
        assert np.std(a) > 6.0 and np.median(a) == pytest.approx(45.0, abs=6.0)
        assert np.quantile(a, 0.95) - np.quantile(a, 0.05) > 20.0
    elif pattern == 'elliptical':
        # A 40 degree cone about an axis 15 degrees forward: the ellipse's front and back arcs
        # see the ground from 35 and 5 degrees (its sides from between).
        assert np.quantile(a, 0.95) == pytest.approx(35.0, abs=3.0)
        assert np.quantile(a, 0.02) < 12.0 and np.std(a) > 6.0
    else:
        assert np.median(a) == pytest.approx(20.0, abs=6.0) and np.std(a) > 8.0
        # The rosette piles its returns up in petals: far from uniform over the site.
        assert _variance_to_mean(pts[on, :2], 3.0, 0.25) > 3.0 * _variance_to_mean(
            pts0[_on_site(pts0), :2], 3.0, 0.25)


def test_scan_pattern_geometry():
    # The pose's quaternion and the patterns' mount agree: x is the pattern's centre.
    from scipy.spatial.transform import Rotation
    for heading in (0.0, 0.7, np.pi):
        q = quaternion(np.array([heading]), np.radians(30.0))[0]
        np.testing.assert_allclose(Rotation.from_quat(q).as_matrix(),
                                   mount_frame(np.radians(30.0), heading)[0], atol=1e-12)
    spin = ScanPattern(kind='spinning', beams=16, beam_fov=30.0, spin_rate=10.0)
    t = np.arange(32000) / 320_000.0  # 0.1 s: one turn
    d = spin.local_directions(t, np.arange(len(t)))
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    elev = np.degrees(np.arcsin(d[:, 2]))
    np.testing.assert_allclose(np.unique(np.round(elev, 6)), np.linspace(-15, 15, 16),
                               atol=1e-6)
    az = np.arctan2(d[:, 1], d[:, 0])
    assert np.ptp(az) > 6.2  # the full circle
    ell = ScanPattern(kind='elliptical', fov=40.0, spin_rate=25.0)
    d = ell.local_directions(np.arange(4000) / 100_000.0, np.arange(4000))  # one turn
    np.testing.assert_allclose(np.degrees(np.arccos(d[:, 0])), 20.0, atol=1e-9)
    assert np.ptp(np.arctan2(d[:, 2], d[:, 1])) > 6.2
    rose = ScanPattern(kind='rosette', fov=70.0)
    d = rose.local_directions(np.arange(100_000) / 100_000.0, np.arange(100_000))
    off = np.degrees(np.arccos(np.clip(d[:, 0], -1, 1)))
    assert off.max() == pytest.approx(35.0, abs=0.1) and np.median(off) < 30.0
    # Non-repetitive: the second half second does not retrace the first.
    a, b = d[:50_000], d[50_000:]
    assert np.abs(a - b).max() > 0.1


# --- configuration and command line -----------------------------------------------------------

def test_presets_and_overrides():
    assert set(VEGETATION) == {'default', 'clumped', 'tall', 'bushy', 'mixed'}
    assert set(SCAN) == {'line', 'spinning', 'rosette', 'elliptical'}
    assert flight_config() == FlightConfig()
    cfg = flight_config('tall', 'rosette', density=1500.0, grass_height=0.3, clump_size=20.0,
                        tilt=None)
    assert cfg.grass_height == 0.3 and cfg.vegetation.max_height == 0.45
    assert cfg.vegetation.clump_size == 20.0 and cfg.vegetation.preset == 'tall'
    assert cfg.scan.kind == 'rosette' and cfg.tilt == 20.0 and cfg.sensor.prr == 100_000.0
    assert cfg.sensor.target_density == 1500.0
    assert not cfg.vegetation.plain and VegetationConfig(preset='tall').plain
    for args, kw, match in [(('jungle',), {}, 'unknown vegetation'),
                            (('default', 'velodyne'), {}, 'unknown scan pattern'),
                            ((), {'wind': 3.0}, "unknown flight setting 'wind'")]:
        with pytest.raises(SimulationError, match=match):
            flight_config(*args, **kw)


@pytest.mark.parametrize('cfg,match', [
    (flight_config(clump_size=-1.0), 'clump_size'),
    (flight_config(segments=1), 'segments'),
    (flight_config(bush_height=(0.4, 0.2)), 'min <= max'),
    (flight_config(max_height=0.0), 'max_height'),
    (flight_config(line_spacing=0.1), 'line_spacing'),
    (flight_config('default', 'spinning', beams=0), 'beams'),
    (flight_config('default', 'rosette', prism_rates=(50.0, 50.0)), 'prism_rates'),
    (replace(FlightConfig(), vegetation=VegetationConfig(preset='jungle')), 'jungle'),
    (replace(FlightConfig(), scan=ScanPattern(kind='flash')), 'flash'),
])
def test_bad_settings_raise_before_any_work(cfg, match, tmp_path):
    with pytest.raises(SimulationError, match=match):
        simulate_flight(cfg, tmp_path / 'x.mcap')
    assert not list(tmp_path.iterdir())


def test_line_spacing_sets_the_passes(flights):
    result, labels, _, _, _ = flights('default', 'line', line_spacing=2.5, max_speed=30.0)
    assert labels['flight']['passes'] == [-2.5, 0.0, 2.5] and result.passes == 3
    assert abs(result.density - 600.0) / 600.0 < 0.15


def test_cli_options_reach_the_labels_and_bad_values_are_one_line(tmp_path):
    out = tmp_path / 's.mcap'
    common = [sys.executable, '-m', 'landing_zone', 'simulate-flight', '--out', str(out),
              '--size', '4', '--obstacles', '1', '--height', '4', '--density', '300']
    run = subprocess.run(common + ['--vegetation', 'clumped', '--clump-size', '50',
                                   '--bushes', '0.2', '--scan-pattern', 'rosette',
                                   '--tilt', '25'],
                         cwd=REPO, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr
    labels = json.loads(out.with_name('s.labels.json').read_text())
    veg, scan = labels['site']['vegetation'], labels['site']['scan_pattern']
    assert veg['preset'] == 'clumped' and veg['clump_size'] == 50.0
    assert veg['bush_density'] == 0.2 and veg['clump_radius'] == 0.06
    assert scan['kind'] == 'rosette' and labels['flight']['tilt'] == 25.0
    assert labels['flight']['sensor']['target_density'] == 300.0
    for bad, word in [(['--vegetation', 'jungle'], 'jungle'),
                      (['--scan-pattern', 'flash'], 'flash'),
                      (['--lean', '100'], 'inclination_std')]:
        bad_out = tmp_path / 'bad.mcap'
        run = subprocess.run(common[:5] + [str(bad_out)] + common[6:] + bad, cwd=REPO,
                             capture_output=True, text=True, timeout=120)
        lines = run.stderr.strip().splitlines()
        assert run.returncode == 2 and len(lines) == 1 and word in lines[0]
        assert not bad_out.exists() and not tmp_path.joinpath('bad.labels.json').exists()
