"""geometry_msgs Pose / PoseStamped adapters, for rclpy and rosbags messages, and the stamp
helpers: round trips, normalisation, (R, t) against scipy, and every malformed pose."""
from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from msg_adapters import jazzy_typestore as typestore
from landing_zone.errors import InvalidPoseError, LandingZoneError
from msg_adapters import MessageTypes, as_message_types, make_header, ns_to_stamp, stamp_to_ns
from msg_adapters.pose import (
    make_pose,
    make_pose_stamped,
    pose_stamped_to_arrays,
    pose_to_arrays,
    pose_to_rt,
)


@pytest.fixture(params=['rclpy', 'rosbags'])
def types(request):
    if request.param == 'rclpy':
        pytest.importorskip('geometry_msgs.msg')
        return MessageTypes.rclpy()
    return MessageTypes.rosbags()


def _pose_msg(position, quaternion, stamp=(0, 0)):
    point = SimpleNamespace(x=position[0], y=position[1], z=position[2])
    orientation = SimpleNamespace(x=quaternion[0], y=quaternion[1], z=quaternion[2],
                                  w=quaternion[3])
    return SimpleNamespace(
        header=SimpleNamespace(stamp=SimpleNamespace(sec=stamp[0], nanosec=stamp[1]),
                               frame_id='map'),
        pose=SimpleNamespace(position=point, orientation=orientation))


def test_pose_stamped_round_trip(types):
    q = Rotation.from_euler('zyx', [0.3, -0.2, 0.1]).as_quat()
    msg = make_pose_stamped(1_700_000_001_000_000_042, 'map', [1.5, -2.0, 30.25], q, types)
    assert isinstance(msg, types.get('geometry_msgs/msg/PoseStamped'))
    assert msg.header.frame_id == 'map'
    stamp, position, quaternion = pose_stamped_to_arrays(msg)
    assert stamp == 1_700_000_001_000_000_042
    np.testing.assert_array_equal(position, [1.5, -2.0, 30.25])
    np.testing.assert_allclose(quaternion, q, atol=1e-15)


def test_quaternion_normalised_both_ways(types):
    msg = make_pose_stamped(0, 'map', [0, 0, 0], [0, 0, 2.0, 2.0], types)
    np.testing.assert_allclose([msg.pose.orientation.z, msg.pose.orientation.w],
                               [0.5 ** 0.5] * 2, rtol=1e-15)
    _, _, q = pose_stamped_to_arrays(_pose_msg([0, 0, 0], [0, 0, 0, 3.0]))
    np.testing.assert_array_equal(q, [0, 0, 0, 1])


def test_pose_to_rt_matches_scipy():
    rng = np.random.default_rng(1)
    for _ in range(20):
        q = rng.normal(size=4)
        t = rng.normal(size=3) * 10
        R, t_out = pose_to_rt(_pose_msg(t, q))
        np.testing.assert_allclose(R, Rotation.from_quat(q).as_matrix(), atol=1e-12)
        np.testing.assert_array_equal(t_out, t)
        np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
        assert np.linalg.det(R) == pytest.approx(1.0)


def test_pose_to_rt_takes_pose_and_pose_stamped(types):
    # A yaw of 90 degrees maps the sensor's x axis onto the world's y axis.
    msg = make_pose_stamped(0, 'map', [1, 2, 3], [0, 0, np.sin(np.pi / 4), np.cos(np.pi / 4)],
                            types)
    for m in (msg, msg.pose):
        R, t = pose_to_rt(m)
        np.testing.assert_allclose(R @ [1, 0, 0] + t, [1, 3, 3], atol=1e-15)


def test_make_pose(types):
    pose = make_pose([1, 2, 3], [0, 0, 0, 1], types)
    assert isinstance(pose, types.get('geometry_msgs/msg/Pose'))
    p, q = pose_to_arrays(pose)
    np.testing.assert_array_equal(p, [1, 2, 3])
    np.testing.assert_array_equal(q, [0, 0, 0, 1])


def test_rosbags_pose_survives_cdr():
    store = typestore()
    msg = make_pose_stamped(-1_500_000_000, 'odom', [1, 2, 3], [1, 0, 0, 0], store)
    data = store.serialize_cdr(msg, msg.__msgtype__)
    back = store.deserialize_cdr(data, msg.__msgtype__)
    stamp, p, q = pose_stamped_to_arrays(back)
    assert stamp == -1_500_000_000 and back.header.stamp.nanosec == 500_000_000
    np.testing.assert_array_equal(p, [1, 2, 3])
    np.testing.assert_array_equal(q, [1, 0, 0, 0])


@pytest.mark.parametrize('position,quaternion,match', [
    ([0, 0, np.nan], [0, 0, 0, 1], 'position is not finite'),
    ([0, np.inf, 0], [0, 0, 0, 1], 'position is not finite'),
    ([0, 0, 0], [0, 0, 0, np.nan], 'quaternion is not finite'),
    ([0, 0, 0], [0, 0, 0, 0], 'norm 0'),
    ([0, 0, 0], [1e-9, 0, 0, 0], 'cannot be a rotation'),
    ([0, 0, 0], [0, 0, 0, 'w'], 'non-numeric'),
])
def test_malformed_pose_raises(position, quaternion, match):
    with pytest.raises(InvalidPoseError, match=match):
        pose_stamped_to_arrays(_pose_msg(position, quaternion))


def test_not_a_pose_raises():
    with pytest.raises(InvalidPoseError, match='not a geometry_msgs/PoseStamped'):
        pose_stamped_to_arrays(SimpleNamespace(pose=None))
    with pytest.raises(InvalidPoseError, match='not a geometry_msgs/Pose'):
        pose_to_arrays(SimpleNamespace(position=SimpleNamespace(x=1, y=2, z=3)))


def test_builders_reject_bad_poses(types):
    with pytest.raises(InvalidPoseError, match='position must be 3 finite'):
        make_pose([0, 0, np.nan], [0, 0, 0, 1], types)
    with pytest.raises(InvalidPoseError, match='norm'):
        make_pose_stamped(0, 'map', [0, 0, 0], [0, 0, 0, 0], types)


@pytest.mark.parametrize('ns,sec,nanosec', [
    (0, 0, 0), (1, 0, 1), (1_999_999_999, 1, 999_999_999), (-1, -1, 999_999_999),
    (1_700_000_000_123_456_789, 1_700_000_000, 123_456_789)])
def test_stamp_conversions(types, ns, sec, nanosec):
    stamp = ns_to_stamp(ns, types)
    assert (stamp.sec, stamp.nanosec) == (sec, nanosec)
    assert stamp_to_ns(stamp) == ns
    header = make_header(ns, 'base', types)
    assert stamp_to_ns(header.stamp) == ns and header.frame_id == 'base'


def test_stamp_out_of_range():
    with pytest.raises(LandingZoneError, match='int32 seconds'):
        ns_to_stamp(2**31 * 1_000_000_000, 'rosbags')


def test_as_message_types():
    store = typestore()
    assert as_message_types(store).typestore is store
    assert as_message_types('rclpy').kind == 'rclpy'
    with pytest.raises(ValueError, match="'rclpy' or 'rosbags'"):
        as_message_types('ros1')
    with pytest.raises(TypeError):
        as_message_types(42)
    with pytest.raises(LandingZoneError, match='not in the rosbags typestore'):
        MessageTypes.rosbags().get('nope_msgs/msg/Nothing')
    with pytest.raises(LandingZoneError, match='cannot be imported'):
        MessageTypes.rclpy().get('nope_msgs/msg/Nothing')


def test_odometry_round_trip_and_either_pose_input(types):
    from msg_adapters.pose import make_odometry, read_pose_input

    q = Rotation.from_euler('zyx', [0.3, -0.2, 0.1]).as_quat()
    msg = make_odometry(1_700_000_001_000_000_042, 'odom', 'base_link', [1.5, -2.0, 30.25], q,
                        types)
    assert isinstance(msg, types.get('nav_msgs/msg/Odometry'))
    frame, child, stamp, position, quaternion = read_pose_input(msg)
    assert (frame, child, stamp) == ('odom', 'base_link', 1_700_000_001_000_000_042)
    np.testing.assert_array_equal(position, [1.5, -2.0, 30.25])
    np.testing.assert_allclose(quaternion, q, atol=1e-15)
    ps = make_pose_stamped(5, 'map', [0, 0, 1], [0, 0, 0, 1], types)
    assert read_pose_input(ps)[:3] == ('map', None, 5)
    with pytest.raises(InvalidPoseError, match='not a nav_msgs/Odometry'):
        read_pose_input(SimpleNamespace(child_frame_id='x', header=msg.header))
