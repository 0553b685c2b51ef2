"""Virtual obstacles in recorded returns: the rays that would have hit them are cut short.

:func:`alter_returns` is the array core, ``points (N, 3)`` and ``origins (N, 3)`` in, the
altered points and the mask of altered returns out: every return whose ray, from the sensor
origin to the return, meets an obstacle's surface first is moved to that surface (plus the
sensor's range noise, along the ray); every other return is left exactly as it was. Rays that
passed by stay as they were, and the obstacle's shadow appears by itself: the returns that would
have lain behind it now lie on it. One Embree scene holds all obstacles (:class:`ObstacleScene`,
cast in a frame local to them so float32 keeps sub-micrometre precision); only rays whose
segment meets an obstacle's bounding box (:func:`segments_meet_boxes`, compiled) are cast.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numba as nb
import numpy as np

from landing_zone.errors import ConfigError
from landing_zone.tools.sim.mesh import Mesh
from landing_zone.tools.sim.obstacles import Obstacle
from landing_zone.tools.sim.raycast import RayCaster

__all__ = ['ObstacleScene', 'alter_returns', 'segment_meets_box', 'segments_meet_boxes',
           'RANGE_SIGMA']

RANGE_SIGMA = 0.025  # [m] the simulator's SensorConfig.range_sigma
_BOX_MARGIN = 1e-3  # [m] bounding boxes are widened by this for the ray prefilter


@nb.njit(cache=True, inline='always')
def segment_meets_box(o: np.ndarray, i: int, p: np.ndarray, j: int, boxes: np.ndarray,
                      k: int) -> bool:
    """Whether the segment ``o[i] -> p[j]`` meets the axis-aligned box ``boxes[k]`` (slab
    method; a NaN coordinate meets nothing). Inlined into the compiled loops that call it, so
    the arrays are indexed in place rather than passed per call."""
    t0, t1 = 0.0, 1.0
    for a in range(3):
        start = o[i, a]
        d = p[j, a] - start
        lo, hi = boxes[k, 0, a], boxes[k, 1, a]
        if d != d:
            return False
        if d == 0.0:  # parallel to the slab: inside it everywhere or nowhere
            if not lo <= start <= hi:
                return False
        else:
            ta = (lo - start) / d
            tb = (hi - start) / d
            if ta > tb:
                ta, tb = tb, ta
            t0 = max(t0, ta)
            t1 = min(t1, tb)
            if t0 > t1:
                return False
    return True


@nb.njit(cache=True)
def _meet_kernel(o: np.ndarray, p: np.ndarray, boxes: np.ndarray, out: np.ndarray) -> None:
    """Slab test of every segment against the boxes until one is met."""
    for i in range(p.shape[0]):
        for k in range(boxes.shape[0]):
            if segment_meets_box(o, i, p, i, boxes, k):
                out[i] = True
                break


def segments_meet_boxes(origins: np.ndarray, points: np.ndarray, boxes: np.ndarray
                        ) -> np.ndarray:
    """Which segments ``origin -> point`` meet at least one axis-aligned box (slab method).

    Args:
        origins: (N, 3) or (3,) segment starts.
        points: (N, 3) segment ends (a segment with a NaN meets nothing).
        boxes: (K, 2, 3) lower and upper corners.

    Returns:
        (N,) bool.
    """
    p = np.ascontiguousarray(points, np.float64).reshape(-1, 3)
    o = np.ascontiguousarray(np.broadcast_to(np.asarray(origins, np.float64), p.shape))
    out = np.zeros(len(p), bool)
    b = np.ascontiguousarray(boxes, np.float64).reshape(-1, 2, 3)
    if len(p) and len(b):
        _meet_kernel(o, p, b, out)
    return out


class ObstacleScene:
    """Obstacles ready for ray casting: one Embree scene in a frame local to them.

    Embree works in float32; flights sit tens or hundreds of metres from their frame's origin,
    so the mesh and the rays are shifted by ``offset`` (the obstacles' centre) first.

    Args:
        target: placed obstacles, a :class:`~landing_zone.tools.sim.mesh.Mesh` or a
            :class:`~landing_zone.tools.sim.raycast.RayCaster` (cast as it is, no shift).
        threads: Embree build threads (0: one per core).

    Attributes:
        offset: (3,) world position of the casting frame's origin.
        boxes: (K, 2, 3) world bounding boxes (one per obstacle, one for a mesh or caster).
    """

    def __init__(self, target: Sequence[Obstacle] | Mesh | RayCaster | ObstacleScene,
                 threads: int = 1) -> None:
        if isinstance(target, ObstacleScene):
            self.caster, self.offset, self.boxes = target.caster, target.offset, target.boxes
            return
        if isinstance(target, RayCaster):
            self.caster = target
            self.offset = np.zeros(3)
            self.boxes = target.mesh.bounds()[None] if target.mesh.n_faces else np.zeros(
                (0, 2, 3))
            return
        if isinstance(target, Mesh):
            meshes = [target] if target.n_faces else []
        else:
            meshes = [o.mesh() for o in target]
        self.boxes = np.array([m.bounds() for m in meshes]).reshape(-1, 2, 3)
        self.offset = (self.boxes[:, 0].min(axis=0) + self.boxes[:, 1].max(axis=0)) / 2 \
            if len(self.boxes) else np.zeros(3)
        self.offset = np.round(self.offset, 3)
        local = [Mesh(m.vertices.astype(np.float64) - self.offset, m.faces, m.labels)
                 for m in meshes]
        self.caster = RayCaster(Mesh.concat(local), threads=threads)

    def __len__(self) -> int:
        return len(self.boxes)

    def first_hits(self, points: np.ndarray, origins: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Where each ray ``origin -> point`` first meets an obstacle before the point.

        Returns:
            ``(mask (N,), t (M,), directions (M, 3))``: the rays that meet one, the distance
            from the origin to the hit and the unit direction of each of them [m].
        """
        p = np.asarray(points, np.float64).reshape(-1, 3)
        o = np.broadcast_to(np.asarray(origins, np.float64), p.shape)
        mask = np.zeros(len(p), bool)
        if not len(self.boxes) or not len(p):
            return mask, np.zeros(0), np.zeros((0, 3))
        widened = self.boxes + np.array([-_BOX_MARGIN, _BOX_MARGIN])[None, :, None]
        # Every segment lies in the bounding box of the rays' ends: most clouds of a flight
        # see no obstacle at all and stop here.
        lo = np.minimum(p.min(axis=0), o.min(axis=0))
        hi = np.maximum(p.max(axis=0), o.max(axis=0))
        near = np.all((widened[:, 0] <= hi) & (widened[:, 1] >= lo), axis=1)
        if not near.any():
            return mask, np.zeros(0), np.zeros((0, 3))
        cand = np.flatnonzero(segments_meet_boxes(o, p, widened[near]))
        if not len(cand):
            return mask, np.zeros(0), np.zeros((0, 3))
        d = p[cand] - o[cand]
        r = np.linalg.norm(d, axis=1)
        ok = r > 0
        cand, d, r = cand[ok], d[ok], r[ok]
        d /= r[:, None]
        hits = self.caster.cast(o[cand] - self.offset, d, t_max=float(r.max()) if len(r) else 0)
        before = hits.hit & (hits.t < r)
        mask[cand[before]] = True
        return mask, hits.t[before], d[before]


def alter_returns(points: np.ndarray, origins: np.ndarray,
                  obstacles: Sequence[Obstacle] | Mesh | RayCaster | ObstacleScene,
                  rng: np.random.Generator | None = None, range_sigma: float = RANGE_SIGMA,
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Returns as they would be had the obstacles been there.

    A return whose ray (origin to return) meets an obstacle's surface first moves to that
    point plus Gaussian range noise along the ray; every other return is copied unchanged.

    Args:
        points: (N, 3) returns [m].
        origins: (N, 3) or (3,) sensor origin of each return [m].
        obstacles: placed obstacles, their mesh, a RayCaster of it or an
            :class:`ObstacleScene` (build one to reuse it over many clouds).
        rng: draws the range noise (one normal per altered return, in order); required when
            ``range_sigma > 0``.
        range_sigma: standard deviation of the range noise [m] (0: exactly on the surface).

    Returns:
        ``(points (N, 3) float64, altered (N,) bool)``.

    Raises:
        ConfigError: shapes that do not match, a negative sigma or sigma without rng.
    """
    p = np.asarray(points, np.float64)
    if p.ndim != 2 or p.shape[1] != 3:
        raise ConfigError(f'points must have shape (N, 3), got {p.shape}')
    o = np.asarray(origins, np.float64)
    if o.shape not in ((3,), p.shape):
        raise ConfigError(f'origins must have shape (3,) or {p.shape}, got {o.shape}')
    if not (math.isfinite(range_sigma) and range_sigma >= 0):
        raise ConfigError(f'range_sigma must be a non-negative number, got {range_sigma!r}')
    if range_sigma > 0 and rng is None:
        raise ConfigError('range noise needs a random generator (rng)')
    scene = obstacles if isinstance(obstacles, ObstacleScene) else ObstacleScene(obstacles)
    out = p.copy()
    finite = np.isfinite(p[:, 0]) & np.isfinite(p[:, 1]) & np.isfinite(p[:, 2])
    if o.ndim == 2:
        finite &= np.isfinite(o[:, 0]) & np.isfinite(o[:, 1]) & np.isfinite(o[:, 2])
    elif not np.isfinite(o).all():
        finite[:] = False
    idx = np.flatnonzero(finite)
    sub_o = o if o.ndim == 1 else o[idx]
    mask_f, t, d = scene.first_hits(p[idx], sub_o)
    rows = idx[mask_f]
    if len(rows):
        if range_sigma > 0:
            assert rng is not None
            t = np.maximum(t + rng.normal(0.0, range_sigma, len(t)), 0.0)
        start = o if o.ndim == 1 else o[rows]
        out[rows] = start + d * t[:, None]
    mask = np.zeros(len(p), bool)
    mask[rows] = True
    return out, mask
