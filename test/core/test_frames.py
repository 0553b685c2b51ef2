"""One flight fed three ways gives one grid: the LiDAR's PoseStamped with clouds registered in
``map``, and the body's Odometry with clouds in the body frame or in the LiDAR's own frame, the
LiDAR mounted off the body (landing_zone.tools.sim.odometry_flight). Also: an odometry that
cannot be used (wrong frame, no child frame) or a second pose input is a counted drop, never a
wrong map."""
from __future__ import annotations

import numpy as np
import pytest

from landing_zone.assessor import Assessor
from landing_zone.config import StreamConfig
from landing_zone.poses import Mount, matrix_to_quaternion, quaternion_to_matrix, rpy_to_matrix
from landing_zone.replay import replay
from landing_zone.runtime.stream import NS, Stream
from landing_zone.tools.sim.odometry_flight import DEFAULT_OFFSET, odometry_flight
from msg_adapters import MessageTypes, make_header
from msg_adapters.pointcloud import make_cloud, points_to_structured
from msg_adapters.pose import make_odometry, make_pose_stamped
from test_assessor import small_config


@pytest.fixture(scope='module')
def flights(tmp_path_factory):
    """A small simulated flight, and the same as odometry with body- and sensor-frame clouds."""
    from landing_zone.tools.sim.flight import FlightConfig, simulate_flight

    d = tmp_path_factory.mktemp('frames')
    fixed = d / 'site.mcap'
    simulate_flight(FlightConfig(seed=3, size=8.0, obstacles=2, lines_per_cloud=14), fixed)
    body = odometry_flight(fixed, d / 'body.mcap', cloud_frame='body')
    sensor = odometry_flight(fixed, d / 'sensor.mcap', cloud_frame='sensor',
                             sensor_frame='os_lidar')
    assert body.labels is not None and body.labels.is_file()
    assert body.clouds == sensor.clouds > 10 and body.poses == sensor.poses
    return fixed, body, sensor


def test_the_same_flight_fed_three_ways_gives_the_same_grid(flights, model_file):
    fixed, body, sensor = flights
    ref = replay(fixed, model=model_file, progress=False, warm=False)
    for flight in (body, sensor):
        got = replay(flight.bag, model=model_file, progress=False, warm=False,
                     pose_topic=flight.pose_topic, cloud_frame=flight.cloud_frame,
                     sensor_offset=flight.sensor_offset)
        assert got.stats['clouds'] == ref.stats['clouds'] == body.clouds
        assert got.stats['dropped_clouds'] == 0
        a, b = ref.assessment, got.assessment
        assert a.shape == b.shape and np.allclose(a.origin, b.origin)
        pa, pb = a.grid(a.p_safe), b.grid(b.p_safe)
        np.testing.assert_array_equal(np.isfinite(pa), np.isfinite(pb))  # same unknown tiles
        known = np.isfinite(pa)
        assert known.sum() > 20
        assert np.abs(pa[known] - pb[known]).max() <= 0.02
    # without the offset the LiDAR's returns are registered as if it sat at the body's
    # origin, level: the grid shows it
    wrong = replay(sensor.bag, model=model_file, progress=False, warm=False,
                   pose_topic=sensor.pose_topic, cloud_frame='sensor')
    a, b = ref.assessment, wrong.assessment
    ga, gb = a.grid(a.ground_z), b.grid(b.ground_z)
    assert ga.shape != gb.shape or not np.array_equal(np.isfinite(ga), np.isfinite(gb)) or \
        np.nanmax(np.abs(ga - gb)) > 0.1


def test_mount_and_rotations_round_trip():
    R = rpy_to_matrix(0.1, -0.4, 2.0)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(quaternion_to_matrix(matrix_to_quaternion(R)), R, atol=1e-12)
    # yaw alone turns x into y (REP-103)
    np.testing.assert_allclose(rpy_to_matrix(0, 0, np.pi / 2) @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    mount = Mount(DEFAULT_OFFSET)
    R_c, t_c = rpy_to_matrix(0.05, 0.0, 1.0), np.array([3.0, -2.0, 8.0])
    R_s, t_s = mount.sensor_pose(R_c, t_c)
    np.testing.assert_allclose(t_s, R_c @ DEFAULT_OFFSET[:3] + t_c)
    back = mount.body_pose(R_s, t_s)
    np.testing.assert_allclose(back[0], R_c, atol=1e-12)
    np.testing.assert_allclose(back[1], t_c, atol=1e-12)


def _stream(**stream):
    return Stream(Assessor(small_config()), StreamConfig(**stream))


def _cloud(types, stamp, frame):
    xyz = np.random.default_rng(0).uniform(-1, 1, (50, 3)).astype(np.float32)
    xyz[:, 2] -= 8.0
    return make_cloud(points_to_structured(xyz), make_header(stamp, frame, types), types)


def test_unusable_odometry_is_a_counted_drop_with_a_warning_naming_it():
    types = MessageTypes.rosbags()
    stamp = 10 * NS
    # an odometry in another frame: the pose and the cloud that needed it, both as wrong_frame
    s = _stream(cloud_frame='body', sensor_offset=(0.1, 0, 0, 0, 0, 0))
    said = []
    s.on_drop = lambda reason, message: said.append((reason, message))
    s.add_pose_msg(make_odometry(stamp, 'odom', 'base_link', [0, 0, 8], [0, 0, 0, 1], types))
    s.add_cloud_msg(_cloud(types, stamp, 'base_link'))
    s.flush()
    assert s.clouds == 0 and s.dropped_clouds['wrong_frame'] == 1
    assert s.dropped_poses['wrong_frame'] == 1
    assert any("frame_id 'odom', expected 'map'" in m for _, m in said)
    # no child frame, where the offset and the body cloud need one
    s = _stream(cloud_frame='body', sensor_offset=(0.1, 0, 0, 0, 0, 0))
    said = []
    s.on_drop = lambda reason, message: said.append((reason, message))
    s.add_pose_msg(make_odometry(stamp, 'map', '', [0, 0, 8], [0, 0, 0, 1], types))
    s.add_cloud_msg(_cloud(types, stamp, 'base_link'))
    s.flush()
    assert s.dropped_poses['no_child_frame'] == 1 and s.dropped_clouds['no_child_frame'] == 1
    assert any('child_frame_id is empty; sensor_offset and cloud_frame' in m for _, m in said)
    # ... but a registered cloud without an offset needs none
    s = _stream()
    s.add_pose_msg(make_odometry(stamp, 'map', '', [0, 0, 8], [0, 0, 0, 1], types))
    s.add_cloud_msg(_cloud(types, stamp, 'map'))
    assert s.clouds == 1
    # a body cloud in the fixed frame, or in a frame not the odometry's child: wrong_frame
    s = _stream(cloud_frame='body')
    s.add_pose_msg(make_odometry(stamp, 'map', 'base_link', [0, 0, 8], [0, 0, 0, 1], types))
    s.add_cloud_msg(_cloud(types, stamp, 'map'))
    s.add_cloud_msg(_cloud(types, stamp, 'imu'))
    assert s.dropped_clouds['wrong_frame'] == 2 and s.clouds == 0
    s.add_cloud_msg(_cloud(types, stamp, 'base_link'))
    assert s.clouds == 1
    # a PoseStamped after odometry: a second input, not mixed in
    s.add_pose_msg(make_pose_stamped(stamp + NS, 'map', [5, 5, 8], [0, 0, 0, 1], types))
    assert s.dropped_poses['second_input'] == 1 and s.poses == 1
    # no pose at all: no_pose
    s = _stream()
    s.add_cloud_msg(_cloud(types, stamp, 'map'))
    s.flush()
    assert s.dropped_clouds['no_pose'] == 1


def test_simulate_odometry_flight_writes_the_bag_and_its_labels(tmp_path):
    from landing_zone.io.bags import bag_topics
    from landing_zone.tools.sim.flight import FlightConfig
    from landing_zone.tools.sim.odometry_flight import simulate_odometry_flight

    flight, odom = simulate_odometry_flight(
        FlightConfig(seed=1, size=6.0, obstacles=1, lines_per_cloud=14), tmp_path / 'o.mcap',
        cloud_frame='sensor', sensor_offset=(0.0, 0.1, -0.1, 0.05, 0.2, 0.0))
    assert odom.bag.is_file() and odom.labels == tmp_path / 'o.labels.json'
    assert odom.labels.is_file() and odom.clouds == flight.clouds
    assert bag_topics(odom.bag) == {'/lidar/points': 'sensor_msgs/msg/PointCloud2',
                                    '/odometry': 'nav_msgs/msg/Odometry'}
    assert odom.replay_args() == ['--points-topic', '/lidar/points', '--pose-topic', '/odometry',
                                  '--cloud-frame', 'sensor', '--sensor-offset', '0', '0.1',
                                  '-0.1', '0.05', '0.2', '0']
