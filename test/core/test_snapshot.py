"""Map snapshots: exact round trip, refusals with one line, another model, atomic writes."""
from __future__ import annotations

import json

import numpy as np
import pytest

from landing_zone.assessor import Assessor
from landing_zone.runtime.snapshot import SnapshotError, load_snapshot, save_snapshot
from test_assessor import fly, make_model, small_config


@pytest.fixture(scope='module')
def flown(model_file):
    """An assessor after a short flight, with some voxels hit past 255 (high bytes)."""
    a = Assessor(small_config(), model=model_file)
    rng = np.random.default_rng(3)
    fly(a, rng, [(x, 0.3, 8.0) for x in np.linspace(-1.0, 2.5, 8)])
    a.integrate(np.tile([[0.51, 0.52, 0.03]], (400, 1)), (0.0, 0.0, 8.0), stamp=9.0)
    a.assess()
    assert a.map.cold_blocks > 0
    return a


def test_round_trip_restores_counts_tiles_and_stamp_exactly(tmp_path, flown, model_file):
    path = tmp_path / 'map.snapshot'
    size = save_snapshot(path, flown, stamp_ns=9_000_000_001)
    assert size == path.stat().st_size and not (tmp_path / 'map.snapshot.tmp').exists()
    b = Assessor(small_config(), model=model_file)
    header = load_snapshot(path, b)
    assert header['tiles_restored'] and header['stamp_ns'] == 9_000_000_001
    for x, y in zip(flown.map.counts(), b.map.counts()):
        np.testing.assert_array_equal(x, y)
    assert b.map.cold_blocks == flown.map.cold_blocks
    np.testing.assert_array_equal(b.map.lo, flown.map.lo)
    again = b.assess()  # nothing changed since the last pass: the same tiles, none re-judged
    last = flown.last
    assert again.reassessed == 0 and again.origin == last.origin
    np.testing.assert_array_equal(again.p_safe, last.p_safe)
    np.testing.assert_array_equal(again.ground_z, last.ground_z)
    assert b.last_stamp == flown.last_stamp == 9.0
    # and it goes on as the original would: the same next cloud gives the same map
    cloud = np.random.default_rng(5).uniform(-2, 2, (3000, 3)) * (1, 1, 0.05)
    for a in (flown, b):
        a.integrate(cloud, (0.2, 0.1, 8.0))
    for x, y in zip(flown.map.counts(), b.map.counts()):
        np.testing.assert_array_equal(x, y)
    np.testing.assert_array_equal(flown.assess().p_safe, b.assess().p_safe)


def test_mismatched_or_bad_files_are_refused_in_one_line(tmp_path, flown, model_file):
    path = tmp_path / 'map.snapshot'
    save_snapshot(path, flown)
    cases = {'region_center': Assessor(small_config(), center=(1.0, 2.0), model=model_file)}
    cfg = small_config()
    cfg.map.size_xy = 6.0
    cases['shape'] = Assessor(cfg, model=model_file)
    cfg = small_config()
    cfg.frame_id = 'odom'
    cases['frame_id'] = Assessor(cfg, model=model_file)
    for what, other in cases.items():
        before = other.map.counts()
        with pytest.raises(SnapshotError) as err:
            load_snapshot(path, other)
        text = str(err.value)
        assert '\n' not in text and f'was made for {what}' in text, text
        for x, y in zip(before, other.map.counts()):  # left as it was
            np.testing.assert_array_equal(x, y)
    fresh = Assessor(small_config(), model=model_file)
    bad = tmp_path / 'bad.snapshot'
    for content, words in [(b'', 'only 0 bytes'), (b'\xff' * 64, 'is not a snapshot'),
                           (b'\x02\x00\x00\x00\x00\x00\x00\x00{}', 'is not a snapshot')]:
        bad.write_bytes(content)
        with pytest.raises(SnapshotError, match=words):
            load_snapshot(bad, fresh)
    with pytest.raises(SnapshotError, match='not found'):
        load_snapshot(tmp_path / 'none.snapshot', fresh)
    # a safetensors file of another kind (a model) is no snapshot either
    with pytest.raises(SnapshotError, match='is not a snapshot'):
        load_snapshot(model_file, fresh)


def test_a_snapshot_of_another_model_keeps_the_counts_and_judges_again(tmp_path, flown):
    path = tmp_path / 'map.snapshot'
    save_snapshot(path, flown)
    other = make_model(tmp_path / 'other.safetensors', seed=7)
    b = Assessor(small_config(), model=other)
    assert not load_snapshot(path, b)['tiles_restored']
    for x, y in zip(flown.map.counts(), b.map.counts()):
        np.testing.assert_array_equal(x, y)
    result = b.assess()
    assert result.reassessed == len(result)  # every tile judged by this model


def test_header_is_readable_json_and_no_code_runs_on_load(tmp_path, flown):
    path = tmp_path / 'map.snapshot'
    save_snapshot(path, flown)
    data = path.read_bytes()
    n = int.from_bytes(data[:8], 'little')
    header = json.loads(json.loads(data[8:8 + n])['__metadata__']['landing_zone'])
    assert header['format'] == 'landing_zone.snapshot/1' and header['frame_id'] == 'map'
    assert b'pickle' not in data[:8 + n] and not data.startswith(b'PK')  # no npz, no pickle
