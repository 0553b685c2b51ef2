"""The path of a simulated flight: a lawnmower of straight passes, and the speed it is flown at.

The helicopter flies passes along x at constant height and speed, spaced so that every site
point lies within half a swath of one; unless given, the speed is the one that puts the target
density onto the site (on flat ground the density is inversely proportional to the speed; the
constant follows from the scan geometry, :func:`density_constant`, or for another scan pattern
from its footprint on flat ground, :func:`pattern_footprint`), up to ``max_speed``.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.flight_settings import FlightConfig
from landing_zone.tools.sim.sensor import mount_frame

__all__ = ['pass_offsets', 'Footprint', 'pattern_footprint', 'footprint_density_constant',
           'density_constant', 'quaternion', 'Lawnmower']

_SWATH_ANGLE = 40.0  # [deg] scan angle out to which a pass counts as covering the ground


def pass_offsets(config: FlightConfig, swath_half: float | None = None) -> np.ndarray:
    """Cross-track positions (y) of the passes: every site point within half a swath of one.

    ``swath_half`` defaults to the line scanner's; ``config.line_spacing``, when given, puts
    the passes that far apart, centred on the site (as many as it takes to span it).
    """
    if config.line_spacing is not None:
        n = max(1, math.ceil(config.size / config.line_spacing - 1e-9))
        return (np.arange(n) - 0.5 * (n - 1)) * config.line_spacing
    if swath_half is None:
        swath_half = config.height * math.tan(math.radians(_SWATH_ANGLE)) / math.cos(
            math.radians(config.tilt))
    n = max(1, math.ceil(config.size / (2.0 * swath_half)))
    return -0.5 * config.size + (np.arange(n) + 0.5) * config.size / n


@dataclass
class Footprint:
    """Where a scan pattern's pulses meet flat ground, seen from the moving vehicle."""

    y: np.ndarray  # cross-track bin centres [m]
    rate: np.ndarray  # returns per second per metre of cross-track at y
    swath_half: float  # [m]
    reach: tuple[float, float]  # along-track extent of the returns (behind, ahead) [m]


def pattern_footprint(config: FlightConfig, seconds: float = 1.0) -> Footprint:
    """The footprint of ``config.scan`` on flat ground ``config.height`` below, sampled over
    ``seconds`` of pulses at heading 0.

    The swath is where the cross-track rate stays at or above 0.6 of its mean over the middle
    (a quarter of the height either side; the line scanner's 40 of 50 degrees keep about that
    share of its centre's density); the reach holds all but 0.5 % of the returns at either end
    among those that can fall on the site.
    """
    s, h = config.sensor, config.height
    n = max(int(round(seconds * s.prr)), 1000)
    idx = np.arange(n)
    local = config.scan.local_directions(idx / s.prr, idx)
    d = local @ mount_frame(math.radians(config.tilt), np.zeros(1))[0].T
    down = d[:, 2] < -1e-9
    t = np.full(n, np.inf)
    t[down] = h / -d[down, 2]
    ok = t <= s.max_range
    x, y = (t[ok, None] * d[ok, :2]).T
    span = 4.0 * h + config.size
    bin_w = max(0.01 * h, 0.02)
    edges = np.arange(-span, span + 0.5 * bin_w, bin_w)
    counts, _ = np.histogram(y, edges)
    rate = counts / (n / s.prr) / bin_w
    centres = 0.5 * (edges[1:] + edges[:-1])
    # Smooth over about 0.1 h so that the rosette's petals do not end the swath early.
    k = max(1, int(round(0.1 * h / bin_w)))
    smooth = np.convolve(rate, np.ones(2 * k + 1) / (2 * k + 1), mode='same')
    middle = np.abs(centres) <= 0.25 * h
    ref = float(smooth[middle].mean())
    if ref <= 0:
        raise SimulationError(f'the {config.scan.kind} scanner tilted {config.tilt:g} degrees '
                              f'puts no returns under the vehicle')
    covered = smooth >= 0.6 * ref
    right = np.flatnonzero(~covered & (centres > 0))
    left = np.flatnonzero(~covered & (centres < 0))
    w_r = centres[right[0]] if len(right) else span
    w_l = -centres[left[-1]] if len(left) else span
    near = np.abs(y) <= config.size  # the returns that can fall on the site
    lo_x, hi_x = np.quantile(x[near], [0.005, 0.995]) if near.any() else (0.0, 0.0)
    return Footprint(centres, rate, float(min(w_r, w_l)), (float(lo_x), float(hi_x)))


def footprint_density_constant(config: FlightConfig, passes: np.ndarray,
                               foot: Footprint) -> float:
    """K such that the mean density over the site on flat ground is K / speed (any pattern):
    at cross-track offset y from a pass, the vehicle sweeps rate(y) returns per second over
    each metre across, spread along ``speed`` metres of track."""
    y = np.linspace(-0.5 * config.size, 0.5 * config.size, 2001)
    cover = np.interp(y[:, None] - passes[None, :], foot.y, foot.rate, left=0.0,
                      right=0.0).sum(axis=1)
    return float(cover.mean())


def density_constant(config: FlightConfig, passes: np.ndarray) -> float:
    """K such that the mean density over the site on flat ground is K / speed [1/m^2 * m/s].

    A line lands ``height * tan(tilt)`` ahead; along it, at scan angle theta, consecutive
    pulses lie ``height * res / (cos(tilt) cos^2(theta))`` apart (y = h tan(theta) / cos(tilt)),
    and lines lie ``speed * line_period`` apart along x. Summed over the passes and averaged
    across the site.
    """
    s = config.sensor
    tilt = math.radians(config.tilt)
    res = math.radians(s.angular_resolution)
    half_fov = math.radians(0.5 * s.fov_horizontal)
    y = np.linspace(-0.5 * config.size, 0.5 * config.size, 2001)
    theta = np.arctan((y[:, None] - passes[None, :]) * math.cos(tilt) / config.height)
    cover = np.where(np.abs(theta) <= half_fov, np.cos(theta) ** 2, 0.0).sum(axis=1)
    return float(math.cos(tilt) / (s.line_period * res * config.height) * cover.mean())


def quaternion(heading: np.ndarray, tilt: float) -> np.ndarray:
    """(n, 4) xyzw: yaw ``heading`` about z, then pitch so the sensor's x axis is the central
    beam (pitched down by 90 deg - tilt)."""
    pitch = 0.5 * math.pi - tilt
    cy, sy = np.cos(0.5 * heading), np.sin(0.5 * heading)
    cp, sp = math.cos(0.5 * pitch), math.sin(0.5 * pitch)
    # q_z(heading) * q_y(pitch)
    return np.stack([-sy * sp, cy * sp, sy * cp, cy * cp], axis=-1)


class Lawnmower:
    """Passes along +x / -x (alternating) at constant speed, joined by straight turns."""

    def __init__(self, config: FlightConfig, passes: np.ndarray, speed: float,
                 reach: tuple[float, float] | None = None) -> None:
        half = 0.5 * config.size
        if reach is None:
            ahead = config.height * math.tan(math.radians(config.tilt))
            reach = (ahead, ahead)
        behind, ahead = reach  # along-track extent of the returns from the vehicle
        run = 1.0  # [m] scanned beyond the site's edge at both ends
        self.height = config.height
        self.speed = speed
        self.segments = []  # (t0, t1, start xy, end xy, heading, scanning)
        t = 0.0
        prev_end = None
        for k, y in enumerate(passes):
            sign = 1.0 if k % 2 == 0 else -1.0
            # The ground line lies `ahead` in front (for other scanners: the returns lie
            # `behind` .. `ahead` in front): the vehicle runs from before the site until all
            # of them have crossed it.
            x0 = sign * (-half - run - ahead)
            x1 = sign * (half + run - behind)
            start, end = np.array([x0, y]), np.array([x1, y])
            if prev_end is not None:
                dt = float(np.hypot(*(start - prev_end))) / speed
                heading = math.atan2(*(start - prev_end)[::-1])
                self.segments.append((t, t + dt, prev_end, start, heading, False))
                t += dt
            dt = abs(x1 - x0) / speed
            self.segments.append((t, t + dt, start, end, 0.0 if sign > 0 else math.pi, True))
            t += dt
            prev_end = end
        self.duration = t

    def __call__(self, times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        times = np.asarray(times, dtype=float)
        pos = np.zeros((len(times), 3))
        heading = np.zeros(len(times))
        for t0, t1, a, b, h, _ in self.segments:
            m = (times >= t0) & (times <= t1)
            f = ((times[m] - t0) / (t1 - t0))[:, None]
            pos[m, :2] = a + f * (b - a)
            heading[m] = h
        pos[:, 2] = self.height
        return pos, heading
