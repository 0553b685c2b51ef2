"""synth3: the plan (pairs, splits by family and instance), deterministic resumable shards,
the families of every scene, and leaving a family out (landing_zone.tools.evaluate.lofo)."""
from __future__ import annotations

import hashlib
import json
from collections import Counter

import numpy as np
import pytest

from landing_zone.errors import ConfigError, DatasetError
from landing_zone.tools.evaluate.lofo import (family_figures, family_folds, family_report,
                                              hold_out, markdown_families, parse_hold_out,
                                              scene_families)
from landing_zone.tools.sim.dataset import simulate_dataset
from landing_zone.tools.sim.shards import SceneDataset
from landing_zone.tools.sim.families import TEST_BASE, TEST_FAMILIES, TRAIN_FAMILIES
from landing_zone.tools.sim.synth3 import (SENSOR_FAMILIES, SYNTH3_FAMILIES, families_of,
                                           scene_plan, select_scenes, synth3_train_families)
from landing_zone.tools.sim.vegetation import SYNTH3_VEGETATION


def digest(root):
    files = sorted((root / 'shards').glob('*.npz')) + [root / 'meta.json']
    return {f.name: hashlib.sha256(f.read_bytes()).hexdigest() for f in files}


@pytest.fixture(scope='module')
def small(tmp_path_factory):
    """Twelve scenes: six pairs, in shards of four, by two workers."""
    root = tmp_path_factory.mktemp('synth3') / 'data'
    simulate_dataset('synth3', root, scenes=12, workers=2, seed=4, shard_size=4,
                     progress=False)
    return root


def test_plan_pairs_and_splits():
    plans = [scene_plan(i, 0) for i in range(4000)]
    for a, b in zip(plans[0::2], plans[1::2]):
        # Twins: everything but the label is the same, one of them unsafe.
        assert {a['label'], b['label']} == {0, 1}
        strip = ('index', 'label')
        assert {k: v for k, v in a.items() if k not in strip} == \
            {k: v for k, v in b.items() if k not in strip}
    train = [p for p in plans if p['split'] == 'train']
    test = [p for p in plans if p['split'] == 'test']
    assert 0.2 < len(test) / len(plans) < 0.3
    # By family: test families only in the test split; by instance: disjoint index ranges.
    assert {p['family'] for p in train} == set(synth3_train_families())
    assert {p['family'] for p in test} == set(SYNTH3_FAMILIES)
    assert set(synth3_train_families()) == set(TRAIN_FAMILIES) & set(SYNTH3_FAMILIES)
    assert max(p['instance'] for p in train) < TEST_BASE <= min(p['instance'] for p in test)
    assert {p['vegetation']['family'] for p in plans} == set(SYNTH3_VEGETATION)
    assert {p['sensor']['family'] for p in plans} == set(SENSOR_FAMILIES)
    dens = np.array([p['sensor']['density'] for p in plans])
    heights = np.array([p['sensor']['height'] for p in plans])
    assert 1000 <= dens.min() and dens.max() <= 5000 and 4 <= heights.min() < heights.max() <= 20
    slopes = [p['terrain']['slope'] for p in plans]
    assert max(slopes) > 11.0
    assert 0.2 < np.mean([p['hide'] is not None for p in plans]) < 0.4
    # The plan depends on the seed, the split does not.
    other = [scene_plan(i, 1) for i in range(40)]
    assert [p['split'] for p in other] == [p['split'] for p in plans[:40]]
    assert [p['family'] for p in other] != [p['family'] for p in plans[:40]]
    idx = select_scenes(10, 'test')
    assert all(scene_plan(int(i))['split'] == 'test' for i in idx) and len(idx) == 10


def test_scenes_record_their_families_and_are_deterministic(small, tmp_path):
    ds = SceneDataset(small, 'all')
    assert len(ds) == 12 and ds.meta['dataset'] == 'synth3'
    fams = scene_families(ds)
    for i in range(len(ds)):
        s = ds[i]
        p = s.params
        assert families_of(p) == {a: fams[a][i] for a in fams}
        assert (p['obstacle'] is None) == (s.label == 1)
        assert len(s.points) > 1000 and s.points.dtype == np.float32
        if p['obstacle'] is not None:
            assert p['obstacle']['family'] == p['family']
            assert p['obstacle']['model'] == f"{p['family']}/{p['instance']}"
            assert (s.hit_class == 2).sum() > 0  # the obstacle is seen
        # The achieved density is near the plan's (flat-ground estimate for passes).
        assert 0.5 < p['density'] / p['sensor']['density'] < 1.6
    # Same seed, one worker, another shard order of completion: the same bytes.
    again = tmp_path / 'again'
    simulate_dataset('synth3', again, scenes=12, workers=1, seed=4, shard_size=4,
                     progress=False)
    assert digest(again) == digest(small)
    # Interrupted: a shard lost and a half-written one; the rerun restores the same bytes.
    (again / 'shards' / 'shard-00001.npz').unlink()
    (again / 'shards' / 'shard-00002.npz.tmp-99').write_bytes(b'partial')
    s = simulate_dataset('synth3', again, scenes=12, workers=1, seed=4, shard_size=4,
                         progress=False)
    assert (s['generated'], s['skipped']) == (4, 8)
    assert digest(again) == digest(small)


def test_hold_out_drops_whole_pairs_of_a_family(small):
    ds = SceneDataset(small, 'all')
    fams = scene_families(ds)
    family = Counter(fams['obstacle']).most_common(1)[0][0]
    sub = hold_out(ds, [f'obstacle:{family}'])
    kept = fams['obstacle'][sub.positions]
    assert family not in set(kept) and len(sub) == int((fams['obstacle'] != family).sum())
    assert int((sub.labels == 0).sum()) == int((sub.labels == 1).sum())  # still balanced
    assert sub[0].params['family'] != family
    veg = fams['vegetation'][0]
    both = hold_out(ds, [f'obstacle:{family}', f'vegetation:{veg}'])
    assert len(both) < len(sub) or veg not in set(fams['vegetation'][sub.positions])
    assert hold_out(ds, []) is ds
    for bad, match in [('log', 'AXIS:FAMILY'), ('colour:red', 'unknown axis'),
                       ('obstacle:spaceship', 'unknown obstacle family'),
                       ('vegetation:log', 'unknown vegetation family')]:
        with pytest.raises(ConfigError, match=match):
            parse_hold_out([bad])


def test_hold_out_needs_a_dataset_with_families(tmp_path):
    root = tmp_path / 's2'
    simulate_dataset('synth2', root, scenes=2, workers=1, progress=False)
    with pytest.raises(DatasetError, match='records no families'):
        hold_out(SceneDataset(root, 'all'), ['obstacle:log'])


def test_family_figures_and_the_lofo_table():
    class R:
        def __init__(self, name, scores):
            self.name, self.scores = name, np.asarray(scores, float)

    # Two families, two scenes each; 'b' misjudged by the first method.
    params = [{'family': f, 'vegetation': {'family': 'uniform'}, 'terrain': {'family': 'flat'},
               'sensor': {'family': 'line'}} for f in ('a', 'a', 'b', 'b')]
    labels = np.array([1, 0, 1, 0])
    r1 = R('one', [0.9, 0.1, 0.2, 0.95])
    r2 = R('two', [0.8, 0.3, 0.7, 0.05])
    rep = family_report([r1, r2], params, labels, held_out={'two': [('obstacle', 'b')]})
    fa = rep['methods']['one']['obstacle']['a']
    fb = rep['methods']['one']['obstacle']['b']
    assert fa['auc'] == 1.0 and fa['unsafe_ge_0.5'] == 0.0 and fa['safe_lt_0.5'] == 0.0
    assert fb['auc'] == 0.0 and fb['unsafe_ge_0.5'] == 1.0 and fb['unsafe_ge_0.9'] == 1.0
    assert fb['safe_lt_0.5'] == 1.0
    # The LOFO row of 'b' is the model that held it out.
    assert rep['lofo']['obstacle']['b']['model'] == 'two'
    assert rep['lofo']['obstacle']['b']['auc'] == 1.0 and 'a' not in rep['lofo']['obstacle']
    # Nothing here trained on synth3: no in-family figures beside it.
    assert rep['lofo']['obstacle']['b']['in_family'] is None
    # Pooled: each scene of a family with a LOFO row, scored by that row's model.
    pooled = rep['lofo_pooled']['obstacle']
    assert pooled['families'] == 1 and pooled['n'] == 2 and pooled['auc'] == 1.0
    text = markdown_families(rep)
    assert text.startswith('Leave one family out') and '| obstacle:b | 2 (1) | 1.000 |' in text
    assert '| obstacle: all 1 families pooled | 2 (1) |' in text
    # Trained on synth3 and not holding 'b' out: 'one' is 'b' in family (and 'a' has no row).
    rep = family_report([r1, r2], params, labels, held_out={'two': [('obstacle', 'b')]},
                        trained_on_synth3={'one': True, 'two': True})
    seen = rep['lofo']['obstacle']['b']['in_family']
    assert seen['model'] == 'one' and seen['auc'] == 0.0 and seen['unsafe_ge_0.9'] == 1.0
    assert '| two | 0.000 / 100.0% / 100.0% |' in markdown_families(rep)
    # Two families held out by two models: pooled, each scene by its own family's model.
    r3 = R('three', [0.1, 0.9, 0.2, 0.3])  # wrong on 'a' (held out), not on 'b'
    rep = family_report([r2, r3], params, labels,
                        held_out={'two': [('obstacle', 'b')], 'three': [('obstacle', 'a')]})
    pooled = rep['lofo_pooled']['obstacle']
    assert pooled['families'] == 2 and pooled['n'] == 4
    assert pooled['unsafe_ge_0.5'] == 0.5 and pooled['safe_lt_0.5'] == 0.5  # 'a' by 'three'
    f = family_figures(np.array([0.95, 0.6, 0.2]), np.array([0, 0, 1]))
    assert f['unsafe_ge_0.5'] == 1.0 and f['unsafe_ge_0.9'] == 0.5 and f['n_unsafe'] == 2
    assert json.dumps(rep)  # JSON-ready
    # A test family counts as held out by any model trained on synth3's train split.
    params[2]['family'] = params[3]['family'] = TEST_FAMILIES[0]
    rep = family_report([r1], params, labels, trained_on_synth3={'one': True})
    assert rep['lofo']['obstacle'][TEST_FAMILIES[0]]['model'] == 'one'


def test_train_without_a_family_and_evaluate_by_family(small, tmp_path):
    """The trainer leaves the family out and says so in the model; evaluate --by-family then
    reports that family in the LOFO table with that model (real training, tiny budget)."""
    from landing_zone.tools.evaluate.roc import evaluate
    from landing_zone.judging.checkpoint import read_metadata
    from landing_zone.tools.learn.train import TrainConfig, train
    ds = SceneDataset(small, 'train')
    family = Counter(scene_families(ds)['obstacle']).most_common(1)[0][0]
    out = tmp_path / 'lofo.safetensors'
    summary = train(small, out, TrainConfig(epochs=1, augment_copies=1, batch_size=4,
                                            val_fraction=0.25, hold_out=[f'obstacle:{family}']),
                    progress=False)
    meta = read_metadata(out)
    assert meta['training']['hold_out'] == [f'obstacle:{family}']
    assert meta['datasets'] == ['synth3'] and family in meta['source']
    kept = int((scene_families(ds)['obstacle'] != family).sum())
    assert meta['n_train_scenes'] + meta['n_val_scenes'] == kept and summary['samples'] > 0
    res = evaluate(small, out, split='train', by_family=True, progress=False)
    fam = res['families']
    assert set(fam['methods']) == {next(iter(res['methods']))}
    # The held-out family's scenes are in the split (not in training): judged by this model.
    n_family = int((scene_families(ds)['obstacle'] == family).sum())
    assert fam['lofo']['obstacle'][family]['n'] == n_family > 0
    assert 'Leave one family out' in res['table'] and f'obstacle:{family}' in res['table']


def test_family_folds_partition_the_train_families():
    from landing_zone.tools.sim.vegetation import SYNTH3_VEGETATION
    train = synth3_train_families()  # synth3's, fixed as families are added
    folds = family_folds(4, seed=0)
    flat = [spec for fold in folds for spec in fold]
    assert sorted(flat) == sorted([f'obstacle:{f}' for f in train]
                                  + [f'vegetation:{f}' for f in SYNTH3_VEGETATION])
    for axis, n in (('obstacle', len(train)), ('vegetation', len(SYNTH3_VEGETATION))):
        sizes = [sum(s.startswith(axis + ':') for s in fold) for fold in folds]
        assert max(sizes) - min(sizes) <= 1 and sum(sizes) == n and min(sizes) >= 1
    assert family_folds(4, seed=0) == folds and family_folds(4, seed=1) != folds
    for bad in (1, len(SYNTH3_VEGETATION) + 1):
        with pytest.raises(ConfigError):
            family_folds(bad)


def test_calibrate_on_out_of_family_logits(small, tmp_path):
    """A fold model's logits on the scenes of the family it held out set the final model's
    temperature and offset; the weights stay bit for bit, and P(safe) follows the new
    calibration (real training, tiny budget)."""
    from landing_zone.judging.checkpoint import load_model, read_metadata
    from landing_zone.judging.inference import predict
    from landing_zone.tools.learn.recalibrate import calibrate, out_of_family_logits
    from landing_zone.tools.learn.train import TrainConfig, train
    ds = SceneDataset(small, 'train')
    family = Counter(scene_families(ds)['obstacle']).most_common(1)[0][0]
    cfg = dict(epochs=1, augment_copies=1, batch_size=4, val_fraction=0.25)
    fold, final = tmp_path / 'fold.safetensors', tmp_path / 'final.safetensors'
    train(small, fold, TrainConfig(**cfg, hold_out=[f'obstacle:{family}']), progress=False)
    train(small, final, TrainConfig(**cfg), progress=False)
    z, y, info = out_of_family_logits([fold], small, per_model=100)
    n_family = int((scene_families(ds)['obstacle'] == family).sum())
    assert len(z) == len(y) == n_family == info[0]['scenes'] and set(y) <= {0, 1}
    assert info[0]['hold_out'] == [f'obstacle:{family}']
    out = tmp_path / 'calibrated.safetensors'
    s = calibrate(final, [fold], small, out, per_model=100)
    meta, before = read_metadata(out), read_metadata(final)
    assert meta['weights_sha256'] == before['weights_sha256']
    assert meta['temperature'] == pytest.approx(s['temperature'])
    assert meta['calibration_offset'] == pytest.approx(s['offset'])
    assert meta['calibration']['n'] == n_family and meta['training'] == before['training']
    net, _ = load_model(out)
    x = np.zeros((2, 1, net.config.input_size, *(net.config.input_size,) * 2), np.float32)
    x[1] = -1.0
    logits = predict(net, x, logits=True)
    expected = 1.0 / (1.0 + np.exp(-(logits / s['temperature'] + s['offset'])))
    assert np.allclose(predict(net, x), expected, atol=1e-6)
    with pytest.raises(ConfigError, match='held no family out'):
        out_of_family_logits([final], small)


def test_calibrate_like_carries_the_initial_models_correction_over(small, tmp_path):
    """A fine-tuned model gets its initial model's out-of-family correction on top of its own
    in-family fit: the initial model like itself gets its own calibration back, another net
    gets T = T_m / a, b = a b_m + b_o - a b_i (a = T_i / T_o); the weights stay bit for bit
    (real training, tiny budget)."""
    from landing_zone.judging.checkpoint import (input_configs, load_model, read_metadata,
                                                 save_model)
    from landing_zone.tools.learn.calibration import fit_platt
    from landing_zone.tools.learn.recalibrate import _in_family_logits, calibrate_like
    from landing_zone.tools.learn.train import TrainConfig, train
    cfg = dict(epochs=1, augment_copies=1, batch_size=4, val_fraction=0.25)
    initial, tuned = tmp_path / 'initial.safetensors', tmp_path / 'tuned.safetensors'
    train(small, initial, TrainConfig(**cfg), progress=False)
    net, meta = load_model(initial)
    net.temperature, net.offset = 0.7, -0.9  # as `calibrate` leaves it
    save_model(initial, net, meta)
    train(small, tuned, TrainConfig(**cfg, seed=1), progress=False)
    same = calibrate_like(initial, initial, small, tmp_path / 'same.safetensors', scenes=100)
    assert same['temperature'] == pytest.approx(0.7) and same['offset'] == pytest.approx(-0.9)
    out = tmp_path / 'tuned_cal.safetensors'
    s = calibrate_like(tuned, initial, small, out, scenes=100)
    (tuned_net, tuned_meta), (initial_net, _) = load_model(tuned), load_model(initial)
    (z_m, z_i), y = _in_family_logits([tuned_net, initial_net], input_configs(tuned_meta),
                                      small, 100, 0, 0, False)
    t_m, b_m = fit_platt(z_m, y)
    t_i, b_i = fit_platt(z_i, y)
    a = t_i / 0.7
    assert s['temperature'] == pytest.approx(t_m / a)
    assert s['offset'] == pytest.approx(a * b_m - 0.9 - a * b_i)
    meta, before = read_metadata(out), read_metadata(tuned)
    assert meta['weights_sha256'] == before['weights_sha256']
    assert meta['calibration']['method'] == 'like' and meta['calibration']['n'] == len(y)
    assert meta['temperature'] == pytest.approx(s['temperature'])


def test_train_on_an_even_subset_keeps_whole_pairs(small, tmp_path):
    from landing_zone.judging.checkpoint import read_metadata
    from landing_zone.tools.learn.train import TrainConfig, train
    out = tmp_path / 'sub.safetensors'
    train(small, out, TrainConfig(epochs=1, augment_copies=1, batch_size=4, val_fraction=0.25,
                                  max_scenes=6), progress=False)
    meta = read_metadata(out)
    assert meta['n_train_scenes'] + meta['n_val_scenes'] == 6 and '6 scenes' in meta['source']
    assert meta['training']['max_scenes'] == 6


def test_other_families_draw_only_those_and_share_no_draw(tmp_path):
    """A synth3 dataset of other families: its train pairs draw the train families among them,
    its test pairs every one of them; its meta names them, its seeds differ from the default
    dataset's, and synth3's own plans are untouched (named in their order, they are the
    default)."""
    fams = ('frame', 'mesh', 'coil')
    plans = [scene_plan(i, 0, fams) for i in range(600)]
    assert {p['family'] for p in plans if p['split'] == 'train'} == {'frame', 'mesh'}
    assert {p['family'] for p in plans if p['split'] == 'test'} == set(fams)
    default = [scene_plan(i, 0) for i in range(40)]
    assert [scene_plan(i, 0, SYNTH3_FAMILIES) for i in range(40)] == default
    assert [p['vegetation'] for p in plans[:40]] != [p['vegetation'] for p in default]
    root = tmp_path / 'thin'
    simulate_dataset('synth3', root, scenes=4, workers=1, seed=2, shard_size=2,
                     progress=False, families=('frame', 'mesh'))
    ds = SceneDataset(root, 'all')
    assert ds.meta['obstacle_families'] == ['frame', 'mesh']
    assert ds.meta['obstacle_split']['train'] == ['frame', 'mesh']
    assert set(scene_families(ds)['obstacle']) <= {'frame', 'mesh'}
    # Resuming with other families is refused, not mixed into the directory.
    with pytest.raises(DatasetError):
        simulate_dataset('synth3', root, scenes=4, workers=1, seed=2, shard_size=2,
                         progress=False, families=('frame',))
    from landing_zone.errors import SimulationError
    with pytest.raises(SimulationError, match='none is a train family'):
        scene_plan(0, 0, ('coil',))
    with pytest.raises(SimulationError, match='--families is a synth3 option'):
        simulate_dataset('synth2', tmp_path / 's2', scenes=2, families=('frame',))


def test_edge_pairs_put_the_obstacle_just_beyond_or_just_inside_the_tile(tmp_path):
    """--edge: in that share of pairs both scenes hold the same instance turned the same way at
    one edge of the tile; in the unsafe scene its standing part reaches ``reach`` in, in the
    safe one its whole footprint stands ``gap`` beyond (the tile labels of flights agree). Off,
    the plans are synth3's own; on, the dataset records the share, shares no draw with the
    default one, and refuses to be resumed with another share."""
    from landing_zone.errors import SimulationError
    from landing_zone.tools.sim.families import instance
    from landing_zone.tools.sim.flight_site import polygon_overlaps_square
    from landing_zone.tools.sim.obstacles import Obstacle
    from landing_zone.tools.sim.synth3 import EDGE_GAP, EDGE_REACH

    default = [scene_plan(i, 0) for i in range(60)]
    assert [scene_plan(i, 0, None, 0.0) for i in range(60)] == default
    plans = [scene_plan(i, 0, None, 0.5) for i in range(600)]
    at_edge = [p for p in plans if 'edge' in p]
    assert 0.4 < len(at_edge) / len(plans) < 0.6
    assert all(plans[2 * k]['edge'] == plans[2 * k + 1]['edge']
               for k in range(300) if 'edge' in plans[2 * k])
    assert [p['vegetation'] for p in plans[:40]] != [p['vegetation'] for p in default[:40]]
    for p in at_edge:
        assert EDGE_GAP[0] <= p['edge']['gap'] <= EDGE_GAP[1]
        assert EDGE_REACH[0] <= p['edge']['reach'] <= EDGE_REACH[1]

    root = tmp_path / 'edge'
    simulate_dataset('synth3', root, scenes=4, workers=1, seed=3, shard_size=2, progress=False,
                     edge=1.0)
    ds = SceneDataset(root, 'all')
    assert ds.meta['edge']['share'] == 1.0 and ds.meta['edge']['pairs'] == 2
    lo, hi = np.array([-0.5, -0.5]), np.array([0.5, 0.5])
    scenes = [ds[i] for i in range(len(ds))]
    for pair in (scenes[:2], scenes[2:]):
        obs = {}
        for sc in pair:
            p, ob = sc.params, sc.params['obstacle']
            placed = Obstacle(instance(p['family'], p['instance']).model, ob['x'], ob['y'],
                              ob['z'], ob['yaw'])
            fp = placed.footprint()
            a = 0.5 * np.pi * p['edge']['side']
            out = np.array([np.cos(a), np.sin(a)])
            if sc.label == 1:  # wholly beyond the edge, by the gap
                assert not polygon_overlaps_square(fp, lo, hi)
                assert np.min(fp @ out) == pytest.approx(0.5 + p['edge']['gap'], abs=1e-3)
            else:  # overlapping, and what stands reaches in by the reach
                assert polygon_overlaps_square(fp, lo, hi)
                v = placed.vertices()
                inner = v[np.all(np.abs(v[:, :2]) < 0.5, axis=1)]
                assert len(inner) and np.max(inner[:, 2] - placed.z) > 0.05
                assert np.min(v[:, :2] @ out) <= 0.5 - p['edge']['reach'] + 1e-3
                inside = np.all(np.abs(sc.points[:, :2]) < 0.5, axis=1)
                assert np.any(inside & (sc.hit_class == 2))  # the tile sees it
            obs[sc.label] = ob
        assert obs[0]['model'] == obs[1]['model'] and obs[0]['yaw'] == obs[1]['yaw']
    with pytest.raises(DatasetError):
        simulate_dataset('synth3', root, scenes=4, workers=1, seed=3, shard_size=2,
                         progress=False, edge=0.5)
    # nor with other ranges (a dataset made before they changed keeps its own)
    meta = json.loads((root / 'meta.json').read_text())
    meta['edge']['gap'] = [0.02, 0.3]
    (root / 'meta.json').write_text(json.dumps(meta))
    with pytest.raises(DatasetError):
        simulate_dataset('synth3', root, scenes=4, workers=1, seed=3, shard_size=2,
                         progress=False, edge=1.0)
    from landing_zone.tools.sim.library import get_model
    from landing_zone.tools.sim.obstacles import at_edge
    with pytest.raises(SimulationError, match='either reach or gap'):
        at_edge(get_model('box'), 0.0, 0, 0.0, 0.5, 0.1)
    with pytest.raises(SimulationError, match='--edge must be a share'):
        scene_plan(0, 0, None, 1.5)
    with pytest.raises(SimulationError, match='--edge is a synth3 option'):
        simulate_dataset('synth2', tmp_path / 's2', scenes=2, edge=0.5)


def test_other_vegetation_draws_only_those_and_shares_no_draw(tmp_path):
    """--vegetation: a synth3 dataset grown of other vegetation families (the meadow prior):
    every scene draws from them, its meta names them, its seeds differ from the default
    dataset's, resuming with other vegetation is refused, and synth3's own plans are untouched
    (named in their order, its six are the default)."""
    from landing_zone.errors import SimulationError
    from landing_zone.tools.sim.vegetation import SYNTH3_VEGETATION
    plans = [scene_plan(i, 0, vegetation=('meadow',)) for i in range(200)]
    assert {p['vegetation']['family'] for p in plans} == {'meadow'}
    both = [scene_plan(i, 0, vegetation=('meadow', 'shrub')) for i in range(200)]
    assert {p['vegetation']['family'] for p in both} == {'meadow', 'shrub'}
    default = [scene_plan(i, 0) for i in range(40)]
    assert [scene_plan(i, 0, vegetation=SYNTH3_VEGETATION) for i in range(40)] == default
    assert [p['family'] for p in plans[:40]] != [p['family'] for p in default]
    root = tmp_path / 'meadow'
    simulate_dataset('synth3', root, scenes=4, workers=1, seed=2, shard_size=2,
                     progress=False, vegetation=('meadow',))
    ds = SceneDataset(root, 'all')
    assert ds.meta['vegetation_families'] == ['meadow']
    assert ds.meta['families']['vegetation'] == ['meadow']
    assert set(scene_families(ds)['vegetation']) == {'meadow'}
    with pytest.raises(DatasetError):
        simulate_dataset('synth3', root, scenes=4, workers=1, seed=2, shard_size=2,
                         progress=False, vegetation=('meadow', 'uniform'))
    with pytest.raises(SimulationError, match="unknown vegetation family 'jungle'"):
        scene_plan(0, 0, vegetation=('jungle',))
    with pytest.raises(SimulationError, match='distinct'):
        scene_plan(0, 0, vegetation=('meadow', 'meadow'))
    with pytest.raises(SimulationError, match='--vegetation is a synth3 option'):
        simulate_dataset('synth2', tmp_path / 's2', scenes=2, vegetation=('meadow',))
