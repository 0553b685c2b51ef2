"""The engines (landing_zone/tools/engines.py): simulate, evaluate-flights, train-fleet and tune
give
the same outputs as processes here and as Ray tasks, whatever the number of workers; a Ray
worker killed mid-task is retried and the output is complete and identical; without Ray,
``--engine ray`` says in one line how to get it.

One local Ray cluster of 2 CPUs (``ray.init(num_cpus=2)``) serves the whole module. Outputs are
compared between two runs on this machine, never with pinned bytes: float output differs
between CPUs."""
from __future__ import annotations

import hashlib
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from landing_zone.tools.engines import INSTALL_HINT, check_engine, run_tasks
from landing_zone.errors import ConfigError, EngineError

REPO = Path(__file__).resolve().parents[2]
SMALL = 'C5-F8-P2-D32'


def digest(root: Path) -> dict[str, str]:
    """Every file a dataset directory holds (a leftover temporary file would show)."""
    return {str(f.relative_to(root)): hashlib.sha256(f.read_bytes()).hexdigest()
            for f in sorted(root.rglob('*')) if f.is_file()}


@pytest.fixture(scope='module')
def ray_cluster():
    ray = pytest.importorskip('ray')
    # The test module's own task functions (the killer below) travel by value: Ray's workers
    # cannot import test modules.
    ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])
    ray.init(num_cpus=2, include_dashboard=False, logging_level='warning')
    yield ray
    ray.shutdown()


# --- the engine itself ------------------------------------------------------------------------

def _square(x: int) -> int:
    return x * x


def _refuse(x: int) -> int:
    raise ConfigError(f'task {x} refuses')


def test_bad_engine_arguments_are_one_line_errors():
    with pytest.raises(EngineError, match='engine must be one of local, ray'):
        check_engine('dask')
    with pytest.raises(EngineError, match='--address names a Ray cluster'):
        check_engine('local', address='auto')
    with pytest.raises(EngineError, match='workers must be a positive integer'):
        list(run_tasks(_square, [1], workers=0))


def test_local_engine_runs_every_task_once():
    for workers in (1, 2):
        out = dict(run_tasks(_square, list(range(5)), workers=workers, start_method='spawn'))
        assert out == {i: i * i for i in range(5)}
    assert list(run_tasks(_square, [])) == []


def test_task_errors_come_back_as_they_were_raised(ray_cluster):
    for engine in ('local', 'ray'):
        with pytest.raises(ConfigError, match='task 1 refuses'):
            list(run_tasks(_refuse, [1], engine=engine, workers=2))


# --- simulate ---------------------------------------------------------------------------------

def test_simulate_same_bytes_across_engines_and_worker_counts(ray_cluster, tmp_path):
    from landing_zone.tools.sim.dataset import simulate_dataset

    args = dict(scenes=6, seed=5, shard_size=2, progress=False)
    runs = {}
    for name, kw in {'local1': dict(workers=1), 'local2': dict(workers=2),
                     'ray': dict(engine='ray', workers=2)}.items():
        s = simulate_dataset('synth2', tmp_path / name, **args, **kw)
        assert s['generated'] == 6 and s['shards'] == 3
        runs[name] = digest(tmp_path / name)
    assert len(runs['ray']) == 4  # meta.json and three shards, nothing else
    assert runs['local1'] == runs['local2'] == runs['ray']


def _shard_killing_itself_once(task):
    """The shard task, whose worker process dies on its first attempt at shard 1 (a marker
    file beside the dataset says it already died once)."""
    from landing_zone.tools.sim import dataset

    out, _, _, k, *_ = task
    marker = Path(out).parent / f'{Path(out).name}.killed-{k}'
    if k == 1 and not marker.exists():
        marker.touch()
        # die mid-shard, as a killed worker would: half a shard's temporary file left behind
        (Path(out) / 'shards' / f'shard-{k:05d}.npz.tmp-{os.getpid()}').write_bytes(b'PK')
        os._exit(1)
    return dataset._make_shard(task)  # the worker's module: the real one


def test_a_killed_worker_is_retried_and_the_dataset_is_whole(ray_cluster, tmp_path,
                                                             monkeypatch):
    from landing_zone.tools.sim import dataset

    args = dict(scenes=6, seed=5, shard_size=2, progress=False, workers=2)
    dataset.simulate_dataset('synth2', tmp_path / 'local', **args)
    monkeypatch.setattr(dataset, '_make_shard', _shard_killing_itself_once)
    s = dataset.simulate_dataset('synth2', tmp_path / 'ray', engine='ray', **args)
    assert (tmp_path / 'ray.killed-1').exists()  # the worker did die once
    assert s['generated'] == 6
    assert digest(tmp_path / 'ray') == digest(tmp_path / 'local')


def test_without_ray_engine_ray_says_how_to_get_it(tmp_path):
    # Ray made unimportable, as on an install without the [ray] extra
    code = ('import sys\n'
            'class Block:\n'
            '    def find_spec(self, name, path=None, target=None):\n'
            '        if name.split(".")[0] == "ray":\n'
            '            raise ModuleNotFoundError(f"No module named {name!r}", name=name)\n'
            'sys.meta_path.insert(0, Block())\n'
            'from landing_zone.tools.cli import main\n'
            'main(sys.argv[1:])\n')
    commands = [
        ['simulate', '--dataset', 'synth1', '--out', str(tmp_path / 'd'), '--engine', 'ray'],
        ['evaluate-flights', str(tmp_path / 'x.mcap'), '--engine', 'ray'],
        ['tune', '--data', str(tmp_path), '--engine', 'ray'],
        ['train-fleet', '--data', str(tmp_path), '--out-dir', str(tmp_path / 'f'),
         '--engine', 'ray'],
    ]
    for argv in commands:
        r = subprocess.run([sys.executable, '-c', code, *argv], cwd=tmp_path,
                           capture_output=True, text=True, timeout=120)
        assert r.returncode == 2, (argv, r.stderr)
        assert r.stderr.strip().splitlines() == [f'landing-zone: error: {INSTALL_HINT}'], argv
    assert not (tmp_path / 'd').exists() and not (tmp_path / 'f').exists()


# --- evaluate-flights -------------------------------------------------------------------------

@pytest.fixture(scope='module')
def flights(tmp_path_factory):
    from landing_zone.tools.sim.flight import flight_config, simulate_flight

    root = tmp_path_factory.mktemp('flights')
    bags = []
    for seed in (1, 2):
        cfg = flight_config('default', 'line', size=6.0, obstacles=2,
                            kinds=('rock', 'tire', 'cinder_block', 'box'), seed=seed)
        bags.append(simulate_flight(cfg, root / f'site{seed}.mcap').bag)
    return [Path(b) for b in bags]


def _figures(doc):
    """What must not depend on the engine: everything but the seconds."""
    drop = ('seconds', 'flights_per_s', 'engine', 'workers')
    return {k: ([{a: b for a, b in f.items() if a != 'seconds'} for f in v]
                if k == 'flights' else v) for k, v in doc.items() if k not in drop}


def test_flight_figures_count_what_a_planner_meets():
    """Obstacle tiles passed at 0.5 and at 0.9, safe tiles flagged (< 0.5), unjudged tiles;
    None where a class is missing; the markdown table shows each."""
    from landing_zone.tools.evaluate.flights import _figures as figures, markdown_flights
    f = figures(np.array([0.95, 0.6, 0.2, 0.4, 0.8]), np.array([0, 0, 0, 1, 1]), 8)
    assert f['obstacle_passed'] == pytest.approx(2 / 3)
    assert f['obstacle_passed_0.9'] == pytest.approx(1 / 3)
    assert f['safe_flagged'] == pytest.approx(1 / 2)
    assert f['obstacle_judged_safe'] == 2 and f['unjudged'] == pytest.approx(3 / 8)
    clear = figures(np.array([0.3, 0.9]), np.array([1, 1]), 2)
    assert clear['obstacle_passed'] is None and clear['obstacle_passed_0.9'] is None
    assert clear['safe_flagged'] == 0.5 and clear['auc'] is None
    sites = {'sites_listed': 1, 'sites_over_obstacle': 0, 'site_ece': None}
    table = markdown_flights({'flights': [dict(f, bag='a.mcap', **sites)],
                              'pooled': dict(clear, **sites)})
    assert '| a.mcap | 5 of 8 | ' in table and '66.7% (2 of 3) | 33.3% | 50.0% |' in table
    assert '| **pooled** | 2 of 2 | - | ' in table and '| - | - | 50.0% |' in table


@pytest.mark.slow
def test_evaluate_flights_same_figures_across_engines(ray_cluster, flights, model_file,
                                                      tmp_path):
    from landing_zone.io.labels import read_labels
    from landing_zone.tools.evaluate.flights import evaluate_flights

    local = evaluate_flights(flights, workers=1, model=model_file,
                             json_path=tmp_path / 'local.json')
    on_ray = evaluate_flights(flights, engine='ray', model=model_file)
    assert _figures(local) == _figures(on_ray)
    assert json.loads((tmp_path / 'local.json').read_text()) == json.loads(json.dumps(local))
    # the figures are those of the labels: every labelled tile counted, obstacles as labelled
    unsafe = [sum(not t['safe'] for t in read_labels(b.with_suffix('.labels.json'))['tiles'])
              for b in flights]
    assert [f['tiles_labelled'] for f in local['flights']] == [36, 36]
    pooled = local['pooled']
    assert pooled['tiles_labelled'] == 72
    assert pooled['tiles_judged'] == sum(f['tiles_judged'] for f in local['flights'])
    assert pooled['obstacle_tiles'] <= sum(unsafe) and pooled['obstacle_tiles'] > 0
    assert pooled['unjudged'] == pytest.approx(1 - pooled['tiles_judged'] / 72)
    for f in local['flights'] + [pooled]:
        for key in ('auc', 'ece', 'obstacle_passed', 'obstacle_passed_0.9', 'safe_flagged',
                    'site_ece'):
            assert f[key] is None or 0.0 <= f[key] <= 1.0
        assert 0 <= f['sites_over_obstacle'] <= f['sites_listed']
        assert 0 <= f['footprints_unsafe'] <= f['footprints']
    # the sites' figures pool by sums; a footprint of 3 x 3 tiles is scored when all its tiles
    # are labelled (16 inside the 6 x 6 m site) or one is labelled unsafe (centred beside it)
    for key in ('sites_listed', 'sites_over_obstacle', 'footprints', 'footprints_unsafe'):
        assert pooled[key] == sum(f[key] for f in local['flights'])
    assert 0 < pooled['footprints'] <= 2 * 8 * 8
    assert [Path(f['bag']).name for f in local['flights']] == ['site1.mcap', 'site2.mcap']


def test_evaluate_flights_refuses_a_flight_without_labels(flights, tmp_path):
    lone = tmp_path / 'lone.mcap'
    lone.write_bytes(flights[0].read_bytes())
    r = subprocess.run([sys.executable, '-m', 'landing_zone', 'evaluate-flights',
                        str(flights[0]), str(lone)], capture_output=True, text=True,
                       timeout=120)
    assert r.returncode == 2
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and 'lone.labels.json is missing' in lines[0]


# --- training fan-out -------------------------------------------------------------------------

@pytest.fixture(scope='module')
def tiny_data(tmp_path_factory):
    from landing_zone.tools.sim.dataset import simulate_dataset

    root = tmp_path_factory.mktemp('synth1') / 'data'
    simulate_dataset('synth1', root, scenes=16, workers=1, seed=3, progress=False)
    return root


def _weights(path: Path) -> dict[str, np.ndarray]:
    from safetensors.numpy import load_file
    return load_file(path)


@pytest.mark.slow
def test_fleet_members_same_weights_across_engines(ray_cluster, tiny_data, tmp_path):
    from landing_zone.tools.learn.fleet import fleet_jobs, train_fleet
    from landing_zone.tools.learn.train import TrainConfig

    cfg = TrainConfig(arch=SMALL, epochs=1, augment_copies=1, max_samples=8, val_fraction=0.25,
                      dropout=0.0, checkpoint_minutes=0.0, seed=4)
    jobs = fleet_jobs(cfg, members=2)
    assert [(n, c.seed) for n, c in jobs] == [('model_m0', 4), ('model_m1', 5)]
    local = train_fleet(tiny_data, tmp_path / 'local', jobs, workers=2)
    # on workers that replayed flights before (the module's cluster): fresh ones are used
    on_ray = train_fleet(tiny_data, tmp_path / 'ray', jobs, engine='ray')
    for name in ('model_m0', 'model_m1'):
        a = _weights(tmp_path / 'local' / f'{name}.safetensors')
        b = _weights(tmp_path / 'ray' / f'{name}.safetensors')
        assert a.keys() == b.keys() and all(np.array_equal(a[k], b[k]) for k in a)
        assert local['models'][name]['val_auc'] == on_ray['models'][name]['val_auc']
    m0 = _weights(tmp_path / 'local' / 'model_m0.safetensors')
    m1 = _weights(tmp_path / 'local' / 'model_m1.safetensors')
    assert not all(np.array_equal(m0[k], m1[k]) for k in m0)  # the seeds differ
    again = train_fleet(tiny_data, tmp_path / 'ray', jobs, engine='ray')
    assert not any(m['trained'] for m in again['models'].values())  # a rerun skips them
    assert json.loads((tmp_path / 'ray' / 'fleet.json').read_text())['models'].keys() == \
        {'model_m0', 'model_m1'}


def test_lofo_fleet_names_one_model_per_family():
    from landing_zone.tools.learn.fleet import fleet_jobs, lofo_families
    from landing_zone.tools.learn.train import TrainConfig

    holds = lofo_families()
    assert 'obstacle:rock' in holds and 'vegetation:lodged' in holds
    jobs = fleet_jobs(TrainConfig(), holds)
    assert [n for n, _ in jobs] == [f'lofo_{h.replace(":", "_")}' for h in holds]
    assert all(c.hold_out == [h] for (_, c), h in zip(jobs, holds))
    with pytest.raises(ConfigError, match='unknown obstacle family'):
        fleet_jobs(TrainConfig(), ['obstacle:unicorn'])


@pytest.mark.slow
def test_tune_same_draws_across_engines(ray_cluster, tiny_data, tmp_path):
    from landing_zone.tools.learn.tune import TuneConfig, tune

    # seed 0: draws 0 and 1 are pruned unseen (72M and 698M weights), draw 2 is trained
    cfg = TuneConfig(trials=3, epochs=1, augment_copies=1, max_samples=8, max_params=300_000,
                     parallel=2, threads=1)
    runs = {}
    for engine in ('local', 'ray'):
        rows = tune(tiny_data, cfg, storage=f'journal:{tmp_path / engine / "tune.journal"}',
                    out_dir=tmp_path / engine / 'models', progress=False, engine=engine)
        runs[engine] = sorted((r['draw'], r['spec'], r['state'], r['val_auc']) for r in rows)
    assert [(d, state) for d, _, state, _ in runs['local']] == [
        (0, 'PRUNED'), (1, 'PRUNED'), (2, 'COMPLETE')]
    assert runs['local'] == runs['ray']
