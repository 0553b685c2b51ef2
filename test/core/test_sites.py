"""Landing sites on hand-made probability grids."""
from __future__ import annotations

import numpy as np
import pytest

from landing_zone.config import SiteConfig
from landing_zone.errors import ConfigError
from landing_zone.judging.sites import find_sites, footprint_mask, site_probabilities


def test_footprint_mask_counts_tiles_the_disc_overlaps():
    # radius 1.5 on 1 m tiles: the 3 x 3 block (the disc only touches the tiles 2 away)
    assert footprint_mask(1.5, 1.0).shape == (3, 3)
    assert footprint_mask(1.5, 1.0).all()
    # radius 0.5: only the centre tile (its neighbours are touched at their edges)
    assert footprint_mask(0.5, 1.0).tolist() == [[True]]
    # radius 1.6: the 5 x 5 block but its corners (nearest corner point 2.12 m away; the
    # tile two over and one up is 1.58 m away)
    m = footprint_mask(1.6, 1.0)
    assert m.shape == (5, 5)
    assert m.sum() == 25 - 4
    assert not m[0, 0] and m[0, 1] and m[2, 0]
    # every tile under the mask overlaps the disc (brute force on a fine grid)
    r = 2.3
    m = footprint_mask(r, 1.0)
    h = m.shape[0] // 2
    xs = np.linspace(-h - 0.5, h + 0.5, 401)
    gx, gy = np.meshgrid(xs, xs, indexing='ij')
    inside = gx ** 2 + gy ** 2 < r * r
    ti = np.clip(np.floor(gx + 0.5).astype(int) + h, 0, 2 * h)
    tj = np.clip(np.floor(gy + 0.5).astype(int) + h, 0, 2 * h)
    hit = np.zeros_like(m)
    hit[ti[inside], tj[inside]] = True
    assert np.array_equal(hit, m)


def test_footprint_probability_is_the_least_tile_probability_under_the_disc():
    rng = np.random.default_rng(0)
    p = rng.uniform(0.6, 1.0, (7, 7))
    c = rng.uniform(0.2, 1.0, (7, 7))
    ps, pm, cs = site_probabilities(p, c, 1.5, 1.0)
    assert ps[3, 3] == p[2:5, 2:5].min()
    assert pm[3, 3] == pytest.approx(np.prod(p[2:5, 2:5]) ** (1 / 9))
    assert cs[3, 3] == pytest.approx(c[2:5, 2:5].min())
    # never above the probability of any one tile under it (no event is likelier than one it
    # implies), never below the product (what independent tiles would give)
    inner = (slice(1, 6), slice(1, 6))
    assert np.all(ps[inner] <= pm[inner]) and np.all(pm[inner] ** 9 <= ps[inner] + 1e-12)
    # footprints reaching past the grid are disqualified
    assert np.isnan(ps[0, 3]) and np.isnan(ps[6, 6])
    assert np.isfinite(ps[1:6, 1:6]).all()


def test_best_site_is_the_clear_patch():
    p = np.full((12, 10), 0.7)
    p[6:9, 2:5] = 0.99  # a clear 3 x 3 patch centred on cell (7, 3)
    conf = np.ones_like(p)
    sites = find_sites(p, conf, origin=(-6, -5), config=SiteConfig(footprint_radius=1.5,
                       top_k=3, min_p_safe=0.0))
    best = sites[0]
    assert best.index == (7 - 6, 3 - 5)
    assert (best.x, best.y) == (1.5, -1.5)
    assert best.p_safe == pytest.approx(0.99)
    assert sites == sorted(sites, key=lambda s: -s.p_safe)


def test_unknown_tile_disqualifies_its_footprints():
    p = np.full((9, 9), 0.95)
    p[4, 4] = np.nan
    conf = np.ones_like(p)
    ps, pm, _ = site_probabilities(p, conf, 1.5, 1.0)
    assert np.isnan(ps[3:6, 3:6]).all() and np.isnan(pm[3:6, 3:6]).all()
    assert np.isfinite(ps[1, 1])
    sites = find_sites(p, conf, origin=(0, 0), config=SiteConfig(1.5, top_k=50, min_p_safe=0.0),
                       min_separation=0.0)
    for s in sites:
        assert max(abs(s.index[0] - 4), abs(s.index[1] - 4)) >= 2
    assert len(sites) == 7 * 7 - 9


def test_an_unknown_patch_is_never_preferred_to_a_poor_known_one():
    p = np.full((9, 9), np.nan)
    p[1:4, 1:4] = 0.6
    conf = np.ones_like(p)
    sites = find_sites(p, conf, origin=(0, 0), config=SiteConfig(1.5, top_k=5, min_p_safe=0.0))
    assert [s.index for s in sites] == [(2, 2)]
    assert sites[0].p_safe == pytest.approx(0.6)


def test_non_maximum_suppression_keeps_sites_apart():
    p = np.full((20, 20), 0.9)
    p[10, 10] = 0.999
    conf = np.ones_like(p)
    cfg = SiteConfig(footprint_radius=1.5, top_k=5, min_p_safe=0.0)
    sites = find_sites(p, conf, origin=(0, 0), config=cfg)
    assert len(sites) == 5
    xy = np.array([[s.x, s.y] for s in sites])
    d = np.linalg.norm(xy[:, None] - xy[None], axis=-1)
    assert d[np.triu_indices(5, 1)].min() >= 3.0
    # every footprint's least tile is 0.9: the tie goes to those whose other tiles are surer,
    # the footprints over the excellent tile
    assert all(s.p_safe == pytest.approx(0.9) for s in sites)
    assert max(abs(sites[0].index[0] - 10), abs(sites[0].index[1] - 10)) <= 1


def test_min_p_safe_and_zero_probability():
    p = np.full((6, 6), 0.9)
    p[2, 2] = 0.0
    conf = np.full_like(p, 0.5)
    ps, pm, cs = site_probabilities(p, conf, 1.5, 1.0)
    assert ps[2, 2] == 0.0 and ps[3, 3] == 0.0 and pm[3, 3] == 0.0
    assert cs[4, 4] == pytest.approx(0.5)
    sites = find_sites(p, conf, origin=(0, 0), config=SiteConfig(1.5, 10, min_p_safe=0.5),
                       min_separation=0.0)
    # the footprints inside the grid clear of the unsafe tile, at the others' 0.9
    assert sorted(s.index for s in sites) == [(i, j) for i in range(1, 5) for j in range(1, 5)
                                              if max(abs(i - 2), abs(j - 2)) >= 2]
    assert all(s.p_safe == pytest.approx(0.9) for s in sites)
    sites = find_sites(p, conf, origin=(0, 0), config=SiteConfig(1.5, 10, min_p_safe=0.0),
                       ground_z=np.full_like(p, 0.25))
    assert all(s.z == 0.25 for s in sites)
    assert sites[-1].p_safe == 0.0


def test_one_doubtful_tile_bounds_its_footprints():
    # sure ground but one tile the net doubts: every footprint over it reads that tile's P, the
    # threshold leaves them out for the obstacle, and the footprints clear of it are listed
    p = np.full((9, 9), 0.97)
    p[4, 4] = 0.3
    conf = np.ones_like(p)
    cfg = SiteConfig(1.5, top_k=50, min_p_safe=0.8)
    ps, _, _ = site_probabilities(p, conf, 1.5, 1.0)
    assert np.all(ps[3:6, 3:6] == 0.3)
    sites = find_sites(p, conf, origin=(0, 0), config=cfg, min_separation=0.0)
    assert len(sites) == 7 * 7 - 9
    assert all(max(abs(s.index[0] - 4), abs(s.index[1] - 4)) >= 2 for s in sites)
    assert all(s.p_safe == pytest.approx(0.97) for s in sites)


def test_footprint_truth_is_every_tile_under_it_labelled_safe():
    from landing_zone.tools.evaluate.footprints import footprint_truth

    truth = np.ones((6, 6), np.int8)
    truth[1, 1] = 0   # an obstacle tile
    truth[4, 4] = -1  # a tile without a label
    ft = footprint_truth(truth, 1.5, 1.0)
    # off the grid counts as unlabelled; an unsafe tile under a footprint decides it
    assert ft[0, 0] == 0 and ft[0, 5] == -1 and ft[5, 0] == -1
    for i in range(1, 5):
        for j in range(1, 5):
            near = (max(abs(i - 1), abs(j - 1)) <= 1, max(abs(i - 4), abs(j - 4)) <= 1)
            assert ft[i, j] == (0 if near[0] else -1 if near[1] else 1), (i, j)
    assert (ft[1:5, 1:5] == 1).sum() == 16 - 4 - 4


def test_bad_arguments_raise_config_errors():
    with pytest.raises(ConfigError, match='footprint radius'):
        footprint_mask(0.0, 1.0)
    with pytest.raises(ConfigError, match='one shape'):
        site_probabilities(np.zeros((3, 3)), np.zeros((3, 4)), 1.0, 1.0)
    with pytest.raises(ConfigError, match='landing_sites.top_k'):
        find_sites(np.zeros((3, 3)), np.zeros((3, 3)), (0, 0), SiteConfig(top_k=-1))
    assert find_sites(np.zeros((0, 0)), np.zeros((0, 0)), (0, 0)) == []
    # a footprint within one tile is judged on that tile alone
    assert site_probabilities(np.full((1, 1), 0.5), np.ones((1, 1)), 0.4, 1.0)[0][0, 0] == 0.5
