"""The compiled voxel walk against an exact rational reference, plus its bookkeeping.

The reference is the definition itself: with ``u = p / voxel_size`` the segment [o, p] meets
the half-open cells ``{floor(o + t (p - o)) : t in [0, 1]}``. Between two consecutive plane
crossings the cell cannot change, so evaluating ``floor`` exactly (``fractions.Fraction``) at
every crossing parameter and at the midpoints between them lists every cell, corners and edges
included. The return's cell gets the hit, the others in the window the passes.
"""
from __future__ import annotations

import math
from fractions import Fraction

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from landing_zone.config import MapConfig
from landing_zone.mapping.density_map import DensityMap
from landing_zone.errors import InvalidCloudError
from landing_zone.mapping.rays import IntegrationStats
from landing_zone.mapping.raytrace import COUNT_MAX

VS = 0.25  # a power of two, so that world / voxel_size is exact and ties stay ties


def exact_cells(o_u, p_u) -> list[tuple[int, int, int]]:
    """Cells met by the segment in lattice units, in order along it (exact arithmetic)."""
    o = [Fraction(float(v)) for v in o_u]
    p = [Fraction(float(v)) for v in p_u]
    d = [p[a] - o[a] for a in range(3)]
    ts = {Fraction(0), Fraction(1)}
    for a in range(3):
        if d[a] != 0:
            lo, hi = sorted((o[a], p[a]))
            for k in range(math.ceil(lo), math.floor(hi) + 1):
                ts.add((k - o[a]) / d[a])
    ts = sorted(ts)
    probes = []
    for i, t in enumerate(ts):
        probes.append(t)
        if i + 1 < len(ts):
            probes.append((t + ts[i + 1]) / 2)
    cells: list[tuple[int, int, int]] = []
    for t in probes:
        c = tuple(math.floor(o[a] + t * d[a]) for a in range(3))
        if not cells or cells[-1] != c:
            cells.append(c)
    assert len(set(cells)) == len(cells)  # monotone per axis: never back into a cell
    return cells


def expected_counts(dmap: DensityMap, origin_m, point_m):
    """Reference (hit cell or None, set of pass cells) in global indices, window only."""
    o_u = np.asarray(origin_m, np.float64) / dmap.voxel_size
    p_u = np.asarray(point_m, np.float64) / dmap.voxel_size
    cells = exact_cells(o_u, p_u)
    lo, hi = dmap.lo, dmap.hi
    inside = [c for c in cells if all(lo[a] <= c[a] < hi[a] for a in range(3))]
    end = tuple(int(v) for v in np.floor(p_u))
    hit = end if end in inside else None
    return hit, {c for c in inside if c != end}


def kernel_counts(dmap: DensityMap):
    h, p = dmap.counts()
    hit_cells = [tuple(int(v) for v in g + dmap.lo) for g in np.argwhere(h)]
    pass_cells = {tuple(int(v) for v in g + dmap.lo) for g in np.argwhere(p)}
    return h, p, hit_cells, pass_cells


def small_map(shape_xy=16, shape_z=16, lo=None, parallel=True) -> DensityMap:
    cfg = MapConfig(voxel_size=VS, size_xy=shape_xy * VS, size_z=shape_z * VS,
                    z_below=shape_z * VS / 2)
    dmap = DensityMap(cfg, parallel=parallel)
    if lo is not None:
        dmap.set_lo(np.array(lo, np.int64))
    return dmap


def ray_sets(rng: np.random.Generator, n: int, lo, hi) -> tuple[np.ndarray, np.ndarray]:
    """Rays in lattice units: random, on the 1/4-voxel grid (ties), axis-aligned, diagonal."""
    lo = np.asarray(lo, np.float64)
    hi = np.asarray(hi, np.float64)
    span = hi - lo
    a_lo, a_hi = lo - 0.6 * span, hi + 0.6 * span  # start and end inside and outside
    k = n // 6
    o, p = [], []
    # 1. generic floats
    o.append(rng.uniform(a_lo, a_hi, (k, 3)))
    p.append(rng.uniform(a_lo, a_hi, (k, 3)))
    # 2. quarter-voxel grid: faces, edges and corners hit exactly, all sign mixes
    o.append(np.round(rng.uniform(a_lo, a_hi, (k, 3)) * 4) / 4)
    p.append(np.round(rng.uniform(a_lo, a_hi, (k, 3)) * 4) / 4)
    # 3. along one axis, some exactly on faces or edges
    oo = np.round(rng.uniform(a_lo, a_hi, (k, 3)) * 2) / 2
    pp = oo.copy()
    axis = rng.integers(0, 3, k)
    pp[np.arange(k), axis] = np.round(rng.uniform(a_lo[axis], a_hi[axis]) * 4) / 4
    o.append(oo)
    p.append(pp)
    # 4. through lattice corners: from a corner (or a half-integer point) along (+-1,+-1,+-1)
    #    and along face diagonals, crossing several planes at once at every step
    start = np.floor(rng.uniform(lo, hi, (k, 3))) + rng.choice([0.0, 0.5], (k, 1))
    dirs = rng.choice([-1.0, 0.0, 1.0], (k, 3))
    dirs[np.all(dirs == 0, axis=1)] = (1.0, -1.0, 1.0)
    length = rng.integers(1, 24, (k, 1)) + rng.choice([0.0, 0.5], (k, 1))
    o.append(start)
    p.append(start + dirs * length)
    # 5. ratios 1:2:3 through edges and corners (ties between non-equal steps)
    start = np.floor(rng.uniform(a_lo, a_hi, (k, 3)))
    dirs = rng.permuted(np.tile([1.0, 2.0, 3.0], (k, 1)), axis=1) * rng.choice([-1, 1], (k, 3))
    o.append(start)
    p.append(start + dirs * rng.integers(1, 8, (k, 1)))
    # 6. rays lying exactly in a face plane (one coordinate an integer on both ends)
    oo = rng.uniform(a_lo, a_hi, (n - 5 * k, 3))
    pp = rng.uniform(a_lo, a_hi, (n - 5 * k, 3))
    axis = rng.integers(0, 3, n - 5 * k)
    plane = np.floor(rng.uniform(lo[axis], hi[axis]))
    oo[np.arange(n - 5 * k), axis] = plane
    pp[np.arange(n - 5 * k), axis] = plane
    o.append(oo)
    p.append(pp)
    return np.concatenate(o), np.concatenate(p)


@pytest.mark.parametrize('origin,point,hit,passes', [
    # through the edge at (1, 1): both axes step up together, no zero-length cell
    ((0.5, 0.5, 0.5), (2.5, 2.5, 0.5), (2, 2, 0), [(0, 0, 0), (1, 1, 0)]),
    # the same edge, travelled backwards: both step down together
    ((2.5, 2.5, 0.5), (0.5, 0.5, 0.5), (0, 0, 0), [(2, 2, 0), (1, 1, 0)]),
    # x up and y down through the edge at (1, 1): the cell holding the crossing point, (1, 1),
    # is met (for a single instant) between (0, 1) and (1, 0)
    ((0.5, 1.5, 0.5), (1.5, 0.5, 0.5), (1, 0, 0), [(0, 1, 0), (1, 1, 0)]),
    # through the corner (1, 1, 1) on the main diagonal
    ((0.5, 0.5, 0.5), (1.5, 1.5, 1.5), (1, 1, 1), [(0, 0, 0)]),
    # a return exactly on a face belongs to the cell above it
    ((0.5, 0.5, 0.5), (2.0, 0.5, 0.5), (2, 0, 0), [(0, 0, 0), (1, 0, 0)]),
    ((2.5, 0.5, 0.5), (1.0, 0.5, 0.5), (1, 0, 0), [(2, 0, 0)]),
    # a ray lying in the face x = 1 runs through the cells above it
    ((1.0, 0.5, 0.5), (1.0, 2.5, 0.5), (1, 2, 0), [(1, 0, 0), (1, 1, 0)]),
    # an origin exactly on a face, moving down: its own cell is met at t = 0
    ((2.0, 0.5, 0.5), (0.5, 0.5, 0.5), (0, 0, 0), [(2, 0, 0), (1, 0, 0)]),
])
def test_tie_rule_by_hand(origin, point, hit, passes):
    """The half-open rule on hand-checked cases (lattice units, voxel size 1/4 m)."""
    dmap = small_map(8, 8, lo=(0, 0, 0))
    dmap.integrate(np.array([point]) * VS, np.array(origin) * VS)
    _, _, hit_cells, pass_cells = kernel_counts(dmap)
    assert hit_cells == [hit]
    assert pass_cells == set(passes)
    want = expected_counts(dmap, np.array(origin) * VS, np.array(point) * VS)
    assert want == (hit, set(passes))


@pytest.mark.parametrize('shape_xy,shape_z,lo', [
    (16, 16, None),  # storage aligned with the window
    (13, 11, (-7, 5, -3)),  # padded ring dimensions, window not brick-aligned
    (16, 12, (37, -21, 6)),  # a window that wraps around the ring on every axis
])
def test_every_ray_matches_exact_reference(shape_xy, shape_z, lo):
    rng = np.random.default_rng(7)
    dmap = small_map(shape_xy, shape_z, lo)
    if lo is not None:
        # walk the window around first, so its storage wraps (set_lo is the ring's job)
        dmap.set_lo(dmap.lo + (5, -9, 3))
        dmap.set_lo(np.array(lo, np.int64))
    o_u, p_u = ray_sets(rng, 1200, dmap.lo, dmap.hi)
    o_m, p_m = o_u * VS, p_u * VS
    mismatches = []
    total = IntegrationStats()
    for i in range(len(o_m)):
        if np.all(o_m[i] == p_m[i]):
            continue
        stats = dmap.integrate(p_m[i:i + 1], o_m[i])
        total = total + stats
        h, p, hit_cells, pass_cells = kernel_counts(dmap)
        want_hit, want_pass = expected_counts(dmap, o_m[i], p_m[i])
        assert h.max(initial=0) <= 1 and p.max(initial=0) <= 1
        got_hit = hit_cells[0] if hit_cells else None
        if got_hit != want_hit or pass_cells != want_pass:
            mismatches.append((o_u[i], p_u[i], got_hit, want_hit,
                               sorted(pass_cells ^ want_pass)))
        # stats: integrated iff any cell in the window; outside hit iff passes only
        assert stats.integrated == int(want_hit is not None or bool(want_pass))
        assert stats.outside_hits == int(want_hit is None and bool(want_pass))
        assert stats.missed == 1 - stats.integrated
        assert stats.voxels == len(want_pass) + (want_hit is not None)
        dmap.clear()
    assert not mismatches, f'{len(mismatches)} rays differ, first: {mismatches[:3]}'
    # the test exercised what it claims to
    assert total.integrated > 500 and total.missed > 50 and total.outside_hits > 100


def test_real_voxel_size_far_from_the_origin_matches_reference():
    """5 cm voxels (not dyadic) around a UTM-like position: still the exact cells of u = p / vs."""
    cfg = MapConfig(voxel_size=0.05, size_xy=0.8, size_z=0.6, z_below=0.3)
    center = np.array([512345.678, 4231987.123, 312.5])
    dmap = DensityMap(cfg, center=center)
    rng = np.random.default_rng(17)
    n = 400
    pts = center + rng.uniform(-0.6, 0.6, (n, 3))
    origins = center + rng.uniform(-0.6, 0.6, (n, 3))
    origins[: n // 2] = center + (0.1, -0.2, 5.0)  # half from a sensor far above the box
    for i in range(n):
        dmap.integrate(pts[i:i + 1], origins[i])
        _, _, hit_cells, pass_cells = kernel_counts(dmap)
        want_hit, want_pass = expected_counts(dmap, origins[i], pts[i])
        assert (hit_cells[0] if hit_cells else None) == want_hit
        assert pass_cells == want_pass
        dmap.clear()


def test_batch_equals_sum_of_single_rays_and_threads_agree():
    rng = np.random.default_rng(11)
    maps = [small_map(16, 12, (3, -6, -5), parallel=par) for par in (True, False)]
    o_u, p_u = ray_sets(rng, 3000, maps[0].lo, maps[0].hi)
    keep = ~np.all(o_u == p_u, axis=1)
    o_m, p_m = o_u[keep] * VS, p_u[keep] * VS
    want_h = np.zeros(maps[0].shape, np.int64)
    want_p = np.zeros(maps[0].shape, np.int64)
    lo = maps[0].lo
    for i in range(len(o_m)):
        hit, passes = expected_counts(maps[0], o_m[i], p_m[i])
        if hit is not None:
            want_h[tuple(np.subtract(hit, lo))] += 1
        for c in passes:
            want_p[tuple(np.subtract(c, lo))] += 1
    for dmap in maps:
        stats = dmap.integrate(p_m, o_m)  # one batch, sorted and split into parts inside
        h, p = dmap.counts()
        np.testing.assert_array_equal(h, want_h)
        np.testing.assert_array_equal(p, want_p)
        assert stats.voxels == want_h.sum() + want_p.sum()
        assert stats.integrated - stats.outside_hits == want_h.sum()


def test_single_origin_broadcasts_like_per_row_origins():
    rng = np.random.default_rng(3)
    a, c = small_map(), small_map()
    pts = rng.uniform(-3, 3, (500, 3))
    origin = np.array([0.3, -0.7, 3.9])
    sa = a.integrate(pts, origin)
    sc = c.integrate(pts, np.tile(origin, (500, 1)))
    assert sa.integrated > 0 and sa == sc
    for x, y in zip(a.counts(), c.counts()):
        np.testing.assert_array_equal(x, y)


def test_float32_input_is_read_as_its_float64_value():
    a, b = small_map(), small_map()
    pts = np.array([[0.1, 0.2, -1.3], [1.7, -0.4, -0.9]], np.float32)
    origin = np.array([0.0, 0.0, 1.5], np.float32)
    a.integrate(pts, origin)
    b.integrate(pts.astype(np.float64), origin.astype(np.float64))
    for x, y in zip(a.counts(), b.counts()):
        np.testing.assert_array_equal(x, y)


def test_bad_rows_are_dropped_and_counted():
    dmap = small_map()
    pts = np.array([
        [0.1, 0.1, -0.5],  # fine
        [np.nan, 0.0, 0.0],  # NaN point
        [np.inf, 0.0, 0.0],  # Inf point
        [0.3, 0.3, 0.3],  # zero length (equal to its origin)
        [50.0, 50.0, 50.0],  # ray from outside that never meets the map
        [0.2, -0.3, -0.1],  # origin below is non-finite
        [1e15, 0.0, 0.0],  # absurdly far: dropped as non-finite
    ])
    origins = np.array([
        [0.0, 0.0, 1.5], [0.0, 0.0, 1.5], [0.0, 0.0, 1.5], [0.3, 0.3, 0.3],
        [60.0, 50.0, 50.0], [0.0, -np.inf, 0.0], [0.0, 0.0, 1.0]])
    stats = dmap.integrate(pts, origins)
    assert stats == IntegrationStats(returns=7, integrated=1, nonfinite=4, degenerate=1,
                                     missed=1, outside_hits=0, voxels=stats.voxels)
    assert stats.dropped == 5
    assert stats.returns == stats.integrated + stats.nonfinite + stats.degenerate + stats.missed
    h, _ = dmap.counts()
    assert h.sum() == 1


@pytest.mark.parametrize('points,origins,match', [
    (np.zeros((4, 2)), np.zeros(3), r'points must have shape \(N, 3\)'),
    (np.zeros(3), np.zeros(3), r'points must have shape \(N, 3\), got \(3,\)'),
    (np.zeros((4, 3)), np.zeros((3, 3)), 'origins must be .* N = 4 rows'),
    (np.zeros((4, 3)), np.zeros((4, 2)), r'origins must have shape \(3,\) or \(N, 3\)'),
    (np.array([['a', 'b', 'c']]), np.zeros(3), 'points must be numeric'),
    (np.zeros((2, 3), complex), np.zeros(3), 'points must be numeric'),
])
def test_wrong_shapes_raise_invalid_cloud(points, origins, match):
    with pytest.raises(InvalidCloudError, match=match):
        small_map().integrate(points, origins)


def test_empty_batch_and_integer_input():
    dmap = small_map()
    assert dmap.integrate(np.zeros((0, 3)), np.zeros(3)) == IntegrationStats()
    stats = dmap.integrate(np.array([[0, 0, -1]], np.int32), np.array([0, 0, 1]))
    assert stats.integrated == 1 and dmap.counts()[0].sum() == 1


def test_counts_saturate_and_never_wrap():
    dmap = small_map()
    # every ray: from the middle of one voxel down into the middle of the one below it
    o = np.array([0.125, 0.125, 0.375])
    one = np.array([[0.125, 0.125, 0.125]])
    ga = tuple(dmap.world_to_index(one[0]) - dmap.lo)
    gb = tuple(dmap.world_to_index(o) - dmap.lo)
    done = 0
    for n, want in [(255, 255), (1, 256), (300, 556), (65000, COUNT_MAX), (5000, COUNT_MAX)]:
        dmap.integrate(np.repeat(one, n, axis=0), o)
        done += n
        h, p = dmap.counts()
        assert h[ga] == want and p[gb] == want
        assert h.sum() == want and p.sum() == want  # nothing leaked into other voxels
    assert dmap.cold_blocks == 1
    d = dmap.density()
    assert d[ga] == np.float32((COUNT_MAX + 1) / (COUNT_MAX + 2))
    assert d[gb] == np.float32(1 / (COUNT_MAX + 2))
    assert dmap.observed()[ga] and dmap.observed().sum() == 2


def test_cold_blocks_follow_bricks_in_both_parts():
    """Overflow in many bricks of both thread parts at once (pools grow mid-batch)."""
    dmap = small_map(16, 8)
    rng = np.random.default_rng(5)
    xy = (rng.integers(0, 16, (40, 2)) + 0.5) * VS + dmap.lo[:2] * VS
    pts = np.column_stack([xy, np.full(40, (dmap.lo[2] + 0.5) * VS)])
    origins = pts + (0.0, 0.0, 7 * VS)
    reps = 300
    dmap._pool = dmap._pool[:, :1].copy()  # start tiny: exercises stop, grow and resume
    stats = dmap.integrate(np.repeat(pts, reps, axis=0), np.repeat(origins, reps, axis=0))
    assert stats.integrated == 40 * reps
    h, p = dmap.counts()
    cells = dmap.world_to_index(pts) - dmap.lo
    uniq, mult = np.unique(cells, axis=0, return_counts=True)
    for c, m in zip(uniq, mult):
        assert h[tuple(c)] == m * reps
        for dz in range(1, 8):
            assert p[c[0], c[1], c[2] + dz] == m * reps
    assert h.sum() == 40 * reps and p.sum() == 7 * 40 * reps
    assert dmap.cold_blocks > 4


def test_every_brick_overflowing_fits_the_bounded_pool():
    cfg = MapConfig(voxel_size=VS, size_xy=8 * VS, size_z=4 * VS, z_below=2 * VS)
    dmap = DensityMap(cfg)
    g = np.stack(np.meshgrid(*(np.arange(n) for n in dmap.shape), indexing='ij'), -1)
    cells = g.reshape(-1, 3) + dmap.lo
    pts = (cells + 0.5) * VS
    origins = pts + (0.3 * VS, 0.2 * VS, 0.1 * VS)  # same voxel: one hit, no pass
    reps = 260
    stats = dmap.integrate(np.tile(pts, (reps, 1)), np.tile(origins, (reps, 1)))
    assert stats.integrated == reps * len(pts)
    h, p = dmap.counts()
    assert np.all(h == reps) and not p.any()
    assert dmap.cold_blocks == 4  # every brick of the 8 x 8 x 4 map
    # 2 hot + 2 cold bytes + 1/16 byte of index per voxel, plus a few bytes of bookkeeping
    assert dmap.nbytes <= 4.07 * h.size + 200


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(seed=st.integers(0, 2 ** 32 - 1), n=st.integers(1, 300), split=st.integers(0, 300))
def test_properties_hits_density_and_batching(seed, n, split):
    rng = np.random.default_rng(seed)
    one, two = small_map(16, 8), small_map(16, 8)
    pts = rng.uniform(-3, 3, (n, 3))
    origins = rng.uniform(-3, 3, (n, 3))
    stats = one.integrate(pts, origins)
    k = min(split, n)
    s2 = two.integrate(pts[:k], origins[:k]) + two.integrate(pts[k:], origins[k:])
    h, p = one.counts()
    # one batch or two: the same counts and the same statistics
    for x, y in zip((h, p), two.counts()):
        np.testing.assert_array_equal(x, y)
    assert stats == s2
    # every integrated return inside the map is exactly one hit
    inside = one.contains_index(one.world_to_index(pts))
    assert h.sum() == stats.integrated - stats.outside_hits == inside.sum()
    assert h.sum() + p.sum() == stats.voxels
    d = one.density()
    assert np.all((d > 0) & (d < 1))
    np.testing.assert_array_equal(one.observed(), (h + p) > 0)
