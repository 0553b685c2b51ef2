"""The outside publisher of ``bench live``: a LiDAR driver at a chosen rate, in its own process.

``python -m landing_zone.tools.bench.live_publisher --bag SITE.mcap --points N --hz H ...``
publishes clouds of ``N`` returns at ``H`` Hz and sensor poses at 100 Hz on ``/lidar/points``
and ``/lidar/pose``, for ``--seconds``, then writes what it published (each cloud's stamp and
the monotonic time right after its publish) as JSON.

The clouds are made from a recorded flight so that the node's work per return is a real one:
output cloud ``k`` (stamp ``k / H`` after the start) takes the flight's returns of the matching
``1 / H`` of flight time and resamples them to ``N`` (with replacement, 1 cm of jitter, seeded),
with the flight's sensor pose; the flight is cut into a ring of ``4 H`` clouds (4 s, built and
serialized before the first publish) that repeats, stamped from the wall clock at the start
(so the stamps of one run after another keep increasing, as a driver's do). Like a
driver, a cloud goes out when its scan is complete (``1 / H`` after its stamp) and poses go out
as their time comes, so a cloud's pose is there when the cloud arrives. Messages are published
as CDR bytes, re-stamped in place, so publishing costs this process next to nothing.
"""
from __future__ import annotations

import argparse
import json
import struct
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

NS = 1_000_000_000
POSE_HZ = 100.0
RING_SECONDS = 4.0
T0 = 1_800_000_000 * NS  # the ring is built with stamps from here; publishing re-stamps it


def _flight(bag: Path) -> tuple[list[tuple[int, np.ndarray]], Any]:
    """The flight's clouds (stamp, float32 xyz) and a pose buffer over its poses."""
    from landing_zone.io.bags import read_messages
    from landing_zone.poses import PoseBuffer
    from msg_adapters.pose import read_pose_msg
    from msg_adapters import stamp_to_ns
    from msg_adapters.pointcloud import cloud_to_xyz

    clouds = []
    poses = PoseBuffer(max_age_s=1e9, tolerance_s=1.0)
    for m in read_messages(bag, ['/lidar/points', '/lidar/pose']):
        if m.topic == '/lidar/pose':
            _, stamp, position, quaternion = read_pose_msg(m.msg)
            poses.add(stamp, position, quaternion)
        else:
            xyz, _ = cloud_to_xyz(m.msg)
            clouds.append((stamp_to_ns(m.msg.header.stamp), xyz.astype(np.float32)))
    return clouds, poses


def build_ring(bag: Path, points: int, hz: float, seed: int, frame: str = 'map'
               ) -> tuple[list[bytes], list[bytes], float]:
    """Serialized clouds and poses of one ring (stamps from T0) and its length [s]."""
    from msg_adapters import jazzy_typestore as typestore
    from msg_adapters import MessageTypes, make_header
    from msg_adapters.pointcloud import make_cloud, points_to_structured
    from msg_adapters.pose import make_pose_stamped

    clouds, poses = _flight(bag)
    types = MessageTypes.rosbags()
    store = typestore()
    rng = np.random.default_rng(seed)
    f0 = clouds[0][0]
    f_span = clouds[-1][0] - f0
    n_ring = max(1, int(round(RING_SECONDS * hz)))
    ring_s = n_ring / hz
    out_clouds = []
    for k in range(n_ring):
        # the ring starts a third into the flight (the vehicle over the site) and wraps
        a = f0 + (f_span // 3 + int(k * NS / hz)) % max(f_span, 1)
        src = [xyz for s, xyz in clouds if a <= s < a + NS / hz] or \
            [min(clouds, key=lambda c: abs(c[0] - a))[1]]
        pool = np.concatenate(src)
        pick = pool[rng.integers(0, len(pool), points)]
        pick = pick + rng.normal(0.0, 0.01, pick.shape).astype(np.float32)
        header = make_header(T0 + int(k * NS / hz), frame, types)
        msg = make_cloud(points_to_structured(pick), header, types)
        out_clouds.append(bytes(store.serialize_cdr(msg, 'sensor_msgs/msg/PointCloud2')))
    out_poses = []
    for j in range(int(round(ring_s * POSE_HZ))):
        a = f0 + (f_span // 3 + int(j * NS / POSE_HZ)) % max(f_span, 1)
        position, quaternion = poses.lookup(a)
        msg = make_pose_stamped(T0 + int(j * NS / POSE_HZ), frame, position, quaternion, types)
        out_poses.append(bytes(store.serialize_cdr(msg, 'geometry_msgs/msg/PoseStamped')))
    return out_clouds, out_poses, ring_s


def _restamped(data: bytes, stamp_ns: int) -> bytes:
    buf = bytearray(data)
    struct.pack_into('<iI', buf, 4, *divmod(stamp_ns, NS))  # the header stamp (CDR LE)
    return bytes(buf)


def publish(args: argparse.Namespace) -> dict[str, Any]:
    import rclpy
    from geometry_msgs.msg import PoseStamped
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2

    clouds, poses, ring_s = build_ring(Path(args.bag), args.points, args.hz, args.seed)
    rclpy.init()
    node = rclpy.create_node('landing_zone_bench_publisher')
    qos = QoSProfile(depth=args.depth, history=HistoryPolicy.KEEP_LAST,
                     reliability=ReliabilityPolicy.RELIABLE if args.reliability == 'reliable'
                     else ReliabilityPolicy.BEST_EFFORT)
    pub_c = node.create_publisher(PointCloud2, '/lidar/points', qos)
    pub_p = node.create_publisher(PoseStamped, '/lidar/pose', qos)
    deadline = time.monotonic() + args.wait
    while time.monotonic() < deadline and (pub_c.get_subscription_count() == 0
                                           or pub_p.get_subscription_count() == 0):
        time.sleep(0.05)
    time.sleep(0.3)  # let the matching settle on both sides
    stamps: list[int] = []
    times: list[float] = []
    n_c = int(args.seconds * args.hz)
    n_p = int((args.seconds + 1.0 / args.hz) * POSE_HZ) + 1
    # one timeline: cloud k goes out at (k + 1) / hz, pose j at j / POSE_HZ (seconds)
    events = sorted([((k + 1) / args.hz, 1, k) for k in range(n_c)]
                    + [(j / POSE_HZ, 0, j) for j in range(n_p)])
    t0 = time.monotonic()
    base = time.time_ns()
    late = 0.0
    for due, kind, i in events:
        delay = t0 + due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        else:
            late = max(late, -delay)
        if kind == 1:
            stamp = base + int(round(i * NS / args.hz))
            pub_c.publish(_restamped(clouds[i % len(clouds)], stamp))
            times.append(time.monotonic())
            stamps.append(stamp)
        else:
            stamp = base + int(round(i * NS / POSE_HZ))
            pub_p.publish(_restamped(poses[i % len(poses)], stamp))
    time.sleep(args.linger)
    node.destroy_node()
    rclpy.try_shutdown()
    return {'published': len(stamps), 'stamps': stamps, 'times': times, 'late_s': late,
            'ring_seconds': ring_s, 'points': args.points, 'hz': args.hz}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split('\n\n')[0])
    ap.add_argument('--bag', required=True)
    ap.add_argument('--points', type=int, required=True)
    ap.add_argument('--hz', type=float, required=True)
    ap.add_argument('--seconds', type=float, default=10.0)
    ap.add_argument('--reliability', choices=('best_effort', 'reliable'), default='best_effort')
    ap.add_argument('--depth', type=int, default=5, help='publisher history depth')
    ap.add_argument('--seed', type=int, default=0)
    ap.add_argument('--wait', type=float, default=30.0, help='wait for the node [s]')
    ap.add_argument('--linger', type=float, default=1.0)
    ap.add_argument('--out', required=True, help='JSON of what was published')
    args = ap.parse_args(argv)
    result = publish(args)
    Path(args.out).write_text(json.dumps(result), encoding='utf-8')


if __name__ == '__main__':
    sys.exit(main())
