"""Training: it learns, it is deterministic, it resumes exactly, it refuses what it cannot do."""
import csv

import numpy as np
import pytest
import torch

from landing_zone.config import MapConfig, TileConfig
from landing_zone.errors import ConfigError, DatasetError, ModelError
from landing_zone.judging.checkpoint import load_model, read_metadata, save_model
from landing_zone.judging.inference import predict
from landing_zone.judging.net import SafetyNet, SafetyNetConfig
from landing_zone.tools.sim.shards import Scene
from landing_zone.judging.patches import scene_to_input
from landing_zone.tools.learn.samples import AugmentedVolumes, EpochSampler, cut_context, voxelize
from landing_zone.tools.learn.scenes import ScenePack, split_scenes
from landing_zone.tools.learn.state import log_path, state_path
from landing_zone.tools.learn.fitting import roc_auc
from landing_zone.tools.learn.train import TrainConfig, train

SMALL = 'C5-F8-P2-D32'


def toy_scene(rng, unsafe, n=4000):
    """A LiDAR patch over flat ground, seen from a sensor 5-7 m back and 3.5-5 m up, with an
    axis-aligned box (16-30 cm wide, 15-30 cm tall) near the tile centre when ``unsafe``.

    Returns are the first intersection of each ray with the ground or the box (slab method).
    """
    sensor = np.array([rng.uniform(-7, -5), rng.uniform(-1, 1), rng.uniform(3.5, 5.0)])
    target = np.column_stack([rng.uniform(-1.5, 1.5, n), rng.uniform(-1.5, 1.5, n),
                              rng.normal(0.0, 0.01, n)])
    d = target - sensor
    t = np.ones(n)
    params = {'obstacle': None}
    if unsafe:
        half = rng.uniform(0.08, 0.15, 2)
        height = rng.uniform(0.15, 0.3)
        c = rng.uniform(-0.25, 0.25, 2)
        lo = np.array([c[0] - half[0], c[1] - half[1], -0.05])
        hi = np.array([c[0] + half[0], c[1] + half[1], height])
        with np.errstate(divide='ignore', invalid='ignore'):
            t0, t1 = (lo - sensor) / d, (hi - sensor) / d
        t_in = np.minimum(t0, t1).max(axis=1)
        t_out = np.maximum(t0, t1).min(axis=1)
        hit = (t_in <= t_out) & (t_in > 0) & (t_in < 1)
        t[hit] = t_in[hit]
        params = {'obstacle': {'kind': 'box', 'x': float(c[0]), 'y': float(c[1]), 'z': 0.0,
                               'yaw': 0.0, 'size': [float(2 * half[0]), float(2 * half[1]),
                                                    float(height)]}}
    pts = sensor + t[:, None] * d
    return Scene(pts.astype(np.float32), np.broadcast_to(sensor, pts.shape).astype(np.float32),
                 0 if unsafe else 1, params)


def toy_scenes(n, seed):
    """``n`` scenes alternating unsafe (box) and safe (open ground)."""
    rng = np.random.default_rng(seed)
    return [toy_scene(rng, i % 2 == 0) for i in range(n)]


def quick_config(**kw):
    base = dict(arch=SMALL, epochs=1, augment_copies=2, val_fraction=0.25, dropout=0.0,
                checkpoint_minutes=0.0)
    base.update(kw)
    return TrainConfig(**base)


def weights(path):
    model, _ = load_model(path)
    return {k: v.clone() for k, v in model.state_dict().items()}


def same_weights(a, b):
    return a.keys() == b.keys() and all(torch.equal(a[k], b[k]) for k in a)


# --- it learns ---------------------------------------------------------------------------------

@pytest.mark.slow
def test_a_short_training_separates_boxes_from_open_ground(tmp_path):
    out = tmp_path / 'm.safetensors'
    summary = train(toy_scenes(80, seed=1), out,
                    quick_config(epochs=3, augment_copies=4, val_fraction=0.2),
                    progress=False)
    model, meta = load_model(out)
    # held-out scenes, never seen in training or validation
    test = ScenePack.from_scenes(toy_scenes(40, seed=2))
    x, y = voxelize(test, MapConfig(), TileConfig())
    auc = roc_auc(y.numpy(), predict(model, x))
    assert auc > 0.8, f'AUC {auc:.3f} on held-out scenes'
    # the file knows what it is
    assert meta['model']['spec'] == SMALL and meta['training']['epochs'] == 3
    assert meta['voxel_size'] == 0.05 and meta['tiles']['padding'] == 6
    assert meta['metrics']['samples'] == 3 * 64 * 4
    assert 0 < summary['temperature'] == model.temperature
    with open(log_path(out), newline='') as f:
        rows = list(csv.DictReader(f))
    assert [int(r['epoch']) for r in rows] == [1, 2, 3]
    assert all(float(r['train_loss']) > 0 for r in rows)
    assert state_path(out).exists()


# --- determinism and resuming ------------------------------------------------------------------

def test_same_seed_same_model_other_seed_other_model(tmp_path):
    scenes = toy_scenes(12, seed=3)
    cfg = quick_config(dropout=0.5)
    train(scenes, tmp_path / 'a.safetensors', cfg, progress=False)
    train(scenes, tmp_path / 'b.safetensors', cfg, progress=False)
    train(scenes, tmp_path / 'c.safetensors', quick_config(dropout=0.5, seed=1), progress=False)
    assert same_weights(weights(tmp_path / 'a.safetensors'), weights(tmp_path / 'b.safetensors'))
    assert not same_weights(weights(tmp_path / 'a.safetensors'),
                            weights(tmp_path / 'c.safetensors'))


def test_resume_after_an_epoch_continues_exactly(tmp_path):
    scenes = toy_scenes(12, seed=4)
    train(scenes, tmp_path / 'full.safetensors', quick_config(epochs=2, dropout=0.5),
          progress=False)
    part = tmp_path / 'part.safetensors'
    train(scenes, part, quick_config(epochs=1, dropout=0.5), progress=False)
    train(scenes, part, quick_config(epochs=2, dropout=0.5), resume=True, progress=False)
    assert same_weights(weights(tmp_path / 'full.safetensors'), weights(part))
    with open(log_path(part), newline='') as f:
        assert [int(r['epoch']) for r in csv.DictReader(f)] == [1, 2]


def killed_run(monkeypatch, scenes, out, samples, cfg):
    """Train ``out`` with ``cfg`` until the data loader has drawn ``samples`` augmented
    samples, then die as an interrupted process would (the training state stays)."""
    calls = {'n': 0}
    original = AugmentedVolumes.__getitem__

    def dying(self, key):
        if self.augment:
            calls['n'] += 1
            if calls['n'] > samples:
                raise KeyboardInterrupt
        return original(self, key)

    monkeypatch.setattr(AugmentedVolumes, '__getitem__', dying)
    with pytest.raises(KeyboardInterrupt):
        train(scenes, out, cfg, progress=False)
    monkeypatch.setattr(AugmentedVolumes, '__getitem__', original)


def test_resume_within_an_epoch_continues_exactly(tmp_path, monkeypatch):
    scenes = toy_scenes(16, seed=5)
    cfg = quick_config(epochs=1, batch_size=4, dropout=0.5)
    train(scenes, tmp_path / 'full.safetensors', cfg, progress=False)
    # the same run, killed at the 5th batch; the state is saved after every batch
    part = tmp_path / 'part.safetensors'
    killed_run(monkeypatch, scenes, part, 4 * 4, quick_config(
        epochs=1, batch_size=4, dropout=0.5, checkpoint_minutes=1e-9))
    assert not part.exists() and state_path(part).exists()
    train(scenes, part, cfg, resume=True, progress=False)
    assert same_weights(weights(tmp_path / 'full.safetensors'), weights(part))


def test_the_cosine_schedule_is_its_own_run_and_resumes_exactly(tmp_path, monkeypatch):
    scenes = toy_scenes(16, seed=5)
    cfg = quick_config(epochs=2, batch_size=4, dropout=0.5, lr_schedule='cosine')
    full = tmp_path / 'full.safetensors'
    train(scenes, full, cfg, progress=False)
    train(scenes, tmp_path / 'flat.safetensors', quick_config(epochs=2, batch_size=4,
                                                              dropout=0.5), progress=False)
    assert not same_weights(weights(full), weights(tmp_path / 'flat.safetensors'))
    part = tmp_path / 'part.safetensors'
    killed_run(monkeypatch, scenes, part, 4 * 5, quick_config(
        epochs=2, batch_size=4, dropout=0.5, lr_schedule='cosine', checkpoint_minutes=1e-9))
    with pytest.raises(ConfigError, match='--resume: epochs was 2'):
        train(scenes, part, quick_config(epochs=3, batch_size=4, dropout=0.5,
                                         lr_schedule='cosine'), resume=True, progress=False)
    train(scenes, part, cfg, resume=True, progress=False)
    assert same_weights(weights(full), weights(part))
    with pytest.raises(ConfigError, match="lr_schedule must be 'constant' or 'cosine'"):
        quick_config(lr_schedule='step').validate()


def test_resume_with_other_settings_is_refused(tmp_path):
    scenes = toy_scenes(8, seed=6)
    out = tmp_path / 'm.safetensors'
    train(scenes, out, quick_config(), progress=False)
    with pytest.raises(ConfigError, match='--resume: lr was 0.01'):
        train(scenes, out, quick_config(epochs=2, lr=0.02), resume=True, progress=False)


def test_init_must_match_the_architecture(tmp_path):
    other = tmp_path / 'other.safetensors'
    save_model(other, SafetyNet(SafetyNetConfig('C3-F4-P4-D8')))
    with pytest.raises(ModelError, match='--init model .* is C3-F4-P4-D8'):
        train(toy_scenes(8, seed=7), tmp_path / 'm.safetensors', quick_config(), init=other,
              progress=False)


def calibrated_start(tmp_path, scenes):
    """A toy model with an out-of-family calibration (as landing-zone calibrate leaves it)."""
    start = tmp_path / 'start.safetensors'
    train(scenes, start, quick_config(), progress=False)
    net, meta = load_model(start)
    net.temperature, net.offset = 0.8, -0.5
    save_model(start, net, meta)
    return start


def test_fine_tuning_keeps_the_initial_calibration_anchored(tmp_path):
    scenes = toy_scenes(12, seed=10)
    start = calibrated_start(tmp_path, scenes)
    out = tmp_path / 'site.safetensors'
    s = train(scenes, out, quick_config(lr=0.001), init=start, progress=False)
    net, meta = load_model(out)
    assert s['calibration'] == 'anchored' and meta['calibration']['method'] == 'anchored'
    assert net.temperature == pytest.approx(0.8) and net.offset <= -0.5
    assert meta['calibration']['initial_model'] == str(start)
    refit = train(scenes, tmp_path / 'r.safetensors', quick_config(lr=0.001, calibration='refit'),
                  init=start, progress=False)
    assert refit['offset'] == 0.0
    assert 'calibration' not in read_metadata(tmp_path / 'r.safetensors')


def test_the_anchor_also_holds_on_anchor_sets_never_trained_on(tmp_path):
    scenes = toy_scenes(12, seed=10)
    start = calibrated_start(tmp_path, scenes)
    out = tmp_path / 'site.safetensors'
    anchor_scenes = toy_scenes(10, seed=21)
    train(scenes, out, quick_config(lr=0.001), init=start, progress=False,
          anchor_data=[anchor_scenes])
    net, meta = load_model(out)
    cal = meta['calibration']
    assert 'anchor set' in cal['fitted_on']
    groups = {e['source']: e for e in cal['groups']}
    assert set(groups) == {'list'}  # a scene sequence is named by its type
    held = [e for e in cal['groups'] if e['group'] == 1]
    assert len(held) == 1 and held[0]['obstacles'] == sum(s.label == 0 for s in anchor_scenes)
    for e in cal['groups']:
        assert net.offset <= e['offset_limit']
        for t in ('0.5', '0.9'):
            assert e['passed'][t]['anchored'] <= e['passed'][t]['initial']
    assert net.offset == min([-0.5] + [e['offset_limit'] for e in cal['groups']])


def test_anchor_data_must_be_held_out_and_need_the_anchored_calibration(tmp_path):
    scenes = toy_scenes(8, seed=10)
    with pytest.raises(ConfigError, match='anchored calibration'):
        train(scenes, tmp_path / 'm.safetensors', quick_config(), progress=False,
              anchor_data=[toy_scenes(4, seed=3)])
    d = tmp_path / 'synth3_some'
    with pytest.raises(ConfigError, match='both training data and anchor data'):
        train([d, tmp_path / 'hybrid'], tmp_path / 'm.safetensors', quick_config(),
              init=tmp_path / 'start.safetensors', anchor_data=[d], progress=False)


def test_an_ensemble_is_fine_tuned_as_one_net_and_stays_an_ensemble(tmp_path):
    from landing_zone.judging.ensemble import SafetyEnsemble
    from landing_zone.tools.learn.ensembles import assemble
    scenes = toy_scenes(12, seed=13)
    a, b = tmp_path / 'a.safetensors', tmp_path / 'b.safetensors'
    train(scenes, a, quick_config(seed=0), progress=False)
    train(scenes, b, quick_config(seed=1), progress=False)
    ens = tmp_path / 'e.safetensors'
    assemble([a, b], ens)
    start, meta = load_model(ens)
    start.temperature, start.offset = 0.9, -0.4
    save_model(ens, start, meta)
    out = tmp_path / 'site.safetensors'
    train(scenes, out, quick_config(lr=0.001), init=ens, progress=False)
    tuned, tmeta = load_model(out)
    assert isinstance(tuned, SafetyEnsemble) and tuned.size == 2
    assert tmeta['calibration']['method'] == 'anchored' and tuned.temperature == pytest.approx(0.9)
    # every member moved
    for k in range(2):
        before = start.members[k].state_dict()
        after = tuned.members[k].state_dict()
        assert any(not torch.equal(before[n], after[n]) for n in before)


def test_the_leniency_penalty_acts_only_when_fine_tuning(tmp_path):
    scenes = toy_scenes(12, seed=11)
    start = calibrated_start(tmp_path, scenes)
    # at the first batch the net is the initial one (no penalty); from the second on it is not
    train(scenes, tmp_path / 'a.safetensors', quick_config(batch_size=4), init=start,
          progress=False)
    train(scenes, tmp_path / 'b.safetensors', quick_config(batch_size=4, leniency_penalty=0.0),
          init=start, progress=False)
    assert not same_weights(weights(tmp_path / 'a.safetensors'),
                            weights(tmp_path / 'b.safetensors'))
    # from scratch there is no initial net to compare with: the weight changes nothing
    train(scenes, tmp_path / 'c.safetensors', quick_config(), progress=False)
    train(scenes, tmp_path / 'd.safetensors', quick_config(leniency_penalty=3.0), progress=False)
    assert same_weights(weights(tmp_path / 'c.safetensors'), weights(tmp_path / 'd.safetensors'))


def test_a_anchored_calibration_needs_an_initial_model(tmp_path):
    with pytest.raises(ConfigError, match='--init'):
        train(toy_scenes(8, seed=12), tmp_path / 'm.safetensors',
              quick_config(calibration='anchored'), progress=False)
    with pytest.raises(ConfigError, match='calibration must be'):
        quick_config(calibration='platt').validate()


@pytest.mark.slow
def test_workers_and_voxel_cache_give_what_the_training_process_would(tmp_path):
    scenes = toy_scenes(10, seed=8)
    train(scenes, tmp_path / 'a.safetensors', quick_config(), progress=False)
    train(scenes, tmp_path / 'b.safetensors', quick_config(workers=1), progress=False)
    assert same_weights(weights(tmp_path / 'a.safetensors'), weights(tmp_path / 'b.safetensors'))
    summary = train(scenes, tmp_path / 'c.safetensors', quick_config(cache_voxels=2),
                    progress=False)
    assert summary['samples'] == 8 * 2 and np.isfinite(summary['val_loss'])


# --- the pieces --------------------------------------------------------------------------------

def test_augmentation_is_a_function_of_seed_epoch_scene_and_copy():
    pack = ScenePack.from_scenes(toy_scenes(4, seed=9))
    ds = AugmentedVolumes(pack, MapConfig(), TileConfig(), seed=0)
    draws = {ds.draw(e, s, c)[:2] for e in range(2) for s in range(4) for c in range(3)}
    assert len(draws) == 24  # all different
    assert ds.draw(1, 2, 0) == AugmentedVolumes(pack, MapConfig(), TileConfig(), 0).draw(1, 2, 0)
    yaw, dz, cuts = ds.draw(0, 0, 0)
    assert 0 <= yaw < 2 * np.pi and -0.3 <= dz <= 0.3 and cuts == []
    x, y = ds[(0, 1, 0)]
    assert x.shape == (1, 32, 32, 32) and float(y) == 1.0
    assert AugmentedVolumes(pack, MapConfig(), TileConfig(), 0, augment=False).draw(3, 1, 2) \
        == (0.0, 0.0, [])


def test_a_scene_at_the_tiles_edge_turns_by_quarter_turns_only():
    """An obstacle 2 cm beyond the edge must not be turned into the tile (nor one reaching in
    turned out of it): such scenes take the drawn yaw rounded to a quarter turn, and the rest
    of their draws, and every other scene's, stay as they were."""
    pack = ScenePack.from_scenes(toy_scenes(4, seed=9))
    plain = AugmentedVolumes(pack, MapConfig(), TileConfig(), seed=0)
    pack.params[1]['edge'] = {'side': 0, 'along': 0.1, 'gap': 0.02, 'reach': 0.1, 'yaw': 0.0}
    straddling = {'dataset': 'synth3', 'obstacle': {'model': 'log'}, 'label': 0}
    pack.params[2].update(straddling, inside=False)
    pack.params[3].update(straddling, inside=True)
    ds = AugmentedVolumes(pack, MapConfig(), TileConfig(), seed=0)
    assert ds.quarter_turns.tolist() == [False, True, True, False]
    quarter = 0.5 * np.pi
    for e in range(3):
        for c in range(8):
            for scene in (0, 3):
                assert ds.draw(e, scene, c) == plain.draw(e, scene, c)
            for scene in (1, 2):
                (yaw, dz, cuts), (yaw0, dz0, cuts0) = ds.draw(e, scene, c), plain.draw(e, scene, c)
                assert (dz, cuts) == (dz0, cuts0)
                assert yaw in (0.0, quarter, 2 * quarter, 3 * quarter)
                assert min(abs(yaw - yaw0), 2 * np.pi - abs(yaw - yaw0)) <= quarter / 2 + 1e-12


def test_edge_drop_cuts_only_the_context():
    pack = ScenePack.from_scenes(toy_scenes(2, seed=9))
    plain = AugmentedVolumes(pack, MapConfig(), TileConfig(), seed=0)
    ds = AugmentedVolumes(pack, MapConfig(), TileConfig(), seed=0, edge_drop=1.0)
    draws = [ds.draw(e, 0, c) for e in range(4) for c in range(10)]
    # the yaw and shift stream is the one without cuts; every sample is cut, a third twice
    assert [d[:2] for d in draws] == [plain.draw(e, 0, c)[:2] for e in range(4) for c in range(10)]
    n_cuts = [len(d[2]) for d in draws]
    assert set(n_cuts) == {1, 2} and 5 <= n_cuts.count(2) <= 25
    for _, dist in (c for d in draws for c in d[2]):
        assert 0.5 <= dist <= 0.5 + 6 * 0.05
    pts, org = pack.scene(0)
    kept, korg = cut_context(pts, org, [(0.0, 0.6)])
    assert len(kept) == len(korg) and np.all(kept[:, 0] <= 0.6)
    assert np.array_equal(kept, pts[pts[:, 0] <= 0.6])  # nothing else goes
    # cut at the tile's own edge (+x): the padding beyond it becomes unobserved (input 0, but
    # for rays passing over it); the tile keeps every hit and loses only passes of rays that
    # ended beyond the cut, so no voxel of it gets emptier
    full, cut = scene_to_input(pts, org), scene_to_input(*cut_context(pts, org, [(0.0, 0.5)]))
    assert cut.ground_z[0] == full.ground_z[0]
    x_full, x_cut = full.inputs[0, 0], cut.inputs[0, 0]
    inner, beyond = slice(6, 26), slice(27, 32)
    assert np.mean(x_cut[beyond, inner] == 0) > np.mean(x_full[beyond, inner] == 0) + 0.3
    assert np.all(x_cut[inner, inner] >= x_full[inner, inner] - 1e-6)


def test_concatenated_sources_index_through():
    from landing_zone.tools.learn.scenes import ConcatScenes
    a, b = toy_scenes(3, seed=1), toy_scenes(4, seed=2)
    both = ConcatScenes([a, b])
    assert len(both) == 7 and both.labels.tolist() == [0, 1, 0, 0, 1, 0, 1]
    assert both[2] is a[2] and both[3] is b[0] and both[6] is b[3]
    with pytest.raises(IndexError):
        both[7]


def test_the_parts_of_a_source_are_named_as_they_are_numbered():
    from landing_zone.tools.evaluate.lofo import SceneSubset
    from landing_zone.tools.learn.scenes import ConcatScenes, part_names, part_of
    a, b = toy_scenes(3, seed=1), toy_scenes(4, seed=2)
    both = ConcatScenes([a, b], ['hybrid', 'synth3_some'])
    assert part_names(both, 'both') == ['hybrid', 'synth3_some']
    sub = SceneSubset(both, np.array([1, 5]))  # through a subset, as part_of looks
    assert part_of(sub, np.array([0, 1])).tolist() == [0, 1]
    assert part_names(sub, 'sub') == ['hybrid', 'synth3_some']
    assert part_names(a, 'a') == ['a']  # one source: the name given
    assert ConcatScenes([a, b]).names == ['list', 'list']
    with pytest.raises(ValueError, match='1 names for 2 sources'):
        ConcatScenes([a, b], ['one'])


def test_epoch_sampler_orders_and_caps():
    s = EpochSampler(np.array([10, 11, 12]), copies=2, seed=0)
    s.set_epoch(0)
    keys = [tuple(k) for k in s]
    assert sorted(keys) == sorted((0, sc, c) for sc in (10, 11, 12) for c in (0, 1))
    s.set_epoch(1)
    assert [k[1:] for k in s] != [k[1:] for k in keys]
    s.set_epoch(0, start=4)
    assert list(s) == keys[4:] and len(s) == 2
    capped = EpochSampler(np.array([10, 11, 12]), copies=2, seed=0, max_samples=4)
    assert len(list(capped)) == 4 == len(capped)


def test_validation_split_is_by_scene_and_per_class():
    labels = np.array([0] * 30 + [1] * 10)
    tr, va = split_scenes(labels, 0.1, seed=0)
    assert len(np.intersect1d(tr, va)) == 0 and len(tr) + len(va) == 40
    assert (labels[va] == 0).sum() == 3 and (labels[va] == 1).sum() == 1
    assert np.array_equal(va, split_scenes(labels, 0.1, seed=0)[1])
    assert len(split_scenes(labels, 0.0, seed=0)[1]) == 0


def test_scene_pack_gives_the_scenes_back():
    scenes = toy_scenes(3, seed=10)
    pack = ScenePack.from_scenes(scenes)
    for i, s in enumerate(scenes):
        p, o = pack.scene(i)
        np.testing.assert_array_equal(p, s.points)
        np.testing.assert_array_equal(o, s.origins)
    assert pack.labels.tolist() == [0, 1, 0]
    assert pack.origins.shape[0] == 3  # one scan position per scene, stored once


def test_bad_data_and_settings_are_refused(tmp_path):
    with pytest.raises(DatasetError, match='both classes'):
        train([toy_scene(np.random.default_rng(0), False) for _ in range(4)],
              tmp_path / 'm.safetensors', quick_config(), progress=False)
    with pytest.raises(ConfigError, match="token 1 'Q3'"):
        train(toy_scenes(4, 0), tmp_path / 'm.safetensors', quick_config(arch='Q3'),
              progress=False)
    with pytest.raises(ConfigError, match='epochs must be >= 1'):
        quick_config(epochs=0).validate()
    with pytest.raises(DatasetError, match='no dataset directory'):
        train(tmp_path, tmp_path / 'm.safetensors', quick_config(), progress=False)


@pytest.mark.slow
def test_training_needs_only_torch_numpy_numba_scipy_sklearn_safetensors_tqdm(tmp_path):
    """What a bare training box offers (Python, torch, numpy, numba, scipy, scikit-learn, and
    safetensors and tqdm, which the package requires: no hand-made copies of them)."""
    import subprocess
    import sys
    from pathlib import Path
    script = f'''
import sys
for name in ('typer', 'optuna', 'rclpy', 'rosbags', 'matplotlib', 'trimesh', 'embreex', 'mcap',
             'rich'):
    sys.modules[name] = None
sys.path.insert(0, {str(Path(__file__).parent)!r})
from test_train import toy_scenes, quick_config
from landing_zone.tools.learn.train import train
from landing_zone.judging.checkpoint import load_model
train(toy_scenes(8, 0), {str(tmp_path / 'm.safetensors')!r}, quick_config(), progress=True)
print(load_model({str(tmp_path / 'm.safetensors')!r})[0].spec)
'''
    r = subprocess.run([sys.executable, '-c', script], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == SMALL


# --- architecture search -----------------------------------------------------------------------

def test_spec_from_search_params():
    from landing_zone.tools.learn.tune import spec_from_params
    params = {'conv_layers': 2, 'kernel_0': 7, 'filters_0': 32, 'pool_0': 2, 'kernel_1': 5,
              'filters_1': 64, 'pool_1': 2, 'log2_hidden': 9}
    assert spec_from_params(params) == 'C7-F32-P2-C5-F64-P2-D512'
    assert spec_from_params({'conv_layers': 1, 'kernel_0': 3, 'filters_0': 128, 'pool_0': 1,
                             'log2_hidden': 7}) == 'C3-F128-P1-D128'


@pytest.mark.slow
def test_search_resumes_from_its_storage(tmp_path):
    from landing_zone.tools.learn.tune import TuneConfig, tune
    scenes = toy_scenes(8, seed=11)
    storage = f'sqlite:///{tmp_path / "tune.db"}'
    # a tiny budget; nets above 300k parameters are pruned unseen, which most draws are
    cfg = TuneConfig(trials=2, epochs=1, augment_copies=1, max_samples=8, max_params=300_000)
    rows = tune(scenes, cfg, storage=storage, out_dir=tmp_path / 'm', progress=False)
    assert len(rows) == 2
    cfg.trials = 4
    rows = tune(scenes, cfg, storage=storage, out_dir=tmp_path / 'm', progress=False)
    assert len(rows) == 4
    assert sorted(r['number'] for r in rows) == [0, 1, 2, 3]
    specs = [r['spec'] for r in rows]
    assert len(set(specs)) == len(specs)  # the resumed search did not redraw the first trials
    for r in rows:
        assert r['state'] in ('COMPLETE', 'PRUNED')
        if r['state'] == 'COMPLETE':
            assert 0.0 <= r['val_auc'] <= 1.0 and r['params'] <= 300_000
        else:
            assert r['note']
