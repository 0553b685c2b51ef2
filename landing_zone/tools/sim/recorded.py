"""A recorded flight read as the node would integrate it: every return with its sensor origin.

Poses and clouds are decoded as the stream decodes them; a cloud's origin is the pose
interpolated at its header stamp. :mod:`landing_zone.tools.sim.insert` and
:mod:`landing_zone.tools.sim.hybrid` cut and alter what this reads. The clouds' bytes are read with
:func:`cloud_points`, which keeps each return's row in the cloud so :func:`alter_cloud` can
rewrite exactly those bytes: only the ``x``, ``y``, ``z`` (and integer ``label``) bytes of the
altered returns change, in the cloud's own layout, precision and byte order.
"""
from __future__ import annotations

import dataclasses
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from landing_zone.errors import BagError
from landing_zone.tools.sim.alteration import ObstacleScene, alter_returns
from landing_zone.tools.sim.mesh import OBSTACLE

__all__ = ['FlightReturns', 'read_flight', 'cloud_points', 'alter_cloud', 'has_label_field']


def _data_offset(raw: bytes | memoryview, data: np.ndarray) -> int:
    """Where a PointCloud2's ``data`` bytes start inside its CDR serialization.

    ``data`` (a ``uint8[]``: a 4-byte length, then the bytes) is followed only by ``is_dense``
    (one byte) and at most 3 bytes of end padding, so its start is found from the end and
    checked against the length prefix and the bytes themselves.
    """
    buf = np.frombuffer(raw, np.uint8)
    n = len(data)
    order = '<' if buf[1] == 1 else '>'  # encapsulation: CDR_LE (0x0001) or CDR_BE (0x0000)
    want = np.frombuffer(np.asarray(data, np.uint8).tobytes(), np.uint8) if n else None
    for pad in range(4):
        off = len(buf) - 1 - pad - n
        if off < 8:
            break
        size = int(np.frombuffer(buf[off - 4:off].tobytes(), order + 'u4')[0])
        if size == n and (n == 0 or np.array_equal(buf[off:off + n], want)):
            return off
    raise BagError('cannot locate the data bytes of a PointCloud2 in its CDR payload')


def has_label_field(view: np.ndarray) -> bool:
    names = view.dtype.names or ()
    if 'label' not in names:
        return False
    dt = view.dtype.fields['label'][0]
    return dt.shape == () and dt.kind in 'iu'


def cloud_points(msg: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A cloud's structured view, its finite returns (M, 3) float64 and their flat indices.

    Raises:
        InvalidCloudError: malformed, or x, y, z not FLOAT32 / FLOAT64 of count 1.
    """
    from landing_zone.errors import InvalidCloudError
    from msg_adapters.pointcloud import cloud_view

    view = cloud_view(msg)
    names = view.dtype.names or ()
    for name in ('x', 'y', 'z'):
        if name not in names:
            raise InvalidCloudError(f'cloud lacks field {name!r}')
        dt = view.dtype.fields[name][0]
        if dt.shape != () or dt.kind != 'f':
            raise InvalidCloudError(f'cloud field {name!r} must be FLOAT32 or FLOAT64')
    xyz = np.empty((*view.shape, 3))
    with np.errstate(invalid='ignore'):  # signalling NaNs in garbage bytes
        for k, name in enumerate(('x', 'y', 'z')):
            xyz[..., k] = view[name]
    xyz = xyz.reshape(-1, 3)
    rows = np.flatnonzero(np.isfinite(xyz[:, 0]) & np.isfinite(xyz[:, 1])
                          & np.isfinite(xyz[:, 2]))
    return view, xyz[rows], rows


def alter_cloud(raw: bytes | memoryview, msg: Any, origin: np.ndarray, scene: ObstacleScene,
                rng: np.random.Generator, range_sigma: float) -> tuple[bytes | None, int, int]:
    """The cloud's CDR bytes with its altered returns rewritten (None when none is).

    Returns:
        ``(new bytes or None, finite returns, altered returns)``.
    """
    from msg_adapters.pointcloud import cloud_view

    view, xyz, finite = cloud_points(msg)
    new, mask = alter_returns(xyz, origin, scene, rng, range_sigma)
    if not mask.any():
        return None, len(finite), 0
    rows = finite[mask]
    out = bytearray(raw)
    off = _data_offset(raw, msg.data)
    data = np.frombuffer(out, np.uint8, count=len(msg.data), offset=off)
    full = cloud_view(dataclasses.replace(msg, data=data))
    i, j = np.unravel_index(rows, view.shape)
    for k, name in enumerate(('x', 'y', 'z')):
        full[name][i, j] = new[mask, k]
    if has_label_field(full):
        full['label'][i, j] = OBSTACLE
    return bytes(out), len(finite), int(mask.sum())


@dataclass
class FlightReturns:
    """Every finite return of a flight's clouds in the fixed frame, with its sensor origin.

    Attributes:
        points: (N, 3) float64 returns [m], in bag order.
        cloud: (N,) int64 index of each return's cloud.
        origins: (C, 3) float64 sensor origin of each cloud: the pose interpolated at its
            header stamp; NaN where the poses do not reach its stamp.
        stamps: (C,) int64 header stamps [ns].
        labels: (N,) uint8 the clouds' integer ``label`` field (simulated flights: 0 ground,
            1 grass, 2 obstacle); 255 where a cloud has none.
        poses: every pose of the flight, for interpolation.
    """

    points: np.ndarray
    cloud: np.ndarray
    origins: np.ndarray
    stamps: np.ndarray
    labels: np.ndarray
    poses: Any = field(repr=False, default=None)

    def ray_origins(self, index: np.ndarray | None = None) -> np.ndarray:
        """(N, 3) origin of each return (of ``index``)."""
        cloud = self.cloud if index is None else self.cloud[index]
        return self.origins[cloud]


def read_flight(bag: str | os.PathLike[str], points_topic: str = '/lidar/points',
                pose_topic: str = '/lidar/pose', frame_id: str = 'map') -> FlightReturns:
    """All returns of a flight with their sensor origins, as the node would integrate them.

    Poses and clouds are decoded as the stream decodes them
    (:func:`~msg_adapters.pose.read_pose_msg`,
    :func:`~msg_adapters.pointcloud.read_cloud_header`); a cloud's origin is the pose
    interpolated at its header stamp by a
    :class:`~landing_zone.poses.PoseBuffer` holding every pose, with the stream's tolerance
    (``StreamConfig.pose_tolerance``) at both ends. Clouds and poses in other frames are left
    out, as are malformed ones.

    Raises:
        BagError: unreadable bag, missing topics, no pose or no cloud in the frame.
    """
    from landing_zone.io.bags import RawBag, require_topics
    from landing_zone.errors import InvalidCloudError, InvalidPoseError
    from landing_zone.poses import PoseBuffer
    from landing_zone.config import StreamConfig
    from msg_adapters.pointcloud import read_cloud_header
    from msg_adapters.pose import read_pose_msg

    bag = Path(bag)
    require_topics(bag, points_topic, pose_topic)
    poses = PoseBuffer(max_age_s=1e9, max_len=2**62, tolerance_s=StreamConfig().pose_tolerance)
    chunks: list[np.ndarray] = []
    labels: list[np.ndarray] = []
    stamps: list[int] = []
    with RawBag(bag) as src:
        for m in src.messages([points_topic, pose_topic]):
            msg = src.deserialize(m)
            if m.topic == pose_topic:
                try:
                    frame, stamp, position, quaternion = read_pose_msg(msg)
                except InvalidPoseError:
                    continue
                if frame == frame_id:
                    poses.add(stamp, position, quaternion)
                continue
            try:
                frame, stamp = read_cloud_header(msg)
                if frame != frame_id:
                    continue
                view, xyz, rows = cloud_points(msg)
            except InvalidCloudError:
                continue
            chunks.append(xyz)
            stamps.append(stamp)
            if has_label_field(view):
                labels.append(np.clip(view['label'].reshape(-1)[rows], 0, 255).astype(np.uint8))
            else:
                labels.append(np.full(len(rows), 255, np.uint8))
    if not len(poses):
        raise BagError(f'{bag}: no pose in frame {frame_id!r} on {pose_topic}: the sensor '
                       'origins of the returns are unknown')
    if not chunks:
        raise BagError(f'{bag}: no cloud in frame {frame_id!r} on {points_topic}')
    origins = np.full((len(stamps), 3), np.nan)
    for c, stamp in enumerate(stamps):
        try:
            origins[c] = poses.lookup(stamp)[0]
        except InvalidPoseError:
            pass
    sizes = [len(c) for c in chunks]
    return FlightReturns(np.concatenate(chunks),
                         np.repeat(np.arange(len(chunks), dtype=np.int64), sizes),
                         origins, np.array(stamps, np.int64), np.concatenate(labels), poses)
