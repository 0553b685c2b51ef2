"""Plane residuals baseline: robust plane fit and clipped residual score."""
from __future__ import annotations

import numpy as np
import pytest

from landing_zone.tools.evaluate.baselines import PlaneResiduals, fit_plane, plane_residual_sum
from landing_zone.tools.evaluate.baselines.toy import heightfield_volume
from landing_zone.errors import DatasetError, InvalidCloudError


def _box(x, y):
    return 0.012 + np.where((np.abs(x) < 0.2) & (np.abs(y) < 0.2), 0.3, 0.0)


FLAT = heightfield_volume(lambda x, y: 0.012 + 0 * x)
TILTED = heightfield_volume(lambda x, y: 0.012 + 0.3 * x + 0.1 * y)
BOX = heightfield_volume(_box)


def test_flat_is_safer_than_box_and_tilt_as_safe_as_flat():
    method = PlaneResiduals()
    res = method.residuals(np.stack([FLAT, TILTED, BOX])[:, None])
    # 8 x 8 voxels of box top (0.4 m square) stand 0.3 m off the ground plane: each contributes
    # the clip, and the side walls add more.
    assert res[2] > 0.1 * 64
    assert res[0] == pytest.approx(0.0, abs=1e-9)
    # A plane crossing every occupied voxel leaves no residual, whatever its slope.
    assert abs(res[1] - res[0]) < 0.01 * (res[2] - res[0])
    score = method.score(np.stack([FLAT, TILTED, BOX]))
    np.testing.assert_allclose(score, -res)
    assert score[0] > score[2] and score[1] > score[2]


def test_steeper_slope_and_padding_obstacles_do_not_count():
    # 35 degrees is still a plane; a tall post in the padding lies outside the 1 m core.
    steep = heightfield_volume(lambda x, y: 0.012 + 0.7 * x)
    post = heightfield_volume(
        lambda x, y: 0.012 + np.where((np.abs(x - 0.7) < 0.05) & (np.abs(y) < 0.05), 0.5, 0.0))
    res = PlaneResiduals().residuals(np.stack([steep, post]))
    assert res[0] < 0.05 and res[1] < 1e-9


def test_residual_grows_with_obstacle_height_until_the_clip():
    def box_of(height):
        return heightfield_volume(
            lambda x, y: 0.012 + np.where((np.abs(x) < 0.1) & (np.abs(y) < 0.1), height, 0.0))
    res = PlaneResiduals().residuals(np.stack([box_of(h) for h in (0.05, 0.1, 0.3, 0.6)]))
    assert np.all(np.diff(res[:3]) > 0)
    # Beyond the clip only the extra side-wall voxels add (each at most 0.1 m).
    assert res[3] >= res[2]


def test_fit_plane_recovers_a_tilted_plane_despite_outliers():
    rng = np.random.default_rng(3)
    xy = rng.uniform(-0.5, 0.5, (400, 2))
    z = 0.2 * xy[:, 0] - 0.1 * xy[:, 1] + 0.05 + rng.normal(0, 0.005, 400)
    z[:120] += rng.uniform(0.2, 0.6, 120)  # 30 % outliers, all on one side
    normal, offset = fit_plane(np.column_stack([xy, z]), inlier_distance=0.02, seed=1)
    true = np.array([-0.2, 0.1, 1.0]) / np.linalg.norm([-0.2, 0.1, 1.0])
    assert np.dot(normal, true) > 0.999
    assert -offset / normal[2] == pytest.approx(0.05, abs=0.005)


def test_score_returns_from_raw_points():
    rng = np.random.default_rng(0)
    xy = rng.uniform(-0.6, 0.6, (2000, 2))
    flat = np.column_stack([xy, 0.002 * rng.standard_normal(2000)])
    tilted = np.column_stack([xy, 0.25 * xy[:, 0] + 0.002 * rng.standard_normal(2000)])
    box = flat.copy()
    inside = (np.abs(xy[:, 0]) < 0.2) & (np.abs(xy[:, 1]) < 0.2)
    box[inside, 2] += 0.3
    flat[0] = np.nan  # dropped, not fatal
    s = PlaneResiduals().score_returns([flat, tilted, box])
    # The box top clips at 0.1 m a point; 2 mm noise costs about 1.6 mm a point on any slope.
    core = np.all(np.abs(xy) <= 0.5, axis=1).sum()
    assert s[2] < -0.1 * inside.sum() * 0.95
    assert s[0] > -0.003 * core and s[1] > -0.003 * core
    assert abs(s[1] - s[0]) < 0.05 * abs(s[2] - s[0])
    with pytest.raises(InvalidCloudError, match='cloud 0'):
        PlaneResiduals().score_returns([np.zeros((4, 2))])


def test_deterministic_and_batch_independent():
    vols = np.stack([FLAT, TILTED, BOX, np.roll(BOX, 3, axis=0)])
    a = PlaneResiduals(seed=5).score(vols)
    b = PlaneResiduals(seed=5).score(vols[::-1])[::-1]
    assert a.tobytes() == b.tobytes()


def test_empty_nan_and_malformed_inputs():
    method = PlaneResiduals()
    empty = np.zeros((1, 32, 32, 32), np.float32)  # nothing observed: nothing to fit
    nan = BOX.copy()
    nan[10:20, 10:20, 25] = np.nan  # free voxels above the box, read as unobserved
    s = method.score(np.stack([empty[0], nan]))
    assert s[0] == 0.0
    assert s[1] == method.score(BOX[None])[0]
    assert method.score(np.zeros((0, 1, 32, 32, 32), np.float32)).shape == (0,)
    with pytest.raises(DatasetError, match='one channel'):
        method.score(np.zeros((1, 2, 32, 32, 32)))
    with pytest.raises(DatasetError, match='centred tile'):
        method.score(np.zeros((1, 1, 31, 31, 31)))
    assert plane_residual_sum(np.zeros((2, 3))) == 0.0
