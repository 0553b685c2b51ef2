"""The tiles' results on the map's tile window, kept between passes and shifted as it scrolls.

One table, :data:`FIELDS`, says what a tile holds (name, dtype, value before any judgement); a
pass's :class:`~landing_zone.judging.judgement.Judgement` is stored into the cells of the tiles
it judged, and every other tile keeps what it had.
"""
from __future__ import annotations

import numpy as np

from landing_zone.errors import ConfigError
from landing_zone.judging.judgement import Judgement

__all__ = ['TileState', 'FIELDS']

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
        sx, sy = self.shape
        # overlap in old cell coordinates: [d, d + shape) ∩ [0, shape)
        a = np.maximum(d, 0)
        b = np.minimum(d + np.array([sx, sy]), [sx, sy])
        if np.all(b > a):
            for name in FIELDS:
                getattr(fresh, name)[a[0] - d[0]:b[0] - d[0], a[1] - d[1]:b[1] - d[1]] = \
                    getattr(self, name)[a[0]:b[0], a[1]:b[1]]
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
            if not isinstance(a, np.ndarray) or a.shape != want.shape or a.dtype != want.dtype:
                raise ConfigError(f'tile state {name!r} does not fit {want.shape} {want.dtype}')
            setattr(self, name, a.copy())
