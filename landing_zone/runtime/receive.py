"""What the live receive path keeps before integration: a bounded arrival queue and the
publishers' sequence numbers (clouds lost before this process could take them).

Used by :class:`~landing_zone.runtime.ingest.LivePipeline`; ROS-free.
"""
from __future__ import annotations

import collections
import struct
import threading
from collections.abc import Hashable
from dataclasses import dataclass
from typing import Any

from landing_zone.errors import LandingZoneError

__all__ = ['SequenceGaps', 'ReceiveQueue', 'PLACE_RETURNS', 'MIN_PLACE_RETURNS', 'decode_cloud',
           'POINTS_TYPE']

POINTS_TYPE = 'sensor_msgs/msg/PointCloud2'
# rmw's "no sequence number" (RMW_MESSAGE_INFO_SEQUENCE_NUMBER_UNSUPPORTED) and anything
# above 2^63: not a count this process can reason about.
_SEQ_MAX = 2 ** 63


class SequenceGaps:
    """Clouds lost before this process could take them, from publication sequence numbers.

    Every DDS writer numbers its samples 1, 2, 3, ... A gap between two numbers that arrived
    from one publisher is that many samples lost on the way (the reader's history overflowing,
    a lost fragment, ...). Numbers are kept per publisher (its GID), since two publishers on
    one topic count independently; with no GID (``publisher=None``) all arrivals are taken as one
    publisher's, and a number that does not increase starts a new count (a restarted publisher).

    A publisher's first arrival ``s`` says ``s - 1`` samples came before it: published before
    the subscription matched, or lost while it did (``missed_at_start``). Samples lost after
    a publisher's last arrival leave no gap and cannot be seen here.

    Attributes:
        transport: samples lost between two arrivals of a publisher, in all.
        missed_at_start: samples before each publisher's first arrival, in all.
        publishers: publishers (or, without GIDs, counts) seen.
    """

    def __init__(self) -> None:
        self._last: dict[Hashable, int] = {}
        self.transport = 0
        self.missed_at_start = 0
        self.publishers = 0

    def observe(self, publisher: Hashable, seq: int | None) -> tuple[int, int]:
        """Record one arrival.

        Args:
            publisher: the publisher's identity (its GID bytes), or None if unknown.
            seq: its publication sequence number; None, 0 or rmw's "unsupported" are ignored.

        Returns:
            ``(lost, missed_at_start)`` this arrival revealed.
        """
        if seq is None or seq <= 0 or seq >= _SEQ_MAX:
            return 0, 0
        last = self._last.get(publisher)
        self._last[publisher] = seq
        if last is None or seq <= last:
            self.publishers += 1
            self.missed_at_start += seq - 1
            return 0, seq - 1
        lost = seq - last - 1
        self.transport += lost
        return lost, 0


@dataclass
class _Entry:
    kind: str  # 'cloud' or 'pose'
    payload: Any  # CDR bytes or a message
    arrival: float  # clock() when it was offered
    nbytes: int
    points: int = 0  # declared points of a cloud (0 when unknown before decoding)


# A cloud of PLACE_RETURNS declared returns or more takes a whole place of the queue's
# ``max_clouds``; a smaller one the share of a place its returns are, at least
# MIN_PLACE_RETURNS / PLACE_RETURNS (a cloud whose size is unknown, bytes that are no cloud):
# integrating it costs about that share, and so a flood of tiny or malformed clouds (a few
# hundred returns declared, or none) cannot push the clouds that carry the data out of the queue.
# (test_node: 100 malformed clouds/s beside a 20 Hz flight pushed good clouds out, under load.)
PLACE_RETURNS = 1000
MIN_PLACE_RETURNS = 50


def _place_share(points: int) -> int:
    """A cloud's share of a queue place, in returns (PLACE_RETURNS: one whole place)."""
    return min(max(int(points), MIN_PLACE_RETURNS), PLACE_RETURNS)


class ReceiveQueue:
    """Clouds and poses in arrival order, bounded; the newest cloud always gets in.

    Poses ride in the same queue, so the stream sees clouds and poses in the order they came;
    they are tiny, and bounded separately (``max_poses``, oldest dropped first).

    Args:
        max_clouds: places for clouds: a cloud of at least :data:`PLACE_RETURNS` declared
            returns takes one, a smaller one its share of one (at least 1/20), so the queue
            holds ``max_clouds`` real clouds however many tiny ones come beside them.
        max_bytes: bytes of clouds held at most (a cloud larger than this alone still gets in,
            alone).
        max_poses: poses held at most.

    Attributes:
        dropped_clouds, dropped_poses: pushed out to make room (the ``overload`` counts).
        peak_clouds: the most clouds it held at once.
    """

    def __init__(self, max_clouds: int, max_bytes: int, max_poses: int = 1000) -> None:
        self.max_clouds = int(max_clouds)
        self.max_bytes = int(max_bytes)
        self.max_poses = int(max_poses)
        self._items: collections.deque[_Entry] = collections.deque()
        self._cond = threading.Condition(threading.Lock())
        self._clouds = 0
        self._share = 0  # places taken, in returns (see _place_share)
        self._poses = 0
        self._bytes = 0
        self.dropped_clouds = 0
        self.dropped_points = 0
        self.dropped_poses = 0
        self.peak_clouds = 0

    def put(self, kind: str, payload: Any, arrival: float, nbytes: int = 0,
            points: int = 0) -> int:
        """Append one cloud (``kind='cloud'``) or pose; return how many entries it pushed out."""
        entry = _Entry(kind, payload, arrival, int(nbytes), int(points))
        pushed = 0
        with self._cond:
            if kind == 'cloud':
                share = _place_share(entry.points)
                while self._clouds and (
                        self._share + share > self.max_clouds * PLACE_RETURNS
                        or self._bytes + entry.nbytes > self.max_bytes):
                    self._remove_oldest('cloud')
                    pushed += 1
                self._clouds += 1
                self._share += share
                self._bytes += entry.nbytes
                self.peak_clouds = max(self.peak_clouds, self._clouds)
            else:
                while self._poses >= self.max_poses:
                    self._remove_oldest('pose')
                    pushed += 1
                self._poses += 1
            self._items.append(entry)
            self._cond.notify()
        return pushed

    def _remove_oldest(self, kind: str) -> None:
        for i, e in enumerate(self._items):
            if e.kind == kind:
                del self._items[i]
                if kind == 'cloud':
                    self._clouds -= 1
                    self._share -= _place_share(e.points)
                    self._bytes -= e.nbytes
                    self.dropped_clouds += 1
                    self.dropped_points += e.points
                else:
                    self._poses -= 1
                    self.dropped_poses += 1
                return

    def get(self, timeout: float) -> _Entry | None:
        """The oldest entry, waiting up to ``timeout`` seconds; None if none came."""
        with self._cond:
            if not self._items:
                self._cond.wait(timeout)
                if not self._items:
                    return None
            e = self._items.popleft()
            if e.kind == 'cloud':
                self._clouds -= 1
                self._share -= _place_share(e.points)
                self._bytes -= e.nbytes
            else:
                self._poses -= 1
            return e

    def wake(self) -> None:
        """Wake a waiting :meth:`get` (to stop)."""
        with self._cond:
            self._cond.notify_all()

    @property
    def clouds(self) -> int:
        """Clouds waiting now."""
        return self._clouds

    def __len__(self) -> int:
        return len(self._items)


def decode_cloud(payload: Any) -> Any:
    """A cloud message from what the subscription took: CDR bytes (decoded with the rosbags
    deserializer replay uses) or a message object (returned as it is).

    Raises:
        LandingZoneError: the bytes are not a serialized PointCloud2.
    """
    if not isinstance(payload, (bytes, bytearray, memoryview)):
        return payload
    from msg_adapters import jazzy_typestore

    try:
        return jazzy_typestore().deserialize_cdr(payload, POINTS_TYPE)
    except Exception as err:  # rosbags raises SerdeError, struct.error, IndexError, ...
        text = ' '.join(str(err).split()) or type(err).__name__
        raise LandingZoneError(f'not a serialized PointCloud2 ({len(payload)} bytes): '
                               f'{text[:120]}') from None


def _declared_size(payload: Any) -> tuple[int, int]:
    """(bytes, points) of a cloud as cheaply as it can be told, for the queue's bounds and the
    overload counts: from CDR bytes, ``height * width`` read where a PointCloud2 keeps them
    (after the header's stamp and frame_id), 0 points if the bytes do not get that far."""
    if isinstance(payload, (bytes, bytearray, memoryview)):
        return len(payload), _cdr_points(payload)
    try:
        return len(payload.data), int(payload.width) * int(payload.height)
    except (AttributeError, TypeError, ValueError):
        return 0, 0


def _cdr_points(data: bytes | bytearray | memoryview) -> int:
    # encapsulation (4 bytes: byte order in the second), stamp (int32 sec, uint32 nanosec),
    # frame_id (uint32 length with its NUL, then the characters), then uint32 height and
    # width, 4-aligned counting from after the encapsulation
    try:
        order = '<' if data[1] == 1 else '>'
        (n,) = struct.unpack_from(order + 'I', data, 12)
        off = 16 + n
        off += (-(off - 4)) % 4
        height, width = struct.unpack_from(order + 'II', data, off)
    except (IndexError, struct.error):
        return 0
    return int(height) * int(width)
