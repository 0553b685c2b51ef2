"""Survey files: LAS / LAZ point clouds and their trajectories, as the node's input messages.

A surveyor's airborne LiDAR file holds georeferenced returns (in the file's projected CRS,
often in feet), each with its GPS time and scan angle, but no sensor origins; the map needs the
ray from the sensor to each return. :func:`read_survey` reads the file with laspy (LAZ through
its lazrs backend) and the sensor positions over time from:

* ``--trajectory FILE.csv``: rows ``t,x,y,z`` (a header row is skipped), time in the file's
  GPS time, position in the file's CRS and units;
* ``--trajectory FILE.sbet`` (or ``.out``): Applanix SBET records (17 little-endian float64:
  time, latitude, longitude [rad], altitude [m], ...), projected into the file's CRS with
  pyproj;
* nothing: **derived** from per-point GPS time and scan angle, assuming each flight line
  (``point_source_id``, split where time jumps by more than :data:`LINE_GAP` s) was flown
  straight and level at constant speed by a scanner sweeping across the track (the LAS scan
  angle is the angle from nadir; the spec puts positive angles to the right of the flight
  direction, some systems to the left, so the side that puts the sensor above its returns is
  taken). Then the
  track's direction is that of the returns' centroid moving with time, the sensor's height
  comes from ``offset across the track = (sensor z - return z) * tan(scan angle)`` (least
  squares over the line), and its along-track position from the returns' along-track position
  at each time. A line without spread in scan angle cannot be solved and is refused.

Coordinates are handled in FLOAT64: a **local origin** (the data's centre rounded to
:data:`ORIGIN_STEP` m, so tiles keep their georeferenced 1 m lattice; vertically to 1 m) is
subtracted and the file's units converted to metres before anything becomes float32; the
report states the origin (``survey.origin``), so a tile at local (x, y) lies at ``origin + (x,
y) / metres_per_unit`` in the file's CRS.

The returns become ``sensor_msgs/PointCloud2`` messages of :data:`CLOUD_SECONDS` of GPS time
each, with a ``geometry_msgs/PoseStamped`` of the trajectory before each, so replay runs them
through exactly the node's pipeline.
"""
from __future__ import annotations

import math
import os
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from landing_zone.errors import BagError
from landing_zone.io.bags import BagMessage

__all__ = ['SURVEY_SUFFIXES', 'Survey', 'is_survey', 'read_survey', 'read_trajectory',
           'derive_trajectory', 'DERIVED_ASSUMPTION']

SURVEY_SUFFIXES = ('.las', '.laz')
# GPS time of returns in one cloud message [s].
CLOUD_SECONDS = 0.01
# A flight line ends where the returns' GPS time jumps by more than this [s].
LINE_GAP = 1.0
# The local origin is a multiple of this [m] horizontally (a whole number of tiles).
ORIGIN_STEP = 100.0
# Trajectory samples of a derived line [Hz].
DERIVED_RATE = 20.0
DERIVED_ASSUMPTION = (
    'sensor origins derived from GPS time and scan angle: each flight line straight, level and '
    'at constant speed, the scan across the track (scan angle from nadir; positive to the '
    'side that puts the sensor above its returns)')
# GeoTIFF ProjLinearUnitsGeoKey values -> metres per unit (when pyproj is absent).
_GEOTIFF_UNITS = {9001: 1.0, 9002: 0.3048, 9003: 1200.0 / 3937.0}
_SBET_FIELDS = 17


@dataclass
class Survey:
    """A survey file's returns and sensor trajectory, in a local metric frame.

    Attributes:
        path: the file.
        points: (N, 3) float64 returns in the local frame [m], in GPS-time order.
        times: (N,) float64 GPS time of each return [s].
        traj_times: (K,) float64 trajectory times [s], increasing.
        traj_xyz: (K, 3) float64 sensor positions in the local frame [m].
        origin: (3,) float64 the local frame's origin in the file's CRS and units.
        metres_per_unit: the file's linear unit [m].
        crs: the CRS's name ('' if the file has none).
        trajectory_source: where the origins came from (a file, or the derivation).
        notes: what was assumed, one line each.
    """

    path: Path
    points: np.ndarray
    times: np.ndarray
    traj_times: np.ndarray
    traj_xyz: np.ndarray
    origin: np.ndarray
    metres_per_unit: float
    crs: str = ''
    trajectory_source: str = ''
    notes: list[str] = field(default_factory=list)

    def describe(self) -> dict[str, Any]:
        """The report's ``survey`` entry."""
        return {'file': str(self.path), 'crs': self.crs,
                'origin': [float(v) for v in self.origin],
                'metres_per_unit': self.metres_per_unit,
                'local_frame': 'metres; file CRS = origin + local / metres_per_unit',
                'returns': int(len(self.points)),
                'gps_time': [float(self.times[0]), float(self.times[-1])] if len(self.times)
                else [],
                'trajectory': self.trajectory_source, 'notes': list(self.notes)}

    def to_file_crs(self, xy: np.ndarray) -> np.ndarray:
        """Local (x, y) [m] -> the file's CRS and units (float64)."""
        out: np.ndarray = self.origin[:2] + np.asarray(xy, np.float64) / self.metres_per_unit
        return out

    def messages(self, points_topic: str, pose_topic: str, frame_id: str = 'map',
                 cloud_seconds: float = CLOUD_SECONDS) -> Iterator[BagMessage]:
        """The returns as clouds of ``cloud_seconds`` and the sensor poses before each, in
        time order, as replay reads a bag (rosbags messages)."""
        from msg_adapters import MessageTypes, make_header
        from msg_adapters.pointcloud import make_cloud, points_to_structured

        types = MessageTypes.rosbags()
        t = self.times
        if not len(t):
            return
        t0 = math.floor(float(t[0]))
        # stamps from the first whole second of GPS time on (adjusted GPS time may be negative)
        base_ns = int(t0 * 1e9) if t0 >= 0 else 0
        bins = np.floor((t - t0) / cloud_seconds).astype(np.int64)
        edges = np.flatnonzero(np.diff(bins)) + 1
        starts = np.concatenate([[0], edges])
        ends = np.concatenate([edges, [len(t)]])
        for a, b in zip(starts.tolist(), ends.tolist()):
            mid = 0.5 * (t[a] + t[b - 1])
            stamp = base_ns + int(round((mid - t0) * 1e9))
            pos = np.array([np.interp(mid, self.traj_times, self.traj_xyz[:, k])
                            for k in range(3)])
            header = make_header(stamp, frame_id, types)
            pose = types.build(
                'geometry_msgs/msg/PoseStamped', header=header,
                pose=types.build('geometry_msgs/msg/Pose',
                                 position=types.build('geometry_msgs/msg/Point', x=pos[0],
                                                      y=pos[1], z=pos[2]),
                                 orientation=types.build('geometry_msgs/msg/Quaternion',
                                                         x=0.0, y=0.0, z=0.0, w=1.0)))
            yield BagMessage(pose_topic, stamp, 'geometry_msgs/msg/PoseStamped', pose)
            # float64 fields: the local frame keeps millimetres, the map rounds to its voxels
            arr = points_to_structured(self.points[a:b], dtype=np.float64)
            yield BagMessage(points_topic, stamp, 'sensor_msgs/msg/PointCloud2',
                             make_cloud(arr, make_header(stamp, frame_id, types), types))


def is_survey(path: str | os.PathLike[str]) -> bool:
    """A LAS or LAZ file (by its suffix)."""
    return Path(path).suffix.lower() in SURVEY_SUFFIXES


def _linear_unit(header: Any) -> tuple[float, str, str]:
    """(metres per unit, CRS name, how it was found) of a LAS header."""
    try:
        crs = header.parse_crs()
    except ImportError:  # pyproj absent: the GeoTIFF key says the unit
        crs = None
        for vlr in header.vlrs:
            for key in getattr(vlr, 'geo_keys', None) or []:
                if key.id == 3076 and key.value_offset in _GEOTIFF_UNITS:
                    return _GEOTIFF_UNITS[key.value_offset], '', 'GeoTIFF ProjLinearUnitsGeoKey'
    except Exception:  # a CRS record pyproj cannot parse: as if none
        crs = None
    if crs is not None:
        axes = [a for a in crs.axis_info if a.unit_conversion_factor]
        if axes:
            return float(axes[0].unit_conversion_factor), str(crs.name), 'the file\'s CRS'
        return 1.0, str(crs.name), 'the file\'s CRS (no axis unit: metres)'
    return 1.0, '', 'no CRS in the file: metres assumed'


def read_trajectory(path: str | os.PathLike[str], crs_of: Any = None
                    ) -> tuple[np.ndarray, np.ndarray]:
    """Sensor positions over time: ``(times (K,), xyz (K, 3))`` float64, time-sorted.

    A CSV holds ``t,x,y,z`` rows in the survey's CRS and units (a header row is skipped). An
    SBET (``.sbet`` / ``.out``) holds geographic positions, projected into the survey's CRS
    (``crs_of``: a pyproj CRS) with pyproj.

    Raises:
        BagError: missing, unreadable or malformed file, fewer than two samples.
    """
    p = Path(path)
    if not p.is_file():
        raise BagError(f'trajectory {p} not found')
    suffix = p.suffix.lower()
    try:
        if suffix in ('.sbet', '.out'):
            raw = np.fromfile(p, dtype='<f8')
            if raw.size == 0 or raw.size % _SBET_FIELDS:
                raise BagError(f'trajectory {p}: not an SBET file ({raw.size * 8} bytes is not '
                               f'a whole number of {_SBET_FIELDS * 8}-byte records)')
            rec = raw.reshape(-1, _SBET_FIELDS)
            if crs_of is None:
                raise BagError(f'trajectory {p}: an SBET is geographic, and the survey has no '
                               'CRS to project it into')
            try:
                from pyproj import Transformer
            except ImportError:
                raise BagError('an SBET trajectory needs pyproj to project it: pip install '
                               'pyproj') from None
            tr = Transformer.from_crs('EPSG:4979', crs_of, always_xy=True)
            x, y, z = tr.transform(np.degrees(rec[:, 2]), np.degrees(rec[:, 1]), rec[:, 3])
            times, xyz = rec[:, 0], np.column_stack([x, y, z])
        else:
            text = p.read_text(encoding='utf-8').splitlines()
            rows = [r for r in text if r.strip() and not r.lstrip().startswith('#')]
            try:
                float(rows[0].split(',')[0])
            except (ValueError, IndexError):
                rows = rows[1:]  # a header row
            data = np.array([[float(v) for v in r.split(',')[:4]] for r in rows], np.float64)
            if data.ndim != 2 or data.shape[1] != 4:
                raise BagError(f'trajectory {p}: expected rows t,x,y,z')
            times, xyz = data[:, 0], data[:, 1:]
    except (OSError, UnicodeDecodeError) as err:
        raise BagError(f'cannot read trajectory {p}: {err}') from err
    except ValueError as err:
        raise BagError(f'trajectory {p}: not numbers t,x,y,z ({err})') from err
    ok = np.all(np.isfinite(xyz), axis=1) & np.isfinite(times)
    times, xyz = times[ok], xyz[ok]
    if len(times) < 2:
        raise BagError(f'trajectory {p}: fewer than two valid samples')
    order = np.argsort(times, kind='stable')
    return times[order], xyz[order]


def derive_trajectory(points: np.ndarray, times: np.ndarray, scan_angle: np.ndarray,
                      line_id: np.ndarray) -> tuple[np.ndarray, np.ndarray, int]:
    """Sensor positions from GPS time and scan angle (see the module docstring).

    Args:
        points: (N, 3) float64 returns in a metric frame, time-sorted.
        times: (N,) GPS times [s].
        scan_angle: (N,) scan angles from nadir [deg], positive right of the track.
        line_id: (N,) flight line of each return (``point_source_id``).

    Returns:
        ``(times (K,), xyz (K, 3), lines)``: samples at :data:`DERIVED_RATE` over each line.

    Raises:
        BagError: a line too short, or without spread in scan angle, to be solved.
    """
    new = np.concatenate([[True], (np.diff(times) > LINE_GAP) | (np.diff(line_id) != 0)])
    seg = np.cumsum(new) - 1
    out_t, out_x = [], []
    for s in range(int(seg[-1]) + 1 if len(seg) else 0):
        idx = np.flatnonzero(seg == s)
        if len(idx) < 50:
            continue  # a few stray returns: their rays are left to the neighbours' poses
        t, p, tan = times[idx], points[idx], np.tan(np.radians(scan_angle[idx]))
        span = float(t[-1] - t[0])
        if span <= 0 or np.ptp(tan) < math.tan(math.radians(2.0)):
            raise BagError(f'cannot derive sensor origins for flight line {int(line_id[idx[0]])}'
                           ': its scan angles do not spread (give --trajectory)')
        # the track's direction: the returns' centroid moving with time
        tc = t - t.mean()
        vel = np.array([np.polyfit(tc, p[:, k], 1)[0] for k in range(2)])
        speed = float(np.hypot(*vel))
        if not math.isfinite(speed) or speed <= 0:
            raise BagError('cannot derive sensor origins: the returns do not move along a '
                           'track (give --trajectory)')
        a = vel / speed
        # c . p + z tan(theta) = c . s + z_s tan(theta): a line in tan(theta), for c the
        # side positive angles point to; systems differ on which side that is, and only one
        # puts the sensor above its returns
        top = float(p[:, 2].max())
        for c in (np.array([a[1], -a[0]]), np.array([-a[1], a[0]])):  # right, then left
            zs, q = np.polyfit(tan, p[:, :2] @ c + p[:, 2] * tan, 1)
            if zs > top:
                break
        else:
            raise BagError(f'cannot derive sensor origins for flight line '
                           f'{int(line_id[idx[0]])}: no sensor height above the returns fits '
                           'its scan angles (give --trajectory)')
        along = np.polyfit(tc, p[:, :2] @ a, 1)
        ts = np.arange(t[0], t[-1] + 1.0 / DERIVED_RATE, 1.0 / DERIVED_RATE)
        pa = np.polyval(along, ts - t.mean())
        xy = pa[:, None] * a[None, :] + q * c[None, :]
        out_t.append(ts)
        out_x.append(np.column_stack([xy, np.full(len(ts), zs)]))
    if not out_t:
        raise BagError('cannot derive sensor origins: no flight line with enough returns '
                       '(give --trajectory)')
    tt = np.concatenate(out_t)
    xx = np.concatenate(out_x)
    order = np.argsort(tt, kind='stable')
    return tt[order], xx[order], len(out_t)


def read_survey(path: str | os.PathLike[str],
                trajectory: str | os.PathLike[str] | None = None,
                log: Any = None) -> Survey:
    """A LAS / LAZ file and its sensor trajectory in a local metric frame.

    Args:
        path: the survey file.
        trajectory: CSV or SBET of the sensor positions; None: derived from GPS time and scan
            angle (stated in ``notes`` and logged).
        log: called with one line per assumption made (default: none).

    Raises:
        BagError: a missing, unreadable or unsuitable file (no GPS time, no returns).
    """
    try:
        import laspy
    except ImportError:
        raise BagError('reading LAS/LAZ needs laspy: pip install "laspy[lazrs]"') from None
    p = Path(path)
    if not p.is_file():
        raise BagError(f'survey {p} not found')
    try:
        las = laspy.read(p)
    except Exception as err:  # laspy and lazrs raise their own kinds on a bad file
        raise BagError(f'cannot read survey {p}: {type(err).__name__}: {err}') from err
    names = set(las.point_format.dimension_names)
    if 'gps_time' not in names:
        raise BagError(f'survey {p}: point format {las.point_format.id} has no GPS time')
    notes: list[str] = []
    say = log if log is not None else (lambda _line: None)
    scale, crs_name, how = _linear_unit(las.header)
    if scale != 1.0:
        notes.append(f'coordinates in units of {scale:g} m ({how}); converted to metres, '
                     'heights assumed in the same unit')
    elif 'assumed' in how:
        notes.append(how)
    xyz = np.column_stack([np.asarray(las.x, np.float64), np.asarray(las.y, np.float64),
                           np.asarray(las.z, np.float64)])
    times = np.asarray(las.gps_time, np.float64)
    ok = np.all(np.isfinite(xyz), axis=1) & np.isfinite(times)
    if not ok.any():
        raise BagError(f'survey {p}: no returns with finite coordinates and time')
    order = np.argsort(times, kind='stable')
    order = order[ok[order]]
    xyz, times = xyz[order], times[order]
    centre = 0.5 * (xyz.min(axis=0) + xyz.max(axis=0))
    step = ORIGIN_STEP / scale
    origin = np.array([math.floor(centre[0] / step) * step, math.floor(centre[1] / step) * step,
                       math.floor(centre[2] * scale) / scale])
    local = (xyz - origin) * scale
    if trajectory is not None:
        crs = None
        try:
            crs = las.header.parse_crs()
        except Exception:  # no pyproj or no CRS: only an SBET needs it, and says so
            pass
        tt, tx = read_trajectory(trajectory, crs)
        traj = (tx - origin) * scale
        source = f'{Path(trajectory).name}'
    else:
        angle_name = 'scan_angle' if 'scan_angle' in names else 'scan_angle_rank'
        angle = np.asarray(getattr(las, angle_name), np.float64)[order]
        if angle_name == 'scan_angle':
            angle = angle * 0.006  # LAS 1.4: units of 0.006 degrees
        lines = np.asarray(las.point_source_id, np.int64)[order] if 'point_source_id' in \
            names else np.zeros(len(order), np.int64)
        tt, traj, n_lines = derive_trajectory(local, times, angle, lines)
        source = f'derived from GPS time and scan angle ({n_lines} flight line(s))'
        notes.append(DERIVED_ASSUMPTION)
        say(DERIVED_ASSUMPTION)
    for line in notes:
        if line != DERIVED_ASSUMPTION:
            say(line)
    return Survey(path=p, points=local, times=times, traj_times=tt, traj_xyz=traj,
                  origin=origin, metres_per_unit=scale, crs=crs_name,
                  trajectory_source=source, notes=notes)
