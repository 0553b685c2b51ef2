"""Replay: the node's pipeline over a bag, its output bag, report, PNG and CLI errors."""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from landing_zone.assessor import Assessor
from landing_zone.io.bags import BagWriter, read_messages
from landing_zone.errors import BagError
from landing_zone.replay import output_topics, replay
from landing_zone.config import StreamConfig
from landing_zone.runtime.stream import NS
from msg_adapters import MessageTypes, make_header, stamp_to_ns
from msg_adapters.grid import grid_values
from msg_adapters.pointcloud import cloud_to_structured, make_cloud, points_to_structured
from msg_adapters.pose import make_pose_stamped
from test_assessor import scene_cloud, small_config

T0 = 1_700_000_000 * NS
Q = (0.0, 0.0, 0.0, 1.0)


def sensor_at(t: float) -> np.ndarray:
    """A slow pass over the site: 0.5 m/s along x, 8 m up."""
    return np.array([-1.0 + 0.5 * t, 0.2, 8.0])


def write_flight(path, seed=0, seconds=4.0, cloud_hz=5, pose_hz=20, n=2500,
                 points_topic='/lidar/points', pose_topic='/lidar/pose', storage='mcap'):
    """A small flight bag: registered clouds of flat ground with a box, poses of the sensor.

    Returns the (stamp_ns, xyz, origin) of every cloud, for building the expected result.
    """
    rng = np.random.default_rng(seed)
    types = MessageTypes.rosbags()
    clouds = []
    with BagWriter(path, storage=storage, overwrite=True) as bag:
        bag.add_topic(points_topic, 'sensor_msgs/msg/PointCloud2')
        bag.add_topic(pose_topic, 'geometry_msgs/msg/PoseStamped')
        for k in range(int(seconds * pose_hz) + 1):
            t = k / pose_hz
            stamp = T0 + int(round(t * NS))
            bag.write(pose_topic, stamp + 1000,
                      make_pose_stamped(stamp, 'map', sensor_at(t), Q, types))
        for k in range(int(seconds * cloud_hz)):
            t = (k + 0.5) / cloud_hz
            stamp = T0 + int(round(t * NS))
            origin = sensor_at(t)
            xyz = scene_cloud(rng, origin, n=n, half=3.0)
            clouds.append((stamp, xyz, origin))
            msg = make_cloud(points_to_structured(xyz), make_header(stamp, 'map', types), types)
            bag.write(points_topic, stamp + 2000, msg)
    return clouds


@pytest.fixture(scope='module')
def flight(tmp_path_factory):
    path = tmp_path_factory.mktemp('bag') / 'flight.mcap'
    return path, write_flight(path)


@pytest.fixture(scope='module')
def replayed(tmp_path_factory, flight, model_file):
    d = tmp_path_factory.mktemp('out')
    res = replay(flight[0], d / 'out.mcap', d / 'report.json', model=model_file,
                 config=small_config(), stream_config=StreamConfig(assessment_period=1.0),
                 progress=False)
    return res, d


def test_replay_equals_the_assessor_fed_directly(flight, replayed, model_file):
    res, _ = replayed
    a = Assessor(small_config(), model=model_file)
    for stamp, xyz, origin in flight[1]:
        a.integrate(xyz, origin)
    ref = a.assess()
    got = res.assessment
    assert got.origin == ref.origin and np.array_equal(got.index, ref.index)
    np.testing.assert_array_equal(np.isnan(got.p_safe), np.isnan(ref.p_safe))
    np.testing.assert_allclose(got.p_safe, ref.p_safe, atol=2e-3, equal_nan=True)
    assert res.stats['clouds'] == 20 and res.stats['points'] == 20 * 2500
    assert res.stats['dropped_points'] == 0
    assert res.bag_seconds == pytest.approx(3.8)


def test_output_bag_has_every_topic_at_assessment_stamps(replayed, flight):
    res, d = replayed
    msgs = list(read_messages(d / 'out.mcap'))
    by_topic: dict[str, list] = {}
    for m in msgs:
        by_topic.setdefault(m.topic, []).append(m)
    assert set(by_topic) == set(output_topics())
    grids = by_topic['/assessor/safety_grid']
    assert len(grids) == res.assessments >= 4  # one per second of stamp time, plus the last
    stamps = [m.stamp_ns for m in grids]
    assert stamps == sorted(stamps)
    cloud_stamps = {s for s, _, _ in flight[1]}
    assert all(s in cloud_stamps for s in stamps)  # published at a cloud's stamp
    assert all(stamp_to_ns(m.msg.header.stamp) == m.stamp_ns for m in grids)
    last = grids[-1].msg
    assert last.data.tolist() == grid_values(res.assessment).T.reshape(-1).tolist()
    cloud = cloud_to_structured(by_topic['/assessor/safety_cloud'][-1].msg)
    have = np.isfinite(res.assessment.ground_z)
    np.testing.assert_allclose(cloud['p_safe'], res.assessment.p_safe[have], equal_nan=True)
    assert len(by_topic['/diagnostics']) == len(grids)


def test_overlapped_passes_are_the_passes_run_one_after_another(replayed, flight, model_file):
    """Replay judges each pass on a worker thread while the next clouds are integrated; every
    grid it wrote is the grid of running that pass at once, in turn (the scrolling map makes
    the window move between passes, which the overlap must not see)."""
    from landing_zone.runtime.stream import Stream

    res, d = replayed
    stream = Stream(Assessor(small_config(), model=model_file),
                    StreamConfig(assessment_period=1.0))  # the replayed fixture's period
    expect = []
    for m in read_messages(flight[0], ['/lidar/points', '/lidar/pose']):
        (stream.add_pose_msg if m.topic == '/lidar/pose' else stream.add_cloud_msg)(m.msg)
        if stream.due():
            expect.append((stream.assess(), stream.assessed_stamp_ns))
    stream.flush()
    if stream.unassessed:
        expect.append((stream.assess(), stream.assessed_stamp_ns))
    grids = [m.msg for m in read_messages(d / 'out.mcap', ['/assessor/safety_grid'])]
    assert len(grids) == len(expect) == res.assessments
    origins = set()
    for g, (a, stamp) in zip(grids, expect):
        assert stamp_to_ns(g.header.stamp) == stamp
        assert g.data.tolist() == grid_values(a).T.reshape(-1).tolist()
        origins.add(a.origin)
    assert len(origins) > 1  # the window did move
    # and replay's own switches give the same bag: passes in turn, and no warm-up (the
    # warm-up runs on a scratch map and stream of its own; the stream above had none)
    seq = replay(flight[0], d / 'seq.mcap', None, model=model_file, config=small_config(),
                 stream_config=StreamConfig(assessment_period=1.0), progress=False,
                 overlap=False, warm=False)
    assert seq.assessments == res.assessments
    assert [m.msg.data.tobytes() for m in read_messages(d / 'seq.mcap', [
        '/assessor/safety_grid'])] == [g.data.tobytes() for g in grids]


def test_report(replayed):
    res, d = replayed
    doc = json.loads((d / 'report.json').read_text())
    assert {'frame_id', 'tile_size', 'tiles', 'landing_sites', 'stats'} <= set(doc)
    assert {'clouds', 'points', 'dropped_points', 'seconds'} <= set(doc['stats'])
    assert doc['stats']['clouds'] == 20
    p = [t['p_safe'] for t in doc['tiles']]
    assert sum(v is None for v in p) == int((~res.assessment.known).sum())
    assert doc['config']['map.size_xy'] == 8.0 and doc['config']['region_center'] == []
    # the test model has no OOD reference beside it: the report says the signal was off
    assert doc['ood_reference'] is None and res.ood_reference is None
    assert len(res.top_view) > 0 and res.top_view.shape[1] == 3


def test_replay_is_deterministic_and_fixed_mode_stays_put(tmp_path, flight, replayed,
                                                          model_file):
    res, d = replayed
    again = replay(flight[0], tmp_path / 'o.mcap', tmp_path / 'r.json', model=model_file,
                   config=small_config(), stream_config=StreamConfig(assessment_period=1.0),
                   progress=False)
    a = json.loads((d / 'report.json').read_text())
    b = json.loads((tmp_path / 'r.json').read_text())
    assert a['tiles'] == b['tiles'] and a['landing_sites'] == b['landing_sites']
    grids = [[m.msg.data.tobytes() for m in read_messages(p, ['/assessor/safety_grid'])]
             for p in (d / 'out.mcap', tmp_path / 'o.mcap')]
    assert grids[0] == grids[1]
    fixed = replay(flight[0], None, None, model=model_file, config=small_config(),
                   center=(10.0, 0.0), progress=False)
    assert fixed.assessment.origin == (6, -4)
    assert again.stats['clouds'] == fixed.stats['clouds'] == 20


def test_a_sqlite3_bag_replays_like_the_mcap(tmp_path, replayed, model_file):
    bag = tmp_path / 'flight_db3'
    write_flight(bag, storage='sqlite3')  # the same seed: the same messages
    assert list(bag.glob('*.db3'))
    res = replay(bag, None, None, model=model_file, config=small_config(),
                 stream_config=StreamConfig(assessment_period=1.0), progress=False)
    ref = replayed[0].assessment
    np.testing.assert_array_equal(res.assessment.p_safe, ref.p_safe)
    assert res.stats['clouds'] == 20


def test_missing_topics_and_bad_bags_are_bag_errors(tmp_path, flight, model_file):
    with pytest.raises(BagError, match='lacks topic /points'):
        replay(flight[0], None, None, points_topic='/points', model=model_file)
    with pytest.raises(BagError, match='carries geometry_msgs/msg/PoseStamped'):
        replay(flight[0], None, None, points_topic='/lidar/pose', model=model_file)
    with pytest.raises(BagError, match='not found'):
        replay(tmp_path / 'nope.mcap', None, None, model=model_file)
    assert not (tmp_path / 'o.mcap').exists()


def run_cli(*args):
    return subprocess.run([sys.executable, '-m', 'landing_zone', *map(str, args)],
                          capture_output=True, text=True, timeout=120)


def test_cli_errors_are_one_line_exit_2(tmp_path, flight, model_file):
    out = run_cli('replay', tmp_path / 'missing.mcap', '--out', tmp_path / 'o.mcap',
                  '--report', tmp_path / 'r.json', '--model', model_file)
    assert out.returncode == 2, out.stderr
    assert out.stderr.strip().splitlines() == [
        f'landing-zone: error: bag not found: {tmp_path / "missing.mcap"}']
    out = run_cli('replay', flight[0], '--out', tmp_path / 'o.mcap', '--report',
                  tmp_path / 'r.json', '--points-topic', '/velodyne', '--model', model_file)
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and 'lacks topic /velodyne' in lines[0]
    corrupt = tmp_path / 'corrupt.mcap'
    corrupt.write_bytes(flight[0].read_bytes()[:3000])
    out = run_cli('replay', corrupt, '--out', tmp_path / 'o.mcap', '--report',
                  tmp_path / 'r.json', '--model', model_file)
    assert out.returncode == 2 and len(out.stderr.strip().splitlines()) == 1, out.stderr
    assert 'Traceback' not in out.stderr
    out = run_cli('replay', flight[0], '--out', tmp_path / 'o.mcap', '--report',
                  tmp_path / 'r.json', '--model', tmp_path / 'no-model.safetensors')
    assert out.returncode == 2 and 'model file not found' in out.stderr
    assert not (tmp_path / 'o.mcap').exists() and not (tmp_path / 'r.json').exists()


def test_cli_replay_prints_a_summary(tmp_path, flight, model_file):
    params = tmp_path / 'p.yaml'
    params.write_text('assessor:\n  ros__parameters:\n    map:\n      size_xy: 8.0\n'
                      '      recenter_distance: 1.0\n    tiles:\n'
                      '      min_observed_fraction: 0.1\n    assessment_period: 2.0\n')
    out = run_cli('replay', flight[0], '--out', tmp_path / 'o.mcap', '--report',
                  tmp_path / 'r.json', '--model', model_file, '--params', params)
    assert out.returncode == 0, out.stderr
    assert 'replayed 20 clouds (50,000 returns' in out.stdout and 'real time' in out.stdout
    assert 'OOD reference: none' in out.stdout
    doc = json.loads((tmp_path / 'r.json').read_text())
    assert len(doc['tiles']) == 64 and doc['stats']['assessments'] == 2
