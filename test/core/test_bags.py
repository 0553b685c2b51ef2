"""Bag I/O round trips: PointCloud2 + PoseStamped written with BagWriter (single .mcap file, MCAP
and SQLite3 bag directories) and read back in log-time order with equal bytes and values; a ROS 1
.bag written with rosbags' rosbag1 writer; an .mcap written by the mcap package without index;
and every failure (missing, not a bag, truncated, corrupt, absent topics, bad writes) as a
one-line BagError."""
from __future__ import annotations

import numpy as np
import pytest

from landing_zone.io.bags import BagMessage, BagWriter, bag_topics, read_messages
from landing_zone.errors import BagError
from msg_adapters import MessageTypes, make_header, stamp_to_ns
from msg_adapters import jazzy_typestore as typestore
from msg_adapters.pointcloud import cloud_to_structured, cloud_to_xyz, make_cloud
from msg_adapters.pointcloud import points_to_structured
from msg_adapters.pose import make_pose_stamped, pose_stamped_to_arrays

CLOUD = 'sensor_msgs/msg/PointCloud2'
POSE = 'geometry_msgs/msg/PoseStamped'
T0 = 1_700_000_000_000_000_000


def _flight(seed=0, n_clouds=4, n_poses=9):
    """Messages of a short flight: (topic, stamp_ns, msg), clouds at 5 Hz, poses at 20 Hz."""
    rng = np.random.default_rng(seed)
    types = MessageTypes.rosbags()
    out = []
    for i in range(n_clouds):
        stamp = T0 + i * 200_000_000
        xyz = rng.normal(size=(50 + i, 3)) * 5
        xyz[::10, 2] = np.nan
        arr = points_to_structured(xyz, {'intensity': rng.random(len(xyz)).astype(np.float32)})
        out.append(('/lidar/points', stamp, make_cloud(arr, make_header(stamp, 'map', types),
                                                       types)))
    for i in range(n_poses):
        stamp = T0 + i * 50_000_000 + 1_000  # no ties with clouds: their order is unspecified
        out.append(('/lidar/pose', stamp, make_pose_stamped(
            stamp, 'map', [i, 2 * i, 30.0], rng.normal(size=4), types)))
    return out


def _write(path, messages, **kw):
    with BagWriter(path, **kw) as bag:
        bag.add_topic('/lidar/points', CLOUD)
        bag.add_topic('/lidar/pose', POSE)
        for topic, stamp, msg in reversed(messages):  # written out of order on purpose
            bag.write(topic, stamp, msg)


def _assert_read_back(got, written):
    want = sorted(written, key=lambda m: m[1])
    assert [(m.topic, m.stamp_ns) for m in got] == [(t, s) for t, s, _ in want]
    assert all(isinstance(m, BagMessage) for m in got)
    for message, (topic, stamp, msg) in zip(got, want):
        if topic == '/lidar/points':
            assert message.msgtype == CLOUD
            assert bytes(message.msg.data) == bytes(msg.data)
            assert stamp_to_ns(message.msg.header.stamp) == stamp
            for name in ('x', 'y', 'z', 'intensity'):
                np.testing.assert_array_equal(cloud_to_structured(message.msg)[name],
                                              cloud_to_structured(msg)[name])
            assert cloud_to_xyz(message.msg)[1] == cloud_to_xyz(msg)[1]
        else:
            assert message.msgtype == POSE
            for a, b in zip(pose_stamped_to_arrays(message.msg), pose_stamped_to_arrays(msg)):
                np.testing.assert_array_equal(a, b)


def test_single_mcap_file_round_trip(tmp_path):
    flight = _flight()
    path = tmp_path / 'site.mcap'
    _write(path, flight)
    assert path.is_file() and [p.name for p in tmp_path.iterdir()] == ['site.mcap']
    assert bag_topics(path) == {'/lidar/points': CLOUD, '/lidar/pose': POSE}
    _assert_read_back(list(read_messages(path)), flight)
    clouds = list(read_messages(path, topics=['/lidar/points']))
    assert len(clouds) == 4 and {m.topic for m in clouds} == {'/lidar/points'}


@pytest.mark.parametrize('storage', ['mcap', 'sqlite3'])
def test_bag_directory_round_trip(tmp_path, storage):
    flight = _flight(seed=1)
    path = tmp_path / 'flight'
    _write(path, flight, storage=storage)
    suffix = '.mcap' if storage == 'mcap' else '.db3'
    assert (path / 'metadata.yaml').is_file() and (path / f'flight{suffix}').is_file()
    _assert_read_back(list(read_messages(path)), flight)
    assert bag_topics(path) == {'/lidar/points': CLOUD, '/lidar/pose': POSE}
    # The storage file alone names the bag too.
    poses = list(read_messages(path / f'flight{suffix}', topics='/lidar/pose'))
    assert [m.stamp_ns for m in poses] == [T0 + i * 50_000_000 + 1_000 for i in range(9)]


def test_ros1_bag(tmp_path):
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore
    ros1 = get_typestore(Stores.ROS1_NOETIC)
    Header = ros1.types['std_msgs/msg/Header']
    Time = ros1.types['builtin_interfaces/msg/Time']
    flight = _flight(seed=2)
    path = tmp_path / 'old.bag'
    with Writer(path) as writer:
        connections = {topic: writer.add_connection(topic, msgtype, typestore=ros1)
                       for topic, msgtype in (('/lidar/points', CLOUD), ('/lidar/pose', POSE))}
        for topic, stamp, msg in sorted(flight, key=lambda m: m[1]):
            # The same content in ROS 1 types: headers carry a seq.
            sec, nanosec = divmod(stamp, 1_000_000_000)
            header = Header(seq=7, stamp=Time(sec=sec, nanosec=nanosec), frame_id='map')
            msgtype = CLOUD if topic == '/lidar/points' else POSE
            fields = {k: getattr(msg, k) for k in msg.__dataclass_fields__ if k != 'header'}
            if msgtype == CLOUD:
                fields['fields'] = [ros1.types['sensor_msgs/msg/PointField'](
                    name=f.name, offset=f.offset, datatype=f.datatype, count=f.count)
                    for f in msg.fields]
            else:
                p, o = msg.pose.position, msg.pose.orientation
                fields['pose'] = ros1.types['geometry_msgs/msg/Pose'](
                    position=ros1.types['geometry_msgs/msg/Point'](x=p.x, y=p.y, z=p.z),
                    orientation=ros1.types['geometry_msgs/msg/Quaternion'](
                        x=o.x, y=o.y, z=o.z, w=o.w))
            ros1_msg = ros1.types[msgtype](header=header, **fields)
            writer.write(connections[topic], stamp, ros1.serialize_ros1(ros1_msg, msgtype))
    assert bag_topics(path) == {'/lidar/points': CLOUD, '/lidar/pose': POSE}
    got = list(read_messages(path))
    assert got[0].msg.header.seq == 7
    _assert_read_back(got, flight)


def test_unindexed_mcap_from_the_mcap_package(tmp_path):
    # A minimal ROS 2 profile file, no chunks and no summary: read by a linear scan.
    from mcap.writer import Writer
    store = typestore()
    flight = _flight(seed=3, n_clouds=2, n_poses=3)
    path = tmp_path / 'plain.mcap'
    with path.open('wb') as f:
        writer = Writer(f, use_chunking=False, use_summary_offsets=False)
        writer.start(profile='ros2', library='test')
        channels = {}
        for topic, msgtype in (('/lidar/points', CLOUD), ('/lidar/pose', POSE)):
            schema = writer.register_schema(name=msgtype, encoding='ros2msg',
                                            data=store.generate_msgdef(msgtype)[0].encode())
            channels[topic] = writer.register_channel(topic=topic, message_encoding='cdr',
                                                      schema_id=schema)
        # as a recorder writes them: in log-time order (rosbags reads an unindexed file so)
        for topic, stamp, msg in sorted(flight, key=lambda m: m[1]):
            writer.add_message(channel_id=channels[topic], log_time=stamp, publish_time=stamp,
                               data=bytes(store.serialize_cdr(msg, msg.__msgtype__)))
        writer.finish()
    assert bag_topics(path) == {'/lidar/points': CLOUD, '/lidar/pose': POSE}
    _assert_read_back(list(read_messages(path)), flight)
    # out of log-time order, an unindexed file cannot be read in order: a one-line BagError
    shuffled = tmp_path / 'shuffled.mcap'
    with shuffled.open('wb') as f:
        writer = Writer(f, use_chunking=False, use_summary_offsets=False)
        writer.start(profile='ros2', library='test')
        channels = {}
        for topic, msgtype in (('/lidar/points', CLOUD), ('/lidar/pose', POSE)):
            schema = writer.register_schema(name=msgtype, encoding='ros2msg',
                                            data=store.generate_msgdef(msgtype)[0].encode())
            channels[topic] = writer.register_channel(topic=topic, message_encoding='cdr',
                                                      schema_id=schema)
        for topic, stamp, msg in flight:  # the clouds, then the poses
            writer.add_message(channel_id=channels[topic], log_time=stamp, publish_time=stamp,
                               data=bytes(store.serialize_cdr(msg, msg.__msgtype__)))
        writer.finish()
    with pytest.raises(BagError, match='shuffled.mcap.*not in timestamp order') as err:
        list(read_messages(shuffled))
    assert '\n' not in str(err.value)


def test_overwrite(tmp_path):
    path = tmp_path / 'site.mcap'
    _write(path, _flight(seed=4, n_clouds=1, n_poses=1))
    with pytest.raises(BagError, match='exists already'):
        _write(path, _flight())
    flight = _flight(seed=5, n_clouds=2, n_poses=2)
    _write(path, flight, overwrite=True)
    _assert_read_back(list(read_messages(path)), flight)
    assert [p.name for p in tmp_path.iterdir()] == ['site.mcap']


def test_failed_write_leaves_nothing(tmp_path):
    for name in ('site.mcap', 'flight'):
        with pytest.raises(RuntimeError):
            with BagWriter(tmp_path / name) as bag:
                bag.add_topic('/lidar/pose', POSE)
                bag.write('/lidar/pose', 1, _flight(n_clouds=0, n_poses=1)[0][2])
                raise RuntimeError('simulated crash')
    assert list(tmp_path.iterdir()) == []


def test_writer_errors(tmp_path):
    pose = _flight(n_clouds=0, n_poses=1)[0][2]
    with BagWriter(tmp_path / 'a.mcap') as bag:
        bag.add_topic('/lidar/pose', POSE)
        with pytest.raises(BagError, match='added twice'):
            bag.add_topic('/lidar/pose', POSE)
        with pytest.raises(BagError, match='unknown to the typestore'):
            bag.add_topic('/x', 'nope_msgs/msg/Nothing')
        with pytest.raises(BagError, match='was not added'):
            bag.write('/other', 1, pose)
        bag.add_topic('/lidar/points', CLOUD)
        with pytest.raises(BagError, match='carries sensor_msgs/msg/PointCloud2, got a geometry'):
            bag.write('/lidar/points', 1, pose)
        pose.header.stamp.sec = 2**40  # out of int32: serialization fails
        with pytest.raises(BagError, match='cannot write a geometry_msgs/msg/PoseStamped'):
            bag.write('/lidar/pose', 1, pose)
    with pytest.raises(BagError, match="storage must be 'mcap' or 'sqlite3'"):
        BagWriter(tmp_path / 'b', storage='rosbag1')
    with pytest.raises(BagError, match='needs storage mcap'):
        BagWriter(tmp_path / 'b.mcap', storage='sqlite3')
    with pytest.raises(BagError, match='is not a directory'):
        BagWriter(tmp_path / 'missing' / 'b.mcap').open()
    with pytest.raises(BagError, match='is not open'):
        BagWriter(tmp_path / 'c.mcap').add_topic('/a', POSE)


def test_read_errors(tmp_path):
    with pytest.raises(BagError, match='bag not found'):
        list(read_messages(tmp_path / 'none.mcap'))
    (tmp_path / 'dir').mkdir()
    with pytest.raises(BagError, match='without metadata.yaml'):
        bag_topics(tmp_path / 'dir')
    (tmp_path / 'notes.txt').write_text('hello')
    with pytest.raises(BagError, match='is not a bag'):
        list(read_messages(tmp_path / 'notes.txt'))
    (tmp_path / 'fake.mcap').write_text('hello, not an mcap file at all')
    with pytest.raises(BagError, match='fake.mcap'):
        list(read_messages(tmp_path / 'fake.mcap'))
    (tmp_path / 'fake.bag').write_bytes(b'#ROSBAG V2.0\n' + bytes(100))
    with pytest.raises(BagError, match='fake.bag'):
        list(read_messages(tmp_path / 'fake.bag'))
    (tmp_path / 'lone.db3').write_bytes(b'')
    with pytest.raises(BagError, match='without the metadata.yaml'):
        list(read_messages(tmp_path / 'lone.db3'))
    path = tmp_path / 'ok.mcap'
    _write(path, _flight(n_clouds=1, n_poses=1))
    with pytest.raises(BagError, match=r'lacks topic\(s\) /cam, /imu .*has /lidar/points'):
        list(read_messages(path, topics=['/imu', '/lidar/pose', '/cam']))
    bagdir = tmp_path / 'bagdir'
    _write(bagdir, _flight(n_clouds=1, n_poses=1))
    with pytest.raises(BagError, match=r'lacks topic\(s\) /imu'):
        list(read_messages(bagdir, topics=['/imu']))


@pytest.mark.parametrize('name', ['site.mcap', 'flight', 'flight.db3', 'old.bag'])
def test_truncated_and_corrupt_bags_raise_bag_error(tmp_path, name):
    """Cut or overwrite bytes anywhere: reading gives messages or a BagError, nothing else."""
    src = tmp_path / 'src'
    src.mkdir()
    flight = _flight(seed=6, n_clouds=3, n_poses=3)
    if name == 'old.bag':
        from rosbags.rosbag1 import Writer
        from rosbags.typesys import Stores, get_typestore
        ros1 = get_typestore(Stores.ROS1_NOETIC)
        target = src / name
        with Writer(target) as writer:
            conn = writer.add_connection('/c', 'std_msgs/msg/String', typestore=ros1)
            for i in range(20):
                msg = ros1.types['std_msgs/msg/String'](data=f'message {i}' * 20)
                writer.write(conn, T0 + i, ros1.serialize_ros1(msg, 'std_msgs/msg/String'))
    else:
        bag = src / name.replace('.db3', '')
        _write(bag, flight, storage='sqlite3' if name.endswith('.db3') else 'mcap')
        target = src / name if name == 'site.mcap' else bag / f'flight{bag.suffix}'
        target = bag / 'flight.db3' if name.endswith('.db3') else target
        target = bag / 'flight.mcap' if name == 'flight' else target
    original = target.read_bytes()
    rng = np.random.default_rng(0)
    outcomes = {'error': 0, 'read': 0}
    for trial in range(24):
        data = bytearray(original)
        if trial < 8:
            data = data[:int(len(data) * (trial + 1) / 9)]
        else:
            start = int(rng.integers(0, len(data) - 64))
            data[start:start + 64] = rng.integers(0, 256, 64, dtype=np.uint8).tobytes()
        target.write_bytes(bytes(data))
        read_path = target if name in ('site.mcap', 'old.bag') else target.parent
        try:
            bag_topics(read_path)
            for _ in read_messages(read_path):
                pass
            outcomes['read'] += 1
        except BagError as err:
            assert '\n' not in str(err)
            outcomes['error'] += 1
    assert outcomes['error'] >= 8  # every truncation at least is noticed
