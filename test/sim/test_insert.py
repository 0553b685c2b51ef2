"""insert-obstacles: insertion is exact and minimal.

Real bags (a small simulated flight over bare ground, and test_replay's hand-made flight whose
poses must be interpolated) go through :func:`insert_obstacles`; the output bag is read back
as raw CDR and compared message by message, byte by byte, with the input. The altered returns
are checked against the box's surface and counted against an independent slab-method ray/box
test written here; bad input is one line on stderr, exit 2 and no file.
"""
from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from landing_zone.tools import cli
from landing_zone.io.bags import BagWriter, RawBag
from landing_zone.tools.sim.alteration import ObstacleScene, alter_returns, segments_meet_boxes
from landing_zone.tools.sim.insert import insert_obstacles
from landing_zone.tools.sim.placement import ground_height
from landing_zone.tools.sim.recorded import read_flight
from landing_zone.tools.sim.flight import flight_config, simulate_flight
from landing_zone.tools.sim.library import get_model
from landing_zone.tools.sim.obstacles import Obstacle
from msg_adapters import MessageTypes, make_header, stamp_to_ns
from msg_adapters.pointcloud import cloud_to_structured, make_cloud, points_to_structured
from test_replay import sensor_at, write_flight

BOX = get_model('box')


def slab_hits(origins, points, lo, hi):
    """Independent reference: which segments origin -> point enter the box [lo, hi] before
    their end (t in [0, 1))."""
    d = points - origins
    with np.errstate(divide='ignore', invalid='ignore'):
        t1 = (lo - origins) / d
        t2 = (hi - origins) / d
    tmin = np.where(d == 0, np.where((origins > lo) & (origins < hi), -np.inf, np.inf),
                    np.minimum(t1, t2)).max(axis=1)
    tmax = np.where(d == 0, np.where((origins > lo) & (origins < hi), np.inf, -np.inf),
                    np.maximum(t1, t2)).min(axis=1)
    return (tmin <= tmax) & (tmax >= 0) & (tmin < 1)


def box_distance(p, lo, hi):
    """Signed distance to an axis-aligned box's surface (negative inside)."""
    c, h = (lo + hi) / 2, (hi - lo) / 2
    q = np.abs(p - c) - h
    outside = np.linalg.norm(np.maximum(q, 0), axis=1)
    inside = np.minimum(q.max(axis=1), 0)
    return outside + inside


def raw_messages(path):
    with RawBag(path) as src:
        return src.topics, [(m.topic, m.stamp_ns, bytes(m.data)) for m in src.messages()]


def decode(path, topic='/lidar/points'):
    """(stamp_ns, structured points) of every cloud, in bag order."""
    with RawBag(path) as src:
        out = []
        for m in src.messages([topic]):
            msg = src.deserialize(m)
            out.append((stamp_to_ns(msg.header.stamp), cloud_to_structured(msg)))
        return out


@pytest.fixture(scope='module')
def site(tmp_path_factory):
    """A 4 m site of bare ground, no obstacles: one pass, about 100 clouds."""
    d = tmp_path_factory.mktemp('site')
    cfg = flight_config(size=4.0, obstacles=0, grass_density=0.0)
    simulate_flight(cfg, d / 'site.mcap', threads=1)
    return d / 'site.mcap'


def _box_on_ground(bag, x, y, sink=0.025):
    g = ground_height(read_flight(bag).points, x, y, 0.5)
    return Obstacle(BOX, x, y, g - sink, 0.0)


def _pose_origins(path):
    """The pose of each cloud's stamp (the simulator writes one at every cloud's stamp)."""
    with RawBag(path) as src:
        out = {}
        for m in src.messages(['/lidar/pose']):
            msg = src.deserialize(m)
            p = msg.pose.position
            out[stamp_to_ns(msg.header.stamp)] = np.array([p.x, p.y, p.z])
        return out


def test_obstacle_where_no_ray_passes_changes_no_byte(site, tmp_path):
    far = Obstacle(BOX, 500.5, 500.5, 0.0, 0.3)
    res = insert_obstacles(site, tmp_path / 'out.mcap', obstacles=[far])
    assert res.altered == 0 and res.altered_clouds == 0 and res.clouds > 50
    topics_in, msgs_in = raw_messages(site)
    topics_out, msgs_out = raw_messages(tmp_path / 'out.mcap')
    assert topics_in == topics_out
    assert msgs_in == msgs_out
    doc = json.loads((tmp_path / 'out.labels.json').read_text())
    assert doc['obstacles'][-1]['inserted'] is True
    unsafe = [(t['x'], t['y']) for t in doc['tiles'] if not t['safe']]
    assert unsafe == [(500.5, 500.5)]


@pytest.mark.parametrize('sigma', [0.0, 0.025])
def test_box_on_open_ground_is_exact_and_minimal(site, tmp_path, sigma):
    box = _box_on_ground(site, 0.3, 0.2)
    res = insert_obstacles(site, tmp_path / 'out.mcap', obstacles=[box], range_sigma=sigma,
                           seed=3)
    v = box.vertices()
    lo, hi = v.min(axis=0), v.max(axis=0)
    origins = _pose_origins(site)
    _, msgs_in = raw_messages(site)
    _, msgs_out = raw_messages(tmp_path / 'out.mcap')
    # every pose and every other message: the same bytes, the same log times
    assert [m[:2] for m in msgs_in] == [m[:2] for m in msgs_out]
    for a, b in zip(msgs_in, msgs_out):
        if a[0] != '/lidar/points':
            assert a == b
    altered = expected = 0
    clouds_in, clouds_out = decode(site), decode(tmp_path / 'out.mcap')
    for (stamp, a), (_, b) in zip(clouds_in, clouds_out):
        pa = np.column_stack([a['x'], a['y'], a['z']]).astype(np.float64)
        pb = np.column_stack([b['x'], b['y'], b['z']]).astype(np.float64)
        changed = np.any(pa != pb, axis=1)
        hit = slab_hits(origins[stamp], pa, lo, hi)
        expected += int(hit.sum())
        altered += int(changed.sum())
        np.testing.assert_array_equal(changed, hit)
        # unchanged returns: every byte of the point; altered ones keep intensity
        assert a[~changed].tobytes() == b[~changed].tobytes()
        np.testing.assert_array_equal(a['intensity'], b['intensity'])
        assert np.all(b['label'][changed] == 2)
        if changed.any():
            dist = box_distance(pb[changed], lo, hi)
            tol = 1e-4 if sigma == 0 else 4 * sigma
            assert np.abs(dist).max() < tol
            # the moved return lies on its own ray, nearer than before
            o = origins[stamp]
            da = pa[changed] - o
            db = pb[changed] - o
            cos = np.sum(da * db, axis=1) / np.linalg.norm(da, axis=1) / np.linalg.norm(db,
                                                                                        axis=1)
            assert cos.min() > 1 - 1e-9
        if sigma == 0:
            assert not np.any(box_distance(pb, lo, hi) < -1e-4), 'a return ends inside the box'
    assert altered == expected == res.altered
    assert altered > 30  # the box was seen from above and the side
    # the messages of the altered clouds differ only in their data bytes of x, y, z, label
    for a, b in zip(msgs_in, msgs_out):
        if a[2] != b[2]:
            diff = np.flatnonzero(np.frombuffer(a[2], np.uint8) != np.frombuffer(b[2], np.uint8))
            assert len(a[2]) == len(b[2]) and diff.min() > 64  # header, fields untouched


def test_same_seed_same_bytes(site, tmp_path):
    kw = dict(count=2, seed=5, region=(-1.5, -1.5, 1.5, 1.5))
    insert_obstacles(site, tmp_path / 'a.mcap', **kw)
    insert_obstacles(site, tmp_path / 'b.mcap', **kw)
    insert_obstacles(site, tmp_path / 'c.mcap', **{**kw, 'seed': 6})
    a, b, c = (raw_messages(tmp_path / f'{n}.mcap')[1] for n in 'abc')
    assert a == b and a != c
    la, lb = ((tmp_path / f'{n}.labels.json').read_text() for n in 'ab')
    assert la == lb
    doc = json.loads(la)
    inserted = [o for o in doc['obstacles'] if o.get('inserted')]
    assert len(inserted) == 2
    assert all(o['model'] in ('rock_08', 'rock_09', 'rock_10', 'rock_11', 'tire_b')
               for o in inserted)  # rock, tire of the test group
    assert sum(not t['safe'] for t in doc['tiles']) >= 2


def test_interpolated_poses_in_a_db3_bag(tmp_path):
    """Clouds between poses (test_replay's flight, SQLite storage, no label field): the origin
    is the pose interpolated at the cloud's stamp."""
    bag = tmp_path / 'flight'
    write_flight(bag, seconds=2.0, storage='sqlite3')
    box = Obstacle(BOX, -1.6, -1.2, -0.02, 0.4)
    res = insert_obstacles(bag, tmp_path / 'out.mcap', obstacles=[box], range_sigma=0.0,
                           region=(-3, -3, 3, 3))
    scene = ObstacleScene([box])
    t0 = None
    total = 0
    for (stamp, a), (_, b) in zip(decode(bag), decode(tmp_path / 'out.mcap')):
        t0 = stamp if t0 is None else t0
        pa = np.column_stack([a['x'], a['y'], a['z']]).astype(np.float64)
        pb = np.column_stack([b['x'], b['y'], b['z']]).astype(np.float64)
        from test_replay import T0
        origin = sensor_at((stamp - T0) / 1e9)
        ref, mask = alter_returns(pa, origin, scene, range_sigma=0.0)
        np.testing.assert_allclose(pb, ref.astype(np.float32), atol=1e-6)
        total += int(mask.sum())
    assert total == res.altered > 0
    doc = json.loads((tmp_path / 'out.labels.json').read_text())
    assert [o['model'] for o in doc['obstacles']] == ['box']  # no labels: covered tiles safe
    assert any(t['safe'] for t in doc['tiles'])


def _to_ros1(src, dst):
    """The same flight as a ROS 1 bag (headers with a seq)."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    from landing_zone.io.bags import read_messages
    ros1 = get_typestore(Stores.ROS1_NOETIC)
    t = ros1.types
    with Writer(dst) as writer:
        conns = {}
        for m in read_messages(src):
            if m.topic not in conns:
                conns[m.topic] = writer.add_connection(m.topic, m.msgtype, typestore=ros1)
            h = m.msg.header
            header = t['std_msgs/msg/Header'](seq=1, stamp=t['builtin_interfaces/msg/Time'](
                sec=h.stamp.sec, nanosec=h.stamp.nanosec), frame_id=h.frame_id)
            if m.topic == '/lidar/points':
                c = m.msg
                msg = t[m.msgtype](header=header, height=c.height, width=c.width, fields=[
                    t['sensor_msgs/msg/PointField'](name=f.name, offset=f.offset,
                                                    datatype=f.datatype, count=f.count)
                    for f in c.fields], is_bigendian=c.is_bigendian, point_step=c.point_step,
                    row_step=c.row_step, data=c.data, is_dense=c.is_dense)
            else:
                p, o = m.msg.pose.position, m.msg.pose.orientation
                msg = t[m.msgtype](header=header, pose=t['geometry_msgs/msg/Pose'](
                    position=t['geometry_msgs/msg/Point'](x=p.x, y=p.y, z=p.z),
                    orientation=t['geometry_msgs/msg/Quaternion'](x=o.x, y=o.y, z=o.z, w=o.w)))
            writer.write(conns[m.topic], m.stamp_ns, ros1.serialize_ros1(msg, m.msgtype))


def test_ros1_bag_in_ros2_mcap_out(tmp_path):
    write_flight(tmp_path / 'f.mcap', seconds=1.0)
    _to_ros1(tmp_path / 'f.mcap', tmp_path / 'f.bag')
    box = Obstacle(BOX, -1.6, -1.2, -0.02, 0.4)
    for name in ('f.mcap', 'f.bag'):
        insert_obstacles(tmp_path / name, tmp_path / f'out_{name}.mcap', obstacles=[box],
                         seed=2, region=(-3, -3, 3, 3))
    a = decode(tmp_path / 'out_f.mcap.mcap')
    b = decode(tmp_path / 'out_f.bag.mcap')
    assert len(a) == len(b) > 0
    for (sa, pa), (sb, pb) in zip(a, b):
        assert sa == sb and pa.tobytes() == pb.tobytes()
    assert any(not np.array_equal(p, q) for (_, p), (_, q) in zip(a, decode(tmp_path / 'f.mcap')))


def test_alter_returns_arrays_match_the_slab_test(rng):
    lo, hi = np.array([0.9, -0.1, 0.0]), np.array([1.1, 0.1, 0.2])
    box = Obstacle(BOX, 1.0, 0.0, 0.0, 0.0)
    v = box.vertices()
    np.testing.assert_allclose([v.min(axis=0), v.max(axis=0)],
                               [[0.925, -0.075, 0.0], [1.075, 0.075, 0.15]])
    lo, hi = v.min(axis=0), v.max(axis=0)
    origins = np.array([0.0, 0.0, 5.0]) + rng.normal(0, 0.1, (20000, 3))
    points = np.column_stack([rng.uniform(0.5, 1.5, 20000), rng.uniform(-0.5, 0.5, 20000),
                              np.zeros(20000)])
    out, mask = alter_returns(points, origins, [box], range_sigma=0.0)
    hit = slab_hits(origins, points, lo, hi)
    np.testing.assert_array_equal(mask, hit)
    np.testing.assert_array_equal(out[~mask], points[~mask])
    assert np.abs(box_distance(out[mask], lo, hi)).max() < 1e-5
    assert segments_meet_boxes(origins, points, np.array([[lo, hi]]))[mask].all()
    # noise: seeded, along the ray, same rays altered
    a, ma = alter_returns(points, origins, [box], np.random.default_rng(1), 0.025)
    b, _ = alter_returns(points, origins, [box], np.random.default_rng(1), 0.025)
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(ma, mask)
    assert 0.01 < np.std(box_distance(a[mask], lo, hi)) < 0.04


def test_ground_height_under_grass():
    rng = np.random.default_rng(0)
    n = 20000
    xy = rng.uniform(-0.6, 0.6, (n, 2))
    ground = 0.3 + 0.02 * xy[:, 0]
    z = ground + rng.normal(0, 0.02, n)
    grass = rng.random(n) < 0.7  # most returns from blades up to 25 cm
    z[grass] = ground[grass] + rng.uniform(0.0, 0.25, grass.sum())
    g = ground_height(np.column_stack([xy, z]), 0.0, 0.0, 0.5)
    assert abs(g - 0.3) < 0.015
    assert ground_height(np.zeros((0, 3)), 0.0, 0.0, 0.5) is None


# --- bad input: one line, exit 2, nothing written -----------------------------------------------

def _run(capsys, *args):
    with pytest.raises(SystemExit) as exc:
        cli.main(['insert-obstacles', *map(str, args)])
    err = capsys.readouterr().err
    return exc.value.code, err.strip().splitlines()


def _points_only_bag(path, with_pose_topic=False):
    types = MessageTypes.rosbags()
    with BagWriter(path) as bag:
        bag.add_topic('/lidar/points', 'sensor_msgs/msg/PointCloud2')
        if with_pose_topic:
            bag.add_topic('/lidar/pose', 'geometry_msgs/msg/PoseStamped')
        xyz = np.random.default_rng(0).uniform(-2, 2, (100, 3)).astype(np.float32)
        bag.write('/lidar/points', 10, make_cloud(points_to_structured(xyz),
                                                  make_header(10, 'map', types), types))


@pytest.mark.parametrize('case', ['no_pose_topic', 'no_poses', 'region_outside', 'bad_kind',
                                  'too_many', 'bad_group', 'no_region'])
def test_bad_input_is_one_line_and_writes_nothing(site, tmp_path, capsys, case):
    out = tmp_path / 'out.mcap'
    bag = site
    args: list = ['--region', -1, -1, 1, 1]
    if case == 'no_pose_topic':
        bag = tmp_path / 'points.mcap'
        _points_only_bag(bag)
        want = 'lacks topic /lidar/pose'
    elif case == 'no_poses':
        bag = tmp_path / 'points.mcap'
        _points_only_bag(bag, with_pose_topic=True)
        want = 'no pose'
    elif case == 'region_outside':
        args = ['--region', 40, 40, 50, 50]
        want = 'holds no returns'
    elif case == 'bad_kind':
        args += ['--kinds', 'rock,piano']
        want = "unknown obstacle kind 'piano'"
    elif case == 'too_many':
        args += ['--count', 400]
        want = 'do not fit'
    elif case == 'bad_group':
        args += ['--group', 'val']
        want = 'group'
    else:
        bag = tmp_path / 'copy.mcap'
        bag.write_bytes(site.read_bytes())  # no labels beside it
        args = []
        want = 'give a region'
    before = set(tmp_path.iterdir())
    code, lines = _run(capsys, bag, '--out', out, *args)
    assert code == 2
    assert len(lines) == 1 and lines[0].startswith('landing-zone: error: ') and want in lines[0]
    assert set(tmp_path.iterdir()) == before  # no bag, no labels, no temporary left


def test_cli_end_to_end(site, tmp_path):
    out = tmp_path / 'h.mcap'
    r = subprocess.run([sys.executable, '-m', 'landing_zone', 'insert-obstacles', str(site),
                        '--out', str(out), '--count', '2', '--kinds', 'box', '--seed', '1'],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert 'inserted 2 obstacle(s)' in r.stdout and out.exists()
    doc = json.loads(out.with_name('h.labels.json').read_text())
    assert sum(1 for o in doc['obstacles'] if o.get('inserted')) == 2
    r = subprocess.run([sys.executable, '-m', 'landing_zone', 'insert-obstacles', str(site),
                        '--out', str(out)], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2 and 'Traceback' not in r.stderr
    assert r.stderr.strip().splitlines() == [
        f'landing-zone: error: {out} exists already (use --overwrite)']
