"""The obstacle library: boxes (synth1), rocks, tires and cinder blocks (synth2).

Every model (:class:`~landing_zone.tools.sim.obstacles.ObstacleModel`) is a procedural mesh,
fixed (the library does not depend on any user seed), in a local frame whose footprint is
centred on the origin and whose lowest point is at z = 0:

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

import numpy as np

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.families import FAMILIES, instance_model, is_instance_name
from landing_zone.tools.sim.obstacles import ObstacleModel
from landing_zone.tools.sim.shapes import box_parts, cinder_block, flatten_bed, noisy_hull, \
    normalise

__all__ = ['KINDS', 'library', 'models', 'get_model', 'MAX_HEIGHT', 'MIN_HEIGHT', 'MAX_ACROSS']

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


def _box(edge: float = 0.15) -> tuple[np.ndarray, np.ndarray]:
    return box_parts([((0.0, 0.0, 0.0), (edge, edge, edge))])


def _rock(index: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(20150526 + 7919 * index)
    height, proportions = _ROCKS[index]
    v, f = noisy_hull(rng, proportions)
    v = flatten_bed(v)  # rocks settle on a flattish bed
    # A random yaw of the shape itself, so the rocks' long axes do not all lie along x.
    yaw = rng.uniform(0.0, np.pi)
    c, s = math.cos(yaw), math.sin(yaw)
    v = v @ np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]).T
    v = normalise(v)
    # Scale to the rock's height; shrink horizontally if it would be too wide.
    v *= height / v[:, 2].max()
    r = np.max(np.hypot(v[:, 0], v[:, 1]))
    if 2.0 * r > 0.94 * MAX_ACROSS:
        v[:, :2] *= 0.94 * MAX_ACROSS / (2.0 * r)
    return v, np.asarray(f)


def _tire(major: float, tube: float, flatten: float, upright: bool
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
    return normalise(v), f


@functools.lru_cache(maxsize=1)
def library() -> dict[str, ObstacleModel]:
    """All models by name (built once per process)."""
    out: dict[str, ObstacleModel] = {}
    v, f = _box(0.15)
    out['box'] = ObstacleModel('box', 'box', 'both', normalise(v), f)
    for k in range(len(_ROCKS)):
        v, f = _rock(k)
        group = 'train' if k < _N_TRAIN_ROCKS else 'test'
        out[f'rock_{k:02d}'] = ObstacleModel(f'rock_{k:02d}', 'rock', group, v, f,
                                             embed=0.1 * float(v[:, 2].max()))
    v, f = _tire(major=0.14, tube=0.05, flatten=0.9, upright=True)
    out['tire_a'] = ObstacleModel('tire_a', 'tire', 'train', v, f, embed=0.02)
    v, f = _tire(major=0.16, tube=0.075, flatten=1.1, upright=False)
    out['tire_b'] = ObstacleModel('tire_b', 'tire', 'test', v, f)
    v, f = cinder_block(0.39, 0.19, 0.19, cores=2, wall=0.032, web=0.026, on_side=False)
    out['cinder_block_a'] = ObstacleModel('cinder_block_a', 'cinder_block', 'train', v, f)
    v, f = cinder_block(0.44, 0.215, 0.215, cores=3, wall=0.03, web=0.025, on_side=True)
    out['cinder_block_b'] = ObstacleModel('cinder_block_b', 'cinder_block', 'test', v, f)
    return out


def models(kinds: tuple[str, ...] | list[str] | None = None,
           group: str | None = None) -> list[ObstacleModel]:
    """Models of the given kinds (all if None) usable in ``group`` ('train', 'test', None)."""
    if kinds is not None:
        unknown = [k for k in kinds if k not in KINDS]
        if unknown:
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
        if is_instance_name(name):
            return instance_model(name)
    if name not in lib:
        raise SimulationError(f'unknown obstacle model {name!r}; choose from '
                              f'{", ".join(lib)}')
    return lib[name]
