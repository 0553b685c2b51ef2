"""The one pipeline: placement, incremental assessment, unknown tiles, report, model checks."""
from __future__ import annotations

import json
import threading

import numpy as np
import pytest

from landing_zone.assessor import Assessor, default_model_path, tile_confidence
from landing_zone.config import AssessorConfig, MapConfig, TileConfig
from landing_zone.errors import InvalidCloudError, ModelError

SMALL_SPEC = 'C5-F4-P2-C3-F8-P2-D16'  # the paper's shape, shrunk so tests run fast


def make_model(path, input_size: int = 32, seed: int = 0, **metadata):
    """A model file of the right architecture from a seeded, untrained net."""
    import torch

    from landing_zone.judging.checkpoint import save_model
    from landing_zone.judging.net import SafetyNet, SafetyNetConfig

    torch.manual_seed(seed)
    net = SafetyNet(SafetyNetConfig(spec=SMALL_SPEC, input_size=input_size))
    # An untrained head sits at P = 0.5 everywhere (logits within +-0.2); spread it so tiles
    # differ measurably without saturating.
    with torch.no_grad():
        net.head.weight.mul_(20.0)
        net.head.bias.fill_(2.0)
    save_model(path, net, {'voxel_size': 0.05, **metadata})
    return path


def small_config(**tiles) -> AssessorConfig:
    """An 8 x 8 x 4 m map (64 tiles) with judging thresholds a few clouds can meet."""
    cfg = AssessorConfig()
    cfg.map = MapConfig(size_xy=8.0, size_z=4.0, z_below=2.0, recenter_distance=1.0)
    cfg.tiles = TileConfig(min_observed_fraction=tiles.pop('min_observed_fraction', 0.1),
                           min_returns=tiles.pop('min_returns', 20), **tiles)
    return cfg


def scene_cloud(rng, sensor, n=6000, half=4.0, box=(1.5, 1.5), ground=0.0):
    """Returns on flat ground at z = ground with a 1 x 1 x 1 m box, seen from ``sensor``."""
    xy = rng.uniform(-half, half, (n, 2)) + np.asarray(sensor[:2])
    z = np.full(n, ground)
    on_box = (np.abs(xy[:, 0] - box[0]) < 0.5) & (np.abs(xy[:, 1] - box[1]) < 0.5)
    z[on_box] += 1.0
    return np.column_stack([xy, z]).astype(np.float32)


def fly(assessor, rng, sensors, **kw):
    for s in sensors:
        s = np.asarray(s, np.float64)
        assessor.integrate(scene_cloud(rng, s, **kw), s)


# around (0, 0), none more than map.recenter_distance (1 m) from the first
SENSORS = [(0.0, 0.0, 8.0), (0.7, -0.7, 8.0), (0.7, 0.7, 8.0), (-0.7, 0.7, 8.0)]


def test_confidence_grows_with_observation_and_stays_in_unit_interval():
    f = np.array([0.0, 0.1, 0.25, 0.5, 0.9])
    c = tile_confidence(f, np.full(5, 1000), 1.0)
    assert np.all(np.diff(c) >= 0) and c[0] == 0.0 and c[-1] == c[-2] < 1.0
    c = tile_confidence(np.full(4, 0.5), np.array([0, 10, 100, 100000]), 1.0)
    assert c[0] == 0.0 and np.all(np.diff(c) > 0) and c[-1] == pytest.approx(1.0)
    assert tile_confidence(0.5, 100, 1.0) == pytest.approx(1 - np.exp(-1), rel=1e-6)


def test_follow_mode_places_whole_tiles_under_the_sensor(model_file):
    a = Assessor(small_config(), model=model_file)
    assert a.follow
    rng = np.random.default_rng(1)
    sensor = np.array([13.3, -7.6, 30.0])
    a.integrate(scene_cloud(rng, sensor, ground=5.0), sensor)
    lo = a.map.lo
    assert lo[0] % a.tile_vox == 0 and lo[1] % a.tile_vox == 0
    c = a.center
    assert abs(c[0] - 13.3) <= 0.5 and abs(c[1] + 7.6) <= 0.5
    # the window's height sits on the ground (z = 5), z_below under it
    assert a.map.bounds[0][2] == pytest.approx(3.0, abs=0.06)
    # a small move keeps the window, a larger one scrolls it by whole tiles
    a.integrate(scene_cloud(rng, sensor + [0.6, 0, 0], ground=5.0), sensor + [0.6, 0, 0])
    assert np.array_equal(a.map.lo, lo)
    a.integrate(scene_cloud(rng, sensor + [3.0, 0, 0], ground=5.0), sensor + [3.0, 0, 0])
    assert a.map.lo[0] - lo[0] == 3 * a.tile_vox and a.map.lo[1] == lo[1]


def test_fixed_mode_never_scrolls(model_file):
    a = Assessor(small_config(), center=(2.2, -3.9), model=model_file)
    assert not a.follow and a.config.center == (2.2, -3.9)
    rng = np.random.default_rng(2)
    lo0 = a.map.lo[:2].copy()
    for s in [(2.0, -4.0, 8.0), (30.0, 30.0, 8.0)]:
        a.integrate(scene_cloud(rng, s), s)
        assert np.array_equal(a.map.lo[:2], lo0)
    assert abs(a.center[0] - 2.2) <= 0.5 and abs(a.center[1] + 3.9) <= 0.5
    r = a.assess()
    assert r.origin == (int(lo0[0] // a.tile_vox), int(lo0[1] // a.tile_vox))
    # config.center works like the keyword
    cfg = small_config()
    cfg.center = (2.2, -3.9)
    assert np.array_equal(Assessor(cfg, model=model_file).map.lo[:2], lo0)


def test_fixed_mode_height_follows_the_ground_at_the_centre(model_file):
    from landing_zone.mapping.window import CENTRAL_RETURNS

    a = Assessor(small_config(), center=(0.0, 0.0), model=model_file)
    rng = np.random.default_rng(4)
    lo0 = a.map.lo[:2].copy()
    # the first cloud, flown beyond the region's edge, sees ground 2.5 m higher than its centre
    s = np.array([9.0, 0.0, 10.5])
    a.integrate(scene_cloud(rng, s, half=1.5, ground=2.5), s)
    assert abs(a.center[2] - 2.5) < 0.1
    # a few returns at the centre are not enough to move it
    s = np.array([0.0, 0.0, 8.0])
    a.integrate(scene_cloud(rng, s, n=CENTRAL_RETURNS // 2, half=0.5), s)
    assert abs(a.center[2] - 2.5) < 0.1
    # a cloud over the centre places it there; XY never moves
    a.integrate(scene_cloud(rng, s, half=3.0), s)
    assert abs(a.center[2]) < 0.1 and np.array_equal(a.map.lo[:2], lo0)
    r = a.assess()
    centre = r.lookup(0.5, 0.5)
    assert np.isfinite(r.ground_z[centre]) and abs(r.ground_z[centre]) < 0.1


def test_judged_tiles_are_the_networks_output_and_others_unknown(model_file):
    from landing_zone.judging.inference import predict
    from landing_zone.judging.tiles import extract_tiles

    a = Assessor(small_config(), model=model_file)
    rng = np.random.default_rng(3)
    fly(a, rng, SENSORS, half=2.5)  # returns only within ~3.5 m of the centre
    r = a.assess()
    assert len(r) == 64 and r.shape == (8, 8)
    known = r.known
    assert 0 < known.sum() < 64
    # the map's corners saw no returns: unknown, with no confidence
    corner = r.lookup(-3.9, -3.9)
    assert np.isnan(r.p_safe[corner]) and r.confidence[corner] == 0.0
    # every judged tile is valid per the tiler and has the network's probability
    batch = extract_tiles(a.map, a.config.tiles, r.index)
    assert np.array_equal(batch.valid, known)
    expect = predict(a.model, batch.inputs[batch.valid])
    np.testing.assert_allclose(r.p_safe[known], expect, atol=1e-6)
    assert np.unique(np.round(r.p_safe[known], 3)).size > 3  # the tiles do differ
    np.testing.assert_allclose(r.confidence, tile_confidence(
        batch.observed_fraction, batch.n_returns, 1.0), atol=1e-6)
    # ground: the box's tile stands 1 m higher than open ground
    assert r.ground_z[r.lookup(1.5, 1.5)] > r.ground_z[r.lookup(-1.5, -1.5)] + 0.5


def test_a_stated_obstacle_prior_moves_every_judgement_by_its_log_odds(tmp_path, model_file):
    from scipy.special import logit

    from landing_zone.errors import ConfigError
    from landing_zone.judging.inference import prior_shift

    assert prior_shift(0.5) == 0.0 and prior_shift(0.1) == pytest.approx(np.log(9.0))
    assert prior_shift(0.2, calibrated_at=0.2) == 0.0 and prior_shift(0.9) < 0
    with pytest.raises(ConfigError, match='obstacle_prior must lie in'):
        prior_shift(0.0)

    def judged(prior, model=model_file):
        cfg = small_config()
        cfg.guard.enabled = False
        cfg.model.obstacle_prior = prior
        with Assessor(cfg, model=model) as a:
            fly(a, np.random.default_rng(3), SENSORS, half=2.5)
            return a.assess().p_safe

    even, rare = judged(0.5), judged(0.1)
    known = np.isfinite(even) & np.isfinite(rare)
    assert known.sum() > 3
    # every tile the same way: the ranking is the net's, only the prior changed
    np.testing.assert_allclose(logit(rare[known].astype(np.float64)) -
                               logit(even[known].astype(np.float64)), np.log(9.0), atol=1e-3)
    # a model calibrated at another share is moved from that share, as its metadata states
    other = make_model(tmp_path / 'at20.safetensors', calibration_prior=0.2)
    np.testing.assert_allclose(judged(0.2, other)[known], even[known], atol=1e-6)
    with pytest.raises(ConfigError, match='model.obstacle_prior'):
        cfg = small_config()
        cfg.model.obstacle_prior = 1.0
        cfg.validate()


def test_only_changed_tiles_are_reassessed_and_the_result_matches_a_full_pass(model_file):
    rng = np.random.default_rng(4)
    clouds = [scene_cloud(rng, s, half=2.5) for s in SENSORS]
    local = scene_cloud(rng, (0, 0, 8.0), n=3000, half=0.45)  # within the 4 tiles at (0, 0)
    a = Assessor(small_config(), model=model_file)
    for c, s in zip(clouds, SENSORS):
        a.integrate(c, s)
    first = a.assess()
    assert first.reassessed > 0
    assert a.assess().reassessed == 0  # nothing changed
    a.integrate(local, (0.0, 0.0, 8.0))
    second = a.assess()
    # rays from 8 m up to within 0.45 m of (0, 0) change only the central tiles; widened by
    # the padding's reach (one tile) that is at most a 4 x 4 block
    assert 4 <= second.reassessed <= 16
    far = [second.lookup(x, y) for x, y in [(-3.5, -3.5), (3.5, -2.5), (-2.5, 3.5)]]
    for i in far:
        assert np.array_equal(second.p_safe[i], first.p_safe[i], equal_nan=True)
    # the incremental result equals one pass over the same clouds on a fresh assessor
    b = Assessor(small_config(), model=model_file)
    for c, s in zip(clouds, SENSORS):
        b.integrate(c, s)
    b.integrate(local, (0.0, 0.0, 8.0))
    full = b.assess()
    np.testing.assert_array_equal(np.isnan(full.p_safe), np.isnan(second.p_safe))
    np.testing.assert_allclose(full.p_safe, second.p_safe, atol=2e-3, equal_nan=True)
    np.testing.assert_allclose(full.confidence, second.confidence, atol=1e-6)


def test_tiles_that_scroll_out_are_forgotten(model_file):
    a = Assessor(small_config(), model=model_file)
    rng = np.random.default_rng(5)
    fly(a, rng, SENSORS, half=3.0)
    before = a.assess()
    kept = before.lookup(2.5, 0.5)
    p_kept = before.p_safe[kept]
    assert np.isfinite(p_kept)
    # move 3 m in +x: tiles x < -1 leave, tiles at x > 4 enter unobserved
    s = np.array([3.0, 0.0, 8.0])
    a.integrate(np.empty((0, 3), np.float32), s)  # no returns: only the move
    after = a.assess()
    assert after.origin[0] == before.origin[0] + 3
    assert after.lookup(-3.5, 0.5) is None
    assert np.isnan(after.p_safe[after.lookup(6.5, 0.5)])
    assert after.p_safe[after.lookup(2.5, 0.5)] == pytest.approx(p_kept, abs=2e-3)


def test_report_follows_the_contract(model_file):
    a = Assessor(small_config(), model=model_file)
    fly(a, np.random.default_rng(6), SENSORS, half=2.5)
    r = a.assess()
    rep = r.to_report({'clouds': 4, 'points': 24000, 'dropped_points': 0, 'seconds': 1.0})
    text = json.dumps(rep, allow_nan=False)  # no NaN may leak into the JSON
    back = json.loads(text)
    assert back['frame_id'] == 'map' and back['tile_size'] == 1.0
    assert len(back['tiles']) == 64
    # the contract's keys (slope_deg among them), and the ground's roughness and clearance
    assert set(back['tiles'][0]) == {'x', 'y', 'ground_z', 'p_safe', 'confidence', 'slope_deg',
                                     'roughness', 'clearance'}
    assert any(t['slope_deg'] is not None for t in back['tiles'])
    assert all(set(s) >= {'x', 'y', 'p_safe', 'slope_deg'} for s in back['landing_sites'])
    nulls = [t for t in back['tiles'] if t['p_safe'] is None]
    assert len(nulls) == int((~r.known).sum()) > 0
    assert all(t['x'] % 1.0 == 0.5 for t in back['tiles'])
    assert back['stats']['clouds'] == 4
    assert isinstance(back['landing_sites'], list)


def test_bad_input_is_refused_and_the_map_survives(model_file):
    a = Assessor(small_config(), model=model_file)
    rng = np.random.default_rng(7)
    fly(a, rng, SENSORS[:2], half=2.5)
    hits0, passes0 = a.map.counts()
    with pytest.raises(InvalidCloudError, match='points'):
        a.integrate(np.zeros((10, 2)), (0, 0, 8))
    with pytest.raises(InvalidCloudError, match='origin'):
        a.integrate(np.zeros((10, 3)), (0, np.nan, 8))
    with pytest.raises(InvalidCloudError, match='points'):
        a.integrate(np.array([['a', 'b', 'c']]), (0, 0, 8))
    h, p = a.map.counts()
    assert np.array_equal(h, hits0) and np.array_equal(p, passes0)
    pts = scene_cloud(rng, (0, 0, 8.0), n=100)
    pts[::2] = np.nan
    pts[1::4, 2] = np.inf
    st = a.integrate(pts, (0, 0, 8.0))
    assert st.nonfinite == 75 and st.integrated == 25
    h, p = a.map.counts()
    assert np.all(h >= hits0) and np.all(p >= passes0)


def test_model_problems_are_model_errors(tmp_path, model_file):
    with pytest.raises(ModelError, match='not found'):
        Assessor(small_config(), model=tmp_path / 'missing.safetensors')
    bad = tmp_path / 'bad.safetensors'
    bad.write_bytes(b'not a model at all')
    with pytest.raises(ModelError):
        Assessor(small_config(), model=bad)
    with pytest.raises(ModelError, match='36'):
        Assessor(small_config(), model=make_model(tmp_path / 'wide.safetensors', 36))
    cfg = small_config()
    cfg.map.voxel_size = 0.1
    cfg.tiles.padding = 11  # 10 + 22 = 32 voxels: the right input size, the wrong voxels
    with pytest.raises(ModelError, match='0.05 m voxels'):
        Assessor(cfg, model=model_file)
    cfg = small_config()
    cfg.model.path = str(model_file)
    assert Assessor(cfg).model_path == model_file


def test_default_model_lookup_names_where_it_looked(monkeypatch, tmp_path):
    import landing_zone.assessor as mod

    monkeypatch.setattr(mod, 'MODEL_FILENAME', 'surely-not-there.safetensors')
    with pytest.raises(ModelError, match='surely-not-there'):
        default_model_path()


def test_integration_and_assessment_on_two_threads(model_file):
    rng = np.random.default_rng(8)
    sensors = [(x, y, 8.0) for x in (-1, 0, 1) for y in (-1, 0, 1)]
    clouds = [scene_cloud(rng, s, n=3000, half=2.5) for s in sensors]
    a = Assessor(small_config(), model=model_file)
    done = threading.Event()
    passes = []

    def assess_loop():
        while not done.is_set():
            passes.append(a.assess())

    worker = threading.Thread(target=assess_loop)
    worker.start()
    try:
        for c, s in zip(clouds, sensors):
            a.integrate(c, s)
    finally:
        done.set()
        worker.join()
    final = a.assess()
    b = Assessor(small_config(), model=model_file)
    for c, s in zip(clouds, sensors):
        b.integrate(c, s)
    ref = b.assess()
    assert len(passes) >= 1
    np.testing.assert_array_equal(np.isnan(final.p_safe), np.isnan(ref.p_safe))
    np.testing.assert_allclose(final.p_safe, ref.p_safe, atol=2e-3, equal_nan=True)
