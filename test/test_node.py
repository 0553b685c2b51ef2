"""The `assessor` node over loopback DDS: driven by `play`, it ends where `replay` ends.

The node runs as a subprocess (``python -m landing_zone.frontends.node``) in a DDS domain of this
test's own (from its pid), discovery limited to localhost; the test listens with a private rclpy
Context.
"""
from __future__ import annotations

import os
import subprocess
import sys
import time

import numpy as np
import pytest

pytest.importorskip('rclpy')

from landing_zone.frontends.replay import replay  # noqa: E402
from msg_adapters import stamp_to_ns  # noqa: E402
from msg_adapters.pointcloud import cloud_to_structured  # noqa: E402

pytestmark = pytest.mark.ros

DOMAIN = str(100 + os.getpid() % 100)  # 100..199: clear of the usual 0 and the suite's 87
ENV = dict(os.environ, ROS_DOMAIN_ID=DOMAIN, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST',
           PYTHONUNBUFFERED='1')
# the defaults, but a history that holds every cloud of the short burst the test plays
NODE_ARGS = ['-p', 'idle_flush:=0.5', '-p', 'qos_depth:=200', '-r', 'points:=/lidar/points',
             '-r', 'sensor_pose:=/lidar/pose']


@pytest.fixture(scope='module')
def flight(tmp_path_factory):
    """A small simulated flight: an 8 m site with two obstacles, one pass (about 2 s)."""
    from landing_zone.io.bags import read_messages
    from landing_zone.sim.flight import FlightConfig, simulate_flight

    path = tmp_path_factory.mktemp('bag') / 'site.mcap'
    simulate_flight(FlightConfig(seed=1, size=8.0, obstacles=2), path)
    stamps = [m.stamp_ns for m in read_messages(path, ['/lidar/points'])]
    return path, stamps


def start_node(*ros_args):
    return subprocess.Popen([sys.executable, '-m', 'landing_zone.frontends.node', '--ros-args',
                             *map(str, ros_args)], env=ENV, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)


def stop(proc):
    if proc.poll() is None:
        proc.send_signal(2)  # SIGINT: the node's KeyboardInterrupt path
        try:
            proc.wait(timeout=15)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.stdout.read() if proc.stdout else ''


class Listener:
    """A private-context node that keeps the last message of each output topic."""

    def __init__(self):
        import rclpy
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseArray
        from nav_msgs.msg import OccupancyGrid
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
        from sensor_msgs.msg import PointCloud2

        os.environ.update(ROS_DOMAIN_ID=DOMAIN, ROS_AUTOMATIC_DISCOVERY_RANGE='LOCALHOST')
        self.context = rclpy.Context()
        rclpy.init(context=self.context, domain_id=int(DOMAIN))
        self.node = rclpy.create_node('test_listener', context=self.context)
        self.executor = rclpy.executors.SingleThreadedExecutor(context=self.context)
        self.executor.add_node(self.node)
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.last = {}
        self.count = {}
        for topic, cls, qos in [('/assessor/safety_grid', OccupancyGrid, latched),
                                ('/assessor/safety_cloud', PointCloud2, latched),
                                ('/assessor/landing_sites', PoseArray, latched),
                                ('/diagnostics', DiagnosticArray, 10)]:
            self.node.create_subscription(cls, topic, self._keeper(topic), qos)

    def _keeper(self, topic):
        def keep(msg):
            self.last[topic] = msg
            self.count[topic] = self.count.get(topic, 0) + 1
        return keep

    def spin_until(self, predicate, timeout):
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            self.executor.spin_once(timeout_sec=0.05)
            if predicate():
                return True
        return False

    def close(self):
        import rclpy
        self.executor.shutdown()
        self.node.destroy_node()
        rclpy.try_shutdown(context=self.context)


@pytest.fixture
def listener():
    lst = Listener()
    yield lst
    lst.close()


def test_node_driven_by_play_ends_where_replay_ends(tmp_path, flight, model_file, listener):
    bag, stamps = flight
    last_stamp = stamps[-1]
    node = start_node('-p', f'model.path:={model_file}', *NODE_ARGS)
    try:
        # the node subscribes once it has loaded the model; play waits for it (up to 60 s)
        played = subprocess.run([sys.executable, '-m', 'landing_zone', 'play', str(bag),
                                 '--rate', '1.0', '--wait', '60'], env=ENV,
                                capture_output=True, text=True, timeout=120)
        assert played.returncode == 0, played.stderr
        assert f'{len(stamps)} on /lidar/points' in played.stdout, played.stdout

        def final_grid():
            m = listener.last.get('/assessor/safety_grid')
            return m is not None and stamp_to_ns(m.header.stamp) == last_stamp

        assert listener.spin_until(final_grid, timeout=30), \
            f'no final grid; node said:\n{stop(node)}'
        listener.spin_until(lambda: stamp_to_ns(
            listener.last['/assessor/safety_cloud'].header.stamp) == last_stamp, timeout=5)

        def diagnosed():
            d = listener.last.get('/diagnostics')
            return d is not None and any(kv.key == 'clouds integrated'
                                         and kv.value == str(len(stamps))
                                         for kv in d.status[0].values)

        listener.spin_until(diagnosed, timeout=5)
    finally:
        log = stop(node)
    assert node.returncode == 0, log
    ref = replay(bag, None, None, model=model_file, progress=False).assessment
    grid = listener.last['/assessor/safety_grid']
    assert (grid.info.width, grid.info.height) == ref.shape
    assert grid.info.origin.position.x == ref.origin[0] * 1.0
    values = np.array(grid.data, np.int16).reshape(ref.shape[1], ref.shape[0]).T
    unknown = values == -1
    diag = {kv.key: kv.value for kv in listener.last['/diagnostics'].status[0].values}
    drops = sum(int(v) for k, v in diag.items() if k.startswith('dropped clouds'))
    if drops == 0 and diag['clouds integrated'] == str(len(stamps)):
        # nothing was lost on the way: the node assessed the same map as replay
        np.testing.assert_array_equal(unknown, ~np.isfinite(ref.grid(ref.p_safe)))
        cloud = cloud_to_structured(listener.last['/assessor/safety_cloud'])
        have = np.isfinite(ref.ground_z)
        np.testing.assert_allclose(cloud['z'], ref.ground_z[have], atol=1e-5)
        np.testing.assert_allclose(cloud['p_safe'], ref.p_safe[have], atol=6e-3,
                                   equal_nan=True)
        sites = listener.last['/assessor/landing_sites'].poses
        assert len(sites) == len(ref.sites)
    else:
        # A loaded machine made the node drop clouds (counted, by reason): the tiles those
        # clouds alone would have made judgeable may stay unknown, nothing else may differ.
        assert int(diag['clouds integrated']) + drops == len(stamps), diag
        assert not np.any(~unknown & ~np.isfinite(ref.grid(ref.p_safe))), diag
    known = ~unknown & np.isfinite(ref.grid(ref.p_safe))
    expect = np.rint(100 * (1 - ref.grid(ref.p_safe)[known]))
    # equal up to one percent step (bf16 batches may differ); with drops, tiles whose clouds
    # were lost may differ more, so that case only checks the judged tiles agree in sign
    if drops == 0:
        assert np.abs(values[known] - expect).max() <= 1
    else:
        assert np.mean((values[known] >= 50) == (expect >= 50)) > 0.9


def test_bad_input_is_counted_and_the_node_keeps_running(model_file, listener):
    from geometry_msgs.msg import PoseStamped
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import PointCloud2, PointField

    node = start_node('-p', f'model.path:={model_file}', '-p', 'diagnostics_period:=0.2',
                      '-p', 'warn_period:=100.0', *NODE_ARGS)
    try:
        pub = listener.node.create_publisher(PointCloud2, '/lidar/points',
                                             qos_profile_sensor_data)
        pose_pub = listener.node.create_publisher(PoseStamped, '/lidar/pose',
                                                  qos_profile_sensor_data)
        assert listener.spin_until(lambda: pub.get_subscription_count() > 0, timeout=60), \
            stop(node)
        xyz = np.zeros(3, np.float32).tobytes() * 4
        fields = [PointField(name=c, offset=4 * i, datatype=7, count=1)
                  for i, c in enumerate('xyz')]
        bad = [PointCloud2(height=1, width=4, point_step=12, row_step=48, data=xyz[:-3],
                           fields=fields),  # truncated
               PointCloud2(height=1, width=4, point_step=12, row_step=48, data=xyz,
                           fields=fields[:2]),  # no z
               PointCloud2(height=1, width=4, point_step=12, row_step=48, data=xyz,
                           fields=fields)]  # fine, but frame 'lidar'
        for i, m in enumerate(bad):
            m.header.frame_id = 'lidar' if i == 2 else 'map'
        pose = PoseStamped()
        pose.header.frame_id = 'map'
        pose.pose.position.x = float('nan')

        def counts():
            msg = listener.last.get('/diagnostics')
            if msg is None:
                return {}
            d = {kv.key: kv.value for kv in msg.status[0].values}
            return {k: int(d[f'dropped {k}']) for k in (
                'clouds: malformed', 'clouds: wrong_frame', 'poses: bad_pose')}

        def counted():
            c = counts()
            return bool(c) and c['clouds: malformed'] >= 2 and c['clouds: wrong_frame'] >= 2 \
                and c['poses: bad_pose'] >= 2

        # best effort: send a few rounds until each kind was seen at least twice
        deadline = time.monotonic() + 30
        while not counted() and time.monotonic() < deadline:
            for m in bad:
                pub.publish(m)
            pose_pub.publish(pose)
            listener.spin_until(counted, timeout=0.5)
        assert counted(), (counts(), stop(node))
        assert node.poll() is None  # still running
        level = listener.last['/diagnostics'].status[0].level
        assert level == b'\x01'  # WARN: nothing integrated yet
    finally:
        log = stop(node)
    assert node.returncode == 0, log
    # rate-limited: one warning per kind, however many came
    assert log.count("frame_id 'lidar'") == 1, log


def test_missing_model_refuses_to_start_with_one_line(tmp_path):
    proc = subprocess.run([sys.executable, '-m', 'landing_zone.frontends.node', '--ros-args', '-p',
                           f'model.path:={tmp_path / "none.safetensors"}'], env=ENV,
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 1
    out = (proc.stdout + proc.stderr).strip().splitlines()
    assert len(out) == 1 and 'cannot start: model file not found' in out[0], out
    assert 'Traceback' not in proc.stderr


def test_parameters_are_described_validated_and_applied(model_file, listener):
    from rcl_interfaces.srv import DescribeParameters, SetParameters
    from rclpy.parameter import Parameter

    from landing_zone.config import PARAMETERS, default_parameters

    # every parameter has a description; the YAML lists every one of them
    assert set(default_parameters()) | {'region_center'} == set(PARAMETERS)
    node = start_node('-p', f'model.path:={model_file}', *NODE_ARGS)
    try:
        n = listener.node
        setter = n.create_client(SetParameters, '/assessor/set_parameters')
        describe = n.create_client(DescribeParameters, '/assessor/describe_parameters')
        assert listener.spin_until(lambda: setter.service_is_ready(), timeout=60), stop(node)

        def call(client, request):
            future = client.call_async(request)
            listener.spin_until(future.done, timeout=10)
            return future.result()

        res = call(setter, SetParameters.Request(parameters=[
            Parameter(name, value=value).to_parameter_msg() for name, value in [
                ('tiles.min_returns', 40), ('map.voxel_size', 0.1),
                ('landing_sites.min_p_safe', 1.5), ('assessment_period', 0.5)]]))
        ok = [(r.successful, r.reason) for r in res.results]
        assert ok[0] == (True, '') and ok[3] == (True, '')
        assert not ok[1][0] and 'read-only' in ok[1][1]
        assert not ok[2][0] and 'range' in ok[2][1]
        desc = call(describe, DescribeParameters.Request(
            names=['map.voxel_size', 'tiles.min_returns', 'region_center']))
        d = {x.name: x for x in desc.descriptors}
        assert d['map.voxel_size'].read_only and d['map.voxel_size'].description
        assert d['map.voxel_size'].floating_point_range[0].to_value == 1.0
        assert not d['tiles.min_returns'].read_only
        assert d['tiles.min_returns'].integer_range[0].from_value == 0
        assert d['region_center'].read_only
    finally:
        log = stop(node)
    assert 'parameters changed: tiles.min_returns=40' in log


def test_params_file_has_the_ros_layout_and_every_default():
    import yaml

    from landing_zone.config import default_parameters
    from landing_zone.io.params import read_params_file

    root = os.path.join(os.path.dirname(__file__), '..', 'config', 'assessor.yaml')
    flat = read_params_file(root)
    assert flat == default_parameters()  # the file states every default, nothing else
    doc = yaml.safe_load(open(root))
    assert list(doc) == ['assessor'] and list(doc['assessor']) == ['ros__parameters']
