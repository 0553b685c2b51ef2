"""Plane residuals: how far a tile's surface departs from its best-fitting plane.

The simplest landing-zone test (the paper's first baseline): fit a plane robustly to the
occupied voxels of the tile's 1 m core, sum each point's distance to it clipped to 0.1 m, and
call the tile safer the smaller that sum. It needs no training; a tilted but smooth slope scores
like flat ground, which is both its appeal and, on terrain where slope matters, its limit.

The robust fit is MSAC (RANSAC scored by truncated squared distance) over a fixed set of
random triples, all hypotheses tested at once as one ``(N, K)`` distance matrix, then refined
by total least squares on the inliers. scikit-learn's RANSACRegressor does the same job, but
its per-call validation and estimator cloning cost milliseconds per tile, ten times the fit.
"""
from __future__ import annotations

from typing import Any, Callable, Sequence

import numpy as np

from landing_zone.tools.evaluate.baselines.volumes import VolumeGeometry, as_volumes
from landing_zone.errors import ConfigError, InvalidCloudError

__all__ = ['PlaneResiduals', 'fit_plane', 'plane_residual_sum']


def fit_plane(points: np.ndarray, inlier_distance: float, seed: int = 0,
              hypotheses: int = 64, min_normal_z: float = 0.5,
              refinements: int = 2) -> tuple[np.ndarray, float]:
    """Fit a plane robustly to 3D points.

    Args:
        points: (N, 3) float coordinates [m], N >= 3.
        inlier_distance: distance [m] within which a point supports a plane.
        seed: seed of the random triples (the same for every call, so a tile's score does
            not depend on which batch it came in).
        hypotheses: random triples tried.
        min_normal_z: planes steeper than arccos(min_normal_z) are not ground and are skipped
            (otherwise the side of a large box could win).
        refinements: rounds of total least squares on the current inliers.

    Returns:
        (normal, offset): unit normal with a non-negative z component and the offset d of the
        plane ``normal . p + d = 0``.

    Raises:
        InvalidCloudError: fewer than 3 points or a non-finite coordinate.
    """
    pts = np.asarray(points, np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or pts.shape[0] < 3:
        raise InvalidCloudError(f'a plane fit needs (N >= 3, 3) points, got shape {pts.shape}')
    if not np.all(np.isfinite(pts)):
        raise InvalidCloudError('a plane fit needs finite points')
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, pts.shape[0], size=(hypotheses, 3))
    p0, p1, p2 = pts[idx[:, 0]], pts[idx[:, 1]], pts[idx[:, 2]]
    normals = np.cross(p1 - p0, p2 - p0)  # (K, 3)
    length = np.linalg.norm(normals, axis=1)
    ok = length > 1e-12
    normals[ok] /= length[ok, None]
    normals *= np.where(normals[:, 2:3] < 0, -1.0, 1.0)
    ok &= normals[:, 2] >= min_normal_z
    if ok.any():
        normals = normals[ok]
        offsets = -np.einsum('kj,kj->k', normals, p0[ok])
        dist = pts @ normals.T + offsets  # (N, K)
        cost = np.minimum(dist * dist, inlier_distance ** 2).sum(axis=0)
        best = int(np.argmin(cost))
        normal, offset = normals[best], float(offsets[best])
    else:
        # No usable triple (all collinear or steep): start from the horizontal plane through the
        # median height, which the refinement then tilts if the points allow it.
        normal, offset = np.array([0.0, 0.0, 1.0]), -float(np.median(pts[:, 2]))
    for _ in range(refinements):
        inl = np.abs(pts @ normal + offset) <= inlier_distance
        if inl.sum() < 3:
            break
        centroid = pts[inl].mean(axis=0)
        centred = pts[inl] - centroid
        _, vecs = np.linalg.eigh(centred.T @ centred)
        cand = vecs[:, 0] * (1.0 if vecs[2, 0] >= 0 else -1.0)
        if cand[2] < min_normal_z:  # inliers degenerate (a line): keep the hypothesis
            break
        normal, offset = cand, -float(centroid @ cand)
    return normal, offset


def plane_residual_sum(points: np.ndarray, clip: float = 0.1, inlier_distance: float = 0.05,
                       tolerance: float | Callable[[np.ndarray], float] = 0.0,
                       seed: int = 0) -> float:
    """Sum over points of the distance to their robust plane, each clipped to ``clip`` [m].

    Args:
        points: (N, 3) coordinates [m]; fewer than 3 give 0 (nothing to depart from).
        clip: largest contribution of one point [m].
        inlier_distance: inlier band of the robust fit [m].
        tolerance: distance [m] below which a point counts as on the plane, or a function of
            the fitted unit normal giving it; for voxels, the half-extent of the voxel along
            the normal, so that a plane crossing a voxel leaves it no residual and
            quantisation does not penalise slopes.
        seed: seed of the robust fit's random triples.
    """
    pts = np.asarray(points, np.float64)
    if pts.shape[0] < 3:
        return 0.0
    normal, offset = fit_plane(pts, inlier_distance, seed=seed)
    dist = np.abs(pts @ normal + offset)
    tol = tolerance(normal) if callable(tolerance) else float(tolerance)
    res = np.clip(dist - tol, 0.0, clip)
    return float(res.sum())


class PlaneResiduals:
    """The "Plane residuals" baseline: score = minus the clipped residual sum (higher = safer).

    Attributes:
        name: the paper's name of the method.
        probabilistic: whether scores are P(safe) (evaluation reports an ECE only then).
    """

    name = 'Plane residuals'
    probabilistic = False  # a negated length [m], not P(safe): evaluation reports no ECE

    def __init__(self, geometry: VolumeGeometry | None = None, clip: float = 0.1,
                 inlier_distance: float | None = None, seed: int = 0) -> None:
        """Set up the baseline.

        Args:
            geometry: voxel size, tile core and occupancy threshold of the inputs.
            clip: largest residual one point contributes [m] (the paper's 0.1 m).
            inlier_distance: inlier band of the robust fit [m]; default one voxel.
            seed: seed of the robust fit's random triples.

        Raises:
            ConfigError: a parameter is out of range.
        """
        self.geometry = geometry if geometry is not None else VolumeGeometry()
        self.geometry.validate()
        if not (np.isfinite(clip) and clip > 0):
            raise ConfigError(f'clip must be positive, got {clip!r}')
        self.clip = float(clip)
        self.inlier_distance = float(self.geometry.voxel_size if inlier_distance is None
                                     else inlier_distance)
        if not (np.isfinite(self.inlier_distance) and self.inlier_distance > 0):
            raise ConfigError(f'inlier_distance must be positive, got {inlier_distance!r}')
        self.seed = int(seed)

    def residuals(self, inputs: Any) -> np.ndarray:
        """Clipped residual sum [m] of each volume's occupied core voxels, shape (T,)."""
        vol = as_volumes(inputs)
        g = self.geometry
        core = g.core(vol.shape[1])
        xs = g.centres(vol.shape[1])[core]
        zs = g.centres(vol.shape[3])
        half = 0.5 * g.voxel_size

        def voxel_tolerance(normal: np.ndarray) -> float:
            # Half-extent of a cube along the normal: the plane touches the voxel within it.
            return half * float(np.abs(normal).sum())

        out = np.zeros(vol.shape[0])
        occupied = vol[:, core, core, :] >= g.occupied_value
        for t in range(vol.shape[0]):
            i, j, k = np.nonzero(occupied[t])
            pts = np.stack([xs[i], xs[j], zs[k]], axis=1)
            out[t] = plane_residual_sum(pts, self.clip, self.inlier_distance,
                                        voxel_tolerance, self.seed)
        return out

    def score(self, inputs: Any) -> np.ndarray:
        """Safety score of each volume (T,): the negated residual sum, higher = safer."""
        return -self.residuals(inputs)

    def score_returns(self, clouds: Sequence[np.ndarray]) -> np.ndarray:
        """The same score from raw returns, one (N, 3) cloud per tile in the tile's frame.

        The cloud is cropped to the tile core (|x|, |y| <= tile_size / 2); non-finite points
        are dropped. Returns are not quantised, so no voxel tolerance applies.

        Raises:
            InvalidCloudError: a cloud is not (N, 3).
        """
        half = 0.5 * self.geometry.tile_size
        out = np.zeros(len(clouds))
        for t, cloud in enumerate(clouds):
            pts = np.asarray(cloud, np.float64)
            if pts.ndim != 2 or pts.shape[1] != 3:
                raise InvalidCloudError(f'cloud {t} must be (N, 3), got shape {pts.shape}')
            keep = np.all(np.isfinite(pts), axis=1)
            keep &= (np.abs(pts[:, 0]) <= half) & (np.abs(pts[:, 1]) <= half)
            out[t] = -plane_residual_sum(pts[keep], self.clip, self.inlier_distance,
                                         0.0, self.seed)
        return out
