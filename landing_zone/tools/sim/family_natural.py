"""The generators of the natural families (and rubble): stones, slabs, heaps of chunks, logs,
stumps and heaps of sticks, each ``rng -> Shape`` (see :mod:`landing_zone.tools.sim.families`)."""
from __future__ import annotations

import math

import numpy as np

from landing_zone.tools.sim import shapes as sh
from landing_zone.tools.sim.family_shape import MAX_RADIUS, Shape

__all__ = ['rock', 'slab', 'rubble', 'log', 'stump', 'brush']


def rock(rng: np.random.Generator) -> Shape:
    h = rng.uniform(0.12, 0.50)
    length = rng.uniform(max(0.6 * h, 0.14), 0.68)
    width = rng.uniform(0.5, 1.0) * length
    v, f = sh.noisy_hull(rng, (0.5 * length, 0.5 * width, 0.5 * h))
    v = sh.settle(sh.flatten_bed(v))
    return Shape(v, f, 'lying', params={'length': length, 'width': width})


def slab(rng: np.random.Generator) -> Shape:
    thick = rng.uniform(0.10, 0.20)
    length = rng.uniform(0.3, 0.68)
    width = rng.uniform(0.5, 0.95) * length
    v, f = sh.noisy_hull(rng, (0.5 * length, 0.5 * width, 0.5 * thick), points=(30, 60),
                         jitter=(0.85, 1.1), dent=0.06)
    v = sh.settle(sh.flatten_bed(v, 0.3))
    pose = sh.pick(rng, {'lying': 0.65, 'leaning': 0.35})
    if pose == 'leaning':
        v = sh.tilt(v, math.radians(rng.uniform(25.0, 70.0)), rng.uniform(0, 2 * math.pi))
    return Shape(v, f, pose, params={'thickness': thick, 'length': length})


def rubble(rng: np.random.Generator) -> Shape:
    pieces = []
    for _ in range(int(rng.integers(4, 10))):
        if rng.uniform() < 0.5:  # a chunk of concrete or stone
            axes = rng.uniform(0.04, 0.13, 3)
            v, f = sh.noisy_hull(rng, axes, points=(12, 30), dent=0.08)
        else:  # a brick or a broken one
            ext = np.array([rng.uniform(0.12, 0.23), rng.uniform(0.06, 0.11),
                            rng.uniform(0.05, 0.075)])
            v, f = sh.box(ext)
        pieces.append((sh.settle(v @ sh.random_rotation(rng).T), f))
    bodies = sh.heap(rng, pieces, rng.uniform(0.12, 0.25), 0.01)
    v, f = sh.join(bodies)
    return Shape(sh.settle(v), f, 'lying', 'piled', params={'pieces': len(pieces)})


def log(rng: np.random.Generator) -> Shape:
    r = rng.uniform(0.05, 0.15)
    length = rng.uniform(0.3, 0.68)
    v, f = sh.rod((-0.5 * length, 0.0, 0.0), (0.5 * length, 0.0, 0.0), r, 14)
    # Bark: every vertex off the axis moves radially by a few per cent.
    radial = np.hypot(v[:, 1], v[:, 2])
    scale = np.where(radial > 1e-9, 1.0 + rng.uniform(-0.07, 0.07, len(v)), 1.0)
    v[:, 1:] *= scale[:, None]
    bodies = [(v, f)]
    if rng.uniform() < 0.4:  # a branch stub
        x = rng.uniform(-0.35, 0.35) * length
        ang = rng.uniform(0, 2 * math.pi)
        d = np.array([rng.uniform(-0.3, 0.3), math.cos(ang), math.sin(ang)])
        d /= np.linalg.norm(d)
        p0 = np.array([x, 0.0, 0.0])
        bodies.append(sh.rod(p0, p0 + d * (r + rng.uniform(0.05, 0.15)),
                             rng.uniform(0.2, 0.4) * r, 8))
    v, f = sh.join(bodies)
    v = sh.settle(v)
    pose = sh.pick(rng, {'lying': 0.7, 'leaning': 0.3})
    if pose == 'leaning':  # one end on the ground, the other propped up
        v = sh.settle(v @ sh.rotation((0.0, 1.0, 0.0), -math.radians(rng.uniform(15, 40))).T)
    return Shape(v, f, pose, params={'radius': r, 'length': length})


def stump(rng: np.random.Generator) -> Shape:
    radius = rng.uniform(0.1, 0.22)
    h = rng.uniform(0.15, 0.55)
    base = radius * rng.uniform(1.15, 1.5)
    profile = np.array([[0.0, 0.0], [base, 0.0], [0.95 * base, 0.06 * h],
                        [1.05 * radius, 0.25 * h], [radius, 0.9 * h], [0.95 * radius, h],
                        [0.0, h]])
    v, f = sh.revolved(profile, 24)
    theta = np.arctan2(v[:, 1], v[:, 0])
    wobble = np.ones(len(v))
    for k in (2, 3, 5):  # an irregular (buttressed) outline
        wobble += rng.uniform(0.0, 0.07) * np.cos(k * theta + rng.uniform(0, 2 * math.pi))
    v[:, :2] *= wobble[:, None]
    top = v[:, 2] > 0.85 * h  # a broken or saw-cut top
    v[top, 2] += h * rng.uniform(-0.10, 0.03, int(top.sum()))
    bodies = [(v, f)]
    for _ in range(int(rng.integers(0, 4))):  # roots running out along the ground
        ang = rng.uniform(0, 2 * math.pi)
        rr = rng.uniform(0.025, 0.05)
        d = np.array([math.cos(ang), math.sin(ang), 0.0])
        bodies.append(sh.rod(d * 0.5 * base + np.array([0, 0, rr]),
                             d * min(base + rng.uniform(0.08, 0.2), MAX_RADIUS - 0.02)
                             + np.array([0, 0, 0.5 * rr]), rr, 8))
    v, f = sh.join(bodies)
    return Shape(sh.settle(v), f, 'upright', params={'radius': radius})


def brush(rng: np.random.Generator) -> Shape:
    bodies = []
    placed: list[np.ndarray] = []
    spread = rng.uniform(0.1, 0.2)
    for k in range(int(rng.integers(5, 13))):
        length = rng.uniform(0.3, 0.65)
        r = rng.uniform(0.012, 0.035)
        upright = k >= 2 and rng.uniform() < 0.2  # a few twigs stick up out of the heap
        pitch = math.radians(rng.uniform(20, 45) if upright else rng.normal(0.0, 10.0))
        yaw = rng.uniform(0, 2 * math.pi)
        d = np.array([math.cos(yaw) * math.cos(pitch), math.sin(yaw) * math.cos(pitch),
                      math.sin(pitch)])
        # Three pieces, each bent a little off the stick's line.
        t = np.linspace(-0.5, 0.5, 4)[:, None] * length * d
        bend = rng.normal(0.0, 0.02, (4, 3))
        bend[[0, -1]] *= 0.3
        ang, rad = rng.uniform(0, 2 * math.pi), spread * math.sqrt(rng.uniform())
        xy = np.array([rad * math.cos(ang), rad * math.sin(ang)])
        pts = t + bend + np.array([xy[0], xy[1], 0.0])
        pts[:, 2] -= pts[:, 2].min()
        # It rests on whatever lies under its middle (a heap, not a tower: sticks bridge).
        z = sh.stack_height(placed, xy, 0.06)
        pts[:, 2] += max(z - r, 0.0) + r
        bodies.append(sh.tube(pts, r, 7))
        placed.append(bodies[-1][0])
    v, f = sh.join(bodies)
    return Shape(sh.settle(v), f, 'lying', 'piled', True, {'sticks': len(placed)})
