"""The guard: opaque structure above the ground fires, grass does not, unknown stays unknown."""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from landing_zone.config import AssessorConfig, GuardConfig, MapConfig
from landing_zone.errors import ConfigError
from landing_zone.judging.guard import guard_p_safe, solid_structure

VS = 0.05
TV = 20  # voxels per 1 m tile


def ground_box(nx=2, ny=1, nz=40, ground_k=10, rays=20):
    """Counts of flat ground at voxel ``ground_k`` seen by ``rays`` rays per column."""
    hits = np.zeros((nx * TV, ny * TV, nz), np.uint32)
    passes = np.zeros_like(hits)
    hits[:, :, ground_k] = rays
    passes[:, :, ground_k + 1:] = rays
    return hits, passes


def add_block(hits, passes, x, y, k0, k1, rays=20):
    """An opaque block over voxels [x0, x1) x [y0, y1) x [k0, k1): rays end on its top and
    sides, nothing reaches inside, the ground under it is hidden."""
    (x0, x1), (y0, y1) = x, y
    hits[x0:x1, y0:y1, :k1] = 0
    passes[x0:x1, y0:y1, :k1] = 0
    hits[x0:x1, y0:y1, k1 - 1] = rays
    passes[x0:x1, y0:y1, k1:] = rays
    # the sides: a few rays end there, the voxel beneath (inside the block) sees none
    hits[x0, y0:y1, k0:k1] = np.maximum(hits[x0, y0:y1, k0:k1], min(rays, 6))


def judge(hits, passes, ground_k=10, tiles=((0, 0), (1, 0)), config=None):
    tiles = np.array(tiles, np.int64)
    gz = np.full(len(tiles), (ground_k + 0.5) * VS)
    return solid_structure(hits, passes, np.zeros(3, np.int64), VS, tiles, gz, TV,
                           config or GuardConfig())


def test_an_opaque_block_fires_on_its_tile_only():
    hits, passes = ground_box()
    add_block(hits, passes, (4, 12), (5, 12), 11, 16)  # 40 x 35 cm, 25 cm high, in tile 0
    r = judge(hits, passes)
    assert r.fired.tolist() == [True, False]
    assert r.hits[0] >= 8 * 7 * 20 and r.hits[1] == 0
    # its top: the voxel 15..16 above the ground voxel, upper face 0.275 m above its centre
    assert r.height[0] == pytest.approx(0.275) and np.isnan(r.height[1])


def test_grass_that_rays_pass_through_does_not_fire():
    hits, passes = ground_box()
    # every voxel of a 40 cm canopy holds returns, but most rays go on to the ground
    hits[:, :, 11:19] = 4
    passes[:, :, 11:19] = 16
    r = judge(hits, passes)
    assert not r.fired.any() and (r.hits == 0).all()


def test_a_shadowless_dense_layer_does_not_fire():
    hits, passes = ground_box()
    # voxels where half the rays end, yet as many rays cross the voxel beneath: a canopy
    # dense enough to stop rays is still no solid when the rays go on below it
    hits[:, :, 14] = 10
    passes[:, :, 13] = 10
    passes[:, :, 14] = 10
    assert not judge(hits, passes).fired.any()


def test_a_thin_wall_seen_from_the_side_fires_by_its_shadow_beside_it():
    hits, passes = ground_box()
    # a 5 cm thick wall, 25 cm high, 40 cm long, across rays that come from -x: its voxels
    # end half the rays reaching them, the rest cross them (the wall fills part of a voxel) and
    # the voxels beneath are wall too, so only the voxels behind it (+x) lie in its shadow
    x, (y0, y1), (k0, k1) = 8, (4, 12), (11, 16)
    hits[x, y0:y1, k0:k1] = 10
    passes[x, y0:y1, k0:k1] = 5
    hits[x + 1:x + 4, y0:y1, :k1] = 0
    passes[x + 1:x + 4, y0:y1, :k1] = 0
    assert judge(hits, passes).fired[0]
    # the same voxels with the rays going on behind them: grass, not a wall
    passes[x + 1:x + 4, y0:y1, :k1] = 20
    assert not judge(hits, passes).fired[0]


def test_low_structure_is_below_the_guard():
    hits, passes = ground_box()
    add_block(hits, passes, (4, 12), (5, 12), 11, 13)  # 10 cm high: its top under 12 cm
    assert not judge(hits, passes).fired.any()
    r = judge(hits, passes, config=GuardConfig(min_height=0.05))
    assert r.fired[0]


def test_a_block_reaching_in_from_the_neighbour_is_seen_whole():
    hits, passes = ground_box()
    add_block(hits, passes, (14, 21), (5, 12), 11, 16)  # 1 voxel (5 cm) inside tile 1
    r = judge(hits, passes)
    assert r.fired.tolist() == [True, True]
    # tile 1 traces the cluster 20 cm back across its edge, more than its own 5 cm
    narrow = judge(hits, passes, config=GuardConfig(margin=0.0))
    assert 0 < narrow.hits[1] < r.hits[1] < r.hits[0]


def test_a_block_ending_at_the_edge_fires_within_one_voxel_of_reach():
    hits, passes = ground_box()
    # its last column is voxel 19, tile 0's last: the map cannot tell whether it reaches into
    # tile 1 by less than a voxel
    add_block(hits, passes, (12, 20), (5, 12), 11, 16)
    assert judge(hits, passes).fired.tolist() == [True, True]
    assert judge(hits, passes, config=GuardConfig(reach=0.0)).fired.tolist() == [True, False]
    # a voxel of open ground between them: tile 1 is clear
    hits, passes = ground_box()
    add_block(hits, passes, (11, 19), (5, 12), 11, 16)
    assert judge(hits, passes).fired.tolist() == [True, False]
    with pytest.raises(ConfigError, match='guard.reach'):
        GuardConfig(reach=0.3).validate()


def test_too_few_returns_do_not_fire():
    hits, passes = ground_box()
    add_block(hits, passes, (4, 6), (5, 6), 11, 14, rays=5)  # 10 x 5 x 15 cm, 10 returns
    r = judge(hits, passes)
    assert 0 < r.hits[0] < GuardConfig().min_cluster_hits and not r.fired[0]


def test_tiles_without_ground_never_fire():
    hits, passes = ground_box()
    add_block(hits, passes, (4, 12), (5, 12), 11, 16)
    tiles = np.array([[0, 0], [1, 0]], np.int64)
    r = solid_structure(hits, passes, np.zeros(3, np.int64), VS, tiles,
                        np.array([np.nan, np.nan]), TV, GuardConfig())
    assert not r.fired.any() and np.isnan(r.height).all()


def test_the_cap_lowers_p_safe_and_unknown_stays_unknown():
    hits, passes = ground_box(nx=3)
    add_block(hits, passes, (4, 12), (5, 12), 11, 16)
    add_block(hits, passes, (44, 52), (5, 12), 11, 16)
    r = judge(hits, passes, tiles=((0, 0), (1, 0), (2, 0)))
    assert r.fired.tolist() == [True, False, True]
    p = guard_p_safe(np.array([0.99, 0.97, np.nan], np.float32), r, GuardConfig(max_p_safe=0.05))
    assert p[0] == pytest.approx(0.05) and p[1] == pytest.approx(0.97) and np.isnan(p[2])
    low = guard_p_safe(np.array([0.01, 0.5, 0.2], np.float32), r, GuardConfig())
    assert low[0] == pytest.approx(0.01)  # a cap, never a raise


def test_the_guard_is_deterministic():
    rng = np.random.default_rng(3)
    hits = rng.integers(0, 6, (60, 40, 40)).astype(np.uint32)
    passes = rng.integers(0, 6, (60, 40, 40)).astype(np.uint32)
    tiles = np.array([[0, 0], [1, 0], [2, 0], [0, 1], [1, 1], [2, 1]], np.int64)
    gz = np.full(6, 0.3)
    cfg = GuardConfig(min_cluster_hits=1)
    a = solid_structure(hits, passes, np.zeros(3, np.int64), VS, tiles, gz, TV, cfg)
    b = solid_structure(hits.copy(), passes.copy(), np.zeros(3, np.int64), VS, tiles, gz, TV,
                        cfg)
    assert a.hits.sum() > 0
    for name in ('fired', 'hits', 'voxels', 'height'):
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name))


def test_guard_parameters_are_checked_and_flat():
    with pytest.raises(ConfigError, match='guard.min_hit_ratio'):
        GuardConfig(min_hit_ratio=0.0).validate()
    with pytest.raises(ConfigError, match='guard.max_height'):
        GuardConfig(min_height=0.5, max_height=0.4).validate()
    flat = AssessorConfig().to_flat()
    assert flat['guard.enabled'] is True and 'guard.max_p_safe' in flat
    cfg = AssessorConfig.from_flat({'guard.min_cluster_hits': 40, 'guard.enabled': False})
    assert cfg.guard.min_cluster_hits == 40 and cfg.guard.enabled is False


# --- on simulated flights (the simulator's tall grass, a box inserted into the flight) ---------

@pytest.fixture(scope='module')
def grass_flight(tmp_path_factory):
    """A 6 m site of tall grass (blades 0.3-0.45 m, 1000 per m^2 in a typical patch) and the
    same flight with a 40 x 30 x 25 cm box standing in the grass."""
    from landing_zone.tools.sim.insert import insert_obstacles
    from landing_zone.tools.sim.placement import SINK, ground_height
    from landing_zone.tools.sim.recorded import read_flight
    from landing_zone.tools.sim.flight import flight_config, simulate_flight
    from landing_zone.tools.sim.obstacles import Obstacle, ObstacleModel
    from landing_zone.tools.sim.shapes import box_parts, normalise

    out = tmp_path_factory.mktemp('guard')
    cfg = flight_config('tall', 'line', size=6.0, obstacles=0, seed=3, grass_density=1000.0)
    clear = simulate_flight(cfg, out / 'grass.mcap').bag
    v, f = box_parts([((0.0, 0.0, 0.0), (0.4, 0.3, 0.25))])
    model = ObstacleModel('test_box', 'box', 'test', normalise(v), f)
    points = read_flight(clear).points
    g = ground_height(points, 0.5, 0.5, 0.6)
    box = Obstacle(model, 0.5, 0.5, g - SINK, 0.3)
    boxed = insert_obstacles(clear, out / 'box.mcap', obstacles=[box], seed=1).bag
    return clear, boxed, out / 'box.labels.json'


def assess_flight(bag, size=8.0, **guard):
    from landing_zone.assessor import Assessor
    from landing_zone.tools.sim.recorded import read_flight

    cfg = AssessorConfig(map=MapConfig(size_xy=size))
    for k, v in guard.items():
        setattr(cfg.guard, k, v)
    a = Assessor(cfg, center=(0.0, 0.0))
    fl = read_flight(bag)
    for c in range(len(fl.origins)):
        if np.isfinite(fl.origins[c]).all():
            a.integrate(fl.points[fl.cloud == c], fl.origins[c])
    return a.assess()


@pytest.mark.slow
def test_a_box_in_tall_grass_fires_and_the_grass_alone_does_not(grass_flight):
    clear, boxed, labels = grass_flight
    threshold = GuardConfig().min_cluster_hits
    grass = assess_flight(clear)
    judged = grass.known
    assert judged.sum() >= 30
    # the tallest solid cluster of the grass stays well below the threshold: not a near miss
    assert not grass.guard.any() and grass.guard_hits[judged].max() <= threshold // 2
    box = assess_flight(boxed)
    truth = {(t['x'], t['y']): t['safe'] for t in json.loads(labels.read_text())['tiles']}
    unsafe = [k for k in range(len(box)) if truth.get(tuple(box.centers[k])) is False]
    assert unsafe and box.guard[unsafe].all()
    assert (box.guard_hits[unsafe] >= 3 * threshold).all()  # hundreds of returns on the box
    assert (box.p_safe[unsafe] <= GuardConfig().max_p_safe).all()
    assert np.nanmax(box.guard_height[unsafe]) == pytest.approx(0.25, abs=0.08)
    others = np.array([truth.get(tuple(c), True) for c in box.centers]) & box.known
    assert not box.guard[others].any()  # nowhere else
    report = box.to_report()
    assert {(e['x'], e['y']) for e in report['reasons']} == {
        tuple(box.centers[k]) for k in unsafe}
    assert all(e['reason'].startswith('solid structure') for e in report['reasons'])


@pytest.mark.slow
def test_the_guard_leaves_unknown_tiles_unknown_and_repeats_itself(grass_flight):
    _, boxed, _ = grass_flight
    a = assess_flight(boxed, size=20.0)
    b = assess_flight(boxed, size=20.0)
    np.testing.assert_array_equal(a.p_safe, b.p_safe)
    np.testing.assert_array_equal(a.guard_hits, b.guard_hits)
    assert (~a.known).any()  # the map reaches beyond the site: tiles nobody saw
    assert not a.guard[~a.known].any()
    off = assess_flight(boxed, size=20.0, enabled=False)
    np.testing.assert_array_equal(np.isnan(off.p_safe), np.isnan(a.p_safe))
    np.testing.assert_array_equal(off.p_safe, a.p_net)  # the network's own P(safe)
    assert not off.guard.any()


def test_the_guard_on_simulated_patches_fires_on_boxes_not_on_open_ground():
    """voxelize_guarded gives the network the cubes voxelize gives it (cut_patch on the counts
    patch_counts reads is scene_to_input) and the guard's finding from the same counts: it
    fires on the toy boxes only (at 4400 returns/m^2), in a loader worker as in this process."""
    from landing_zone.config import TileConfig
    from landing_zone.judging.patches import (cut_patch, patch_counts, patch_ground,
                                              scene_to_input)
    from landing_zone.tools.learn.samples import voxelize
    from landing_zone.tools.evaluate.scene_guard import voxelize_guarded
    from landing_zone.tools.learn.scenes import ScenePack
    from test_train import toy_scene
    rng = np.random.default_rng(3)
    scenes = [toy_scene(rng, i % 2 == 0, n=40000) for i in range(6)]
    mcfg, tcfg = MapConfig(), TileConfig()
    counts = patch_counts(scenes[0].points, scenes[0].origins, mcfg, tcfg)
    cube = cut_patch(counts, mcfg, tcfg, patch_ground(counts, mcfg, tcfg)).inputs
    assert np.array_equal(cube, scene_to_input(scenes[0].points, scenes[0].origins, mcfg,
                                               tcfg).inputs)
    pack = ScenePack.from_scenes(scenes)
    x, y, found = voxelize_guarded(pack, mcfg, tcfg, GuardConfig())
    x0, y0 = voxelize(pack, mcfg, tcfg)
    assert torch.equal(x, x0) and torch.equal(y, y0)
    labels = np.array([s.label for s in scenes])
    assert found.fired.tolist() == (labels == 0).tolist()
    assert np.all(found.hits[labels == 0] >= GuardConfig().min_cluster_hits)
    assert np.all(np.isfinite(found.height[labels == 0]))
    pack.share_memory()
    x1, _, again = voxelize_guarded(pack, mcfg, tcfg, GuardConfig(), workers=1)
    assert torch.equal(x1, x0) and again.fired.tolist() == found.fired.tolist()
    assert again.hits.tolist() == found.hits.tolist()


def test_evaluate_with_the_guard_judges_as_the_assessor_does(tmp_path):
    """evaluate(..., guard=True) caps each CNN's P(safe) where the guard fires on the scene
    (here the toy boxes), leaves the other scenes' P(safe) as the network gave it, and names
    the rows '... + guard' (the shipped model, real scoring)."""
    from landing_zone.assessor import default_model_path
    from landing_zone.judging.checkpoint import load_model, save_model
    from landing_zone.tools.evaluate.roc import evaluate_scenes
    from test_train import toy_scene
    rng = np.random.default_rng(3)
    scenes = [toy_scene(rng, i % 2 == 0, n=40000) for i in range(6)]
    unsafe = np.array([s.label == 0 for s in scenes])
    # the shipped net made lenient (its offset raised) so that the cap has P(safe) to lower
    net, meta = load_model(default_model_path())
    net.temperature, net.offset = 1000.0, 3.0  # P(safe) near 0.95 everywhere
    lenient = tmp_path / 'lenient.safetensors'
    save_model(lenient, net, meta)
    runs = {}
    for guard in (False, True):
        out = tmp_path / f'scores_{guard}.json'
        res = evaluate_scenes(scenes, 'toy', 'test', lenient, scores_path=out, guard=guard)
        (name, scores), = json.loads(out.read_text())['methods'].items()
        runs[guard] = name, np.asarray(scores), res
    (plain_name, plain, _), (name, capped, res) = runs[False], runs[True]
    assert name == f'{plain_name} + guard' and f'| {name} |' in res['table']
    assert res['methods'][name]['ece'] is not None
    assert np.all(capped[unsafe] <= GuardConfig().max_p_safe + 1e-6)
    assert np.allclose(capped[~unsafe], plain[~unsafe])
    assert plain[unsafe].max() > GuardConfig().max_p_safe  # the cap had something to do
