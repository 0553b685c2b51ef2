"""geometry_msgs Pose / PoseStamped and nav_msgs Odometry <-> (stamp, position, quaternion).

Readers take rclpy and rosbags messages alike (attributes only); builders take a
:class:`~msg_adapters.MessageTypes` (or a rosbags typestore, ``'rclpy'``, ``'rosbags'``) saying
which implementation to build: the simulator writes rosbags messages into bags, the node
publishes rclpy ones. Quaternions are ``(x, y, z, w)``, normalised on the way in; a non-finite
pose or a zero quaternion raises :class:`~landing_zone.errors.InvalidPoseError`.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

from landing_zone.errors import InvalidPoseError
from landing_zone.poses import normalize_quaternion, quaternion_to_matrix
from msg_adapters import MessageTypes, as_message_types, make_header, ns_to_stamp, stamp_to_ns

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

__all__ = [
    'read_pose_msg',
    'read_odometry_msg',
    'read_pose_input',
    'make_odometry',
    'ODOMETRY_TYPE',
    'POSE_TYPE',
    'pose_to_arrays',
    'pose_stamped_to_arrays',
    'pose_to_rt',
    'make_pose',
    'make_pose_stamped',
    'stamp_to_ns',
    'ns_to_stamp',
]

POSE_TYPE = 'geometry_msgs/msg/PoseStamped'
ODOMETRY_TYPE = 'nav_msgs/msg/Odometry'


def pose_to_arrays(pose: Any) -> tuple[np.ndarray, np.ndarray]:
    """Position and unit quaternion of a ``geometry_msgs/Pose``.

    Args:
        pose: The Pose (rclpy or rosbags).

    Returns:
        ``(position (3,), quaternion (4,) xyzw)``, float64.

    Raises:
        InvalidPoseError: Missing attributes, non-finite values or a zero quaternion.
    """
    try:
        p, o = pose.position, pose.orientation
        position = np.array([p.x, p.y, p.z], dtype=np.float64)
        quaternion = np.array([o.x, o.y, o.z, o.w], dtype=np.float64)
    except AttributeError as err:
        raise InvalidPoseError(f'not a geometry_msgs/Pose: {err}') from None
    except (TypeError, ValueError) as err:
        raise InvalidPoseError(f'pose holds non-numeric values: {err}') from None
    if not np.isfinite(position).all():
        raise InvalidPoseError(f'pose position is not finite: {position.tolist()}')
    return position, normalize_quaternion(quaternion)


def pose_stamped_to_arrays(msg: Any) -> tuple[int, np.ndarray, np.ndarray]:
    """Stamp, position and unit quaternion of a ``geometry_msgs/PoseStamped``.

    Returns:
        ``(stamp_ns, position (3,), quaternion (4,) xyzw)``.

    Raises:
        InvalidPoseError: Malformed message (see :func:`pose_to_arrays`).
    """
    try:
        stamp_ns = stamp_to_ns(msg.header.stamp)
        pose = msg.pose
    except AttributeError as err:
        raise InvalidPoseError(f'not a geometry_msgs/PoseStamped: {err}') from None
    except (TypeError, ValueError) as err:
        raise InvalidPoseError(f'pose stamp is not an integer time: {err}') from None
    return (stamp_ns, *pose_to_arrays(pose))


def read_pose_msg(msg: Any) -> tuple[str, int, np.ndarray, np.ndarray]:
    """A ``geometry_msgs/PoseStamped`` as the stream takes it (the node and the bag tools alike).

    Returns:
        ``(frame_id, stamp_ns, position (3,), unit quaternion (4,) xyzw)``.

    Raises:
        InvalidPoseError: Not a PoseStamped, non-finite, or a zero quaternion.
    """
    try:
        frame = msg.header.frame_id
    except AttributeError as err:
        raise InvalidPoseError(f'not a geometry_msgs/PoseStamped: {err}') from None
    return (frame, *pose_stamped_to_arrays(msg))


def read_odometry_msg(msg: Any) -> tuple[str, str, int, np.ndarray, np.ndarray]:
    """A ``nav_msgs/Odometry`` as the stream takes it: the pose of its child frame.

    Returns:
        ``(frame_id, child_frame_id, stamp_ns, position (3,), unit quaternion (4,) xyzw)``.

    Raises:
        InvalidPoseError: Not an Odometry, non-finite, or a zero quaternion.
    """
    try:
        frame, child = msg.header.frame_id, msg.child_frame_id
        stamp_ns = stamp_to_ns(msg.header.stamp)
        pose = msg.pose.pose
    except AttributeError as err:
        raise InvalidPoseError(f'not a nav_msgs/Odometry: {err}') from None
    except (TypeError, ValueError) as err:
        raise InvalidPoseError(f'odometry stamp is not an integer time: {err}') from None
    return (frame, child, stamp_ns, *pose_to_arrays(pose))


def read_pose_input(msg: Any) -> tuple[str, str | None, int, np.ndarray, np.ndarray]:
    """A PoseStamped or an Odometry, told apart by its fields.

    Returns:
        ``(frame_id, child_frame_id, stamp_ns, position, quaternion)``; ``child_frame_id`` is
        None for a PoseStamped (it has none) and may be '' for an Odometry that left it empty.

    Raises:
        InvalidPoseError: Neither, non-finite, or a zero quaternion.
    """
    if hasattr(msg, 'child_frame_id'):
        return read_odometry_msg(msg)
    frame, stamp_ns, position, quaternion = read_pose_msg(msg)
    return frame, None, stamp_ns, position, quaternion


def pose_to_rt(msg: Any) -> tuple[np.ndarray, np.ndarray]:
    """Rotation and translation of a Pose or PoseStamped: world = R @ local + t.

    Returns:
        ``(R (3, 3), t (3,))``.

    Raises:
        InvalidPoseError: Malformed message.
    """
    pose = msg.pose if hasattr(msg, 'header') and hasattr(msg, 'pose') else msg
    position, quaternion = pose_to_arrays(pose)
    return quaternion_to_matrix(quaternion), position


def make_pose(position: ArrayLike, quaternion: ArrayLike,
              types: MessageTypes | Typestore | str = 'rclpy') -> Any:
    """A ``geometry_msgs/Pose``.

    Args:
        position: (3,) position.
        quaternion: (4,) orientation ``(x, y, z, w)``, normalised here.
        types: Which message implementation to build.

    Raises:
        InvalidPoseError: Non-finite values or a zero quaternion.
    """
    types = as_message_types(types)
    p = np.asarray(position, dtype=np.float64)
    if p.shape != (3,) or not np.isfinite(p).all():
        raise InvalidPoseError(f'position must be 3 finite values, got {p.tolist()}')
    x, y, z, w = (float(v) for v in normalize_quaternion(quaternion))
    return types.build(
        'geometry_msgs/msg/Pose',
        position=types.build('geometry_msgs/msg/Point', x=float(p[0]), y=float(p[1]),
                             z=float(p[2])),
        orientation=types.build('geometry_msgs/msg/Quaternion', x=x, y=y, z=z, w=w))


def make_odometry(stamp_ns: int, frame_id: str, child_frame_id: str, position: ArrayLike,
                  quaternion: ArrayLike,
                  types: MessageTypes | Typestore | str = 'rclpy') -> Any:
    """A ``nav_msgs/Odometry`` of ``child_frame_id`` in ``frame_id`` (covariances and twist
    zero, as an odometry that does not estimate them publishes them).

    Raises:
        InvalidPoseError: Non-finite values or a zero quaternion.
    """
    from msg_adapters.grid import build

    types = as_message_types(types)
    pose = build(types, 'geometry_msgs/msg/PoseWithCovariance',
                 pose=make_pose(position, quaternion, types))
    return build(types, ODOMETRY_TYPE, header=make_header(stamp_ns, frame_id, types),
                 child_frame_id=str(child_frame_id), pose=pose)


def make_pose_stamped(stamp_ns: int, frame_id: str, position: ArrayLike, quaternion: ArrayLike,
                      types: MessageTypes | Typestore | str = 'rclpy') -> Any:
    """A ``geometry_msgs/PoseStamped``.

    Args:
        stamp_ns: Stamp [ns].
        frame_id: Frame of the pose.
        position: (3,) position.
        quaternion: (4,) orientation ``(x, y, z, w)``, normalised here.
        types: Which message implementation to build.

    Raises:
        InvalidPoseError: Non-finite values or a zero quaternion.
    """
    types = as_message_types(types)
    return types.build('geometry_msgs/msg/PoseStamped',
                       header=make_header(stamp_ns, frame_id, types),
                       pose=make_pose(position, quaternion, types))
