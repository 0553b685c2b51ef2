"""An obstacle: a model in its own frame, the same model placed in the world, and placing it.

A model's mesh is in a local frame whose footprint is centred on the origin and whose lowest
point is at z = 0. The fixed models of synth1 and synth2 are in
:mod:`~landing_zone.tools.sim.library`, the generated ones in
:mod:`~landing_zone.tools.sim.families`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.mesh import OBSTACLE, Mesh
from landing_zone.tools.sim.terrain import Terrain

__all__ = ['ObstacleModel', 'Obstacle', 'place', 'at_edge']


@dataclass(frozen=True)
class ObstacleModel:
    """One shape of the library, in its local frame (footprint centred, lowest point z = 0).

    Attributes:
        name: unique name, e.g. ``rock_03``.
        kind: a kind of the library (:data:`~landing_zone.tools.sim.library.KINDS`) or a
            family's name.
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
        xy = self.vertices()[:, :2]
        return xy[ConvexHull(xy).vertices]

    def to_json(self) -> dict:
        """The record of docs/INTERFACES.md §3 (plus the model's name)."""
        return {'kind': self.model.kind, 'model': self.model.name,
                'x': round(self.x, 4), 'y': round(self.y, 4), 'z': round(self.z, 4),
                'yaw': round(self.yaw, 4), 'size': [round(v, 4) for v in self.model.size]}


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
