"""Evaluation: calibration figures on hand-made probabilities, ROC/AUC, the report files."""
import json
import subprocess
import sys

import numpy as np
import pytest
import torch

from landing_zone.tools.learn.calibration import (binary_nll, expected_calibration_error,
                                                  fit_temperature, reliability)
from landing_zone.errors import ConfigError, DatasetError
from landing_zone.tools.evaluate.methods import evaluate_methods
from landing_zone.tools.evaluate.roc import evaluate_scenes, markdown_table, results_json
from landing_zone.tools.evaluate.figures import class_models, confident_mistakes
from landing_zone.judging.inference import predict
from landing_zone.judging.net import SafetyNet, SafetyNetConfig
from test_train import quick_config, toy_scenes


# --- calibration -------------------------------------------------------------------------------

def test_ece_of_hand_made_probabilities():
    # 10 tiles at 0.1 with 1 safe: calibrated; 10 at 0.9 with 5 safe: off by 0.4
    p = np.array([0.1] * 10 + [0.9] * 10)
    y = np.array([1] + [0] * 9 + [1] * 5 + [0] * 5)
    assert expected_calibration_error(p[:10], y[:10]) == pytest.approx(0.0)
    assert expected_calibration_error(p[10:], y[10:]) == pytest.approx(0.4)
    assert expected_calibration_error(p, y) == pytest.approx(0.2)
    # perfectly confident and right: 0; confident and always wrong: 1
    assert expected_calibration_error([1.0, 0.0], [1, 0]) == 0.0
    assert expected_calibration_error([1.0, 0.0], [0, 1]) == 1.0


def test_reliability_bins():
    p = np.array([0.0, 0.05, 0.5, 0.51, 0.99, 1.0])
    y = np.array([0, 0, 1, 0, 1, 1])
    rel = reliability(p, y, bins=4)
    np.testing.assert_allclose(rel.edges, [0, 0.25, 0.5, 0.75, 1.0])
    assert rel.count.tolist() == [2, 0, 2, 2]  # 0.5 opens bin 2; 1.0 closes the last bin
    np.testing.assert_allclose(rel.confidence[[0, 2, 3]], [0.025, 0.505, 0.995])
    np.testing.assert_allclose(rel.frequency[[0, 2, 3]], [0.0, 0.5, 1.0])
    assert np.isnan(rel.confidence[1]) and np.isnan(rel.frequency[1])
    # ECE = (2 * 0.025 + 2 * 0.005 + 2 * 0.005) / 6
    assert rel.ece == pytest.approx((0.05 + 0.01 + 0.01) / 6)


def test_bad_probabilities_are_refused():
    with pytest.raises(ConfigError, match='lie in'):
        expected_calibration_error([0.5, 1.2], [0, 1])
    with pytest.raises(ConfigError, match='lie in'):
        expected_calibration_error([0.5, np.nan], [0, 1])
    with pytest.raises(ConfigError, match='labels'):
        expected_calibration_error([0.5, 0.5], [0, 2])
    with pytest.raises(ConfigError, match='2 probabilities for 3'):
        expected_calibration_error([0.5, 0.5], [0, 1, 1])


def test_temperature_recovers_the_scale_of_overconfident_logits():
    rng = np.random.default_rng(0)
    z = rng.normal(0.0, 4.0, 20000)
    y = (rng.random(z.size) < 1 / (1 + np.exp(-z / 2.5))).astype(int)  # truth: T = 2.5
    t = fit_temperature(z, y)
    assert t == pytest.approx(2.5, rel=0.06)
    assert binary_nll(z, y, t) < binary_nll(z, y, 1.0)
    assert fit_temperature(z[:5], np.ones(5)) == 1.0  # one class: nothing to fit


# --- ROC / AUC and the tables ------------------------------------------------------------------

class Fixed:
    """A method that returns given scores (and says whether they are probabilities)."""

    def __init__(self, name, scores, probabilistic=None):
        self.name = name
        self._scores = np.asarray(scores, float)
        if probabilistic is not None:
            self.probabilistic = probabilistic

    def score(self, inputs):
        return self._scores[:len(inputs)]


def test_auc_and_ece_of_known_scores():
    y = np.array([1, 1, 1, 0, 0, 0])
    x = np.zeros((6, 1, 4, 4, 4), np.float32)
    res = evaluate_methods([Fixed('perfect', [0.9, 0.8, 0.7, 0.3, 0.2, 0.1]),
                            Fixed('reversed', [0.1, 0.2, 0.3, 0.7, 0.8, 0.9]),
                            Fixed('constant', [0.5] * 6),
                            Fixed('residuals', [-0.1, -0.2, -0.3, -1.0, -2.0, -3.0]),
                            Fixed('ranks', [6, 5, 4, 3, 2, 1], probabilistic=False)], x, y)
    by = {r.name: r for r in res}
    assert by['perfect'].auc == 1.0 and by['reversed'].auc == 0.0
    assert by['constant'].auc == 0.5
    assert by['residuals'].auc == 1.0 and by['residuals'].ece is None  # not probabilities
    assert by['ranks'].ece is None
    # perfect: bins 0.1, 0.2, 0.3 all unsafe, 0.7, 0.8, 0.9 all safe -> mean gap 0.2
    assert by['perfect'].ece == pytest.approx(0.2)
    assert by['perfect'].tpr[-1] == 1.0 and by['perfect'].fpr[-1] == 1.0
    assert all(r.ms_per_volume >= 0 for r in res)
    doc = results_json(res, 'toy', 'test', 6, 3)
    assert set(doc) == {'dataset', 'split', 'n', 'n_unsafe', 'methods'}
    assert doc['methods']['perfect'] == {'auc': 1.0, 'ece': 0.2, 'ms_per_volume':
                                         doc['methods']['perfect']['ms_per_volume']}
    assert doc['methods']['residuals']['ece'] is None
    table = markdown_table(res, 'toy', 'test', 6, 3)
    assert '| perfect | 1.000 | 0.200 |' in table and '| residuals | 1.000 | - |' in table


def test_methods_must_return_one_finite_score_per_volume():
    x = np.zeros((4, 1, 4, 4, 4), np.float32)
    y = np.array([1, 0, 1, 0])
    with pytest.raises(DatasetError, match='returned 3 scores'):
        evaluate_methods([Fixed('short', [1, 2, 3])], x, y)
    with pytest.raises(DatasetError, match='finite: False'):
        evaluate_methods([Fixed('nan', [1, np.nan, 0, 1])], x, y)
    with pytest.raises(DatasetError, match='safe and unsafe'):
        evaluate_methods([Fixed('any', [1, 1, 1, 1])], x, np.ones(4))


def test_confident_mistakes_are_the_worst_first():
    p = np.array([0.9, 0.2, 0.6, 0.4, 0.95, 0.05])
    y = np.array([0, 1, 0, 1, 1, 0])
    fp, fn = confident_mistakes(p, y, k=2)
    assert fp.tolist() == [0, 2]  # unsafe, scored safest first
    assert fn.tolist() == [1, 3]  # safe, scored least safe first


# --- look inside -------------------------------------------------------------------------------

def test_class_models_move_the_score_the_right_way():
    torch.manual_seed(0)
    net = SafetyNet(SafetyNetConfig('C5-F8-P2-D32', dropout=0.0)).eval()
    cm = class_models(net, steps=40)
    safe, unsafe = cm['safe'], cm['unsafe']
    assert safe.shape == (32, 32, 32) and np.abs(safe).max() <= 1.0
    logit = predict(net, np.stack([safe, np.zeros_like(safe), unsafe])[:, None],
                    precision='fp32', logits=True)
    assert logit[0] > logit[1] > logit[2]
    assert all(p.requires_grad for p in net.parameters())


def test_evaluate_writes_the_report(tmp_path):
    from landing_zone.tools.learn.train import train
    model = tmp_path / 'm.safetensors'
    train(toy_scenes(16, seed=1), model, quick_config(), progress=False)
    out = tmp_path / 'eval'
    res = evaluate_scenes(toy_scenes(12, seed=2), 'toy', 'test', model,
                          json_path=tmp_path / 'r.json', out_dir=out,
                          extra_methods=[Fixed('always safe', np.ones(12))],
                          scores_path=tmp_path / 's.json')
    per = json.loads((tmp_path / 's.json').read_text())
    assert per['scenes'] == list(range(12)) and len(per['labels']) == 12
    assert per['methods']['always safe'] == [1.0] * 12
    assert per['labels'] == [int(toy_scenes(12, seed=2)[i].label) for i in range(12)]
    doc = json.loads((tmp_path / 'r.json').read_text())
    assert doc['n'] == 12 and doc['n_unsafe'] == 6 and doc['dataset'] == 'toy'
    assert list(doc['methods']) == ['CNN C5-F8-P2-D32', 'always safe']
    assert doc['methods']['always safe']['auc'] == 0.5
    assert 0.0 <= doc['methods']['CNN C5-F8-P2-D32']['ece'] <= 1.0
    assert res['table'] == (out / 'table.md').read_text()
    for name in ('roc.png', 'reliability.png', 'false_positives.png', 'false_negatives.png',
                 'filters.png', 'class_models.png'):
        assert (out / name).read_bytes()[:4] == b'\x89PNG', name


def test_several_models_share_one_table(tmp_path):
    """Two files of one spec get a row each (told apart by file name), and a model with other
    tiles (less padding: a 28^3 input) is given volumes voxelized its own way."""
    import shutil
    from dataclasses import asdict
    from landing_zone.config import TileConfig
    from landing_zone.judging.checkpoint import save_model
    from landing_zone.tools.learn.train import train
    a = tmp_path / 'a.safetensors'
    train(toy_scenes(16, seed=1), a, quick_config(), progress=False)
    b = tmp_path / 'b.safetensors'
    shutil.copy(a, b)
    c = tmp_path / 'c.safetensors'
    torch.manual_seed(0)
    save_model(c, SafetyNet(SafetyNetConfig('C3-F4-P2-D8', input_size=28)),
               {'voxel_size': 0.05, 'tiles': asdict(TileConfig(padding=4))})
    res = evaluate_scenes(toy_scenes(12, seed=2), 'toy', 'test', [a, b, c],
                          extra_methods=[Fixed('always safe', np.ones(12))])
    m = res['methods']
    assert list(m) == ['CNN C5-F8-P2-D32 (a)', 'CNN C5-F8-P2-D32 (b)', 'CNN C3-F4-P2-D8',
                       'always safe']
    assert m['CNN C5-F8-P2-D32 (a)']['auc'] == m['CNN C5-F8-P2-D32 (b)']['auc']
    assert 0.0 <= m['CNN C3-F4-P2-D8']['auc'] <= 1.0
    assert '| CNN C3-F4-P2-D8 |' in res['table']
    with pytest.raises(ConfigError, match='share the row'):
        evaluate_scenes(toy_scenes(12, seed=2), 'toy', 'test', [a, a])


@pytest.mark.slow
def test_cli_trains_and_evaluates_a_simulated_dataset(tmp_path):
    from landing_zone.tools.sim.dataset import simulate_dataset
    data = tmp_path / 'synth1'
    simulate_dataset('synth1', data, scenes=30, workers=1, seed=0, progress=False)
    model = tmp_path / 'm.safetensors'

    def cli(*args):
        return subprocess.run([sys.executable, '-m', 'landing_zone', *args],
                              capture_output=True, text=True, timeout=300)

    r = cli('train', '--data', str(data), '--data', str(data), '--arch', 'C5-F8-P4-D16',
            '--out', str(model), '--epochs', '1', '--augment-copies', '1', '--val-fraction',
            '0.2')
    assert r.returncode == 0, r.stderr
    from landing_zone.judging.checkpoint import read_metadata
    assert read_metadata(model)['n_train_scenes'] + read_metadata(model)['n_val_scenes'] \
        == 2 * 25  # the train split (25 of 30 scenes) twice
    assert 'wrote' in r.stdout and model.exists()
    r = cli('evaluate', '--data', str(data), '--model', str(model), '--model',
            str(model), '--json', str(tmp_path / 'r.json'))
    assert r.returncode == 2 and 'Traceback' not in r.stderr and 'share the row' in r.stderr
    r = cli('evaluate', '--data', str(data), '--model', str(model), '--json',
            str(tmp_path / 'r.json'))
    assert r.returncode == 0, r.stderr
    doc = json.loads((tmp_path / 'r.json').read_text())
    assert doc['dataset'] == 'synth1' and doc['split'] == 'test' and doc['n'] == 5
    assert '| CNN C5-F8-P4-D16 |' in r.stdout
    r = cli('train', '--data', str(data), '--arch', 'C5-F8-X', '--out', str(model))
    assert r.returncode == 2 and 'Traceback' not in r.stderr
    assert r.stderr.startswith("landing-zone: error: bad token 3 'X'")


def test_temperature_stays_finite_on_perfectly_separated_logits():
    z = np.array([-6.0, -4.0, -3.0, 2.0, 5.0, 7.0])
    y = np.array([0, 0, 0, 1, 1, 1])
    t = fit_temperature(z, y)
    assert 0.05 < t < 1.0  # sharper, but not driven to the bound
    assert fit_temperature(z, y, prior_sigma=None) == pytest.approx(0.05, rel=1e-2)


def test_platt_recovers_temperature_and_offset():
    """Labels drawn from sigmoid(z / 2 - 1) give back T near 2 and b near -1; with b = 0 fixed
    by the data (one class shifted nowhere) the offset stays near 0."""
    from landing_zone.tools.learn.calibration import binary_nll, fit_platt
    rng = np.random.default_rng(3)
    z = rng.normal(0.0, 4.0, 20000)
    y = (rng.random(z.size) < 1.0 / (1.0 + np.exp(-(z / 2.0 - 1.0)))).astype(int)
    t, b = fit_platt(z, y)
    assert t == pytest.approx(2.0, rel=0.06) and b == pytest.approx(-1.0, abs=0.08)
    assert binary_nll(z, y, t, b) < binary_nll(z, y, t, 0.0) < binary_nll(z, y)
    y0 = (rng.random(z.size) < 1.0 / (1.0 + np.exp(-z / 0.5))).astype(int)
    t0, b0 = fit_platt(z, y0)
    assert t0 == pytest.approx(0.5, rel=0.1) and abs(b0) < 0.1
    assert fit_platt(z[:1], y[:1]) == (1.0, 0.0) and fit_platt(z, np.ones_like(y)) == (1.0, 0.0)
