"""``landing-zone play``: publish a bag's messages over rclpy at the recorded (or a scaled) rate.

There is no ``ros2 bag`` in a pip-installed ROS, so this is how a recorded or simulated flight
drives the live node. Messages are read with :mod:`landing_zone.io.bags` (ROS 2 .mcap / .db3,
ROS 1 .bag), turned into rclpy messages through their CDR bytes (rosbags serializes, rclpy
deserializes: the wire format is the one thing both implementations share exactly) and
published in log-time order, each at ``start + (log_time - first_log_time) / rate``.
"""
from __future__ import annotations

import os
import time
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from landing_zone.errors import BagError, ConfigError

__all__ = ['PlayStats', 'parse_remaps', 'play', 'to_rclpy']


@dataclass
class PlayStats:
    """What a play published."""

    messages: int = 0
    by_topic: dict[str, int] = field(default_factory=dict)
    bag_seconds: float = 0.0  # log-time span of the messages played [s]
    seconds: float = 0.0  # wall time from the first message to the last [s]
    late: float = 0.0  # the most a message was published after its due time [s]


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


def to_rclpy(msg: Any, msgtype: str, cls: type) -> Any:
    """A rosbags message as an instance of the rclpy class ``cls``, via its CDR bytes."""
    from rclpy.serialization import deserialize_message

    from msg_adapters import jazzy_typestore

    try:
        cdr = jazzy_typestore().serialize_cdr(msg, msgtype)
    except Exception as err:  # rosbags' SerdeError and friends: a message this store can't write
        raise BagError(f'cannot convert a {msgtype} for publishing: {err}') from err
    return deserialize_message(bytes(cdr), cls)


def play(bag: str | os.PathLike[str], rate: float = 1.0, topics: Iterable[str] | None = None,
         remap: dict[str, str] | None = None, wait_subscribers: float = 0.0,
         linger: float = 0.5, progress: bool = True, qos_depth: int = 100,
         context: Any = None) -> PlayStats:
    """Publish a bag's messages at their recorded rate times ``rate``.

    Args:
        bag: ROS 2 bag (directory, .mcap, .db3) or ROS 1 .bag.
        rate: playback speed (2.0: twice as fast).
        topics: only these topics (each must be in the bag); default all.
        remap: bag topic -> published topic.
        wait_subscribers: wait up to this long [s] until every topic has a subscriber before
            the first message (0: start at once).
        linger: keep the publishers alive this long [s] after the last message, so reliable
            transports deliver it.
        progress: show a tqdm progress bar (on a terminal).
        qos_depth: publisher history depth (reliable, volatile).
        context: an initialised rclpy Context; default: a private one created here.

    Returns:
        :class:`PlayStats`.

    Raises:
        BagError: the bag is missing, unreadable, or lacks a topic asked for.
        ConfigError: a rate that is not positive.
    """
    import rclpy
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from tqdm import tqdm

    from landing_zone.io.bags import bag_topics, read_messages
    from msg_adapters import MessageTypes

    if not rate > 0:
        raise ConfigError(f'rate must be positive, got {rate}')
    available = bag_topics(Path(bag))
    wanted = sorted(available) if topics is None else list(topics)
    missing = [t for t in wanted if t not in available]
    if missing:
        raise BagError(f'{bag} lacks topic(s) {", ".join(missing)} (it has '
                       f'{", ".join(sorted(available)) or "no topics"})')
    remap = remap or {}
    own = context is None
    if own:
        context = rclpy.Context()
        rclpy.init(context=context)
    node = rclpy.create_node('landing_zone_player', context=context)
    stats = PlayStats()
    try:
        types = MessageTypes.rclpy()
        qos = QoSProfile(depth=qos_depth, history=HistoryPolicy.KEEP_LAST,
                         reliability=ReliabilityPolicy.RELIABLE)
        pubs = {}
        for topic in wanted:
            cls = types.get(available[topic])
            pubs[topic] = (node.create_publisher(cls, remap.get(topic, topic), qos), cls)
        if wait_subscribers > 0:
            deadline = time.monotonic() + wait_subscribers
            while time.monotonic() < deadline and not all(
                    p.get_subscription_count() > 0 for p, _ in pubs.values()):
                time.sleep(0.05)
        start_wall = None
        first_ns = last_ns = 0
        bar = tqdm(read_messages(bag, wanted), unit=' msg', desc=f'play {Path(bag).name}',
                   disable=None if progress else True, mininterval=0.5, leave=False)
        for m in bar:
            if start_wall is None:
                start_wall, first_ns = time.monotonic(), m.stamp_ns
            due = start_wall + (m.stamp_ns - first_ns) / 1e9 / rate
            delay = due - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                stats.late = max(stats.late, -delay)
            pub, cls = pubs[m.topic]
            pub.publish(to_rclpy(m.msg, m.msgtype, cls))
            stats.messages += 1
            stats.by_topic[m.topic] = stats.by_topic.get(m.topic, 0) + 1
            last_ns = m.stamp_ns
        if start_wall is not None:
            stats.seconds = time.monotonic() - start_wall
            stats.bag_seconds = (last_ns - first_ns) / 1e9
        time.sleep(max(linger, 0.0))
    finally:
        node.destroy_node()
        if own:
            rclpy.try_shutdown(context=context)
    return stats
