"""The front ends' settings: the stream's timing and input frames (node and replay), the live
receive path's bounds and the node's own."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

from landing_zone.config.facts import _check_fields, _from_names, param
from landing_zone.errors import ConfigError

__all__ = ['StreamConfig', 'LiveConfig', 'NodeConfig', 'QOS_RELIABILITY', 'CLOUD_FRAMES',
           'live_config']

# Where the returns of a cloud are (docs/INTERFACES.md §1): registered in the fixed frame, in
# the frame C whose pose the pose input gives (the body, for odometry), or in the LiDAR's own.
CLOUD_FRAMES = ('fixed', 'body', 'sensor')


@dataclass
class StreamConfig:
    """The stream's timing (:mod:`landing_zone.runtime.stream`), shared by node and replay."""

    assessment_period: float = param(0.5, 'Stamp time between assessments', 's', (0.0, 60.0),
                                     open_lo=True)
    pose_tolerance: float = param(0.05, "How far a cloud may lie outside the poses' span", 's',
                                  (0.0, 10.0))
    pose_wait: float = param(0.5, 'How long (stamp time) a cloud may wait for its pose', 's',
                             (0.0, 10.0))
    max_pending: int = param(20, 'Clouds that may wait for their pose at once', '', (1, 1000))
    pose_history: float = param(30.0, 'Span of poses kept for interpolation', 's',
                                (0.0, 3600.0), open_lo=True, read_only=True)
    # FAST-LIO's /cloud_registered is fixed, its /cloud_registered_body body, a driver's scan
    # sensor; body and sensor clouds are registered with C's pose at the cloud's stamp
    cloud_frame: str = param(
        'fixed', 'Frame of the returns of points: fixed (registered in frame_id), body (in the '
        "frame C the pose input gives) or sensor (in the LiDAR's own frame)", read_only=True)
    # odometry gives the body's (the IMU's) pose; the rays start at the LiDAR
    sensor_offset: tuple[float, ...] = param(
        (0.0,) * 6, "The LiDAR's pose in C: x, y, z, roll, pitch, yaw", 'm, rad',
        read_only=True)

    def validate(self) -> None:
        _check_fields(self, '')
        if self.cloud_frame not in CLOUD_FRAMES:
            raise ConfigError(f'cloud_frame must be one of {", ".join(CLOUD_FRAMES)}, got '
                              f'{self.cloud_frame!r}')
        try:
            offset = [float(v) for v in self.sensor_offset]
        except (TypeError, ValueError):
            raise ConfigError('sensor_offset must be six numbers (x, y, z, roll, pitch, yaw), '
                              f'got {self.sensor_offset!r}') from None
        if len(offset) != 6 or not all(math.isfinite(v) for v in offset):
            raise ConfigError('sensor_offset must be six finite numbers (x, y, z, roll, pitch, '
                              f'yaw), got {self.sensor_offset!r}')
        self.sensor_offset = tuple(offset)

    @property
    def needs_child_frame(self) -> bool:
        """Whether the pose input must say which frame it is the pose of (an odometry's
        ``child_frame_id``): the offset or a body or sensor cloud applies to that frame."""
        return self.cloud_frame != 'fixed' or any(v != 0.0 for v in self.sensor_offset)


@dataclass
class LiveConfig:
    """The live receive path's bounds (:mod:`landing_zone.runtime.ingest`), node only."""

    # clouds that may wait for the integration thread: 1 s at 20 Hz, room for the clouds that
    # come while an assessment pass has the CPU (10 overflowed now and then at 0.3 M returns/s
    # on a busy 2-core machine)
    # (a cloud of fewer than 1000 returns counts as its share of one, at least 1/20: a flood
    # of tiny or malformed clouds cannot push the real ones out; runtime.ingest)
    receive_queue: int = param(
        20, 'Clouds that may wait for integration, small ones by their share of 1000 returns; '
        'more push out the oldest (overload)', '', (1, 10000), read_only=True)
    receive_queue_mb: float = param(64.0, '... and at most this many MB of them', 'MB',
                                    (1.0, 100000.0), read_only=True)
    idle_flush: float = param(
        1.0, 'After this long without input, waiting clouds are settled and the last ones '
        'assessed', 's', (0.05, 60.0))

    # the cloud-to-grid latency: with passes only every assessment_period of stamp time a
    # cloud waits half a period on average before a pass takes it in
    eager_interval: float = param(
        0.15, 'A pass also starts before it is due once integration has caught up and this '
        'long passed since the last began; 0: only every assessment_period', 's', (0.0, 60.0))

    def validate(self) -> None:
        if isinstance(self.receive_queue, bool) or not isinstance(self.receive_queue, int):
            raise ConfigError(f'receive_queue must be a positive integer, got '
                              f'{self.receive_queue!r}')
        _check_fields(self, '')


# The subscriptions' reliability choices (rclpy's ReliabilityPolicy names them in the node).
QOS_RELIABILITY = ('best_effort', 'reliable')


@dataclass
class NodeConfig:
    """The ``assessor`` node's own settings (the front end's, not the pipeline's)."""

    # 50: room for the clouds that arrive while the executor thread waits for the GIL (5 lost
    # about 1 in 200 at 120 Hz on the live branch's measurements)
    qos_depth: int = param(50, 'History depth of the points and pose subscriptions', '',
                           (1, 1000), read_only=True)
    qos_reliability: str = param(
        'best_effort', 'Reliability of the subscriptions: best_effort (any publisher) or '
        'reliable', read_only=True)
    diagnostics_period: float = param(1.0, 'Time between /diagnostics messages', 's',
                                      (0.1, 60.0), read_only=True)
    warn_period: float = param(5.0, 'Least time between two warnings of one kind', 's',
                               (0.0, 3600.0))
    snapshot_path: str = param(
        '', 'Map snapshot: saved periodically, loaded at start if it matches; empty: none',
        read_only=True,
        name='snapshot.path')
    snapshot_period: float = param(10.0, 'Time between two snapshots (wall time)', 's',
                                   (1.0, 86400.0), name='snapshot.period')
    # a planner must never act on a grid that silently stopped updating (/diagnostics level)
    stale_after: float = param(1.0, '/diagnostics goes WARN when no cloud or no pose has '
                               'arrived for this long', 's', (0.0, 3600.0), open_lo=True)
    stale_error: float = param(3.0, '... and ERROR past this long', 's', (0.0, 3600.0),
                               open_lo=True)

    def validate(self) -> None:
        if self.qos_reliability not in QOS_RELIABILITY:
            raise ConfigError(f'qos_reliability must be one of {", ".join(QOS_RELIABILITY)}, '
                              f'got {self.qos_reliability!r}')
        _check_fields(self, '')
        if not self.stale_error >= self.stale_after:
            raise ConfigError(f'stale_error ({self.stale_error}) must not be shorter than '
                              f'stale_after ({self.stale_after})')

    @classmethod
    def from_flat(cls, flat: dict[str, Any]) -> NodeConfig:
        """The node's settings among dotted parameters (by their parameter names); others are
        ignored, missing ones keep their defaults.

        Raises:
            ConfigError: a value out of range or not one of the choices.
        """
        cfg: NodeConfig = _from_names(cls, flat)
        return cfg


def live_config(flat: dict[str, Any]) -> LiveConfig:
    """The receive path's settings among dotted parameters (others are ignored).

    Raises:
        ConfigError: a value out of range.
    """
    cfg: LiveConfig = _from_names(LiveConfig, flat)
    return cfg
