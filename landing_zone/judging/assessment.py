"""What one assessment pass returns: every tile of the map's window and the landing sites.

The :class:`~landing_zone.assessor.Assessor` makes one at every pass; the front ends publish it
(the node's grids and clouds), write it (REPORT.json, :meth:`Assessment.to_report`) or draw it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from landing_zone.judging.guard import REASON_SOLID
from landing_zone.judging.sites import Candidates, LandingSite

__all__ = ['Assessment']


@dataclass
class Assessment:
    """The tiles of the map's window and the landing sites, at one moment.

    The tiles are the map's XY window cut on the global tile lattice, listed x-major (tile
    ``(origin[0] + i, origin[1] + j)`` is entry ``i * shape[1] + j``), so every per-tile array
    reshapes to the grid with :meth:`grid`.

    Attributes:
        frame_id: fixed frame of the coordinates.
        tile_size: tile edge [m].
        origin: global tile index (kx, ky) of grid cell (0, 0).
        shape: tiles of the grid along x and y.
        index: (T, 2) int64 global tile indices.
        centers: (T, 2) float64 tile centres [m].
        ground_z: (T,) float64 estimated ground height [m] (the ground plane's at the tile
            centre, else the tiler's); NaN where none was found.
        p_safe: (T,) float32 P(safe); NaN where the tile is not observed enough to judge.
        confidence: (T,) float32 in [0, 1].
        observed_fraction: (T,) float32 observed share of each tile's cube.
        n_returns: (T,) int64 returns in each tile's column.
        sites: landing-site candidates, best first.
        footprint_radius: radius of the vehicle footprint the sites were found for [m].
        stamp: time [s] of the newest cloud integrated before this assessment, if given.
        reassessed: tiles re-extracted in this pass (the others kept their results).
        seconds: wall time of this pass [s].
        p_net: (T,) float32 the network's own P(safe), before the guard; None: not kept.
        guard: (T,) bool the guard capped the tile's P(safe) (:mod:`landing_zone.judging.guard`).
        guard_hits: (T,) int64 returns on the largest solid cluster reaching into the tile.
        guard_height: (T,) float32 top of that cluster above the ground [m]; NaN: none.
        slope_deg: (T,) float32 slope of the tile's ground plane [deg]; NaN: no plane.
        roughness: (T,) float32 RMS residual of its ground about the plane [m]; NaN: no plane.
        clearance: (T,) float32 free height above its ground within the map [m]; NaN: no plane.
        grad: (T, 2) float64 the ground plane's gradient (dz/dx, dz/dy); NaN: no plane.
        candidates: every tile-centred footprint with its figures and its reasons to be left
            out (:class:`~landing_zone.judging.sites.Candidates`).
        ood: (T,) float32 the tile's feature distance over the OOD threshold (past 1: unlike
            the training data, :mod:`landing_zone.judging.ood`); NaN where not judged or
            without a reference.
        grazing: (T,) bool unknown for too few returns from steep rays (seen only at grazing
            angles, ``tiles.min_ray_depression_deg``); None: not kept.
    """

    frame_id: str
    tile_size: float
    origin: tuple[int, int]
    shape: tuple[int, int]
    index: np.ndarray
    centers: np.ndarray
    ground_z: np.ndarray
    p_safe: np.ndarray
    confidence: np.ndarray
    observed_fraction: np.ndarray
    n_returns: np.ndarray
    sites: list[LandingSite] = field(default_factory=list)
    footprint_radius: float = 0.0
    stamp: float | None = None
    reassessed: int = 0
    seconds: float = 0.0
    p_net: np.ndarray | None = None
    guard: np.ndarray | None = None
    guard_hits: np.ndarray | None = None
    guard_height: np.ndarray | None = None
    slope_deg: np.ndarray | None = None
    roughness: np.ndarray | None = None
    clearance: np.ndarray | None = None
    grad: np.ndarray | None = None
    candidates: Candidates | None = None
    ood: np.ndarray | None = None
    grazing: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.index.shape[0])

    @property
    def known(self) -> np.ndarray:
        """(T,) bool, tiles that were judged (p_safe is a number)."""
        out: np.ndarray = np.isfinite(self.p_safe)
        return out

    def grid(self, values: np.ndarray) -> np.ndarray:
        """A per-tile array as the (X, Y) grid (cell (i, j) is tile ``origin + (i, j)``)."""
        return np.asarray(values).reshape(self.shape)

    def lookup(self, x: float, y: float) -> int | None:
        """Entry of the tile containing world point (x, y), or None outside the grid."""
        i = math.floor(x / self.tile_size) - self.origin[0]
        j = math.floor(y / self.tile_size) - self.origin[1]
        if 0 <= i < self.shape[0] and 0 <= j < self.shape[1]:
            return i * self.shape[1] + j
        return None

    def reasons(self) -> list[str | None]:
        """Per tile, why its P(safe) is lower than the network's (None: it is the network's)."""
        from landing_zone.judging.judgement import REASON_GRAZING
        from landing_zone.judging.ood import REASON_OOD  # the OOD module imports torch

        if self.guard is None or self.guard_hits is None or self.guard_height is None:
            return [None] * len(self)
        n = len(self)
        ood = self.ood if self.ood is not None else np.full(n, np.nan, np.float32)
        p_net = self.p_net if self.p_net is not None else self.p_safe
        grazing = self.grazing if self.grazing is not None else np.zeros(n, np.bool_)
        out: list[str | None] = []
        for g, hits, h, p, q, r, side in zip(self.guard.tolist(), self.guard_hits.tolist(),
                                             self.guard_height.tolist(), self.p_safe.tolist(),
                                             p_net.tolist(), ood.tolist(), grazing.tolist()):
            if side:  # unknown whatever the network and the guard said
                out.append(REASON_GRAZING)
            elif g:
                out.append(f'{REASON_SOLID}: {hits} returns up to {h:.2f} m')
            elif math.isnan(p) and not math.isnan(q):
                # judged by the network, made unknown after it: only the OOD signal does that
                out.append(f'{REASON_OOD}: feature distance {r:.2f} x the threshold')
            else:
                out.append(None)
        return out

    def to_report(self, stats: dict[str, Any] | None = None) -> dict[str, Any]:
        """The REPORT.json document (docs/INTERFACES.md §3).

        Beyond the contract's keys, ``reasons`` lists the tiles whose P(safe) is lower than the
        network's (``x``, ``y``, ``reason``, ``p_net``: the network's own P(safe)), tiles carry
        ``roughness`` and ``clearance`` beside ``slope_deg``, sites their ``step``,
        ``clearance`` and ground ``normal``, and ``rejected_sites`` lists every candidate
        footprint left out with its ``reasons`` (but those whose one reason is ``unknown``).
        The reasons cover the guard's caps and the tiles the OOD signal or a grazing view made
        unknown (``p_safe`` null).

        Args:
            stats: the front end's counters (clouds, points, dropped_points, seconds, ...).
        """
        tiles = []
        nan = np.full(len(self), np.nan)
        slope = (self.slope_deg if self.slope_deg is not None else nan).tolist()
        rough = (self.roughness if self.roughness is not None else nan).tolist()
        clear = (self.clearance if self.clearance is not None else nan).tolist()
        for (x, y), gz, p, c, sl, ro, cl in zip(self.centers.tolist(), self.ground_z.tolist(),
                                                self.p_safe.tolist(),
                                                self.confidence.tolist(), slope, rough, clear):
            tiles.append({'x': x, 'y': y,
                          'ground_z': None if math.isnan(gz) else round(gz, 4),
                          'p_safe': None if math.isnan(p) else round(p, 6),
                          'confidence': round(c, 6),
                          'slope_deg': None if math.isnan(sl) else round(sl, 3),
                          'roughness': None if math.isnan(ro) else round(ro, 4),
                          'clearance': None if math.isnan(cl) else round(cl, 3)})
        # why a tile's P(safe) is below the network's goes beside the tiles, one entry per
        # such tile
        lowered = [{'x': x, 'y': y, 'reason': why,
                    'p_net': None if self.p_net is None else round(float(self.p_net[k]), 6)}
                   for k, ((x, y), why) in enumerate(zip(self.centers.tolist(), self.reasons()))
                   if why is not None]
        rejected = (self.candidates.rejected(include_unknown_only=False)
                    if self.candidates is not None else [])
        return {'frame_id': self.frame_id, 'tile_size': self.tile_size, 'tiles': tiles,
                'landing_sites': [s.to_dict() for s in self.sites],
                'stats': dict(stats or {}), 'reasons': lowered, 'rejected_sites': rejected}
