"""The safety CNN: spec parsing, shapes, checkpoints, inference."""
import json

import numpy as np
import pytest
import torch

from landing_zone.errors import ConfigError, ModelError
from landing_zone.judging.checkpoint import load_model, read_metadata, save_model
from landing_zone.judging.inference import predict
from landing_zone.judging.net import PAPER_SPEC, SafetyNet, SafetyNetConfig
from landing_zone.judging.spec import Layer, format_spec, parse_spec

SMALL = 'C5-F8-P2-D32'


def small_net(spec=SMALL, seed=0, dropout=0.5):
    torch.manual_seed(seed)
    return SafetyNet(SafetyNetConfig(spec, dropout=dropout))


def volumes(n, seed=0):
    return np.random.default_rng(seed).uniform(-1, 1, (n, 1, 32, 32, 32)).astype(np.float32)


# --- the spec ----------------------------------------------------------------------------------

@pytest.mark.parametrize('spec', [PAPER_SPEC, 'C7-F64-P4-D512', SMALL, 'C3-F32-P1-D128',
                                  'D64', 'P2-C3-F16-D64-D32', 'C3-F8-C3-F8-P4-D16',
                                  'S2-F4-C5-F32-P2-C3-F64-D128'])
def test_spec_round_trips(spec):
    assert format_spec(parse_spec(spec, 32)) == spec
    assert SafetyNet(SafetyNetConfig(spec)).spec == spec


def test_spec_parses_into_layers():
    assert parse_spec(PAPER_SPEC) == [Layer('conv', 7, 32), Layer('pool', 2),
                                      Layer('conv', 5, 64), Layer('pool', 2),
                                      Layer('dense', 512)]


@pytest.mark.parametrize('spec,match', [
    ('', 'non-empty'),
    ('C7', 'lacks its filter count'),
    ('C7-P2-D8', "token 2 'P2'.*followed by its filter count"),
    ('F32-D8', "token 1 'F32'.*must follow a convolution"),
    ('C7-F32-X2', "token 3 'X2'"),
    ('C0-F8', "token 1 'C0'"),
    ('c7-f32', "token 1 'c7'"),
    ('C7-F32--D8', "token 3 ''"),
    ('D512-C3-F8', "token 2 'C3'.*before dense"),
    ('D512-P2', "token 2 'P2'.*before dense"),
    ('C5-F99999', "token 2 'F99999'.*at most"),
    ('S2-P2-D8', "token 2 'P2'.*S2 must be followed by its filter count"),
    ('D8-S2-F4', "token 2 'S2'.*before dense"),
])
def test_bad_specs_name_the_bad_token(spec, match):
    with pytest.raises(ConfigError, match=match):
        parse_spec(spec)


def test_a_spec_that_shrinks_the_input_to_nothing_is_refused():
    with pytest.raises(ConfigError, match="token 7 'C9'.*shrinks the 32"):
        parse_spec('C9-F8-C9-F8-C9-F8-C9-F8-D8', 32)
    with pytest.raises(ConfigError, match="token 3 'P64'"):
        SafetyNet(SafetyNetConfig('C3-F8-P64-D8'))


# --- the net -----------------------------------------------------------------------------------

def test_paper_net_shapes_and_cost():
    net = SafetyNet(SafetyNetConfig(PAPER_SPEC))
    # 32 -> C7 26 -> P2 13 -> C5 9 -> P2 4: 64 * 4^3 = 4096 features into D512
    assert net.dense[0].fc.in_features == 4096
    assert net.features[0].conv.weight.shape == (32, 1, 7, 7, 7)
    macs = 26 ** 3 * 32 * 343 + 9 ** 3 * 64 * 32 * 125 + 4096 * 512 + 512
    assert net.flops() == macs
    logits, loss = net.eval()(torch.zeros(3, 1, 32, 32, 32), torch.ones(3))
    assert logits.shape == (3,) and loss.ndim == 0


def test_a_strided_convolution_halves_the_side_from_all_eight_voxels_of_a_block():
    torch.manual_seed(0)
    net = SafetyNet(SafetyNetConfig('S2-F4-C5-F32-P2-C3-F64-D128')).eval()
    conv = net.features[0].conv
    assert conv.stride == (2, 2, 2) and conv.weight.shape == (4, 1, 2, 2, 2)
    # it stands where a pool would: no dropout after it (there is after a stride-1 one)
    assert isinstance(net.features[0].drop, torch.nn.Identity)
    assert isinstance(net.features[1].drop, torch.nn.Dropout)
    # 32 -> S2 16 -> C5 12 -> P2 6 -> C3 4: the shipped net's 64 * 4^3 features into D128
    assert net.dense[0].fc.in_features == 4096 and net.input_pool == 1
    assert net.flops() == (16 ** 3 * 4 * 8 + 12 ** 3 * 32 * 4 * 125 + 4 ** 3 * 64 * 32 * 27
                           + 4096 * 128 + 128)
    # two cubes whose 2^3 blocks hold the same maximum, arranged otherwise: the pool sees
    # the same thing, the strided convolution does not
    a = -torch.ones(1, 1, 32, 32, 32)
    b = a.clone()
    a[0, 0, 10, 10, 10] = 1.0  # one voxel of the block at (5, 5, 5)
    b[0, 0, 10:12, 10:12, 10] = 1.0  # a 2 x 2 layer of it
    pool = torch.nn.functional.max_pool3d
    assert torch.equal(pool(a, 2), pool(b, 2))
    assert not torch.equal(conv(a)[..., 5, 5, 5], conv(b)[..., 5, 5, 5])


def test_dropout_only_in_training():
    net = small_net(dropout=0.5)
    x = torch.from_numpy(volumes(4))
    net.train()
    a, _ = net(x)
    b, _ = net(x)
    assert not torch.equal(a, b)
    net.eval()
    assert torch.equal(net(x)[0], net(x)[0])
    assert not any(isinstance(m, torch.nn.Dropout) for m in small_net(dropout=0.0).modules())


# --- checkpoints -------------------------------------------------------------------------------

def test_save_load_round_trips_bit_exactly(tmp_path):
    net = small_net().eval()
    net.temperature = 1.7
    path = tmp_path / 'm.safetensors'
    save_model(path, net, {'voxel_size': 0.05, 'metrics': {'auc': 0.9}, 'seed': 3})
    loaded, meta = load_model(path)
    assert not loaded.training
    assert loaded.spec == SMALL and loaded.temperature == 1.7
    assert meta['voxel_size'] == 0.05 and meta['metrics'] == {'auc': 0.9} and meta['seed'] == 3
    for (k, v), (k2, v2) in zip(net.state_dict().items(), loaded.state_dict().items()):
        assert k == k2 and torch.equal(v, v2)
    x = volumes(5)
    np.testing.assert_array_equal(predict(net, x, precision='fp32'),
                                  predict(loaded, x, precision='fp32'))
    assert read_metadata(path)['model']['spec'] == SMALL


def test_weights_of_another_architecture_are_refused(tmp_path):
    from safetensors.torch import save_file
    path = tmp_path / 'm.safetensors'
    save_model(path, small_net())
    meta = read_metadata(path)
    other = small_net('C5-F16-P2-D32')
    meta['model']['spec'] = SMALL  # a file that claims SMALL but holds C5-F16 weights
    save_file({k: v.contiguous() for k, v in other.state_dict().items()}, str(path),
              metadata={'landing_zone': json.dumps(meta)})
    with pytest.raises(ModelError, match="do not match architecture C5-F8-P2-D32.*shape"):
        load_model(path)


def test_corrupt_files_are_refused_with_one_line(tmp_path):
    path = tmp_path / 'm.safetensors'
    save_model(path, small_net())
    data = bytearray(path.read_bytes())
    flipped = tmp_path / 'flipped.safetensors'
    flipped.write_bytes(bytes(data[:-100]) + bytes(b ^ 0xFF for b in data[-100:]))
    truncated = tmp_path / 'truncated.safetensors'
    truncated.write_bytes(bytes(data[:len(data) // 2]))
    text = tmp_path / 'text.safetensors'
    text.write_text('not a model\n')
    for bad, match in [(flipped, 'corrupt'), (truncated, 'not a readable'),
                       (text, 'not a readable'), (tmp_path / 'missing.safetensors',
                                                  'not found')]:
        with pytest.raises(ModelError, match=match) as info:
            load_model(bad)
        assert '\n' not in str(info.value)


def test_metadata_must_be_json(tmp_path):
    path = tmp_path / 'm.safetensors'
    with pytest.raises(ModelError, match='JSON'):
        save_model(path, small_net(), {'bad': object()})
    assert not path.exists()


# --- inference ---------------------------------------------------------------------------------

def test_predict_gives_calibrated_probabilities():
    net = small_net().eval()
    x = volumes(7)
    logits = predict(net, x, precision='fp32', logits=True)
    with torch.no_grad():
        ref, _ = net(torch.from_numpy(x))
    np.testing.assert_allclose(logits, ref.numpy(), rtol=1e-4, atol=1e-5)
    net.temperature = 2.0
    p = predict(net, x, precision='fp32', batch_size=3)
    np.testing.assert_allclose(p, 1 / (1 + np.exp(-ref.numpy() / 2.0)), rtol=1e-4, atol=1e-6)
    assert p.dtype == np.float32 and p.shape == (7,)
    # (T, S, S, S) works too
    np.testing.assert_array_equal(predict(net, x[:, 0], precision='fp32', batch_size=3), p)


def test_bf16_agrees_with_fp32():
    net = small_net().eval()
    x = volumes(6)
    p32 = predict(net, x, precision='fp32')
    p16 = predict(net, x, precision='bf16')
    assert np.max(np.abs(p32 - p16)) < 0.02


def test_predict_follows_weight_updates():
    net = small_net().eval()
    x = volumes(2)
    before = predict(net, x, precision='fp32', logits=True)
    with torch.no_grad():
        net.head.bias += 1.0
    after = predict(net, x, precision='fp32', logits=True)
    np.testing.assert_allclose(after - before, 1.0, rtol=1e-5)


def test_inference_pools_before_the_relu_and_takes_pooled_inputs_with_the_same_numbers():
    """Eval mode pools a convolution's output before its ReLU (exact: ReLU is monotone), and
    a net that opens with a pool takes its inputs pooled already (the assessor's tiler pools
    them): the logits and features are those of the layers run one by one."""
    torch.manual_seed(3)
    net = SafetyNet(SafetyNetConfig('P2-C5-F8-P2-C3-F8-D16')).eval()
    assert net.input_pool == 2 and small_net().input_pool == 1
    x = torch.from_numpy(volumes(5, seed=1))
    with torch.no_grad():
        step = x
        for block in net.features:  # conv, ReLU, (dropout: identity), pool, in that order
            step = block(step)
        ref = net.dense(step.reshape(5, -1))
        pooled = torch.nn.functional.max_pool3d(x, 2)
        assert torch.equal(net.embed(x), ref)
        assert torch.equal(net.embed(pooled, pooled=True), ref)
    p_full = predict(net, x.numpy(), precision='fp32', logits=True)
    p_pooled = predict(net, pooled.numpy(), precision='fp32', logits=True, pooled=True)
    np.testing.assert_array_equal(p_pooled, p_full)
    with pytest.raises(ConfigError, match=r'\(T, 1, 16, 16, 16\)'):
        predict(net, x.numpy(), pooled=True)
    with pytest.raises(ConfigError, match='does not open with a pool'):
        predict(small_net(), pooled.numpy(), pooled=True)


def test_predict_rejects_bad_inputs():
    net = small_net()
    x = volumes(2)
    x[0, 0, 1, 2, 3] = np.nan
    with pytest.raises(ConfigError, match='NaN'):
        predict(net, x)
    with pytest.raises(ConfigError, match=r'\(T, 1, 32, 32, 32\)'):
        predict(net, np.zeros((2, 1, 16, 16, 16), np.float32))
    with pytest.raises(ConfigError, match='precision'):
        predict(net, volumes(1), precision='fp8')
    assert predict(net, np.zeros((0, 1, 32, 32, 32), np.float32)).shape == (0,)


# --- the files: the safetensors package, and the models shipped in models/ ----------------------

def test_shipped_models_load_unchanged_with_their_metadata():
    from pathlib import Path
    models = Path(__file__).resolve().parents[2] / 'models'
    x = volumes(2)
    # NAME.ood.safetensors beside a model is its OOD reference, not a model (test_ood)
    for path in sorted(p for p in models.glob('*.safetensors')
                       if not p.name.endswith('.ood.safetensors')):
        net, meta = load_model(path)
        assert meta['format'] == 'landing_zone.safety_net/1' and meta['model']['spec'] == net.spec
        assert net.temperature > 0
        if path.name != 'landing_zone.safetensors':
            assert net.spec in path.name
        assert predict(net, x).shape == (2,)


def test_damaged_files_are_refused(tmp_path):
    path = tmp_path / 'm.safetensors'
    save_model(path, small_net())
    data = path.read_bytes()
    cases = {'short': data[:5], 'truncated': data[:-8], 'trailing': data + b'\0' * 8,
             'header': (10 ** 9).to_bytes(8, 'little') + data[8:]}
    for name, blob in cases.items():
        bad = tmp_path / f'{name}.safetensors'
        bad.write_bytes(blob)
        with pytest.raises(ModelError, match='not a readable safetensors model'):
            load_model(bad)
