"""The OOD signal: the reference file, the distance, and tiles judged safe made unknown."""
from __future__ import annotations

import shutil

import numpy as np
import pytest

from landing_zone.errors import ModelError
from landing_zone.judging.ood import (FeatureReference, fit_reference, load_reference,
                                      reference_path_for, save_reference, unit_rows)


def clusters(rng, n=400, d=16):
    """Features of two tight clusters (training-like tiles)."""
    centres = rng.normal(size=(2, d))
    return centres[rng.integers(0, 2, n)] + 0.05 * rng.normal(size=(n, d))


def test_the_distance_is_the_kth_neighbours_of_unit_features(rng):
    ref = FeatureReference(unit_rows(rng.normal(size=(50, 8))), 3, 1.0, 99.0, 'x')
    q = rng.normal(size=(7, 8)) * 5.0  # the length of a feature vector does not matter
    brute = np.linalg.norm(unit_rows(q)[:, None] - ref.features[None], axis=2)
    np.testing.assert_allclose(ref.distance(q), np.sort(brute, axis=1)[:, 2], atol=1e-5)
    np.testing.assert_allclose(ref.distance(q, chunk=2), ref.distance(q), atol=1e-6)
    assert ref.distance(np.zeros((0, 8))).shape == (0,)
    with pytest.raises(ModelError, match='holds 8 features per tile'):
        ref.distance(np.zeros((3, 9)))


def test_near_tiles_pass_and_far_ones_do_not(rng):
    x = clusters(rng)
    ref = fit_reference(x[:200], x[200:], 'abc', k=5, quantile=99.0)
    assert len(ref.features) == 200 and ref.threshold > 0
    assert np.allclose(np.linalg.norm(ref.features, axis=1), 1.0, atol=1e-5)
    # the threshold is the held-out tiles' 99th percentile: about 1 % of them lie past it
    assert (ref.ratio(x[200:]) > 1.0).mean() <= 0.02
    near = x[:50] + 0.01 * rng.normal(size=(50, 16))
    far = rng.normal(size=(50, 16))  # random directions, nowhere near the two clusters
    assert (ref.ratio(near) <= 1.0).mean() >= 0.95
    assert (ref.ratio(far) > 1.0).all()
    with pytest.raises(ValueError, match='at least k = 5'):
        fit_reference(x[:3], x[3:], 'abc', k=5)
    with pytest.raises(ValueError, match='quantile'):
        fit_reference(x[:200], x[200:], 'abc', quantile=0.0)


def test_fitting_is_deterministic(rng):
    x = clusters(rng)
    a = fit_reference(x[:200], x[200:], 'abc', k=5)
    b = fit_reference(x[:200].copy(), x[200:].copy(), 'abc', k=5)
    np.testing.assert_array_equal(a.features, b.features)
    assert a.threshold == b.threshold and a.digest == b.digest
    np.testing.assert_array_equal(a.distance(x), b.distance(x))


def test_the_reference_round_trips_and_belongs_to_one_model(rng, tmp_path):
    x = clusters(rng)
    ref = fit_reference(x[:200], x[200:], 'f00d' * 16, k=5, meta={'data': 'test'})
    path = tmp_path / 'net.ood.safetensors'
    save_reference(path, ref)
    back = load_reference(path, 'f00d' * 16, dim=16)
    np.testing.assert_array_equal(back.features, ref.features)
    assert (back.k, back.threshold, back.quantile, back.meta, back.digest) == (
        ref.k, ref.threshold, ref.quantile, {'data': 'test'}, ref.digest)
    with pytest.raises(ModelError, match='fitted for another model'):
        load_reference(path, 'beef' * 16)
    with pytest.raises(ModelError, match='16 features per tile, the model has 128'):
        load_reference(path, 'f00d' * 16, dim=128)
    assert reference_path_for('models/landing_zone.safetensors').name == \
        'landing_zone.ood.safetensors'


def test_bad_files_are_refused_with_one_line(rng, tmp_path):
    from safetensors.numpy import save_file

    with pytest.raises(ModelError, match='OOD reference not found'):
        load_reference(tmp_path / 'none.ood.safetensors', 'a')
    junk = tmp_path / 'junk.ood.safetensors'
    junk.write_bytes(b'\x10\x00\x00\x00\x00\x00\x00\x00{"a": not json}')
    with pytest.raises(ModelError, match='not a readable OOD reference') as err:
        load_reference(junk, 'a')
    assert '\n' not in str(err.value)
    plain = tmp_path / 'plain.safetensors'
    save_file({'features': np.ones((4, 2), np.float32)}, str(plain))
    with pytest.raises(ModelError, match='without OOD reference metadata'):
        load_reference(plain, 'a')
    bad_k = tmp_path / 'k.ood.safetensors'
    save_file({'features': np.ones((4, 2), np.float32)}, str(bad_k), metadata={
        'landing_zone_ood': '{"format": "landing_zone.ood/1", "k": 9, "threshold": 0.1, '
                            '"quantile": 99, "weights_sha256": "a"}'})
    with pytest.raises(ModelError, match='malformed OOD reference'):
        load_reference(bad_k, 'a')
    not_unit = tmp_path / 'unit.ood.safetensors'
    save_file({'features': np.ones((4, 2), np.float32)}, str(not_unit), metadata={
        'landing_zone_ood': '{"format": "landing_zone.ood/1", "k": 2, "threshold": 0.1, '
                            '"quantile": 99, "weights_sha256": "a"}'})
    with pytest.raises(ModelError, match='not of unit length'):
        load_reference(not_unit, 'a')


def test_the_features_come_from_the_same_forward_pass(model_file):
    import torch

    from landing_zone.judging.checkpoint import load_model
    from landing_zone.judging.inference import Predictor

    net, _ = load_model(model_file)
    x = np.random.default_rng(1).uniform(-1, 1, (5, 1, 32, 32, 32)).astype(np.float32)
    with Predictor(net) as predictor:
        p, f = predictor.with_features(x, batch_size=2)
        np.testing.assert_allclose(p, predictor(x), atol=1e-6)
    assert f.shape == (5, net.head.in_features) and f.dtype == np.float32
    with torch.no_grad():
        logits = net.head(torch.from_numpy(f)).squeeze(1).numpy()
    np.testing.assert_allclose(1 / (1 + np.exp(-logits / net.temperature)), p, atol=1e-5)


def fit_for(model, inputs_ref, inputs_held, k=3):
    """A reference of the model for the given input volumes."""
    from landing_zone.judging.checkpoint import load_model, read_metadata
    from landing_zone.judging.inference import Predictor

    net, _ = load_model(model)
    with Predictor(net) as predictor:
        ref = predictor.with_features(inputs_ref)[1]
        held = predictor.with_features(inputs_held)[1]
    save_reference(reference_path_for(model), fit_reference(
        ref, held, read_metadata(model)['weights_sha256'], k=k))


def assess(model, seed=6, **ood):
    from test_assessor import SENSORS, fly, small_config

    from landing_zone.assessor import Assessor

    cfg = small_config()
    for k, v in ood.items():
        setattr(cfg.ood, k, v)
    a = Assessor(cfg, model=model)
    fly(a, np.random.default_rng(seed), SENSORS, half=2.5)
    return a, a.assess()


def map_inputs(model, seed):
    """The valid network inputs of one small flown map (the training-like tiles here)."""
    a, _ = assess(model, seed=seed, enabled=False)
    from landing_zone.judging.tiles import extract_tiles
    b = extract_tiles(a.map, a.config.tiles)
    a.close()
    return b.inputs[b.valid]


def test_tiles_unlike_the_reference_become_unknown_and_typical_ones_do_not(model_file,
                                                                           tmp_path):
    model = tmp_path / 'net.safetensors'
    shutil.copy(model_file, model)
    plain, base = assess(model)
    assert plain.ood is None and base.ood is not None and np.isnan(base.ood).all()
    judged = base.known
    safe = judged & (base.p_safe >= 0.5)
    assert safe.any() and (judged & ~safe).any()

    # a reference of tiles like these (maps of the same scene, other noise): typical
    fit_for(model, np.concatenate([map_inputs(model, s) for s in (1, 2)]), map_inputs(model, 3))
    a, typical = assess(model)
    assert a.ood is not None and a.ood_path == reference_path_for(model)
    assert np.isfinite(typical.ood[judged]).all()
    assert (typical.ood[judged] <= 1.0).mean() >= 0.9
    assert np.isnan(typical.p_safe).sum() <= np.isnan(base.p_safe).sum() + 0.1 * judged.sum()
    np.testing.assert_array_equal(typical.p_net, base.p_net)
    a.close()

    # a reference of inputs nothing like a map's (uniform noise): every judged tile is far
    noise = np.random.default_rng(2).uniform(-1, 1, (90, 1, 32, 32, 32)).astype(np.float32)
    fit_for(model, noise[:60], noise[60:])
    a, r = assess(model)
    assert (r.ood[judged] > 1.0).all()
    assert np.isnan(r.p_safe[safe]).all()  # a "safe" unlike the training data: unknown
    np.testing.assert_array_equal(r.p_safe[judged & ~safe], base.p_safe[judged & ~safe])
    np.testing.assert_array_equal(r.p_net, base.p_net)
    # confidence scaled by threshold / distance
    np.testing.assert_allclose(r.confidence[judged], base.confidence[judged] / r.ood[judged],
                               rtol=1e-5)
    report = r.to_report()
    assert sum(t['p_safe'] is None for t in report['tiles']) == int((~judged | safe).sum())
    reasons = report['reasons']
    assert len(reasons) == int(safe.sum())
    assert all(e['reason'].startswith('unlike the training data: feature distance')
               and e['p_net'] >= 0.5 for e in reasons)
    # the tiles keep the contract's keys (and the ground plane's figures beside them)
    assert not any(set(t) - {'x', 'y', 'ground_z', 'p_safe', 'confidence', 'slope_deg',
                             'roughness', 'clearance'} for t in report['tiles'])
    a.close()
    # the same map and reference: the same bytes
    a2, r2 = assess(model)
    np.testing.assert_array_equal(r2.ood, r.ood)
    np.testing.assert_array_equal(r2.confidence, r.confidence)
    a2.close()
    # switched off, the reference is not even read
    off, r_off = assess(model, enabled=False)
    assert off.ood is None
    np.testing.assert_array_equal(r_off.p_safe, base.p_safe)
    off.close()


def test_a_missing_bad_or_foreign_reference_stops_the_assessor(model_file, tmp_path, rng):
    with pytest.raises(ModelError, match='OOD reference not found'):
        assess(model_file, path=str(tmp_path / 'none.ood.safetensors'))
    x = clusters(rng, d=8)
    other = tmp_path / 'other.ood.safetensors'
    save_reference(other, fit_reference(x[:200], x[200:], '0' * 64, k=3))
    with pytest.raises(ModelError, match='fitted for another model'):
        assess(model_file, path=str(other))
    # beside the model, a broken file is refused too, not skipped
    model = tmp_path / 'net.safetensors'
    shutil.copy(model_file, model)
    reference_path_for(model).write_bytes(b'not a safetensors file')
    with pytest.raises(ModelError, match='not a readable OOD reference'):
        assess(model)


def test_a_net_in_memory_is_checked_by_its_weights(model_file, tmp_path):
    from landing_zone.judging.checkpoint import load_model, read_metadata, weights_sha256

    net, meta = load_model(model_file)
    assert weights_sha256(net) == read_metadata(model_file)['weights_sha256']
    model = tmp_path / 'net.safetensors'
    shutil.copy(model_file, model)
    noise = np.random.default_rng(2).uniform(-1, 1, (20, 1, 32, 32, 32)).astype(np.float32)
    fit_for(model, noise[:10], noise[10:])
    a, _ = assess(net, path=str(reference_path_for(model)))
    assert a.ood is not None
    a.close()


@pytest.mark.slow
def test_fit_ood_gives_the_same_reference_for_a_seed_and_the_assessor_finds_it(
        model_file, tmp_path):
    import subprocess
    import sys

    from landing_zone.judging.checkpoint import read_metadata
    from landing_zone.tools.learn.ood_fit import fit_ood
    from landing_zone.tools.sim.dataset import simulate_dataset

    data = tmp_path / 'data'
    simulate_dataset('synth1', data, scenes=24, workers=1, seed=0, progress=False, split='train')
    model = tmp_path / 'net.safetensors'
    shutil.copy(model_file, model)
    kw = dict(scenes=20, views=2, k=3, seed=4, progress=False)
    fit = fit_ood(model, [data], tmp_path / 'one.ood.safetensors', **kw)
    fit_ood(model, [data], tmp_path / 'two.ood.safetensors', **kw)
    # same model, data and seed: the same bytes (on this machine)
    assert (tmp_path / 'one.ood.safetensors').read_bytes() == \
        (tmp_path / 'two.ood.safetensors').read_bytes()
    assert (fit.scenes, fit.reference_tiles + fit.held_out_tiles) == (20, 40)
    ref = load_reference(fit.path, read_metadata(model)['weights_sha256'])
    assert ref.k == 3 and ref.meta['scenes'] == 20 and ref.meta['held_out_scenes'] == 5
    other = fit_ood(model, [data], tmp_path / 'three.ood.safetensors', **{**kw, 'seed': 5})
    assert other.reference.digest != fit.reference.digest  # another draw

    def cli(*args):
        return subprocess.run([sys.executable, '-m', 'landing_zone', *args],
                              capture_output=True, text=True, timeout=300)

    out = cli('fit-ood', '--model', str(model), '--data', str(data), '--out',
              str(reference_path_for(model)), '--scenes', '20', '--views', '2', '--k', '3',
              '--seed', '4', '--quiet')
    assert out.returncode == 0, out.stderr
    assert 'reference tiles' in out.stdout and 'threshold' in out.stdout
    assert reference_path_for(model).read_bytes() == fit.path.read_bytes()
    a, _ = assess(model)  # found beside the model
    assert a.ood_path == reference_path_for(model)
    a.close()
    # a bad model file on the command line: one line, exit 2, no traceback
    bad = tmp_path / 'bad.safetensors'
    bad.write_bytes(b'junk')
    out = cli('fit-ood', '--model', str(bad), '--data', str(data), '--out',
              str(tmp_path / 'x.ood.safetensors'))
    assert out.returncode == 2 and 'Traceback' not in out.stderr
    assert len(out.stderr.strip().splitlines()) == 1 and 'bad.safetensors' in out.stderr


def test_the_shipped_model_has_its_reference():
    from landing_zone.assessor import default_model_path
    from landing_zone.judging.checkpoint import load_model

    model = default_model_path()
    net, meta = load_model(model)
    ref = load_reference(reference_path_for(model), meta['weights_sha256'],
                         dim=net.head.in_features)
    assert ref.k == 10 and ref.quantile == 99.5 and 0.0 < ref.threshold < 2.0
    assert ref.features.nbytes < 6e6  # shipped files stay well under 10 MB


def test_a_snapshot_restores_tiles_only_under_the_same_reference(model_file, tmp_path):
    from landing_zone.runtime.snapshot import load_snapshot, save_snapshot

    model = tmp_path / 'net.safetensors'
    shutil.copy(model_file, model)
    noise = np.random.default_rng(2).uniform(-1, 1, (30, 1, 32, 32, 32)).astype(np.float32)
    fit_for(model, noise[:20], noise[20:])
    a, r = assess(model)
    path = tmp_path / 'map.snapshot'
    save_snapshot(path, a)
    b, _ = assess(model, seed=7)  # same reference: the tiles and their OOD ratios come back
    assert load_snapshot(path, b)['tiles_restored']
    np.testing.assert_array_equal(b.assess().ood, r.ood)
    c, _ = assess(model, seed=7, enabled=False)  # judged without it: judged again
    assert not load_snapshot(path, c)['tiles_restored']
    for x in (a, b, c):
        x.close()
