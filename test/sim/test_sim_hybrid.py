"""The hybrid dataset: patches cut from small simulated flights, half with an inserted obstacle,
read back through SceneDataset and scene_to_input like synth2; deterministic and resumable."""
from __future__ import annotations

import json

import numpy as np
import pytest

from landing_zone.tools import cli
from landing_zone.tools.sim.recorded import read_flight
from landing_zone.tools.sim.shards import SceneDataset
from landing_zone.tools.sim.flight import flight_config, simulate_flight
from landing_zone.tools.sim.hybrid import column_rays, simulate_hybrid
from landing_zone.tools.sim.library import get_model, models
from landing_zone.tools.sim.obstacles import Obstacle
from landing_zone.judging.patches import scene_to_input
from test_insert import slab_hits


@pytest.fixture(scope='module')
def flights(tmp_path_factory):
    """Two 5 m sites with grass and no obstacles (16 clear inner tiles each)."""
    d = tmp_path_factory.mktemp('flights')
    out = []
    for seed in (0, 1):
        cfg = flight_config(size=5.0, obstacles=0, grass_density=300.0, seed=seed)
        out.append(simulate_flight(cfg, d / f'site{seed}.mcap', threads=1).bag)
    return out


@pytest.fixture(scope='module')
def hybrid(flights, tmp_path_factory):
    out = tmp_path_factory.mktemp('hybrid') / 'set'
    summary = simulate_hybrid(flights, out, patches=8, seed=4, shard_size=3, progress=False)
    return out, summary


def test_loads_like_synth2_with_both_labels(hybrid):
    out, summary = hybrid
    meta = json.loads((out / 'meta.json').read_text())
    assert meta['dataset'] == 'hybrid' and meta['complete'] and meta['split_by'] == 'flight'
    assert [f['split'] for f in meta['flights']] == ['train', 'test']
    train, test = SceneDataset(out, 'train'), SceneDataset(out, 'test')
    assert len(train) == len(test) == 8 == summary['counts']['train']['safe'] * 2
    for ds in (train, test):
        assert sorted(set(ds.labels.tolist())) == [0, 1]
        assert (ds.labels == 0).sum() == 4
    for ds, group in ((train, 'train'), (test, 'test')):
        allowed = {m.name for m in models(('rock', 'tire', 'cinder_block'), group)}
        for scene in ds:
            assert scene.params['split'] == group
            assert scene.points.dtype == np.float32 and scene.origins.shape == scene.points.shape
            ob = scene.params['obstacle']
            assert (ob is None) == (scene.label == 1)
            if ob is not None:
                assert ob['model'] in allowed


def test_unsafe_scenes_hold_returns_on_their_obstacle(hybrid):
    out, _ = hybrid
    ds = SceneDataset(out, 'all')
    for scene in ds:
        on = scene.hit_class == 2
        if scene.label == 1:
            assert not on.any()  # flights without obstacles, nothing inserted
            continue
        assert on.sum() == scene.params['altered'] > 10
        ob = scene.params['obstacle']
        v = Obstacle(get_model(ob['model']), ob['x'], ob['y'], ob['z'], ob['yaw']).vertices()
        lo, hi = v.min(axis=0) - 0.1, v.max(axis=0) + 0.1  # 4 sigma of range noise
        p = scene.points[on]
        assert np.all((p >= lo) & (p <= hi))
        # the obstacle overlaps the tile (centre at most half its radius outside)
        assert max(abs(ob['x']), abs(ob['y'])) < 0.5 + 0.5 * get_model(ob['model']).radius


def test_scene_to_input_of_a_hybrid_scene(hybrid):
    ds = SceneDataset(hybrid[0], 'all')
    for i in (0, len(ds) - 1):
        scene = ds[i]
        batch = scene_to_input(scene.points, scene.origins)
        assert batch.inputs.shape == (1, 1, 32, 32, 32)
        assert batch.valid[0] and abs(batch.ground_z[0]) < 0.1
        # the patch frame: the tile is centred on (0, 0) and the column kept around it
        inside = np.all(np.abs(scene.points[:, :2]) <= 0.5, axis=1)
        assert inside.sum() > 1000


def test_same_seed_same_bytes_and_resume(flights, hybrid, tmp_path):
    out, _ = hybrid
    again = tmp_path / 'again'
    simulate_hybrid(flights, again, patches=8, seed=4, shard_size=3, progress=False)
    shards = sorted(p.name for p in (out / 'shards').iterdir())
    assert shards == sorted(p.name for p in (again / 'shards').iterdir()) and len(shards) == 6
    for name in shards:
        assert (out / 'shards' / name).read_bytes() == (again / 'shards' / name).read_bytes()
    assert (out / 'meta.json').read_text() == (again / 'meta.json').read_text()
    # an interrupted run: a shard missing is made again, the others are kept
    (again / 'shards' / shards[1]).unlink()
    s = simulate_hybrid(flights, again, patches=8, seed=4, shard_size=3, progress=False)
    assert s['generated'] == 3 and s['skipped'] == 13
    assert (out / 'shards' / shards[1]).read_bytes() == (again / 'shards' / shards[1]).read_bytes()
    other = tmp_path / 'other'
    simulate_hybrid(flights, other, patches=8, seed=5, shard_size=3, progress=False)
    assert (other / 'shards' / shards[0]).read_bytes() != (out / 'shards' / shards[0]).read_bytes()


def test_column_rays_match_a_slab_test(flights):
    fr = read_flight(flights[0])
    tiles = np.array([[-1, -1], [0, 0], [1, -2]])
    centres = tiles + 0.5
    boxes = np.stack([np.column_stack([centres - 0.8, np.full(3, -1.0)]),
                      np.column_stack([centres + 0.8, np.full(3, 2.0)])], axis=1)
    rays = column_rays(fr.points, fr.cloud, fr.origins, tiles, boxes)
    o = fr.ray_origins()
    for q in range(3):
        ref = np.flatnonzero(slab_hits(o, fr.points, boxes[q, 0], boxes[q, 1])
                             | np.all((fr.points >= boxes[q, 0]) & (fr.points <= boxes[q, 1]),
                                      axis=1))
        np.testing.assert_array_equal(rays[q], ref)
        assert len(ref) > 1000


def test_one_flight_splits_by_tile_and_bad_input(flights, tmp_path, capsys):
    s = simulate_hybrid(flights[:1], tmp_path / 'one', patches=16, seed=0, progress=False)
    assert s['split_by'] == 'tile' and s['scenes'] == 16
    assert s['counts']['test']['safe'] + s['counts']['test']['unsafe'] > 0
    with pytest.raises(SystemExit) as exc:
        cli.main(['simulate', '--dataset', 'hybrid', '--out', str(tmp_path / 'x')])
    assert exc.value.code == 2
    assert capsys.readouterr().err.strip().splitlines() == [
        'landing-zone: error: --dataset hybrid needs the flights: --from BAG (repeat for more)']
    assert not (tmp_path / 'x').exists()
