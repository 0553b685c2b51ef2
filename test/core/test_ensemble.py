"""Ensembles of safety CNNs judged as one net: the mean logit, files, the command."""
import json

import numpy as np
import pytest
import torch

from landing_zone.errors import ConfigError, ModelError
from landing_zone.judging.checkpoint import load_model, read_metadata, save_model
from landing_zone.judging.ensemble import SafetyEnsemble
from landing_zone.judging.inference import Predictor, predict
from landing_zone.judging.net import SafetyNet, SafetyNetConfig
from landing_zone.tools.learn.ensembles import assemble

SPEC = 'P2-C5-F8-P2-C3-F8-D16'


def member(seed, spec=SPEC):
    torch.manual_seed(seed)
    return SafetyNet(SafetyNetConfig(spec)).eval()


def volumes(n, seed=0):
    return np.random.default_rng(seed).uniform(-1, 1, (n, 1, 32, 32, 32)).astype(np.float32)


def test_the_logit_is_the_mean_of_the_members_raw_logits():
    nets = [member(s) for s in range(3)]
    for k, n in enumerate(nets):  # the members' own calibrations play no part
        n.temperature, n.offset = 0.5 + k, -1.0
    ens = SafetyEnsemble(nets).eval()
    ens.temperature, ens.offset = 0.8, -0.3
    x = volumes(6)
    with torch.no_grad():
        raw = torch.stack([n(torch.from_numpy(x))[0] for n in nets]).mean(0).numpy()
    np.testing.assert_allclose(predict(ens, x, precision='fp32', logits=True), raw,
                               rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(predict(ens, x, precision='fp32'),
                               1 / (1 + np.exp(-(raw / 0.8 - 0.3))), rtol=1e-5, atol=1e-6)
    assert ens.size == 3 and ens.spec == SPEC and ens.input_pool == 2
    assert ens.flops() == sum(n.flops() for n in nets) + 3


def test_features_are_the_members_side_by_side_and_pooled_inputs_give_the_same_numbers():
    nets = [member(s) for s in range(2)]
    ens = SafetyEnsemble(nets).eval()
    x = volumes(4)
    with Predictor(ens) as p:
        prob, feats = p.with_features(x, precision='fp32')
        pooled = torch.nn.functional.max_pool3d(torch.from_numpy(x), 2).numpy()
        np.testing.assert_allclose(p(pooled, precision='fp32', pooled=True), prob, rtol=1e-5,
                                   atol=1e-6)
    assert feats.shape == (4, 2 * nets[0].head.in_features) == (4, ens.head.in_features)
    with torch.no_grad():
        first = nets[0].embed(torch.from_numpy(x)).numpy()
    np.testing.assert_allclose(feats[:, :first.shape[1]], first, rtol=1e-5, atol=1e-6)


def test_members_of_other_architectures_are_refused():
    with pytest.raises(ConfigError, match='member 1 is P2-C5-F16.*share an architecture'):
        SafetyEnsemble([member(0), member(1, 'P2-C5-F16-P2-C3-F8-D16')])
    with pytest.raises(ConfigError, match='1 to 16 members'):
        SafetyEnsemble([])


def test_an_ensemble_file_round_trips_bit_exactly_and_is_refused_when_damaged(tmp_path):
    ens = SafetyEnsemble([member(s) for s in range(3)]).eval()
    ens.temperature, ens.offset = 0.7, -0.9
    path = tmp_path / 'e.safetensors'
    save_model(path, ens, {'voxel_size': 0.05})
    back, meta = load_model(path)
    assert isinstance(back, SafetyEnsemble) and back.size == 3 and not back.training
    assert meta['ensemble']['members'] == 3
    assert (back.temperature, back.offset) == (0.7, -0.9)
    x = volumes(3)
    np.testing.assert_array_equal(predict(ens, x, precision='fp32'),
                                  predict(back, x, precision='fp32'))
    # the member count is checked, and every member's weights are in the digest
    from safetensors.torch import load_file, save_file
    tensors = load_file(str(path))
    for bad_count in (0, 99, 'three'):
        m = read_metadata(path)
        m['ensemble']['members'] = bad_count
        bad = tmp_path / f'count_{bad_count}.safetensors'
        save_file(tensors, str(bad), metadata={'landing_zone': json.dumps(m)})
        with pytest.raises(ModelError, match='bad architecture.*ensemble.members'):
            load_model(bad)
    tensors['members.2.head.bias'] = tensors['members.2.head.bias'] + 1.0
    bad = tmp_path / 'tampered.safetensors'
    save_file(tensors, str(bad), metadata={'landing_zone': json.dumps(read_metadata(path))})
    with pytest.raises(ModelError, match='SHA-256 differs'):
        load_model(bad)


def _trained_member(path, seed, hold_out):
    save_model(path, member(seed), {'voxel_size': 0.05, 'tiles': {'tile_size': 1.0},
                                    'training': {'hold_out': hold_out, 'seed': seed}})


def test_assemble_records_its_members_and_what_none_of_them_saw(tmp_path):
    paths = [tmp_path / f'm{k}.safetensors' for k in range(3)]
    _trained_member(paths[0], 0, [])
    _trained_member(paths[1], 1, ['obstacle:coil', 'obstacle:log', 'vegetation:bare'])
    _trained_member(paths[2], 2, ['obstacle:coil', 'vegetation:bare'])
    meta = assemble(paths[1:], tmp_path / 'e.safetensors')
    assert meta['training']['hold_out'] == ['obstacle:coil', 'vegetation:bare']
    assert [m['file'] for m in meta['ensemble']['member_files']] == ['m1.safetensors',
                                                                     'm2.safetensors']
    assert (meta['temperature'], meta['calibration_offset']) == (1.0, 0.0)
    assert 'calibration' not in meta  # nothing fitted yet: lofo_calibrated.py refuses to copy it
    assert assemble(paths, tmp_path / 'all.safetensors')['training']['hold_out'] == []
    net, _ = load_model(tmp_path / 'e.safetensors')
    x = volumes(2)
    raw = np.mean([predict(load_model(p)[0], x, logits=True) for p in paths[1:]], axis=0)
    np.testing.assert_allclose(predict(net, x, logits=True), raw, rtol=1e-5, atol=1e-6)


def test_assemble_refuses_what_cannot_be_one_ensemble(tmp_path):
    a, b, c = (tmp_path / f'{n}.safetensors' for n in 'abc')
    _trained_member(a, 0, [])
    save_model(b, member(1), {'voxel_size': 0.1, 'tiles': {'tile_size': 1.0}})
    with pytest.raises(ConfigError, match='at least two'):
        assemble([a], tmp_path / 'e.safetensors')
    with pytest.raises(ConfigError, match='other inputs'):
        assemble([a, b], tmp_path / 'e.safetensors')
    assemble([a, a], c)
    with pytest.raises(ConfigError, match='an ensemble itself'):
        assemble([a, c], tmp_path / 'e.safetensors')


def test_the_ensemble_command_writes_one_file_or_says_what_is_wrong_in_one_line(tmp_path):
    import subprocess
    import sys

    def run(*args):
        return subprocess.run([sys.executable, '-m', 'landing_zone', 'ensemble', *args],
                              capture_output=True, text=True, timeout=120)

    a, b = tmp_path / 'a.safetensors', tmp_path / 'b.safetensors'
    _trained_member(a, 0, ['obstacle:coil'])
    _trained_member(b, 1, ['obstacle:coil', 'obstacle:log'])
    out = tmp_path / 'e.safetensors'
    res = run('--member', str(a), '--member', str(b), '--out', str(out))
    assert res.returncode == 0, res.stderr
    assert 'wrote' in res.stdout and 'no member trained on: obstacle:coil' in res.stdout
    assert isinstance(load_model(out)[0], SafetyEnsemble)
    res = run('--member', str(a), '--member', str(tmp_path / 'missing.safetensors'),
              '--out', str(out))
    assert res.returncode == 2 and 'Traceback' not in res.stderr
    assert res.stderr.strip().splitlines() == [
        f'landing-zone: error: model file not found: {tmp_path / "missing.safetensors"}']


def test_the_assessor_judges_with_an_ensemble_file_as_with_one_net(tmp_path):
    from test_assessor import SENSORS, fly, make_model, small_config

    from landing_zone.assessor import Assessor
    from landing_zone.judging.tiles import extract_tiles

    members = [make_model(tmp_path / f'm{k}.safetensors', seed=k) for k in range(2)]
    out = tmp_path / 'e.safetensors'
    assemble(members, out)
    a = Assessor(small_config(), model=out)
    assert isinstance(a.model, SafetyEnsemble)
    fly(a, np.random.default_rng(3), SENSORS, half=2.5)
    r = a.assess()
    known = r.known
    assert 0 < known.sum() < 64
    batch = extract_tiles(a.map, a.config.tiles, r.index)
    x = batch.inputs[batch.valid]
    raw = np.mean([predict(load_model(m)[0], x, logits=True) for m in members], axis=0)
    np.testing.assert_allclose(r.p_safe[known], 1 / (1 + np.exp(-raw)), atol=1e-5)
    a.close()
