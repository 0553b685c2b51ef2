"""Per-voxel hand-crafted features of a density volume, as in point-cloud classification.

Each occupied voxel of a tile's core gets 16 features, in five groups:

- spectral shape (Demantke et al. 2011; Weinmann et al. 2015): linearity, planarity and
  scattering from the eigenvalues ``l1 >= l2 >= l3`` of the covariance of the occupied voxels
  in the voxel's (2r+1)^3 neighbourhood (r = 1: 3x3x3);
- directional: the angle to vertical of the normal (eigenvector of ``l3``) and of the principal
  direction (of ``l1``), and the spread (standard deviation) of the normal angle over the
  neighbourhood;
- height: height above the tile's ground estimate (the centre of voxel S // 2 in z, where
  :mod:`landing_zone.judging.tiles` puts the ground voxel), and the standard deviation and the
  range of the occupied heights in the surrounding columns;
- more shape: omnivariance, eigenentropy, and the fill of the neighbourhood (occupied
  fraction);
- density statistics, standing in for the range-variance features of the literature (the
  volumes carry densities, not ranges): the voxel's own density, the variance of the density
  over its neighbourhood (penetrable vegetation leaves mixed densities, solid ground sharp
  ones), the number of occupied-below-free transitions along z in its column (surfaces seen
  with free space above: layered vegetation or overhangs give more than one), and the fraction
  of the column below the voxel observed free (rays that went past a hit).

Everything is vectorised: neighbourhood moments come from separable 1D correlations with
offset kernels (sums of 1, dx, dy, dz, dx^2, dx*dy, ... over the neighbourhood, exact small
integers, so the covariance suffers no cancellation), then one batched ``np.linalg.eigh``.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage

from landing_zone.tools.evaluate.baselines.volumes import VolumeGeometry, as_volumes
from landing_zone.errors import ConfigError

__all__ = ['FEATURE_NAMES', 'VoxelFeatures', 'voxel_features', 'spectral_features']

FEATURE_NAMES = (
    'linearity', 'planarity', 'scattering',
    'normal_angle', 'principal_angle', 'normal_angle_spread',
    'height', 'column_height_std', 'column_height_range',
    'omnivariance', 'eigenentropy', 'neighbourhood_fill',
    'density', 'density_variance', 'column_layers', 'free_below',
)

# Eigenvalues (voxel^2) below this count as zero: the neighbourhood is degenerate there.
_EIG_EPS = 1e-6
# Eigenvalues closer than this fraction of the largest count as equal (eigenvector undefined).
_REL_GAP = 1e-3
# Angle given where a direction is undefined (isolated voxel, or no normal on a line): the
# middle of [0, pi/2], so it reads as neither horizontal nor vertical.
_NO_ANGLE = np.pi / 4


@dataclass
class VoxelFeatures:
    """Features of the occupied core voxels of a batch of volumes.

    Attributes:
        values: (M, F) float32, columns as in :data:`FEATURE_NAMES`.
        volume: (M,) int64, the volume each row belongs to.
        ijk: (M, 3) int64, the row's voxel index (x, y, z) in its volume.
    """

    values: np.ndarray
    volume: np.ndarray
    ijk: np.ndarray


def spectral_features(eigenvalues: np.ndarray) -> np.ndarray:
    """Linearity, planarity, scattering from eigenvalues sorted ascending, (P, 3) -> (P, 3).

    A degenerate neighbourhood (largest eigenvalue zero: one isolated voxel) reads as pure
    scattering (0, 0, 1), the behaviour of isolated returns such as noise or sparse leaves.
    """
    lam = np.clip(np.asarray(eigenvalues, np.float64), 0.0, None)
    l3, l2, l1 = lam[:, 0], lam[:, 1], lam[:, 2]
    ok = l1 > _EIG_EPS
    safe = np.where(ok, l1, 1.0)
    out = np.stack([(l1 - l2) / safe, (l2 - l3) / safe, l3 / safe], axis=1)
    out[~ok] = (0.0, 0.0, 1.0)
    return out


def _moments(occ: np.ndarray, radius: int) -> dict[tuple[int, int, int], np.ndarray]:
    """Sums of dx^p dy^q dz^s over occupied neighbours (p + q + s <= 2), offsets in voxels."""
    offs = np.arange(-radius, radius + 1, dtype=np.float32)
    kern = (np.ones_like(offs), offs, offs * offs)

    def corr(a: np.ndarray, power: int, axis: int) -> np.ndarray:
        return ndimage.correlate1d(a, kern[power], axis=axis, mode='constant', cval=0.0)

    along_x = {p: corr(occ, p, 1) for p in range(3)}
    along_xy = {(p, q): corr(along_x[p], q, 2) for p in range(3) for q in range(3 - p)}
    return {(p, q, s): corr(along_xy[p, q], s, 3)
            for (p, q) in along_xy for s in range(3 - p - q)}


def _box_mean(a: np.ndarray, width: int, axes: int) -> np.ndarray:
    size = (1,) + (width,) * axes + (1,) * (a.ndim - 1 - axes)
    return ndimage.uniform_filter(a, size=size, mode='constant', cval=0.0)


def _chunk_features(vol: np.ndarray, g: VolumeGeometry, radius: int,
                    column_radius: int) -> tuple[np.ndarray, np.ndarray]:
    """Features of one chunk (B, X, Y, Z): (M, F) values and (M, 4) indices (b, i, j, k)."""
    nb, nx, _, nz = vol.shape
    core = g.core(nx)
    occ_b = vol >= g.occupied_value
    free_b = vol <= g.free_value
    occ = occ_b.astype(np.float32)

    # Voxels whose neighbourhood statistics the core needs: the core dilated by the radius.
    region = np.zeros(nx, bool)
    region[max(core.start - radius, 0):core.stop + radius] = True
    evalmask = occ_b & region[None, :, None, None] & region[None, None, :, None]
    b, i, j, k = np.nonzero(evalmask)

    # -- local covariance and its eigen-decomposition --
    mom = _moments(occ, radius)
    at = (b, i, j, k)
    n = mom[0, 0, 0][at].astype(np.float64)  # >= 1: the voxel itself is occupied
    mean = np.stack([mom[1, 0, 0][at], mom[0, 1, 0][at], mom[0, 0, 1][at]], 1) / n[:, None]
    sec = np.empty((n.size, 3, 3))
    for (r, c), key in {(0, 0): (2, 0, 0), (1, 1): (0, 2, 0), (2, 2): (0, 0, 2),
                        (0, 1): (1, 1, 0), (0, 2): (1, 0, 1), (1, 2): (0, 1, 1)}.items():
        sec[:, r, c] = sec[:, c, r] = mom[key][at] / n
    cov = sec - mean[:, :, None] * mean[:, None, :]
    lam, vec = np.linalg.eigh(cov)  # ascending; vec[:, :, m] is the m-th eigenvector
    lam = np.clip(lam, 0.0, None)
    spectral = spectral_features(lam)

    # An eigenvector is defined only where its eigenvalue stands apart from the next: a line
    # has no normal, a disc no principal direction, a ball neither. Elsewhere eigh returns an
    # arbitrary vector of the degenerate subspace, so the angle is replaced by _NO_ANGLE.
    gap = _REL_GAP * lam[:, 2] + _EIG_EPS
    normal_ok = lam[:, 1] - lam[:, 0] > gap
    principal_ok = lam[:, 2] - lam[:, 1] > gap
    normal_angle = np.where(normal_ok, np.arccos(np.clip(np.abs(vec[:, 2, 0]), 0.0, 1.0)),
                            _NO_ANGLE)
    principal_angle = np.where(principal_ok,
                               np.arccos(np.clip(np.abs(vec[:, 2, 2]), 0.0, 1.0)), _NO_ANGLE)

    width = 2 * radius + 1
    dense = np.zeros((3,) + vol.shape, np.float32)
    dense[0][at] = normal_ok
    dense[1][at] = np.where(normal_ok, normal_angle, 0.0)
    dense[2][at] = np.where(normal_ok, normal_angle ** 2, 0.0)
    m_e, m_a, m_a2 = (_box_mean(d, width, 3)[at].astype(np.float64) for d in dense)
    with np.errstate(divide='ignore', invalid='ignore'):
        mu = m_a / m_e
        spread = np.where(m_e > 0, np.sqrt(np.clip(m_a2 / m_e - mu * mu, 0.0, None)), 0.0)

    total = lam.sum(axis=1)
    e = lam / np.where(total > _EIG_EPS, total, 1.0)[:, None]
    e[total <= _EIG_EPS] = 1.0 / 3.0  # isolated voxel: no preferred direction
    omnivariance = np.cbrt(np.prod(e, axis=1))
    with np.errstate(divide='ignore', invalid='ignore'):
        entropy = 0.0 - np.sum(np.where(e > 0, e * np.log(e), 0.0), axis=1)
    fill = n / width ** 3

    # -- heights: above the ground estimate, and over the surrounding columns --
    # tiles.py puts the ground voxel at z index S // 2: heights count from its centre.
    height = (k - nz // 2) * g.voxel_size
    kk = np.arange(nz, dtype=np.float32)
    count = occ.sum(axis=3)
    cw = 2 * column_radius + 1
    c_mean = _box_mean(count, cw, 2)
    z_mean = _box_mean((occ * kk).sum(axis=3), cw, 2)
    z2_mean = _box_mean((occ * kk * kk).sum(axis=3), cw, 2)
    col = (b, i, j)
    cm = c_mean[col].astype(np.float64)  # > 0: the voxel's own column is occupied
    zbar = z_mean[col] / cm
    col_std = np.sqrt(np.clip(z2_mean[col] / cm - zbar * zbar, 0.0, None)) * g.voxel_size
    has = count > 0
    top = np.where(has, nz - 1 - np.argmax(occ_b[..., ::-1], axis=3), -1)
    bottom = np.where(has, np.argmax(occ_b, axis=3), nz)
    size = (1, cw, cw)
    top_n = ndimage.maximum_filter(top, size=size, mode='constant', cval=-1)
    bottom_n = ndimage.minimum_filter(bottom, size=size, mode='constant', cval=nz)
    col_range = (top_n[col] - bottom_n[col]) * g.voxel_size

    # -- density statistics (what the grid offers in place of ranges) --
    density = vol[at]
    v_mean = _box_mean(vol, width, 3)[at].astype(np.float64)
    v2_mean = _box_mean(vol * vol, width, 3)[at].astype(np.float64)
    dens_var = np.clip(v2_mean - v_mean * v_mean, 0.0, None)
    layers = (occ_b[..., :-1] & free_b[..., 1:]).sum(axis=3)[col]
    free_cum = np.cumsum(free_b, axis=3, dtype=np.int32)
    free_below = (free_cum[at] - free_b[at]) / np.maximum(k, 1)

    values = np.column_stack([
        spectral, normal_angle, principal_angle, spread, height, col_std, col_range,
        omnivariance, entropy, fill, density, dens_var, layers, free_below,
    ]).astype(np.float32)
    in_core = ((i >= core.start) & (i < core.stop) & (j >= core.start) & (j < core.stop))
    idx = np.stack([b, i, j, k], axis=1)
    return values[in_core], idx[in_core]


def voxel_features(inputs: Any, geometry: VolumeGeometry | None = None, radius: int = 1,
                   column_radius: int = 2, chunk: int = 64) -> VoxelFeatures:
    """Per-voxel features of the occupied voxels in each volume's tile core.

    Args:
        inputs: network inputs (T, 1, S, S, S) or (T, S, S, S), ``2 * density - 1``.
        geometry: voxel size, tile core and thresholds of the inputs.
        radius: neighbourhood half-width [voxels] of the covariance and density statistics
            (1: 3x3x3).
        column_radius: half-width [voxels] of the block of columns the height statistics span.
        chunk: volumes processed at once (bounds the memory of the intermediate grids).

    Returns:
        The features, the volume of each row and its voxel index.

    Raises:
        DatasetError: malformed inputs.
        ConfigError: a parameter out of range.
    """
    g = geometry if geometry is not None else VolumeGeometry()
    g.validate()
    if radius < 1 or column_radius < 0 or chunk < 1:
        raise ConfigError(f'need radius >= 1, column_radius >= 0, chunk >= 1, got {radius}, '
                          f'{column_radius}, {chunk}')
    vol = as_volumes(inputs)
    core = g.core(vol.shape[1])  # validates the cube against the tile
    # The core's features depend on voxels at most this far outside it (covariances at the
    # core's neighbours reach 2 * radius; column blocks reach column_radius), so filtering a
    # crop gives the same values for a fraction of the work.
    margin = min(max(2 * radius, column_radius), core.start)
    lo, hi = core.start - margin, core.stop + margin
    values, idx = [], []
    for start in range(0, vol.shape[0], chunk):
        crop = np.ascontiguousarray(vol[start:start + chunk, lo:hi, lo:hi])
        v, ix = _chunk_features(crop, g, radius, column_radius)
        ix[:, 0] += start
        ix[:, 1:3] += lo
        values.append(v)
        idx.append(ix)
    if not values:
        return VoxelFeatures(np.zeros((0, len(FEATURE_NAMES)), np.float32),
                             np.zeros(0, np.int64), np.zeros((0, 3), np.int64))
    all_idx = np.concatenate(idx).astype(np.int64)
    return VoxelFeatures(np.concatenate(values), all_idx[:, 0], all_idx[:, 1:])
