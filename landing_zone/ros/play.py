"""``landing-zone play``: publish a bag's messages over rclpy at the recorded (or a scaled) rate.

There is no ``ros2 bag`` in a pip-installed ROS, so this is how a recorded or simulated flight
drives the live node. Messages are read with :class:`landing_zone.io.bags.RawBag` (ROS 2 .mcap /
.db3, ROS 1 .bag converted to CDR) and published as they are stored, their CDR bytes handed to
rclpy's serialized publish (the wire format is the one thing both implementations share exactly,
and nothing is deserialized on the way), in log-time order, each at
``start + (log_time - first_log_time) / rate``.

By default it first waits (up to ``wait_subscribers`` seconds) until the topics have their
subscribers and the subscriptions have matched, so a node that is already up gets the bag
whole: a message published before the match is lost to it (``missed_at_start``).

``loops`` plays the bag again and again (a soak test); with ``restamp`` every pass after the
first is shifted in time, log time and the ``header.stamp`` of every message that starts with a
``std_msgs/Header`` alike, by whole bag spans, so the stamps keep increasing as a live sensor's do.
"""
from __future__ import annotations

import itertools
import os
import struct
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from landing_zone.errors import BagError, ConfigError

__all__ = ['PlayStats', 'parse_remaps', 'play', 'wait_for_subscribers', 'WAIT_SUBSCRIBERS']

# How long play waits for subscribers by default [s]: a node starting beside it is ready in a
# few seconds (model, warm-up) before it subscribes.
WAIT_SUBSCRIBERS = 30.0
# Once one topic has a subscriber, how long the others may take [s]: a node subscribes to all
# its inputs at once, so a topic still without one then is one nobody listens to.
SETTLE_OTHERS = 2.0
# After discovery, time for the subscriber's side of the match (the reader must know the writer
# too, or it drops what the writer sends) [s].
MATCH_SETTLE = 0.5


@dataclass
class PlayStats:
    """What a play published."""

    messages: int = 0
    by_topic: dict[str, int] = field(default_factory=dict)
    bag_seconds: float = 0.0  # log-time span of the messages played [s]
    seconds: float = 0.0  # wall time from the first message to the last [s]
    late: float = 0.0  # the most a message was published after its due time [s]
    loops: int = 0  # passes over the bag begun
    subscribed: int = -1  # topics that had a subscriber when it began (-1: it did not wait)


def parse_remaps(remaps: Iterable[str] | None) -> dict[str, str]:
    """``['/lidar/points:=/points', ...]`` -> ``{'/lidar/points': '/points'}``.

    Raises:
        ConfigError: an entry is not ``FROM:=TO``.
    """
    out: dict[str, str] = {}
    for item in remaps or []:
        src, sep, dst = item.partition(':=')
        if not sep or not src or not dst:
            raise ConfigError(f'remap must look like /from:=/to, got {item!r}')
        out[src] = dst
    return out


def wait_for_subscribers(pubs: Iterable[Any], timeout: float) -> int:
    """Wait until every publisher has a subscriber (or, once one has, :data:`SETTLE_OTHERS`
    for the rest), then :data:`MATCH_SETTLE`; return how many have one."""
    pubs = list(pubs)
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        have = sum(p.get_subscription_count() > 0 for p in pubs)
        if have == len(pubs):
            break
        if have:
            deadline = min(deadline, time.monotonic() + SETTLE_OTHERS)
        time.sleep(0.05)
    have = sum(p.get_subscription_count() > 0 for p in pubs)
    if have:
        time.sleep(MATCH_SETTLE)
    return have


def play(bag: str | os.PathLike[str], rate: float = 1.0, topics: Iterable[str] | None = None,
         remap: dict[str, str] | None = None, wait_subscribers: float = WAIT_SUBSCRIBERS,
         linger: float = 0.5, progress: bool = True, qos_depth: int = 100,
         context: Any = None, reliability: str = 'reliable', loops: int = 1,
         restamp: bool = False, duration: float | None = None,
         on_publish: Callable[[str, int, float], None] | None = None) -> PlayStats:
    """Publish a bag's messages at their recorded rate times ``rate``.

    Args:
        bag: ROS 2 bag (directory, .mcap, .db3) or ROS 1 .bag.
        rate: playback speed (2.0: twice as fast).
        topics: only these topics (each must be in the bag); default all.
        remap: bag topic -> published topic.
        wait_subscribers: wait up to this long [s] until the topics have subscribers before
            the first message (:func:`wait_for_subscribers`; 0: start at once).
        linger: keep the publishers alive this long [s] after the last message, so reliable
            transports deliver it.
        progress: show a tqdm progress bar (on a terminal).
        qos_depth: publisher history depth (volatile).
        context: an initialised rclpy Context; default: a private one created here.
        reliability: 'reliable' or 'best_effort' (what a LiDAR driver uses).
        loops: passes over the bag (0: until ``duration`` ends).
        restamp: shift the stamps of every pass after the first by whole bag spans.
        duration: stop after this many seconds of playing [s]; None: when the loops end.
        on_publish: called with (topic, header stamp [ns] or -1, time.monotonic() after the
            publish) for every message (the benchmarks measure latencies from it).

    Returns:
        :class:`PlayStats`.

    Raises:
        BagError: the bag is missing, unreadable, or lacks a topic asked for.
        ConfigError: a rate that is not positive, an unknown reliability.
    """
    import rclpy

    # the rate, the reliability and the topics, checked
    if not rate > 0:
        raise ConfigError(f'rate must be positive, got {rate}')
    policy = _reliability_policy(reliability)
    available, wanted = _wanted_topics(bag, topics)
    remap = remap or {}
    # a node, in a context of its own unless one is given
    own = context is None
    if own:
        context = rclpy.Context()
        rclpy.init(context=context)
    node = rclpy.create_node('landing_zone_player', context=context)
    stats = PlayStats()
    try:
        # a publisher per topic; the wait until they have subscribers
        pubs = _publishers(node, wanted, available, remap, qos_depth, policy)
        if wait_subscribers > 0:
            stats.subscribed = wait_for_subscribers(pubs.values(), wait_subscribers)
        # the passes over the bag, each message at its due time
        player = _Player(pubs, stats, rate, restamp, duration, on_publish)
        player.play(bag, wanted, loops, progress)
        # time for reliable transports to deliver the last messages
        time.sleep(max(linger, 0.0))
    finally:
        node.destroy_node()
        if own:
            rclpy.try_shutdown(context=context)
    return stats


def _reliability_policy(reliability: str) -> Any:
    """The rclpy ReliabilityPolicy named ``reliability``.

    Raises:
        ConfigError: neither 'reliable' nor 'best_effort'.
    """
    from rclpy.qos import ReliabilityPolicy

    policies = {'reliable': ReliabilityPolicy.RELIABLE,
                'best_effort': ReliabilityPolicy.BEST_EFFORT}
    if reliability not in policies:
        raise ConfigError(f'reliability must be reliable or best_effort, got {reliability!r}')
    return policies[reliability]


def _wanted_topics(bag: str | os.PathLike[str], topics: Iterable[str] | None
                   ) -> tuple[dict[str, str], list[str]]:
    """(the bag's topic -> type, the topics to play: ``topics``, default all, sorted).

    Raises:
        BagError: the bag is missing or unreadable, or lacks one of ``topics``.
    """
    from landing_zone.io.bags import bag_topics

    available = bag_topics(Path(bag))
    wanted = sorted(available) if topics is None else list(topics)
    missing = [t for t in wanted if t not in available]
    if missing:
        raise BagError(f'{bag} lacks topic(s) {", ".join(missing)} (it has '
                       f'{", ".join(sorted(available)) or "no topics"})')
    return available, wanted


def _publishers(node: Any, wanted: list[str], available: dict[str, str],
                remap: dict[str, str], qos_depth: int, policy: Any) -> dict[str, Any]:
    """Bag topic -> a publisher of its type on the remapped topic (volatile, keep last
    ``qos_depth``, reliability ``policy``)."""
    from rclpy.qos import HistoryPolicy, QoSProfile

    from msg_adapters import MessageTypes

    types = MessageTypes.rclpy()
    qos = QoSProfile(depth=qos_depth, history=HistoryPolicy.KEEP_LAST, reliability=policy)
    pubs = {}
    for topic in wanted:
        cls = types.get(available[topic])
        pubs[topic] = node.create_publisher(cls, remap.get(topic, topic), qos)
    return pubs


class _Player:
    """Publishes the passes over a bag, each message at
    ``start + (log_time - first_log_time) / rate``, counting them into ``stats``.

    The clock starts at the first message. A pass after the first is ``k`` bag spans later in
    log time (its stamps too, with ``restamp``); playing stops when the passes end or the
    next message is due after ``duration``.
    """

    def __init__(self, pubs: dict[str, Any], stats: PlayStats, rate: float, restamp: bool,
                 duration: float | None,
                 on_publish: Callable[[str, int, float], None] | None) -> None:
        self.pubs = pubs
        self.stats = stats
        self.rate = rate
        self.restamp = restamp
        self.duration = duration
        self.on_publish = on_publish
        self.start_wall: float | None = None
        self.end: float | None = None  # when the duration ends (monotonic) [s]
        self.first_ns = self.last_ns = 0
        self.bar: Any = None  # the progress bar of the pass playing (or last played)

    def play(self, bag: str | os.PathLike[str], wanted: list[str], loops: int,
             progress: bool) -> None:
        """Play ``loops`` passes over the topics ``wanted`` (0: until the duration ends, or
        for ever), then set the stats' spans."""
        from tqdm import tqdm

        from landing_zone.io.bags import RawBag

        span_ns = 0
        with RawBag(bag) as src:
            stamped = {t: _starts_with_header(src, t) for t in wanted}
            passes = itertools.count() if loops == 0 else range(loops)
            for k in passes:
                self.stats.loops += 1
                self.bar = tqdm(src.messages(wanted), unit=' msg', desc=f'play {Path(bag).name}',
                                disable=None if progress else True, mininterval=0.5,
                                leave=False)
                done = self._play_pass(self.bar, k * span_ns, stamped)
                if k == 0:
                    # a pass after this one starts one mean message interval after its end
                    n = max(self.stats.messages - 1, 1)
                    span_ns = (self.last_ns - self.first_ns) + (self.last_ns - self.first_ns) // n
                if done or span_ns <= 0:
                    break
        if self.start_wall is not None:
            self.stats.seconds = time.monotonic() - self.start_wall
            self.stats.bag_seconds = (self.last_ns - self.first_ns) / 1e9

    def _play_pass(self, messages: Iterable[Any], shift: int, stamped: dict[str, bool]) -> bool:
        """Publish one pass's messages, ``shift`` [ns] later in log time than recorded, each
        at its due time; True: the duration ended before its end."""
        for m in messages:
            if self.start_wall is None:
                self.start_wall, self.first_ns = time.monotonic(), m.stamp_ns
                if self.duration is not None:
                    self.end = self.start_wall + self.duration
            t_ns = m.stamp_ns + shift
            due = self.start_wall + (t_ns - self.first_ns) / 1e9 / self.rate
            delay = due - time.monotonic()
            if self.end is not None and due > self.end:
                return True
            if delay > 0:
                time.sleep(delay)
            else:
                self.stats.late = max(self.stats.late, -delay)
            self._publish(m, shift if self.restamp else 0, stamped[m.topic])
            self.last_ns = t_ns
        return False

    def _publish(self, m: Any, shift_ns: int, stamped: bool) -> None:
        """Publish message ``m``'s CDR bytes, its header stamp (if it has one) moved by
        ``shift_ns``, and count it."""
        data, stamp = bytes(m.data), -1
        if stamped:
            data, stamp = _restamp(data, shift_ns)
        self.pubs[m.topic].publish(data)
        if self.on_publish is not None:
            self.on_publish(m.topic, stamp, time.monotonic())
        self.stats.messages += 1
        self.stats.by_topic[m.topic] = self.stats.by_topic.get(m.topic, 0) + 1


def _starts_with_header(src: Any, topic: str) -> bool:
    """Whether a topic's type begins with a std_msgs/Header (so its stamp sits at CDR bytes
    4..12: right after the 4-byte encapsulation header, int32 sec and uint32 nanosec)."""
    store, msgtype = src.types_of(topic), src.topics[topic]
    try:
        fields = store.fielddefs[msgtype][1]
        first = fields[0]
        return first[0] == 'header' and 'std_msgs/msg/Header' in repr(first[1])
    except (KeyError, IndexError, TypeError):
        return False


def _restamp(data: bytes, shift_ns: int) -> tuple[bytes, int]:
    """(CDR with its header stamp moved by ``shift_ns``, the new stamp [ns])."""
    fmt = '>iI' if data[1] == 0 else '<iI'  # encapsulation 0x0000: big-endian CDR
    sec, nsec = struct.unpack_from(fmt, data, 4)
    stamp = sec * 1_000_000_000 + nsec + shift_ns
    if shift_ns == 0:
        return data, stamp
    buf = bytearray(data)
    struct.pack_into(fmt, buf, 4, *divmod(stamp, 1_000_000_000))
    return bytes(buf), stamp
