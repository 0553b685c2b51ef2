"""An outside publisher for test_node: malformed clouds at a high rate, a good flight among them.

``python test/ros/mixed_publisher.py --bag SITE.mcap --seconds 60 --bad-hz 100 --start 20 --out X``
publishes, best effort, for ``--seconds``: malformed clouds at ``--bad-hz`` (cycling through the
kinds below, from a publisher of their own) and NaN poses, and, from ``--start`` seconds on, the
bag's clouds and poses at their recorded rate (their CDR bytes as stored). It writes the counts it
published by kind as JSON, so the test can compare them with what the node counted.
"""
from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

KINDS = ('truncated', 'no_z', 'int_x', 'garbage', 'wrong_frame')
REASON = {'truncated': 'malformed', 'no_z': 'malformed', 'int_x': 'malformed',
          'garbage': 'malformed', 'wrong_frame': 'wrong_frame'}


def bad_clouds():
    """One message (or CDR bytes) of every kind."""
    from sensor_msgs.msg import PointCloud2, PointField

    n = 200
    xyz = np.random.default_rng(0).uniform(-3, 3, (n, 3)).astype(np.float32).tobytes()
    f32 = [PointField(name=c, offset=4 * i, datatype=7, count=1) for i, c in enumerate('xyz')]

    def cloud(fields, data, frame='map'):
        m = PointCloud2(height=1, width=n, point_step=12, row_step=12 * n, fields=fields,
                        data=data)
        m.header.frame_id = frame
        return m

    ints = [PointField(name='x', offset=0, datatype=5, count=1)] + f32[1:]
    garbage = bytes([0, 1, 0, 0]) + np.random.default_rng(1).bytes(64)
    return {'truncated': cloud(f32, xyz[:-7]), 'no_z': cloud(f32[:2], xyz),
            'int_x': cloud(ints, xyz), 'garbage': garbage,
            'wrong_frame': cloud(f32, xyz, frame='lidar')}


def main(argv=None):
    ap = argparse.ArgumentParser()
    ap.add_argument('--bag', required=True)
    ap.add_argument('--seconds', type=float, default=60.0)
    ap.add_argument('--bad-hz', type=float, default=100.0)
    ap.add_argument('--start', type=float, default=20.0)
    ap.add_argument('--out', required=True)
    args = ap.parse_args(argv)

    import rclpy
    from geometry_msgs.msg import PoseStamped
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import PointCloud2

    from landing_zone.io.bags import RawBag

    with RawBag(args.bag) as src:
        good = [(m.stamp_ns, m.topic, bytes(m.data)) for m in src.messages()]
    rclpy.init()
    node = rclpy.create_node('mixed_publisher')
    qos = qos_profile_sensor_data
    pub_bad = node.create_publisher(PointCloud2, '/lidar/points', qos)
    pub_bad_pose = node.create_publisher(PoseStamped, '/lidar/pose', qos)
    pub_good = {'/lidar/points': node.create_publisher(PointCloud2, '/lidar/points', qos),
                '/lidar/pose': node.create_publisher(PoseStamped, '/lidar/pose', qos)}
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and any(p.get_subscription_count() == 0 for p in
                                              [pub_bad, pub_bad_pose, *pub_good.values()]):
        time.sleep(0.05)
    time.sleep(0.5)
    bad = bad_clouds()
    nan_pose = PoseStamped()
    nan_pose.header.frame_id = 'map'
    nan_pose.pose.position.x = float('nan')
    g0 = good[0][0]
    events = [(k / args.bad_hz, 0, k) for k in range(int(args.seconds * args.bad_hz))]
    events += [(args.start + (s - g0) / 1e9, 1, i) for i, (s, _, _) in enumerate(good)]
    events.sort()
    counts = {k: 0 for k in KINDS}
    counts.update(good_clouds=0, good_poses=0, bad_poses=0)
    t0 = time.monotonic()
    for due, kind, i in events:
        delay = t0 + due - time.monotonic()
        if delay > 0:
            time.sleep(delay)
        if kind == 0:
            which = KINDS[i % len(KINDS)]
            pub_bad.publish(bad[which])
            counts[which] += 1
            if i % 10 == 0:
                pub_bad_pose.publish(nan_pose)
                counts['bad_poses'] += 1
        else:
            _, topic, data = good[i]
            pub_good[topic].publish(data)
            counts['good_clouds' if topic == '/lidar/points' else 'good_poses'] += 1
    time.sleep(1.0)
    node.destroy_node()
    rclpy.try_shutdown()
    counts['by_reason'] = {}
    for k in KINDS:
        counts['by_reason'][REASON[k]] = counts['by_reason'].get(REASON[k], 0) + counts[k]
    with open(args.out, 'w', encoding='utf-8') as f:
        json.dump(counts, f)


if __name__ == '__main__':
    sys.exit(main())
