"""The tiles' results on the map's tile window, kept between passes and shifted as it scrolls.

One table, :data:`FIELDS`, says what a tile holds (name, dtype, value before any judgement); a
pass's :class:`~landing_zone.judging.judgement.Judgement` is stored into the cells of the tiles
it judged, and every other tile keeps what it had.
"""
from __future__ import annotations

import math

import numba as nb
import numpy as np

from landing_zone.errors import ConfigError
from landing_zone.judging.judgement import Judgement

__all__ = ['TileState', 'TileCounts', 'FIELDS']

# name: (dtype, value of a tile never judged)
FIELDS: dict[str, tuple[type, object]] = {
    'p_safe': (np.float32, np.nan),  # the judgement: P(safe), NaN unknown
    'confidence': (np.float32, 0.0),  # how much it rests on observation, in [0, 1]
    'ground_z': (np.float64, np.nan),  # the ground's height at the centre [m]
    'observed_fraction': (np.float32, 0.0),  # share of the cube observed
    'n_returns': (np.int64, 0),  # returns in the tile's column
    'p_net': (np.float32, np.nan),  # the network's P(safe), before the guard
    'guard': (np.bool_, False),  # the guard fired
    'guard_hits': (np.int64, 0),  # returns on the guard's cluster
    'guard_height': (np.float32, np.nan),  # top of the guard's cluster above the ground [m]
    'grad_x': (np.float64, np.nan),  # the ground plane's gradient
    'grad_y': (np.float64, np.nan),
    'roughness': (np.float32, np.nan),  # RMS distance of the ground points from the plane [m]
    'clearance': (np.float32, np.nan),  # free height above the clutter [m]
    'overhead': (np.float32, np.nan),  # height of structure seen overhead [m]
    'ood': (np.float32, np.nan),  # OOD ratio of the tile's features
    'grazing': (np.bool_, False),  # unknown: too few returns from steep rays
}


class TileState:
    """Per-tile results on the map's tile window (one (X, Y) array per field of
    :data:`FIELDS`, as attributes), anchored at the window's global tile ``origin``."""

    p_safe: np.ndarray
    confidence: np.ndarray
    ground_z: np.ndarray
    observed_fraction: np.ndarray
    n_returns: np.ndarray
    p_net: np.ndarray
    guard: np.ndarray
    guard_hits: np.ndarray
    guard_height: np.ndarray
    grad_x: np.ndarray
    grad_y: np.ndarray
    roughness: np.ndarray
    clearance: np.ndarray
    overhead: np.ndarray
    ood: np.ndarray
    grazing: np.ndarray

    def __init__(self, origin: np.ndarray, shape: tuple[int, int]) -> None:
        self.origin = np.asarray(origin, np.int64).copy()
        self.shape = shape
        for name, (dtype, fill) in FIELDS.items():
            setattr(self, name, np.full(shape, fill, dtype))

    def move(self, origin: np.ndarray) -> None:
        """Re-anchor at ``origin``: keep the tiles still inside, forget those that left."""
        origin = np.asarray(origin, np.int64)
        d = origin - self.origin
        if not d.any():
            return
        fresh = TileState(origin, self.shape)
        for name in FIELDS:
            _shift(getattr(self, name), getattr(fresh, name), d)
        self.__dict__.update(fresh.__dict__)

    def cells(self, index: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Cell coordinates of global tile indices and which of them lie in the window."""
        rel = np.asarray(index, np.int64) - self.origin
        inside = np.all((rel >= 0) & (rel < self.shape), axis=1)
        return rel[:, 0], rel[:, 1], inside

    def store(self, found: Judgement, confidence: np.ndarray) -> None:
        """Write one pass's results (``confidence``: (K,) per judged tile) into the cells of
        the tiles it judged that are still in the window."""
        batch, ground, guard = found.batch, found.ground, found.guard
        if batch is None:
            return
        i, j, inside = self.cells(batch.index)
        i, j = i[inside], j[inside]
        self.p_safe[i, j] = found.p_safe[inside]
        self.p_net[i, j] = found.p_net[inside]
        if guard is not None:
            self.guard[i, j] = guard.fired[inside]
            self.guard_hits[i, j] = guard.hits[inside]
            self.guard_height[i, j] = guard.height[inside]
        else:
            self.guard[i, j], self.guard_hits[i, j], self.guard_height[i, j] = False, 0, np.nan
        self.ground_z[i, j] = batch.ground_z[inside]
        if ground is not None:
            # the plane's height at the centre, where the tile has a plane
            has = np.isfinite(ground.plane_z)
            self.ground_z[i, j] = np.where(has, ground.plane_z, batch.ground_z)[inside]
            self.grad_x[i, j] = ground.grad[inside, 0]
            self.grad_y[i, j] = ground.grad[inside, 1]
            self.roughness[i, j] = ground.roughness[inside]
            self.clearance[i, j] = ground.clearance[inside]
            self.overhead[i, j] = ground.overhead[inside]
        self.observed_fraction[i, j] = batch.observed_fraction[inside]
        self.n_returns[i, j] = batch.n_returns[inside]
        self.confidence[i, j] = confidence[inside]
        self.ood[i, j] = found.ood[inside]
        self.grazing[i, j] = found.grazing[inside]

    def export(self) -> dict[str, np.ndarray]:
        """Copies of the origin and every field, keyed ``tiles.NAME``."""
        out = {'tiles.origin': self.origin.copy()}
        for name in FIELDS:
            out[f'tiles.{name}'] = getattr(self, name).copy()
        return out

    def restore(self, state: dict[str, np.ndarray]) -> None:
        """Take the fields of :meth:`export`'s arrays (copied) into this state.

        Raises:
            ConfigError: the arrays do not fit this window (origin, shapes or dtypes).
        """
        origin = state.get('tiles.origin')
        if not isinstance(origin, np.ndarray) or origin.shape != (2,) or \
                not np.array_equal(origin, self.origin):
            raise ConfigError('tile state origin does not match the map window')
        for name in FIELDS:
            a = state.get(f'tiles.{name}')
            want = getattr(self, name)
            if a is None and name == 'grazing':
                continue  # a snapshot older than the field: no tile made unknown by it
            if not isinstance(a, np.ndarray) or a.shape != want.shape or a.dtype != want.dtype:
                raise ConfigError(f'tile state {name!r} does not fit {want.shape} {want.dtype}')
            setattr(self, name, a.copy())


class TileCounts:
    """A count per tile on the map's tile window, added to at every cloud and moved with the
    window as the cloud moves it (unlike :class:`TileState`, which moves at a pass).

    Holds the returns that came from rays at least ``tiles.min_ray_depression_deg`` below the
    horizontal: a tile seen only at grazing angles (a ground vehicle's view) is not judged.
    """

    def __init__(self, origin: np.ndarray, shape: tuple[int, int], tile_size: float) -> None:
        self.origin = np.asarray(origin, np.int64).copy()
        self.shape = shape
        self.tile_size = float(tile_size)
        self.counts = np.zeros(shape, np.int64)

    def move(self, origin: np.ndarray) -> None:
        """Re-anchor at ``origin``: keep the tiles still inside, forget those that left."""
        origin = np.asarray(origin, np.int64)
        d = origin - self.origin
        if d.any():
            fresh = np.zeros(self.shape, np.int64)
            _shift(self.counts, fresh, d)
            self.counts, self.origin = fresh, origin.copy()

    def add_steep(self, pts: np.ndarray, origin: np.ndarray, depression_deg: float) -> None:
        """Count into their tiles the returns of ``pts`` ((N, 3) [m], float32 or float64)
        whose ray from ``origin`` drops at least ``depression_deg`` below the horizontal;
        those outside the window, and rows with NaN or Inf, are not counted."""
        tan2 = math.tan(math.radians(depression_deg)) ** 2
        o = np.asarray(origin, np.float64)
        _count_steep(pts, float(o[0]), float(o[1]), float(o[2]), tan2, 1.0 / self.tile_size,
                     int(self.origin[0]), int(self.origin[1]), self.counts)

    def take(self, index: np.ndarray) -> np.ndarray:
        """(K,) counts of the global tiles ``index`` ((K, 2)); 0 outside the window."""
        rel = np.asarray(index, np.int64).reshape(-1, 2) - self.origin
        inside = np.all((rel >= 0) & (rel < self.shape), axis=1)
        out = np.zeros(len(rel), np.int64)
        out[inside] = self.counts[rel[inside, 0], rel[inside, 1]]
        return out


# one pass over the cloud in compiled code: the same test in numpy takes a dozen passes over
# every return, a tenth of the cloud's integration time
@nb.njit(cache=True, nogil=True)
def _count_steep(pts: np.ndarray, ox: float, oy: float, oz: float, tan2: float, scale: float,
                 oi: int, oj: int, counts: np.ndarray) -> None:  # pragma: no cover (compiled)
    sx, sy = counts.shape
    for k in range(pts.shape[0]):
        dz = oz - pts[k, 2]
        dx = pts[k, 0] - ox
        dy = pts[k, 1] - oy
        # dz^2 >= tan^2(A) (dx^2 + dy^2) with 0 < dz < inf: no trigonometry per return; NaN
        # compares False, an infinite drop is no direction
        if not (0.0 < dz < np.inf and dz * dz >= tan2 * (dx * dx + dy * dy)):
            continue
        i = np.floor(pts[k, 0] * scale) - oi
        j = np.floor(pts[k, 1] * scale) - oj
        if 0 <= i < sx and 0 <= j < sy:
            counts[int(i), int(j)] += 1


def _shift(old: np.ndarray, fresh: np.ndarray, d: np.ndarray) -> None:
    """Copy into ``fresh`` the cells of ``old`` still inside a window moved by ``d`` tiles."""
    sx, sy = old.shape
    # overlap in old cell coordinates: [d, d + shape) ∩ [0, shape)
    a = np.maximum(d, 0)
    b = np.minimum(d + np.array([sx, sy]), [sx, sy])
    if np.all(b > a):
        fresh[a[0] - d[0]:b[0] - d[0], a[1] - d[1]:b[1] - d[1]] = old[a[0]:b[0], a[1]:b[1]]
