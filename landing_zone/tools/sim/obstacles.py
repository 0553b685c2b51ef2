"""The obstacle library: boxes (synth1), rocks, tires and cinder blocks (synth2), and placement.

Every model is a procedural mesh, fixed (the library does not depend on any user seed), in a
local frame whose footprint is centred on the origin and whose lowest point is at z = 0:

* ``box``: the (0.15 m)^3 cube of synth1.
* ``rock_00`` .. ``rock_11``: noisy convex hulls of points on a randomly proportioned ellipsoid,
  subdivided once with the new vertices pushed inwards (shallow dents: convex-ish, not a
  polyhedron), with a flattened bed; 15 to 40 cm high, under 50 cm across.
* ``tire_a`` (a wheelbarrow tire standing upright) and ``tire_b`` (a small tire lying flat):
  tori with flattened (tread-like) cross sections.
* ``cinder_block_a`` (a standard two-core block standing, cores vertical) and
  ``cinder_block_b`` (a three-core block on its side, cores horizontal): outer walls and webs as
  boxes, so the cores are real holes a ray can pass into.

Models are split into a train and a test group so that no model appears in both halves of
synth2: rocks 0-7, tire A and block A train; rocks 8-11, tire B and block B test.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.mesh import OBSTACLE, Mesh
from landing_zone.tools.sim.terrain import Terrain

__all__ = ['KINDS', 'ObstacleModel', 'Obstacle', 'library', 'models', 'get_model', 'place',
           'at_edge', 'MAX_HEIGHT', 'MIN_HEIGHT', 'MAX_ACROSS']

KINDS = ('box', 'rock', 'tire', 'cinder_block')
MIN_HEIGHT = 0.15  # [m] synth2 obstacles are at least this high ...
MAX_HEIGHT = 0.40  # ... at most this high ...
MAX_ACROSS = 0.50  # ... and less than this across (largest horizontal extent)

# The twelve rocks: height [m] and proportions (length : width : height of the ellipsoid the
# hull is drawn around), chosen so that the library holds distinct forms (slabs, pillars,
# elongated stones, round boulders, mounds) and both groups hold small and large rocks.
_ROCKS = (
    (0.16, (1.00, 0.80, 0.30)),  # 0 flat slab
    (0.22, (1.00, 0.40, 0.45)),  # 1 elongated stone
    (0.30, (1.00, 0.90, 0.90)),  # 2 round boulder
    (0.38, (0.55, 0.45, 1.00)),  # 3 pillar
    (0.19, (1.00, 0.60, 0.60)),  # 4 cobble
    (0.26, (1.00, 0.95, 0.45)),  # 5 broad mound
    (0.34, (1.00, 0.70, 0.80)),  # 6 lumpy boulder
    (0.24, (1.00, 0.35, 0.75)),  # 7 slab on its edge
    (0.17, (1.00, 0.85, 0.75)),  # 8 small round stone
    (0.28, (1.00, 0.50, 0.65)),  # 9 long boulder
    (0.36, (0.80, 0.75, 1.00)),  # 10 tall boulder
    (0.21, (1.00, 0.75, 0.40)),  # 11 flat stone
)
_N_TRAIN_ROCKS = 8


@dataclass(frozen=True)
class ObstacleModel:
    """One shape of the library, in its local frame (footprint centred, lowest point z = 0).

    Attributes:
        name: unique name, e.g. ``rock_03``.
        kind: one of :data:`KINDS`.
        group: ``train``, ``test`` or ``both`` (models used by both splits: the synth1 box).
        vertices: (V, 3) float64 vertex positions [m].
        faces: (F, 3) int64 vertex indices, counter-clockwise seen from outside.
        embed: how deep the model sits in the ground when placed [m].
    """

    name: str
    kind: str
    group: str
    vertices: np.ndarray
    faces: np.ndarray
    embed: float = 0.0

    @property
    def size(self) -> tuple[float, float, float]:
        """Extents (dx, dy, dz) of the model's bounding box in its own frame [m]."""
        ext = self.vertices.max(axis=0) - self.vertices.min(axis=0)
        return (float(ext[0]), float(ext[1]), float(ext[2]))

    @property
    def radius(self) -> float:
        """Largest horizontal distance of a vertex from the model's origin [m]."""
        return float(np.max(np.hypot(self.vertices[:, 0], self.vertices[:, 1])))

    @property
    def across(self) -> float:
        """Largest horizontal distance between two vertices (the width of its footprint) [m]."""
        from scipy.spatial import ConvexHull
        xy = self.vertices[:, :2]
        hull = xy[ConvexHull(xy).vertices]
        return float(np.max(np.linalg.norm(hull[:, None] - hull[None], axis=-1)))


@dataclass(frozen=True)
class Obstacle:
    """A model placed in the world: rotated by ``yaw`` about z, its origin moved to (x, y, z)."""

    model: ObstacleModel
    x: float
    y: float
    z: float
    yaw: float

    def vertices(self) -> np.ndarray:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        rot = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        return self.model.vertices @ rot.T + np.array([self.x, self.y, self.z])

    def mesh(self) -> Mesh:
        """The placed obstacle as triangles labelled OBSTACLE."""
        return Mesh.from_arrays(self.vertices(), self.model.faces, OBSTACLE)

    def footprint(self) -> np.ndarray:
        """(K, 2) convex hull of the obstacle's vertices seen from above, counter-clockwise."""
        from scipy.spatial import ConvexHull
        xy = self.vertices()[:, :2]
        return xy[ConvexHull(xy).vertices]

    def to_json(self) -> dict:
        """The record of docs/INTERFACES.md §3 (plus the model's name)."""
        return {'kind': self.model.kind, 'model': self.model.name,
                'x': round(self.x, 4), 'y': round(self.y, 4), 'z': round(self.z, 4),
                'yaw': round(self.yaw, 4), 'size': [round(v, 4) for v in self.model.size]}


def _normalise(vertices: np.ndarray) -> np.ndarray:
    """Centre the footprint's bounding box on the origin and put the lowest point at z = 0."""
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    return vertices - np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])


def _box_parts(parts: list[tuple[tuple[float, float, float], tuple[float, float, float]]]
               ) -> tuple[np.ndarray, np.ndarray]:
    """Boxes given as (centre, extents) joined into one vertex/face list."""
    import trimesh
    verts, faces, offset = [], [], 0
    for centre, extents in parts:
        box = trimesh.creation.box(extents=extents)
        verts.append(np.asarray(box.vertices) + np.asarray(centre))
        faces.append(np.asarray(box.faces) + offset)
        offset += len(box.vertices)
    return np.concatenate(verts), np.concatenate(faces)


def _box(edge: float = 0.15) -> tuple[np.ndarray, np.ndarray]:
    return _box_parts([((0.0, 0.0, 0.0), (edge, edge, edge))])


def _rock(index: int) -> tuple[np.ndarray, np.ndarray]:
    from landing_zone.tools.sim.shapes import flatten_bed, noisy_hull
    rng = np.random.default_rng(20150526 + 7919 * index)
    height, proportions = _ROCKS[index]
    v, f = noisy_hull(rng, proportions)
    v = flatten_bed(v)  # rocks settle on a flattish bed
    # A random yaw of the shape itself, so the rocks' long axes do not all lie along x.
    yaw = rng.uniform(0.0, np.pi)
    c, s = math.cos(yaw), math.sin(yaw)
    v = v @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T
    v = _normalise(v)
    # Scale to the rock's height; shrink horizontally if it would be too wide.
    v *= height / v[:, 2].max()
    r = np.max(np.hypot(v[:, 0], v[:, 1]))
    if 2.0 * r > 0.94 * MAX_ACROSS:
        v[:, :2] *= 0.94 * MAX_ACROSS / (2.0 * r)
    return v, np.asarray(f)


def _tire(major: float, tube: float, flatten: float, upright: bool,
          ) -> tuple[np.ndarray, np.ndarray]:
    import trimesh
    torus = trimesh.creation.torus(major_radius=major, minor_radius=tube,
                                   major_sections=48, minor_sections=16)
    v = np.asarray(torus.vertices, dtype=float)
    # Flatten the tube's cross section along the axis: a tire is wider than a round tube.
    v[:, 2] *= flatten
    if upright:
        v = v[:, [0, 2, 1]]
        f = np.asarray(torus.faces)[:, ::-1]  # the axis swap mirrors: keep faces outward
    else:
        f = np.asarray(torus.faces)
    return _normalise(v), f


def _cinder_block(length: float, width: float, height: float, cores: int, wall: float,
                  web: float, on_side: bool) -> tuple[np.ndarray, np.ndarray]:
    # Along x: end wall, (core, web) * (cores - 1), core, end wall; along y: two side walls.
    core = (length - 2 * wall - (cores - 1) * web) / cores
    parts = [((0.0, (width - wall) / 2, 0.0), (length, wall, height)),
             ((0.0, -(width - wall) / 2, 0.0), (length, wall, height))]
    inner = width - 2 * wall
    x = -length / 2
    for k in range(cores + 1):
        thick = wall if k in (0, cores) else web
        parts.append(((x + thick / 2, 0.0, 0.0), (thick, inner, height)))
        x += thick + core
    v, f = _box_parts(parts)
    if on_side:
        v = v[:, [0, 2, 1]]
        f = f[:, ::-1]
    return _normalise(v), f


@functools.lru_cache(maxsize=1)
def library() -> dict[str, ObstacleModel]:
    """All models by name (built once per process)."""
    out: dict[str, ObstacleModel] = {}
    v, f = _box(0.15)
    out['box'] = ObstacleModel('box', 'box', 'both', _normalise(v), f)
    for k in range(len(_ROCKS)):
        v, f = _rock(k)
        group = 'train' if k < _N_TRAIN_ROCKS else 'test'
        out[f'rock_{k:02d}'] = ObstacleModel(f'rock_{k:02d}', 'rock', group, v, f,
                                             embed=0.1 * float(v[:, 2].max()))
    v, f = _tire(major=0.14, tube=0.05, flatten=0.9, upright=True)
    out['tire_a'] = ObstacleModel('tire_a', 'tire', 'train', v, f, embed=0.02)
    v, f = _tire(major=0.16, tube=0.075, flatten=1.1, upright=False)
    out['tire_b'] = ObstacleModel('tire_b', 'tire', 'test', v, f)
    v, f = _cinder_block(0.39, 0.19, 0.19, cores=2, wall=0.032, web=0.026, on_side=False)
    out['cinder_block_a'] = ObstacleModel('cinder_block_a', 'cinder_block', 'train', v, f)
    v, f = _cinder_block(0.44, 0.215, 0.215, cores=3, wall=0.03, web=0.025, on_side=True)
    out['cinder_block_b'] = ObstacleModel('cinder_block_b', 'cinder_block', 'test', v, f)
    return out


def models(kinds: tuple[str, ...] | list[str] | None = None,
           group: str | None = None) -> list[ObstacleModel]:
    """Models of the given kinds (all if None) usable in ``group`` ('train', 'test', None)."""
    if kinds is not None:
        unknown = [k for k in kinds if k not in KINDS]
        if unknown:
            from landing_zone.tools.sim.families import FAMILIES
            hint = (f' ({unknown[0]!r} is an obstacle family: give it as a family, e.g. '
                    f'--families {unknown[0]})' if unknown[0] in FAMILIES else '')
            raise SimulationError(f'unknown obstacle kind {unknown[0]!r}; choose from '
                                  f'{", ".join(KINDS)}{hint}')
    if group not in (None, 'train', 'test'):
        raise SimulationError(f"obstacle group must be 'train' or 'test', got {group!r}")
    return [m for m in library().values()
            if (kinds is None or m.kind in kinds)
            and (group is None or m.group in (group, 'both'))]


def get_model(name: str) -> ObstacleModel:
    """The model called ``name``: a library model or an obstacle family's instance
    (``FAMILY/INDEX``, see :mod:`landing_zone.tools.sim.families`)."""
    lib = library()
    if name not in lib and '/' in name:
        from landing_zone.tools.sim.families import instance_model, is_instance_name
        if is_instance_name(name):
            return instance_model(name)
    if name not in lib:
        raise SimulationError(f'unknown obstacle model {name!r}; choose from '
                              f'{", ".join(lib)}')
    return lib[name]


def place(model: ObstacleModel, x: float, y: float, yaw: float, terrain: Terrain) -> Obstacle:
    """Set ``model`` on the ground at (x, y) turned by ``yaw``.

    It rests at the lowest ground height under its footprint (so no part floats), sunk by the
    model's ``embed`` depth (rocks are partly buried).
    """
    probe = Obstacle(model, x, y, 0.0, yaw)
    fp = probe.footprint()
    # Ground under the footprint: its corners, edge midpoints and centre.
    pts = np.concatenate([fp, 0.5 * (fp + np.roll(fp, -1, axis=0)), [[x, y]]])
    z = float(np.min(terrain.height(pts[:, 0], pts[:, 1]))) - model.embed
    return Obstacle(model, float(x), float(y), z, float(yaw))


def at_edge(model: ObstacleModel, yaw: float, side: int, along: float, half: float,
            tall: float, reach: float | None = None, gap: float | None = None
            ) -> tuple[float, float]:
    """Where ``model`` turned by ``yaw`` stands at one edge of the square [-half, half]^2
    (``side`` 0, 1, 2, 3: the +x, +y, -x, -y edge): with ``reach``, its part standing ``tall``
    above its base (its top half, if lower) reaches that far into the square; with ``gap``, its
    whole footprint stands that far beyond the edge. In both, that part's innermost vertex lies
    ``along`` the edge (the coordinate across the edge's normal). Returns its (x, y).
    """
    if (reach is None) == (gap is None):
        raise SimulationError('at_edge: give either reach or gap')
    v = Obstacle(model, 0.0, 0.0, 0.0, yaw).vertices()
    a = 0.5 * math.pi * side
    out = np.array([math.cos(a), math.sin(a)])  # the edge's outward normal
    lateral = np.array([-out[1], out[0]])
    depth = v[:, :2] @ out
    above = v[:, 2] - model.embed
    standing = np.flatnonzero(above >= min(tall, 0.5 * float(above.max())))
    k = standing[np.argmin(depth[standing])]
    n = half - reach - depth[k] if reach is not None else half + gap - depth.min()
    xy = n * out + (along - v[k, :2] @ lateral) * lateral
    return float(xy[0]), float(xy[1])
