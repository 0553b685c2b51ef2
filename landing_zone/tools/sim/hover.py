"""The nodding line scanner hovering over an area of interest, until it holds the target density.

The mount nods back and forth, centred on the area of interest, and scanning goes on until the
returns that fall into the area of interest reach the target density. By default the nod rate is
chosen so that one sweep delivers a quarter of the target (``sweeps_per_target``), so the
coverage of the area is uniform and the last, partial sweep adds at most a quarter. Only rays
that can reach the region of interest (a box) are generated: the angular window of each sweep is
computed from the box, which is what makes a hover scan cheap (a few ten thousand rays instead
of the millions of a full 100 x 100 degree sweep). The scanner's geometry and noise are
:mod:`landing_zone.tools.sim.sensor`'s.
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.raycast import RayCaster
from landing_zone.tools.sim.sensor import BrownianWalk, Returns, SensorConfig, \
    direction_angles, ray_box_interval, scan_directions

__all__ = ['HoverScan', 'HoverGeometry', 'estimate_nod_rate', 'hover_scan']


@dataclass
class HoverScan:
    """A hover scan's returns and how it went."""

    returns: Returns
    nod_rate: float  # [deg/s]
    sweeps: int  # nod sweeps started (the last one usually partial)
    duration: float  # time from the first to the last pulse [s]
    rays: int  # rays cast
    aoi_returns: int  # returns inside the area of interest
    aoi_area: float  # [m^2]
    cast_seconds: float = 0.0  # time spent in Embree

    @property
    def density(self) -> float:
        """Achieved returns per m^2 over the area of interest."""
        return self.aoi_returns / self.aoi_area


def _box_samples(lo: np.ndarray, hi: np.ndarray, per_edge: int = 33) -> np.ndarray:
    """Points on the 12 edges of a box (its angular extent as seen from outside)."""
    corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1])
                        for z in (lo[2], hi[2])])
    s = np.linspace(0.0, 1.0, per_edge)[:, None]
    pts = [corners]
    for a in range(8):
        for b in range(a + 1, 8):
            if np.count_nonzero(corners[a] != corners[b]) == 1:
                pts.append(corners[a] + s * (corners[b] - corners[a]))
    return np.concatenate(pts)


def _nod_angle(t: np.ndarray, phi_lo: float, span: float, omega: float) -> np.ndarray:
    """Triangle wave: up from phi_lo to phi_lo + span, back down, at omega [rad/s]."""
    if span <= 0.0:
        return np.full(np.shape(t), phi_lo)
    u = np.asarray(t) * (omega / span)
    k = np.floor(u)
    frac = u - k
    return phi_lo + span * np.where(np.mod(k, 2.0) == 0.0, frac, 1.0 - frac)


@dataclass
class HoverGeometry:
    sensor: SensorConfig
    position: np.ndarray
    heading: float
    phi_lo: float  # lowest nod angle [rad]
    span: float  # nod range [rad]
    thetas: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))

    @classmethod
    def make(cls, sensor: SensorConfig, position: np.ndarray, target: np.ndarray,
             heading: float) -> 'HoverGeometry':
        _, phi_c = direction_angles(target - position, heading)
        span = math.radians(sensor.fov_vertical)
        return cls(sensor, position, heading, float(phi_c) - 0.5 * span, span, sensor.thetas())

    def window(self, origin: np.ndarray, lo: np.ndarray, hi: np.ndarray, margin: float
               ) -> tuple[float, float, int, int]:
        """Nod range [rad] and pulse index range that can reach the box [lo, hi] (+margin)."""
        pts = _box_samples(lo - margin, hi + margin)
        if np.all((origin > lo - margin) & (origin < hi + margin)):
            raise SimulationError('the sensor is inside the region of interest')
        theta, phi = direction_angles(pts - origin, self.heading)
        res = math.radians(self.sensor.angular_resolution)
        th0 = -0.5 * math.radians(self.sensor.fov_horizontal)
        i_lo = max(int(math.floor((theta.min() - th0) / res)) - 1, 0)
        i_hi = min(int(math.ceil((theta.max() - th0) / res)) + 1, len(self.thetas) - 1)
        return float(phi.min()), float(phi.max()), i_lo, i_hi

    def lines_in_window(self, sweep: int, omega: float, phi_a: float, phi_b: float
                        ) -> np.ndarray:
        """Indices of the lines of ``sweep`` whose nod angle passes through [phi_a, phi_b]."""
        period = self.sensor.line_period
        t_sweep = self.span / omega
        t0 = sweep * t_sweep
        a = min(max(phi_a - self.phi_lo, 0.0), self.span)
        b = min(max(phi_b - self.phi_lo, 0.0), self.span)
        if sweep % 2 == 0:
            ta, tb = t0 + a / omega, t0 + b / omega
        else:
            ta, tb = t0 + (self.span - b) / omega, t0 + (self.span - a) / omega
        first = max(int(math.floor(ta / period)) - 1, int(math.ceil(t0 / period)))
        last = min(int(math.ceil(tb / period)) + 1,
                   int(math.ceil((t0 + t_sweep) / period)) - 1)
        return np.arange(first, last + 1, dtype=np.int64)

    def rays(self, lines: np.ndarray, i_lo: int, i_hi: int, omega: float
             ) -> tuple[np.ndarray, np.ndarray]:
        """Directions (n_lines, n_pulses, 3) and times (n_lines, n_pulses) of the window."""
        idx = np.arange(i_lo, i_hi + 1)
        times = lines[:, None] * self.sensor.line_period + idx[None, :] / self.sensor.prr
        phi = _nod_angle(times, self.phi_lo, self.span, omega)
        return scan_directions(self.thetas[idx][None, :], phi, self.heading), times


def _aoi_count_flat(geom: HoverGeometry, omega: float, aoi_lo: np.ndarray,
                    aoi_hi: np.ndarray, ground_z: float) -> int:
    """Pulses of sweep 0 that land in the area of interest on the plane z = ground_z."""
    lo = np.array([aoi_lo[0], aoi_lo[1], ground_z])
    hi = np.array([aoi_hi[0], aoi_hi[1], ground_z])
    phi_a, phi_b, i_lo, i_hi = geom.window(geom.position, lo, hi, 1e-6)
    lines = geom.lines_in_window(0, omega, phi_a, phi_b)
    d, _ = geom.rays(lines, i_lo, i_hi, omega)
    dz = d[..., 2]
    with np.errstate(divide='ignore', invalid='ignore'):
        t = (ground_z - geom.position[2]) / dz
    p = geom.position[:2] + t[..., None] * d[..., :2]
    inside = (dz < 0) & np.all((p >= aoi_lo) & (p < aoi_hi), axis=-1)
    return int(np.count_nonzero(inside))


def estimate_nod_rate(sensor: SensorConfig, position: np.ndarray, aoi_lo: np.ndarray,
                      aoi_hi: np.ndarray, ground_z: float = 0.0, heading: float = 0.0
                      ) -> float:
    """Nod rate [deg/s] at which one sweep puts 1/sweeps_per_target of the target density
    into the area of interest (on flat ground at ``ground_z``).

    The returns per sweep are inversely proportional to the nod rate (the lines crossing the
    area are that much further apart), so one reference sweep on the plane gives the rate.

    Raises:
        SimulationError: the area of interest cannot be seen from ``position``.
    """
    if sensor.fov_vertical <= 0:
        raise SimulationError('a hover scan needs the nodding mount: sensor fov_vertical must '
                              'be positive')
    if sensor.nod_rate is not None:
        return float(sensor.nod_rate)
    position = np.asarray(position, dtype=float)
    aoi_lo = np.asarray(aoi_lo, dtype=float)
    aoi_hi = np.asarray(aoi_hi, dtype=float)
    target = np.array([(aoi_lo[0] + aoi_hi[0]) / 2, (aoi_lo[1] + aoi_hi[1]) / 2, ground_z])
    geom = HoverGeometry.make(sensor, position, target, heading)
    # A slow reference sweep (many lines over the area) keeps the count's rounding small.
    omega_ref = math.radians(2.0)
    for _ in range(8):
        n_ref = _aoi_count_flat(geom, omega_ref, aoi_lo, aoi_hi, ground_z)
        if n_ref >= 2000 or n_ref == 0:
            break
        omega_ref /= 4.0
    if n_ref == 0:
        raise SimulationError('the area of interest is not in view of the sensor at '
                              f'{np.round(position, 2).tolist()}')
    area = float(np.prod(aoi_hi - aoi_lo))
    per_sweep = sensor.target_density * area / sensor.sweeps_per_target
    omega = omega_ref * n_ref / per_sweep
    # Interleave the sweeps. Lines of one sweep lie delta = omega * line_period apart in nod
    # angle; sweep j (up for even j, down for odd) puts them at offsets -j*s resp. (j+1)*s
    # (mod 1) of that spacing, with s = span / delta. With frac(s) = 1 / (2n) the first n
    # sweeps fill the offsets k/n, k = 0..n-1: evenly spread lines, not stripes.
    n = sensor.sweeps_per_target
    s = geom.span / (omega * sensor.line_period)
    s = max(round(s - 0.5 / n), 1) + 0.5 / n
    return math.degrees(geom.span / (s * sensor.line_period))


def hover_scan(caster: RayCaster, sensor: SensorConfig, position: np.ndarray,
               aoi_lo: np.ndarray, aoi_hi: np.ndarray, box_lo: np.ndarray, box_hi: np.ndarray,
               rng: np.random.Generator, ground_z: float = 0.0, heading: float = 0.0,
               wander_bound: float | None = None) -> HoverScan:
    """Scan from a hovering vehicle until the area of interest holds the target density.

    Args:
        caster: the world to scan.
        sensor: the scanner.
        position: (3,) nominal sensor position [m].
        aoi_lo, aoi_hi: (2,) corners of the area of interest in x, y [m]; the density counts
            the returns whose x, y fall inside it.
        box_lo, box_hi: (3,) corners of the region of interest: only returns whose ray (from
            the origin to the return) passes through this box are kept.
        rng: randomness of the wander and the range noise.
        ground_z: nominal ground height (the nod is centred on the area of interest there).
        heading: direction of flight [rad] (scan lines run across it).
        wander_bound: per-axis bound of the origin's random walk [m] (None: unbounded).

    Returns:
        The kept returns (in time order) and the scan's figures.

    Raises:
        SimulationError: the area cannot be seen or the target is not reached in
            ``sensor.max_scan_time``.
    """
    sensor.validate()
    position = np.asarray(position, dtype=float)
    aoi_lo, aoi_hi = np.asarray(aoi_lo, dtype=float), np.asarray(aoi_hi, dtype=float)
    box_lo, box_hi = np.asarray(box_lo, dtype=float), np.asarray(box_hi, dtype=float)
    omega_deg = estimate_nod_rate(sensor, position, aoi_lo, aoi_hi, ground_z, heading)
    omega = math.radians(omega_deg)
    target = np.array([(aoi_lo[0] + aoi_hi[0]) / 2, (aoi_lo[1] + aoi_hi[1]) / 2, ground_z])
    geom = HoverGeometry.make(sensor, position, target, heading)
    walk = BrownianWalk(sensor.wander_sigma, rng, wander_bound)
    area = float(np.prod(aoi_hi - aoi_lo))
    goal = int(math.ceil(sensor.target_density * area))
    t_sweep = geom.span / omega
    # Within one sweep the origin wanders by less than this (5 sigma) plus a millimetre.
    sweep_margin = 5.0 * sensor.wander_sigma * math.sqrt(t_sweep) + 1e-3
    parts: list[Returns] = []
    n_aoi = 0
    rays = 0
    sweep = 0
    cast_seconds = 0.0
    while n_aoi < goal:
        if sweep * t_sweep > sensor.max_scan_time:
            raise SimulationError(
                f'hover scan did not reach {sensor.target_density:g} returns/m^2 over the area '
                f'of interest within {sensor.max_scan_time:g} s ({n_aoi / area:.0f} so far): '
                'is the area hidden from the sensor?')
        start = walk.at([sweep * t_sweep])[0]
        phi_a, phi_b, i_lo, i_hi = geom.window(position + start, box_lo, box_hi, sweep_margin)
        lines = geom.lines_in_window(sweep, omega, phi_a, phi_b)
        sweep += 1
        if not len(lines) or i_hi < i_lo:
            continue
        line_times = lines * sensor.line_period
        origins = position + walk.at(line_times)
        dirs, times = geom.rays(lines, i_lo, i_hi, omega)
        n_lines, n_pulses = times.shape
        line_of = np.repeat(np.arange(n_lines), n_pulses)
        dirs = dirs.reshape(-1, 3)
        times = times.reshape(-1)
        org = origins[line_of]
        t_in, t_out = ray_box_interval(org, dirs, box_lo, box_hi)
        through = t_in <= t_out
        idx = np.flatnonzero(through)
        t_cast = time.perf_counter()
        hits = caster.cast(org[idx], dirs[idx], sensor.max_range)
        cast_seconds += time.perf_counter() - t_cast
        rays += len(idx)
        hit = hits.hit
        idx = idx[hit]
        rng_noise = rng.standard_normal(len(idx)) * sensor.range_sigma
        t_meas = hits.t[hit] + rng_noise
        # Keep the returns whose measured ray segment reaches the box.
        keep = t_in[idx] <= t_meas
        idx, t_meas, labels = idx[keep], t_meas[keep], hits.label[hit][keep]
        pts = org[idx] + t_meas[:, None] * dirs[idx]
        in_aoi = np.all((pts[:, :2] >= aoi_lo) & (pts[:, :2] < aoi_hi), axis=1)
        per_line = np.bincount(line_of[idx][in_aoi], minlength=n_lines)
        cum = n_aoi + np.cumsum(per_line)
        last_line = n_lines - 1
        if cum[-1] >= goal:
            # The target is reached during this line: scanning stops at its end.
            last_line = int(np.searchsorted(cum, goal))
        sel = line_of[idx] <= last_line
        n_aoi = int(cum[last_line])
        parts.append(Returns(pts[sel], labels[sel], times[idx][sel], line_of[idx][sel],
                             origins[:last_line + 1], line_times[:last_line + 1]))
    returns = Returns.concat(parts).compact_lines()
    duration = float(np.ptp(returns.times)) if len(returns) else 0.0
    return HoverScan(returns, omega_deg, sweep, duration, rays, n_aoi, area, cast_seconds)
