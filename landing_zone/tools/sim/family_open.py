"""The generators of the open families of thin structure: frames of rods, welded mesh and loops
of wire or hose, each ``rng -> Shape`` (see :mod:`landing_zone.tools.sim.families`)."""
from __future__ import annotations

import math

import numpy as np

from landing_zone.tools.sim import shapes as sh
from landing_zone.tools.sim.family_shape import Shape

__all__ = ['frame', 'mesh', 'hoop']


def frame(rng: np.random.Generator) -> Shape:
    """Open frames of thin rods: stools, sawhorses, trestles, tripods, a chair's skeleton."""
    r = rng.uniform(0.008, 0.022)
    h = rng.uniform(0.25, 0.6)
    kind = sh.pick(rng, {'four_legs': 0.55, 'sawhorse': 0.25, 'tripod': 0.2})
    bodies: list[sh.Body] = []
    if kind == 'tripod':
        top_r = rng.uniform(0.03, 0.1)
        foot_r = rng.uniform(0.18, 0.32)
        a0 = rng.uniform(0, 2 * math.pi)
        tops, feet = [], []
        for k in range(3):
            a = a0 + 2 * math.pi * k / 3
            tops.append((top_r * math.cos(a), top_r * math.sin(a), h))
            feet.append((foot_r * math.cos(a), foot_r * math.sin(a), r))
            bodies.append(sh.rod(feet[-1], tops[-1], r, 8))
        for k in range(3):  # the ring at the top and, on some, a spreader half way down
            bodies.append(sh.rod(tops[k], tops[(k + 1) % 3], 0.8 * r, 8))
        if rng.uniform() < 0.5:
            mid = [0.5 * (np.array(t) + np.array(f)) for t, f in zip(tops, feet)]
            for k in range(3):
                bodies.append(sh.rod(mid[k], mid[(k + 1) % 3], 0.7 * r, 8))
    else:
        length = rng.uniform(0.3, 0.65)
        width = rng.uniform(0.25, 0.6) if kind == 'four_legs' else rng.uniform(0.3, 0.55)
        splay = rng.uniform(0.0, 0.08) if kind == 'four_legs' else 0.0
        top_w = 0.5 * width if kind == 'four_legs' else rng.uniform(0.02, 0.06)
        hx, hy = 0.5 * length, 0.5 * width
        feet = [(sx * hx, sy * hy, r) for sx in (-1, 1) for sy in (-1, 1)]
        tops = [(sx * (hx - splay), sy * (top_w - splay), h) for sx in (-1, 1) for sy in (-1, 1)]
        for f, t in zip(feet, tops):
            bodies.append(sh.rod(f, t, r, 8))
        # the top rails (a sawhorse's beam is the long pair), and stretchers on some
        for a, b in ((0, 2), (1, 3), (0, 1), (2, 3)):
            bodies.append(sh.rod(tops[a], tops[b], r, 8))
        if rng.uniform() < 0.6:
            z = rng.uniform(0.2, 0.5)
            mid = [tuple(np.array(f) + z * (np.array(t) - np.array(f)))
                   for f, t in zip(feet, tops)]
            for a, b in ((0, 2), (1, 3)) if rng.uniform() < 0.5 else ((0, 1), (2, 3)):
                bodies.append(sh.rod(mid[a], mid[b], 0.8 * r, 8))
        if kind == 'four_legs' and rng.uniform() < 0.35:  # a chair's back
            back = rng.uniform(0.15, 0.3)
            for t in (tops[0], tops[1]):
                bodies.append(sh.rod(t, (t[0], t[1], h + back), r, 8))
            bodies.append(sh.rod((tops[0][0], tops[0][1], h + back),
                                 (tops[1][0], tops[1][1], h + back), r, 8))
    v, f = sh.join(bodies)
    pose = sh.pick(rng, {'upright': 0.5, 'lying': 0.3, 'leaning': 0.2})
    if pose == 'lying':  # knocked over onto its side
        v = sh.lying(v)
    elif pose == 'leaning':  # propped up on two legs
        v = sh.tilt(v, math.radians(rng.uniform(10, 30)), rng.uniform(0, 2 * math.pi))
    return Shape(sh.settle(v), f, pose, 'single', True, {'kind': kind, 'rod': r})


def _propped(rng: np.random.Generator, bodies: list[sh.Body]) -> sh.Body:
    """``bodies`` standing in the x-z plane, tilted 20-60 degrees about the x axis and their top
    edge propped on a stake (a fence panel, a hoop leant against a post)."""
    v, f = sh.join(bodies)
    v = sh.tilt(v, math.radians(rng.uniform(20, 60)), math.pi / 2)
    top = v[v[:, 2] > v[:, 2].max() - 0.01]
    x, y = float(top[:, 0].mean()), float(top[:, 1].mean())
    return sh.join([(v, f), sh.rod((x, y, 0.0), (x, y, float(v[:, 2].max())), 0.01, 8)])


def _grid(width: float, height: float, pitch_u: float, pitch_v: float, wire: float
          ) -> list[sh.Body]:
    """A welded wire grid in the x-z plane, centred on x = 0, from z = 0 to ``height``."""
    out = []
    nu = max(int(round(width / pitch_u)), 1)
    nv = max(int(round(height / pitch_v)), 1)
    for x in np.linspace(-0.5 * width, 0.5 * width, nu + 1):
        out.append(sh.rod((x, 0.0, 0.0), (x, 0.0, height), wire, 6))
    for z in np.linspace(wire, height - wire, nv + 1):
        out.append(sh.rod((-0.5 * width, 0.0, z), (0.5 * width, 0.0, z), wire, 6))
    return out


def mesh(rng: np.random.Generator) -> Shape:
    """Welded wire mesh: a fence or grate panel standing on feet or leaning, or a wire cage
    (a basket, a gabion's frame) upright or tipped over."""
    wire = rng.uniform(0.002, 0.006)
    pu, pv = rng.uniform(0.04, 0.15), rng.uniform(0.04, 0.15)
    if rng.uniform() < 0.55:
        width, height = rng.uniform(0.35, 0.68), rng.uniform(0.25, 0.6)
        bodies = _grid(width, height, pu, pv, wire)
        if rng.uniform() < 0.5:  # a heavier frame around the panel
            fr = rng.uniform(0.006, 0.014)
            bodies += [sh.rod((-0.5 * width, 0, 0), (-0.5 * width, 0, height), fr, 8),
                       sh.rod((0.5 * width, 0, 0), (0.5 * width, 0, height), fr, 8),
                       sh.rod((-0.5 * width, 0, height), (0.5 * width, 0, height), fr, 8)]
        pose = sh.pick(rng, {'upright': 0.5, 'leaning': 0.5})
        if pose == 'upright':  # two feet across the panel keep it standing
            foot = rng.uniform(0.12, 0.3)
            for x in (-0.4 * width, 0.4 * width):
                bodies.append(sh.rod((x, -0.5 * foot, 0.01), (x, 0.5 * foot, 0.01), 0.01, 8))
            v, f = sh.join(bodies)
        else:
            v, f = _propped(rng, bodies)
        return Shape(sh.settle(v), f, pose, 'single', True, {'form': 'panel', 'wire': wire})
    lx, ly, lz = rng.uniform(0.25, 0.6), rng.uniform(0.25, 0.6), rng.uniform(0.2, 0.45)
    bodies = []
    for y in (-0.5 * ly, 0.5 * ly):  # four walls and a bottom; the top is open on most
        bodies += [(bv + np.array([0.0, y, 0.0]), bf) for bv, bf in _grid(lx, lz, pu, pv, wire)]
    turn = sh.rotation(sh.Z_UP, math.pi / 2)
    for x in (-0.5 * lx, 0.5 * lx):
        bodies += [(bv @ turn.T + np.array([x, 0.0, 0.0]), bf)
                   for bv, bf in _grid(ly, lz, pu, pv, wire)]
    flat = sh.rotation((1.0, 0.0, 0.0), math.pi / 2)
    lids = (0.0, lz) if rng.uniform() < 0.3 else (0.0,)
    for z in lids:
        bodies += [(bv @ flat.T + np.array([0.0, 0.5 * ly, z + wire]), bf)
                   for bv, bf in _grid(lx, ly, pu, pv, wire)]
    v, f = sh.join(bodies)
    pose = sh.pick(rng, {'upright': 0.6, 'lying': 0.4})
    if pose == 'lying':
        v = sh.settle(v @ sh.rotation((0.0, 1.0, 0.0), math.pi / 2).T)
    return Shape(sh.settle(v), f, pose, 'single', True, {'form': 'cage', 'wire': wire})


def _loop(rng: np.random.Generator, radius: float, wobble: float, n: int = 64) -> np.ndarray:
    """A closed loop of wire around the origin in the x-y plane: a circle bent out of round
    (radial waves of 2-3 lobes) and warped out of its plane, its polyline running a little past
    the start so that the tube's two capped ends overlap (a closed loop, one closed body)."""
    t = np.linspace(0.0, 2 * math.pi * (1.0 + 2.0 / n), n + 3)
    r = np.full_like(t, radius)
    z = np.zeros_like(t)
    for k in (2, 3):
        r += radius * rng.uniform(0.0, wobble) * np.cos(k * t + rng.uniform(0, 2 * math.pi))
        z += radius * rng.uniform(0.0, wobble) * np.sin((k - 1) * t + rng.uniform(0, 2 * math.pi))
    return np.stack([r * np.cos(t), r * np.sin(t), z], axis=1)


def hoop(rng: np.random.Generator) -> Shape:
    """Closed loops of wire, hose and cable: a hoop or a wheel rim standing on feet, one or a
    few propped up leaning, or a tangle of bent loops lying through each other. Unlike a coil (a
    helix round one axis) the loops have axes of their own."""
    kind = sh.pick(rng, {'standing': 0.3, 'leaning': 0.3, 'tangle': 0.4})
    if kind == 'tangle':  # 2-6 loops of wire or cable, bent, each tipped up to 75 degrees
        pieces = []
        for _ in range(int(rng.integers(2, 7))):
            loop = _loop(rng, rng.uniform(0.08, 0.22), rng.uniform(0.05, 0.3))
            v, f = sh.tube(loop, rng.uniform(0.002, 0.009), 6)
            v = sh.tilt(v, math.radians(rng.uniform(0, 75)), rng.uniform(0, 2 * math.pi))
            ang, off = rng.uniform(0, 2 * math.pi), 0.12 * math.sqrt(rng.uniform())
            # through each other, all on the ground: loops interlock rather than stack
            pieces.append((v + np.array([off * math.cos(ang), off * math.sin(ang), 0.0]), f))
        v, f = sh.join(pieces)
        return Shape(sh.settle(v), f, 'lying', 'piled', True, {'kind': kind, 'loops': len(pieces)})
    radius = rng.uniform(0.12, 0.3)
    tube_r = rng.uniform(0.004, 0.02)
    hoops = 1 if kind == 'standing' or rng.uniform() < 0.6 else int(rng.integers(2, 4))
    bodies = []
    for k in range(hoops):  # a round hoop standing in the x-z plane, side by side along y
        v, f = sh.tube(_loop(rng, radius * rng.uniform(0.85, 1.0), 0.04), tube_r, 8)
        v = sh.settle(v @ sh.rotation((1.0, 0.0, 0.0), math.pi / 2).T)
        bodies.append((v + np.array([0.0, 0.06 * k, 0.0]), f))
    if kind == 'standing':  # on two feet across its plane, as a rim in a stand
        foot = rng.uniform(0.1, 0.25)
        for x in (-0.3 * radius, 0.3 * radius):
            bodies.append(sh.rod((x, -0.5 * foot, 0.01), (x, 0.5 * foot, 0.01), 0.01, 8))
        v, f = sh.join(bodies)
        return Shape(sh.settle(v), f, 'upright', 'single', True,
                     {'kind': kind, 'radius': radius, 'tube': tube_r})
    v, f = _propped(rng, bodies)
    return Shape(sh.settle(v), f, 'leaning', 'single' if hoops == 1 else 'piled', True,
                 {'kind': kind, 'radius': radius, 'tube': tube_r, 'hoops': hoops})
