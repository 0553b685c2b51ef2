"""Tiles: ground estimates and network inputs on hand-built count grids, and from real maps."""
import math

import numpy as np
import pytest

from landing_zone.config import MapConfig, TileConfig
from landing_zone.errors import ConfigError, InvalidCloudError
from landing_zone.judging.patches import centre_columns, patch_columns, scene_to_input
from landing_zone.judging.tiles import (extract_tiles, tile_voxels, tiles_from_counts,
                                        tiles_in_box, widen_tiles)

VS = 0.05
TV = 20
PAD = 6
SIDE = TV + 2 * PAD
HIT, PASS = 5, 4  # counts of a surface voxel (hits) and of the free voxels above it (passes)
X_SURF = (HIT - 0) / (HIT + 0 + 2)  # input value of a surface voxel: 2 * 6/7 - 1
X_FREE = (0 - PASS) / (0 + PASS + 2)


def heightfield_grid(heights, nz=60):
    """Counts of a surface seen from above: hits at the surface voxel of each column, passes
    above it, nothing (unobserved) below. ``heights``: (X, Y) int z indices, -1 = no data."""
    heights = np.asarray(heights)
    nx, ny = heights.shape
    k = np.arange(nz)[None, None, :]
    hz = heights[:, :, None]
    hits = np.where((k == hz) & (hz >= 0), HIT, 0).astype(np.uint32)
    passes = np.where((k > hz) & (hz >= 0), PASS, 0).astype(np.uint32)
    return hits, passes


def lower_quantile(values, q=0.05):
    v = np.sort(np.asarray(values).ravel())
    return v[int(math.floor(q * (len(v) - 1)))]


# --- the lattice -------------------------------------------------------------------------------

def test_tiles_in_box_are_whole_tiles_on_the_global_lattice():
    # x voxels [-30, 50): tiles -1 (voxels -20..-1) and 0, 1 (0..39); tile 2 (40..59) is cut off
    idx = tiles_in_box((-30, 5, 0), (80, 40, 10), TV)
    assert sorted(set(idx[:, 0].tolist())) == [-1, 0, 1]
    assert sorted(set(idx[:, 1].tolist())) == [1]  # y voxels [5, 45): only tile 1 is whole
    assert idx.tolist() == sorted(idx.tolist())


def test_tile_centres_sit_at_half_metres():
    h, p = heightfield_grid(np.full((40, 40), 10))
    b = tiles_from_counts(h, p, (-20, -20, 0), VS)
    assert b.index.tolist() == [[-1, -1], [-1, 0], [0, -1], [0, 0]]
    np.testing.assert_allclose(b.centers, [[-0.5, -0.5], [-0.5, 0.5], [0.5, -0.5], [0.5, 0.5]])


def test_widen_tiles_adds_the_neighbour_rings():
    w = widen_tiles(np.array([[0, 0], [1, 0]]))
    assert len(w) == 12 and w.tolist() == sorted(w.tolist())
    assert [-1, -1] in w.tolist() and [2, 1] in w.tolist() and [3, 0] not in w.tolist()
    assert len(widen_tiles(np.array([[5, 5]]), rings=2)) == 25
    assert len(widen_tiles(np.zeros((0, 2), int))) == 0


def test_tile_size_must_be_whole_voxels():
    assert tile_voxels(0.05, TileConfig()) == 20
    with pytest.raises(ConfigError, match='whole multiple'):
        tile_voxels(0.03, TileConfig())


# --- ground and inputs on hand-built grids -----------------------------------------------------

def test_flat_ground_gives_its_height_and_the_exact_input():
    g = 25
    h, p = heightfield_grid(np.full((60, 60), g))
    lo = (0, 0, -30)
    b = tiles_from_counts(h, p, lo, VS)
    assert len(b) == 9 and b.valid.all()
    np.testing.assert_allclose(b.ground_z, (lo[2] + g + 0.5) * VS)
    assert b.inputs.shape == (9, 1, SIDE, SIDE, SIDE) and b.inputs.dtype == np.float32
    # the centre tile sees neighbours in its padding: every column looks the same
    x = b.inputs[4, 0]
    zg = PAD + TV // 2  # the ground voxel sits at the cube's vertical middle
    np.testing.assert_allclose(x[:, :, zg], X_SURF, rtol=1e-6)
    np.testing.assert_allclose(x[:, :, zg + 1:], X_FREE, rtol=1e-6)
    np.testing.assert_array_equal(x[:, :, :zg], 0.0)  # below the ground: unobserved
    # cube_lo maps input voxels back to the lattice
    assert b.cube_lo[4].tolist() == [20 - PAD, 20 - PAD, lo[2] + g - TV // 2 - PAD]
    # the unpadded cube: the ground layer and everything above it observed
    assert b.observed_fraction[4] == pytest.approx((TV - TV // 2) / TV)
    assert b.n_returns[4] == HIT * TV * TV


def test_edge_tiles_read_outside_the_box_as_unobserved():
    h, p = heightfield_grid(np.full((20, 20), 10))
    b = tiles_from_counts(h, p, (0, 0, 0), VS)
    x = b.inputs[0, 0]
    np.testing.assert_array_equal(x[:PAD], 0.0)
    np.testing.assert_array_equal(x[:, SIDE - PAD:], 0.0)
    assert np.all(x[PAD:PAD + TV, PAD:PAD + TV, PAD + TV // 2] > 0)


def test_sloped_ground_takes_a_low_quantile_of_the_columns():
    xs = np.arange(40)
    heights = np.repeat((10 + 0.5 * xs).astype(int)[:, None], 40, axis=1)  # ~27 deg slope
    h, p = heightfield_grid(heights)
    b = tiles_from_counts(h, p, (0, 0, 0), VS)
    for t, (kx, ky) in enumerate(b.index):
        cols = heights[kx * TV:(kx + 1) * TV, ky * TV:(ky + 1) * TV]
        want = lower_quantile(cols)
        assert b.ground_z[t] == pytest.approx((want + 0.5) * VS)
        # near the low edge of the tile, never below its lowest column
        assert cols.min() <= want <= cols.min() + 0.1 * (cols.max() - cols.min()) + 1


def test_a_box_does_not_lift_the_ground_and_shows_in_the_input():
    g = 20
    heights = np.full((20, 20), g)
    heights[4:12, 6:14] = g + 6  # a 40 x 40 x 30 cm box top (16 % of the columns)
    h, p = heightfield_grid(heights)
    # its sides: the columns under the top edge are hit all the way down
    for k in range(g, g + 6):
        h[4:12, 6:14, k] = np.maximum(h[4:12, 6:14, k], HIT)
    b = tiles_from_counts(h, p, (0, 0, 0), VS)
    assert b.ground_z[0] == pytest.approx((g + 0.5) * VS)
    x = b.inputs[0, 0]
    zg = PAD + TV // 2
    assert np.all(x[PAD + 4:PAD + 12, PAD + 6:PAD + 14, zg + 6] > 0)  # the top
    assert np.all(x[PAD + 4:PAD + 12, PAD + 6:PAD + 14, zg + 7:] < 0)  # free above it
    assert np.all(x[PAD:PAD + 4, PAD:PAD + TV, zg + 1:] < 0)  # free beside it


def test_dense_grass_hides_most_of_the_ground_but_not_the_estimate(rng):
    g = 15
    heights = np.full((20, 20), g)
    h, p = heightfield_grid(heights)
    # 85 % of the columns: grass blades (occupied, 1-6 voxels above the ground) hide the ground
    hidden = rng.random((20, 20)) < 0.85
    for i, j in zip(*np.nonzero(hidden)):
        top = g + rng.integers(1, 7)
        h[i, j, :top] = 0
        p[i, j, :top] = 0
        h[i, j, top] = 3
        p[i, j, top] = 1
        for k in range(g + 1, top):  # some lower blade voxels seen through gaps
            if rng.random() < 0.5:
                h[i, j, k] = 2
                p[i, j, k] = 1
    b = tiles_from_counts(h, p, (0, 0, 0), VS)
    assert b.valid[0]
    assert b.ground_z[0] == pytest.approx((g + 0.5) * VS)


def test_a_few_low_outliers_are_ignored(rng):
    g = 30
    h, p = heightfield_grid(np.full((20, 20), g))
    cols = rng.choice(400, 12, replace=False)  # 3 % of the columns
    for c in cols:
        h[c // 20, c % 20, g - 10] = 1  # one return 50 cm below the ground
    b = tiles_from_counts(h, p, (0, 0, 0), VS)
    assert b.ground_z[0] == pytest.approx((g + 0.5) * VS)
    # but many of them (half the tile) would move it: the estimate is a quantile, not a mode
    for c in range(0, 400, 2):
        h[c // 20, c % 20, g - 10] = 1
    assert tiles_from_counts(h, p, (0, 0, 0), VS).ground_z[0] == pytest.approx(
        (g - 10 + 0.5) * VS)


def test_a_voxel_counts_as_occupied_from_the_configured_density():
    h, p = heightfield_grid(np.full((20, 20), 20))
    h[:, :, 10] = 1
    p[:, :, 10] = 1  # density 2/4 = 0.5 < 0.6: not occupied
    b = tiles_from_counts(h, p, (0, 0, 0), VS)
    assert b.ground_z[0] == pytest.approx(20.5 * VS)
    b = tiles_from_counts(h, p, (0, 0, 0), VS, TileConfig(occupied_density=0.5))
    assert b.ground_z[0] == pytest.approx(10.5 * VS)


# --- validity ----------------------------------------------------------------------------------

def test_unobserved_tiles_are_unknown_never_guessed():
    heights = np.full((40, 20), 10)
    heights[20:] = -1  # the second tile has no data at all
    h, p = heightfield_grid(heights)
    b = tiles_from_counts(h, p, (0, 0, 0), VS)
    assert b.valid.tolist() == [True, False]
    assert math.isnan(b.ground_z[1])
    assert b.n_returns[1] == 0 and b.observed_fraction[1] == 0
    np.testing.assert_array_equal(b.inputs[1], 0.0)


def test_thin_observation_or_few_returns_make_a_tile_unknown():
    heights = np.full((20, 20), 10)
    h, p = heightfield_grid(heights)
    p[:] = 0  # only the surface voxels are observed: 1/20 of the cube
    b = tiles_from_counts(h, p, (0, 0, 0), VS)
    assert b.observed_fraction[0] == pytest.approx(1 / TV)
    assert not b.valid[0] and np.isfinite(b.ground_z[0])
    assert tiles_from_counts(h, p, (0, 0, 0), VS,
                             TileConfig(min_observed_fraction=0.05)).valid[0]
    h2, p2 = heightfield_grid(heights)
    h2[:, :, 10] = 0
    h2[0, :19, 10] = 1  # 19 returns in the column, one short of min_returns
    assert not tiles_from_counts(h2, p2, (0, 0, 0), VS).valid[0]
    h2[0, 19, 10] = 1
    assert tiles_from_counts(h2, p2, (0, 0, 0), VS).valid[0]


def test_invalid_inputs_false_skips_only_cubes_no_network_reads(rng):
    """The assessor's tiler leaves the cubes of tiles that cannot be valid all zeros; every
    other field, and every valid tile's cube, is what the full build gives (at the boundary
    of ``min_observed_fraction`` too)."""
    heights = rng.integers(8, 13, (60, 60))
    h, p = heightfield_grid(heights)
    p[20:40, :20] = 0  # tile (1, 0): only its surface observed, exactly 1/20 of the cube
    p[40:, :20] = 0
    h[40, 0, :] = 0  # tile (2, 0): one column short of it
    h[:20, 40:] = np.minimum(h[:20, 40:], 1)
    h[:20, 40:][:, 1:] = 0
    h[10:20, 40] = 0  # tile (0, 2): 10 returns, too few
    h[40:, 40:] = 0
    p[40:, 40:] = 0  # tile (2, 2): nothing observed
    cfg = TileConfig(min_observed_fraction=1 / TV)
    full = tiles_from_counts(h, p, (0, 0, 0), VS, cfg)
    lean = tiles_from_counts(h, p, (0, 0, 0), VS, cfg, invalid_inputs=False)
    for name in ('index', 'ground_z', 'observed_fraction', 'n_returns', 'valid', 'cube_lo'):
        np.testing.assert_array_equal(getattr(lean, name), getattr(full, name))
    np.testing.assert_array_equal(lean.inputs[full.valid], full.inputs[full.valid])
    assert full.valid.tolist().count(False) >= 3 and full.valid[full.index.tolist().index([1, 0])]
    skipped = [t for t in range(len(full)) if not full.valid[t]
               and np.any(full.inputs[t] != 0) and np.all(lean.inputs[t] == 0)]
    # the few-returns tile was not built; the one a column short of the fraction is within the
    # margin the skip keeps, so it was (and is still not valid)
    order = full.index.tolist()
    assert skipped == [order.index([0, 2])] and not full.valid[order.index([2, 0])]


def test_pooled_inputs_are_the_max_pooled_cubes(rng):
    """``pool=2`` writes each cube max-pooled (what the shipped net reads first), on flat and
    sheared (ground-aligned) cubes and at the box's edges; everything else is unchanged."""
    import torch

    from landing_zone.judging.ground import fit_ground

    heights = np.clip(10 + np.round(np.arange(60)[:, None] * 0.2 + rng.normal(0, 1, (60, 60))),
                      0, 59).astype(np.int64)
    h, p = heightfield_grid(heights)
    p[:, :, 40:] += rng.integers(0, 3, p[:, :, 40:].shape).astype(np.uint32)
    tiles = np.array([[0, 0], [1, 1], [2, 2], [-1, 1], [1, 2]])
    ground = fit_ground(h, p, np.zeros(3, np.int64), VS, tiles, TV, 0.6, 0.5)
    for cfg in (TileConfig(), TileConfig(align_to_ground=True)):
        full = tiles_from_counts(h, p, (0, 0, 0), VS, cfg, tiles, ground)
        pooled = tiles_from_counts(h, p, (0, 0, 0), VS, cfg, tiles, ground, pool=2)
        assert pooled.inputs.shape == (len(tiles), 1, SIDE // 2, SIDE // 2, SIDE // 2)
        ref = torch.nn.functional.max_pool3d(torch.from_numpy(full.inputs), 2).numpy()
        np.testing.assert_array_equal(pooled.inputs, ref)
        for name in ('index', 'ground_z', 'observed_fraction', 'n_returns', 'valid', 'cube_lo'):
            np.testing.assert_array_equal(getattr(pooled, name), getattr(full, name))
    with pytest.raises(ConfigError, match='pool'):
        tiles_from_counts(h, p, (0, 0, 0), VS, pool=5)


def test_requested_tiles_outside_the_box_are_unknown():
    h, p = heightfield_grid(np.full((20, 20), 10))
    b = tiles_from_counts(h, p, (0, 0, 0), VS, tiles=np.array([[0, 0], [5, -3]]))
    assert b.valid.tolist() == [True, False]
    assert b.index.tolist() == [[0, 0], [5, -3]]


def test_bad_arguments_raise_config_errors():
    h, p = heightfield_grid(np.full((20, 20), 10))
    with pytest.raises(ConfigError, match='one shape'):
        tiles_from_counts(h, p[:10], (0, 0, 0), VS)
    with pytest.raises(ConfigError, match='integer counts'):
        tiles_from_counts(h.astype(float), p, (0, 0, 0), VS)
    with pytest.raises(ConfigError, match='tiles must be'):
        tiles_from_counts(h, p, (0, 0, 0), VS, tiles=np.zeros((3, 3), int))
    with pytest.raises(ConfigError, match='lo must be'):
        tiles_from_counts(h, p, (0, 0), VS)


# --- from real maps ----------------------------------------------------------------------------

def flat_returns(rng, n=40000, half=3.0, sensor=(-6.0, 0.0, 5.0)):
    xy = rng.uniform(-half, half, (n, 2))
    pts = np.column_stack([xy, rng.normal(0.0, 0.005, n)])
    return pts, np.asarray(sensor, float)


def test_extract_tiles_reads_a_density_map_like_its_counts(rng):
    from landing_zone.mapping.density_map import DensityMap
    dmap = DensityMap(MapConfig(size_xy=4.0, size_z=2.0, z_below=1.0))
    pts, origin = flat_returns(rng, half=2.0)
    dmap.integrate(pts, origin)
    b = extract_tiles(dmap)
    assert len(b) == 16
    assert b.valid.all()
    assert np.all(np.abs(b.ground_z) < 2 * VS)
    h, p = dmap.counts()
    ref = tiles_from_counts(h, p, dmap.lo, dmap.voxel_size, TileConfig())
    np.testing.assert_array_equal(b.inputs, ref.inputs)
    np.testing.assert_array_equal(b.ground_z, ref.ground_z)
    # a subset (dirty tiles) reads only its neighbourhood and gives the same tiles
    sub = extract_tiles(dmap, tiles=b.index[[5, 10]])
    np.testing.assert_array_equal(sub.inputs, b.inputs[[5, 10]])
    np.testing.assert_array_equal(sub.valid, b.valid[[5, 10]])


def test_scene_to_input_finds_the_ground_whatever_the_augmentation(rng):
    pts, origin = flat_returns(rng)
    ref = scene_to_input(pts, origin)
    assert len(ref) == 1 and ref.valid[0]
    assert ref.inputs.shape == (1, 1, SIDE, SIDE, SIDE)
    assert ref.index.tolist() == [[0, 0]] and ref.centers.tolist() == [[0.0, 0.0]]
    for yaw, dz in [(0.7, 0.0), (2.0, 0.23), (-1.0, -0.3)]:
        b = scene_to_input(pts, origin, yaw=yaw, z_shift=dz)
        assert b.valid[0]
        assert abs(b.ground_z[0]) < 2 * VS  # in the patch frame: the shift is undone
        # the cube follows the ground: the occupied layer stays at the cube's middle
        x = b.inputs[0, 0, PAD:PAD + TV, PAD:PAD + TV]
        layer = np.argmax((x > 0.2).sum(axis=(0, 1)))
        assert abs(layer - (PAD + TV // 2)) <= 1
    again = scene_to_input(pts, origin, yaw=2.0, z_shift=0.23)
    np.testing.assert_array_equal(again.inputs, scene_to_input(pts, origin, yaw=2.0,
                                                               z_shift=0.23).inputs)


@pytest.mark.parametrize('slope_deg', [0.0, 10.0])
@pytest.mark.parametrize('align', [True, False])
def test_scene_to_input_matches_a_deployed_map(rng, slope_deg, align):
    """The same returns, placed on tile (0, 0) of a full-size map, give the input the assessor
    cuts there: its ground planes fitted first, the cube aligned to the tile's plane with
    ``tiles.align_to_ground`` (the default), cut level without."""
    from landing_zone.judging.ground import fit_ground
    from landing_zone.mapping.density_map import DensityMap
    pts, origin = flat_returns(rng, n=20000, half=1.5)
    pts[:, 2] += math.tan(math.radians(slope_deg)) * pts[:, 0]
    cfg = TileConfig(align_to_ground=align)
    b = scene_to_input(pts, origin, tile_cfg=cfg)
    dmap = DensityMap(MapConfig(size_xy=6.0), center=(0.5, 0.5, 0.0))
    shift = np.array([0.5, 0.5, 0.0])
    dmap.integrate(pts + shift, origin + shift)
    h, p = dmap.counts()
    tile = np.array([[0, 0]])
    ground = fit_ground(h, p, dmap.lo, dmap.voxel_size, tile, dmap.tile_vox)
    deployed = tiles_from_counts(h, p, dmap.lo, dmap.voxel_size, cfg, tile, ground)
    np.testing.assert_array_equal(b.inputs, deployed.inputs)
    assert b.ground_z[0] == deployed.ground_z[0]
    # aligned, the sloped ground lies in the cube's middle layer; cut level, it crosses layers
    x = b.inputs[0, 0, PAD:PAD + TV, PAD:PAD + TV]
    occ = x > 0.2
    rows = np.argmax(occ, axis=-1)[occ.any(axis=-1)]
    spread = int(rows.max() - rows.min())
    assert spread <= 2 if align or slope_deg == 0.0 else spread >= 3


def test_scene_to_input_rejects_bad_clouds():
    with pytest.raises(InvalidCloudError):
        scene_to_input(np.zeros((5, 2)), np.zeros(3))
    with pytest.raises(ConfigError, match='finite'):
        scene_to_input(np.zeros((5, 3)), np.zeros(3), yaw=float('nan'))


def test_scene_to_input_survives_nonfinite_returns(rng):
    pts, origin = flat_returns(rng, n=5000, half=1.5)
    pts[::50] = np.nan
    b = scene_to_input(pts, origin)
    assert b.valid[0] and np.isfinite(b.inputs).all()


def test_patch_columns_carry_the_centre_plane_across_the_patch():
    """A patch of 3 x 3 tiles: heights over the centre tile's plane in every column (the
    neighbours' too, for what compares a tile with its surroundings), and the centre tile's
    columns as centre_columns cuts them."""
    hits, passes = heightfield_grid(np.full((3 * TV, 3 * TV), 10))
    lo = np.array([-TV, -TV, -20])
    mcfg, tcfg = MapConfig(voxel_size=VS), TileConfig()
    grad = np.array([0.1, -0.05])
    h, p, above, centre = patch_columns((hits, passes, lo), mcfg, tcfg, 0.25, grad)
    assert h is hits and p is passes and above.shape == hits.shape
    assert centre.sum() == TV * TV and centre[TV:2 * TV, TV:2 * TV].all()
    # column (0, 3 * TV - 1): a corner of the neighbour tiles, x = -1.475, y = +1.475 m from the
    # centre tile's centre; voxel 7 is at z = (-20 + 7 + 0.5) * 0.05 m
    plane = 0.25 + 0.1 * -1.475 - 0.05 * 1.475
    assert above[0, 3 * TV - 1, 7] == pytest.approx((-20 + 7 + 0.5) * VS - plane)
    ch, cp, ca = centre_columns((hits, passes, lo), mcfg, tcfg, 0.25, grad)
    assert np.array_equal(ch, hits[TV:2 * TV, TV:2 * TV])
    assert np.array_equal(cp, passes[TV:2 * TV, TV:2 * TV])
    assert np.array_equal(ca, above[TV:2 * TV, TV:2 * TV])
