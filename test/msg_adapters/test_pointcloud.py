"""PointCloud2 <-> numpy: the cases of ros2/common_interfaces sensor_msgs_py's
test_point_cloud2.py (NaNs, organized clouds, mixed dtypes, count > 1, padded point_step, byte
order), empty clouds, every malformed-cloud check, round trips through rclpy and rosbags messages
(and through CDR), and a fuzz test that corrupt clouds raise InvalidCloudError and nothing else.
"""
from __future__ import annotations

import array
import sys
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from msg_adapters import jazzy_typestore as typestore
from landing_zone.errors import InvalidCloudError
from msg_adapters import MessageTypes, make_header
from msg_adapters.pointcloud import (
    DATATYPES,
    cloud_dtype,
    cloud_to_structured,
    cloud_to_xyz,
    make_cloud,
    points_to_structured,
    structured_to_cloud_fields,
)

# The reference test's points: one NaN in point 4.
PYLIST = [(0.0, 0.1, 0.2), (1.0, 1.1, 1.2), (2.0, 2.1, 2.2),
          (3.0, 3.1, 3.2), (4.0, np.nan, 4.2), (5.0, 5.1, 5.2)]
POINTS = np.array(PYLIST, dtype=np.float32)
XYZ_FIELDS = [('x', 0, 7, 1), ('y', 4, 7, 1), ('z', 8, 7, 1)]


def field(name, offset, datatype, count=1):
    return SimpleNamespace(name=name, offset=offset, datatype=datatype, count=count)


def cloud(fields, data, width, height=1, point_step=None, row_step=None, bigendian=None):
    """A message-shaped object: the adapters read attributes only."""
    point_step = point_step if point_step is not None else len(data) // max(width * height, 1)
    return SimpleNamespace(
        header=None, height=height, width=width, fields=[field(*f) for f in fields],
        is_bigendian=(sys.byteorder == 'big') if bigendian is None else bigendian,
        point_step=point_step,
        row_step=row_step if row_step is not None else point_step * width,
        data=data, is_dense=False)


def xyz_cloud(points=POINTS, **kw):
    return cloud(XYZ_FIELDS, bytearray(np.ascontiguousarray(points, '=f4').tobytes()),
                 width=len(points), point_step=12, **kw)


# --- decoding (sensor_msgs_py test cases) ----------------------------------------------------

def test_xyz_drops_nans_and_counts_them():
    xyz, dropped = cloud_to_xyz(xyz_cloud())
    assert dropped == 1
    assert xyz.dtype == np.float64 and xyz.flags.c_contiguous
    np.testing.assert_array_equal(xyz, POINTS[[0, 1, 2, 3, 5]].astype(np.float64))


def test_structured_keeps_nans():
    arr = cloud_to_structured(xyz_cloud())
    assert arr.dtype.names == ('x', 'y', 'z') and arr.shape == (6,)
    got = np.stack([arr['x'], arr['y'], arr['z']], axis=1)
    np.testing.assert_array_equal(got, POINTS)  # NaN positions compare equal here


@pytest.mark.parametrize('value', [np.inf, -np.inf, np.nan])
def test_xyz_drops_every_nonfinite(value):
    points = POINTS.copy()
    points[4] = (1.0, 2.0, 3.0)
    points[0, 2] = value
    points[3, 0] = value
    xyz, dropped = cloud_to_xyz(xyz_cloud(points))
    assert dropped == 2
    np.testing.assert_array_equal(xyz, points[[1, 2, 4, 5]])


def test_organized_cloud_row_major_and_shape():
    points = np.arange(2 * 3 * 3, dtype=np.float32).reshape(2, 3, 3)  # height 2, width 3
    msg = xyz_cloud(points.reshape(-1, 3), height=2)
    msg.width = 3
    msg.row_step = 36
    xyz, dropped = cloud_to_xyz(msg)
    assert dropped == 0
    np.testing.assert_array_equal(xyz, points.reshape(-1, 3))
    organized = cloud_to_structured(msg, organized=True)
    assert organized.shape == (2, 3)
    np.testing.assert_array_equal(organized['z'], points[..., 2])


def test_organized_cloud_with_row_padding():
    # row_step > width * point_step: 5 padding bytes (0xAB) end every row.
    points = np.arange(2 * 3 * 3, dtype=np.float32).reshape(2, 3, 3) + 0.5
    rows = [points[r].tobytes() + b'\xab' * 5 for r in range(2)]
    msg = cloud(XYZ_FIELDS, b''.join(rows), width=3, height=2, point_step=12, row_step=41)
    xyz, _ = cloud_to_xyz(msg)
    np.testing.assert_array_equal(xyz, points.reshape(-1, 3))
    np.testing.assert_array_equal(cloud_to_structured(msg)['y'], points[..., 1].reshape(-1))


def test_mixed_datatypes():
    struct = np.array(list(map(tuple, POINTS)), dtype=[('a', np.float32), ('b', np.float64),
                                                       ('c', np.uint8)])
    fields = [('a', 0, 7, 1), ('b', 4, 8, 1), ('c', 12, 2, 1)]
    msg = cloud(fields, bytearray(struct.tobytes()), width=6, point_step=struct.itemsize)
    arr = cloud_to_structured(msg)
    assert arr.dtype == struct.dtype  # packed, 13 bytes
    for name in struct.dtype.names:
        np.testing.assert_array_equal(arr[name], struct[name])


def test_every_datatype_decodes():
    rng = np.random.default_rng(3)
    fields, offset, columns = [], 0, {}
    for datatype, (_, code) in DATATYPES.items():
        dt = np.dtype('<' + code)
        values = (rng.normal(size=5) * 50).astype(dt) if dt.kind == 'f' else \
            rng.integers(np.iinfo(dt).min, np.iinfo(dt).max, size=5, endpoint=True, dtype=dt)
        name = f'f{datatype}'
        fields.append((name, offset, datatype, 1))
        columns[name] = (offset, values)
        offset += dt.itemsize
    data = bytearray(5 * offset)
    buf = np.frombuffer(data, np.uint8).reshape(5, offset)
    for name, (off, values) in columns.items():
        buf[:, off:off + values.itemsize] = values.view(np.uint8).reshape(5, -1)
    arr = cloud_to_structured(cloud(fields, data, width=5, bigendian=False))
    for name, (_, values) in columns.items():
        assert arr[name].dtype == values.dtype.newbyteorder('=')
        np.testing.assert_array_equal(arr[name], values)


def test_count_greater_than_one():
    # sensor_msgs_py reads a count-3 field 'x' as x_0, x_1, x_2: here it is one (N, 3) subarray.
    msg = cloud([('x', 0, 7, 3)], bytearray(POINTS.tobytes()), width=6, point_step=12)
    arr = cloud_to_structured(msg)
    assert arr.dtype.names == ('x',) and arr['x'].shape == (6, 3)
    np.testing.assert_array_equal(arr['x'], POINTS)
    with pytest.raises(InvalidCloudError, match='lacks field.*y, z'):
        cloud_to_xyz(msg)


def test_count_greater_than_one_beside_xyz():
    dt = np.dtype([('x', '<f4'), ('y', '<f4'), ('z', '<f4'), ('rgb', 'u1', (3,))])
    src = np.zeros(4, dt)
    src['x'], src['rgb'] = [1, 2, 3, 4], [[1, 2, 3], [4, 5, 6], [7, 8, 9], [10, 11, 12]]
    msg = cloud(XYZ_FIELDS + [('rgb', 12, 2, 3)], src.tobytes(), width=4, point_step=15,
                bigendian=False)
    np.testing.assert_array_equal(cloud_to_structured(msg)['rgb'], src['rgb'])
    np.testing.assert_array_equal(cloud_to_xyz(msg)[0][:, 0], [1, 2, 3, 4])


def test_xyz_with_count_greater_than_one_rejected():
    msg = cloud([('x', 0, 7, 2), ('y', 8, 7, 1), ('z', 12, 7, 1)], bytes(32), width=2)
    with pytest.raises(InvalidCloudError, match="field 'x' has count 2"):
        cloud_to_xyz(msg)


@pytest.mark.parametrize('point_step', [20, 123])
def test_padded_point_step(point_step):
    padded = np.zeros(6, dtype={'names': ['x', 'y', 'z'], 'formats': ['=f4'] * 3,
                                'offsets': [0, 4, 8], 'itemsize': point_step})
    for axis, name in enumerate('xyz'):
        padded[name] = POINTS[:, axis]
    raw = bytearray(padded.tobytes())
    raw[12:point_step] = b'\x7f' * (point_step - 12)  # garbage in the padding is ignored
    msg = cloud(XYZ_FIELDS, raw, width=6, point_step=point_step)
    xyz, dropped = cloud_to_xyz(msg)
    assert dropped == 1
    np.testing.assert_array_equal(xyz, POINTS[[0, 1, 2, 3, 5]])
    arr = cloud_to_structured(msg)
    assert arr.dtype.itemsize == point_step


def test_fields_in_any_order_and_offset():
    # z first, x last, a double y in the middle, 3 bytes of padding between.
    dt = np.dtype({'names': ['z', 'y', 'x'], 'formats': ['<f4', '<f8', '<f4'],
                   'offsets': [0, 7, 18], 'itemsize': 24})
    src = np.zeros(3, dt)
    src['x'], src['y'], src['z'] = [1, 2, 3], [10, 20, 30], [-1, -2, -3]
    msg = cloud([('z', 0, 7, 1), ('y', 7, 8, 1), ('x', 18, 7, 1)], src.tobytes(), width=3,
                point_step=24, bigendian=False)
    np.testing.assert_array_equal(cloud_to_xyz(msg)[0],
                                  [[1, 10, -1], [2, 20, -2], [3, 30, -3]])


@pytest.mark.parametrize('code,datatype', [('f4', 7), ('f8', 8)])
def test_big_endian(code, datatype):
    size = np.dtype(code).itemsize
    fields = [('x', 0, datatype, 1), ('y', size, datatype, 1), ('z', 2 * size, datatype, 1),
              ('intensity', 3 * size, 4, 1)]
    dt = np.dtype({'names': ['x', 'y', 'z', 'intensity'],
                   'formats': ['>' + code] * 3 + ['>u2'],
                   'offsets': [0, size, 2 * size, 3 * size], 'itemsize': 3 * size + 2})
    src = np.zeros(6, dt)
    for axis, name in enumerate('xyz'):
        src[name] = POINTS[:, axis]
    src['intensity'] = [1, 256, 513, 65535, 7, 0]
    msg = cloud(fields, src.tobytes(), width=6, point_step=dt.itemsize, bigendian=True)
    xyz, dropped = cloud_to_xyz(msg)
    assert dropped == 1
    np.testing.assert_array_equal(xyz, POINTS[[0, 1, 2, 3, 5]])
    arr = cloud_to_structured(msg)
    assert arr.dtype['intensity'].isnative
    np.testing.assert_array_equal(arr['intensity'], [1, 256, 513, 65535, 7, 0])
    # Read as little-endian, the same bytes give other numbers: the flag matters.
    msg.is_bigendian = False
    assert not np.array_equal(cloud_to_structured(msg)['intensity'], arr['intensity'])


@pytest.mark.parametrize('width,height', [(0, 1), (0, 0), (5, 0)])
def test_empty_cloud(width, height):
    msg = cloud(XYZ_FIELDS, b'', width=width, height=height, point_step=12)
    xyz, dropped = cloud_to_xyz(msg)
    assert xyz.shape == (0, 3) and dropped == 0
    assert cloud_to_structured(msg).shape == (0,)
    assert cloud_to_structured(msg, organized=True).shape == (height, width)


@pytest.mark.parametrize('data', [
    lambda b: bytes(b), lambda b: bytearray(b), lambda b: memoryview(b),
    lambda b: array.array('B', b), lambda b: np.frombuffer(b, np.uint8).copy(),
    lambda b: list(b)])
def test_data_container_types(data):
    raw = POINTS.astype('<f4').tobytes()
    msg = cloud(XYZ_FIELDS, data(raw), width=6, point_step=12, bigendian=False)
    np.testing.assert_array_equal(cloud_to_xyz(msg)[0], POINTS[[0, 1, 2, 3, 5]])


def test_cloud_dtype():
    msg = cloud([('x', 0, 7, 1), ('y', 4, 7, 1), ('z', 8, 7, 1), ('t', 16, 8, 2)], bytes(64),
                width=2, point_step=32, bigendian=True)
    dt = cloud_dtype(msg)
    assert dt.itemsize == 32 and dt.fields['t'] == (np.dtype(('>f8', (2,))), 16)


# --- malformed clouds -------------------------------------------------------------------------

def _malformed():
    good = dict(fields=XYZ_FIELDS, data=bytes(24), width=2, point_step=12)
    cases = [
        (dict(good, data=bytes(23)), 'data has 23 bytes, expected height'),
        (dict(good, data=bytes(36)), 'data has 36 bytes'),
        (dict(good, row_step=20), 'row_step 20 is less than width'),
        (dict(good, fields=XYZ_FIELDS[:2]), r'lacks field\(s\) z'),
        (dict(good, fields=[]), 'lacks field.*no fields'),
        (dict(good, fields=XYZ_FIELDS[:2] + [('z', 8, 9, 1)]), 'unsupported datatype 9'),
        (dict(good, fields=XYZ_FIELDS[:2] + [('z', 8, 0, 1)]), 'unsupported datatype 0'),
        (dict(good, fields=XYZ_FIELDS[:2] + [('z', 10, 7, 1)]), 'ends at byte 14, beyond'),
        (dict(good, fields=XYZ_FIELDS[:2] + [('z', 8, 8, 1)]), 'ends at byte 16, beyond'),
        (dict(good, fields=XYZ_FIELDS[:2] + [('z', 8, 7, 0)]), 'count 0'),
        (dict(good, fields=XYZ_FIELDS[:2] + [('z', -4, 7, 1)]), 'negative offset'),
        (dict(good, fields=XYZ_FIELDS + [('x', 0, 7, 1)]), "'x' appears twice"),
        (dict(good, fields=XYZ_FIELDS + [('', 0, 7, 1)]), 'empty or non-string name'),
        (dict(good, fields=XYZ_FIELDS[:2] + [('z', 8, 5, 1)]), "'z' is INT32"),
        (dict(good, width=-1), 'width is negative'),
        (dict(good, data='abc'), 'not a byte buffer'),
        (dict(good, data=[0] * 23 + [256]), r'outside \[0, 255\]'),
        (dict(good, data=np.zeros(6, np.float32)), 'dtype float32, expected uint8'),
        (dict(good, width=2.0), 'width is not an integer'),
        (dict(good, bigendian=np.array([True, False])), 'is_bigendian is not a boolean'),
    ]
    return cases


@pytest.mark.parametrize('kwargs,match', _malformed())
def test_malformed_cloud_raises(kwargs, match):
    msg = cloud(**kwargs)
    with pytest.raises(InvalidCloudError, match=match):
        cloud_to_xyz(msg)


def test_missing_attribute_raises():
    msg = xyz_cloud()
    del msg.row_step
    with pytest.raises(InvalidCloudError, match="no attribute 'row_step'"):
        cloud_to_structured(msg)


# --- building messages and round trips -------------------------------------------------------

def test_points_to_structured_layout():
    arr = points_to_structured(POINTS, {'intensity': [1.5] * 6, 'ring': np.arange(6, dtype='u2'),
                                        'normal': np.ones((6, 3), np.float32)})
    assert arr.dtype.names == ('x', 'y', 'z', 'intensity', 'ring', 'normal')
    assert arr.dtype['intensity'] == np.float32 and arr.dtype['ring'] == np.uint16
    spec = structured_to_cloud_fields(arr)
    assert spec['fields'] == [('x', 0, 7, 1), ('y', 4, 7, 1), ('z', 8, 7, 1),
                              ('intensity', 12, 7, 1), ('ring', 16, 4, 1), ('normal', 18, 7, 3)]
    assert spec['point_step'] == 30 and spec['row_step'] == 180 and not spec['is_dense']
    assert spec['data'].nbytes == 180


@pytest.mark.parametrize('bad,match', [
    (dict(xyz=np.zeros((3, 2))), r'shape \(N, 3\)'),
    (dict(xyz=np.zeros((3, 3)), fields={'t': np.zeros(4)}), "field 't' has shape"),
    (dict(xyz=np.zeros((3, 3)), fields={'t': np.zeros(3, np.int64)}), 'no PointField'),
    (dict(xyz=np.zeros((3, 3)), dtype=np.int32), 'float32 or float64'),
])
def test_points_to_structured_rejects(bad, match):
    with pytest.raises(InvalidCloudError, match=match):
        points_to_structured(**bad)


def test_structured_to_cloud_fields_rejects():
    with pytest.raises(InvalidCloudError, match='structured array'):
        structured_to_cloud_fields(np.zeros((4, 3)))
    with pytest.raises(InvalidCloudError, match='1 or 2 dimensions'):
        structured_to_cloud_fields(np.zeros((1, 2, 3), [('x', 'f4')]))
    with pytest.raises(InvalidCloudError, match="'c' has dtype complex"):
        structured_to_cloud_fields(np.zeros(3, [('x', 'f4'), ('c', 'c8')]))


def test_structured_to_cloud_fields_writes_little_endian():
    big = np.zeros(2, [('x', '>f8'), ('y', '>f8'), ('z', '>f8'), ('i', '>i2')])
    big['x'], big['i'] = [1.0, -2.0], [3, -4]
    spec = structured_to_cloud_fields(big)
    assert spec['is_bigendian'] is False
    assert bytes(spec['data'][:8]) == np.float64(1.0).astype('<f8').tobytes()
    assert bytes(spec['data'][24:26]) == np.int16(3).astype('<i2').tobytes()


def _random_structured(rng, n, organized=False):
    dt = np.dtype({'names': ['x', 'y', 'z', 'intensity', 'ring', 'label', 'normal'],
                   'formats': ['<f4', '<f4', '<f4', '>f8', '<u2', 'i1', ('<f4', (3,))],
                   'offsets': [0, 4, 8, 16, 24, 27, 32], 'itemsize': 48})
    arr = np.zeros(n, dt)
    for name in ('x', 'y', 'z'):
        arr[name] = rng.normal(size=n) * 10
    arr['x'][::7] = np.nan
    arr['intensity'] = rng.random(n)
    arr['ring'] = rng.integers(0, 65536, n)
    arr['label'] = rng.integers(-128, 128, n)
    arr['normal'] = rng.normal(size=(n, 3))
    return arr.reshape(4, n // 4) if organized else arr


def _assert_same_values(got, want):
    assert got.dtype.names == want.dtype.names and got.shape == want.shape
    for name in want.dtype.names:
        np.testing.assert_array_equal(got[name], want[name])
        assert got.dtype.fields[name][1] == want.dtype.fields[name][1]


@pytest.fixture(params=['rclpy', 'rosbags'])
def types(request):
    if request.param == 'rclpy':
        pytest.importorskip('sensor_msgs.msg')
        return MessageTypes.rclpy()
    return MessageTypes.rosbags()


@pytest.mark.parametrize('organized', [False, True])
def test_round_trip_through_messages(types, organized):
    rng = np.random.default_rng(7)
    arr = _random_structured(rng, 64, organized)
    msg = make_cloud(arr, make_header(1_700_000_000_123_456_789, 'map', types), types)
    cls = types.get('sensor_msgs/msg/PointCloud2')
    assert isinstance(msg, cls)
    assert (msg.height, msg.width) == ((4, 16) if organized else (1, 64))
    assert msg.point_step == 48 and msg.is_dense is False and msg.is_bigendian is False
    assert msg.header.stamp.sec == 1_700_000_000 and msg.header.stamp.nanosec == 123_456_789
    got = cloud_to_structured(msg, organized=organized)
    _assert_same_values(got, arr)
    xyz, dropped = cloud_to_xyz(msg)
    flat = arr.reshape(-1)
    keep = np.isfinite(flat['x'])
    assert dropped == np.count_nonzero(~keep)
    np.testing.assert_array_equal(xyz, np.stack([flat[n][keep] for n in 'xyz'], axis=1))
    # A second trip gives the same bytes: the layout and the zeroed padding are reproduced.
    again = make_cloud(got, msg.header, types)
    assert bytes(again.data) == bytes(msg.data)


def test_round_trip_through_cdr():
    store = typestore()
    types = MessageTypes.rosbags(store)
    arr = _random_structured(np.random.default_rng(8), 40, organized=True)
    msg = make_cloud(arr, make_header(5, 'lidar', types), types)
    back = store.deserialize_cdr(store.serialize_cdr(msg, msg.__msgtype__), msg.__msgtype__)
    assert isinstance(back.data, np.ndarray)
    _assert_same_values(cloud_to_structured(back, organized=True), arr)


def test_make_cloud_equals_hand_built_rclpy_message():
    # test_create_cloud of sensor_msgs_py: the builder gives exactly the reference message.
    msg_mod = pytest.importorskip('sensor_msgs.msg')
    from std_msgs.msg import Header
    ref = msg_mod.PointCloud2(
        header=Header(frame_id='frame'), height=1, width=6, is_dense=False,
        is_bigendian=False,
        fields=[msg_mod.PointField(name=n, offset=4 * i, datatype=msg_mod.PointField.FLOAT32,
                                   count=1) for i, n in enumerate('xyz')],
        point_step=12, row_step=72, data=POINTS.astype('<f4').tobytes())
    built = make_cloud(points_to_structured(POINTS), Header(frame_id='frame'), 'rclpy')
    assert built == ref
    built = make_cloud(points_to_structured(POINTS), Header(frame_id='frame2'), 'rclpy')
    assert built != ref


def test_is_dense_flag():
    arr = points_to_structured(np.zeros((3, 3)), {'t': np.array([np.nan, 0, 0], np.float32)})
    assert structured_to_cloud_fields(arr)['is_dense']  # non-finite t is not an invalid point
    arr['z'][1] = np.inf
    assert not structured_to_cloud_fields(arr)['is_dense']


# --- fuzz ---------------------------------------------------------------------------------------

# A valid layout: x, y, z (float32 or float64) and extra fields of any datatype and count, in a
# shuffled order, each after a gap of padding; then zero to two corruptions of the message.
_EXTRA = st.tuples(st.integers(1, 8), st.integers(1, 3), st.integers(0, 3))
_CORRUPTION = st.one_of(
    st.tuples(st.sampled_from(['width', 'height', 'point_step', 'row_step']),
              st.one_of(st.integers(-3, 80), st.just(2**32 - 1), st.just(2.5), st.none())),
    st.tuples(st.just('field'), st.tuples(
        st.integers(0, 9), st.sampled_from(['offset', 'datatype', 'count', 'name']),
        st.one_of(st.integers(-2, 60), st.sampled_from(['x', 'y', '', None])))),
    st.tuples(st.just('drop_field'), st.integers(0, 9)),
    st.tuples(st.just('data'), st.integers(-9, 9)),
    st.tuples(st.just('bigendian'), st.booleans()),
)


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(xyz_type=st.sampled_from([7, 8]), extras=st.lists(_EXTRA, max_size=4),
       order=st.randoms(use_true_random=False), tail=st.integers(0, 9),
       width=st.integers(0, 6), height=st.integers(0, 3), row_pad=st.integers(0, 7),
       bigendian=st.booleans(), corruptions=st.lists(_CORRUPTION, max_size=2),
       seed=st.integers(0, 2**16))
def test_fuzz_only_invalid_cloud_error(xyz_type, extras, order, tail, width, height, row_pad,
                                       bigendian, corruptions, seed):
    specs = [(n, xyz_type, 1, 0) for n in 'xyz'] + [
        (f'f{i}', d, c, gap) for i, (d, c, gap) in enumerate(extras)]
    order.shuffle(specs)
    layout, offset = [], 0
    for name, datatype, count, gap in specs:
        offset += gap
        layout.append((name, offset, datatype, count))
        offset += int(DATATYPES[datatype][1][1]) * count
    point_step = offset + tail
    row_step = width * point_step + row_pad
    # Random bytes: NaNs, infinities and any integers, as a sensor or a bit flip may give.
    data = bytearray(np.random.default_rng(seed).integers(0, 256, height * row_step,
                                                          dtype=np.uint8).tobytes())
    msg = cloud(layout, data, width=width, height=height, point_step=point_step,
                row_step=row_step, bigendian=bigendian)
    for kind, value in corruptions:
        if kind == 'field' and msg.fields:
            index, attr, new = value
            setattr(msg.fields[index % len(msg.fields)], attr, new)
        elif kind == 'drop_field' and msg.fields:
            del msg.fields[value % len(msg.fields)]
        elif kind == 'data':
            msg.data = data[:value] if value < 0 else data + bytes(value)
        elif kind == 'bigendian':
            msg.is_bigendian = value
        elif kind in ('width', 'height', 'point_step', 'row_step'):
            setattr(msg, kind, value)
    n = width * height
    try:
        arr = cloud_to_structured(msg)
        assert arr.shape == (msg.width * msg.height,)
    except InvalidCloudError:
        assert corruptions, 'a valid cloud was rejected'
    try:
        xyz, dropped = cloud_to_xyz(msg)
        assert xyz.shape[1] == 3 and np.isfinite(xyz).all()
        assert xyz.shape[0] + dropped == msg.width * msg.height
    except InvalidCloudError:
        assert corruptions, 'a valid cloud was rejected'
    if not corruptions:
        # The valid cloud decodes to exactly its bytes, whichever the layout.
        bo = '>' if bigendian else '<'
        code = bo + DATATYPES[xyz_type][1]
        rows = np.frombuffer(bytes(data), np.uint8).reshape(height, row_step)
        rows = rows[:, :width * point_step]
        points = rows.reshape(n, point_step) if n else np.zeros((0, point_step), np.uint8)
        want = np.stack([points[:, o:o + np.dtype(code).itemsize].copy().view(code)[:, 0]
                         for name, o, _, _ in sorted(layout) if name in 'xyz'], axis=1)
        with np.errstate(invalid='ignore'):
            want = want.astype(np.float64).reshape(-1, 3)
        finite = np.isfinite(want).all(axis=1)
        np.testing.assert_array_equal(xyz, want[finite])
        assert dropped == n - finite.sum()
