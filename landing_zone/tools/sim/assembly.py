"""The ``assembly`` family: random assemblies of parts, a shape prior rather than a thing.

Every other family is a kind of object (a bucket, a pallet, a coil). A net trained on a list of
kinds learns those kinds; on a shape none of them resembles it can be confidently wrong, and
that is what sites nobody simulated hold. This family spans the shape traits instead of
naming an object: an instance is one to five parts drawn from solid, hollow and gappy
primitives (blocks, cylinders, irregular lumps, plates, thin rods, tubes, rings, open shells,
bundles of sticks), each with its own sizes and orientation, heaped or set side by side, then
posed upright, on its side or leaning, scaled into 10-60 cm and 70 cm across by
:func:`landing_zone.tools.sim.families.instance` as every family is. Most instances are nothing a
person would name; that is the point (domain randomisation over obstacle shape).

It is a train family: it widens what training sees without being any held-out family. In a
leave-one-family-out run it stays in training while the held-out family is left out, so the
held-out figure measures a shape never seen beside a broad prior of shapes, which is what a
new site is.
"""
from __future__ import annotations

import math

import numpy as np

from landing_zone.tools.sim import shapes as sh
from landing_zone.tools.sim.family_shape import Shape

__all__ = ['build', 'PARTS']

# What a part can be, and how often it is drawn; the open ones let rays into a cavity or
# between their members.
PARTS = {'block': 1.0, 'cylinder': 1.0, 'lump': 1.2, 'plate': 0.9, 'rod': 0.7, 'tube': 0.7,
         'ring': 0.5, 'shell': 0.7, 'sticks': 0.6}
_OPEN = {'tube', 'ring', 'shell', 'sticks'}


def _turned(rng: np.random.Generator, v: np.ndarray) -> np.ndarray:
    """``v`` turned at random: a yaw always, a full random rotation half the time."""
    if rng.uniform() < 0.5:
        v = v @ sh.random_rotation(rng).T
    return sh.settle(v @ sh.rotation(sh.Z_UP, rng.uniform(0.0, 2 * math.pi)).T)


def _part(rng: np.random.Generator) -> tuple[list[sh.Body], str]:
    """One part at its own size, settled on z = 0, and its kind."""
    import trimesh
    kind = sh.pick(rng, PARTS)
    if kind == 'block':
        bodies = [sh.box(rng.uniform(0.04, 0.5, 3))]
    elif kind == 'cylinder':
        r, length = rng.uniform(0.03, 0.2), rng.uniform(0.08, 0.6)
        bodies = [sh.rod((0, 0, 0), (0, 0, length), r, 16)]
    elif kind == 'lump':
        bodies = [sh.noisy_hull(rng, rng.uniform(0.03, 0.25, 3), dent=rng.uniform(0.0, 0.2))]
    elif kind == 'plate':
        bodies = [sh.box((rng.uniform(0.15, 0.6), rng.uniform(0.1, 0.5),
                          rng.uniform(0.008, 0.04)))]
    elif kind == 'rod':
        bodies = [sh.rod((0, 0, 0), (0, 0, rng.uniform(0.2, 0.7)), rng.uniform(0.006, 0.03), 8)]
    elif kind == 'tube':
        r = rng.uniform(0.04, 0.2)
        m = trimesh.creation.annulus(r_min=r - min(rng.uniform(0.005, 0.02), 0.4 * r), r_max=r,
                                     height=rng.uniform(0.1, 0.5), sections=24)
        bodies = [(np.asarray(m.vertices, float).copy(), np.asarray(m.faces, np.int64).copy())]
    elif kind == 'ring':
        m = trimesh.creation.torus(major_radius=rng.uniform(0.08, 0.25),
                                   minor_radius=rng.uniform(0.015, 0.06), major_sections=32,
                                   minor_sections=12)
        bodies = [(np.asarray(m.vertices, float).copy(), np.asarray(m.faces, np.int64).copy())]
    elif kind == 'shell':  # an open box: a floor and four walls, its top open
        lx, ly, lz = rng.uniform(0.15, 0.5), rng.uniform(0.15, 0.5), rng.uniform(0.1, 0.45)
        t = rng.uniform(0.005, 0.025)
        bodies = [sh.box((lx, ly, t), (0, 0, 0.5 * t)),
                  sh.box((t, ly, lz), (0.5 * (lx - t), 0, 0.5 * lz)),
                  sh.box((t, ly, lz), (-0.5 * (lx - t), 0, 0.5 * lz)),
                  sh.box((lx, t, lz), (0, 0.5 * (ly - t), 0.5 * lz)),
                  sh.box((lx, t, lz), (0, -0.5 * (ly - t), 0.5 * lz))]
    else:  # sticks: a loose bundle of rods crossing each other
        r = rng.uniform(0.006, 0.03)
        bodies = []
        for _ in range(int(rng.integers(3, 9))):
            c = rng.uniform(-0.12, 0.12, 3) + np.array([0.0, 0.0, 0.15])
            d = rng.standard_normal(3)
            d *= 0.5 * rng.uniform(0.2, 0.6) / np.linalg.norm(d)
            bodies.append(sh.rod(c - d, c + d, r * rng.uniform(0.7, 1.3), 8))
    v, f = sh.join(bodies)
    if kind != 'shell':  # a shell keeps its opening up (turned over it is a closed box)
        v = _turned(rng, v)
    else:
        v = sh.settle(v @ sh.rotation(sh.Z_UP, rng.uniform(0.0, 2 * math.pi)).T)
    # back into bodies, each watertight on its own
    out, start = [], 0
    for bv, bf in bodies:
        out.append((v[start:start + len(bv)], bf))
        start += len(bv)
    return out, kind


def build(rng: np.random.Generator) -> Shape:
    """An assembly (the family's generator: ``rng -> Shape``)."""
    n = int(rng.choice([1, 2, 3, 4, 5], p=[0.3, 0.3, 0.2, 0.12, 0.08]))
    parts, kinds = [], []
    for _ in range(n):
        bodies, kind = _part(rng)
        parts.append(bodies)
        kinds.append(kind)
    if n == 1:
        bodies = parts[0]
    else:  # heaped near the centre, or set apart with gaps between
        spread = rng.uniform(0.05, 0.3)
        bodies = sh.heap(rng, [sh.join(p) for p in parts], spread, 0.01)
    v, f = sh.join(bodies)
    pose = sh.pick(rng, {'upright': 0.45, 'lying': 0.3, 'leaning': 0.25})
    if pose == 'lying':
        v = sh.lying(v)
    elif pose == 'leaning':
        v = sh.tilt(v, math.radians(rng.uniform(15, 60)), rng.uniform(0, 2 * math.pi))
    # Heights spread over the family's range: a heap of parts stands tall, so the assembly is
    # scaled to a drawn height (flat ones at most 1.5 x, not blown up into blocks).
    v = sh.settle(v)
    v *= min(rng.uniform(0.10, 0.60) / float(v[:, 2].max()), 1.5)
    is_open = n == 1 and kinds[0] in _OPEN or 'sticks' in kinds
    return Shape(sh.settle(v), f, pose, 'single' if n == 1 else 'piled', is_open,
                 {'parts': kinds})
