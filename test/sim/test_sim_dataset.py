"""Datasets: the Table I sweeps, deterministic shards, resume, the split, SceneDataset."""
from __future__ import annotations

import hashlib
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from landing_zone.errors import DatasetError, SimulationError
from landing_zone.tools.sim import shards as shards_mod
from landing_zone.tools.sim import sweeps as sweeps_mod
from landing_zone.tools.sim.dataset import simulate_dataset
from landing_zone.tools.sim.shards import SceneDataset
from landing_zone.tools.sim.sweeps import SWEEPS, scene_plan, scene_rng, select_scenes
from landing_zone.tools.sim.library import get_model, models

REPO = Path(__file__).resolve().parents[2]


def digest(root: Path) -> dict[str, str]:
    files = sorted((root / 'shards').glob('*.npz')) + [root / 'meta.json']
    return {f.name: hashlib.sha256(f.read_bytes()).hexdigest() for f in files}


@pytest.fixture(scope='module')
def small(tmp_path_factory):
    root = tmp_path_factory.mktemp('synth2') / 'data'
    summary = simulate_dataset('synth2', root, scenes=6, workers=1, seed=5, shard_size=3,
                               progress=False)
    return root, summary


def test_sweeps_match_table_one():
    s1, s2 = SWEEPS['synth1'], SWEEPS['synth2']
    assert dict(s1.axes)['grass_density'] == tuple(float(d) for d in range(100, 1201, 100))
    assert dict(s1.axes)['resolution'] == (0.05, 0.1, 0.2, 0.41)
    assert dict(s2.axes)['grass_density'][-2:] == (1600.0, 1800.0)
    assert dict(s2.axes)['blade_width'] == (0.003, 0.005, 0.008)
    for s in (s1, s2):
        axes = dict(s.axes)
        assert axes['grass_height'] == (0.1, 0.2, 0.3)
        assert axes['sensor_offset'] == (-5.0, -10.0)
        assert axes['sensor_height'] == (4.0, 8.0)
    assert (s1.instances, s1.total) == (20, 12 * 4 * 3 * 2 * 2 * 20)
    assert (s2.instances, s2.total) == (40, 17 * 3 * 3 * 2 * 2 * 40)
    # Every setting: exactly half of its instances unsafe.
    for name, s in SWEEPS.items():
        for setting in (0, 7, s.n_settings - 1):
            labels = [scene_plan(name, setting * s.instances + j)['label']
                      for j in range(s.instances)]
            assert sum(labels) == s.instances // 2
    # Settings enumerate the whole product once.
    seen = {tuple(sorted(s2.setting(k).items())) for k in range(s2.n_settings)}
    assert len(seen) == s2.n_settings


def test_subsampling_is_even_and_balanced():
    idx = select_scenes('synth2', 400)
    assert len(idx) == len(set(idx.tolist())) == 400
    plans = [scene_plan('synth2', int(i)) for i in idx]
    dens = {p['grass_density'] for p in plans}
    assert dens == set(dict(SWEEPS['synth2'].axes)['grass_density'])
    assert abs(sum(p['label'] for p in plans) - 200) < 40
    test_share = np.mean([p['split'] == 'test' for p in plans])
    assert 0.12 < test_share < 0.28
    only_test = select_scenes('synth2', 50, split='test')
    assert len(only_test) == 50
    assert all(scene_plan('synth2', int(i))['split'] == 'test' for i in only_test)


def test_test_group_models_never_in_train_scenes():
    test_models = {m.name for m in models(('rock', 'tire', 'cinder_block'), 'test')}
    drawn = {'train': set(), 'test': set()}
    for i in select_scenes('synth2', 1500):
        plan = scene_plan('synth2', int(i))
        if plan['label'] == 0:
            name = sweeps_mod.choose_model(SWEEPS['synth2'], plan['split'],
                                           scene_rng('synth2', int(i), 0))
            drawn[plan['split']].add(name)
    assert not drawn['train'] & test_models
    assert drawn['test'] <= test_models
    # Both groups get used in full.
    assert len(drawn['test']) == len(test_models)
    assert len(drawn['train']) == len(models(('rock', 'tire', 'cinder_block'), 'train'))


def test_dataset_files_and_loader(small):
    root, summary = small
    assert summary['scenes'] == 6 and summary['generated'] == 6
    meta = json.loads((root / 'meta.json').read_text())
    assert meta['complete'] and meta['format_version'] == shards_mod.FORMAT_VERSION
    assert meta['dataset'] == 'synth2' and meta['seed'] == 5
    assert set(meta['obstacle_split']['train']).isdisjoint(meta['obstacle_split']['test'])
    train, test = SceneDataset(root, 'train'), SceneDataset(root, 'test')
    assert len(train) + len(test) == 6
    counts = meta['counts']
    assert len(test) == counts['test']['safe'] + counts['test']['unsafe']
    seen = set()
    for ds, split in ((train, 'train'), (test, 'test')):
        for k, scene in enumerate(ds):
            p = scene.params
            assert p['split'] == split and p['index'] not in seen
            seen.add(p['index'])
            assert scene.points.dtype == np.float32 and scene.origins.dtype == np.float32
            assert scene.points.shape == scene.origins.shape == (p['n_returns'], 3)
            assert scene.label == ds.labels[k] == (0 if p['obstacle'] else 1)
            # The target density over the tile.
            tile = np.all(np.abs(scene.points[:, :2]) < 0.5, axis=1)
            assert abs(tile.sum() - 3000) / 3000 < 0.1
            # Origins: the hovering sensor, a few cm from its nominal position.
            nominal = [p['sensor_offset'], 0.0, p['sensor_height']]
            assert np.all(np.linalg.norm(scene.origins - nominal, axis=1) < 0.5)
            if p['obstacle'] is not None:
                ob = p['obstacle']
                model = get_model(ob['model'])
                assert model.group in (split, 'both')
                # Inside the tile, or straddling its edge with at least half its radius in.
                assert max(abs(ob['x']), abs(ob['y'])) <= 0.5 + 0.5 * model.radius
                assert np.count_nonzero((scene.hit_class == 2) & tile) > 0
                assert np.count_nonzero(scene.hit_class == 2) > 10
            else:
                assert not np.any(scene.hit_class == 2)
    assert repr(train).startswith('SceneDataset(')
    with pytest.raises(IndexError):
        train[len(train)]


def test_same_seed_same_bytes_any_worker_count(small, tmp_path):
    root, _ = small
    again = tmp_path / 'again'
    simulate_dataset('synth2', again, scenes=6, workers=2, seed=5, shard_size=3, progress=False)
    assert digest(again) == digest(root)
    # A fresh process (the command line's case) forks its workers instead: same bytes.
    forked = tmp_path / 'forked'
    code = ('from landing_zone.tools.sim.dataset import simulate_dataset\n'
            f'simulate_dataset("synth2", r"{forked}", scenes=6, workers=3, seed=5, '
            'shard_size=3, progress=False)\n')
    run = subprocess.run([sys.executable, '-c', code], cwd=REPO, capture_output=True,
                         text=True, timeout=120)
    assert run.returncode == 0, run.stderr
    assert digest(forked) == digest(root)
    other = tmp_path / 'other'
    simulate_dataset('synth2', other, scenes=3, workers=1, seed=6, shard_size=3, progress=False)
    first = SceneDataset(other, 'all')[0].points
    assert not np.array_equal(first, SceneDataset(root, 'all')[0].points)


def test_interrupted_run_resumes(small, tmp_path):
    root, _ = small
    work = tmp_path / 'work'
    simulate_dataset('synth2', work, scenes=6, workers=1, seed=5, shard_size=3, progress=False)
    shard = work / 'shards' / 'shard-00001.npz'
    shard.unlink()
    (work / 'shards' / 'shard-00000.npz').write_bytes(b'truncated')  # a torn write
    (work / 'shards' / 'shard-00001.npz.tmp-999').write_bytes(b'partial')
    summary = simulate_dataset('synth2', work, scenes=6, workers=1, seed=5, shard_size=3,
                               progress=False)
    assert summary['skipped'] == 0 and summary['generated'] == 6
    assert digest(work) == digest(root)
    assert not list((work / 'shards').glob('*.tmp-*'))
    summary = simulate_dataset('synth2', work, scenes=6, workers=1, seed=5, shard_size=3,
                               progress=False)
    assert summary['skipped'] == 6 and summary['generated'] == 0
    with pytest.raises(DatasetError, match='another dataset'):
        simulate_dataset('synth2', work, scenes=6, workers=1, seed=7, shard_size=3,
                         progress=False)


def test_delta_coding_is_exact(rng):
    mm = rng.integers(-32768, 32768, (5000, 3)).astype(np.int16)
    mm[:3] = [[32767, -32768, 0], [-32768, 32767, 1], [32767, 32767, -1]]  # worst jumps
    enc = shards_mod._delta_encode(mm)
    assert enc.dtype == np.int16 and enc.shape == (3, 5000)
    np.testing.assert_array_equal(shards_mod._delta_decode(enc), mm)


def test_incomplete_or_missing_dataset_is_an_error(tmp_path):
    with pytest.raises(DatasetError, match='no meta.json'):
        SceneDataset(tmp_path)
    (tmp_path / 'meta.json').write_text(json.dumps({'format_version': 1, 'complete': False}))
    with pytest.raises(DatasetError, match='incomplete'):
        SceneDataset(tmp_path)


@pytest.mark.parametrize('kwargs,match', [
    ({'dataset': 'synth9'}, 'unknown dataset'),
    ({'scenes': 0}, 'scenes'),
    ({'seed': -1}, 'seed'),
    ({'workers': 0}, 'workers'),
    ({'split': 'val'}, 'split'),
])
def test_bad_arguments_raise_before_any_work(kwargs, match, tmp_path):
    args = {'dataset': 'synth1', 'out': tmp_path / 'x', 'scenes': 2, 'progress': False}
    args.update(kwargs)
    with pytest.raises(SimulationError, match=match):
        simulate_dataset(**args)
    assert not (tmp_path / 'x').exists()


def test_generation_imports_only_the_dataset_machines_packages(tmp_path):
    # A dataset machine needs numpy, scipy, numba, trimesh, embreex and tqdm only: generate
    # with every other installed package made unimportable (optional imports of trimesh and
    # scipy then fail as they would there).
    code = (
        'import importlib.machinery, sys\n'
        'ALLOWED = {"numpy", "scipy", "numba", "trimesh", "embreex", "tqdm", "landing_zone"}\n'
        'class Block:\n'
        '    def find_spec(self, name, path=None, target=None):\n'
        '        top = name.split(".")[0]\n'
        '        if top in ALLOWED or top in sys.stdlib_module_names or "." in name:\n'
        '            return None\n'
        '        spec = importlib.machinery.PathFinder.find_spec(name, path)\n'
        '        if spec is not None and "-packages" in str(spec.origin):\n'
        '            raise ModuleNotFoundError(f"blocked: {name}", name=name)\n'
        '        return None\n'
        'sys.meta_path.insert(0, Block())\n'
        'BEFORE = set(sys.modules)  # (site hooks of the venv load before this)\n'
        'from landing_zone.tools.sim.dataset import simulate_dataset\n'
        f'simulate_dataset("synth1", r"{tmp_path / "d"}", scenes=2, workers=1)\n'
        'files = [str(getattr(sys.modules[m], "__file__", "")) for m in list(sys.modules)\n'
        '         if m not in BEFORE]\n'
        'dirs = {f.split("-packages/")[1].split("/")[0] for f in files if "-packages/" in f}\n'
        'print(" ".join(sorted(dirs)))\n')
    out = subprocess.run([sys.executable, '-c', code], cwd=REPO, capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    third_party = set(out.stdout.strip().splitlines()[-1].split())
    assert third_party <= {'numpy', 'scipy', 'numba', 'trimesh', 'embreex', 'tqdm'}, third_party
    assert len(SceneDataset(tmp_path / 'd', 'all')) == 2


def test_module_entry_point_reports_bad_input_in_one_line(tmp_path):
    out = subprocess.run([sys.executable, '-m', 'landing_zone', 'simulate', '--dataset',
                          'synth1', '--out', str(tmp_path / 'x'), '--scenes', '0'],
                         cwd=REPO, capture_output=True, text=True, timeout=60)
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('landing-zone: error:')
