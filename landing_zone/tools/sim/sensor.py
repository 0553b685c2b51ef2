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

Hovering (:mod:`landing_zone.tools.sim.hover`): the mount nods back and forth over the area of
interest until its returns reach the target density.

Flying (:func:`path_scan`): every pulse of every line along a trajectory (a pushbroom), the
scan plane tilted forward by a fixed nod angle. Or, with a :class:`ScanPattern` other than
``line``, the pulses of another scanner mounted the same way (its centre tilted forward by the
same angle): a spinning multi-beam scanner or a rosette (non-repetitive) scanner, see there.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, replace
from typing import Callable

import numpy as np

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.mesh import GRASS, GROUND, OBSTACLE
from landing_zone.tools.sim.raycast import RayCaster

__all__ = ['SensorConfig', 'Returns', 'BrownianWalk', 'scan_directions', 'direction_angles',
           'ray_box_interval', 'path_scan', 'SCAN_PATTERNS', 'ScanPattern', 'mount_frame']

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
