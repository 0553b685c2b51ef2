"""The scrolling density map: lattice placement, ring-buffer scrolling, reads, dirty tiles."""
from __future__ import annotations

import numpy as np
import pytest

from landing_zone.config import MapConfig
from landing_zone.mapping.density_map import DensityMap
from landing_zone.errors import ConfigError

VS = 0.25


def make_map(nxy=16, nz=12, center=(0.0, 0.0, 0.0), tile_vox=4) -> DensityMap:
    cfg = MapConfig(voxel_size=VS, size_xy=nxy * VS, size_z=nz * VS, z_below=nz * VS / 2)
    return DensityMap(cfg, center=center, tile_vox=tile_vox)


def fill_random(dmap: DensityMap, n: int, seed: int) -> None:
    """Rays from above the map down to points spread over (and a bit beyond) its box."""
    rng = np.random.default_rng(seed)
    lo, hi = dmap.bounds
    pts = rng.uniform(lo - 0.5, hi + 0.5, (n, 3))
    pts[:, 2] = rng.uniform(lo[2], (lo[2] + hi[2]) / 2, n)
    origins = pts + rng.uniform(-1.0, 1.0, (n, 3))
    origins[:, 2] = hi[2] + 1.0
    dmap.integrate(pts, origins)


def global_counts(dmap: DensityMap, lo, shape):
    return dmap.counts(np.asarray(lo, np.int64), np.asarray(shape, np.int64))


def test_default_geometry_and_memory():
    dmap = DensityMap()
    assert dmap.shape == (400, 400, 80) and dmap.voxel_size == 0.05
    np.testing.assert_array_equal(dmap.lo, [-200, -200, -40])
    nvox = 400 * 400 * 80
    # hot bytes for hits and passes plus the sparse cold index: well under 4 bytes per voxel
    assert 2 * nvox <= dmap.nbytes <= 2.1 * nvox
    h, p = dmap.counts()
    assert h.shape == (400, 400, 80) and h.dtype == np.uint32 and p.dtype == np.uint32
    assert not dmap.observed().any()
    assert np.all(dmap.density() == 0.5)


def test_recenter_places_window_on_the_lattice():
    dmap = make_map(16, 12)
    assert dmap.recenter((1.3, -0.2, 0.6)) > 0
    # floor(c / vs) - (nx // 2, ny // 2, round(z_below / vs)) with z_below = 1.5 m = 6 voxels
    np.testing.assert_array_equal(dmap.lo, [5 - 8, -1 - 8, 2 - 6])
    assert dmap.recenter((1.3, -0.2, 0.6)) == 0  # same window: nothing moves
    assert dmap.recenter((1.26, -0.01, 0.51)) == 0  # same voxel of the centre
    lo_m, hi_m = dmap.bounds
    np.testing.assert_allclose(hi_m - lo_m, [4.0, 4.0, 3.0])


@pytest.mark.parametrize('shift', [
    (1, 0, 0), (-1, 0, 0), (0, 3, 0), (0, -5, 0), (0, 0, 2), (0, 0, -7),
    (5, -6, 3), (-9, 11, -4), (15, -15, 11), (4, 4, 4), (-13, 2, 9),
])
def test_counts_follow_world_position_and_entering_cells_are_unobserved(shift):
    dmap = make_map(16, 12)
    fill_random(dmap, 3000, seed=1)
    old_lo = dmap.lo.copy()
    h0, p0 = dmap.counts()
    assert h0.sum() > 100 and p0.sum() > 1000
    new_lo = old_lo + np.array(shift)
    entered = dmap.set_lo(new_lo)
    np.testing.assert_array_equal(dmap.lo, new_lo)
    n = np.array(dmap.shape)
    assert entered == n.prod() - np.prod(n - np.abs(shift))
    h1, p1 = dmap.counts()
    # the overlap of old and new windows keeps its counts at the same world voxels
    a = np.maximum(old_lo, new_lo)
    b = np.minimum(old_lo + n, new_lo + n)
    old_sel = tuple(slice(a[i] - old_lo[i], b[i] - old_lo[i]) for i in range(3))
    new_sel = tuple(slice(a[i] - new_lo[i], b[i] - new_lo[i]) for i in range(3))
    np.testing.assert_array_equal(h1[new_sel], h0[old_sel])
    np.testing.assert_array_equal(p1[new_sel], p0[old_sel])
    # everything else entered and starts unobserved, although its storage held old data
    fresh = np.ones(dmap.shape, bool)
    fresh[new_sel] = False
    assert fresh.sum() == entered
    assert not h1[fresh].any() and not p1[fresh].any()
    assert np.all(dmap.density()[fresh] == 0.5)
    # reading the old window by global index: what left reads 0, what stayed is unchanged
    hg, pg = global_counts(dmap, old_lo, n)
    np.testing.assert_array_equal(hg[old_sel], h0[old_sel])
    assert hg.sum() == h0[old_sel].sum() and pg.sum() == p0[old_sel].sum()


def test_scrolling_step_by_step_equals_one_jump():
    """The ring buffer is invisible: a window moved in steps holds what one jump keeps."""
    steps = [(3, 0, 0), (0, -7, 2), (5, -1, 1), (2, 0, 0)]  # monotone per axis
    walked = make_map(16, 12)
    jumped = make_map(16, 12)
    for dmap in (walked, jumped):
        fill_random(dmap, 1500, seed=2)
    for step in steps:
        walked.set_lo(walked.lo + step)
    jumped.set_lo(jumped.lo + np.sum(steps, axis=0))
    np.testing.assert_array_equal(walked.lo, jumped.lo)
    for dmap in (walked, jumped):
        fill_random(dmap, 1500, seed=3)
    for x, y in zip(walked.counts(), jumped.counts()):
        np.testing.assert_array_equal(x, y)
    assert walked.counts()[1].sum() > 0


def test_shift_larger_than_the_map_clears_everything():
    for shift in [(16, 0, 0), (0, -16, 0), (0, 0, 12), (-40, 3, 1)]:
        dmap = make_map(16, 12)
        fill_random(dmap, 1000, seed=4)
        assert dmap.observed().any()
        assert dmap.set_lo(dmap.lo + shift) == 16 * 16 * 12
        assert not dmap.observed().any()
        assert dmap.counts()[1].sum() == 0


def test_sub_window_reads_and_outside_reads_zero():
    dmap = make_map(16, 12)
    fill_random(dmap, 2000, seed=5)
    h, p = dmap.counts()
    d = dmap.density()
    lo = dmap.lo
    # a box that sticks out of the window on every side
    q_lo = lo + (-3, 5, -2)
    q_n = np.array([10, 14, 20])
    hq, pq = global_counts(dmap, q_lo, q_n)
    dq = dmap.density(q_lo, q_n)
    oq = dmap.observed(q_lo, q_n)
    for i in range(q_n[0]):
        for j in range(q_n[1]):
            for k in range(q_n[2]):
                g = q_lo + (i, j, k) - lo
                if np.all((g >= 0) & (g < dmap.shape)):
                    assert hq[i, j, k] == h[tuple(g)] and pq[i, j, k] == p[tuple(g)]
                    assert dq[i, j, k] == d[tuple(g)]
                else:
                    assert hq[i, j, k] == 0 and pq[i, j, k] == 0 and dq[i, j, k] == 0.5
                    assert not oq[i, j, k]
    np.testing.assert_array_equal(dmap.observed(), (h + p) > 0)
    hf = h.astype(np.float64)
    np.testing.assert_array_equal(d, ((hf + 1) / (hf + p + 2)).astype(np.float32))
    # into caller-provided arrays (reused: stale values must go)
    bufs = (np.full(tuple(q_n), 7, np.uint32), np.full(tuple(q_n), 7, np.uint32))
    got = dmap.counts(q_lo, q_n, out=bufs)
    assert got[0] is bufs[0] and got[1] is bufs[1]
    np.testing.assert_array_equal(got[0], hq)
    np.testing.assert_array_equal(got[1], pq)
    with pytest.raises(ConfigError, match='out must be'):
        dmap.counts(q_lo, q_n, out=(np.zeros(3, np.uint32), np.zeros(3, np.uint32)))
    # a box entirely outside, and an empty box
    assert global_counts(dmap, lo + 100, (3, 3, 3))[0].sum() == 0
    assert dmap.density(lo, (0, 4, 4)).shape == (0, 4, 4)


def test_bad_query_arguments_raise():
    dmap = make_map()
    with pytest.raises(ConfigError, match='shape'):
        dmap.counts(dmap.lo, (2, -1, 3))
    with pytest.raises(ConfigError, match='lo must be three integers'):
        dmap.counts((0.5, 1.0, 2.0), (1, 1, 1))
    with pytest.raises(ConfigError, match='map lo must be three integers'):
        dmap.set_lo((1, 2))
    with pytest.raises(ConfigError, match='center'):
        dmap.recenter((np.nan, 0.0, 0.0))
    with pytest.raises(ConfigError, match='voxel_size'):
        DensityMap(MapConfig(voxel_size=0.0))


def test_cold_counts_survive_scrolling_and_are_released_when_they_leave():
    dmap = make_map(16, 12)
    lo = dmap.lo
    cell = lo + (2, 9, 3)  # x near the low edge, so a shift of +5 in x drops it
    keep = lo + (12, 4, 3)
    pts = (np.array([cell, keep]) + 0.5) * VS
    origins = pts + (0.0, 0.0, 2 * VS)
    dmap.integrate(np.repeat(pts, 300, axis=0), np.repeat(origins, 300, axis=0))
    assert dmap.cold_blocks == 2
    dmap.set_lo(lo + (5, 0, 0))
    assert dmap.cold_blocks == 1  # the block of the cell that left was given back
    h, p = global_counts(dmap, keep, (1, 1, 3))
    assert h[0, 0, 0] == 300 and list(p[0, 0, 1:]) == [300, 300]
    assert global_counts(dmap, cell, (1, 1, 1))[0].sum() == 0
    # the cell's storage is reused by an entering voxel: it must start from 0, not 256+
    entering = lo + (2 + 16, 9, 3)
    assert global_counts(dmap, entering, (1, 1, 1))[0].sum() == 0
    dmap.integrate((entering[None] + 0.5) * VS, (entering + (0.5, 0.5, 1.5)) * VS)
    assert global_counts(dmap, entering, (1, 1, 1))[0][0, 0, 0] == 1


def _changed_tiles(before, after, dmap, lo):
    changed = np.any((before[0] != after[0]) | (before[1] != after[1]), axis=2)
    idx = np.argwhere(changed) + lo[:2]
    return {tuple(int(v) for v in k) for k in np.floor_divide(idx, dmap.tile_vox)}


def test_dirty_tiles_cover_every_change():
    dmap = make_map(16, 12, tile_vox=4)
    assert len(dmap.pop_dirty()) == 0
    rng = np.random.default_rng(6)
    for batch in range(5):
        before = dmap.counts()
        lo = dmap.lo
        pts = rng.uniform(*dmap.bounds, (4, 3))
        origins = pts + rng.uniform(-0.6, 0.6, (4, 3))
        dmap.integrate(pts, origins)
        dirty = {tuple(k) for k in dmap.pop_dirty().tolist()}
        changed = _changed_tiles(before, dmap.counts(), dmap, lo)
        assert changed and changed <= dirty
        assert len(dirty) < 16  # a superset, but not everything (16 tiles in the window)
    assert len(dmap.pop_dirty()) == 0


def test_dirty_tiles_after_scrolling():
    dmap = make_map(16, 12, tile_vox=4)
    dmap.set_lo(np.array([-6, -8, -6]))  # x not aligned to tiles
    fill_random(dmap, 2000, seed=7)
    dmap.pop_dirty()
    old_lo = dmap.lo.copy()
    before = global_counts(dmap, old_lo - (8, 8, 0), np.array(dmap.shape) + (16, 16, 0))
    dmap.set_lo(old_lo + (3, -2, 0))
    after = global_counts(dmap, old_lo - (8, 8, 0), np.array(dmap.shape) + (16, 16, 0))
    dirty = {tuple(k) for k in dmap.pop_dirty().tolist()}
    changed = _changed_tiles(before, after, dmap, old_lo - (8, 8, 0))
    # every tile still (partly) in the window whose content changed is reported
    k_lo = dmap.lo[:2] // 4
    k_hi = (dmap.hi[:2] - 1) // 4
    in_window = {k for k in changed if np.all((k >= k_lo) & (k <= k_hi))}
    assert in_window and in_window <= dirty
    # a vertical shift changes every column
    dmap.set_lo(dmap.lo + (0, 0, 1))
    assert len(dmap.pop_dirty()) == np.prod(k_hi - k_lo + 1)


def test_mark_tile_size_resets_the_record():
    dmap = make_map(16, 12, tile_vox=4)
    dmap.mark_tile_size(8)
    tiles = dmap.pop_dirty()
    k_lo = dmap.lo[:2] // 8
    k_hi = (dmap.hi[:2] - 1) // 8
    assert len(tiles) == np.prod(k_hi - k_lo + 1)
    with pytest.raises(ConfigError):
        dmap.mark_tile_size(0)


def test_serial_and_threaded_maps_agree():
    a = make_map(16, 12)
    b = make_map(16, 12)
    b.parallel = False
    fill_random(a, 3000, seed=8)
    fill_random(b, 3000, seed=8)
    for x, y in zip(a.counts(), b.counts()):
        np.testing.assert_array_equal(x, y)


def test_floor_z_is_a_lower_bound_of_every_count():
    """No voxel under ``floor_z`` holds a count, whatever the rays' directions, scrolling,
    clearing or a restored state; an empty map reports one level under its top."""
    rng = np.random.default_rng(4)
    dmap = DensityMap(MapConfig(size_xy=4.0, size_z=4.0, z_below=2.0))
    assert dmap.floor_z == int(dmap.hi[2]) - 1
    origin = np.array([0.3, -0.2, 6.0])
    pts = np.column_stack([rng.uniform(-1.5, 1.5, (500, 2)), rng.uniform(-0.5, 0.3, 500)])
    dmap.integrate(pts, origin)
    up = np.column_stack([rng.uniform(-1.5, 1.5, (50, 2)), np.full(50, 1.5)])
    dmap.integrate(up, np.array([0.0, 0.0, -1.2]))  # rays rising from below the ground
    for step in range(3):
        h, p = dmap.counts()
        k = np.nonzero((h + p).any(axis=(0, 1)))[0]
        floor = dmap.floor_z - int(dmap.lo[2])
        assert k.min() >= floor and floor <= int(np.floor(-1.2 / dmap.voxel_size)) - dmap.lo[2]
        assert floor >= 0
        dmap.recenter((0.5 * step, 0.0, 0.4 * step))
    state = dmap.export_state()
    dmap.clear()
    assert dmap.floor_z == int(dmap.hi[2]) - 1
    dmap.import_state(state)
    assert dmap.floor_z == int(dmap.lo[2])
