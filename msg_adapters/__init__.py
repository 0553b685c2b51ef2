"""Conversions between ROS messages and the numpy arrays the landing_zone core works on.

The adapters read messages through their attributes only, so the same functions accept messages
from rclpy (``sensor_msgs.msg.PointCloud2``, ...) and from a rosbags typestore (what
:func:`landing_zone.io.bags.read_messages` yields). Building messages needs to know which of the
two implementations to build: :class:`MessageTypes` names it, and every builder takes one.

Modules:
    pointcloud: PointCloud2 <-> numpy structured / (N, 3) arrays.
    pose: PoseStamped <-> (stamp, position, quaternion) and (R, t).

Nothing here imports rclpy at import time; :meth:`MessageTypes.rclpy` imports the generated
message modules when a class is first asked for.
"""
from __future__ import annotations

import array
import functools
import importlib
import operator
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from landing_zone.errors import LandingZoneError

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

__all__ = [
    'jazzy_typestore',
    'MessageTypes',
    'as_message_types',
    'stamp_to_ns',
    'ns_to_stamp',
    'make_header',
]

_NS_PER_S = 1_000_000_000
_INT32_MIN, _INT32_MAX = -(2**31), 2**31 - 1


@functools.lru_cache(maxsize=1)
def jazzy_typestore() -> Typestore:
    """The rosbags typestore of ROS 2 Jazzy (messages this project writes are built from it)."""
    from rosbags.typesys import Stores, get_typestore
    return get_typestore(Stores.ROS2_JAZZY)


class MessageTypes:
    """Where message classes come from: rclpy's generated modules or a rosbags typestore.

    Both implementations take every field as a keyword argument with the same names, so a builder
    fills all fields by keyword and works with either. They differ in the type of ``uint8[]``
    fields: rclpy stores ``array.array('B')``, rosbags serializes a numpy ``uint8`` array; see
    :meth:`uint8_array`.

    Args:
        kind: ``'rclpy'`` or ``'rosbags'``.
        typestore: The rosbags typestore to take classes from (only for ``'rosbags'``).
    """

    def __init__(self, kind: Literal['rclpy', 'rosbags'], typestore: Typestore | None = None):
        if kind not in ('rclpy', 'rosbags'):
            raise ValueError(f"MessageTypes kind must be 'rclpy' or 'rosbags', got {kind!r}")
        if kind == 'rosbags' and typestore is None:
            raise ValueError('MessageTypes(kind=\'rosbags\') needs a typestore')
        self.kind = kind
        self.typestore = typestore
        self._classes: dict[str, type] = {}

    @classmethod
    def rclpy(cls) -> MessageTypes:
        """Message classes of the installed ROS 2 Python packages (imported on first use)."""
        return cls('rclpy')

    @classmethod
    def rosbags(cls, typestore: Typestore | None = None) -> MessageTypes:
        """Message classes of a rosbags typestore (default: :func:`jazzy_typestore`)."""
        return cls('rosbags', typestore if typestore is not None else jazzy_typestore())

    def get(self, msgtype: str) -> type:
        """The class of a message type.

        Args:
            msgtype: ROS 2 type name, ``'sensor_msgs/msg/PointCloud2'``.

        Returns:
            The message class.

        Raises:
            LandingZoneError: The type is unknown to this implementation.
        """
        cls = self._classes.get(msgtype)
        if cls is not None:
            return cls
        if self.kind == 'rosbags':
            assert self.typestore is not None
            try:
                cls = self.typestore.types[msgtype]
            except KeyError:
                raise LandingZoneError(f'message type {msgtype} is not in the rosbags typestore'
                                       ) from None
        else:
            parts = msgtype.split('/')
            if len(parts) != 3:
                raise LandingZoneError(f'message type {msgtype!r} is not of the form pkg/msg/Name')
            try:
                cls = getattr(importlib.import_module(f'{parts[0]}.{parts[1]}'), parts[2])
            except (ImportError, AttributeError) as err:
                raise LandingZoneError(f'message type {msgtype} cannot be imported: {err}'
                                       ) from err
        self._classes[msgtype] = cls
        return cls

    def build(self, msgtype: str, **fields: Any) -> Any:
        """Instantiate a message, every field given by keyword."""
        return self.get(msgtype)(**fields)

    def uint8_array(self, data: Any) -> Any:
        """A ``uint8[]`` field value from a bytes-like object, in this implementation's type.

        For rosbags, a contiguous ``uint8`` numpy array is used as it is (shared, not copied).
        """
        if self.kind == 'rclpy':
            out = array.array('B')
            out.frombytes(memoryview(data).cast('B'))
            return out
        if isinstance(data, np.ndarray) and data.dtype == np.uint8 and data.ndim == 1 \
                and data.flags.c_contiguous:
            return data
        return np.frombuffer(data, dtype=np.uint8).copy()

    def __repr__(self) -> str:
        return f'MessageTypes({self.kind!r})'


def as_message_types(types: MessageTypes | Typestore | str) -> MessageTypes:
    """Accept a :class:`MessageTypes`, a rosbags typestore, or ``'rclpy'`` / ``'rosbags'``."""
    if isinstance(types, MessageTypes):
        return types
    if isinstance(types, str):
        if types == 'rclpy':
            return MessageTypes.rclpy()
        if types == 'rosbags':
            return MessageTypes.rosbags()
        raise ValueError(f"message types must be 'rclpy' or 'rosbags', got {types!r}")
    if hasattr(types, 'types') and hasattr(types, 'serialize_cdr'):
        return MessageTypes.rosbags(types)
    raise TypeError(f'cannot build messages from {type(types).__name__}: pass MessageTypes, '
                    "a rosbags Typestore, 'rclpy' or 'rosbags'")


def stamp_to_ns(stamp: Any) -> int:
    """Nanoseconds since the epoch of a ``builtin_interfaces/Time`` (rclpy or rosbags)."""
    return int(stamp.sec) * _NS_PER_S + int(stamp.nanosec)


def ns_to_stamp(stamp_ns: int, types: MessageTypes | Typestore | str) -> Any:
    """A ``builtin_interfaces/Time`` for a stamp in nanoseconds.

    Args:
        stamp_ns: Nanoseconds since the epoch; negative stamps keep ``nanosec`` in [0, 1e9).
        types: Message implementation to build.

    Returns:
        The Time message.

    Raises:
        LandingZoneError: The stamp does not fit the message's int32 seconds.
    """
    sec, nanosec = divmod(operator.index(stamp_ns), _NS_PER_S)
    if not _INT32_MIN <= sec <= _INT32_MAX:
        raise LandingZoneError(f'stamp {stamp_ns} ns does not fit builtin_interfaces/Time '
                               '(int32 seconds)')
    return as_message_types(types).build('builtin_interfaces/msg/Time', sec=sec, nanosec=nanosec)


def make_header(stamp_ns: int, frame_id: str, types: MessageTypes | Typestore | str) -> Any:
    """A ``std_msgs/Header`` with a stamp in nanoseconds and a frame."""
    types = as_message_types(types)
    return types.build('std_msgs/msg/Header', stamp=ns_to_stamp(stamp_ns, types),
                       frame_id=str(frame_id))
