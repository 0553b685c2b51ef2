"""The ROS 2 front end: the ``assessor`` node (``ros2 run landing_zone assessor``).

Topics (docs/INTERFACES.md §1): clouds on ``points`` and the pose of a frame C on
``sensor_pose`` (PoseStamped: the sensor) or ``odometry`` (nav_msgs/Odometry: its child frame, the
body), whichever is published, in (sensor-data QoS: best effort, so it matches reliable and
best-effort publishers alike; ``qos_reliability: reliable`` asks for retransmission). The clouds
are registered in ``frame_id`` or, with ``cloud_frame`` ``body`` or ``sensor``, in C or in the
LiDAR's frame (``sensor_offset`` in C), and registered here with C's pose at their stamp.
``~/safety_grid``, ``~/safety_cloud``, ``~/landing_sites``, ``~/landing_sites_cloud`` (each
site's P(safe), slope, step and clearance), ``~/markers`` out (reliable, transient local, depth
1, so a planner that joins late gets the latest), and ``/diagnostics``.

The node is a thin adapter over :class:`~landing_zone.runtime.ingest.LivePipeline`, which
drives the :class:`~landing_zone.runtime.stream.Stream` and
:class:`~landing_zone.assessor.Assessor` that ``landing-zone replay`` drives too:

* **ready before listening**: the model loads, a saved map snapshot is restored
  (``snapshot.path``), every kernel and the network run once on a synthetic cloud
  (:func:`~landing_zone.runtime.ingest.warm_up`), and only then are the subscriptions
  created; the log says ``ready in X s``;
* **the executor only takes messages**: a cloud's serialized bytes are taken with its
  publisher's GID and sequence number (:mod:`landing_zone.ros.rcl_take`) and queued, a
  pose is queued; decoding and integration run on the pipeline's integration thread, assessment and
  publishing on its assessment thread, so the executor is never held by numba or torch;
* **every cloud is accounted for** in ``/diagnostics``: ``clouds integrated`` plus the
  ``dropped clouds: REASON`` counts equals the clouds published (gaps in each publisher's
  sequence numbers count as ``transport``; see :mod:`landing_zone.runtime.ingest` for every
  reason);
* **overload** (input faster than integration): the receive queue keeps the newest
  ``receive_queue`` clouds, the oldest are dropped and counted as ``overload``, diagnostics go
  WARN, and all of it recovers by itself when the input slows down;
* bad input (malformed clouds, NaN/Inf, wrong frame, an odometry without the child frame the
  offset needs, out-of-order stamps, no pose yet) is counted by reason and warned about at most
  every ``warn_period`` seconds per reason; the map is never touched by it;
* **stale input**: ``/diagnostics`` carries the age of the newest cloud and pose and goes WARN
  when either has not come for ``stale_after`` seconds, ERROR past ``stale_error``, and OK again
  by itself when they resume;
* a parameter the node does not have (a misspelt name on the command line or in a parameters
  file) stops it at start with one line naming the closest real name;
* the map is saved to ``snapshot.path`` every ``snapshot.period`` seconds and on shutdown
  (:mod:`landing_zone.runtime.snapshot`); a restart reloads it when frame, map and region match.

Parameters are the dotted names of :meth:`AssessorConfig.to_flat` (``map.voxel_size``, ...) plus
the stream's timing (:class:`~landing_zone.config.StreamConfig`), the receive path's bounds
(:class:`~landing_zone.config.LiveConfig`) and the node's own
(:class:`~landing_zone.config.NodeConfig`), each declared with a :class:`ParameterDescriptor`
made from its facts in :data:`landing_zone.config.PARAMETERS`; ``config/assessor.yaml`` lists
them all.
"""
from __future__ import annotations

import sys
import threading
import time
from typing import Any

import rclpy
from rcl_interfaces.msg import (FloatingPointRange, IntegerRange, ParameterDescriptor,
                                ParameterType, SetParametersResult)
from rclpy.exceptions import ParameterException, ParameterUninitializedException
from rclpy._rclpy_pybind11 import RCLError
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy,
                       qos_profile_sensor_data)

from landing_zone.config import (PARAMETERS, SECTIONS, NodeConfig, configs_from_flat,
                                 default_parameters, live_config, unknown_parameter_error)
from landing_zone.errors import ConfigError, LandingZoneError
from landing_zone.runtime.ingest import LivePipeline, stale_level
from landing_zone.runtime.stream import NS, Stream

__all__ = ['AssessorNode', 'main']

NODE_NAME = 'assessor'

# NodeConfig.qos_reliability's choices as rclpy's policies
QOS_RELIABILITY = {'best_effort': ReliabilityPolicy.BEST_EFFORT,
                   'reliable': ReliabilityPolicy.RELIABLE}
# Messages the executor takes from a subscription in one go (then it looks at the others).
TAKE_BATCH = 64
_LEVELS = ('OK', 'WARN', 'ERROR')
USAGE = """usage: assessor [-h] [--version] [--ros-args ...]

The landing_zone assessor node: LiDAR clouds and poses in, a per-tile P(safe) grid and
landing sites out (docs/ROS_NODE.md, docs/INTERFACES.md).

examples:
  ros2 run landing_zone assessor --ros-args --params-file config/assessor.yaml
  assessor --ros-args -r points:=/cloud_registered -r odometry:=/Odometry
  assessor --ros-args -r points:=/cloud_registered_body -r odometry:=/Odometry \\
      -p cloud_frame:=body -p "sensor_offset:=[0.0, 0.0, 0.1, 0.0, 0.0, 0.0]"
  ros2 launch landing_zone assessor.launch.py odometry:=/Odometry cloud_frame:=body

options:
  -h, --help  show this help and exit
  --version   print the version and exit
"""


def _descriptor(name: str, value: Any) -> ParameterDescriptor:
    """The descriptor of a parameter, from its facts in :data:`landing_zone.config.PARAMETERS`.

    rcl checks closed ranges; an open end (``[0.5, 1)``) is advertised closed and the endpoint
    itself refused by the on-set check, which validates the whole configuration.
    """
    p = PARAMETERS[name][1]
    d = ParameterDescriptor(name=name, description=p.text, read_only=p.read_only)
    if p.range is not None and isinstance(value, float):
        d.floating_point_range = [FloatingPointRange(from_value=float(p.range[0]),
                                                     to_value=float(p.range[1]), step=0.0)]
    elif p.range is not None and isinstance(value, int) and not isinstance(value, bool):
        d.integer_range = [IntegerRange(from_value=int(p.range[0]), to_value=int(p.range[1]),
                                        step=1)]
    return d


def _node_configs(rest: dict[str, Any]) -> None:
    """Validate the node's own parameters and the receive path's among ``rest``.

    Raises:
        ConfigError: a value out of range or not one of the choices.
    """
    NodeConfig.from_flat(rest)
    live_config(rest)


class AssessorNode(Node):
    """The ``assessor`` node; see the module docstring.

    Raises (from the constructor):
        ModelError: the model file is missing or invalid.
        ConfigError: parameters out of range or inconsistent.
    """

    def __init__(self, **kwargs: Any) -> None:
        t_start = time.perf_counter()
        super().__init__(NODE_NAME, **kwargs)
        defaults = default_parameters()
        self.declare_parameters('', [(name, value, _descriptor(name, value))
                                     for name, value in defaults.items()])
        self.declare_parameter('region_center', Parameter.Type.DOUBLE_ARRAY,
                               ParameterDescriptor(
                                   name='region_center', type=ParameterType.PARAMETER_DOUBLE_ARRAY,
                                   description=PARAMETERS['region_center'][1].text,
                                   read_only=True))
        self._names = list(defaults) + ['region_center']
        # a name given on the command line or in a parameters file that is no parameter here:
        # refuse to start rather than run with the default the user meant to change
        unknown = unknown_parameter_error(sorted(self._parameter_overrides))
        if unknown is not None:
            raise unknown
        config, stream_config, rest = configs_from_flat(self._flat())
        NodeConfig.from_flat(rest)
        live = live_config(rest)
        self.settings = rest
        self._warners: dict[str, Any] = {}
        self._reported: dict[str, int] = {}
        self._publish_lock = threading.Lock()
        self.add_on_set_parameters_callback(self._check_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)
        # the model loads here: a missing or broken one stops the node before any topic exists
        from landing_zone.assessor import Assessor
        self.assessor = Assessor(config)
        t_model = time.perf_counter() - t_start
        self._restored = self._load_snapshot()
        from landing_zone.runtime.ingest import warm_up
        t_warm = warm_up(self.assessor, build=self._build)
        self.stream = Stream(self.assessor, stream_config)
        self.stream.on_drop = self._warn
        self.pipeline = LivePipeline(self.stream, live, publish=self._publish,
                                     on_error=self._warn)
        self._last_snapshot = time.monotonic()
        self._snapshot_lock = threading.Lock()
        self.pipeline.assess_hooks.append(self._periodic_snapshot)

        latched = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseArray
        from nav_msgs.msg import OccupancyGrid
        from sensor_msgs.msg import PointCloud2
        from visualization_msgs.msg import MarkerArray
        self._pubs = [self.create_publisher(OccupancyGrid, '~/safety_grid', latched),
                      self.create_publisher(PointCloud2, '~/safety_cloud', latched),
                      self.create_publisher(PoseArray, '~/landing_sites', latched),
                      self.create_publisher(PointCloud2, '~/landing_sites_cloud', latched),
                      self.create_publisher(MarkerArray, '~/markers', latched)]
        self._pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.pipeline.start()
        if self._restored is not None:
            self._publish(self.assessor.assess(), self._restored)
        self.create_timer(float(rest['diagnostics_period']), self._publish_diagnostics)
        self.ready_seconds = self._subscribe(rest, t_start)
        mode = ('following the sensor' if config.center is None
                else f'fixed at ({config.center[0]:g}, {config.center[1]:g})')
        self.get_logger().info(
            f'ready in {self.ready_seconds:.2f} s (model {t_model:.2f} s, warm-up '
            f'{t_warm:.2f} s): assessing {config.map.size_xy:g} m of '
            f'{config.tiles.tile_size:g} m tiles in frame {config.frame_id!r}, {mode}; model '
            f'{self.assessor.model_path} ({self.assessor.model.config.spec}); OOD reference '
            f'{self._ood_text()}; listening on {self._points_topic} ({stream_config.cloud_frame} '
            f'frame) with poses from {self._pose_topics}')

    def _ood_text(self) -> str:
        """Which OOD reference judges with the model, for the log and /diagnostics."""
        a = self.assessor
        if a.ood is None:
            why = 'ood.enabled false' if not a.config.ood.enabled else 'none beside the model'
            return f'none ({why}: the signal is off)'
        return str(a.ood_path)

    def _subscribe(self, rest: dict[str, Any], t_start: float) -> float:
        """Create the input subscriptions (the last thing the node does before it is ready)."""
        from geometry_msgs.msg import PoseStamped
        from nav_msgs.msg import Odometry
        from sensor_msgs.msg import PointCloud2

        from landing_zone.ros.rcl_take import taker, taker_error

        sensor_qos = QoSProfile(depth=int(rest['qos_depth']),
                                history=HistoryPolicy.KEEP_LAST,
                                reliability=QOS_RELIABILITY[rest['qos_reliability']],
                                durability=qos_profile_sensor_data.durability)
        take = taker()
        if take is not None:
            sub = self.create_subscription(PointCloud2, 'points', self._on_taken, sensor_qos,
                                           raw=True)

            def take_batch(s: Any) -> tuple[list[Any]] | None:
                batch = []
                while len(batch) < TAKE_BATCH:
                    try:
                        taken = take.take(s)
                    except OSError as err:  # rcl failed to take one: it shows as a gap
                        self._warn('take', f'taking a cloud failed: {err}')
                        break
                    if taken is None:
                        break
                    batch.append(taken)
                return (batch,) if batch else None
            sub.lz_take = take_batch  # type: ignore[attr-defined]
        else:
            self.get_logger().warn(f'publisher GIDs unavailable ({taker_error()}); sequence '
                                   'gaps are counted as if one publisher sent every cloud')
            sub = self.create_subscription(PointCloud2, 'points', self._on_raw, sensor_qos,
                                           raw=True)
        self._points_topic = sub.topic_name
        # either pose input; the stream takes the first kind that comes and counts the other
        poses = [self.create_subscription(PoseStamped, 'sensor_pose', self._on_pose, sensor_qos),
                 self.create_subscription(Odometry, 'odometry', self._on_pose, sensor_qos)]
        self._pose_topics = ' or '.join(p.topic_name for p in poses)
        return time.perf_counter() - t_start

    def destroy_node(self) -> None:
        """Destroy the node, then release the assessor's threads."""
        super().destroy_node()
        self.assessor.close()

    # -- parameters -------------------------------------------------------------------------

    def _flat(self, override: dict[str, Any] | None = None) -> dict[str, Any]:
        flat = {}
        for name in self._names:
            try:
                flat[name] = self.get_parameter(name).value
            except ParameterUninitializedException:
                flat[name] = None
        flat.update(override or {})
        return flat

    def _check_parameters(self, params: list[Parameter]) -> SetParametersResult:
        """Refuse a change that would give an invalid configuration (ranges are checked by rcl
        from the descriptors already; this checks consistency across parameters)."""
        try:
            _node_configs(configs_from_flat(self._flat({p.name: p.value for p in params}))[2])
        except ConfigError as err:
            return SetParametersResult(successful=False, reason=str(err))
        return SetParametersResult(successful=True)

    def _apply_parameters(self, params: list[Parameter]) -> None:
        config, stream_config, rest = configs_from_flat(self._flat())
        a = self.assessor
        # only writable parameters get here; copy every section mechanically
        for section in SECTIONS:
            live, new = getattr(a.config, section), getattr(config, section)
            for name, value in vars(new).items():
                setattr(live, name, value)
        for name, value in vars(stream_config).items():
            setattr(self.stream.config, name, value)
        self.stream.poses_buffer.tolerance_ns = int(round(stream_config.pose_tolerance * NS))
        self.pipeline.config.idle_flush = float(rest['idle_flush'])
        self.pipeline.config.eager_interval = float(rest['eager_interval'])
        self.settings.update(rest)
        if any(p.name.startswith(('tiles.', 'guard.')) or p.name == 'landing_sites.clutter_height'
               for p in params):
            a.invalidate()  # every tile is judged again under the new thresholds
        # the other limits of landing_sites apply at the next pass (sites are chosen afresh)
        self.get_logger().info('parameters changed: ' + ', '.join(
            f'{p.name}={p.value}' for p in params))

    # -- input (the executor thread: take and queue, nothing else) -------------------------

    def _warn(self, reason: str, message: str) -> None:
        # one child logger per reason, so one kind of bad input does not hide another
        logger = self._warners.get(reason)
        if logger is None:
            logger = self._warners[reason] = self.get_logger().get_child(reason)
        logger.warn(message, throttle_duration_sec=float(self.settings['warn_period']))

    def _on_taken(self, batch: list[Any]) -> None:
        for t in batch:
            self.pipeline.offer_cloud(t.data, t.publisher, t.seq)

    def _on_raw(self, data: bytes, info: Any) -> None:
        # two required arguments: rclpy passes its MessageInfo only to such a callback
        self.pipeline.offer_cloud(data, None, info.get('publication_sequence_number'))

    def _on_pose(self, msg: Any) -> None:
        self.pipeline.offer_pose(msg)

    # -- output (the assessment thread) ----------------------------------------------------

    def _builders(self) -> list[Any]:
        """The message builders, in the order of the publishers (the grid first: it goes out
        before the others are built)."""
        from msg_adapters import grid

        return [grid.safety_grid, grid.safety_cloud, grid.landing_site_poses,
                grid.landing_sites_cloud, grid.markers]

    def _build(self, result: Any, stamp: int = 0) -> list[Any]:
        return [build(result, stamp) for build in self._builders()]

    def _publish(self, result: Any, stamp: int | None = None) -> None:
        if stamp is None:
            stamp = self.stream.assessed_stamp_ns
        if stamp is None:
            stamp = self.get_clock().now().nanoseconds
        with self._publish_lock:
            try:
                for pub, build in zip(self._pubs, self._builders()):
                    pub.publish(build(result, stamp))
            except RCLError:
                if rclpy.ok(context=self.context):
                    raise  # shutting down: the last grid may find the context gone

    def _load_snapshot(self) -> int | None:
        """Restore the snapshot file if it matches; return its stamp [ns] (None: no map)."""
        from landing_zone.runtime.snapshot import SnapshotError, load_snapshot

        path = str(self.settings.get('snapshot.path') or '')
        if not path:
            return None
        import os
        if not os.path.exists(path):
            self.get_logger().info(f'no snapshot at {path} yet: starting with an empty map')
            return None
        try:
            header = load_snapshot(path, self.assessor)
        except SnapshotError as err:
            self.get_logger().error(f'snapshot refused: {err}; starting with an empty map')
            return None
        note = '' if header['tiles_restored'] else ' (made by another model: tiles judged again)'
        self.get_logger().info(f'snapshot {path} restored: {header.get("clouds", 0)} clouds '
                               f'from {time.ctime(header.get("saved_at", 0))}{note}')
        if header.get('stamp_ns') is not None:
            return int(header['stamp_ns'])
        stamp = self.assessor.last_stamp
        return int(round(stamp * NS)) if stamp is not None else 0

    def save_snapshot(self) -> None:
        """Write the map snapshot now (if ``snapshot.path`` is set); errors are logged."""
        from landing_zone.runtime.snapshot import SnapshotError, save_snapshot

        path = str(self.settings.get('snapshot.path') or '')
        if not path:
            return
        with self._snapshot_lock:
            newest = self.stream.stamp_span[1]
            try:
                save_snapshot(path, self.assessor,
                              newest if newest is not None else self._restored)
            except SnapshotError as err:
                self._warn('snapshot', str(err))
            self._last_snapshot = time.monotonic()

    def _periodic_snapshot(self) -> None:
        if self.settings.get('snapshot.path') and \
                time.monotonic() - self._last_snapshot >= float(self.settings['snapshot.period']):
            self.save_snapshot()

    def finish(self) -> None:
        """Integrate and assess what is queued, stop the threads, save the snapshot."""
        self.pipeline.stop(drain=True, timeout=10.0)
        self.save_snapshot()

    def _publish_diagnostics(self) -> None:
        from msg_adapters import grid

        values = self.pipeline.diagnostics()
        values['ready time [s]'] = f'{self.ready_seconds:.2f}'
        values['OOD reference'] = self._ood_text()
        drops = self.pipeline.dropped_clouds()
        grew = {r: n - self._reported.get(r, 0) for r, n in drops.items()
                if n > self._reported.get(r, 0)}
        self._reported = drops
        if grew:
            level = 'WARN'
            message = 'clouds dropped since the last report: ' + ', '.join(
                f'{n} {r}' for r, n in sorted(grew.items()))
            if 'overload' in grew:
                message = 'overload, the newest clouds are kept; ' + message
        elif self.stream.clouds == 0:
            level, message = 'WARN', 'no cloud integrated yet'
        elif self.pipeline.errors:
            level, message = 'ERROR', f'internal error: {self.pipeline.errors[-1]!r}'
        else:
            level, message = 'OK', f'{self.stream.clouds} clouds integrated'
        stale, why = stale_level(self.pipeline.input_ages(), float(self.settings['stale_after']),
                                 float(self.settings['stale_error']))
        if stale != 'OK':
            message = why if level == 'OK' else f'{why}; {message}'
            level = max(level, stale, key=_LEVELS.index)
        self._pub_diag.publish(grid.diagnostics(values, self.get_clock().now().nanoseconds,
                                                name=f'{self.get_name()}: landing zone',
                                                level=level, message=message))


def main(args: list[str] | None = None) -> None:
    """Entry point of ``assessor`` (talker_qos.py's shutdown idiom); exit 1 if it cannot start."""
    from landing_zone.ros.rcl_take import executor_with_taker

    argv = list(sys.argv if args is None else args)
    own = argv[1:argv.index('--ros-args')] if '--ros-args' in argv else argv[1:]
    if '-h' in own or '--help' in own:
        print(USAGE, end='')
        return
    if '--version' in own:
        from landing_zone import __version__
        print(f'assessor (landing_zone) {__version__}')
        return
    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = AssessorNode()
        executor = executor_with_taker(SingleThreadedExecutor)()
        executor.add_node(node)
        executor.spin()
    except (LandingZoneError, ParameterException) as err:
        # a missing model or a bad parameter: one clear line, no traceback
        rclpy.logging.get_logger(NODE_NAME).fatal(f'cannot start: {err}')
        code = 1
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    except RCLError:
        # SIGINT shuts the context down from rclpy's signal handler; an executor thread
        # that was building its wait set at that instant reports an invalid context instead
        # of ExternalShutdownException. That is the same orderly shutdown; anything else is not.
        if rclpy.ok():
            raise
    finally:
        if node is not None:
            node.finish()
            node.destroy_node()
        rclpy.try_shutdown()
    if code:
        sys.exit(code)


if __name__ == '__main__':
    main()
