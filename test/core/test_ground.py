"""Ground planes on simulated sites of known slope: slope, roughness, clearance, site limits.

Each site is a real scan: Embree rays from sensors 4-8 m up onto a (sloped) Perlin ground with
or without grass, integrated into the density map, then fitted as the assessor fits it.
"""
from __future__ import annotations

import math

import numpy as np
import pytest

from landing_zone.config import MapConfig, SiteConfig
from landing_zone.judging.ground import fit_ground, slope_deg
from landing_zone.judging.sites import GroundGrids, evaluate_candidates, find_sites, reason_names
from landing_zone.judging.tiles import tiles_in_box
from landing_zone.mapping.density_map import DensityMap
from landing_zone.tools.sim.grass import GrassConfig, grass_mesh
from landing_zone.tools.sim.mesh import OBSTACLE, Mesh
from landing_zone.tools.sim.raycast import RayCaster
from landing_zone.tools.sim.terrain import SlopedTerrain, TerrainConfig

HALF = 3.0  # the scanned site is 6 x 6 m around (0, 0)
# sensors both near-nadir (8 m up) and grazing (4 m up, 5 m off), as passes see a tile
SENSORS = np.array([[x, y, 8.0] for x in (-4, 0, 4) for y in (-4, 0, 4)]
                   + [[x, y, 4.0] for x in (-5, 5) for y in (-5, 5)], float)


def bar_mesh(z: float, x0: float = 0.2, x1: float = 0.3, thick: float = 0.05) -> Mesh:
    """A horizontal bar along y over the whole site, its lower face at height ``z``."""
    lo = np.array([x0, -HALF - 1, z])
    hi = np.array([x1, HALF + 1, z + thick])
    corners = np.array([[lo[0] if i & 1 == 0 else hi[0], lo[1] if i & 2 == 0 else hi[1],
                         lo[2] if i & 4 == 0 else hi[2]] for i in range(8)])
    faces = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return Mesh.from_arrays(corners, faces, OBSTACLE)


def scan_site(slope: float = 0.0, grass: float = 0.0, amplitude: float = 0.0,
              wavelength: float = 2.0, extra: Mesh | None = None, seed: int = 0,
              n: int = 250_000, azimuth: float = 0.3):
    """(terrain, points, origins) of a seeded scan of a 6 x 6 m site."""
    rng = np.random.default_rng(seed)
    lo, hi = (-HALF - 3, -HALF - 3), (HALF + 3, HALF + 3)
    terrain = SlopedTerrain(TerrainConfig(amplitude=amplitude, wavelength=wavelength,
                                          octaves=2, spacing=0.05), rng, lo, hi, slope,
                            azimuth)
    meshes = [terrain.mesh()]
    if grass > 0:
        poly = np.array([[lo[0], lo[1]], [hi[0], lo[1]], [hi[0], hi[1]], [lo[0], hi[1]]], float)
        meshes.append(grass_mesh(GrassConfig(density=2000.0, height_mean=grass), terrain, rng,
                                 poly))
    if extra is not None:
        meshes.append(extra)
    caster = RayCaster(Mesh.concat(meshes), threads=1)
    o = SENSORS[rng.integers(0, len(SENSORS), n)]
    tgt = np.column_stack([rng.uniform(-HALF - 0.5, HALF + 0.5, (n, 2)), np.zeros(n)])
    tgt[:, 2] = terrain.height(tgt[:, 0], tgt[:, 1])
    d = tgt - o
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    hits = caster.cast(o, d, 60.0)
    ok = hits.hit
    return terrain, (o[ok] + d[ok] * hits.t[ok, None]).astype(np.float32), o[ok]


def fitted(points, origins):
    """The ground planes of every tile of an 8 x 8 m map over the scan."""
    dmap = DensityMap(MapConfig(size_xy=8.0, size_z=4.0, z_below=2.0), parallel=False)
    dmap.integrate(points, origins)
    h, p = dmap.counts()
    tiles = tiles_in_box(dmap.lo, dmap.shape, dmap.tile_vox)
    return tiles, fit_ground(h, p, dmap.lo, dmap.voxel_size, tiles, dmap.tile_vox)


def inner(tiles):
    """The tiles well inside the scanned site."""
    return np.all(np.abs(tiles + 0.5) < HALF - 0.5, axis=1)


@pytest.mark.parametrize('slope', [0.0, 5.0, 10.0, 15.0])
def test_slope_of_clear_and_grassy_ground(slope):
    for grass, tolerance in ((0.0, 1.0), (0.3, 2.0)):
        terrain, pts, org = scan_site(slope, grass, seed=int(slope))
        tiles, g = fitted(pts, org)
        k = inner(tiles)
        s = g.slope_deg[k]
        assert np.isfinite(s).all(), (slope, grass)
        err = np.abs(s - slope)
        assert err.max() < tolerance, (slope, grass, err.max())
        # the ground height is the plane's at the tile centre: within a voxel of the truth
        c = (tiles[k] + 0.5).astype(float)
        assert np.abs(g.plane_z[k] - terrain.height(c[:, 0], c[:, 1])).max() < 0.05


def test_roughness_ranks_rough_ground_above_smooth():
    _, pts, org = scan_site(6.0, seed=3)
    tiles, smooth = fitted(pts, org)
    _, pts, org = scan_site(6.0, amplitude=0.08, wavelength=0.5, seed=3)
    _, rough = fitted(pts, org)
    k = inner(tiles)
    # every rough tile above every smooth one
    assert rough.roughness[k].min() > smooth.roughness[k].max()
    assert np.median(rough.roughness[k]) > 1.5 * np.median(smooth.roughness[k])
    # the smooth plane's residual is the 5 cm voxels' quantization, about 1.4 cm
    assert np.median(smooth.roughness[k]) < 0.02


def test_clearance_sees_a_bar_above_the_footprint():
    _, pts, org = scan_site(0.0, extra=bar_mesh(1.5), seed=4)
    tiles, g = fitted(pts, org)
    under = inner(tiles) & (tiles[:, 0] == 0)  # the bar spans x 0.2-0.3 m: tile column 0
    others = inner(tiles) & (np.abs(tiles[:, 0]) >= 2)
    assert np.abs(g.clearance[under] - 1.5).max() <= 0.06
    # elsewhere nothing is overhead: free up to the map's top, 2 m above the ground
    assert g.clearance[others].min() > 1.9
    # the ground under the bar is still found
    assert np.abs(g.slope_deg[under]).max() < 1.0
    # a 2 m-radius footprint there is rejected for clearance when 1.8 m are needed
    grid = grids(tiles, g)
    cfg = SiteConfig(footprint_radius=1.0, min_clearance=1.8, min_p_safe=0.0)
    p = np.ones(grid.plane_z.shape)
    cand = evaluate_candidates(p, p, tuple(tiles.min(axis=0)), cfg, 1.0, grid)
    i, j = -tiles.min(axis=0)  # tile (0, 0)
    assert reason_names(cand.reasons[i, j]) == ['clearance']
    assert cand.clearance[i, j] == pytest.approx(1.5, abs=0.06)
    far = i + 2
    assert reason_names(cand.reasons[far, j]) == []
    assert np.isinf(g.overhead[others]).all()  # nothing seen there ...
    # ... so asking for more than the map's 2 m above the ground cannot be answered: unknown
    cfg = SiteConfig(footprint_radius=1.0, min_clearance=2.5, min_p_safe=0.0)
    cand = evaluate_candidates(p, p, tuple(tiles.min(axis=0)), cfg, 1.0, grid)
    assert reason_names(cand.reasons[far, j]) == ['unknown']
    assert reason_names(cand.reasons[i, j]) == ['clearance']  # what is seen is enough


def grids(tiles, g) -> GroundGrids:
    nx, ny = (tiles.max(axis=0) - tiles.min(axis=0) + 1).tolist()
    return GroundGrids(g.plane_z.reshape(nx, ny), g.grad.reshape(nx, ny, 2),
                       g.clearance.reshape(nx, ny), g.overhead.reshape(nx, ny))


def test_no_site_beyond_the_maximum_slope_is_listed():
    _, pts, org = scan_site(12.0, seed=5)
    tiles, g = fitted(pts, org)
    grid = grids(tiles, g)
    p = np.ones(grid.plane_z.shape)
    origin = tuple(tiles.min(axis=0))
    steep = find_sites(p, p, origin, SiteConfig(top_k=20, max_slope_deg=8.0), ground=grid)
    assert steep == []
    cand = evaluate_candidates(p, p, origin, SiteConfig(max_slope_deg=8.0), 1.0, grid)
    known = cand.reasons & 16 == 0  # not unknown
    assert known.sum() > 4 and all('slope' in reason_names(r) for r in cand.reasons[known])
    allowed = find_sites(p, p, origin, SiteConfig(top_k=20, max_slope_deg=15.0), ground=grid)
    assert allowed and all(abs(s.slope_deg - 12.0) < 1.0 for s in allowed)
    # the pose's normal is the slope's: tilted 12 degrees towards the downhill side
    n = np.array(allowed[0].normal)
    assert math.degrees(math.acos(n[2])) == pytest.approx(12.0, abs=1.0)
    assert math.atan2(-n[1], -n[0]) == pytest.approx(0.3, abs=0.1)


def test_a_step_between_tiles_is_measured_and_rejected():
    # two level terraces 0.3 m apart, meeting at the edge x = 0 between two tiles
    z = np.zeros((6, 6))
    z[3:] = 0.3
    ground = GroundGrids(z, np.zeros((6, 6, 2)), np.full((6, 6), 2.0))
    p = np.ones((6, 6))
    cand = evaluate_candidates(p, p, (-3, -3), SiteConfig(footprint_radius=1.5,
                                                          max_step=0.15), 1.0, ground)
    assert cand.step[2, 2] == pytest.approx(0.3) and cand.step[3, 3] == pytest.approx(0.3)
    # across the footprint the kerb also tilts the plane through the tiles' heights (0.3 m
    # over 3 tiles: 8.5 degrees), so both reasons are given
    assert reason_names(cand.reasons[2, 2]) == ['slope', 'step']
    assert cand.slope_deg[2, 2] == pytest.approx(
        float(slope_deg(np.array([0.15, 0.0]))), abs=1e-4)
    # a footprint wholly on one terrace is level and has no step
    assert cand.step[4, 4] == 0.0 and cand.slope_deg[4, 4] == pytest.approx(0.0, abs=1e-9)
    assert reason_names(cand.reasons[4, 4]) == []
    # a lower kerb passes the step limit
    z[3:] = 0.1
    cand = evaluate_candidates(p, p, (-3, -3), SiteConfig(footprint_radius=1.5,
                                                          max_step=0.15), 1.0, ground)
    assert 'step' not in reason_names(cand.reasons[2, 2])


@pytest.mark.parametrize('seed', range(20))
def test_listed_sites_always_keep_every_limit(seed):
    rng = np.random.default_rng(seed)
    shape = (9, 8)
    z = rng.normal(0.0, 0.1, shape)
    grad = rng.normal(0.0, 0.12, shape + (2,))
    clearance = rng.uniform(0.5, 3.0, shape)
    hole = rng.random(shape) < 0.1
    z[hole] = np.nan
    p = rng.uniform(0.9, 1.0, shape)
    cfg = SiteConfig(footprint_radius=float(rng.uniform(0.4, 2.0)), top_k=50,
                     min_p_safe=0.3, max_slope_deg=float(rng.uniform(2.0, 12.0)),
                     max_step=float(rng.uniform(0.05, 0.4)),
                     min_clearance=float(rng.uniform(0.5, 2.5)))
    ground = GroundGrids(z, grad, clearance)
    for s in find_sites(p, p, (0, 0), cfg, ground=ground):
        assert s.slope_deg <= cfg.max_slope_deg
        assert s.step <= cfg.max_step
        assert s.clearance >= cfg.min_clearance
        assert s.p_safe >= cfg.min_p_safe
        assert math.isfinite(s.z)


def test_cubes_aligned_to_the_ground_plane_lie_level():
    from landing_zone.config import TileConfig
    from landing_zone.judging.tiles import tiles_from_counts

    _, pts, org = scan_site(12.0, seed=6)
    dmap = DensityMap(MapConfig(size_xy=8.0, size_z=4.0, z_below=2.0), parallel=False)
    dmap.integrate(pts, org)
    h, p = dmap.counts()
    tiles = tiles_in_box(dmap.lo, dmap.shape, dmap.tile_vox)
    g = fit_ground(h, p, dmap.lo, dmap.voxel_size, tiles, dmap.tile_vox)
    k = inner(tiles)
    tv, pad = dmap.tile_vox, TileConfig().padding

    def ground_rows(config):
        # per column of each tile's own (unpadded) cube, the lowest occupied voxel's index
        b = tiles_from_counts(h, p, dmap.lo, dmap.voxel_size, config, tiles[k], g[k])
        occ = b.inputs[:, 0, pad:pad + tv, pad:pad + tv, :] > 0.2
        return np.where(occ.any(axis=-1), occ.argmax(axis=-1), -1)

    level = ground_rows(TileConfig(align_to_ground=False))
    aligned = ground_rows(TileConfig(align_to_ground=True))
    # cut level, the ground of a 12 degree tile spans a fifth of a metre of the cube ...
    rows = np.where(level >= 0, level, np.nan)
    spread_level = np.nanmax(rows, axis=(1, 2)) - np.nanmin(rows, axis=(1, 2))
    assert np.nanmin(spread_level) >= 3
    # ... aligned, it lies in the ground voxel's layer (tv // 2 + padding) give or take one
    on = aligned[aligned >= 0]
    assert np.mean(np.abs(on - (tv // 2 + pad)) <= 1) > 0.95
    # on by default: the shipped model judges slopes as level ground so (model card)
    assert TileConfig().align_to_ground


def test_the_assessor_lists_no_site_beyond_the_slope_limit_and_says_why(model_file):
    from landing_zone.assessor import Assessor
    from landing_zone.config import AssessorConfig, TileConfig

    _, pts, org = scan_site(12.0, seed=7)
    cfg = AssessorConfig()
    cfg.map = MapConfig(size_xy=8.0, size_z=4.0, z_below=2.0)
    cfg.tiles = TileConfig(min_observed_fraction=0.1)
    cfg.landing_sites = SiteConfig(footprint_radius=1.0, top_k=10, min_p_safe=0.0)
    with Assessor(cfg, center=(0.0, 0.0), model=model_file) as a:
        for s in np.unique(org, axis=0):  # one cloud per sensor position
            mine = np.all(org == s, axis=1)
            a.integrate(pts[mine], s)
        r = a.assess()
        assert r.sites == []  # 12 degrees, the limit 8
        report = r.to_report()
        assert report['landing_sites'] == []
        slope = [e for e in report['rejected_sites'] if 'slope' in e['reasons']]
        assert slope and all(abs(e['slope_deg'] - 12.0) < 1.5 for e in slope)
        # the limit raised at run time (as the node's parameter does): sites, all below it
        a.config.landing_sites.max_slope_deg = 15.0
        r = a.assess()
        assert r.sites and all(s.slope_deg <= 15.0 for s in r.sites)
