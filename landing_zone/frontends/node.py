"""The ROS 2 front end: the ``assessor`` node (``ros2 run landing_zone assessor``).

Topics (docs/INTERFACES.md §1): registered clouds on ``points`` and the sensor pose on
``sensor_pose`` in (sensor-data QoS); ``~/safety_grid``, ``~/safety_cloud``, ``~/landing_sites``,
``~/markers`` out (reliable, transient local, depth 1, so a planner that joins late gets the
latest), and ``/diagnostics``.

The node is a thin adapter over :class:`~landing_zone.frontends.stream.Stream` and
:class:`~landing_zone.assessor.Assessor`, the same objects ``landing-zone replay`` drives:

* the clouds and poses are integrated in their subscription callbacks (one mutually exclusive
  callback group, so they run in turn);
* assessment runs in a timer of a second group on a :class:`MultiThreadedExecutor`, so
  integration never waits for the network; the map's lock is held only while rays are added or
  counts are read;
* overload is bounded and counted: the DDS history keeps ``qos_depth`` clouds (older ones are
  dropped by DDS and counted from gaps in the publication sequence numbers as ``overrun``),
  at most ``max_pending`` clouds wait for their pose, and due assessments never queue up (a late
  pass takes in everything integrated meanwhile);
* bad input (malformed clouds, NaN/Inf, wrong frame, out-of-order stamps, no pose yet) is
  counted by reason, reported in ``/diagnostics`` and warned about at most every
  ``warn_period`` seconds per reason; the map is never touched by it.

Parameters are the dotted names of :meth:`AssessorConfig.to_flat` (``map.voxel_size``, ...) plus
the stream's timing (:class:`~landing_zone.config.StreamConfig`) and the node's own
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
from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
from rclpy.exceptions import ParameterException, ParameterUninitializedException
from rclpy._rclpy_pybind11 import RCLError
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import (DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy,
                       qos_profile_sensor_data)

from landing_zone.config import PARAMETERS, SECTIONS, configs_from_flat, default_parameters
from landing_zone.errors import ConfigError, LandingZoneError
from landing_zone.frontends.stream import NS, Stream

__all__ = ['AssessorNode', 'main']

NODE_NAME = 'assessor'

# How often the assessment timer looks whether a pass is due [s] (wall time).
TICK = 0.02


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


class AssessorNode(Node):
    """The ``assessor`` node; see the module docstring.

    Raises (from the constructor):
        ModelError: the model file is missing or invalid.
        ConfigError: parameters out of range or inconsistent.
    """

    def __init__(self, **kwargs: Any) -> None:
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
        config, stream_config, rest = configs_from_flat(self._flat())
        self.settings = rest
        # the model loads here: a missing or broken one stops the node before any topic exists
        from landing_zone.assessor import Assessor
        self.assessor = Assessor(config)
        self.stream = Stream(self.assessor, stream_config)
        self.stream.on_drop = self._warn
        self._ingest_lock = threading.Lock()  # the stream's input side: callbacks and flush
        self._last_input = time.monotonic()
        self._last_seq: int | None = None
        self._warners: dict[str, Any] = {}
        self._reported_drops = 0
        self.add_on_set_parameters_callback(self._check_parameters)
        self.add_post_set_parameters_callback(self._apply_parameters)

        ingest = MutuallyExclusiveCallbackGroup()
        assess = MutuallyExclusiveCallbackGroup()
        diag = MutuallyExclusiveCallbackGroup()
        from geometry_msgs.msg import PoseStamped
        from sensor_msgs.msg import PointCloud2

        sensor_qos = QoSProfile(depth=int(rest['qos_depth']),
                                history=HistoryPolicy.KEEP_LAST,
                                reliability=qos_profile_sensor_data.reliability,
                                durability=qos_profile_sensor_data.durability)
        self.create_subscription(PointCloud2, 'points', self._on_cloud, sensor_qos,
                                 callback_group=ingest)
        self.create_subscription(PoseStamped, 'sensor_pose', self._on_pose, sensor_qos,
                                 callback_group=ingest)
        latched = QoSProfile(depth=1, history=HistoryPolicy.KEEP_LAST,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseArray
        from nav_msgs.msg import OccupancyGrid
        from visualization_msgs.msg import MarkerArray
        self._pub_grid = self.create_publisher(OccupancyGrid, '~/safety_grid', latched)
        self._pub_cloud = self.create_publisher(PointCloud2, '~/safety_cloud', latched)
        self._pub_sites = self.create_publisher(PoseArray, '~/landing_sites', latched)
        self._pub_markers = self.create_publisher(MarkerArray, '~/markers', latched)
        self._pub_diag = self.create_publisher(DiagnosticArray, '/diagnostics', 10)
        self.create_timer(TICK, self._tick, callback_group=assess)
        self.create_timer(float(rest['diagnostics_period']), self._publish_diagnostics,
                          callback_group=diag)
        mode = ('following the sensor' if config.center is None
                else f'fixed at ({config.center[0]:g}, {config.center[1]:g})')
        self.get_logger().info(
            f'assessing {config.map.size_xy:g} m of {config.tiles.tile_size:g} m tiles in '
            f'frame {config.frame_id!r}, {mode}; model {self.assessor.model_path} '
            f'({self.assessor.model.config.spec})')

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
            configs_from_flat(self._flat({p.name: p.value for p in params}))
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
        self.settings.update(rest)
        if any(p.name.startswith(('tiles.', 'guard.')) for p in params):
            a.invalidate()  # every tile is judged again under the new thresholds
        self.get_logger().info('parameters changed: ' + ', '.join(
            f'{p.name}={p.value}' for p in params))

    # -- input ------------------------------------------------------------------------------

    def _warn(self, reason: str, message: str) -> None:
        # one child logger per reason, so one kind of bad input does not hide another
        logger = self._warners.get(reason)
        if logger is None:
            logger = self._warners[reason] = self.get_logger().get_child(reason)
        logger.warn(message, throttle_duration_sec=float(self.settings['warn_period']))

    def _on_cloud(self, msg: Any, info: Any = None) -> None:
        self._last_input = time.monotonic()
        seq = info.get('publication_sequence_number') if isinstance(info, dict) else None
        if seq is not None:
            # DDS dropped what the history could not hold; an estimate with one publisher
            # (a restarted or second publisher resets the count instead of adding to it)
            if self._last_seq is not None and seq > self._last_seq + 1:
                missed = seq - self._last_seq - 1
                self.stream.dropped_clouds['overrun'] += missed
                self._warn('overrun', f'{missed} cloud(s) lost before the node could take '
                                      f'them (qos_depth {self.settings["qos_depth"]})')
            self._last_seq = seq
        with self._ingest_lock:
            try:
                self.stream.add_cloud_msg(msg)
            except LandingZoneError as err:  # the stream counts bad input; this is a backstop
                self._warn('error', f'cloud dropped: {err}')

    def _on_pose(self, msg: Any) -> None:
        self._last_input = time.monotonic()
        with self._ingest_lock:
            try:
                self.stream.add_pose_msg(msg)
            except LandingZoneError as err:
                self._warn('error', f'pose dropped: {err}')

    # -- output -----------------------------------------------------------------------------

    def _tick(self) -> None:
        idle = time.monotonic() - self._last_input > float(self.settings['idle_flush'])
        if idle and self.stream.pending:
            with self._ingest_lock:
                self.stream.flush()
        if self.stream.due() or (idle and self.stream.unassessed):
            result = self.stream.assess()
            self._publish(result)

    def _publish(self, result: Any) -> None:
        from msg_adapters import grid

        stamp = self.stream.assessed_stamp_ns
        if stamp is None:
            stamp = self.get_clock().now().nanoseconds
        self._pub_grid.publish(grid.safety_grid(result, stamp))
        self._pub_cloud.publish(grid.safety_cloud(result, stamp))
        self._pub_sites.publish(grid.landing_site_poses(result, stamp))
        self._pub_markers.publish(grid.markers(result, stamp))

    def _publish_diagnostics(self) -> None:
        from msg_adapters import grid

        values = self.stream.diagnostics()
        values['dropped clouds: overrun'] = str(self.stream.dropped_clouds.get('overrun', 0))
        drops = int(sum(self.stream.dropped_clouds.values()))
        new_drops = drops - self._reported_drops
        self._reported_drops = drops
        if self.stream.clouds == 0:
            level, message = 'WARN', 'no cloud integrated yet'
        elif new_drops:
            level, message = 'WARN', f'{new_drops} cloud(s) dropped since the last report'
        else:
            level, message = 'OK', f'{self.stream.clouds} clouds integrated'
        self._pub_diag.publish(grid.diagnostics(values, self.get_clock().now().nanoseconds,
                                                name=f'{self.get_name()}: landing zone',
                                                level=level, message=message))


def main(args: list[str] | None = None) -> None:
    """Entry point of ``assessor`` (talker_qos.py's shutdown idiom); exit 1 if it cannot start."""
    rclpy.init(args=args)
    node = None
    code = 0
    try:
        node = AssessorNode()
        executor = MultiThreadedExecutor(num_threads=3)
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
            node.destroy_node()
        rclpy.try_shutdown()
    if code:
        sys.exit(code)


if __name__ == '__main__':
    main()
