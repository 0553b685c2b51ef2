"""The `assessor` node as a robot's graph feeds it: odometry of the body and body-frame clouds,
a stale-input alarm, what a planner reads of the landing sites, a misspelt parameter, a bag
played to a ready node.

As test_node: the node runs as a subprocess in a DDS domain of this test's own, driven by
outside publishers (``landing-zone play``'s function in a process of its own, or the test's
private rclpy Context)."""
from __future__ import annotations

import subprocess
import sys
import time

import numpy as np
import pytest

pytest.importorskip('rclpy')

from landing_zone.config import AssessorConfig  # noqa: E402
from landing_zone.replay import replay  # noqa: E402
from landing_zone.tools.sim.odometry_flight import DEFAULT_OFFSET, odometry_flight  # noqa: E402
from msg_adapters.pointcloud import cloud_to_structured  # noqa: E402
from test_node import (ENV, Listener, flight, grid_values, listener, start_node,  # noqa: E402,F401
                       stop)

pytestmark = pytest.mark.ros

OFFSET = '[' + ', '.join(f'{v:.2f}' for v in DEFAULT_OFFSET) + ']'


@pytest.fixture(scope='module')
def odom_flight(flight, tmp_path_factory):  # noqa: F811
    """test_node's flight as Odometry of a body with body-frame clouds, the LiDAR off the body."""
    bag, stamps = flight
    out = odometry_flight(bag, tmp_path_factory.mktemp('odom') / 'odom.mcap',
                          cloud_frame='body')
    assert out.clouds == len(stamps)
    return out


def play_to(bag, *args, timeout=120):
    """landing_zone.ros.play.play with its defaults (it waits for the subscribers), in a
    process of its own."""
    code = ('import sys; from landing_zone.ros.play import play; '
            's = play(sys.argv[1], progress=False, reliability=sys.argv[2], '
            'rate=float(sys.argv[3])); print(s.subscribed, s.by_topic)')
    out = subprocess.run([sys.executable, '-c', code, str(bag), *map(str, args)], env=ENV,
                         capture_output=True, text=True, timeout=timeout)
    assert out.returncode == 0, out.stderr
    return out.stdout


class Planner(Listener):
    """The test's listener plus a planner's subscription to the sites."""

    def __init__(self):
        super().__init__()
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import PointCloud2

        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        topic = '/assessor/landing_sites_cloud'
        self.node.create_subscription(PointCloud2, topic, self._keeper(topic), latched)


@pytest.fixture
def planner():
    p = Planner()
    yield p
    p.close()


@pytest.mark.slow
@pytest.mark.parametrize('rate', [1.0, 4.0])
def test_odometry_and_body_frame_clouds_give_the_registered_grid(
        rate, flight, odom_flight, model_file, planner):  # noqa: F811
    """Odometry of the body + body-frame clouds with a non-zero sensor offset, played to a ready
    node: every cloud accounted for (1x and 4x); at 1x every cloud arrives (play waits for the
    subscribers), the grid is replay's of the PoseStamped + registered flight (|dP| <= 0.02,
    the same unknown tiles), and a planner reads every listed site's P(safe) live."""
    bag, stamps = flight
    node = start_node('-p', f'model.path:={model_file}', '-p', 'diagnostics_period:=0.2',
                      '-p', 'idle_flush:=0.5', '-p', 'landing_sites.min_p_safe:=0.0',
                      '-p', 'cloud_frame:=body', '-p', f'sensor_offset:={OFFSET}',
                      '-r', 'points:=/lidar/points', '-r', 'odometry:=/odometry')
    try:
        # ready: it publishes diagnostics once it spins, after it subscribed
        assert planner.spin_until(lambda: 'clouds integrated' in planner.diag(), 60), stop(node)
        out = play_to(odom_flight.bag, 'best_effort', rate)
        assert out.startswith('2 '), out  # both topics had their subscriber
        assert planner.spin_until(lambda: planner.accounted(len(stamps)), timeout=60), \
            (planner.diag(), stop(node))
        planner.spin_until(lambda: False, timeout=0.5)
        integrated, drops = planner.accounted(len(stamps))
        assert integrated + sum(drops.values()) == len(stamps), drops
        if rate == 1.0:
            assert integrated == len(stamps) and drops['missed_at_start'] == 0, drops
            assert planner.spin_until(lambda: planner.grid_at(stamps[-1]), timeout=30)
            sites, grids = '/assessor/landing_sites_cloud', '/assessor/safety_grid'
            planner.spin_until(lambda: planner.count.get(sites, 0)
                               >= planner.count.get(grids, 0), 5)
    finally:
        log = stop(node)
    assert node.returncode == 0, log
    assert "(body frame) with poses from /sensor_pose or /odometry" in log, log
    if rate != 1.0:
        return
    cfg = AssessorConfig()
    cfg.landing_sites.min_p_safe = 0.0
    ref = replay(bag, model=model_file, progress=False, config=cfg).assessment
    values = grid_values(planner.last['/assessor/safety_grid'])
    assert values.shape == ref.shape
    ref_p = ref.grid(ref.p_safe)
    np.testing.assert_array_equal(values == -1, ~np.isfinite(ref_p))
    known = np.isfinite(ref_p)
    assert known.sum() > 50
    assert np.abs(values[known] - np.rint(100 * (1 - ref_p[known]))).max() <= 2
    # the planner's view: the sites of the PoseArray, in its order, each with its P(safe)
    poses = planner.last['/assessor/landing_sites'].poses
    sites = cloud_to_structured(planner.last['/assessor/landing_sites_cloud'])
    assert len(sites) == len(poses) > 0
    assert set(sites.dtype.names) == {'x', 'y', 'z', 'p_safe', 'slope_deg', 'step', 'clearance'}
    assert all(sites.dtype[n] == np.float32 for n in sites.dtype.names)
    np.testing.assert_allclose(sites['x'], [p.position.x for p in poses], atol=1e-4)
    np.testing.assert_allclose(sites['y'], [p.position.y for p in poses], atol=1e-4)
    assert np.all((sites['p_safe'] >= 0) & (sites['p_safe'] <= 1))
    assert np.all(np.diff(sites['p_safe']) <= 1e-6) or len(sites) == 1  # best first
    near = {(round(s.x, 2), round(s.y, 2)): s.p_safe for s in ref.sites}
    for s in sites:
        key = (round(float(s['x']), 2), round(float(s['y']), 2))
        if key in near:
            assert abs(near[key] - float(s['p_safe'])) <= 0.02


def _publishers(lst):
    from geometry_msgs.msg import PoseStamped
    from nav_msgs.msg import Odometry
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import PointCloud2

    n = lst.node
    return (n.create_publisher(PointCloud2, '/lidar/points', qos_profile_sensor_data),
            n.create_publisher(Odometry, '/odometry', qos_profile_sensor_data),
            n.create_publisher(PoseStamped, '/lidar/pose', qos_profile_sensor_data))


def _cloud(stamp_ns, frame):
    from sensor_msgs.msg import PointCloud2, PointField

    rng = np.random.default_rng(stamp_ns % 1000)
    n = 3000
    xyz = np.column_stack([rng.uniform(-4, 4, (n, 2)), np.full(n, -8.0)]).astype(np.float32)
    m = PointCloud2(height=1, width=n, point_step=12, row_step=12 * n, is_dense=True,
                    fields=[PointField(name=c, offset=4 * i, datatype=7, count=1)
                            for i, c in enumerate('xyz')], data=xyz.tobytes())
    m.header.frame_id = frame
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    return m


def _odometry(stamp_ns, frame='map', child='base_link'):
    from nav_msgs.msg import Odometry

    m = Odometry()
    m.header.frame_id, m.child_frame_id = frame, child
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
    m.pose.pose.position.x = 0.2 * (stamp_ns / 1e9 - 100)
    m.pose.pose.position.z = 8.0
    m.pose.pose.orientation.w = 1.0
    return m


def test_bad_pose_input_is_counted_and_stale_input_goes_warn_then_error_then_ok(
        model_file, listener):  # noqa: F811
    """One node, fed in phases by an outside publisher at 10 Hz: good odometry + body clouds
    (OK), clouds without poses (no_pose, WARN), odometry in another frame (wrong_frame), odometry
    without a child frame (no_child_frame); then nothing (WARN within stale_after + one
    diagnostics period, ERROR past stale_error), then good input again (OK). Every cloud is
    accounted for and each kind of bad input warned about once."""
    from diagnostic_msgs.msg import DiagnosticArray

    stale_after, stale_error, period = 0.5, 1.5, 0.2
    node = start_node('-p', f'model.path:={model_file}', '-p', f'diagnostics_period:={period}',
                      '-p', f'stale_after:={stale_after}', '-p', f'stale_error:={stale_error}',
                      '-p', 'warn_period:=100.0', '-p', 'cloud_frame:=body',
                      '-p', f'sensor_offset:={OFFSET}', '-r', 'points:=/lidar/points',
                      '-r', 'odometry:=/odometry', '-r', 'sensor_pose:=/lidar/pose')
    levels = []  # (arrival, level) of every diagnostics message
    lst = listener

    def keep_time(msg):
        levels.append((time.monotonic(), msg.status[0].level[0]))
    lst.node.create_subscription(DiagnosticArray, '/diagnostics', keep_time, 1000)
    published = 0
    stamp = [100 * 1_000_000_000]
    last = [0.0]  # when the last message was published
    try:
        clouds, odom, _ = _publishers(lst)
        assert lst.spin_until(lambda: clouds.get_subscription_count() > 0
                              and odom.get_subscription_count() > 0, 60), stop(node)
        lst.spin_until(lambda: False, 0.5)

        def phase(seconds, pose=None, cloud=True):
            nonlocal published
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                stamp[0] += 100_000_000
                if pose is not None:
                    odom.publish(pose(stamp[0]))
                if cloud:
                    clouds.publish(_cloud(stamp[0], 'base_link'))
                    published += 1
                last[0] = time.monotonic()
                lst.spin_until(lambda: False, 0.1)

        def diag_int(key):
            return int(lst.diag().get(key, 0))

        phase(1.5, _odometry)
        assert lst.spin_until(lambda: diag_int('clouds integrated') >= 5, 10), lst.diag()
        assert lst.spin_until(lambda: lst.levels[-1] == 0, 5), (lst.diag(), lst.levels[-5:])
        phase(1.2, None)  # clouds, no pose
        assert lst.spin_until(lambda: diag_int('dropped clouds: no_pose') >= 1, 5), lst.diag()
        assert 'no pose for' in lst.last['/diagnostics'].status[0].message or \
            1 in lst.levels[-8:]
        phase(0.6, lambda s: _odometry(s, frame='odom'))
        phase(0.6, lambda s: _odometry(s, child=''))
        assert lst.spin_until(lambda: diag_int('dropped clouds: wrong_frame') >= 1
                              and diag_int('dropped clouds: no_child_frame') >= 1, 5), lst.diag()
        assert diag_int('dropped poses: wrong_frame') >= 1
        assert diag_int('dropped poses: no_child_frame') >= 1
        phase(0.8, _odometry)  # good again, then silence
        assert lst.spin_until(lambda: lst.levels[-1] == 0, 5), lst.levels[-5:]
        t_stop = last[0]
        assert lst.spin_until(lambda: any(t > t_stop and lv == 2 for t, lv in levels),
                              stale_error + 3), levels[-10:]
        first_warn = min(t for t, lv in levels if t > t_stop and lv >= 1)
        first_error = min(t for t, lv in levels if t > t_stop and lv == 2)
        # a little for the message's way here on a shared machine
        assert first_warn - t_stop <= stale_after + period + 0.3, first_warn - t_stop
        assert first_error - t_stop > stale_error
        msg = lst.last['/diagnostics'].status[0]
        assert 'no cloud for' in msg.message and 'no pose for' in msg.message, msg.message
        assert float(lst.diag()['newest cloud age [s]']) >= stale_error  # 2 decimals
        phase(1.0, _odometry)  # resumes: OK by itself
        assert lst.spin_until(lambda: lst.levels[-1] == 0, 5), lst.levels[-5:]
        assert float(lst.diag()['newest cloud age [s]']) < stale_after
        assert lst.spin_until(lambda: lst.accounted(published), 10), lst.diag()
        integrated, drops = lst.accounted(published)
        assert integrated + sum(drops.values()) == published, drops
    finally:
        log = stop(node)
    assert node.returncode == 0, log
    # throttled: one warning per kind, the pose's and the cloud's
    assert log.count("[assessor.pose_wrong_frame]: odometry dropped: frame_id 'odom', "
                     "expected 'map'") == 1, log
    assert log.count('[assessor.wrong_frame]: cloud dropped: its pose was refused: odometry '
                     "dropped: frame_id 'odom'") == 1, log
    assert log.count('[assessor.pose_no_child_frame]: odometry dropped: child_frame_id is empty;'
                     " sensor_offset and cloud_frame 'body' need the frame it is the pose of"
                     ) == 1, log
    assert log.count('[assessor.no_child_frame]: cloud dropped: its pose was refused') == 1, log


def test_a_misspelt_parameter_stops_the_node_with_the_closest_name(tmp_path, model_file):
    for args in (['-p', 'landing_sites.footprint_radus:=2.0'],
                 ['--params-file', tmp_path / 'p.yaml']):
        (tmp_path / 'p.yaml').write_text(
            'assessor:\n  ros__parameters:\n    landing_sites:\n      footprint_radus: 2.0\n')
        proc = subprocess.run([sys.executable, '-m', 'landing_zone.ros.node', '--ros-args',
                               '-p', f'model.path:={model_file}', *map(str, args)], env=ENV,
                              capture_output=True, text=True, timeout=60)
        out = (proc.stdout + proc.stderr).strip().splitlines()
        assert proc.returncode == 1
        assert len(out) == 1 and "cannot start: unknown parameter 'landing_sites.footprint_radus'"\
            " (did you mean 'landing_sites.footprint_radius'?)" in out[0], out


def test_help_and_version_print_and_exit():
    from landing_zone import __version__

    for flag, expect in (('--help', 'usage: assessor'), ('-h', 'usage: assessor'),
                         ('--version', f'assessor (landing_zone) {__version__}')):
        proc = subprocess.run([sys.executable, '-m', 'landing_zone.ros.node', flag], env=ENV,
                              capture_output=True, text=True, timeout=30)
        assert proc.returncode == 0 and proc.stdout.startswith(expect), proc
