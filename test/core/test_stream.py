"""The shared stream logic: pose interpolation at cloud stamps, waiting, drops by reason,
assessment cadence in stamp time, and fuzzed malformed messages."""
from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from landing_zone.assessor import Assessor
from landing_zone.config import StreamConfig
from landing_zone.runtime.stream import NS, Stream
from msg_adapters import make_header
from msg_adapters.pointcloud import make_cloud, points_to_structured
from msg_adapters.pose import make_pose_stamped
from test_assessor import make_model, scene_cloud, small_config

Q = (0.0, 0.0, 0.0, 1.0)


@pytest.fixture(scope='module')
def model_file(tmp_path_factory):
    return make_model(tmp_path_factory.mktemp('model') / 'small.safetensors')


def recorded(assessor):
    """Record the (stamp, origin) of every integrate call the stream makes."""
    calls = []
    real = assessor.integrate

    def integrate(points, origin, stamp=None):
        calls.append((stamp, np.asarray(origin, float).copy(), len(points)))
        return real(points, origin, stamp=stamp)

    assessor.integrate = integrate
    return calls


def cloud_msg(xyz, stamp_ns, frame='map', types='rclpy'):
    return make_cloud(points_to_structured(np.asarray(xyz, np.float32)),
                      make_header(stamp_ns, frame, types), types)


def pose_msg(stamp_ns, position, frame='map', types='rclpy'):
    return make_pose_stamped(stamp_ns, frame, position, Q, types)


def make_stream(model_file, **cfg):
    a = Assessor(small_config(), center=(0.0, 0.0), model=model_file)
    return Stream(a, StreamConfig(**cfg)), a


def test_cloud_origin_is_the_pose_interpolated_at_its_stamp(model_file):
    s, a = make_stream(model_file)
    calls = recorded(a)
    rng = np.random.default_rng(0)
    s.add_pose(0, (0.0, 0.0, 8.0), Q)
    s.add_pose(NS, (1.0, -2.0, 10.0), Q)
    s.add_cloud(NS // 4, scene_cloud(rng, (0, 0, 8), n=500))
    assert len(calls) == 1
    stamp, origin, n = calls[0]
    assert stamp == pytest.approx(0.25)
    np.testing.assert_allclose(origin, [0.25, -0.5, 8.5])
    assert n == 500 and s.clouds == 1 and s.points == 500


def test_a_cloud_newer_than_every_pose_waits_for_the_next_pose(model_file):
    s, a = make_stream(model_file, pose_wait=1.0)
    calls = recorded(a)
    rng = np.random.default_rng(1)
    s.add_pose(0, (0.0, 0.0, 8.0), Q)
    s.add_cloud(NS // 2, scene_cloud(rng, (0, 0, 8), n=300))
    s.add_cloud(NS // 2 + 10, scene_cloud(rng, (0, 0, 8), n=300))
    assert calls == [] and s.pending == 2
    s.add_pose(NS, (2.0, 0.0, 8.0), Q)
    assert [c[0] for c in calls] == [0.5, pytest.approx(0.5 + 1e-8)]
    np.testing.assert_allclose(calls[0][1], [1.0, 0.0, 8.0])
    assert s.pending == 0 and not s.dropped_clouds


def test_waits_end_in_a_clamped_pose_or_a_drop(model_file):
    s, a = make_stream(model_file, pose_wait=0.5, pose_tolerance=0.05)
    calls = recorded(a)
    rng = np.random.default_rng(2)
    pts = scene_cloud(rng, (0, 0, 8), n=100)
    s.add_pose(0, (0.0, 0.0, 8.0), Q)
    s.add_cloud(NS // 50, pts)  # 0.02 s: within the tolerance of the only pose
    s.add_cloud(NS // 5, pts)  # 0.2 s: beyond it
    assert s.pending == 2
    # a cloud 0.6 s later ends both waits: the first gets the newest pose, the second drops
    s.add_cloud(NS * 3 // 4, pts)
    assert [c[0] for c in calls] == [0.02]
    np.testing.assert_allclose(calls[0][1], [0.0, 0.0, 8.0])
    assert s.dropped_clouds == {'no_pose': 1} and s.dropped_points['no_pose'] == 100
    s.flush()  # end of input: the last one has no pose either
    assert s.dropped_clouds == {'no_pose': 2} and s.pending == 0


def test_drops_are_counted_by_reason(model_file):
    s, a = make_stream(model_file, max_pending=2)
    calls = recorded(a)
    rng = np.random.default_rng(3)
    pts = scene_cloud(rng, (0, 0, 8), n=50)
    s.add_cloud(0, pts)  # no pose yet: waits
    s.add_cloud(10, pts)
    s.add_cloud(20, pts)  # the queue holds two: the oldest goes
    assert s.dropped_clouds == {'queue_full': 1}
    s.add_cloud(15, pts)  # older than one already accepted
    assert s.dropped_clouds['out_of_order'] == 1
    s.add_cloud(30, pts, frame_id='base_link')
    assert s.dropped_clouds['wrong_frame'] == 1
    s.add_cloud(40, np.zeros((5, 2)))
    assert s.dropped_clouds['malformed'] == 1
    s.add_pose(NS, (0.0, 0.0, 8.0), Q)  # the waiting clouds are 1 s older than every pose
    assert s.dropped_clouds['too_old'] == 2 and calls == []
    bad = pts.copy()
    bad[:7] = np.nan
    s.add_cloud(NS, bad)
    assert s.dropped_points['nonfinite'] == 7 and calls[0][2] == 43
    assert s.stats()['dropped_clouds'] == 6
    assert s.stats()['dropped_points'] == 50 * 5 + 5 + 7
    diag = s.diagnostics()
    assert diag['dropped clouds: too_old'] == '2' and diag['dropped points: nonfinite'] == '7'


def test_message_front_door_counts_bad_messages(model_file):
    from sensor_msgs.msg import PointCloud2, PointField

    s, a = make_stream(model_file)
    rng = np.random.default_rng(4)
    s.add_pose_msg(pose_msg(0, (0.0, 0.0, 8.0)))
    s.add_pose_msg(pose_msg(NS, (0.0, 0.0, 8.0), frame='odom'))
    assert s.dropped_poses == {'wrong_frame': 1}
    good = cloud_msg(scene_cloud(rng, (0, 0, 8), n=200), 0)
    no_z = PointCloud2(height=1, width=2, point_step=8, row_step=16, data=bytes(16),
                       fields=[PointField(name='x', offset=0, datatype=7, count=1),
                               PointField(name='y', offset=4, datatype=7, count=1)])
    no_z.header.frame_id = 'map'
    truncated = cloud_msg(scene_cloud(rng, (0, 0, 8), n=10), 0)
    truncated.data = truncated.data[:-5]
    s.add_cloud_msg(no_z)
    s.add_cloud_msg(truncated)
    s.add_cloud_msg(cloud_msg(scene_cloud(rng, (0, 0, 8), n=10), 0, frame='velodyne'))
    assert s.dropped_clouds == {'malformed': 2, 'wrong_frame': 1}
    assert s.dropped_points['malformed'] == 12
    s.add_cloud_msg(good)
    assert s.clouds == 1 and s.points == 200
    # rosbags messages go through the same door
    s.add_cloud_msg(cloud_msg(scene_cloud(rng, (0, 0, 8), n=30), 0, types='rosbags'))
    assert s.clouds == 2 and s.points == 230


def test_assessments_fall_due_on_a_stamp_time_grid(model_file):
    s, _ = make_stream(model_file, assessment_period=1.0)
    rng = np.random.default_rng(5)
    s.add_pose(0, (0.0, 0.0, 8.0), Q)
    s.add_pose(100 * NS, (0.0, 0.0, 8.0), Q)
    due_at = []
    for k in range(26):  # clouds every 0.1 s from t = 10 s
        t = 10 * NS + k * NS // 10
        s.add_cloud(t, scene_cloud(rng, (0, 0, 8), n=50))
        if s.due():
            due_at.append(t / NS)
            r = s.assess()
            assert r.stamp == pytest.approx(t / NS)
    assert due_at == pytest.approx([11.0, 12.0])
    s.add_cloud(15 * NS + 1, scene_cloud(rng, (0, 0, 8), n=50))  # a gap skips 13 and 14
    assert s.due()
    s.assess()
    s.add_cloud(15 * NS + NS // 2, scene_cloud(rng, (0, 0, 8), n=50))
    assert not s.due() and s.unassessed == 1
    assert s.last_latency is not None and s.last_latency >= 0


# --- fuzz: malformed rclpy messages never crash the stream nor lose the map ---------------

_FIELD = st.builds(
    dict, name=st.sampled_from(['x', 'y', 'z', 'intensity', '']),
    offset=st.integers(0, 40), datatype=st.integers(0, 9), count=st.integers(0, 3))


@st.composite
def clouds(draw):
    from sensor_msgs.msg import PointCloud2, PointField

    n = draw(st.integers(0, 6))
    height = draw(st.integers(0, 2))
    point_step = draw(st.integers(0, 32))
    row_step = draw(st.one_of(st.just(n * point_step), st.integers(0, 200)))
    fields = draw(st.one_of(
        st.just([dict(name=c, offset=4 * i, datatype=7, count=1) for i, c in enumerate('xyz')]),
        st.lists(_FIELD, max_size=5)))
    size = draw(st.one_of(st.just(height * row_step), st.integers(0, 300)))
    data = draw(st.binary(min_size=size, max_size=size))
    if draw(st.booleans()):  # real float coordinates, some NaN / Inf / huge
        vals = draw(st.lists(st.sampled_from([0.0, 1.5, -3.0, 2.0e38, float('nan'),
                                              float('inf'), -float('inf'), 7.25]),
                             min_size=len(data) // 4, max_size=len(data) // 4))
        data = np.asarray(vals, '<f4').tobytes() + data[4 * len(vals):]
    msg = PointCloud2(height=height, width=n, point_step=point_step, row_step=row_step,
                      is_bigendian=draw(st.booleans()), data=data,
                      fields=[PointField(**f) for f in fields
                              if 0 <= f['datatype'] <= 255 and f['count'] >= 0])
    msg.header.frame_id = draw(st.sampled_from(['map', 'map', 'other']))
    msg.header.stamp.sec = draw(st.integers(0, 3))
    return msg


@pytest.fixture(scope='module')
def fuzz_stream(model_file):
    s, a = make_stream(model_file)
    rng = np.random.default_rng(6)
    s.add_pose(0, (0.0, 0.0, 8.0), Q)
    s.add_pose(10 * NS, (0.0, 0.0, 8.0), Q)
    s.add_cloud(0, scene_cloud(rng, (0, 0, 8), n=2000))
    return s, a


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow,
                                                                  HealthCheck.data_too_large])
@given(msg=clouds())
def test_fuzzed_clouds_never_crash_nor_lose_the_map(fuzz_stream, msg):
    s, a = fuzz_stream
    h0, p0 = a.map.counts()
    before = s.received_clouds
    s.add_cloud_msg(msg)
    s.flush()
    assert s.received_clouds == before + 1
    h1, p1 = a.map.counts()
    assert np.all(h1 >= h0) and np.all(p1 >= p0)  # fixed map: nothing integrated is lost
    accounted = s.clouds + sum(s.dropped_clouds.values()) + s.pending
    assert accounted == s.received_clouds


@settings(max_examples=40, deadline=None)
@given(x=st.floats(allow_nan=True, allow_infinity=True), w=st.floats(-2, 2),
       frame=st.sampled_from(['map', 'odom']), sec=st.integers(0, 5))
def test_fuzzed_poses_are_counted_not_raised(fuzz_stream, x, w, frame, sec):
    from geometry_msgs.msg import PoseStamped

    s, _ = fuzz_stream
    msg = PoseStamped()
    msg.header.frame_id = frame
    msg.header.stamp.sec = sec
    msg.pose.position.x = x
    msg.pose.orientation.w = w
    n = s.poses + sum(s.dropped_poses.values())
    s.add_pose_msg(msg)
    assert s.poses + sum(s.dropped_poses.values()) == n + 1
