"""The airborne line scanner on a nodding mount (the paper's RIEGL setup), as rays and returns.

Geometry (sensor frame, x = direction of flight, z up): a scan line sweeps the angle ``theta``
across the flight direction, ``-fov_horizontal/2 .. +fov_horizontal/2``, one pulse every
``angular_resolution``; the mount tilts the scan plane forward by the nod angle ``phi``
(0 = the plane contains the nadir), so a pulse leaves along::

    d = (sin(phi) cos(theta), sin(theta), -cos(phi) cos(theta))

turned by the vehicle's heading about z. Pulses follow each other at the pulse repetition rate,
lines follow each other without dead time (a line lasts ``pulses_per_line / prr``), and the nod
angle moves continuously (a triangle wave of ``nod_rate`` over ``fov_vertical``), so it is
evaluated at every pulse's own time.

Noise: every range gets Gaussian noise (``range_sigma``, measured along the ray); the sensor
origin wanders by a Gaussian random walk (Brownian motion, ``wander_sigma`` metres per square
root of a second, independently in x, y and z), sampled once per scan line: within a line
(milliseconds) it moves by micrometres, and one origin per line is what a dataset stores.

Hovering (:func:`hover_scan`): the mount nods back and forth, centred on the area of interest,
and scanning goes on until the returns that fall into the area of interest reach the target
density. By default the nod rate is chosen so that one sweep delivers a quarter of the target
(``sweeps_per_target``), so the coverage of the area is uniform and the last, partial sweep
adds at most a quarter. Only rays that can reach the region of interest (a box) are generated:
the angular window of each sweep is computed from the box, which is what makes a hover scan
cheap (a few ten thousand rays instead of the millions of a full 100 x 100 degree sweep).

Flying (:func:`path_scan`): every pulse of every line along a trajectory (a pushbroom), the
scan plane tilted forward by a fixed nod angle. Or, with a :class:`ScanPattern` other than
``line``, the pulses of another scanner mounted the same way (its centre tilted forward by the
same angle): a spinning multi-beam scanner or a rosette (non-repetitive) scanner, see there.
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field, replace
from typing import Callable

import numpy as np

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.mesh import GRASS, GROUND, OBSTACLE
from landing_zone.tools.sim.raycast import RayCaster

__all__ = ['SensorConfig', 'Returns', 'HoverScan', 'BrownianWalk', 'scan_directions',
           'direction_angles', 'ray_box_interval', 'hover_scan', 'estimate_nod_rate',
           'path_scan', 'SCAN_PATTERNS', 'ScanPattern', 'mount_frame']

# Share of the pulse energy each class reflects (intensities only: a plausible ordering).
_REFLECTIVITY = {GROUND: 0.25, GRASS: 0.45, OBSTACLE: 0.35}


@dataclass(frozen=True)
class SensorConfig:
    """The scanner, its noise and the target of a scan."""

    prr: float = 300_000.0  # pulse repetition rate [1/s]
    angular_resolution: float = 0.1  # angle between pulses of a scan line [deg]
    fov_horizontal: float = 100.0  # width of a scan line [deg]
    fov_vertical: float = 100.0  # range of the nodding mount [deg]
    # [deg/s]; None: chosen from the target density (hover scans) so that one sweep delivers
    # 1/sweeps_per_target of it.
    nod_rate: float | None = None
    sweeps_per_target: int = 4
    range_sigma: float = 0.025  # Gaussian range noise [m]
    wander_sigma: float = 0.02  # random walk of the sensor origin [m / sqrt(s)]
    max_range: float = 150.0  # no return beyond this [m]
    target_density: float = 3000.0  # returns per m^2 over the area of interest
    max_scan_time: float = 600.0  # a hover scan that needs longer fails [s]

    def validate(self) -> None:
        def check(name: str, low: float, high: float, low_open: bool = False) -> None:
            value = getattr(self, name)
            ok = isinstance(value, (int, float)) and math.isfinite(value)
            ok = ok and (value > low if low_open else value >= low) and value <= high
            if not ok:
                bound = '(' if low_open else '['
                raise SimulationError(f'sensor {name} must lie in {bound}{low:g}, {high:g}], '
                                      f'got {value!r}')
        check('prr', 0.0, 1.0e7, low_open=True)
        check('angular_resolution', 0.0, 5.0, low_open=True)
        check('fov_horizontal', 0.0, 100.0, low_open=True)
        check('fov_vertical', 0.0, 100.0)
        check('range_sigma', 0.0, 1.0)
        check('wander_sigma', 0.0, 1.0)
        check('max_range', 0.0, 1.0e4, low_open=True)
        check('target_density', 0.0, 1.0e6, low_open=True)
        check('max_scan_time', 0.0, 1.0e5, low_open=True)
        if self.nod_rate is not None:
            check('nod_rate', 0.0, 1.0e4, low_open=True)
        if not (isinstance(self.sweeps_per_target, int) and 1 <= self.sweeps_per_target <= 64):
            raise SimulationError(f'sensor sweeps_per_target must be an integer in [1, 64], '
                                  f'got {self.sweeps_per_target!r}')
        if self.angular_resolution > self.fov_horizontal:
            raise SimulationError('sensor angular_resolution must not exceed fov_horizontal')

    @property
    def pulses_per_line(self) -> int:
        return int(math.floor(self.fov_horizontal / self.angular_resolution + 1e-9)) + 1

    @property
    def line_period(self) -> float:
        """Duration of one scan line [s]."""
        return self.pulses_per_line / self.prr

    def thetas(self) -> np.ndarray:
        """Scan angle of every pulse of a line [rad]."""
        deg = -0.5 * self.fov_horizontal + self.angular_resolution * np.arange(
            self.pulses_per_line)
        return np.radians(deg)

    def to_dict(self) -> dict:
        return asdict(self)


SCAN_PATTERNS = ('line', 'spinning', 'rosette', 'elliptical')


@dataclass(frozen=True)
class ScanPattern:
    """Where a flying scanner's pulses go, in its own frame (x: the centre of the pattern, z: the
    spin axis of a spinning scanner), at the sensor's pulse rate.

    The frame is mounted like the line scanner's: pitched so that x points ``tilt`` forward of
    the nadir and y across the flight direction (z then points forward and up, ``tilt`` above
    the horizon), and turned with the vehicle's heading.

    * ``line``: the nodding line scanner held at the tilt (the default; :class:`SensorConfig`
      gives its lines).
    * ``spinning``: a multi-beam scanner (Velodyne/Ouster-like) spinning at ``spin_rate`` about
      z; ``beams`` beams at elevations evenly spread over ``beam_fov`` fire one after the
      other, so beam ``i % beams`` fires pulse i at the azimuth the head has reached by then.
      Beam elevation 0 sweeps the plane of the line scanner (tilted forward by ``tilt``) and on
      round to the sky behind; every beam draws a cone, on the ground a curve.
    * ``rosette``: a Risley-prism scanner (Livox-like): the pulse's angular offset from x is
      the sum of two vectors of length ``fov / 4`` turning in opposite senses at
      ``prism_rates`` [rev/s]; with an irrational ratio the petals never repeat and the circle
      of diameter ``fov`` fills up over time, densest at its centre and rim.
    * ``elliptical``: a nutating-mirror (Palmer) scanner: every pulse leaves at ``fov / 2`` from
      x, the mirror turning about x at ``spin_rate`` [rev/s], so the pulses trace the rim of the
      circle of diameter ``fov``; on the ground, seen from a tilted mount, an ellipse, which the
      vehicle's motion sweeps along (every point is crossed twice, by the ellipse's front and
      back arcs, from two view directions).

    Points per second are the sensor's ``prr`` in every pattern; the pulses are grouped into
    "lines" of ``SensorConfig.pulses_per_line`` (the clouds and poses of a flight follow them).
    """

    kind: str = 'line'  # one of SCAN_PATTERNS
    beams: int = 16  # spinning: beams
    beam_fov: float = 30.0  # spinning: spread of the beams' elevations [deg]
    spin_rate: float = 10.0  # spinning, elliptical: [rev/s]
    fov: float = 70.0  # rosette, elliptical: diameter of the circular field of view [deg]
    prism_rates: tuple[float, float] = (120.0, 74.16407864998739)  # rosette [rev/s] (ratio phi)

    def validate(self) -> None:
        """Raise :class:`SimulationError` naming the first nonsensical parameter."""
        if self.kind not in SCAN_PATTERNS:
            raise SimulationError(f'unknown scan pattern {self.kind!r}; choose from '
                                  f'{", ".join(SCAN_PATTERNS)}')
        if not (isinstance(self.beams, int) and 1 <= self.beams <= 256):
            raise SimulationError(f'scan beams must be an integer in [1, 256], got '
                                  f'{self.beams!r}')
        for name, low, high in (('beam_fov', 0.0, 90.0), ('spin_rate', 0.1, 1000.0),
                                ('fov', 1.0, 120.0)):
            value = getattr(self, name)
            if not (isinstance(value, (int, float)) and math.isfinite(value)
                    and low <= value <= high):
                raise SimulationError(f'scan {name} must lie in [{low:g}, {high:g}], got '
                                      f'{value!r}')
        rates = self.prism_rates
        if not (isinstance(rates, (tuple, list)) and len(rates) == 2
                and all(isinstance(r, (int, float)) and math.isfinite(r) and 0 < r <= 1000
                        for r in rates) and rates[0] != rates[1]):
            raise SimulationError(f'scan prism_rates must be two different rates in (0, 1000] '
                                  f'rev/s, got {rates!r}')

    def local_directions(self, times: np.ndarray, index: np.ndarray) -> np.ndarray:
        """Unit directions (..., 3) in the scanner's frame of the pulses fired at ``times``
        [s] with pulse numbers ``index`` (spinning: the beam is ``index % beams``)."""
        times = np.asarray(times, dtype=float)
        if self.kind == 'spinning':
            if self.beams > 1:
                step = math.radians(self.beam_fov) / (self.beams - 1)
                elev = (np.mod(index, self.beams) - 0.5 * (self.beams - 1)) * step
            else:
                elev = np.zeros(np.shape(index))
            az = 2.0 * np.pi * np.mod(self.spin_rate * times, 1.0)
            ce = np.cos(elev)
            return np.stack(np.broadcast_arrays(ce * np.cos(az), ce * np.sin(az), np.sin(elev)),
                            axis=-1)
        if self.kind == 'rosette':
            a = 0.25 * math.radians(self.fov)
            w1 = 2.0 * np.pi * np.mod(self.prism_rates[0] * times, 1.0)
            w2 = 2.0 * np.pi * np.mod(self.prism_rates[1] * times, 1.0)
            dy = a * (np.cos(w1) + np.cos(w2))
            dz = a * (np.sin(w1) - np.sin(w2))
            rho = np.hypot(dy, dz)
            sinc = np.where(rho > 0, np.sin(rho) / np.where(rho > 0, rho, 1.0), 1.0)
            return np.stack([np.cos(rho), sinc * dy, sinc * dz], axis=-1)
        if self.kind == 'elliptical':
            half = 0.5 * math.radians(self.fov)
            w = 2.0 * np.pi * np.mod(self.spin_rate * times, 1.0)
            return np.stack([np.full(w.shape, math.cos(half)), math.sin(half) * np.cos(w),
                             math.sin(half) * np.sin(w)], axis=-1)
        raise SimulationError('the line pattern has no pulse directions of its own '
                              '(see scan_directions)')

    def to_dict(self) -> dict:
        out = asdict(self)
        out['prism_rates'] = list(self.prism_rates)
        return out


def mount_frame(tilt: float, heading: np.ndarray) -> np.ndarray:
    """(n, 3, 3) rotations (columns: the scanner's x, y, z in the world) of a scanner whose x
    points ``tilt`` [rad] forward of the nadir, y to the left, turned by ``heading`` [rad]."""
    heading = np.atleast_1d(np.asarray(heading, dtype=float))
    ch, sh = np.cos(heading), np.sin(heading)
    st, ct = math.sin(tilt), math.cos(tilt)
    zeros = np.zeros_like(ch)
    x = np.stack([st * ch, st * sh, np.full_like(ch, -ct)], axis=-1)
    y = np.stack([-sh, ch, zeros], axis=-1)
    z = np.stack([ct * ch, ct * sh, np.full_like(ch, st)], axis=-1)
    return np.stack([x, y, z], axis=-1)


@dataclass
class Returns:
    """LiDAR returns with their scan lines.

    Attributes:
        points: (N, 3) float64 measured positions [m].
        labels: (N,) uint8 class of the surface each return came from.
        times: (N,) float64 time of each pulse [s].
        line: (N,) int64 index into ``line_origins`` / ``line_times``.
        line_origins: (L, 3) float64 sensor origin during each scan line [m].
        line_times: (L,) float64 start time of each scan line [s].
        intensity: (N,) float32 or None, reflected share of the pulse (flights only).
    """

    points: np.ndarray
    labels: np.ndarray
    times: np.ndarray
    line: np.ndarray
    line_origins: np.ndarray
    line_times: np.ndarray
    intensity: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.points)

    @property
    def origins(self) -> np.ndarray:
        """(N, 3) sensor origin of every return."""
        return self.line_origins[self.line]

    @classmethod
    def empty(cls) -> 'Returns':
        return cls(np.zeros((0, 3)), np.zeros(0, np.uint8), np.zeros(0), np.zeros(0, np.int64),
                   np.zeros((0, 3)), np.zeros(0))

    @classmethod
    def concat(cls, parts: list['Returns']) -> 'Returns':
        """Parts in order; their line tables are stacked and the line indices shifted."""
        parts = [p for p in parts if len(p.line_times)]
        if not parts:
            return cls.empty()
        offsets = np.cumsum([0] + [len(p.line_times) for p in parts[:-1]])
        intensity = None
        if all(p.intensity is not None for p in parts):
            intensity = np.concatenate([p.intensity for p in parts])
        return cls(np.concatenate([p.points for p in parts]),
                   np.concatenate([p.labels for p in parts]),
                   np.concatenate([p.times for p in parts]),
                   np.concatenate([p.line + o for p, o in zip(parts, offsets)]),
                   np.concatenate([p.line_origins for p in parts]),
                   np.concatenate([p.line_times for p in parts]),
                   intensity)

    def compact_lines(self) -> 'Returns':
        """Drop scan lines without returns from the line table (indices remapped)."""
        used, inverse = np.unique(self.line, return_inverse=True)
        return replace(self, line=inverse.astype(np.int64), line_origins=self.line_origins[used],
                       line_times=self.line_times[used])


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


class BrownianWalk:
    """The wandering sensor origin: Brownian motion sampled at increasing times.

    Args:
        sigma: standard deviation after one second, per axis [m].
        rng: randomness.
        bound: the walk is held within +-bound per axis (the vehicle's position hold), so that
            the world built around the expected positions contains every ray. None: unbounded.
    """

    def __init__(self, sigma: float, rng: np.random.Generator, bound: float | None = None
                 ) -> None:
        self.sigma = sigma
        self.rng = rng
        self.bound = bound
        self.t = 0.0
        self.offset = np.zeros(3)

    def at(self, times: np.ndarray) -> np.ndarray:
        """(len(times), 3) offsets at ``times`` (non-decreasing, not before the last call)."""
        times = np.asarray(times, dtype=float)
        if not len(times):
            return np.zeros((0, 3))
        dt = np.diff(np.concatenate([[self.t], times]))
        if np.any(dt < -1e-12):
            raise ValueError('BrownianWalk sampled back in time')
        steps = self.rng.standard_normal((len(times), 3)) * (
            self.sigma * np.sqrt(np.maximum(dt, 0.0)))[:, None]
        path = self.offset + np.cumsum(steps, axis=0)
        if self.bound is not None:
            path = np.clip(path, -self.bound, self.bound)
        self.t = float(times[-1])
        self.offset = path[-1].copy()
        return path


def scan_directions(theta: np.ndarray, phi: np.ndarray, heading: float | np.ndarray = 0.0
                    ) -> np.ndarray:
    """Unit directions (..., 3) of pulses at scan angle ``theta`` and nod angle ``phi`` [rad]."""
    ct = np.cos(theta)
    lx = np.sin(phi) * ct
    ly = np.sin(theta) * np.ones_like(lx)
    lz = -np.cos(phi) * ct
    ch, sh = np.cos(heading), np.sin(heading)
    return np.stack([ch * lx - sh * ly, sh * lx + ch * ly, lz], axis=-1)


def direction_angles(d: np.ndarray, heading: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """Inverse of :func:`scan_directions`: (theta, phi) [rad] of directions (..., 3)."""
    d = d / np.linalg.norm(d, axis=-1, keepdims=True)
    ch, sh = math.cos(heading), math.sin(heading)
    lx = ch * d[..., 0] + sh * d[..., 1]
    ly = -sh * d[..., 0] + ch * d[..., 1]
    return np.arcsin(np.clip(ly, -1.0, 1.0)), np.arctan2(lx, -d[..., 2])


def ray_box_interval(origins: np.ndarray, dirs: np.ndarray, lo: np.ndarray, hi: np.ndarray
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Entry and exit distances of rays through an axis-aligned box (slab method).

    The ray misses the box (or it lies behind the origin) where ``t_in > t_out`` or
    ``t_out < 0``.
    """
    with np.errstate(divide='ignore', invalid='ignore'):
        inv = 1.0 / dirs
        t0 = (lo - origins) * inv
        t1 = (hi - origins) * inv
    # A direction component of 0 gives +-inf (or nan on the slab's plane): inside or outside.
    tmin = np.where(np.isnan(t0), -np.inf, np.minimum(t0, t1))
    tmax = np.where(np.isnan(t1), np.inf, np.maximum(t0, t1))
    return np.maximum(tmin.max(axis=-1), 0.0), tmax.min(axis=-1)


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
class _HoverGeometry:
    sensor: SensorConfig
    position: np.ndarray
    heading: float
    phi_lo: float  # lowest nod angle [rad]
    span: float  # nod range [rad]
    thetas: np.ndarray = field(repr=False, default_factory=lambda: np.zeros(0))

    @classmethod
    def make(cls, sensor: SensorConfig, position: np.ndarray, target: np.ndarray,
             heading: float) -> '_HoverGeometry':
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


def _aoi_count_flat(geom: _HoverGeometry, omega: float, aoi_lo: np.ndarray,
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
    geom = _HoverGeometry.make(sensor, position, target, heading)
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
    geom = _HoverGeometry.make(sensor, position, target, heading)
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


def path_scan(caster: RayCaster, sensor: SensorConfig,
              trajectory: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
              t_start: float, t_end: float, tilt: float, rng: np.random.Generator,
              walk: BrownianWalk | None = None, lines_per_chunk: int = 256,
              pattern: ScanPattern | None = None) -> 'list[Returns]':
    """Every pulse of every scan line from ``t_start`` to ``t_end`` along a trajectory.

    Args:
        caster: the world.
        sensor: the scanner (its nod is held at ``tilt``).
        trajectory: maps times (n,) to nominal positions (n, 3) and headings (n,) [rad].
        t_start, t_end: time span scanned [s]; lines start every ``sensor.line_period``.
        tilt: nod angle of the scan plane, forward from the nadir [rad].
        rng: randomness of the range noise (and of the wander, if ``walk`` is None).
        walk: the origin's random walk, shared across calls so that it stays continuous.
        lines_per_chunk: lines cast per batch (memory: lines x pulses rays).
        pattern: another scanner in the same mount (None or ``line``: the line scanner); its
            "lines" are runs of ``sensor.pulses_per_line`` pulses.

    Returns:
        One :class:`Returns` per chunk of lines, in time order, with intensities.
    """
    sensor.validate()
    if pattern is not None:
        pattern.validate()
        if pattern.kind == 'line':
            pattern = None
    walk = walk if walk is not None else BrownianWalk(sensor.wander_sigma, rng)
    period = sensor.line_period
    first = int(math.ceil(t_start / period - 1e-9))
    last = int(math.floor(t_end / period - 1e-9))
    thetas = sensor.thetas()
    offsets = np.arange(len(thetas)) / sensor.prr
    normals = caster.mesh.face_normals()
    reflect = np.zeros(256, np.float32)
    for cls, value in _REFLECTIVITY.items():
        reflect[cls] = value
    out = []
    for c0 in range(first, last + 1, lines_per_chunk):
        lines = np.arange(c0, min(c0 + lines_per_chunk, last + 1), dtype=np.int64)
        line_times = lines * period
        nominal, heading = trajectory(line_times)
        origins = nominal + walk.at(line_times)
        if pattern is None:
            dirs = scan_directions(thetas[None, :], np.full((len(lines), 1), tilt),
                                   heading[:, None]).reshape(-1, 3)
        else:
            index = lines[:, None] * len(thetas) + np.arange(len(thetas))[None, :]
            local = pattern.local_directions(line_times[:, None] + offsets[None, :], index)
            dirs = np.einsum('lij,lpj->lpi', mount_frame(tilt, heading), local).reshape(-1, 3)
        line_of = np.repeat(np.arange(len(lines)), len(thetas))
        org = origins[line_of]
        hits = caster.cast(org, dirs, sensor.max_range)
        idx = np.flatnonzero(hits.hit)
        t_meas = hits.t[idx] + rng.standard_normal(len(idx)) * sensor.range_sigma
        pts = org[idx] + t_meas[:, None] * dirs[idx]
        labels = hits.label[idx]
        cos_inc = np.abs(np.einsum('ij,ij->i', normals[hits.face[idx]], dirs[idx]))
        intensity = (reflect[labels] * cos_inc * (1.0 + 0.05 * rng.standard_normal(len(idx)))
                     ).astype(np.float32)
        times = line_times[line_of[idx]] + offsets[idx % len(thetas)]
        out.append(Returns(pts, labels, times, line_of[idx], origins, line_times,
                           np.clip(intensity, 0.0, 1.0)))
    return out
