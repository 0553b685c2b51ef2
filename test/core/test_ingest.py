"""The live receive path without DDS: sequence gaps, the bounded queue, the two threads."""
from __future__ import annotations

import threading
import time

import numpy as np
import pytest

from landing_zone.assessor import Assessor
from landing_zone.io.bags import RawBag
from landing_zone.errors import ConfigError
from landing_zone.config import LiveConfig
from landing_zone.runtime.ingest import LivePipeline, warm_up
from landing_zone.runtime.receive import PLACE_RETURNS, ReceiveQueue, SequenceGaps
from landing_zone.replay import replay
from landing_zone.config import StreamConfig
from landing_zone.runtime.stream import Stream
from test_assessor import small_config
from test_replay import write_flight


@pytest.fixture(scope='module')
def flight(tmp_path_factory):
    path = tmp_path_factory.mktemp('bag') / 'flight.mcap'
    write_flight(path, seconds=3.0)
    return path


def raw_messages(bag):
    with RawBag(bag) as src:
        return [(m.topic, bytes(m.data)) for m in src.messages()]


def test_sequence_gaps_are_counted_per_publisher():
    g = SequenceGaps()
    for pub, seq in [('a', 1), ('b', 1), ('a', 2), ('b', 4), ('a', 3), ('b', 5), ('a', 7)]:
        g.observe(pub, seq)
    assert (g.transport, g.missed_at_start, g.publishers) == (2 + 3, 0, 2)
    # a publisher first seen at 6 had 5 before it; rmw's "unsupported" and 0 are ignored
    assert g.observe('c', 6) == (0, 5)
    assert g.observe('c', 2 ** 64 - 1) == (0, 0) and g.observe('c', 0) == (0, 0)
    assert g.observe('c', 8) == (1, 0)
    # without GIDs a count that goes back is a restarted publisher, not a loss
    g2 = SequenceGaps()
    assert [g2.observe(None, s) for s in (1, 2, 5, 1, 2)] == [(0, 0), (0, 0), (2, 0), (0, 0),
                                                              (0, 0)]
    assert g2.publishers == 2


def test_queue_keeps_the_newest_clouds_within_its_bounds():
    q = ReceiveQueue(max_clouds=3, max_bytes=1000, max_poses=2)
    for k in range(5):
        q.put('cloud', k, arrival=float(k), nbytes=100, points=PLACE_RETURNS)
        q.put('pose', f'p{k}', arrival=float(k))
    assert q.clouds == 3 and q.dropped_clouds == 2 and q.dropped_points == 2 * PLACE_RETURNS
    assert q.dropped_poses == 3 and q.peak_clouds == 3
    # arrival order is kept among what is left; the oldest went first
    assert [e.payload for e in iter(lambda: q.get(0.0), None)] == [2, 3, 'p3', 4, 'p4']
    # the byte bound: a cloud as large as the bound pushes out everything before it
    q.put('cloud', 'a', 0.0, nbytes=600)
    q.put('cloud', 'b', 0.0, nbytes=600)
    assert q.clouds == 1 and q.get(0.0).payload == 'b'
    assert q.get(0.01) is None


def test_a_flood_of_tiny_clouds_does_not_push_out_the_real_ones():
    """Malformed clouds declare a few hundred returns or none: each takes its share of a place
    (at least 1/20), so 20 places hold the real clouds and the flood beside them; when real
    clouds do overflow the places, the oldest entries go first, tiny or not."""
    q = ReceiveQueue(max_clouds=20, max_bytes=10 ** 9)
    q.put('cloud', 'real0', 0.0, nbytes=160_000, points=10_000)
    for k in range(100):  # 1 s of 100 Hz malformed clouds: 200 returns declared, or none
        q.put('cloud', f'bad{k}', 0.0, nbytes=2_400, points=200 if k % 5 else 0)
    q.put('cloud', 'real1', 0.0, nbytes=160_000, points=10_000)
    # 2 places + 80 x 0.2 + 20 x 0.05 = 19 places
    assert q.dropped_clouds == 0 and q.clouds == 102
    for k in range(3):
        q.put('cloud', f'real{k + 2}', 0.0, nbytes=160_000, points=10_000)
    # past 20 places the oldest entries make room: the first real cloud, then seven tiny ones
    assert q.dropped_clouds == 1 + 7 and q.dropped_points == 10_000 + 5 * 200
    left = [e.payload for e in iter(lambda: q.get(0.0), None)]
    assert left[0] == 'bad7' and left[-4:] == ['real1', 'real2', 'real3', 'real4']


def test_points_of_a_serialized_cloud_are_read_from_its_bytes(flight):
    from msg_adapters import jazzy_typestore as typestore
    from landing_zone.runtime.receive import _declared_size

    for topic, data in raw_messages(flight):
        if topic == '/lidar/points':
            msg = typestore().deserialize_cdr(data, 'sensor_msgs/msg/PointCloud2')
            assert _declared_size(data) == (len(data), msg.width * msg.height)
    assert _declared_size(b'\x00\x01\x00\x00junk') == (8, 0)
    from msg_adapters import make_header
    from msg_adapters.pointcloud import make_cloud, points_to_structured
    for frame in ('', 'a', 'ab', 'abc', 'lidar_link_front'):  # every padding of the string
        msg = make_cloud(points_to_structured(np.zeros((7, 3), np.float32)),
                         make_header(5, frame, 'rosbags'), 'rosbags')
        data = bytes(typestore().serialize_cdr(msg, 'sensor_msgs/msg/PointCloud2'))
        assert _declared_size(data)[1] == 7, frame


def test_live_config_is_checked():
    with pytest.raises(ConfigError, match='receive_queue'):
        LiveConfig(receive_queue=0).validate()
    with pytest.raises(ConfigError, match='idle_flush'):
        LiveConfig(idle_flush=float('nan')).validate()


def pipeline(model_file, published=None, **live):
    a = Assessor(small_config(), model=model_file)
    results = [] if published is None else published
    p = LivePipeline(Stream(a, StreamConfig()), LiveConfig(idle_flush=0.2, **live),
                     publish=results.append)
    return p, a, results


def offer_all(p, messages, bad_every=0):
    from msg_adapters import jazzy_typestore as typestore

    bad = good = 0
    for k, (topic, data) in enumerate(messages):
        if topic == '/lidar/pose':
            p.offer_pose(typestore().deserialize_cdr(data, 'geometry_msgs/msg/PoseStamped'))
        else:
            good += 1
            p.offer_cloud(data, b'pub', good)
        if bad_every and k % bad_every == 0:
            p.offer_cloud(b'\x00\x01\x00\x00garbage', b'bad', bad + 1)
            bad += 1
    return bad


def test_pipeline_integrates_what_replay_integrates_and_counts_bad_bytes(flight, model_file):
    p, a, results = pipeline(model_file, receive_queue=1000)  # room for the whole burst
    p.start()
    try:
        n_bad = offer_all(p, raw_messages(flight), bad_every=3)
        assert p.drain(timeout=60)
    finally:
        p.stop()
    assert not p.errors
    ref = replay(flight, None, None, model=model_file, config=small_config(), progress=False)
    drops = p.dropped_clouds()
    assert drops['malformed'] == n_bad > 0
    assert p.stream.clouds == ref.stats['clouds']
    assert p.stream.clouds + sum(drops.values()) == p.received
    final = results[-1]
    np.testing.assert_array_equal(np.isnan(final.p_safe), np.isnan(ref.assessment.p_safe))
    np.testing.assert_allclose(final.p_safe, ref.assessment.p_safe, atol=1e-5)
    diag = p.diagnostics()
    assert diag['dropped clouds: malformed'] == str(n_bad)
    assert diag['clouds received'] == str(p.received)


def test_a_full_queue_drops_the_oldest_and_every_cloud_is_counted(flight, model_file):
    p, a, results = pipeline(model_file, receive_queue=3)
    messages = raw_messages(flight)
    offer_all(p, messages)  # before the threads start: nothing is taken out meanwhile
    n_clouds = sum(t == '/lidar/points' for t, _ in messages)
    assert p.queue.dropped_clouds == n_clouds - 3
    p.start()
    try:
        assert p.drain(timeout=60)
    finally:
        p.stop()
    drops = p.dropped_clouds()
    assert drops['overload'] == n_clouds - 3
    assert p.stream.clouds + sum(drops.values()) == n_clouds
    assert p.stream.clouds == 3  # the newest three (poses all came through)
    assert results and np.isfinite(results[-1].p_safe).any()


def test_the_receiving_thread_is_never_held_by_integration(flight, model_file):
    """Offering is queueing: a cloud offered while the integration thread works on a long
    batch returns in well under the batch's time (a real GIL-releasing kernel)."""
    p, a, _ = pipeline(model_file, receive_queue=1000)
    p.start()
    try:
        msgs = raw_messages(flight)
        offer_all(p, msgs[:10])
        clouds = [d for t, d in msgs if t == '/lidar/points']
        worst = 0.0
        stop = time.perf_counter() + 1.0
        k = 100
        while time.perf_counter() < stop:
            t0 = time.perf_counter()
            p.offer_cloud(clouds[k % len(clouds)], b'x', k)
            worst = max(worst, time.perf_counter() - t0)
            k += 1
            time.sleep(0.002)
        p.drain(timeout=60)
    finally:
        p.stop(drain=False)
    assert worst < 0.05, worst


def test_warm_up_leaves_the_map_alone(model_file):
    a = Assessor(small_config(), model=model_file)
    before = a.map.counts()
    built = []
    seconds = warm_up(a, build=built.append)
    # a 4 x 4 tile scratch map, and the network judged some of its tiles
    assert seconds > 0 and len(built) == 1 and len(built[0]) == 16
    assert np.isfinite(built[0].p_safe).any()
    after = a.map.counts()
    assert all(np.array_equal(x, y) for x, y in zip(before, after)) and a.clouds == 0


def test_threads_stop_and_errors_are_kept_not_raised(model_file):
    p, a, _ = pipeline(model_file)
    seen = []
    p.on_error = lambda reason, msg: seen.append(reason)

    def broken(_):
        raise RuntimeError('planner went away')
    p.publish = broken
    p.start()
    p.offer_cloud(b'not cdr')  # counted as malformed, not an error
    deadline = time.monotonic() + 10
    while p.stream.dropped_clouds['malformed'] < 1 and time.monotonic() < deadline:
        time.sleep(0.01)
    p.stop()
    assert p.stream.dropped_clouds['malformed'] == 1 and not p.errors
    assert not [t for t in threading.enumerate() if t.name.startswith('lz-')]


def test_input_ages_give_the_stale_level():
    from landing_zone.runtime.ingest import stale_level

    assert stale_level({'cloud': None, 'pose': None}, 1.0, 3.0) == (
        'WARN', 'no cloud received yet, no pose received yet')
    assert stale_level({'cloud': 0.2, 'pose': 0.1}, 1.0, 3.0) == ('OK', '')
    level, why = stale_level({'cloud': 1.5, 'pose': 0.1}, 1.0, 3.0)
    assert level == 'WARN' and why == 'no cloud for 1.5 s (stale_after 1 s)'
    level, why = stale_level({'cloud': 0.1, 'pose': 4.0}, 1.0, 3.0)
    assert level == 'ERROR' and why == 'no pose for 4.0 s (stale_error 3 s)'
    # the ages follow the arrivals, on the pipeline's clock
    now = [10.0]
    p = LivePipeline(Stream(Assessor(small_config())), clock=lambda: now[0])
    try:
        assert p.input_ages() == {'cloud': None, 'pose': None}
        p.offer_cloud(b'not a cloud')
        now[0] = 11.5
        p.offer_pose(object())
        now[0] = 12.0
        assert p.input_ages() == {'cloud': 2.0, 'pose': 0.5}
        d = p.diagnostics()
        assert d['newest cloud age [s]'] == '2.00' and d['newest pose age [s]'] == '0.50'
    finally:
        p.stream.assessor.close()


def test_eager_passes_only_while_integration_has_room(model_file):
    now = [0.0]
    stream = Stream(Assessor(small_config()))
    p = LivePipeline(stream, LiveConfig(eager_interval=0.25), clock=lambda: now[0])
    try:
        assert not p._eager()  # nothing to assess
        stream.add_pose(0, [0.0, 0.0, 8.0], [0, 0, 0, 1])
        stream.add_cloud(0, np.array([[0.0, 0.0, 0.0], [0.5, 0.5, 0.0]]))
        assert stream.unassessed == 1 and p._eager()
        p._last_pass = 0.0
        now[0] = 0.1
        assert not p._eager()  # within eager_interval of the last pass
        now[0] = 0.3
        assert p._eager()
        p._work.append((0.3, 0.6))  # integration busy 60 % of the last second
        assert not p._eager()
        now[0] = 1.5  # that work is older than a second
        assert p._eager()
        p.config.eager_interval = 0.0
        assert not p._eager()
    finally:
        stream.assessor.close()
