"""Sensor poses over time: a buffer of stamped poses, interpolated at any stamp in its span.

Clouds are stamped when their sweep was taken and poses arrive on their own topic at their own
rate, so the pipeline needs the sensor pose *at the cloud's stamp*: :class:`PoseBuffer` keeps
the recent poses sorted by stamp (out-of-order arrivals included) and interpolates, position
linearly and orientation by spherical linear interpolation (slerp) of unit quaternions.

Quaternions are ``(x, y, z, w)`` (ROS and scipy order), stamps are integer nanoseconds.
"""
from __future__ import annotations

import bisect
import math
import threading
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from landing_zone.errors import ConfigError, InvalidPoseError

__all__ = [
    'PoseLookupError',
    'PoseTooOldError',
    'PoseNotYetError',
    'normalize_quaternion',
    'quaternion_to_matrix',
    'slerp',
    'rpy_to_matrix',
    'matrix_to_quaternion',
    'Mount',
    'PoseBuffer',
]

_NS_PER_S = 1e9
# Below this norm a quaternion carries no direction that normalising could recover.
_MIN_QUATERNION_NORM = 1e-6


class PoseLookupError(InvalidPoseError):
    """No pose can be given at the stamp asked for; ``reason`` says why."""

    reason: Literal['too_old', 'not_yet'] = 'not_yet'


class PoseTooOldError(PoseLookupError):
    """The stamp is older than the oldest pose kept (beyond the tolerance)."""

    reason = 'too_old'


class PoseNotYetError(PoseLookupError):
    """No pose yet at the stamp: the buffer is empty or the stamp is newer than its newest pose
    (beyond the tolerance); waiting for more poses may help."""

    reason = 'not_yet'


def normalize_quaternion(quaternion: ArrayLike) -> np.ndarray:
    """A unit quaternion ``(x, y, z, w)``, float64.

    Raises:
        InvalidPoseError: Not 4 finite values, or (nearly) zero.
    """
    q = np.asarray(quaternion, dtype=np.float64)
    if q.shape != (4,):
        raise InvalidPoseError(f'quaternion must have 4 components, got shape {q.shape}')
    if not np.isfinite(q).all():
        raise InvalidPoseError(f'quaternion is not finite: {q.tolist()}')
    norm = math.sqrt(float(q @ q))
    if norm < _MIN_QUATERNION_NORM:
        raise InvalidPoseError(f'quaternion has norm {norm:.3g}, cannot be a rotation')
    return q / norm


def _position(position: ArrayLike) -> np.ndarray:
    p = np.asarray(position, dtype=np.float64)
    if p.shape != (3,):
        raise InvalidPoseError(f'position must have 3 components, got shape {p.shape}')
    if not np.isfinite(p).all():
        raise InvalidPoseError(f'position is not finite: {p.tolist()}')
    return p


def quaternion_to_matrix(quaternion: ArrayLike) -> np.ndarray:
    """The (3, 3) rotation matrix of a unit quaternion ``(x, y, z, w)`` (normalised first).

    Raises:
        InvalidPoseError: The quaternion is not finite or zero.
    """
    x, y, z, w = normalize_quaternion(quaternion)
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def slerp(q0: np.ndarray, q1: np.ndarray, alpha: float) -> np.ndarray:
    """Spherical linear interpolation between unit quaternions, along the shorter arc.

    Written out rather than through scipy's ``Slerp``, whose construction per lookup costs tens
    of microseconds; the node interpolates once per cloud and per pose.

    Args:
        q0: Unit quaternion at ``alpha = 0``.
        q1: Unit quaternion at ``alpha = 1``.
        alpha: Fraction of the way, in [0, 1].

    Returns:
        The unit quaternion.
    """
    dot = float(q0 @ q1)
    if dot < 0.0:  # q and -q are the same rotation: take the shorter way round
        q1, dot = -q1, -dot
    theta = math.acos(min(dot, 1.0))
    if theta < 1e-6:
        # sin(theta) ~ 0: the weights tend to (1 - alpha, alpha); lerp is exact to O(theta^2).
        q = q0 + alpha * (q1 - q0)
    else:
        s = math.sin(theta)
        q = (math.sin((1.0 - alpha) * theta) / s) * q0 + (math.sin(alpha * theta) / s) * q1
    out: np.ndarray = q / math.sqrt(float(q @ q))
    return out


def rpy_to_matrix(roll: float, pitch: float, yaw: float) -> np.ndarray:
    """The (3, 3) rotation of fixed-axis roll, pitch, yaw [rad] (REP-103: about x, then y,
    then z, so R = Rz(yaw) @ Ry(pitch) @ Rx(roll), as tf2's ``setRPY``)."""
    cr, sr = math.cos(roll), math.sin(roll)
    cp, sp = math.cos(pitch), math.sin(pitch)
    cy, sy = math.cos(yaw), math.sin(yaw)
    return np.array([
        [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
        [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
        [-sp, cp * sr, cp * cr],
    ])


def matrix_to_quaternion(rotation: ArrayLike) -> np.ndarray:
    """The unit quaternion ``(x, y, z, w)`` of a (3, 3) rotation matrix (Shepperd's method)."""
    m = np.asarray(rotation, dtype=np.float64)
    tr = float(m[0, 0] + m[1, 1] + m[2, 2])
    if tr > 0:
        s = 2.0 * math.sqrt(tr + 1.0)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, s / 4]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [s / 4, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 1] + m[1, 0]) / s, s / 4, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, s / 4, (m[1, 0] - m[0, 1]) / s]
    return normalize_quaternion(q)


class Mount:
    """The LiDAR's pose in a frame C (the extrinsic), and what it turns C's pose into.

    Args:
        offset: ``(x, y, z, roll, pitch, yaw)`` of the LiDAR in C [m, rad].
    """

    def __init__(self, offset: ArrayLike = (0.0,) * 6) -> None:
        o = np.asarray(offset, dtype=np.float64)
        if o.shape != (6,) or not np.isfinite(o).all():
            raise ConfigError(f'a sensor offset is six finite numbers, got {o.tolist()}')
        self.t = o[:3].copy()
        self.R = rpy_to_matrix(*o[3:])
        self.identity = not o.any()

    def sensor_pose(self, R_c: np.ndarray, t_c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The LiDAR's ``(R, t)`` in the fixed frame, given C's."""
        if self.identity:
            return R_c, t_c
        return R_c @ self.R, R_c @ self.t + t_c

    def body_pose(self, R_s: np.ndarray, t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """C's ``(R, t)`` in the fixed frame, given the LiDAR's (the inverse of
        :meth:`sensor_pose`)."""
        R_c = R_s @ self.R.T
        return R_c, t_s - R_c @ self.t


class PoseBuffer:
    """Stamped poses kept sorted, interpolated at a stamp; thread-safe.

    Poses older than ``max_age_s`` before the newest are dropped, except the newest of those, so
    every stamp within ``max_age_s`` of the newest pose stays interpolable; at most ``max_len``
    poses are kept.

    Args:
        max_age_s: Time span of poses kept [s].
        max_len: Most poses kept.
        tolerance_s: How far before the oldest or after the newest pose a lookup may fall and
            still get that end pose (no extrapolation) [s].

    Raises:
        ConfigError: A parameter is out of range.
    """

    def __init__(self, max_age_s: float = 10.0, max_len: int = 10_000,
                 tolerance_s: float = 0.05):
        if not max_age_s > 0 or not math.isfinite(max_age_s):
            raise ConfigError(f'max_age_s must be positive and finite, got {max_age_s}')
        if max_len < 2:
            raise ConfigError(f'max_len must be at least 2, got {max_len}')
        if not tolerance_s >= 0 or not math.isfinite(tolerance_s):
            raise ConfigError(f'tolerance_s must be >= 0 and finite, got {tolerance_s}')
        self.max_age_ns = int(round(max_age_s * _NS_PER_S))
        self.max_len = int(max_len)
        self.tolerance_ns = int(round(tolerance_s * _NS_PER_S))
        self._stamps: list[int] = []
        self._positions: list[np.ndarray] = []
        self._quaternions: list[np.ndarray] = []
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return len(self._stamps)

    @property
    def oldest_ns(self) -> int | None:
        """Stamp of the oldest pose kept, or None when empty."""
        with self._lock:
            return self._stamps[0] if self._stamps else None

    @property
    def newest_ns(self) -> int | None:
        """Stamp of the newest pose kept, or None when empty."""
        with self._lock:
            return self._stamps[-1] if self._stamps else None

    def clear(self) -> None:
        """Forget every pose (for example when the clock jumps back)."""
        with self._lock:
            self._stamps.clear()
            self._positions.clear()
            self._quaternions.clear()

    def add(self, stamp_ns: int, position: ArrayLike, quaternion: ArrayLike) -> None:
        """Insert a pose; one with the stamp of a pose already kept replaces it.

        Args:
            stamp_ns: Stamp [ns].
            position: (3,) position.
            quaternion: (4,) orientation ``(x, y, z, w)``, normalised here.

        Raises:
            InvalidPoseError: Non-finite values or a zero quaternion.
        """
        stamp = int(stamp_ns)
        p = _position(position)
        q = normalize_quaternion(quaternion)
        with self._lock:
            stamps = self._stamps
            if not stamps or stamp > stamps[-1]:  # the usual case: in order
                i = len(stamps)
            else:
                i = bisect.bisect_left(stamps, stamp)
                if i < len(stamps) and stamps[i] == stamp:
                    self._positions[i], self._quaternions[i] = p, q
                    return
            stamps.insert(i, stamp)
            self._positions.insert(i, p)
            self._quaternions.insert(i, q)
            self._prune()

    def _prune(self) -> None:
        stamps = self._stamps
        # Keep the newest pose at or before the age horizon as the left end of its interval.
        drop = bisect.bisect_right(stamps, stamps[-1] - self.max_age_ns) - 1
        drop = max(drop, len(stamps) - self.max_len)
        if drop > 0:
            del stamps[:drop], self._positions[:drop], self._quaternions[:drop]

    def lookup(self, stamp_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """The pose at a stamp.

        Args:
            stamp_ns: Stamp [ns].

        Returns:
            ``(position (3,), quaternion (4,) xyzw)``, new arrays.

        Raises:
            PoseNotYetError: Empty buffer, or the stamp is after the newest pose plus tolerance.
            PoseTooOldError: The stamp is before the oldest pose minus tolerance.
        """
        stamp = int(stamp_ns)
        with self._lock:
            stamps = self._stamps
            if not stamps:
                raise PoseNotYetError(f'no pose yet at stamp {stamp} ns: no pose received')
            if stamp >= stamps[-1]:
                if stamp - stamps[-1] > self.tolerance_ns:
                    raise PoseNotYetError(
                        f'no pose yet at stamp {stamp} ns: the newest pose is '
                        f'{(stamp - stamps[-1]) / _NS_PER_S:.3f} s older')
                return self._positions[-1].copy(), self._quaternions[-1].copy()
            if stamp <= stamps[0]:
                if stamps[0] - stamp > self.tolerance_ns:
                    raise PoseTooOldError(
                        f'stamp {stamp} ns is too old: the oldest pose kept is '
                        f'{(stamps[0] - stamp) / _NS_PER_S:.3f} s newer')
                return self._positions[0].copy(), self._quaternions[0].copy()
            i = bisect.bisect_right(stamps, stamp)  # stamps[i - 1] <= stamp < stamps[i]
            s0, s1 = stamps[i - 1], stamps[i]
            p0, p1 = self._positions[i - 1], self._positions[i]
            q0, q1 = self._quaternions[i - 1], self._quaternions[i]
        if stamp == s0:
            return p0.copy(), q0.copy()
        alpha = (stamp - s0) / (s1 - s0)
        return p0 + alpha * (p1 - p0), slerp(q0, q1, alpha)

    def lookup_rt(self, stamp_ns: int) -> tuple[np.ndarray, np.ndarray]:
        """The pose at a stamp as ``(R (3, 3), t (3,))``: world point = R @ sensor point + t.

        Raises:
            PoseNotYetError, PoseTooOldError: As :meth:`lookup`.
        """
        position, quaternion = self.lookup(stamp_ns)
        return quaternion_to_matrix(quaternion), position
