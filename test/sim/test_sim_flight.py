"""Flights: the bag's topics and stamps, density over the site, ground truth, determinism."""
from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from landing_zone.errors import BagError, SimulationError
from landing_zone.tools.sim.flight import START_TIME_NS, simulate_flight
from landing_zone.tools.sim.flight_settings import FlightConfig
from landing_zone.tools.sim.flight_site import polygon_overlaps_square
from landing_zone.tools.sim.library import get_model
from landing_zone.tools.sim.obstacles import Obstacle
from landing_zone.tools.sim.sensor import SensorConfig

REPO = Path(__file__).resolve().parents[2]
SMALL = FlightConfig(size=8.0, obstacles=3, kinds=('rock', 'cinder_block', 'tire'),
                     grass_density=400.0, grass_height=0.2, height=5.0, seed=2,
                     sensor=SensorConfig(target_density=600.0, angular_resolution=0.2,
                                         prr=50_000.0))


@pytest.fixture(scope='module')
def flight(tmp_path_factory):
    out = tmp_path_factory.mktemp('flight') / 'site.mcap'
    result = simulate_flight(SMALL, out)
    from landing_zone.io.bags import read_messages
    msgs = list(read_messages(out))
    return out, result, msgs, json.loads(result.labels.read_text())


def clouds_of(msgs):
    from msg_adapters.pointcloud import cloud_to_structured
    return [(m, cloud_to_structured(m.msg)) for m in msgs if m.topic == '/lidar/points']


def test_bag_topics_types_and_stamps(flight):
    out, result, msgs, _ = flight
    from landing_zone.io.bags import bag_topics
    from msg_adapters import stamp_to_ns
    from msg_adapters.pose import pose_stamped_to_arrays
    assert bag_topics(out) == {'/lidar/points': 'sensor_msgs/msg/PointCloud2',
                               '/lidar/pose': 'geometry_msgs/msg/PoseStamped'}
    stamps = [m.stamp_ns for m in msgs]
    assert stamps == sorted(stamps) and stamps[0] >= START_TIME_NS
    clouds = clouds_of(msgs)
    poses = [m for m in msgs if m.topic == '/lidar/pose']
    assert len(clouds) == result.clouds > 5 and len(poses) >= len(clouds)
    pose_stamps = {m.stamp_ns for m in poses}
    for m, arr in clouds:
        assert m.msg.header.frame_id == 'map'
        assert stamp_to_ns(m.msg.header.stamp) == m.stamp_ns
        assert m.stamp_ns in pose_stamps  # a pose at every cloud's stamp
        assert {f.name: f.datatype for f in m.msg.fields} == {
            'x': 7, 'y': 7, 'z': 7, 'intensity': 7, 'label': 2}  # FLOAT32, UINT8
    # Small time slices: clouds follow each other at the line rate times lines per cloud.
    dt = np.diff([m.stamp_ns for m, _ in clouds]) * 1e-9
    period = SMALL.sensor.line_period * SMALL.lines_per_cloud
    assert np.median(dt) == pytest.approx(period, rel=0.01)
    # Poses fly at the flight height, and the sensor looks ahead: returns lie in front of it.
    for m in poses[:: max(1, len(poses) // 20)]:
        _, p, q = pose_stamped_to_arrays(m.msg)
        assert p[2] == pytest.approx(SMALL.height, abs=0.3)
        assert np.linalg.norm(q) == pytest.approx(1.0)
    assert sum(len(a) for _, a in clouds) == result.points


def test_density_over_the_site_meets_the_target(flight):
    _, result, msgs, _ = flight
    half = SMALL.size / 2
    pts = np.concatenate([np.stack([a['x'], a['y']], 1) for _, a in clouds_of(msgs)])
    on_site = np.all(np.abs(pts) < half, axis=1).sum() / SMALL.size ** 2
    assert on_site == pytest.approx(result.density)
    assert abs(on_site - 600.0) / 600.0 < 0.15
    # Every tile of the site is seen.
    k = np.floor(pts[np.all(np.abs(pts) < half, axis=1)]).astype(int)
    counts = np.bincount((k[:, 0] + 4) * 8 + (k[:, 1] + 4), minlength=64)
    assert counts.min() > 0.3 * counts.mean()


def test_labels_match_the_obstacles(flight):
    _, result, msgs, labels = flight
    assert labels['frame_id'] == 'map' and labels['tile_size'] == 1.0
    tiles = labels['tiles']
    assert len(tiles) == result.tiles == 64
    centres = np.array([[t['x'], t['y']] for t in tiles])
    np.testing.assert_allclose(np.mod(centres, 1.0), 0.5)  # the global lattice, x.5
    unsafe = {(t['x'], t['y']) for t in tiles if not t['safe']}
    assert len(unsafe) == result.unsafe_tiles >= len(labels['obstacles']) == 3
    footprints = []
    for ob in labels['obstacles']:
        assert set(ob) >= {'kind', 'x', 'y', 'z', 'yaw', 'size'}
        model = get_model(ob['model'])
        assert ob['kind'] == model.kind and np.allclose(ob['size'], model.size, atol=1e-3)
        fp = Obstacle(model, ob['x'], ob['y'], ob['z'], ob['yaw']).footprint()
        footprints.append(fp)
        # Every tile the footprint reaches into is unsafe ...
        for v in np.concatenate([fp, [[ob['x'], ob['y']]]]):
            assert (np.floor(v[0]) + 0.5, np.floor(v[1]) + 0.5) in unsafe
    # ... and every unsafe tile holds part of a footprint.
    for cx, cy in unsafe:
        lo, hi = np.array([cx - 0.5, cy - 0.5]), np.array([cx + 0.5, cy + 0.5])
        assert any(polygon_overlaps_square(fp, lo, hi) for fp in footprints)
    # The returns from obstacles fall into unsafe tiles (but for range noise at tile edges).
    arrs = [a for _, a in clouds_of(msgs)]
    lab = np.concatenate([a['label'] for a in arrs])
    xy = np.concatenate([np.stack([a['x'], a['y']], 1) for a in arrs])[lab == 2]
    assert len(xy) > 50
    in_unsafe = [(np.floor(x) + 0.5, np.floor(y) + 0.5) in unsafe for x, y in xy]
    assert np.mean(in_unsafe) > 0.95


def test_same_seed_same_bytes(flight, tmp_path):
    out, _, _, _ = flight
    again = tmp_path / 'site.mcap'
    simulate_flight(SMALL, again)
    assert hashlib.sha256(again.read_bytes()).digest() == hashlib.sha256(
        out.read_bytes()).digest()
    assert again.with_name('site.labels.json').read_bytes() == out.with_name(
        'site.labels.json').read_bytes()
    with pytest.raises(BagError, match='exists'):
        simulate_flight(SMALL, again)


def test_polygon_square_overlap():
    lo, hi = np.zeros(2), np.ones(2)
    tri = np.array([[0.5, 0.5], [2.0, 0.5], [0.5, 2.0]])
    assert polygon_overlaps_square(tri, lo, hi)
    assert not polygon_overlaps_square(tri + 1.5, lo, hi)
    # Touching an edge is no overlap; a diamond around the square's corner is.
    assert not polygon_overlaps_square(np.array([[1.0, 0.0], [2.0, 0.0], [2.0, 1.0],
                                                 [1.0, 1.0]]), lo, hi)
    diamond = np.array([[1.0, 0.9], [1.1, 1.0], [1.0, 1.1], [0.9, 1.0]])
    assert polygon_overlaps_square(diamond, lo, hi)
    # Separated only along the polygon's own edge normal (not the square's axes).
    thin = np.array([[1.05, 1.2], [1.2, 1.05], [1.4, 1.25], [1.25, 1.4]])
    assert not polygon_overlaps_square(thin, lo, hi)


@pytest.mark.parametrize('kwargs,match', [
    ({'kinds': ('rock', 'boulder')}, 'unknown obstacle kind'),
    ({'grass_density': -1.0}, 'grass_density'),
    ({'obstacles': 500}, 'do not fit'),
    ({'size': 2.0}, 'size'),
    ({'height': float('inf')}, 'height'),
    ({'sensor': SensorConfig(angular_resolution=0.0)}, 'angular_resolution'),
])
def test_bad_flights_raise_before_any_work(kwargs, match, tmp_path):
    cfg = FlightConfig(**{**SMALL.__dict__, **kwargs})
    with pytest.raises(SimulationError, match=match):
        simulate_flight(cfg, tmp_path / 'x.mcap')
    assert not list(tmp_path.iterdir())


def test_cli_errors_are_one_line(tmp_path):
    out = subprocess.run([sys.executable, '-m', 'landing_zone', 'simulate-flight', '--out',
                          str(tmp_path / 's.mcap'), '--kinds', 'rock,boulder'],
                         cwd=REPO, capture_output=True, text=True, timeout=120)
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and 'boulder' in lines[0]


def test_render_flight_and_scene(flight, tmp_path):
    from landing_zone.tools.sim.dataset import simulate_dataset
    from landing_zone.tools.sim.render import render
    out, _, _, _ = flight
    png = render(out, tmp_path / 'flight.png')
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n' and png.stat().st_size > 20_000
    data = tmp_path / 'data'
    simulate_dataset('synth1', data, scenes=2, workers=1, progress=False)
    png = render(data, tmp_path / 'scene.png', index=1)
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n' and png.stat().st_size > 20_000
    with pytest.raises(SimulationError, match='.png'):
        render(data, tmp_path / 'scene.jpg')
    with pytest.raises(SimulationError, match='neither'):
        render(tmp_path, tmp_path / 'x.png')
    png = render('library', tmp_path / 'library.png')
    assert png.read_bytes()[:8] == b'\x89PNG\r\n\x1a\n' and png.stat().st_size > 50_000
