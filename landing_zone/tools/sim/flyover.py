"""A patch scanned in passing: one straight pass of a moving scanner of any pattern.

The hover scan of :mod:`landing_zone.tools.sim.sensor` is the paper's nodding line scanner on a
hovering vehicle. The scanners a user flies are mostly mounted still and swept along by the
vehicle's motion (what :func:`landing_zone.tools.sim.sensor.path_scan` simulates for whole
flights): a
line scanner at a fixed tilt (pushbroom), a spinning multi-beam, a rosette, an elliptical
(Palmer) scanner. :func:`flyover_scan` scans one patch that way:

* the vehicle flies straight at ``height`` above the nominal ground, heading ``heading``,
  passing the tile centre ``cross`` metres to its side, at the speed that puts the target
  density onto the area of interest (on flat ground; estimated from every 7th pulse);
* only the part of the pass in which a pulse can reach the patch's column is simulated: the
  pattern's footprint (one second of pulses at heading 0, intersected with the column's top and
  bottom planes) gives the along-track window;
* of that window, only pulses that can pass through the column are cast. For the line scanner
  the scan angles through the column are known per line (as in the hover scan); for the other
  patterns the pulses are culled in blocks of 16: a block is dropped when its first pulse points
  farther from the column's bounding sphere than the pattern can turn in 16 pulses (its angular
  speed bound, plus the spread of a multi-beam's beams). What is cast is exactly what the full
  pass would have cast through the column.

Returns are kept as in the hover scan: those whose measured ray segment reaches the column, one
sensor origin per line of ``pulses_per_line`` pulses (the origin wanders by the same Brownian
walk).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass

import numpy as np

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.raycast import RayCaster
from landing_zone.tools.sim.hover import HoverScan
from landing_zone.tools.sim.sensor import (BrownianWalk, Returns, ScanPattern, SensorConfig,
                                           direction_angles, mount_frame, ray_box_interval,
                                           scan_directions)

__all__ = ['Flyover', 'FlyoverPlan', 'FlyoverScan', 'plan_flyover', 'flyover_scan',
           'flyover_window', 'angular_speed']

_BLOCK = 16  # pulses culled together
_REF_SPEED = 5.0  # [m/s] speed of the density estimate
_SPEEDS = (0.3, 60.0)  # [m/s] the speed is clipped to this range


@dataclass(frozen=True)
class Flyover:
    """One pass over a patch.

    Attributes:
        pattern: the scanner's pattern (``line`` uses the sensor's scan lines at ``tilt``).
        height: above the nominal ground [m].
        tilt: the pattern's centre, forward of the nadir [deg].
        cross: the track passes this far to the left of the tile centre [m].
        heading: direction of flight [rad].
    """

    pattern: ScanPattern
    height: float
    tilt: float
    cross: float = 0.0
    heading: float = 0.0

    def validate(self) -> None:
        self.pattern.validate()
        for name, low, high in (('height', 1.0, 200.0), ('tilt', 0.0, 80.0),
                                ('cross', -200.0, 200.0), ('heading', -10.0, 10.0)):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and low <= v <= high):
                raise SimulationError(f'flyover {name} must lie in [{low:g}, {high:g}], '
                                      f'got {v!r}')

    def axes(self) -> tuple[np.ndarray, np.ndarray]:
        """Unit along-track and cross-track (left) vectors."""
        c, s = math.cos(self.heading), math.sin(self.heading)
        return np.array([c, s, 0.0]), np.array([-s, c, 0.0])


@dataclass
class FlyoverScan(HoverScan):
    """A flyover's returns and how it went (``nod_rate`` 0, ``sweeps`` 1)."""

    speed: float = 0.0  # [m/s]


def angular_speed(pattern: ScanPattern) -> tuple[float, float]:
    """(rad/s, rad): a bound on how fast the pattern's pulse direction turns, and how far apart
    pulses fired at the same moment can be (a multi-beam's beams)."""
    if pattern.kind == 'spinning':
        return 2.0 * math.pi * pattern.spin_rate, 0.5 * math.radians(pattern.beam_fov)
    if pattern.kind == 'rosette':
        a = 0.25 * math.radians(pattern.fov)
        return 2.0 * math.pi * a * (pattern.prism_rates[0] + pattern.prism_rates[1]), 0.0
    if pattern.kind == 'elliptical':
        return 2.0 * math.pi * pattern.spin_rate * math.sin(0.5 * math.radians(pattern.fov)), 0.0
    raise SimulationError(f'no angular speed for the {pattern.kind} pattern')


def _pattern_dirs(fly: Flyover, sensor: SensorConfig, times: np.ndarray, index: np.ndarray
                  ) -> np.ndarray:
    """(n, 3) world directions of the pulses fired at ``times`` with numbers ``index``."""
    if fly.pattern.kind == 'line':
        theta = sensor.thetas()[np.mod(index, sensor.pulses_per_line)]
        return scan_directions(theta, math.radians(fly.tilt), fly.heading)
    local = fly.pattern.local_directions(times, index)
    return local @ mount_frame(math.radians(fly.tilt), fly.heading)[0].T


def flyover_window(fly: Flyover, sensor: SensorConfig, box_lo: np.ndarray, box_hi: np.ndarray,
                   ground_z: float = 0.0) -> tuple[float, float]:
    """Along-track positions (relative to abeam of the box's centre) between which the vehicle
    can put a pulse through the box.

    Raises:
        SimulationError: no pulse of the pattern reaches the box from this track.
    """
    n = 20_000
    t = np.linspace(0.0, 1.0, n, endpoint=False)
    idx = np.round(t * sensor.prr).astype(np.int64)
    d = _pattern_dirs(fly, sensor, t, idx)
    along, left = fly.axes()
    centre = 0.5 * (box_lo + box_hi)
    r_xy = 0.5 * float(np.hypot(*(box_hi[:2] - box_lo[:2])))
    down = d[:, 2] < -1e-6
    offs = []
    for z in (box_lo[2], box_hi[2]):
        dist = (ground_z + fly.height - z) / -d[down, 2]
        ok = dist <= sensor.max_range
        a = dist[ok] * (d[down][ok] @ along)
        c = fly.cross + dist[ok] * (d[down][ok] @ left) - centre @ left
        near = np.abs(c) <= r_xy + 0.5
        offs.append(a[near])
    offs = np.concatenate(offs)
    if not len(offs):
        raise SimulationError(f'the {fly.pattern.kind} scanner {fly.height:g} m up, tilted '
                              f'{fly.tilt:g} degrees, puts no pulse through the patch from '
                              f'{fly.cross:g} m to its side')
    c_along = float(centre @ along)
    margin = r_xy + 0.3
    return c_along - float(offs.max()) - margin, c_along - float(offs.min()) + margin


def _culled(fly: Flyover, sensor: SensorConfig, start: np.ndarray, speed: float,
            n_pulses: int, box_lo: np.ndarray, box_hi: np.ndarray, slack: float
            ) -> np.ndarray:
    """Pulse numbers in [0, n_pulses) of the blocks that can reach the box's bounding sphere."""
    along, _ = fly.axes()
    if fly.pattern.kind == 'line':
        # Per line, the scan angles that can reach the box from anywhere along the window: one
        # contiguous index range (the box is convex and seen from above).
        ppl = sensor.pulses_per_line
        n_lines = -(-n_pulses // ppl)
        corners = np.array([[x, y, z] for x in (box_lo[0], box_hi[0])
                            for y in (box_lo[1], box_hi[1]) for z in (box_lo[2], box_hi[2])])
        res = math.radians(sensor.angular_resolution)
        th0 = -0.5 * math.radians(sensor.fov_horizontal)
        lo_i, hi_i = ppl, -1
        for f in np.linspace(0.0, 1.0, 9):
            origin = start + along * speed * f * n_pulses / sensor.prr
            theta, _ = direction_angles(corners - origin, fly.heading)
            lo_i = min(lo_i, int(math.floor((theta.min() - th0) / res)) - 2)
            hi_i = max(hi_i, int(math.ceil((theta.max() - th0) / res)) + 2)
        lo_i, hi_i = max(lo_i, 0), min(hi_i, ppl - 1)
        if hi_i < lo_i:
            return np.zeros(0, np.int64)
        idx = (np.arange(n_lines)[:, None] * ppl + np.arange(lo_i, hi_i + 1)[None, :]).ravel()
        return idx[idx < n_pulses]
    omega, spread = angular_speed(fly.pattern)
    # A multi-beam's consecutive pulses belong to different beams: its blocks are 16
    # consecutive pulses of one beam (then the beams' spread does not widen the test).
    stride = fly.pattern.beams if fly.pattern.kind == 'spinning' else 1
    if stride > 1:
        spread = 0.0
    span = _BLOCK * stride
    first = (np.arange(0, n_pulses, span, dtype=np.int64)[:, None]
             + np.arange(stride)[None, :]).ravel()
    t = first / sensor.prr
    d = _pattern_dirs(fly, sensor, t, first)
    origin = start + (speed * t)[:, None] * along
    centre = 0.5 * (box_lo + box_hi)
    radius = 0.5 * float(np.linalg.norm(box_hi - box_lo)) + slack + speed * span / sensor.prr
    to = centre - origin
    dist = np.linalg.norm(to, axis=1)
    cos_a = np.einsum('ij,ij->i', d, to) / dist
    angle = np.arccos(np.clip(cos_a, -1.0, 1.0))
    reach = np.arcsin(np.clip(radius / dist, 0.0, 1.0)) + omega * span / sensor.prr + spread
    keep = first[angle <= reach + math.radians(0.5)]
    idx = (keep[:, None] + stride * np.arange(_BLOCK)[None, :]).ravel()
    return np.sort(idx[idx < n_pulses])


def _plane_count(fly: Flyover, sensor: SensorConfig, start: np.ndarray, speed: float,
                 n_pulses: int, aoi_lo: np.ndarray, aoi_hi: np.ndarray, ground_z: float,
                 box_lo: np.ndarray, box_hi: np.ndarray, stride: int = 7) -> float:
    """Expected returns in the area of interest on the plane z = ground_z (every ``stride``-th
    pulse of the culled ones, scaled back; 7 shares no factor with a multi-beam's beams)."""
    along, _ = fly.axes()
    idx = _culled(fly, sensor, start, speed, n_pulses, box_lo, box_hi, 0.0)[::stride]
    t = idx / sensor.prr
    d = _pattern_dirs(fly, sensor, t, idx)
    o = start + (speed * t)[:, None] * along
    with np.errstate(divide='ignore', invalid='ignore'):
        s = (ground_z - o[:, 2]) / d[:, 2]
    p = o[:, :2] + s[:, None] * d[:, :2]
    in_aoi = np.all((p >= aoi_lo) & (p < aoi_hi), axis=1)
    inside = (d[:, 2] < 0) & (s <= sensor.max_range) & in_aoi
    return float(np.count_nonzero(inside) * stride)


@dataclass(frozen=True)
class FlyoverPlan:
    """The part of the pass that is simulated, fixed before the world is built.

    Attributes:
        start: (3,) nominal sensor position at the first pulse [m].
        speed: [m/s].
        n_pulses: pulses of the window.
        wander: per-axis bound of the origin's random walk over the window [m].
    """

    start: np.ndarray
    speed: float
    n_pulses: int
    wander: float

    def sources(self, fly: Flyover, sensor: SensorConfig) -> np.ndarray:
        """(16, 3) corners of the wander boxes at both ends of the window (every sensor
        origin of the pass lies in their convex hull)."""
        along, _ = fly.axes()
        end = self.start + along * self.speed * self.n_pulses / sensor.prr
        box = self.wander * np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1)
                                      for z in (-1, 1)])
        return np.concatenate([self.start + box, end + box])


def plan_flyover(sensor: SensorConfig, fly: Flyover, aoi_lo: np.ndarray, aoi_hi: np.ndarray,
                 box_lo: np.ndarray, box_hi: np.ndarray, ground_z: float = 0.0,
                 max_pulses: int = 50_000_000) -> FlyoverPlan:
    """Where the pass starts, how fast it flies and how long it lasts (no world needed).

    Raises:
        SimulationError: the pass cannot see the patch, or would take more than
            ``max_pulses`` (a configuration no scanner flies).
    """
    sensor.validate()
    fly.validate()
    aoi_lo, aoi_hi = np.asarray(aoi_lo, float), np.asarray(aoi_hi, float)
    box_lo, box_hi = np.asarray(box_lo, float), np.asarray(box_hi, float)
    along, left = fly.axes()
    s0, s1 = flyover_window(fly, sensor, box_lo, box_hi, ground_z)
    start = np.array([0.0, 0.0, ground_z + fly.height]) + fly.cross * left + s0 * along
    area = float(np.prod(aoi_hi - aoi_lo))
    # Returns on flat ground are inversely proportional to the speed: one estimate sets it.
    n_ref = int(math.ceil((s1 - s0) / _REF_SPEED * sensor.prr))
    expected = _plane_count(fly, sensor, start, _REF_SPEED, n_ref, aoi_lo, aoi_hi, ground_z,
                            box_lo, box_hi)
    if expected <= 0:
        raise SimulationError(f'the {fly.pattern.kind} pass {fly.cross:g} m to the side puts '
                              'no return into the tile')
    speed = float(np.clip(_REF_SPEED * expected / (sensor.target_density * area), *_SPEEDS))
    n_pulses = int(math.ceil((s1 - s0) / speed * sensor.prr))
    if n_pulses > max_pulses:
        raise SimulationError(f'the pass would take {n_pulses:,} pulses (more than '
                              f'{max_pulses:,}): lower the density or raise the pulse rate')
    wander = 5.0 * sensor.wander_sigma * math.sqrt(n_pulses / sensor.prr) + 0.01
    return FlyoverPlan(start, speed, n_pulses, wander)


def flyover_scan(caster: RayCaster, sensor: SensorConfig, fly: Flyover, plan: FlyoverPlan,
                 aoi_lo: np.ndarray, aoi_hi: np.ndarray, box_lo: np.ndarray, box_hi: np.ndarray,
                 rng: np.random.Generator) -> FlyoverScan:
    """Scan a patch from one straight pass (see the module's description).

    Args:
        caster: the world.
        sensor: pulse rate, line length (``pulses_per_line``; scan angles of the line
            pattern), noise, range and ``target_density`` [returns/m^2 over the area of
            interest].
        fly: the pass.
        plan: :func:`plan_flyover` of the same arguments.
        aoi_lo, aoi_hi: (2,) the area of interest (the tile) in x, y [m].
        box_lo, box_hi: (3,) the column: only returns whose ray passes through it are kept.
        rng: randomness of the wander and the range noise.

    Returns:
        The kept returns in time order and the figures (``speed``: the speed flown).
    """
    aoi_lo, aoi_hi = np.asarray(aoi_lo, float), np.asarray(aoi_hi, float)
    box_lo, box_hi = np.asarray(box_lo, float), np.asarray(box_hi, float)
    along, _ = fly.axes()
    area = float(np.prod(aoi_hi - aoi_lo))
    start, speed = plan.start, plan.speed
    idx = _culled(fly, sensor, start, speed, plan.n_pulses, box_lo, box_hi, plan.wander)
    ppl = sensor.pulses_per_line
    line_of = idx // ppl
    lines, line_index = np.unique(line_of, return_inverse=True)
    line_times = lines * ppl / sensor.prr
    walk = BrownianWalk(sensor.wander_sigma, rng, plan.wander)
    origins = start + (speed * line_times)[:, None] * along + walk.at(line_times)
    times = idx / sensor.prr
    dirs = _pattern_dirs(fly, sensor, times, idx)
    org = origins[line_index]
    t_in, t_out = ray_box_interval(org, dirs, box_lo, box_hi)
    sel = np.flatnonzero(t_in <= t_out)
    t_cast = time.perf_counter()
    hits = caster.cast(org[sel], dirs[sel], sensor.max_range)
    cast_seconds = time.perf_counter() - t_cast
    hit = hits.hit
    k = sel[hit]
    t_meas = hits.t[hit] + rng.standard_normal(len(k)) * sensor.range_sigma
    keep = t_in[k] <= t_meas
    k, t_meas, labels = k[keep], t_meas[keep], hits.label[hit][keep]
    pts = org[k] + t_meas[:, None] * dirs[k]
    n_aoi = int(np.count_nonzero(np.all((pts[:, :2] >= aoi_lo) & (pts[:, :2] < aoi_hi), axis=1)))
    returns = Returns(pts, labels, times[k], line_index[k].astype(np.int64), origins,
                      line_times).compact_lines()
    duration = float(np.ptp(returns.times)) if len(returns) else 0.0
    return FlyoverScan(returns, 0.0, 1, duration, int(len(sel)), n_aoi, area, cast_seconds,
                       speed=speed)
