"""Per-voxel features of the BoW baseline: spectral, directional, height, density statistics."""
from __future__ import annotations

import numpy as np
import pytest

from landing_zone.tools.evaluate.baselines import FEATURE_NAMES, voxel_features
from landing_zone.tools.evaluate.baselines.features import spectral_features
from landing_zone.tools.evaluate.baselines.toy import heightfield_volume
from landing_zone.errors import ConfigError, DatasetError

S = 32
COL = {name: i for i, name in enumerate(FEATURE_NAMES)}


def _at(feats, volume, ijk):
    row = (feats.volume == volume) & np.all(feats.ijk == ijk, axis=1)
    assert row.sum() == 1, f'voxel {ijk} of volume {volume} not among the features'
    return {name: float(v) for name, v in zip(FEATURE_NAMES, feats.values[row][0])}


def _shapes():
    vols = np.full((4, S, S, S), -0.5, np.float32)  # observed free everywhere ...
    vols[0, 4:28, 16, 16] = 0.6   # ... but a horizontal line along x
    vols[1, :, :, 16] = 0.6       # a horizontal plane
    vols[2, 12:21, 12:21, 12:21] = 0.6  # a solid blob
    vols[3, 16, 16, 4:28] = 0.6   # a vertical line (a pole)
    return vols


def test_spectral_features_of_line_plane_blob():
    f = voxel_features(_shapes())
    line, plane, blob = (_at(f, t, (16, 16, 16)) for t in range(3))
    assert line['linearity'] == pytest.approx(1.0)
    assert plane['planarity'] == pytest.approx(1.0)
    assert blob['scattering'] == pytest.approx(1.0)
    for name in ('planarity', 'scattering'):
        assert line[name] == pytest.approx(0.0, abs=1e-6)
    for name in ('linearity', 'scattering'):
        assert plane[name] == pytest.approx(0.0, abs=1e-6)
    for name in ('linearity', 'planarity'):
        assert blob[name] == pytest.approx(0.0, abs=1e-6)
    # The three sum to 1 by construction; omnivariance is 1/3 only for the isotropic blob.
    rows = f.values[:, :3]
    np.testing.assert_allclose(rows.sum(axis=1), 1.0, atol=1e-5)
    assert blob['omnivariance'] == pytest.approx(1 / 3, abs=1e-6)
    assert blob['eigenentropy'] == pytest.approx(np.log(3), abs=1e-5)
    assert plane['eigenentropy'] == pytest.approx(np.log(2), abs=1e-5)
    assert plane['neighbourhood_fill'] == pytest.approx(9 / 27)


def test_directions_to_vertical():
    f = voxel_features(_shapes())
    line, plane, _, pole = (_at(f, t, (16, 16, 16)) for t in range(4))
    assert plane['normal_angle'] == pytest.approx(0.0, abs=1e-6)
    assert line['principal_angle'] == pytest.approx(np.pi / 2, abs=1e-6)
    assert pole['principal_angle'] == pytest.approx(0.0, abs=1e-6)
    assert plane['normal_angle_spread'] == pytest.approx(0.0, abs=1e-6)
    # A tilted plane's normal leans by its slope; a wall's is horizontal.
    slope = np.arctan(0.5)
    tilted = heightfield_volume(lambda x, y: 0.5 * x + 0.001)
    wall = np.full((S, S, S), -0.5, np.float32)
    wall[16, :, :] = 0.6
    f2 = voxel_features(np.stack([tilted, wall]))
    angles = f2.values[f2.volume == 0, COL['normal_angle']]
    assert np.median(angles) == pytest.approx(slope, abs=0.1)
    assert _at(f2, 1, (16, 16, 16))['normal_angle'] == pytest.approx(np.pi / 2, abs=1e-6)


def test_height_and_column_features_of_a_box():
    box = heightfield_volume(
        lambda x, y: 0.012 + np.where((np.abs(x) < 0.2) & (np.abs(y) < 0.2), 0.3, 0.0))
    f = voxel_features(box[None])
    top = _at(f, 0, (16, 16, 22))  # box top at 0.312 m: voxel [0.30, 0.35)
    ground = _at(f, 0, (8, 8, 16))  # ground 0.4 m from the box
    edge = _at(f, 0, (12, 16, 22))  # top of the box's side wall
    assert top['height'] == pytest.approx(0.3)  # heights count from the ground voxel (16)
    assert ground['height'] == pytest.approx(0.0)
    assert top['column_height_range'] == pytest.approx(0.0)
    assert ground['column_height_range'] == pytest.approx(0.0)
    # Columns within two voxels of the wall see both the ground and the top.
    assert edge['column_height_range'] == pytest.approx(0.3)
    assert edge['column_height_std'] > 0.05
    assert f.values[:, COL['column_layers']].min() == 1  # one surface under free space


def test_density_statistics_see_layers_and_penetration():
    vol = np.zeros((S, S, S), np.float32)
    vol[:, :, :16] = 0.0    # below the ground: unobserved
    vol[:, :, 16] = 0.6     # ground
    vol[:, :, 17:] = -0.5   # free above ...
    vol[:, :, 20] = 0.4     # ... but a canopy layer at 0.2 m
    f = voxel_features(vol[None])
    canopy, ground = _at(f, 0, (16, 16, 20)), _at(f, 0, (16, 16, 16))
    assert canopy['column_layers'] == 2 and ground['column_layers'] == 2
    assert canopy['free_below'] == pytest.approx(3 / 20)  # 17, 18, 19 free of 20 below
    assert ground['free_below'] == 0.0
    assert canopy['density'] == pytest.approx(0.4)
    assert canopy['density_variance'] > 0.1  # a thin sheet among free space


def test_only_core_voxels_and_bad_inputs():
    f = voxel_features(_shapes())
    assert np.all((f.ijk[:, :2] >= 6) & (f.ijk[:, :2] < 26))
    assert np.all(np.isfinite(f.values))
    assert f.values.shape[1] == len(FEATURE_NAMES) == 16
    nan = _shapes()
    nan[1, 10, 10, 16] = np.inf
    g = voxel_features(nan)
    assert np.all(np.isfinite(g.values))
    assert not np.any((g.volume == 1) & np.all(g.ijk == (10, 10, 16), axis=1))
    empty = voxel_features(np.zeros((0, 1, S, S, S), np.float32))
    assert empty.values.shape == (0, 16)
    with pytest.raises(DatasetError):
        voxel_features(np.zeros((2, S, S)))
    with pytest.raises(ConfigError):
        voxel_features(_shapes(), radius=0)


def test_spectral_features_degenerate_neighbourhood():
    out = spectral_features(np.array([[0.0, 0.0, 0.0], [0.0, 0.0, 2.0], [1.0, 1.0, 1.0]]))
    np.testing.assert_allclose(out, [[0, 0, 1], [1, 0, 0], [0, 0, 1]])


def test_thresholds_match_the_tiles_definition():
    # (hits - passes) / (hits + passes + 2) in float32, as tiles.py writes it.
    def x(h, p):
        return np.float32(h - p) / np.float32(h + p + 2)
    vol = np.zeros((S, S, S), np.float32)
    vol[10, 10, 16] = x(2, 1)  # density exactly 0.6: occupied
    vol[12, 12, 16] = x(1, 1)  # density 0.5: neither
    vol[14, 14, 16] = x(1, 0)  # one hit: occupied
    vol[14, 14, 17] = x(1, 2)  # density exactly 0.4: free
    f = voxel_features(vol[None])
    assert {tuple(v) for v in f.ijk} == {(10, 10, 16), (14, 14, 16)}
    assert _at(f, 0, (14, 14, 16))['column_layers'] == 1
    from landing_zone.tools.evaluate.baselines import VolumeGeometry
    with pytest.raises(ConfigError, match='occupied_density'):
        voxel_features(vol[None], VolumeGeometry(occupied_density=0.5))
