"""Obstacle families: parametric generators of many instances, described by shape traits.

A *family* is a generator of obstacle meshes (a boulder, a bucket, a coil of fencing ...): an
*instance* is one draw from it, made from the family's own seed stream,
``SeedSequence([FAMILY_SEED, family.code, index])``, so that instance ``index`` of a family is
the same mesh on every machine and in every process, whoever asks for it first. Each family is
described by what a landing site's obstacle can be rather than by a name:

==============  ===============================================================================
origin          natural / man-made
fill            solid; hollow (a cavity open to the outside in some poses: a bucket, a pipe);
                gappy (rays pass between its parts: slats, sticks, wire)
form            compact / elongated / flat
poses           upright / lying / leaning (each family draws among the ones it lists)
arrangement     single / piled (stacked or heaped pieces)
surface         smooth / irregular
==============  ===============================================================================

Instances stand 10 to 60 cm high (each family its own range) and at most 70 cm across, with no
vertex farther than 48 cm from the centre of the footprint, so that any yaw fits a 1 m tile.
An instance is partly buried when placed: ``ObstacleModel.embed`` is drawn from the family's
``bury`` range (a share of its height), leaving at least 10 cm above the ground.

**The split.** Families are split into a train and a test group (:data:`TEST_FAMILIES`: never in
a training set), and every family's instances are split by index: indices below
:data:`TEST_BASE` are train instances, from it on test instances, so their seed streams are
disjoint. Training draws train instances of train families; a test split draws test instances
of every family.

**The library** (:mod:`landing_zone.tools.sim.obstacles`) stays as it is: its four kinds are families
here (``rock``, ``tire``, ``cinder_block``, ``box``) whose fixed models keep their names and
train/test groups; the families' generators make further instances of them, named like every
instance ``FAMILY/INDEX`` (``rock/1073741830``). ``get_model`` of the obstacle module resolves
both kinds of name.

Meshes are built from trimesh bodies (:mod:`landing_zone.tools.sim.shapes`): every body is closed and
consistently wound; bodies of one instance may overlap (first hits are all a ray caster needs).
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Callable

import numpy as np

from landing_zone.errors import SimulationError
from landing_zone.tools.sim import shapes as sh
from landing_zone.tools.sim.obstacles import ObstacleModel, _cinder_block

if TYPE_CHECKING:
    from landing_zone.tools.sim.obstacles import Obstacle
    from landing_zone.tools.sim.terrain import Terrain

__all__ = ['Traits', 'Family', 'Instance', 'FAMILIES', 'TEST_FAMILIES', 'TRAIN_FAMILIES',
           'TEST_BASE', 'FAMILY_SEED', 'MAX_ACROSS', 'MAX_RADIUS', 'MIN_VISIBLE', 'get_family',
           'instance', 'instance_model', 'is_instance_name', 'parse_families',
           'instance_group', 'draw_instance', 'keep_visible']

FAMILY_SEED = 0x5EED_FA71  # first word of every family's seed stream
TEST_BASE = 1 << 30  # instance indices from here on are test instances
MAX_ACROSS = 0.70  # [m] largest horizontal extent of an instance
MAX_RADIUS = 0.48  # [m] no vertex farther from the footprint's centre (fits a 1 m tile)
MIN_VISIBLE = 0.10  # [m] an instance stands at least this high above the ground when placed
MAX_HEIGHT = 0.60  # [m]


@dataclass(frozen=True)
class Traits:
    """What kind of obstacle a family makes (see the module's table)."""

    origin: str  # 'natural' | 'man-made'
    fill: str  # 'solid' | 'hollow' | 'gappy'
    form: str  # 'compact' | 'elongated' | 'flat'
    poses: tuple[str, ...]  # of 'upright', 'lying', 'leaning'
    arrangement: tuple[str, ...]  # of 'single', 'piled'
    surface: str  # 'smooth' | 'irregular'

    def to_json(self) -> dict:
        return {'origin': self.origin, 'fill': self.fill, 'form': self.form,
                'poses': list(self.poses), 'arrangement': list(self.arrangement),
                'surface': self.surface}


@dataclass
class Shape:
    """What a generator returns: the mesh at its true size and how it came out."""

    vertices: np.ndarray
    faces: np.ndarray
    pose: str
    arrangement: str = 'single'
    open: bool = False  # a cavity or gaps reachable by rays from outside in this pose
    params: dict = field(default_factory=dict)


@dataclass(frozen=True)
class Family:
    """One generator and what it makes.

    Attributes:
        name: the family's name (also the ``kind`` of its instances).
        code: its seed stream (unique, never changes).
        traits: shape properties.
        height: range of its instances' heights before burial [m].
        bury: range of the share of the height sunk into the ground when placed.
        split: 'train' or 'test' (test families never appear in training sets).
        build: the generator, ``rng -> Shape``.
        library: names of the fixed library models of this family.
        description: one line.
    """

    name: str
    code: int
    traits: Traits
    height: tuple[float, float]
    bury: tuple[float, float]
    split: str
    build: Callable[[np.random.Generator], Shape]
    library: tuple[str, ...] = ()
    description: str = ''

    @property
    def solid(self) -> bool:
        return self.traits.fill == 'solid'

    def to_json(self) -> dict:
        return {'name': self.name, 'code': self.code, 'split': self.split,
                'height': list(self.height), 'bury': list(self.bury),
                'traits': self.traits.to_json(), 'library': list(self.library),
                'description': self.description}


@dataclass(frozen=True)
class Instance:
    """One generated obstacle: its model (as the library's) and how it came out."""

    model: ObstacleModel
    family: str
    index: int
    pose: str
    arrangement: str
    open: bool
    params: dict

    def to_json(self) -> dict:
        return {'family': self.family, 'instance': self.index, 'pose': self.pose,
                'arrangement': self.arrangement, 'open': self.open,
                'size': [round(v, 4) for v in self.model.size],
                'embed': round(self.model.embed, 4)}


# --- helpers -----------------------------------------------------------------------------------

def _yawed(v: np.ndarray, yaw: float) -> np.ndarray:
    return v @ sh.rotation(sh.Z_UP, yaw).T


# --- the generators ----------------------------------------------------------------------------

def _rock(rng: np.random.Generator) -> Shape:
    h = rng.uniform(0.12, 0.50)
    length = rng.uniform(max(0.6 * h, 0.14), 0.68)
    width = rng.uniform(0.5, 1.0) * length
    v, f = sh.noisy_hull(rng, (0.5 * length, 0.5 * width, 0.5 * h))
    v = sh.settle(sh.flatten_bed(v))
    return Shape(v, f, 'lying', params={'length': length, 'width': width})


def _slab(rng: np.random.Generator) -> Shape:
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


def _rubble(rng: np.random.Generator) -> Shape:
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


def _log(rng: np.random.Generator) -> Shape:
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


def _stump(rng: np.random.Generator) -> Shape:
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


def _brush(rng: np.random.Generator) -> Shape:
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


def _box(rng: np.random.Generator) -> Shape:
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


def _crate(rng: np.random.Generator) -> Shape:
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


def _bucket(rng: np.random.Generator) -> Shape:
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


def _pipe(rng: np.random.Generator) -> Shape:
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


def _tire(rng: np.random.Generator) -> Shape:
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


def _cinder(rng: np.random.Generator) -> Shape:
    length = rng.uniform(0.3, 0.45)
    width = rng.uniform(0.15, 0.23)
    h = rng.uniform(0.15, 0.23)
    cores = int(rng.integers(2, 4))
    wall, web = rng.uniform(0.025, 0.035), rng.uniform(0.02, 0.03)
    on_side = rng.uniform() < 0.4
    v, f = _cinder_block(length, width, h, cores, wall, web, on_side)
    if rng.uniform() < 0.3:  # another block on top, square or crossed
        top = v.copy()
        if rng.uniform() < 0.5:
            top = _yawed(top, math.pi / 2)
        top = top + np.array([rng.normal(0, 0.03), rng.normal(0, 0.03), float(v[:, 2].max())])
        v, f = sh.join([(v, f), (top, f)])
        return Shape(sh.settle(v), f, 'lying' if on_side else 'upright', 'piled', True,
                     {'cores': cores, 'blocks': 2})
    return Shape(v, f, 'lying' if on_side else 'upright', 'single', True, {'cores': cores})


def _post(rng: np.random.Generator) -> Shape:
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


def _cone(rng: np.random.Generator) -> Shape:
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


def _coil(rng: np.random.Generator) -> Shape:
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


def _pallet(rng: np.random.Generator) -> Shape:
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


def _sack(rng: np.random.Generator) -> Shape:
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


def _frame(rng: np.random.Generator) -> Shape:
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


def _mesh(rng: np.random.Generator) -> Shape:
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


def _hoop(rng: np.random.Generator) -> Shape:
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


def _assembly(rng: np.random.Generator) -> Shape:
    from landing_zone.tools.sim.assembly import build  # it builds Shapes: imported when first used
    return build(rng)


def _t(origin: str, fill: str, form: str, poses: tuple[str, ...], arrangement: tuple[str, ...],
       surface: str) -> Traits:
    return Traits(origin, fill, form, poses, arrangement, surface)


_S, _P = ('single',), ('single', 'piled')
_FAMILY_LIST = (
    Family('rock', 1, _t('natural', 'solid', 'compact', ('lying',), _S, 'irregular'),
           (0.12, 0.50), (0.05, 0.3), 'train', _rock,
           tuple(f'rock_{k:02d}' for k in range(12)), 'stones and boulders, partly sunk'),
    Family('slab', 2, _t('natural', 'solid', 'flat', ('lying', 'leaning'), _S, 'irregular'),
           (0.10, 0.55), (0.0, 0.25), 'train', _slab, (), 'flat stones, lying or on edge'),
    Family('rubble', 3, _t('man-made', 'solid', 'compact', ('lying',), ('piled',), 'irregular'),
           (0.12, 0.45), (0.0, 0.2), 'train', _rubble, (), 'heaps of bricks and chunks'),
    Family('log', 4, _t('natural', 'solid', 'elongated', ('lying', 'leaning'), _S, 'smooth'),
           (0.10, 0.55), (0.0, 0.15), 'train', _log, (), 'logs and thick branches'),
    Family('stump', 5, _t('natural', 'solid', 'compact', ('upright',), _S, 'irregular'),
           (0.15, 0.55), (0.0, 0.0), 'test', _stump, (), 'tree stumps with roots'),
    Family('brush', 6, _t('natural', 'gappy', 'elongated', ('lying',), ('piled',), 'irregular'),
           (0.12, 0.45), (0.0, 0.1), 'train', _brush, (), 'heaps of sticks'),
    Family('box', 7, _t('man-made', 'solid', 'compact', ('upright', 'leaning'), _P, 'smooth'),
           (0.10, 0.50), (0.0, 0.1), 'train', _box, ('box',), 'closed boxes, stacked or tipped'),
    Family('crate', 8, _t('man-made', 'hollow', 'compact', ('upright', 'lying'), _S, 'smooth'),
           (0.18, 0.50), (0.0, 0.05), 'train', _crate, (), 'open-topped and slatted crates'),
    Family('bucket', 9, _t('man-made', 'hollow', 'compact', ('upright', 'lying'), _S, 'smooth'),
           (0.20, 0.50), (0.0, 0.1), 'test', _bucket, (), 'buckets and pails'),
    Family('pipe', 10, _t('man-made', 'hollow', 'elongated', ('lying', 'upright'), _S,
                          'smooth'),
           (0.10, 0.50), (0.0, 0.2), 'train', _pipe, (), 'pipes and tubes, open both ends'),
    Family('tire', 11, _t('man-made', 'hollow', 'compact', ('lying', 'upright', 'leaning'), _P,
                          'smooth'),
           (0.10, 0.60), (0.0, 0.25), 'train', _tire, ('tire_a', 'tire_b'),
           'tires lying, standing, leaning or stacked'),
    Family('cinder_block', 12, _t('man-made', 'hollow', 'compact', ('upright', 'lying'), _P,
                                  'smooth'),
           (0.15, 0.46), (0.0, 0.15), 'train', _cinder, ('cinder_block_a', 'cinder_block_b'),
           'cinder blocks, cores up or sideways, single or two'),
    Family('post', 13, _t('man-made', 'solid', 'elongated', ('upright', 'leaning'), _S,
                          'smooth'),
           (0.20, 0.60), (0.0, 0.05), 'train', _post, (), 'posts and stakes'),
    Family('cone', 14, _t('man-made', 'hollow', 'compact', ('upright', 'lying'), _S, 'smooth'),
           (0.20, 0.60), (0.0, 0.0), 'train', _cone, (), 'traffic cones, standing or knocked'
           ' over'),
    Family('coil', 15, _t('man-made', 'gappy', 'compact', ('lying', 'upright'), _S, 'smooth'),
           (0.10, 0.60), (0.0, 0.1), 'test', _coil, (), 'rolled fencing and wire coils'),
    Family('pallet', 16, _t('man-made', 'gappy', 'flat', ('lying', 'leaning'), _P, 'smooth'),
           (0.10, 0.60), (0.0, 0.05), 'train', _pallet, (), 'pallet sections, slatted'),
    Family('sack', 17, _t('man-made', 'solid', 'flat', ('lying',), _P, 'smooth'),
           (0.10, 0.50), (0.0, 0.1), 'test', _sack, (), 'filled sacks and sandbags'),
    # Added after synth3 (its scenes draw only SYNTH3_FAMILIES): thin open structure
    Family('frame', 18, _t('man-made', 'gappy', 'compact', ('upright', 'lying', 'leaning'), _S,
                           'smooth'),
           (0.20, 0.60), (0.0, 0.05), 'train', _frame, (),
           'open frames of thin rods: stools, sawhorses, tripods'),
    Family('mesh', 19, _t('man-made', 'gappy', 'flat', ('upright', 'leaning', 'lying'), _S,
                          'smooth'),
           (0.20, 0.60), (0.0, 0.05), 'train', _mesh, (),
           'welded wire mesh: fence panels and wire cages'),
    # Closed loops of thin wire or hose: see-through structure with axes of its own
    Family('hoop', 21, _t('man-made', 'gappy', 'compact', ('upright', 'leaning', 'lying'), _P,
                          'smooth'),
           (0.10, 0.60), (0.0, 0.05), 'train', _hoop, (),
           'loops of wire and hose: hoops on feet or propped, tangles of bent loops'),
    # A shape prior, not a kind of object: random assemblies of solid, hollow and gappy parts
    Family('assembly', 20, _t('man-made', 'gappy', 'compact', ('upright', 'lying', 'leaning'),
                              _P, 'irregular'),
           (0.10, 0.60), (0.0, 0.1), 'train', _assembly, (),
           'random assemblies of blocks, lumps, plates, rods, tubes, rings and shells'),
)
FAMILIES: dict[str, Family] = {f.name: f for f in _FAMILY_LIST}
TEST_FAMILIES = tuple(f.name for f in _FAMILY_LIST if f.split == 'test')
TRAIN_FAMILIES = tuple(f.name for f in _FAMILY_LIST if f.split == 'train')
assert len({f.code for f in _FAMILY_LIST}) == len(_FAMILY_LIST)


def get_family(name: str) -> Family:
    """The family called ``name``.

    Raises:
        SimulationError: no such family.
    """
    if name not in FAMILIES:
        raise SimulationError(f'unknown obstacle family {name!r}; choose from '
                              f'{", ".join(FAMILIES)}')
    return FAMILIES[name]


def parse_families(text: str | list[str] | tuple[str, ...]) -> tuple[str, ...]:
    """Family names from a comma separated list; ``all``, ``train`` and ``test`` stand for the
    families of :data:`FAMILIES`, :data:`TRAIN_FAMILIES` and :data:`TEST_FAMILIES`."""
    items = text.split(',') if isinstance(text, str) else list(text)
    out: list[str] = []
    for item in (i.strip() for i in items):
        if not item:
            continue
        names = {'all': tuple(FAMILIES), 'train': TRAIN_FAMILIES,
                 'test': TEST_FAMILIES}.get(item, (item,))
        for name in names:
            get_family(name)
            if name not in out:
                out.append(name)
    return tuple(out)


def instance_group(index: int) -> str:
    """'train' or 'test': which instances a split may use (by index, so by seed stream)."""
    return 'test' if index >= TEST_BASE else 'train'


def _check_index(index: int) -> int:
    if not isinstance(index, (int, np.integer)) or not 0 <= int(index) < 2 * TEST_BASE:
        raise SimulationError(f'obstacle instance index must be an integer in [0, '
                              f'{2 * TEST_BASE}), got {index!r}')
    return int(index)


@functools.lru_cache(maxsize=512)
def instance(family: str, index: int) -> Instance:
    """Instance ``index`` of ``family``: the same mesh in every process.

    Its height is brought into the family's range and its footprint within
    :data:`MAX_ACROSS` and :data:`MAX_RADIUS` (horizontal shrink), and its burial depth drawn.

    Raises:
        SimulationError: unknown family or bad index.
    """
    fam = get_family(family)
    index = _check_index(index)
    rng = np.random.default_rng(np.random.SeedSequence([FAMILY_SEED, fam.code, index]))
    shape = fam.build(rng)
    v = sh.settle(np.asarray(shape.vertices, dtype=np.float64))
    height = float(np.clip(v[:, 2].max(), fam.height[0], min(fam.height[1], MAX_HEIGHT)))
    v = sh.fit(v, height, MAX_ACROSS, MAX_RADIUS)
    bury = rng.uniform(*fam.bury) if fam.bury[1] > 0 else 0.0
    embed = float(min(bury * height, max(height - MIN_VISIBLE, 0.0)))
    model = ObstacleModel(f'{family}/{index}', family, instance_group(index), v,
                          np.asarray(shape.faces, dtype=np.int64), embed=embed)
    return Instance(model, family, index, shape.pose, shape.arrangement, shape.open,
                    dict(shape.params))


def is_instance_name(name: str) -> bool:
    """Whether ``name`` names a family instance (``FAMILY/INDEX``)."""
    fam, sep, idx = name.partition('/')
    return bool(sep) and fam in FAMILIES and idx.isdigit()


def instance_model(name: str) -> ObstacleModel:
    """The model of the instance called ``FAMILY/INDEX``.

    Raises:
        SimulationError: not an instance name.
    """
    if not is_instance_name(name):
        raise SimulationError(f'{name!r} is no obstacle instance name (FAMILY/INDEX with '
                              f'FAMILY one of {", ".join(FAMILIES)})')
    fam, _, idx = name.partition('/')
    return instance(fam, int(idx)).model


def draw_instance(family: str, group: str | None, rng: np.random.Generator) -> Instance:
    """A random instance of ``family`` from the instances of ``group`` ('train', 'test';
    None: test instances, what an evaluation flight or an insertion into a user's bag wants)."""
    if group not in (None, 'train', 'test'):
        raise SimulationError(f"obstacle group must be 'train' or 'test', got {group!r}")
    base = 0 if group == 'train' else TEST_BASE
    return instance(family, base + int(rng.integers(TEST_BASE)))


def keep_visible(obstacle: 'Obstacle', terrain: 'Terrain') -> 'Obstacle':
    """``obstacle`` raised, if need be, until it stands :data:`MIN_VISIBLE` above the ground
    beneath it: placing on the lowest ground under the footprint sinks it on the uphill side
    of a slope, and a buried instance could vanish there."""
    from dataclasses import replace
    v = obstacle.vertices()
    above = float(np.max(v[:, 2] - terrain.height(v[:, 0], v[:, 1])))
    if above < MIN_VISIBLE:
        return replace(obstacle, z=obstacle.z + MIN_VISIBLE - above)
    return obstacle
