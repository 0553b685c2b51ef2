"""The generators of the closed and hollow man-made families: boxes, crates, buckets, pipes,
tires, cinder blocks, posts, cones, coils, pallets and sacks, each ``rng -> Shape`` (see
:mod:`landing_zone.tools.sim.families`)."""
from __future__ import annotations

import math

import numpy as np

from landing_zone.tools.sim import shapes as sh
from landing_zone.tools.sim.family_shape import Shape

__all__ = ['box', 'crate', 'bucket', 'pipe', 'tire', 'cinder', 'post', 'cone', 'coil', 'pallet',
           'sack']


def _yawed(v: np.ndarray, yaw: float) -> np.ndarray:
    return v @ sh.rotation(sh.Z_UP, yaw).T


def box(rng: np.random.Generator) -> Shape:
    arrangement = sh.pick(rng, {'single': 0.7, 'piled': 0.3})
    n = 1 if arrangement == 'single' else int(rng.integers(2, 4))
    pieces = []
    scale = 1.0
    for _ in range(n):
        length = rng.uniform(0.15, 0.6) * scale
        width = rng.uniform(0.5, 1.0) * length
        h = rng.uniform(0.1, 0.45) * (scale if n > 1 else 1.0) / (1.6 if n > 1 else 1.0)
        pieces.append(sh.box((length, width, max(h, 0.05))))
        scale *= 0.8
    bodies = sh.heap(rng, pieces, 0.05 if n > 1 else 0.0, 0.002)
    v, f = sh.join(bodies)
    pose = sh.pick(rng, {'upright': 0.8, 'leaning': 0.2}) if n == 1 else 'upright'
    if pose == 'leaning':  # tipped onto an edge
        v = sh.tilt(v, math.radians(rng.uniform(10, 35)), rng.uniform(0, 2 * math.pi))
    return Shape(sh.settle(v), f, pose, arrangement, params={'boxes': n})


def crate(rng: np.random.Generator) -> Shape:
    length = rng.uniform(0.3, 0.65)
    width = rng.uniform(0.6, 1.0) * length
    h = rng.uniform(0.18, 0.45)
    t = rng.uniform(0.012, 0.025)
    slatted = rng.uniform() < 0.5
    bodies = [sh.box((length, width, t), (0, 0, 0.5 * t))]  # the bottom
    walls = [((0.5 * (length - t), 0.0), (t, width)), ((-0.5 * (length - t), 0.0), (t, width)),
             ((0.0, 0.5 * (width - t)), (length, t)), ((0.0, -0.5 * (width - t)), (length, t))]
    if slatted:
        n = int(rng.integers(2, 5))
        gap = rng.uniform(0.02, 0.05)
        slat = (h - t - (n - 1) * gap) / n
        if slat < 0.02:
            n, slat = 2, 0.5 * (h - t - gap)
        post = rng.uniform(0.03, 0.05)
        for (cx, cy), (ex, ey) in walls:
            for k in range(n):
                z = t + k * (slat + gap) + 0.5 * slat
                bodies.append(sh.box((ex, ey, slat), (cx, cy, z)))
        for sx in (-1, 1):
            for sy in (-1, 1):
                bodies.append(sh.box((post, post, h), (sx * 0.5 * (length - post),
                                                       sy * 0.5 * (width - post), 0.5 * h)))
    else:
        for (cx, cy), (ex, ey) in walls:
            bodies.append(sh.box((ex, ey, h), (cx, cy, 0.5 * h)))
    v, f = sh.join(bodies)
    pose = sh.pick(rng, {'upright': 0.7, 'on_side': 0.15, 'upside_down': 0.15})
    if pose == 'on_side':
        v = sh.settle(v @ sh.rotation((1.0, 0.0, 0.0), math.pi / 2).T)
    elif pose == 'upside_down':
        v = sh.settle(v @ sh.rotation((1.0, 0.0, 0.0), math.pi).T)
    return Shape(v, f, 'lying' if pose == 'on_side' else 'upright', 'single',
                 slatted or pose != 'upside_down',
                 {'slatted': slatted, 'turned': pose})


def bucket(rng: np.random.Generator) -> Shape:
    rb = rng.uniform(0.1, 0.16)
    rt = rb * rng.uniform(1.05, 1.3)
    h = rng.uniform(0.2, 0.45)
    w = rng.uniform(0.004, 0.01)
    profile = np.array([[0.0, 0.0], [rb, 0.0], [rt, h], [rt - w, h], [rb - w, w], [0.0, w]])
    bodies = [sh.revolved(profile, 32)]
    if rng.uniform() < 0.5:  # a wire handle, up over the opening or lying to one side
        ang = np.linspace(0.0, math.pi, 13)
        lean = rng.uniform(0.0, 0.5 * math.pi) if rng.uniform() < 0.5 else 0.0
        arc = np.stack([rt * np.cos(ang), -rt * np.sin(ang) * math.sin(lean),
                        h - 0.02 + rt * np.sin(ang) * math.cos(lean)], axis=1)
        bodies.append(sh.tube(arc, 0.004, 6))
    v, f = sh.join(bodies)
    pose = sh.pick(rng, {'upright': 0.5, 'lying': 0.35, 'upside_down': 0.15})
    if pose == 'lying':
        v = sh.lying(v)
    elif pose == 'upside_down':
        v = sh.settle(v @ sh.rotation((1.0, 0.0, 0.0), math.pi).T)
    return Shape(sh.settle(v), f, 'lying' if pose == 'lying' else 'upright', 'single',
                 pose != 'upside_down', {'radius': rt, 'turned': pose})


def pipe(rng: np.random.Generator) -> Shape:
    import trimesh
    r_out = rng.uniform(0.05, 0.2)
    wall = min(rng.uniform(0.006, 0.025), 0.4 * r_out)
    pose = sh.pick(rng, {'lying': 0.75, 'upright': 0.25})
    length = rng.uniform(0.3, 0.68) if pose == 'lying' else rng.uniform(0.15, 0.5)
    m = trimesh.creation.annulus(r_min=r_out - wall, r_max=r_out, height=length, sections=32)
    v, f = np.asarray(m.vertices, float).copy(), np.asarray(m.faces, np.int64).copy()
    v = sh.lying(v) if pose == 'lying' else sh.settle(v)
    return Shape(v, f, pose, 'single', True, {'radius': r_out, 'wall': wall, 'length': length})


def _torus(major: float, tube: float, flatten: float) -> sh.Body:
    import trimesh
    m = trimesh.creation.torus(major_radius=major, minor_radius=tube, major_sections=40,
                               minor_sections=14)
    v = np.asarray(m.vertices, float).copy()
    v[:, 2] *= flatten  # a tread: wider than a round tube
    return sh.settle(v), np.asarray(m.faces, np.int64).copy()


def tire(rng: np.random.Generator) -> Shape:
    tube = rng.uniform(0.04, 0.09)
    major = rng.uniform(max(0.12, tube + 0.04), 0.34 - tube)
    flatten = rng.uniform(0.8, 1.3)
    pose = sh.pick(rng, {'lying': 0.4, 'upright': 0.3, 'leaning': 0.2, 'stacked': 0.1})
    if pose == 'stacked':
        n = int(rng.integers(2, 4))
        bodies = []
        v0, f0 = _torus(major, tube, flatten)
        thick = float(v0[:, 2].max())
        for k in range(n):
            off = rng.normal(0.0, 0.01, 2)
            bodies.append((v0 + np.array([off[0], off[1], k * 0.97 * thick]), f0))
        v, f = sh.join(bodies)
        return Shape(sh.settle(v), f, 'lying', 'piled', True, {'tires': n, 'major': major})
    v, f = _torus(major, tube, flatten)
    if pose == 'upright':
        v = sh.lying(v)
    elif pose == 'leaning':
        v = sh.tilt(v, math.radians(rng.uniform(20, 60)), rng.uniform(0, 2 * math.pi))
    return Shape(v, f, pose, 'single', True, {'major': major, 'tube': tube})


def cinder(rng: np.random.Generator) -> Shape:
    length = rng.uniform(0.3, 0.45)
    width = rng.uniform(0.15, 0.23)
    h = rng.uniform(0.15, 0.23)
    cores = int(rng.integers(2, 4))
    wall, web = rng.uniform(0.025, 0.035), rng.uniform(0.02, 0.03)
    on_side = rng.uniform() < 0.4
    v, f = sh.cinder_block(length, width, h, cores, wall, web, on_side)
    if rng.uniform() < 0.3:  # another block on top, square or crossed
        top = v.copy()
        if rng.uniform() < 0.5:
            top = _yawed(top, math.pi / 2)
        top = top + np.array([rng.normal(0, 0.03), rng.normal(0, 0.03), float(v[:, 2].max())])
        v, f = sh.join([(v, f), (top, f)])
        return Shape(sh.settle(v), f, 'lying' if on_side else 'upright', 'piled', True,
                     {'cores': cores, 'blocks': 2})
    return Shape(v, f, 'lying' if on_side else 'upright', 'single', True, {'cores': cores})


def post(rng: np.random.Generator) -> Shape:
    h = rng.uniform(0.25, 0.6)
    if rng.uniform() < 0.5:
        side = rng.uniform(0.04, 0.12)
        v, f = sh.box((side, side, h), (0, 0, 0.5 * h))
        params = {'square': side}
    else:
        r = rng.uniform(0.025, 0.06)
        v, f = sh.rod((0, 0, 0), (0, 0, h), r, 12)
        params = {'radius': r}
    pose = sh.pick(rng, {'upright': 0.6, 'leaning': 0.4})
    if pose == 'leaning':
        v = sh.tilt(v, math.radians(rng.uniform(10, 40)), rng.uniform(0, 2 * math.pi))
    return Shape(sh.settle(v), f, pose, params=params)


def cone(rng: np.random.Generator) -> Shape:
    side = rng.uniform(0.25, 0.38)
    plate = rng.uniform(0.02, 0.035)
    h = rng.uniform(0.28, 0.55)
    rb = min(rng.uniform(0.11, 0.16), 0.45 * side)
    rt = rng.uniform(0.02, 0.03)
    w = rng.uniform(0.004, 0.008)
    shell = np.array([[0.0, h - w], [rt - w, h - w], [rb - w, 0.0], [rb, 0.0], [rt, h],
                      [0.0, h]])
    sv, sf = sh.revolved(shell, 32)
    bodies = [(sv + np.array([0.0, 0.0, plate]), sf)]
    hole = 0.5 * min(1.8 * rb, side - 0.04)
    rim = 0.5 * side - hole  # the base plate is a square frame around the cone's opening
    for sx, sy, ex, ey in ((0, 1, side, rim), (0, -1, side, rim), (1, 0, rim, 2 * hole),
                           (-1, 0, rim, 2 * hole)):
        bodies.append(sh.box((ex, ey, plate), (sx * (hole + 0.5 * rim), sy * (hole + 0.5 * rim),
                                               0.5 * plate)))
    v, f = sh.join(bodies)
    pose = sh.pick(rng, {'upright': 0.65, 'lying': 0.35})
    if pose == 'lying':  # knocked over
        v = sh.settle(v @ sh.rotation((1.0, 0.0, 0.0), math.radians(rng.uniform(70, 90))).T)
    return Shape(sh.settle(v), f, pose, 'single', pose == 'lying', {'height': h + plate})


def coil(rng: np.random.Generator) -> Shape:
    radius = rng.uniform(0.12, 0.29)
    wire = rng.uniform(0.004, 0.012)
    pitch = rng.uniform(0.025, 0.08)
    turns = rng.uniform(3.0, min(10.0, 0.66 / pitch))
    n = int(math.ceil(turns * 16)) + 1
    t = np.linspace(0.0, turns * 2 * math.pi, n)
    helix = np.stack([radius * np.cos(t), radius * np.sin(t), pitch * t / (2 * math.pi)], axis=1)
    bodies = [sh.tube(helix, wire, 6)]
    length = float(helix[-1, 2])
    for k in range(int(rng.integers(0, 5))):  # the fence's line wires along the roll
        ang = 2 * math.pi * k / 4 + rng.uniform(0, 0.3)
        p = np.array([radius * math.cos(ang), radius * math.sin(ang), 0.0])
        bodies.append(sh.rod(p, p + np.array([0.0, 0.0, length]), 0.8 * wire, 6))
    v, f = sh.join(bodies)
    pose = sh.pick(rng, {'lying': 0.7, 'upright': 0.3})
    v = sh.lying(v) if pose == 'lying' else sh.settle(v)
    return Shape(v, f, pose, 'single', True, {'radius': radius, 'wire': wire, 'turns': turns})


def pallet(rng: np.random.Generator) -> Shape:
    def one() -> tuple[list[sh.Body], float]:
        length, width = rng.uniform(0.4, 0.68), rng.uniform(0.35, 0.68)
        sh_h, sh_w = rng.uniform(0.07, 0.1), rng.uniform(0.035, 0.05)
        deck = rng.uniform(0.016, 0.022)
        bottom = int(rng.integers(0, 4))
        z0 = deck if bottom else 0.0
        parts = []
        n_str = int(rng.integers(2, 4))
        for y in np.linspace(-0.5 * (width - sh_w), 0.5 * (width - sh_w), n_str):
            parts.append(sh.box((length, sh_w, sh_h), (0.0, y, z0 + 0.5 * sh_h)))
        n_top = int(rng.integers(3, 7))
        board = min(rng.uniform(0.08, 0.14), 0.9 * length / n_top)
        for x in np.linspace(-0.5 * (length - board), 0.5 * (length - board), n_top):
            parts.append(sh.box((board, width, deck), (x, 0.0, z0 + sh_h + 0.5 * deck)))
        if bottom:
            for x in np.linspace(-0.5 * (length - board), 0.5 * (length - board), bottom):
                parts.append(sh.box((board, width, deck), (x, 0.0, 0.5 * deck)))
        return parts, z0 + sh_h + deck

    arrangement = sh.pick(rng, {'single': 0.7, 'piled': 0.3})
    bodies, z = one()
    if arrangement == 'piled':
        for _ in range(int(rng.integers(1, 3))):
            parts, top = one()
            dz, off = z, rng.normal(0.0, 0.02, 2)
            bodies += [(pv + np.array([off[0], off[1], dz]), pf) for pv, pf in parts]
            z += top
    v, f = sh.join(bodies)
    pose = 'lying'
    if arrangement == 'single' and rng.uniform() < 0.25:  # standing on an edge, leaning
        pose = 'leaning'
        v = sh.tilt(v, math.radians(rng.uniform(55, 85)), rng.uniform(0, 2 * math.pi))
    return Shape(sh.settle(v), f, pose, arrangement, True, {})


def sack(rng: np.random.Generator) -> Shape:
    import trimesh

    def one() -> sh.Body:
        length, width = rng.uniform(0.35, 0.7), rng.uniform(0.25, 0.45)
        h = rng.uniform(0.1, 0.3)
        m = trimesh.creation.icosphere(subdivisions=2)
        v = np.asarray(m.vertices, float) * np.array([0.5 * length, 0.5 * width, 0.5 * h])
        # A filled sack: a flat underside, a sagging top, lumps of its contents.
        v[:, 2] = np.where(v[:, 2] < -0.2 * h, -0.2 * h + 0.2 * (v[:, 2] + 0.2 * h), v[:, 2])
        v[:, 2] *= 1.0 - 0.25 * (2.0 * v[:, 0] / length) ** 2
        k = rng.standard_normal((3, 3)) * 6.0
        lumps = np.sin(v @ k + rng.uniform(0, 2 * math.pi, 3)).sum(axis=1, keepdims=True)
        v *= 1.0 + 0.04 * lumps
        return sh.settle(v), np.asarray(m.faces, np.int64).copy()

    arrangement = sh.pick(rng, {'single': 0.7, 'piled': 0.3})
    pieces = [one() for _ in range(1 if arrangement == 'single' else int(rng.integers(2, 4)))]
    v, f = sh.join(sh.heap(rng, pieces, 0.1 if len(pieces) > 1 else 0.0, 0.03))
    return Shape(sh.settle(v), f, 'lying', arrangement, False, {'sacks': len(pieces)})
