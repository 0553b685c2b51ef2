"""Tiles seen only at grazing angles (a ground vehicle's view) are unknown; a helicopter's stay
judged as they were; the steep returns' counts scroll with the map and live through snapshots."""
from __future__ import annotations

import json
import math

import numpy as np
import pytest
from safetensors.numpy import load_file, save_file

from landing_zone.assessor import Assessor
from landing_zone.judging.judgement import REASON_GRAZING
from landing_zone.runtime.snapshot import load_snapshot, save_snapshot
from test_assessor import SENSORS, fly, small_config

VEHICLE = (0.0, 0.0, 1.5)  # a ground vehicle's sensor, 1.5 m above flat ground at z = 0


def vehicle_cloud(rng, n=20000):
    """Returns on flat ground 5-10 m ahead (+x) of VEHICLE: 8.5 to 16.7 degrees down."""
    xy = np.column_stack([rng.uniform(5.0, 10.0, n), rng.uniform(-3.0, 3.0, n)])
    return np.column_stack([xy, np.zeros(n)]).astype(np.float32)


def vehicle_view(model_file, deg):
    a = Assessor(small_config(min_ray_depression_deg=deg), center=(7.5, 0.0), model=model_file)
    a.integrate(vehicle_cloud(np.random.default_rng(0)), VEHICLE)
    return a.assess()


def test_a_ground_vehicles_view_is_unknown_with_its_reason(model_file):
    judged = vehicle_view(model_file, 0.0)  # the rule off: judged as it was
    seen = np.isfinite(judged.p_safe)
    assert seen.sum() >= 8
    assert not np.any(judged.grazing)
    res = vehicle_view(model_file, 20.0)
    # the network still ran on those tiles; its word is not taken
    np.testing.assert_array_equal(res.p_net, judged.p_net)
    assert not np.any(np.isfinite(res.p_safe))
    np.testing.assert_array_equal(res.grazing, seen)
    reasons = res.reasons()
    assert {reasons[k] for k in np.flatnonzero(seen)} == {REASON_GRAZING}
    assert all(reasons[k] is None for k in np.flatnonzero(~seen))
    report = res.to_report()
    assert len(report['reasons']) == seen.sum()
    assert all(r['reason'] == REASON_GRAZING and r['p_net'] is not None
               for r in report['reasons'])
    assert all(t['p_safe'] is None for t in report['tiles'])
    # 5 degrees passes every return (8.5 degrees and steeper): judged again
    np.testing.assert_array_equal(vehicle_view(model_file, 5.0).p_safe, judged.p_safe)


def test_a_helicopters_flight_is_judged_as_without_the_rule(model_file):
    out = []
    for deg in (0.0, 20.0):
        a = Assessor(small_config(min_ray_depression_deg=deg), model=model_file)
        rng = np.random.default_rng(1)
        fly(a, rng, SENSORS)
        first = a.assess()
        fly(a, rng, [(2.0, 0.5, 8.0), (3.5, 1.0, 8.0)])  # on, scrolling
        out.append((first, a.assess()))
    for off, on in zip(*out):
        assert np.isfinite(off.p_safe).sum() > 10
        np.testing.assert_array_equal(on.p_safe, off.p_safe)
        np.testing.assert_array_equal(on.confidence, off.confidence)
        assert not np.any(on.grazing) and on.reasons() == off.reasons()


def steep_by_tile(clouds, deg):
    """{global tile: returns from rays at least ``deg`` down}, counted return by return."""
    out: dict[tuple[int, int], int] = {}
    for pts, org in clouds:
        for x, y, z in pts.tolist():
            d = math.degrees(math.atan2(org[2] - z, math.hypot(x - org[0], y - org[1])))
            if d >= deg:
                k = (math.floor(x), math.floor(y))
                out[k] = out.get(k, 0) + 1
    return out


def test_the_steep_counts_scroll_with_the_window(model_file):
    a = Assessor(small_config(), model=model_file)
    rng = np.random.default_rng(2)
    clouds, lo, hi = [], [], []
    # a sensor low enough that the far returns are grazing, moving +x and scrolling the map
    for x in (0.0, 1.2, 2.4, 3.6):
        org = np.array([x, 0.0, 2.0])
        pts = np.column_stack([rng.uniform(x - 4, x + 4, (3000, 2)),
                               np.zeros(3000)]).astype(np.float32)
        a.integrate(pts, org)
        clouds.append((pts.astype(np.float64), org))
        lo.append(int(a._steep.origin[0]))
        hi.append(lo[-1] + a._steep.shape[0])
    res = a.assess()
    assert res.origin[0] == lo[-1] > lo[0]  # the window scrolled, the counts with it
    sx, sy = res.shape
    expect = steep_by_tile(clouds, 20.0)
    want = np.array([expect.get((i, j), 0) for i, j in res.index.tolist()])
    got = a._steep.take(res.index)
    # the tiles in the window from the first cloud on hold every steep return on them; those
    # that entered later missed the returns that fell on them before
    always = res.index[:, 0] < min(hi)
    assert always.sum() >= 2 * sy and want[always].sum() > 0
    np.testing.assert_array_equal(got[always], want[always])
    assert np.all(got <= want)
    assert got[~always].sum() > 0
    a.close()


@pytest.fixture(scope='module')
def flown(model_file):
    """A helicopter's flight over the middle of the map, then a low sensor's grazing view of
    the strip it did not see (y < -2.5)."""
    a = Assessor(small_config(), model=model_file)
    rng = np.random.default_rng(3)
    fly(a, rng, [(x, 0.3, 8.0) for x in np.linspace(-1.0, 2.5, 8)], half=2.0)
    xy = np.column_stack([rng.uniform(-1.0, 5.0, 8000), rng.uniform(-4.0, -2.6, 8000)])
    a.integrate(np.column_stack([xy, np.zeros(8000)]), (2.0, 0.3, 0.6))
    a.assess()
    assert np.any(a.last.grazing) and np.isfinite(a.last.p_safe).sum() > 10
    return a


def test_the_steep_counts_survive_a_snapshot(tmp_path, flown, model_file):
    path = tmp_path / 'map.snapshot'
    save_snapshot(path, flown)
    b = Assessor(small_config(), model=model_file)
    assert load_snapshot(path, b)['tiles_restored']
    np.testing.assert_array_equal(b._steep.counts, flown._steep.counts)
    np.testing.assert_array_equal(b._steep.origin, flown._steep.origin)
    again = b.assess()
    np.testing.assert_array_equal(again.grazing, flown.last.grazing)
    assert again.reasons() == flown.last.reasons()
    # counted at another angle: the counts are not known, the tiles' return counts stand in
    c = Assessor(small_config(min_ray_depression_deg=30.0), model=model_file)
    load_snapshot(path, c)
    np.testing.assert_array_equal(c._steep.counts, flown.last.grid(flown.last.n_returns))


def test_a_snapshot_without_steep_counts_still_loads(tmp_path, flown, model_file):
    path = tmp_path / 'map.snapshot'
    save_snapshot(path, flown)
    with open(path, 'rb') as f:  # the header as written
        n = int.from_bytes(f.read(8), 'little')
        meta = json.loads(f.read(n))['__metadata__']
    arrays = {k: v for k, v in load_file(path).items()
              if k not in ('steep.returns', 'steep.deg', 'tiles.grazing')}
    old = tmp_path / 'old.snapshot'
    save_file(arrays, old, metadata=meta)
    b = Assessor(small_config(), model=model_file)
    assert load_snapshot(old, b)['tiles_restored']
    # not known: each tile's return count stands in, so no restored tile turns unknown
    last = flown.last
    np.testing.assert_array_equal(b._steep.counts, last.grid(last.n_returns))
    again = b.assess()
    assert again.reassessed == 0 and not np.any(again.grazing)
    np.testing.assert_array_equal(np.isfinite(again.p_safe),
                                  np.isfinite(last.p_safe) & ~last.grazing)
    # judged again, the tiles the map holds pass unless only grazing returns came since
    b.invalidate()
    rejudged = b.assess()
    assert rejudged.reassessed > 0
    assert np.isfinite(rejudged.p_safe).sum() >= np.isfinite(last.p_safe).sum()
