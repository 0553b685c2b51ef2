"""A simulated flight as LiDAR-inertial odometry publishes it: the body's odometry and clouds in
the body (or the LiDAR's own) frame, with the LiDAR mounted off the body.

``simulate-flight`` writes the LiDAR's pose (``/lidar/pose``, geometry_msgs/PoseStamped) and
clouds registered in ``map``. :func:`odometry_flight` turns such a bag into the other shape the
node takes (docs/INTERFACES.md §1): ``nav_msgs/Odometry`` of a body frame on ``/odometry`` (as
FAST-LIO's ``/Odometry``) and the same returns expressed in the body frame (as its
``/cloud_registered_body``) or in the LiDAR's frame (as a driver's scan), the LiDAR at
``sensor_offset`` in the body. The flight's ground truth (``SITE.labels.json``) is copied beside
the new bag. Replaying it with ``--pose-topic /odometry --cloud-frame body --sensor-offset ...``
gives the grid of the original flight.
"""
from __future__ import annotations

import os
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from landing_zone.errors import BagError, ConfigError

__all__ = ['OdometryFlight', 'odometry_flight', 'simulate_odometry_flight', 'DEFAULT_OFFSET']

# The LiDAR 0.2 m ahead of and 0.15 m below the body's origin, pitched 0.3 rad down and yawed
# a little: an extrinsic no step of the chain may ignore without the grid showing it.
DEFAULT_OFFSET = (0.2, 0.0, -0.15, 0.0, 0.3, 0.05)


@dataclass
class OdometryFlight:
    """What :func:`odometry_flight` wrote.

    Attributes:
        bag: the new bag.
        labels: its ground truth (None: the source had none).
        clouds, poses: messages written on ``points_topic`` and ``pose_topic``.
        points_topic, pose_topic, cloud_frame, sensor_offset: how to replay it.
    """

    bag: Path
    labels: Path | None
    clouds: int
    poses: int
    points_topic: str
    pose_topic: str
    cloud_frame: str
    sensor_offset: tuple[float, ...]

    def replay_args(self) -> list[str]:
        """The ``landing-zone replay`` options that read it."""
        return ['--points-topic', self.points_topic, '--pose-topic', self.pose_topic,
                '--cloud-frame', self.cloud_frame,
                '--sensor-offset', *(f'{v:g}' for v in self.sensor_offset)]


def odometry_flight(src: str | os.PathLike[str], out: str | os.PathLike[str], *,
                    sensor_offset: tuple[float, ...] = DEFAULT_OFFSET,
                    cloud_frame: str = 'body', body_frame: str = 'base_link',
                    sensor_frame: str = 'lidar', points_topic: str = '/lidar/points',
                    pose_topic: str = '/lidar/pose', out_pose_topic: str = '/odometry',
                    overwrite: bool = False) -> OdometryFlight:
    """Write ``out``: the flight of bag ``src`` as odometry of a body plus body- or sensor-frame
    clouds.

    Args:
        src: a bag as ``simulate-flight`` writes it (LiDAR poses, clouds in the fixed frame).
        out: the new bag (.mcap).
        sensor_offset: the LiDAR's pose in the body: x, y, z, roll, pitch, yaw [m, rad].
        cloud_frame: 'body' or 'sensor': the frame the returns are written in.
        body_frame, sensor_frame: the frame names (the odometry's ``child_frame_id``; the
            clouds' ``frame_id``).
        points_topic, pose_topic: the topics of ``src``; the clouds keep theirs.
        out_pose_topic: the odometry's topic.
        overwrite: replace an existing ``out``.

    Returns:
        :class:`OdometryFlight`.

    Raises:
        BagError: ``src`` is unreadable or lacks the topics.
        ConfigError: a bad offset or cloud frame.
    """
    from landing_zone.io.bags import BagWriter, read_messages
    from landing_zone.io.labels import labels_path_for
    from landing_zone.poses import Mount, PoseBuffer, matrix_to_quaternion, quaternion_to_matrix
    from msg_adapters import MessageTypes, jazzy_typestore, make_header
    from msg_adapters.pointcloud import cloud_to_structured, make_cloud, read_cloud_header
    from msg_adapters.pose import ODOMETRY_TYPE, make_odometry, read_pose_msg

    if cloud_frame not in ('body', 'sensor'):
        raise ConfigError(f"cloud_frame must be 'body' or 'sensor', got {cloud_frame!r}")
    mount = Mount(sensor_offset)
    src, out = Path(src), Path(out)
    # the LiDAR's poses, to express each cloud at its stamp (the flight writes one at every
    # cloud's stamp, so this is exact; between poses it interpolates as the node does)
    lidar = PoseBuffer(max_age_s=1e6, max_len=10_000_000, tolerance_s=0.0)
    frame_id = None
    for m in read_messages(src, [pose_topic]):
        frame_id, stamp, position, quaternion = read_pose_msg(m.msg)
        lidar.add(stamp, position, quaternion)
    if frame_id is None:
        raise BagError(f'{src} has no pose on {pose_topic}')
    types = MessageTypes.rosbags(jazzy_typestore())
    local = body_frame if cloud_frame == 'body' else sensor_frame
    clouds = poses = 0
    with BagWriter(out, overwrite=overwrite) as bag:
        bag.add_topic(points_topic, 'sensor_msgs/msg/PointCloud2')
        bag.add_topic(out_pose_topic, ODOMETRY_TYPE)
        for m in read_messages(src, [points_topic, pose_topic]):
            if m.topic == pose_topic:
                frame, stamp, position, quaternion = read_pose_msg(m.msg)
                R_b, t_b = mount.body_pose(quaternion_to_matrix(quaternion), position)
                bag.write(out_pose_topic, m.stamp_ns,
                          make_odometry(stamp, frame, body_frame, t_b, matrix_to_quaternion(R_b),
                                        types))
                poses += 1
                continue
            _, stamp = read_cloud_header(m.msg)
            arr = cloud_to_structured(m.msg)
            R_s, t_s = lidar.lookup_rt(stamp)
            R, t = mount.body_pose(R_s, t_s) if cloud_frame == 'body' else (R_s, t_s)
            _to_local(arr, R, t)
            bag.write(points_topic, m.stamp_ns,
                      make_cloud(arr, make_header(stamp, local, types), types))
            clouds += 1
    labels = labels_path_for(src)
    out_labels = None
    if labels.is_file():
        out_labels = labels_path_for(out)
        shutil.copyfile(labels, out_labels)
    return OdometryFlight(out, out_labels, clouds, poses, points_topic, out_pose_topic,
                          cloud_frame, tuple(float(v) for v in sensor_offset))


def simulate_odometry_flight(config: Any, out: str | os.PathLike[str], *,
                             sensor_offset: tuple[float, ...] = DEFAULT_OFFSET,
                             cloud_frame: str = 'body', overwrite: bool = False,
                             threads: int = 0) -> tuple[Any, OdometryFlight]:
    """Simulate a flight (:func:`landing_zone.tools.sim.flight.simulate_flight` with
    ``config``) and write it to ``out`` as :func:`odometry_flight` does, its ground truth
    beside it (``SITE.labels.json``); the LiDAR-pose flight is made in a scratch directory.

    Returns:
        ``(FlightResult, OdometryFlight)``: the simulated flight's figures (its own bag was
        scratch, gone) and what ``out`` holds.
    """
    import tempfile

    from landing_zone.tools.sim.flight import simulate_flight

    out = Path(out)
    if out.exists() and not overwrite:
        raise BagError(f'{out} exists (overwrite to replace it)')
    with tempfile.TemporaryDirectory(prefix='lz_odometry_') as tmp:
        flight = simulate_flight(config, Path(tmp) / 'site.mcap', threads=threads)
        result = odometry_flight(flight.bag, out, sensor_offset=sensor_offset,
                                 cloud_frame=cloud_frame, overwrite=overwrite)
    return flight, result


def _to_local(arr: Any, R: np.ndarray, t: np.ndarray) -> None:
    """Express the x, y, z of a structured cloud in the frame whose pose is ``(R, t)``, in
    place: local = R^T (world - t), in float64, stored in the fields' own type."""
    world = np.column_stack([arr['x'], arr['y'], arr['z']]).astype(np.float64)
    local = (world - t) @ R
    for k, name in enumerate('xyz'):
        arr[name] = local[:, k]
