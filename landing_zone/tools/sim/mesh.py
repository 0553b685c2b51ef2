"""Triangle meshes whose every face carries the class of what it is (ground, grass, obstacle).

A deliberately small container (flat float32 vertices, uint32 faces, one uint8 label per face):
the simulator builds hundreds of thousands of grass triangles per scene with vectorised numpy and
hands the arrays to Embree as they are, so a general mesh library's bookkeeping (vertex merging,
caches, validation) would only cost time. trimesh is used where its algorithms help (hulls,
tori, boxes: see :mod:`landing_zone.tools.sim.obstacles`).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ['GROUND', 'GRASS', 'OBSTACLE', 'NO_RETURN', 'CLASS_NAMES', 'Mesh']

# Class ids of faces and of the returns that hit them.
GROUND = 0
GRASS = 1
OBSTACLE = 2
NO_RETURN = 255  # a ray that hit nothing (never stored in a dataset)
CLASS_NAMES = ('ground', 'grass', 'obstacle')


@dataclass
class Mesh:
    """Triangles with a class id per face.

    Attributes:
        vertices: (V, 3) float32 vertex positions [m].
        faces: (F, 3) uint32 vertex indices, counter-clockwise seen from outside.
        labels: (F,) uint8 class id of each face (GROUND, GRASS or OBSTACLE).
    """

    vertices: np.ndarray
    faces: np.ndarray
    labels: np.ndarray

    def __post_init__(self) -> None:
        self.vertices = np.ascontiguousarray(self.vertices, dtype=np.float32).reshape(-1, 3)
        self.faces = np.ascontiguousarray(self.faces, dtype=np.uint32).reshape(-1, 3)
        self.labels = np.ascontiguousarray(self.labels, dtype=np.uint8).reshape(-1)
        if len(self.labels) != len(self.faces):
            raise ValueError(f'{len(self.labels)} labels for {len(self.faces)} faces')

    @classmethod
    def empty(cls) -> 'Mesh':
        return cls(np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0))

    @classmethod
    def from_arrays(cls, vertices: np.ndarray, faces: np.ndarray, label: int) -> 'Mesh':
        """A mesh whose faces all carry one class id."""
        faces = np.asarray(faces).reshape(-1, 3)
        return cls(vertices, faces, np.full(len(faces), label, dtype=np.uint8))

    @classmethod
    def concat(cls, meshes: list['Mesh']) -> 'Mesh':
        """One mesh holding all faces of ``meshes`` (face order preserved)."""
        meshes = [m for m in meshes if len(m.faces)]
        if not meshes:
            return cls.empty()
        offsets = np.cumsum([0] + [len(m.vertices) for m in meshes[:-1]])
        return cls(np.concatenate([m.vertices for m in meshes]),
                   np.concatenate([m.faces + np.uint32(o) for m, o in zip(meshes, offsets)]),
                   np.concatenate([m.labels for m in meshes]))

    @property
    def n_faces(self) -> int:
        return len(self.faces)

    def triangles(self) -> np.ndarray:
        """(F, 3, 3) float64 corner coordinates of every face."""
        return self.vertices.astype(np.float64)[self.faces]

    def face_normals(self) -> np.ndarray:
        """(F, 3) unit normals (zero for degenerate faces)."""
        tri = self.triangles()
        n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        norm = np.linalg.norm(n, axis=1, keepdims=True)
        return np.divide(n, norm, out=np.zeros_like(n), where=norm > 0)

    def bounds(self) -> np.ndarray:
        """(2, 3) lower and upper corner of the axis-aligned bounding box."""
        if not len(self.vertices):
            return np.zeros((2, 3))
        return np.stack([self.vertices.min(axis=0), self.vertices.max(axis=0)]).astype(float)
