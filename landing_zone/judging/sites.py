"""Landing-site candidates: where a circular footprint fits on tiles judged safe.

A candidate touchdown point sits at a tile centre. The vehicle's footprint is a disc of radius
``SiteConfig.footprint_radius`` around it, and the tiles *under* the footprint are every tile
whose square the open disc overlaps (a tile the disc only touches at an edge is not under it).
The candidate's probability is the least of its tiles':

    P(site safe) = min over tiles under the footprint of p_safe(tile).

It is the most any estimate of P(every one of those tiles is safe) can coherently say (no
event is likelier than one it implies), and it is that probability when the tiles' errors move
together, which they do: neighbouring tiles share returns, padding context, vegetation and
often one obstacle. The product over the tiles (independent tiles) would understate clear
footprints and overstate the evidence; the least P never claims more than a tile shows.

Ties (one tile is often the least under several footprints) go to the footprint whose other
tiles are surer: ``Candidates.p_mean``, their geometric mean. A tile not observed enough to be
judged (p_safe NaN), or off the assessed grid, disqualifies every footprint over it: unknown
ground is never assumed safe.

With the tiles' ground planes (:mod:`landing_zone.judging.ground`) every candidate also gets
the geometry a planner needs, over the tiles under its footprint:

* **slope** [deg]: the steeper of the plane fitted through the tiles' ground heights (their
  planes' heights at the tile centres, least squares) and the steepest tile's own plane, so
  neither a uniform incline nor one steep tile inside a level footprint passes;
* **step** [m]: the largest jump between the ground planes of two neighbouring tiles under it,
  at the middle of their shared edge (a kerb, a terrace, a ditch's edge);
* **clearance** [m]: the least free height above the ground over the footprint, within the
  map (:mod:`~landing_zone.judging.ground`);
* the **normal** of the footprint's plane (the orientation of the published pose).

A candidate is left out, with every reason that applies (:data:`REASONS`): ``obstacle`` (P(all
tiles safe) below ``min_p_safe``), ``slope`` (above ``max_slope_deg``), ``step`` (above
``max_step``), ``clearance`` (structure seen lower than ``min_clearance`` over it),
``unknown`` (a tile under it unjudged, without a ground plane, outside the grid, or the map not
reaching ``min_clearance`` above its ground). Only candidates without any reason are listed.

The listed candidates are ranked by their probability (ties: ``p_mean``, then confidence) and
thinned by greedy non-maximum suppression, so the top K are distinct places (centres at least
``min_separation`` apart, by default one footprint diameter, so their footprints do not
overlap) rather than K neighbours of one spot.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import ndimage

from landing_zone.config import SiteConfig
from landing_zone.errors import ConfigError

__all__ = ['LandingSite', 'GroundGrids', 'Candidates', 'REASONS', 'footprint_mask',
           'site_probabilities', 'site_geometry', 'evaluate_candidates', 'find_sites',
           'normal_quaternion']

# Why a candidate is left out, in this order; bit k of Candidates.reasons is REASONS[k].
REASONS = ('obstacle', 'slope', 'step', 'clearance', 'unknown')
OBSTACLE, SLOPE, STEP, CLEARANCE, UNKNOWN = (1 << k for k in range(len(REASONS)))


def reason_names(code: int) -> list[str]:
    """The reasons set in a :attr:`Candidates.reasons` code, in :data:`REASONS` order."""
    return [name for k, name in enumerate(REASONS) if int(code) >> k & 1]


def _num(v: float, digits: int = 4) -> float | None:
    return None if not math.isfinite(v) else round(float(v), digits)


@dataclass(frozen=True)
class LandingSite:
    """One candidate touchdown point.

    Attributes:
        x: centre x in the fixed frame [m] (a tile centre).
        y: centre y [m].
        z: ground height under the centre [m] (the centre tile's ground estimate; NaN if none).
        p_safe: P(every tile under the footprint is safe): the least tile probability under it.
        confidence: the lowest confidence of the tiles under the footprint, in [0, 1].
        index: the global tile index (kx, ky) of the centre tile.
        slope_deg: slope of the ground under the footprint [deg] (NaN: no ground planes).
        step: largest step between neighbouring tiles' ground under the footprint [m].
        clearance: least free height above the ground over the footprint, within the map [m].
        normal: unit normal (x, y, z) of the footprint's ground plane.
    """

    x: float
    y: float
    z: float
    p_safe: float
    confidence: float
    index: tuple[int, int]
    slope_deg: float = math.nan
    step: float = math.nan
    clearance: float = math.nan
    normal: tuple[float, float, float] = (0.0, 0.0, 1.0)

    def to_dict(self) -> dict[str, Any]:
        """The report's form (docs/INTERFACES.md §3), plus z, confidence, step, clearance and
        the ground normal."""
        return {'x': self.x, 'y': self.y, 'z': _num(self.z), 'p_safe': self.p_safe,
                'confidence': self.confidence, 'slope_deg': _num(self.slope_deg, 3),
                'step': _num(self.step), 'clearance': _num(self.clearance, 3),
                'normal': [round(float(c), 6) for c in self.normal]}


@dataclass
class GroundGrids:
    """The tiles' ground planes on the (X, Y) grid (NaN where a tile has none).

    Attributes:
        plane_z: ground height of each tile's plane at its centre [m].
        grad: (X, Y, 2) the planes' gradients (dz/dx, dz/dy).
        clearance: each tile's free height above its ground, within the map [m].
        overhead: height of the lowest structure seen above each tile's ground [m] (inf:
            none); None: not known apart from ``clearance``.
    """

    plane_z: np.ndarray
    grad: np.ndarray
    clearance: np.ndarray
    overhead: np.ndarray | None = None


@dataclass
class Candidates:
    """Every footprint centred on a tile of the grid: its figures and why it is left out.

    All arrays are (X, Y) on the grid of tile ``origin + (i, j)`` (``normal`` (X, Y, 3)).

    Attributes:
        origin: global tile index of cell (0, 0).
        tile_size: tile edge [m].
        p_safe: P(all tiles under the footprint safe), the least tile probability under it;
            NaN where any is unknown.
        p_mean: the geometric mean of the tile probabilities under it (the ranking's
            tie-break); NaN likewise.
        confidence: the lowest confidence under the footprint; NaN likewise.
        slope_deg, step, clearance, normal: the footprint's geometry (module docstring) over
            the tiles under it that have a ground plane; NaN where none has.
        reasons: uint8 bits of :data:`REASONS`; 0: the candidate may be listed.
    """

    origin: tuple[int, int]
    tile_size: float
    p_safe: np.ndarray
    p_mean: np.ndarray
    confidence: np.ndarray
    slope_deg: np.ndarray
    step: np.ndarray
    clearance: np.ndarray
    normal: np.ndarray
    reasons: np.ndarray

    def center(self, i: int, j: int) -> tuple[float, float]:
        """Centre (x, y) [m] of candidate cell (i, j)."""
        return ((self.origin[0] + i + 0.5) * self.tile_size,
                (self.origin[1] + j + 0.5) * self.tile_size)

    def rejected(self, include_unknown_only: bool = True) -> list[dict[str, Any]]:
        """The candidates left out, x-major: ``x``, ``y``, ``reasons`` (names), ``p_safe``,
        ``slope_deg``, ``step``, ``clearance`` (None where unknown).

        Args:
            include_unknown_only: also list those whose only reason is ``unknown``.
        """
        out = []
        for i, j in zip(*np.nonzero(self.reasons)):
            code = int(self.reasons[i, j])
            if code == UNKNOWN and not include_unknown_only:
                continue
            x, y = self.center(int(i), int(j))
            out.append({'x': x, 'y': y, 'reasons': reason_names(code),
                        'p_safe': _num(self.p_safe[i, j], 6),
                        'slope_deg': _num(self.slope_deg[i, j], 3),
                        'step': _num(self.step[i, j]),
                        'clearance': _num(self.clearance[i, j], 3)})
        return out


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
                       tile_size: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """P(footprint safe), its tie-break and its confidence for a footprint centred on every tile.

    Args:
        p_safe: (X, Y) tile probabilities, NaN where unknown.
        confidence: (X, Y) tile confidences in [0, 1].
        radius: footprint radius [m].
        tile_size: tile edge [m].

    Returns:
        ``(p, p_mean, c)``, (X, Y) float64 each: the least, the geometric mean and the lowest
        confidence under each footprint; NaN where a tile under it is unknown or off the grid.
    """
    p = np.asarray(p_safe, np.float64)
    conf = np.asarray(confidence, np.float64)
    if p.ndim != 2 or p.shape != conf.shape:
        raise ConfigError(f'p_safe and confidence must be 2-D grids of one shape, got '
                          f'{p.shape} and {conf.shape}')
    if p.size == 0:
        return (np.full(p.shape, np.nan),) * 3
    mask = footprint_mask(radius, tile_size)
    unknown = ~np.isfinite(p)
    known = np.clip(np.where(unknown, 1.0, p), 0.0, 1.0)
    p_min = _footprint_min(known, radius, tile_size)
    # a mean of logs does not underflow on a 100-tile footprint; log(0) = -inf stays -inf
    with np.errstate(divide='ignore'):
        log_sum = ndimage.correlate(np.log(known), mask.astype(np.float64), mode='constant',
                                    cval=0.0)
    n_unknown = ndimage.correlate(unknown.astype(np.int32), mask.astype(np.int32),
                                  mode='constant', cval=1)  # off the grid counts as unknown
    conf_min = ndimage.grey_erosion(np.where(unknown, 0.0, conf), footprint=mask,
                                    mode='constant', cval=0.0)
    bad = n_unknown > 0
    return (np.where(bad, np.nan, p_min), np.where(bad, np.nan, np.exp(log_sum / mask.sum())),
            np.where(bad, np.nan, conf_min))


def _shifted(a: np.ndarray, m: int, fill: float = np.nan) -> Any:
    """``view(di, dj)``: ``a`` moved so cell (i, j) reads ``a[i + di, j + dj]`` (fill outside)."""
    pad = [(m, m), (m, m)] + [(0, 0)] * (a.ndim - 2)
    big = np.pad(np.asarray(a, np.float64), pad, constant_values=fill)
    nx, ny = a.shape[:2]

    def view(di: int, dj: int) -> np.ndarray:
        out: np.ndarray = big[m + di:m + di + nx, m + dj:m + dj + ny]
        return out
    return view


def site_geometry(ground: GroundGrids, radius: float, tile_size: float
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Slope, step, clearance and normal of a footprint centred on every tile of a grid.

    Over the tiles under each footprint that have a ground plane (see the module docstring).

    Args:
        ground: the tiles' ground planes on the grid.
        radius: footprint radius [m].
        tile_size: tile edge [m].

    Returns:
        ``(slope_deg, step, clearance, normal, complete)``: (X, Y) float64 each (normal
        (X, Y, 3)), NaN where no tile under the footprint has a plane; ``complete`` (X, Y)
        bool, every tile under the footprint lies in the grid and has a plane.
    """
    z = np.asarray(ground.plane_z, np.float64)
    grad = np.asarray(ground.grad, np.float64)
    mask = footprint_mask(radius, tile_size)
    m = mask.shape[0] // 2
    offs = [(int(a) - m, int(b) - m) for a, b in np.argwhere(mask)]
    ts = float(tile_size)
    zv = _shifted(z, m)
    gv = _shifted(np.where(np.isfinite(z)[..., None], grad, np.nan), m)
    cv = _shifted(np.asarray(ground.clearance, np.float64), m)
    shape = z.shape
    # least squares over the tile centres: sums of the normal equations, per candidate
    s1, su, sv, suu, suv, svv, sz, suz, svz = (np.zeros(shape) for _ in range(9))
    tile_slope = np.full(shape, np.nan)
    clearance = np.full(shape, np.nan)
    complete = np.ones(shape, bool)
    with np.errstate(invalid='ignore'):
        for di, dj in offs:
            zz = zv(di, dj)
            w = np.isfinite(zz)
            complete &= w
            u, v = di * ts, dj * ts
            z0 = np.where(w, zz, 0.0)
            s1 += w
            su += w * u
            sv += w * v
            suu += w * u * u
            suv += w * u * v
            svv += w * v * v
            sz += z0
            suz += u * z0
            svz += v * z0
            g = gv(di, dj)
            tile_slope = np.fmax(tile_slope, np.hypot(g[..., 0], g[..., 1]))
            clearance = np.fmin(clearance, cv(di, dj))
        n = np.maximum(s1, 1.0)
        mu, mv, mz = su / n, sv / n, sz / n
        cuu, cuv, cvv = suu - n * mu * mu, suv - n * mu * mv, svv - n * mv * mv
        cuz, cvz = suz - n * mu * mz, svz - n * mv * mz
        det = cuu * cvv - cuv * cuv
        fit = (s1 >= 3) & (det > 1e-9 * ts ** 4)
        safe_det = np.where(fit, det, 1.0)
        gx = np.where(fit, (cuz * cvv - cvz * cuv) / safe_det, np.nan)
        gy = np.where(fit, (cvz * cuu - cuz * cuv) / safe_det, np.nan)
        # too few tiles for a plane across them (a footprint of one tile): the centre tile's
        centre = gv(0, 0)
        gx = np.where(fit, gx, centre[..., 0])
        gy = np.where(fit, gy, centre[..., 1])
        slope_t = np.fmax(np.hypot(gx, gy), tile_slope)
        slope = np.degrees(np.arctan(slope_t))
        # steps at the shared edges of neighbouring tiles under the footprint
        gxf, gyf = grad[..., 0], grad[..., 1]
        step_x = np.full(shape, np.nan)
        step_y = np.full(shape, np.nan)
        step_x[:-1] = np.abs((z[:-1] + gxf[:-1] * ts / 2) - (z[1:] - gxf[1:] * ts / 2))
        step_y[:, :-1] = np.abs((z[:, :-1] + gyf[:, :-1] * ts / 2)
                                - (z[:, 1:] - gyf[:, 1:] * ts / 2))
        sxv, syv = _shifted(step_x, m), _shifted(step_y, m)
        inside = set(offs)
        step = np.full(shape, np.nan)
        for di, dj in offs:
            if (di + 1, dj) in inside:
                step = np.fmax(step, sxv(di, dj))
            if (di, dj + 1) in inside:
                step = np.fmax(step, syv(di, dj))
        if len(offs) == 1:
            # one tile under the footprint: no pair of tiles, no step between them
            step = np.where(np.isfinite(z), 0.0, np.nan)
        normal = np.stack([-gx, -gy, np.ones(shape)], axis=-1)
        normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    return slope, step, clearance, normal, complete


def _footprint_min(values: np.ndarray, radius: float, tile_size: float) -> np.ndarray:
    """The least of ``values`` under a footprint centred on every tile (NaN ignored)."""
    mask = footprint_mask(radius, tile_size)
    m = mask.shape[0] // 2
    view = _shifted(np.asarray(values, np.float64), m)
    out = np.full(np.shape(values), np.nan)
    for a, b in np.argwhere(mask):
        out = np.fmin(out, view(int(a) - m, int(b) - m))
    return out


def evaluate_candidates(p_safe: np.ndarray, confidence: np.ndarray, origin: tuple[int, int],
                        config: SiteConfig | None = None, tile_size: float = 1.0,
                        ground: GroundGrids | None = None) -> Candidates:
    """Every tile-centred footprint of a grid: P(all safe), geometry, reasons to leave it out.

    Args:
        p_safe: (X, Y) tile probabilities, NaN where unknown.
        confidence: (X, Y) tile confidences in [0, 1].
        origin: global tile index (kx, ky) of cell (0, 0).
        config: footprint and limits; default SiteConfig().
        tile_size: tile edge [m].
        ground: the tiles' ground planes; None: no geometry (only ``obstacle`` and
            ``unknown`` can be reasons, and slope, step and clearance are NaN).
    """
    cfg = config if config is not None else SiteConfig()
    cfg.validate()
    p, p_mean, c = site_probabilities(p_safe, confidence, cfg.footprint_radius, tile_size)
    shape = p.shape
    # the known tiles alone may already make the footprint unsafe
    pk = np.asarray(p_safe, np.float64)
    reasons = np.zeros(shape, np.uint8)
    with np.errstate(invalid='ignore'):
        reasons[_footprint_min(pk, cfg.footprint_radius, tile_size) < cfg.min_p_safe] |= OBSTACLE
    reasons[~np.isfinite(p)] |= UNKNOWN
    if ground is not None and pk.size:
        slope, step, clearance, normal, complete = site_geometry(
            ground, cfg.footprint_radius, tile_size)
        with np.errstate(invalid='ignore'):
            reasons[slope > cfg.max_slope_deg] |= SLOPE
            reasons[step > cfg.max_step] |= STEP
            low = clearance < cfg.min_clearance
            if ground.overhead is not None:
                # structure seen lower than the limit: clearance; only the map's top lower
                # than it: the map cannot tell, unknown
                seen = _footprint_min(ground.overhead, cfg.footprint_radius,
                                      tile_size) < cfg.min_clearance
                reasons[low & seen] |= CLEARANCE
                reasons[low & ~seen] |= UNKNOWN
            else:
                reasons[low] |= CLEARANCE
        reasons[~complete] |= UNKNOWN
    else:
        slope = step = clearance = np.full(shape, np.nan)
        normal = np.zeros(shape + (3,))
        normal[..., 2] = 1.0
    return Candidates(origin=(int(origin[0]), int(origin[1])), tile_size=float(tile_size),
                      p_safe=p, p_mean=p_mean, confidence=c, slope_deg=slope, step=step,
                      clearance=clearance, normal=normal, reasons=reasons)


def normal_quaternion(normal: tuple[float, float, float] | np.ndarray
                      ) -> tuple[float, float, float, float]:
    """(x, y, z, w) of the shortest rotation taking +z onto the unit ``normal`` (no yaw)."""
    nx, ny, nz = (float(v) for v in normal)
    # half-way vector construction: q = (z x n, 1 + z . n), normalised
    q = np.array([-ny, nx, 0.0, 1.0 + nz])
    norm = float(np.linalg.norm(q))
    if not math.isfinite(norm) or norm < 1e-12:
        return (0.0, 0.0, 0.0, 1.0)
    x, y, z, w = (float(v) for v in q / norm)
    return (x, y, z, w)


def find_sites(p_safe: np.ndarray, confidence: np.ndarray, origin: tuple[int, int],
               config: SiteConfig | None = None, tile_size: float = 1.0,
               ground_z: np.ndarray | None = None,
               min_separation: float | None = None,
               ground: GroundGrids | None = None,
               candidates: Candidates | None = None) -> list[LandingSite]:
    """The top-K landing sites of a tile grid, best first, non-maximum suppressed.

    Args:
        p_safe: (X, Y) tile probabilities, NaN where unknown; cell (i, j) is global tile
            ``origin + (i, j)``.
        confidence: (X, Y) tile confidences in [0, 1].
        origin: global tile index (kx, ky) of cell (0, 0).
        config: footprint radius, K, the minimum probability and the limits; default
            SiteConfig().
        tile_size: tile edge [m].
        ground_z: (X, Y) ground heights [m] for the sites' z; NaN where unknown (default
            the ground planes' heights when ``ground`` is given).
        min_separation: smallest distance between two reported centres [m]; default the
            footprint's diameter.
        ground: the tiles' ground planes: the limits on slope, step and clearance apply.
        candidates: :func:`evaluate_candidates`' result for these arguments, if the caller
            has it already.

    Returns:
        At most ``config.top_k`` sites without a reason to leave them out (``p_safe >=
        config.min_p_safe``, and within the limits when ``ground`` is given), best first
        (ties: higher ``p_mean``, higher confidence, then lower x, then lower y).
    """
    cfg = config if config is not None else SiteConfig()
    cfg.validate()
    sep = 2.0 * cfg.footprint_radius if min_separation is None else float(min_separation)
    if not (math.isfinite(sep) and sep >= 0):
        raise ConfigError(f'min_separation must be a non-negative number, got {min_separation!r}')
    if cfg.top_k == 0:
        return []
    cand = candidates if candidates is not None else evaluate_candidates(
        p_safe, confidence, origin, cfg, tile_size, ground)
    p, c = cand.p_safe, cand.confidence
    ok = (cand.reasons == 0) & np.isfinite(p) & (p >= cfg.min_p_safe)
    ii, jj = np.nonzero(ok)
    if ii.size == 0:
        return []
    if ground_z is None and ground is not None:
        ground_z = ground.plane_z
    ps, pm, cs = p[ii, jj], cand.p_mean[ii, jj], c[ii, jj]
    # np.nonzero is x-then-y ordered, and lexsort is stable: ties fall back to that order
    order = np.lexsort((-cs, -pm, -ps))
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
        nrm = cand.normal[i, j]
        sites.append(LandingSite(x=float(centers[n, 0]), y=float(centers[n, 1]), z=z,
                                 p_safe=float(p[i, j]), confidence=float(c[i, j]),
                                 index=(int(kx[n]), int(ky[n])),
                                 slope_deg=float(cand.slope_deg[i, j]),
                                 step=float(cand.step[i, j]),
                                 clearance=float(cand.clearance[i, j]),
                                 normal=(float(nrm[0]), float(nrm[1]), float(nrm[2]))))
    return sites
