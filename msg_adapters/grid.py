"""An assessment -> the node's output messages (docs/INTERFACES.md §1).

Every builder takes a :class:`~msg_adapters.MessageTypes` (or ``'rclpy'`` / ``'rosbags'`` / a
rosbags typestore), so the node publishes rclpy messages and replay writes rosbags messages of
the same content into its .mcap:

* :func:`safety_grid`: ``nav_msgs/OccupancyGrid``, one cell per tile, value
  ``round(100 * (1 - p_safe))`` (0 surely safe, 100 surely unsafe), -1 unknown.
* :func:`safety_cloud`: ``sensor_msgs/PointCloud2``, one point per tile with a ground estimate,
  at (tile centre x, y, ground z), FLOAT32 fields x, y, z, p_safe (NaN unknown), confidence,
  then slope_deg, roughness and clearance of the tile's ground (NaN without a ground plane).
* :func:`landing_site_poses`: ``geometry_msgs/PoseArray``, best first, at the ground, each
  oriented with its z axis along the footprint's ground normal.
* :func:`landing_sites_cloud`: ``sensor_msgs/PointCloud2``, the same sites in the same order, one
  point each at (x, y, ground z), FLOAT32 fields x, y, z, p_safe, slope_deg, step, clearance: what
  a planner reads live to act on a site.
* :func:`markers`: ``visualization_msgs/MarkerArray``: the tiles as a cube list coloured from
  green (safe) through yellow to red (unsafe), grey unknown; a disc of the footprint per site;
  over every candidate left out for a reason other than ``unknown``, that reason as text.
* :func:`diagnostics`: ``diagnostic_msgs/DiagnosticArray`` of key/value strings.

rosbags message classes need every field; :func:`build` fills the ones a builder leaves out
with the message definition's defaults (zeros, empty strings and sequences), as rclpy does.
"""
from __future__ import annotations

import array
import math
from typing import TYPE_CHECKING, Any

import numpy as np

from msg_adapters import MessageTypes, as_message_types, make_header, ns_to_stamp
from msg_adapters.pointcloud import make_cloud, points_to_structured

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

    from landing_zone.assessor import Assessment

__all__ = [
    'OUTPUT_TYPES',
    'build',
    'grid_values',
    'safety_grid',
    'safety_cloud',
    'landing_site_poses',
    'landing_sites_cloud',
    'SITE_FIELDS',
    'markers',
    'reason_text',
    'diagnostics',
]

# Output topic (relative to the node's private namespace) -> message type.
OUTPUT_TYPES = {
    'safety_grid': 'nav_msgs/msg/OccupancyGrid',
    'safety_cloud': 'sensor_msgs/msg/PointCloud2',
    'landing_sites': 'geometry_msgs/msg/PoseArray',
    'landing_sites_cloud': 'sensor_msgs/msg/PointCloud2',
    'markers': 'visualization_msgs/msg/MarkerArray',
}
DIAGNOSTICS_TYPE = 'diagnostic_msgs/msg/DiagnosticArray'

_NUMPY_OF = {'bool': np.bool_, 'byte': np.uint8, 'char': np.uint8, 'octet': np.uint8,
             'int8': np.int8, 'uint8': np.uint8, 'int16': np.int16, 'uint16': np.uint16,
             'int32': np.int32, 'uint32': np.uint32, 'int64': np.int64, 'uint64': np.uint64,
             'float32': np.float32, 'float64': np.float64}
_UNKNOWN_RGBA = (0.5, 0.5, 0.5, 0.6)
_MARKER_CUBE_LIST, _MARKER_CYLINDER, _MARKER_DELETEALL, _MARKER_TEXT = 6, 3, 3, 9
# Colour of the text over a rejected candidate, per first reason.
_REASON_RGBA = {'obstacle': (1.0, 0.3, 0.3, 0.9), 'slope': (1.0, 0.6, 0.0, 0.9),
                'step': (0.8, 0.3, 1.0, 0.9), 'clearance': (0.2, 0.8, 1.0, 0.9)}
_DIAG_LEVELS = {'OK': 0, 'WARN': 1, 'ERROR': 2, 'STALE': 3}


# --- building messages of either implementation -----------------------------------------------

def _base_default(typename: str) -> Any:
    if typename in ('string', 'wstring'):
        return ''
    if typename == 'bool':
        return False
    if typename.startswith('float'):
        return 0.0
    return 0


def _rosbags_default(store: Typestore, msgtype: str) -> dict[str, Any]:
    """Every field of a rosbags message type at its default, by name."""
    from rosbags.typesys.store import Nodetype

    if msgtype == 'geometry_msgs/msg/Quaternion':
        # the one default value in the definitions used here (`float64 w 1`), which the
        # typestore's field definitions do not carry
        return {'x': 0.0, 'y': 0.0, 'z': 0.0, 'w': 1.0}
    out: dict[str, Any] = {}
    for name, (kind, desc) in store.fielddefs[msgtype][1]:
        if kind == Nodetype.BASE:
            out[name] = _base_default(desc[0])
        elif kind == Nodetype.NAME:
            out[name] = store.types[desc](**_rosbags_default(store, desc))
        else:  # ARRAY (fixed length) or SEQUENCE
            (sub_kind, sub_desc), length = desc
            n = length if kind == Nodetype.ARRAY else 0
            if sub_kind == Nodetype.BASE and sub_desc[0] in _NUMPY_OF:
                out[name] = np.zeros(n, _NUMPY_OF[sub_desc[0]])
            elif sub_kind == Nodetype.BASE:
                out[name] = [_base_default(sub_desc[0])] * n
            else:
                out[name] = [store.types[sub_desc](**_rosbags_default(store, sub_desc))
                             for _ in range(n)]
    return out


def build(types: MessageTypes, msgtype: str, **fields: Any) -> Any:
    """A message with the given fields, the others at their defaults (either implementation)."""
    if types.kind == 'rosbags':
        assert types.typestore is not None
        full = _rosbags_default(types.typestore, msgtype)
        unknown = set(fields) - set(full)
        if unknown:
            raise TypeError(f'{msgtype} has no field(s) {", ".join(sorted(unknown))}')
        full.update(fields)
        return types.build(msgtype, **full)
    return types.build(msgtype, **fields)


def _int8_array(types: MessageTypes, values: np.ndarray) -> Any:
    data = np.ascontiguousarray(values, np.int8)
    if types.kind == 'rclpy':
        out = array.array('b')
        out.frombytes(data.tobytes())
        return out
    return data


def _byte(types: MessageTypes, value: int) -> Any:
    # rclpy's `byte` fields hold a bytes object of length 1, rosbags' an int
    return bytes([value]) if types.kind == 'rclpy' else int(value)


def _point(types: MessageTypes, x: float, y: float, z: float) -> Any:
    return types.build('geometry_msgs/msg/Point', x=float(x), y=float(y), z=float(z))


def _pose(types: MessageTypes, x: float, y: float, z: float,
          q: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)) -> Any:
    return types.build('geometry_msgs/msg/Pose', position=_point(types, x, y, z),
                       orientation=types.build('geometry_msgs/msg/Quaternion', x=float(q[0]),
                                               y=float(q[1]), z=float(q[2]), w=float(q[3])))


def _color(types: MessageTypes, rgba: tuple[float, float, float, float]) -> Any:
    r, g, b, a = (float(v) for v in rgba)
    return types.build('std_msgs/msg/ColorRGBA', r=r, g=g, b=b, a=a)


# --- the outputs ---------------------------------------------------------------------------

def grid_values(assessment: Assessment) -> np.ndarray:
    """OccupancyGrid cell values: (X, Y) int8, ``round(100 * (1 - p_safe))``, -1 unknown."""
    p = assessment.grid(assessment.p_safe).astype(np.float64)
    known = np.isfinite(p)
    out = np.full(p.shape, -1, np.int8)
    out[known] = np.rint(100.0 * (1.0 - np.clip(p[known], 0.0, 1.0))).astype(np.int8)
    return out


def _grid_height(assessment: Assessment) -> float:
    """Height to draw the grid at: the median ground of the tiles (0 if none is known)."""
    gz = assessment.ground_z[np.isfinite(assessment.ground_z)]
    return float(np.median(gz)) if gz.size else 0.0


def safety_grid(assessment: Assessment, stamp_ns: int,
                types: MessageTypes | Typestore | str = 'rclpy') -> Any:
    """The ``nav_msgs/OccupancyGrid`` of the tiles (cell (i, j) = tile ``origin + (i, j)``).

    The grid's x axis is the fixed frame's x (``info.width`` = tiles along x), rows run along
    y, and ``info.origin`` is the lower corner of tile ``origin`` at the median ground height.
    """
    types = as_message_types(types)
    values = grid_values(assessment)  # (X, Y)
    nx, ny = assessment.shape
    ts = assessment.tile_size
    info = types.build(
        'nav_msgs/msg/MapMetaData', map_load_time=ns_to_stamp(stamp_ns, types),
        resolution=float(ts), width=int(nx), height=int(ny),
        origin=_pose(types, assessment.origin[0] * ts, assessment.origin[1] * ts,
                     _grid_height(assessment)))
    # OccupancyGrid is row-major with x fastest: data[j * width + i]
    return types.build('nav_msgs/msg/OccupancyGrid',
                       header=make_header(stamp_ns, assessment.frame_id, types), info=info,
                       data=_int8_array(types, values.T.reshape(-1)))


def safety_cloud(assessment: Assessment, stamp_ns: int,
                 types: MessageTypes | Typestore | str = 'rclpy') -> Any:
    """One point per tile with a ground estimate: x, y, z, p_safe (NaN unknown), confidence,
    slope_deg [deg], roughness [m], clearance [m] (NaN where the tile has no ground plane)."""
    types = as_message_types(types)
    have = np.isfinite(assessment.ground_z)
    xyz = np.column_stack([assessment.centers[have], assessment.ground_z[have]])
    nan = np.full(len(assessment), np.nan, np.float32)

    def field_of(values: np.ndarray | None) -> np.ndarray:
        out: np.ndarray = (nan if values is None else values)[have].astype(np.float32)
        return out
    arr = points_to_structured(xyz, {
        'p_safe': assessment.p_safe[have].astype(np.float32),
        'confidence': assessment.confidence[have].astype(np.float32),
        'slope_deg': field_of(assessment.slope_deg),
        'roughness': field_of(assessment.roughness),
        'clearance': field_of(assessment.clearance)}, dtype=np.float32)
    return make_cloud(arr, make_header(stamp_ns, assessment.frame_id, types), types)


def landing_site_poses(assessment: Assessment, stamp_ns: int,
                       types: MessageTypes | Typestore | str = 'rclpy') -> Any:
    """The landing-site candidates as a ``geometry_msgs/PoseArray``, best first.

    Each pose is the footprint's centre on the ground (z 0 where the ground is unknown),
    oriented so its z axis is the ground normal under the footprint (the shortest rotation
    from the vertical: a disc has no heading, so no yaw).
    """
    from landing_zone.judging.sites import normal_quaternion

    types = as_message_types(types)
    poses = [_pose(types, s.x, s.y, 0.0 if math.isnan(s.z) else s.z,
                   normal_quaternion(s.normal)) for s in assessment.sites]
    return types.build('geometry_msgs/msg/PoseArray',
                       header=make_header(stamp_ns, assessment.frame_id, types), poses=poses)


# The fields of ~/landing_sites_cloud beside x, y, z (docs/INTERFACES.md §1).
SITE_FIELDS = ('p_safe', 'slope_deg', 'step', 'clearance')


def landing_sites_cloud(assessment: Assessment, stamp_ns: int,
                        types: MessageTypes | Typestore | str = 'rclpy') -> Any:
    """The landing sites of :func:`landing_site_poses`, in the same order, as a PointCloud2:
    one point per site at (x, y, ground z), FLOAT32 ``p_safe`` (P(every tile under the
    footprint safe)), ``slope_deg`` [deg], ``step`` [m] and ``clearance`` [m] (NaN unknown)."""
    types = as_message_types(types)
    sites = assessment.sites
    xyz = np.array([[s.x, s.y, s.z] for s in sites], np.float64).reshape(-1, 3)
    arr = points_to_structured(xyz, {
        name: np.array([getattr(s, name) for s in sites], np.float32) for name in SITE_FIELDS},
        dtype=np.float32)
    return make_cloud(arr, make_header(stamp_ns, assessment.frame_id, types), types)


def tile_colors(p_safe: np.ndarray) -> np.ndarray:
    """(T, 4) RGBA: red (p 0) -> yellow (0.5) -> green (1); grey where unknown."""
    p = np.asarray(p_safe, np.float64)
    known = np.isfinite(p)
    q = np.clip(np.where(known, p, 0.0), 0.0, 1.0)
    rgba = np.empty((p.size, 4))
    rgba[:, 0] = np.clip(2.0 * (1.0 - q), 0.0, 1.0)
    rgba[:, 1] = np.clip(2.0 * q, 0.0, 1.0)
    rgba[:, 2] = 0.0
    rgba[:, 3] = 0.8
    rgba[~known] = _UNKNOWN_RGBA
    return rgba


def markers(assessment: Assessment, stamp_ns: int, footprint_radius: float | None = None,
            types: MessageTypes | Typestore | str = 'rclpy') -> Any:
    """A ``visualization_msgs/MarkerArray``: clear, the coloured tiles, one disc per site, the
    reasons of the rejected candidates.

    The discs have the footprint's radius (default the assessment's ``footprint_radius``) and
    lie on the footprint's ground plane. Over each candidate left out for a reason other than
    ``unknown`` (namespace ``rejected``) a text names its reasons, e.g. ``slope 12.1 deg``.
    """
    from landing_zone.judging.sites import normal_quaternion
    types = as_message_types(types)
    if footprint_radius is None:
        footprint_radius = assessment.footprint_radius
    header = make_header(stamp_ns, assessment.frame_id, types)
    ts = float(assessment.tile_size)
    out = [build(types, 'visualization_msgs/msg/Marker', header=header, ns='',
                 id=0, action=_MARKER_DELETEALL)]
    have = np.isfinite(assessment.ground_z)
    centers = assessment.centers[have]
    gz = assessment.ground_z[have]
    colors = tile_colors(assessment.p_safe[have])
    out.append(build(
        types, 'visualization_msgs/msg/Marker', header=header, ns='tiles', id=0,
        type=_MARKER_CUBE_LIST, action=0, pose=_pose(types, 0.0, 0.0, 0.0),
        scale=types.build('geometry_msgs/msg/Vector3', x=0.95 * ts, y=0.95 * ts, z=0.02),
        color=_color(types, (1.0, 1.0, 1.0, 1.0)),
        points=[_point(types, x, y, z) for (x, y), z in zip(centers.tolist(), gz.tolist())],
        colors=[_color(types, tuple(c)) for c in colors.tolist()]))
    d = 2.0 * float(footprint_radius)
    for rank, site in enumerate(assessment.sites):
        z = 0.0 if math.isnan(site.z) else site.z
        out.append(build(
            types, 'visualization_msgs/msg/Marker', header=header, ns='landing_sites',
            id=rank, type=_MARKER_CYLINDER, action=0,
            pose=_pose(types, site.x, site.y, z + 0.05, normal_quaternion(site.normal)),
            scale=types.build('geometry_msgs/msg/Vector3', x=d, y=d, z=0.1),
            color=_color(types, (0.1, 0.4, 1.0, 0.5 if rank else 0.8))))
    if assessment.candidates is not None:
        grid_z = assessment.grid(assessment.ground_z)
        for n, entry in enumerate(assessment.candidates.rejected(include_unknown_only=False)):
            k = assessment.lookup(entry['x'], entry['y'])
            gz = float(grid_z.ravel()[k]) if k is not None else math.nan
            out.append(build(
                types, 'visualization_msgs/msg/Marker', header=header, ns='rejected', id=n,
                type=_MARKER_TEXT, action=0,
                pose=_pose(types, entry['x'], entry['y'], (0.0 if math.isnan(gz) else gz) + 0.3),
                scale=types.build('geometry_msgs/msg/Vector3', x=0.0, y=0.0, z=0.25),
                color=_color(types, _REASON_RGBA.get(entry['reasons'][0], (1.0, 1.0, 1.0, 0.9))),
                text=reason_text(entry)))
    return types.build('visualization_msgs/msg/MarkerArray', markers=out)


def reason_text(entry: dict[str, Any]) -> str:
    """One line naming a rejected candidate's reasons with their figures (a marker's text)."""
    parts = []
    for why in entry['reasons']:
        if why == 'slope' and entry.get('slope_deg') is not None:
            parts.append(f"slope {entry['slope_deg']:.1f} deg")
        elif why == 'step' and entry.get('step') is not None:
            parts.append(f"step {entry['step']:.2f} m")
        elif why == 'clearance' and entry.get('clearance') is not None:
            parts.append(f"clearance {entry['clearance']:.2f} m")
        else:
            parts.append(why)
    return ', '.join(parts)


def diagnostics(values: dict[str, str], stamp_ns: int, name: str = 'landing_zone: assessor',
                level: str = 'OK', message: str = '',
                types: MessageTypes | Typestore | str = 'rclpy') -> Any:
    """A ``diagnostic_msgs/DiagnosticArray`` with one status of key/value strings.

    Args:
        values: key -> value (strings).
        stamp_ns: header stamp [ns].
        name: the status's name.
        level: 'OK', 'WARN', 'ERROR' or 'STALE'.
        message: one line summarising the status.
        types: which message implementation to build.
    """
    types = as_message_types(types)
    if level not in _DIAG_LEVELS:
        raise ValueError(f'diagnostic level must be one of {", ".join(_DIAG_LEVELS)}, '
                         f'got {level!r}')
    kv = [types.build('diagnostic_msgs/msg/KeyValue', key=str(k), value=str(v))
          for k, v in values.items()]
    status = types.build('diagnostic_msgs/msg/DiagnosticStatus',
                         level=_byte(types, _DIAG_LEVELS[level]), name=name, message=message,
                         hardware_id='', values=kv)
    return types.build('diagnostic_msgs/msg/DiagnosticArray',
                       header=make_header(stamp_ns, '', types), status=[status])
