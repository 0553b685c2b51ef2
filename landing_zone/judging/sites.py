"""Landing-site candidates: where a circular footprint fits on tiles judged safe.

A candidate touchdown point sits at a tile centre. The vehicle's footprint is a disc of radius
``SiteConfig.footprint_radius`` around it, and the tiles *under* the footprint are every tile
whose square the open disc overlaps (a tile the disc only touches at an edge is not under it).
The candidate's probability is

    P(site safe) = prod over tiles under the footprint of p_safe(tile),

the probability that every one of those tiles is safe **assuming the tiles' judgements are
independent**. They are not quite (neighbouring tiles share returns, padding context and often
the same obstacle), so the product is a conservative figure when errors are positively
correlated across tiles and should be read as a ranking score, not a calibrated probability.
A tile not observed enough to be judged (p_safe NaN), or outside the assessed grid, disqualifies
every footprint that covers it: unknown ground is never assumed safe.

The candidates are ranked by that probability and thinned by greedy non-maximum suppression, so
the top K are distinct places (centres at least ``min_separation`` apart, by default one
footprint diameter, so their footprints do not overlap) rather than K neighbours of one spot.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from landing_zone.config import SiteConfig
from landing_zone.errors import ConfigError

__all__ = ['LandingSite', 'footprint_mask', 'site_probabilities', 'find_sites']


@dataclass(frozen=True)
class LandingSite:
    """One candidate touchdown point.

    Attributes:
        x: centre x in the fixed frame [m] (a tile centre).
        y: centre y [m].
        z: ground height under the centre [m] (the centre tile's ground estimate; NaN if none).
        p_safe: P(every tile under the footprint is safe), assuming independent tiles.
        confidence: the lowest confidence of the tiles under the footprint, in [0, 1].
        index: the global tile index (kx, ky) of the centre tile.
    """

    x: float
    y: float
    z: float
    p_safe: float
    confidence: float
    index: tuple[int, int]

    def to_dict(self) -> dict[str, float | None]:
        """The report's form (docs/INTERFACES.md §3), plus z and confidence."""
        return {'x': self.x, 'y': self.y, 'z': None if math.isnan(self.z) else self.z,
                'p_safe': self.p_safe, 'confidence': self.confidence}


def footprint_mask(radius: float, tile_size: float) -> np.ndarray:
    """Tiles under a disc of ``radius`` centred on a tile centre, as a (2m+1, 2m+1) bool mask.

    Tile offset (i, j) (in tiles, from the centre tile) is under the disc when the disc's
    interior overlaps the tile's square: the square's nearest point to the centre lies at a
    distance strictly below ``radius``.

    Raises:
        ConfigError: radius or tile size not positive and finite.
    """
    if not (math.isfinite(radius) and radius > 0):
        raise ConfigError(f'footprint radius must be a positive number, got {radius!r}')
    if not (math.isfinite(tile_size) and tile_size > 0):
        raise ConfigError(f'tile size must be a positive number, got {tile_size!r}')
    m = int(math.ceil(radius / tile_size + 0.5))
    off = np.arange(-m, m + 1, dtype=np.float64)
    # distance from the centre to the nearest point of the tile at offset k, per axis
    near = np.maximum(np.abs(off) * tile_size - tile_size / 2, 0.0)
    dist2 = near[:, None] ** 2 + near[None, :] ** 2
    mask = dist2 < radius * radius
    # trim empty border rows so the mask stays centred and small
    keep = np.flatnonzero(mask.any(axis=1))
    r = int(max(abs(keep[0] - m), abs(keep[-1] - m)))
    out: np.ndarray = mask[m - r:m + r + 1, m - r:m + r + 1]
    return out


def site_probabilities(p_safe: np.ndarray, confidence: np.ndarray, radius: float,
                       tile_size: float) -> tuple[np.ndarray, np.ndarray]:
    """P(footprint safe) and its confidence for a footprint centred on every tile of a grid.

    Args:
        p_safe: (X, Y) tile probabilities, NaN where unknown.
        confidence: (X, Y) tile confidences in [0, 1].
        radius: footprint radius [m].
        tile_size: tile edge [m].

    Returns:
        ``(p, c)``, both (X, Y) float64: the product of the p_safe under each footprint and the
        lowest confidence under it; NaN where any tile under the footprint is unknown or falls
        outside the grid.
    """
    p = np.asarray(p_safe, np.float64)
    conf = np.asarray(confidence, np.float64)
    if p.ndim != 2 or p.shape != conf.shape:
        raise ConfigError(f'p_safe and confidence must be 2-D grids of one shape, got '
                          f'{p.shape} and {conf.shape}')
    mask = footprint_mask(radius, tile_size)
    if p.size == 0:
        return np.full(p.shape, np.nan), np.full(p.shape, np.nan)
    unknown = ~np.isfinite(p)
    # Sum of logs instead of a product so a 100-tile footprint does not underflow; log(0) is
    # -inf and stays -inf through the sum, which is the right answer (a surely unsafe tile).
    with np.errstate(divide='ignore'):
        logp = np.log(np.clip(np.where(unknown, 1.0, p), 0.0, 1.0))
    log_sum = ndimage.correlate(logp, mask.astype(np.float64), mode='constant', cval=0.0)
    # outside the grid counts as unknown
    n_unknown = ndimage.correlate(unknown.astype(np.int32), mask.astype(np.int32),
                                  mode='constant', cval=1)
    conf_min = ndimage.grey_erosion(np.where(unknown, 0.0, conf), footprint=mask,
                                    mode='constant', cval=0.0)
    bad = n_unknown > 0
    out_p = np.where(bad, np.nan, np.exp(log_sum))
    out_c = np.where(bad, np.nan, conf_min)
    return out_p, out_c


def find_sites(p_safe: np.ndarray, confidence: np.ndarray, origin: tuple[int, int],
               config: SiteConfig | None = None, tile_size: float = 1.0,
               ground_z: np.ndarray | None = None,
               min_separation: float | None = None) -> list[LandingSite]:
    """The top-K landing sites of a tile grid, best first, non-maximum suppressed.

    Args:
        p_safe: (X, Y) tile probabilities, NaN where unknown; cell (i, j) is global tile
            ``origin + (i, j)``.
        confidence: (X, Y) tile confidences in [0, 1].
        origin: global tile index (kx, ky) of cell (0, 0).
        config: footprint radius, K and the minimum probability; default SiteConfig().
        tile_size: tile edge [m].
        ground_z: (X, Y) ground heights [m] for the sites' z; NaN where unknown.
        min_separation: smallest distance between two reported centres [m]; default the
            footprint's diameter.

    Returns:
        At most ``config.top_k`` sites with ``p_safe >= config.min_p_safe``, best first (ties:
        higher confidence, then lower x, then lower y).
    """
    cfg = config if config is not None else SiteConfig()
    cfg.validate()
    sep = 2.0 * cfg.footprint_radius if min_separation is None else float(min_separation)
    if not (math.isfinite(sep) and sep >= 0):
        raise ConfigError(f'min_separation must be a non-negative number, got {min_separation!r}')
    if cfg.top_k == 0:
        return []
    p, c = site_probabilities(p_safe, confidence, cfg.footprint_radius, tile_size)
    ok = np.isfinite(p) & (p >= cfg.min_p_safe)
    ii, jj = np.nonzero(ok)
    if ii.size == 0:
        return []
    ps, cs = p[ii, jj], c[ii, jj]
    # np.nonzero is x-then-y ordered, and lexsort is stable: ties fall back to that order
    order = np.lexsort((-cs, -ps))
    kx = ii[order] + int(origin[0])
    ky = jj[order] + int(origin[1])
    centers = np.column_stack([(kx + 0.5) * tile_size, (ky + 0.5) * tile_size])
    chosen: list[int] = []
    sep2 = sep * sep
    for n in range(order.size):
        if chosen:
            d = centers[chosen] - centers[n]
            if np.any(np.einsum('ij,ij->i', d, d) < sep2 - 1e-9):
                continue
        chosen.append(n)
        if len(chosen) == cfg.top_k:
            break
    sites = []
    for n in chosen:
        i, j = int(ii[order[n]]), int(jj[order[n]])
        z = float(ground_z[i, j]) if ground_z is not None else math.nan
        sites.append(LandingSite(x=float(centers[n, 0]), y=float(centers[n, 1]), z=z,
                                 p_safe=float(p[i, j]), confidence=float(c[i, j]),
                                 index=(int(kx[n]), int(ky[n]))))
    return sites
