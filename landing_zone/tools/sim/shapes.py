"""Mesh building blocks of the obstacle families: bodies, rods, hulls, solids of revolution, poses.

A shape is a list of *bodies*, each a closed triangle surface built by trimesh (boxes,
cylinders, tori, convex hulls, revolved profiles, icospheres), joined into one vertex/face list
without merging vertices across bodies. Bodies may overlap (a pile of stones, a crate's slats
crossing its posts): the ray caster wants first hits only, so no boolean union is needed, and
trimesh's booleans need an external engine that is not among the dependencies. Every body is
watertight on its own, which is what the family tests check (``trimesh.Trimesh.split`` finds
the bodies again by face connectivity).
"""
from __future__ import annotations

import math
from typing import Iterable

import numpy as np

__all__ = ['Body', 'join', 'rotation', 'box', 'rod', 'polyline_rods', 'tube', 'noisy_hull',
           'flatten_bed', 'revolved', 'settle', 'fit', 'tilt', 'stack_height', 'heap', 'pick',
           'random_rotation', 'lying', 'Z_UP', 'normalise', 'box_parts', 'cinder_block']

Body = tuple[np.ndarray, np.ndarray]  # (V, 3) float64 vertices, (F, 3) int64 faces
Z_UP = np.array([0.0, 0.0, 1.0])


def _arrays(mesh: object) -> Body:
    return (np.asarray(mesh.vertices, dtype=np.float64).copy(),  # type: ignore[attr-defined]
            np.asarray(mesh.faces, dtype=np.int64).copy())  # type: ignore[attr-defined]


def join(bodies: Iterable[Body]) -> Body:
    """Bodies as one vertex/face list (faces re-indexed; vertices never merged)."""
    verts, faces, offset = [], [], 0
    for v, f in bodies:
        verts.append(np.asarray(v, dtype=np.float64))
        faces.append(np.asarray(f, dtype=np.int64) + offset)
        offset += len(v)
    if not verts:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    return np.concatenate(verts), np.concatenate(faces)


def rotation(axis: np.ndarray | Iterable[float], angle: float) -> np.ndarray:
    """3x3 rotation by ``angle`` [rad] about ``axis`` (Rodrigues)."""
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    k = np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])
    return np.eye(3) + math.sin(angle) * k + (1.0 - math.cos(angle)) * (k @ k)


def box(extents: Iterable[float], centre: Iterable[float] = (0.0, 0.0, 0.0),
        rot: np.ndarray | None = None) -> Body:
    """An axis-aligned box (turned by ``rot`` about its centre)."""
    import trimesh
    v, f = _arrays(trimesh.creation.box(extents=list(extents)))
    if rot is not None:
        v = v @ rot.T
    return v + np.asarray(list(centre), dtype=float), f


def rod(p0: Iterable[float], p1: Iterable[float], radius: float, sections: int = 8) -> Body:
    """A closed cylinder from ``p0`` to ``p1``."""
    import trimesh
    seg = np.array([list(p0), list(p1)], dtype=float)
    return _arrays(trimesh.creation.cylinder(radius=radius, segment=seg, sections=sections))


def polyline_rods(points: np.ndarray, radius: float, sections: int = 8) -> list[Body]:
    """A bent rod (a stick, a wire) as one cylinder per segment of a polyline.

    Consecutive cylinders overlap at the joints; the outer side of a bend keeps a notch of at
    most ``radius * tan(angle / 2)``, millimetres for the bends used here.
    """
    pts = np.asarray(points, dtype=float)
    return [rod(a, b, radius, sections) for a, b in zip(pts[:-1], pts[1:])
            if np.linalg.norm(b - a) > 1e-6]


def tube(points: np.ndarray, radius: float, sections: int = 8) -> Body:
    """A closed tube of ``radius`` swept along a polyline (a wire, a bent stick): one ring of
    ``sections`` vertices per point, its frame carried along by parallel transport, and a flat
    cap at either end.

    Written here because trimesh's ``sweep_polygon`` needs shapely, which is not among the
    dependencies; one body per polyline also keeps a coil's thousands of faces in one
    vectorised construction instead of one trimesh cylinder per segment.
    """
    pts = np.asarray(points, dtype=float)
    keep = np.concatenate([[True], np.linalg.norm(np.diff(pts, axis=0), axis=1) > 1e-9])
    pts = pts[keep]
    n = len(pts)
    if n < 2:
        raise ValueError('a tube needs two distinct points')
    seg = np.diff(pts, axis=0)
    seg /= np.linalg.norm(seg, axis=1, keepdims=True)
    tangent = np.concatenate([seg[:1], seg[:-1] + seg[1:], seg[-1:]])
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    helper = np.eye(3)[int(np.argmin(np.abs(tangent[0])))]
    normal = np.zeros_like(pts)
    normal[0] = np.cross(tangent[0], helper)
    normal[0] /= np.linalg.norm(normal[0])
    for i in range(1, n):  # parallel transport: no twist between rings
        m = normal[i - 1] - np.dot(normal[i - 1], tangent[i]) * tangent[i]
        normal[i] = m / np.linalg.norm(m)
    binormal = np.cross(tangent, normal)
    ang = 2.0 * np.pi * np.arange(sections) / sections
    ring = (np.cos(ang)[None, :, None] * normal[:, None, :]
            + np.sin(ang)[None, :, None] * binormal[:, None, :])
    verts = np.concatenate([(pts[:, None, :] + radius * ring).reshape(-1, 3), pts[[0, -1]]])
    i = np.arange(n - 1)[:, None] * sections
    j = np.arange(sections)[None, :]
    a, b = i + j, i + (j + 1) % sections
    c, d = a + sections, b + sections
    side = np.concatenate([np.stack([a, b, d], -1).reshape(-1, 3),
                           np.stack([a, d, c], -1).reshape(-1, 3)])
    first, last = n * sections, n * sections + 1
    k = np.arange(sections)
    cap0 = np.stack([np.full(sections, first), (k + 1) % sections, k], axis=1)
    cap1 = np.stack([np.full(sections, last), (n - 1) * sections + k,
                     (n - 1) * sections + (k + 1) % sections], axis=1)
    return verts, np.concatenate([side, cap0, cap1]).astype(np.int64)


def noisy_hull(rng: np.random.Generator, axes: Iterable[float], points: tuple[int, int] = (24, 60),
               jitter: tuple[float, float] = (0.75, 1.15), dent: float = 0.12) -> Body:
    """A stone: the convex hull of random points on an ellipsoid, subdivided once with the new
    (edge midpoint) vertices pushed inwards by up to ``dent`` (shallow dents between corners).

    Args:
        rng: randomness.
        axes: semi-axes of the ellipsoid [m] (any scale; callers fit the result).
        points: range of the number of points.
        jitter: range of the radial scale of each point.
        dent: largest inward push of a new vertex, as a share of its distance to the centre.
    """
    import trimesh
    axes = np.asarray(list(axes), dtype=float)
    n = int(rng.integers(points[0], points[1]))
    dirs = rng.standard_normal((n, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    pts = dirs * axes * rng.uniform(jitter[0], jitter[1], (n, 1))
    hull = trimesh.convex.convex_hull(pts)
    v, f = trimesh.remesh.subdivide(np.asarray(hull.vertices), np.asarray(hull.faces))
    centre = v.mean(axis=0)
    n_hull = len(hull.vertices)
    scale = np.ones(len(v))
    scale[n_hull:] = 1.0 - rng.uniform(0.0, dent, len(v) - n_hull)
    v = centre + (v - centre) * scale[:, None]
    return np.asarray(v, dtype=np.float64), np.asarray(f, dtype=np.int64)


def flatten_bed(v: np.ndarray, share: float = 0.2, squash: float = 0.25) -> np.ndarray:
    """A stone settled on a flattish bed: below ``share`` of its height, heights are squashed
    towards that level by ``squash`` (the lowest fifth of the library's rocks)."""
    z0, z1 = v[:, 2].min(), v[:, 2].max()
    bed = z0 + share * (z1 - z0)
    v[:, 2] = np.where(v[:, 2] < bed, bed - squash * (bed - v[:, 2]), v[:, 2])
    return v


def revolved(profile: np.ndarray, sections: int = 32) -> Body:
    """A solid of revolution about z from a closed (r, z) profile (counter-clockwise, r >= 0)."""
    import trimesh
    return _arrays(trimesh.creation.revolve(np.asarray(profile, dtype=float), sections=sections))


def settle(v: np.ndarray) -> np.ndarray:
    """Centre the footprint's bounding box on the origin and put the lowest point at z = 0."""
    lo, hi = v.min(axis=0), v.max(axis=0)
    return v - np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])


def fit(v: np.ndarray, height: float, max_across: float, max_radius: float) -> np.ndarray:
    """Settle ``v`` and scale it to ``height``; then shrink it horizontally (only) until no two
    vertices lie more than ``max_across`` apart seen from above and none lies farther than
    ``max_radius`` from the footprint's centre (so it fits a tile whatever its yaw)."""
    v = settle(v)
    v = v * (height / v[:, 2].max())
    xy = v[:, :2]
    radius = float(np.max(np.hypot(xy[:, 0], xy[:, 1])))
    across = _across(xy)
    shrink = min(1.0, max_radius / radius if radius > 0 else 1.0,
                 max_across / across if across > 0 else 1.0)
    if shrink < 1.0:
        v[:, :2] *= shrink
    return settle(v)


def _across(xy: np.ndarray) -> float:
    from scipy.spatial import ConvexHull
    hull = xy[ConvexHull(xy).vertices]
    return float(np.max(np.linalg.norm(hull[:, None] - hull[None], axis=-1)))


def tilt(v: np.ndarray, angle: float, azimuth: float = 0.0) -> np.ndarray:
    """Lean ``v`` by ``angle`` [rad] from the vertical towards ``azimuth`` [rad], then settle."""
    axis = np.array([-math.sin(azimuth), math.cos(azimuth), 0.0])
    return settle(v @ rotation(axis, angle).T)


def stack_height(placed: list[np.ndarray], xy: np.ndarray, reach: float) -> float:
    """Where a piece of footprint radius ``reach`` centred at ``xy`` comes to rest on a pile:
    the highest vertex of the pieces already ``placed`` within ``reach`` of its centre, seen
    from above (0: the ground). A coarse rule (it ignores the piece's own underside), enough for
    heaps whose pieces overlap a little."""
    top = 0.0
    for v in placed:
        near = np.hypot(v[:, 0] - xy[0], v[:, 1] - xy[1]) < reach
        if near.any():
            top = max(top, float(v[near, 2].max()))
    return top


def heap(rng: np.random.Generator, pieces: list[Body], spread: float, overlap: float,
         yaw: bool = True) -> list[Body]:
    """Heap settled pieces: each at a random spot within ``spread`` of the centre, resting on
    the highest of the pieces already under it (sunk into them by ``overlap``)."""
    placed: list[np.ndarray] = []
    out = []
    for v, f in pieces:
        v = settle(v @ rotation(Z_UP, rng.uniform(0, 2 * math.pi)).T if yaw else v)
        ang, r = rng.uniform(0, 2 * math.pi), spread * math.sqrt(rng.uniform())
        xy = np.array([r * math.cos(ang), r * math.sin(ang)])
        # Resting on what lies under its middle third: pieces slot in beside each other
        # instead of balancing on the highest point around (a heap, not a tower).
        reach = 0.17 * float(np.max(np.ptp(v[:, :2], axis=0)))
        z = stack_height(placed, xy, reach)
        v = v + np.array([xy[0], xy[1], max(z - overlap, 0.0)])
        placed.append(v)
        out.append((v, f))
    return out


def pick(rng: np.random.Generator, weights: dict[str, float]) -> str:
    """A key of ``weights`` drawn in proportion to its weight (a pose, a part, a kind)."""
    keys = list(weights)
    p = np.array([weights[k] for k in keys], dtype=float)
    return keys[int(rng.choice(len(keys), p=p / p.sum()))]


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A 3x3 rotation uniform over all orientations (a normalised Gaussian quaternion)."""
    from scipy.spatial.transform import Rotation
    q = rng.standard_normal(4)
    return Rotation.from_quat(q / np.linalg.norm(q)).as_matrix()


def lying(v: np.ndarray) -> np.ndarray:
    """Turn a z-axis shape onto its side (axis along y), settled."""
    return settle(v @ rotation((1.0, 0.0, 0.0), math.pi / 2).T)


def normalise(vertices: np.ndarray) -> np.ndarray:
    """Centre the footprint's bounding box on the origin and put the lowest point at z = 0."""
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    return vertices - np.array([(lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, lo[2]])


def box_parts(parts: list[tuple[tuple[float, float, float], tuple[float, float, float]]]
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


def cinder_block(length: float, width: float, height: float, cores: int, wall: float,
                 web: float, on_side: bool) -> tuple[np.ndarray, np.ndarray]:
    """A cinder block of ``cores`` cores as boxes (outer walls and webs), so the cores are real
    holes a ray can pass into; ``on_side`` lays it down with the cores horizontal."""
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
    v, f = box_parts(parts)
    if on_side:
        v = v[:, [0, 2, 1]]
        f = f[:, ::-1]
    return normalise(v), f
