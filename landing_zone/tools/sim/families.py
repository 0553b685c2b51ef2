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

**The library** (:mod:`landing_zone.tools.sim.library`) stays as it is: its four kinds are
families here (``rock``, ``tire``, ``cinder_block``, ``box``) whose fixed models keep their names
and train/test groups; the families' generators make further instances of them, named like
every instance ``FAMILY/INDEX`` (``rock/1073741830``). The library's ``get_model`` resolves both
kinds of name.

The generators live by kind (:mod:`~landing_zone.tools.sim.family_natural`,
:mod:`~landing_zone.tools.sim.family_manmade`, :mod:`~landing_zone.tools.sim.family_open`,
:mod:`~landing_zone.tools.sim.assembly`); this module is their catalogue and draws instances.
Meshes are built from trimesh bodies (:mod:`landing_zone.tools.sim.shapes`): every body is closed
and consistently wound; bodies of one instance may overlap (first hits are all a ray caster
needs).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, replace
from typing import Callable

import numpy as np

from landing_zone.errors import SimulationError
from landing_zone.tools.sim import family_manmade as made
from landing_zone.tools.sim import family_natural as nat
from landing_zone.tools.sim import family_open as opn
from landing_zone.tools.sim import shapes as sh
from landing_zone.tools.sim.assembly import build as build_assembly
from landing_zone.tools.sim.family_shape import MAX_ACROSS, MAX_HEIGHT, MAX_RADIUS, \
    MIN_VISIBLE, Shape
from landing_zone.tools.sim.obstacles import Obstacle, ObstacleModel
from landing_zone.tools.sim.terrain import Terrain

__all__ = ['Traits', 'Family', 'Instance', 'FAMILIES', 'TEST_FAMILIES', 'TRAIN_FAMILIES',
           'TEST_BASE', 'FAMILY_SEED', 'get_family',
           'instance', 'instance_model', 'is_instance_name', 'parse_families',
           'instance_group', 'draw_instance', 'keep_visible']

FAMILY_SEED = 0x5EED_FA71  # first word of every family's seed stream
TEST_BASE = 1 << 30  # instance indices from here on are test instances


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


def _t(origin: str, fill: str, form: str, poses: tuple[str, ...], arrangement: tuple[str, ...],
       surface: str) -> Traits:
    return Traits(origin, fill, form, poses, arrangement, surface)


_S, _P = ('single',), ('single', 'piled')
_FAMILY_LIST = (
    Family('rock', 1, _t('natural', 'solid', 'compact', ('lying',), _S, 'irregular'),
           (0.12, 0.50), (0.05, 0.3), 'train', nat.rock,
           tuple(f'rock_{k:02d}' for k in range(12)), 'stones and boulders, partly sunk'),
    Family('slab', 2, _t('natural', 'solid', 'flat', ('lying', 'leaning'), _S, 'irregular'),
           (0.10, 0.55), (0.0, 0.25), 'train', nat.slab, (), 'flat stones, lying or on edge'),
    Family('rubble', 3, _t('man-made', 'solid', 'compact', ('lying',), ('piled',), 'irregular'),
           (0.12, 0.45), (0.0, 0.2), 'train', nat.rubble, (), 'heaps of bricks and chunks'),
    Family('log', 4, _t('natural', 'solid', 'elongated', ('lying', 'leaning'), _S, 'smooth'),
           (0.10, 0.55), (0.0, 0.15), 'train', nat.log, (), 'logs and thick branches'),
    Family('stump', 5, _t('natural', 'solid', 'compact', ('upright',), _S, 'irregular'),
           (0.15, 0.55), (0.0, 0.0), 'test', nat.stump, (), 'tree stumps with roots'),
    Family('brush', 6, _t('natural', 'gappy', 'elongated', ('lying',), ('piled',), 'irregular'),
           (0.12, 0.45), (0.0, 0.1), 'train', nat.brush, (), 'heaps of sticks'),
    Family('box', 7, _t('man-made', 'solid', 'compact', ('upright', 'leaning'), _P, 'smooth'),
           (0.10, 0.50), (0.0, 0.1), 'train', made.box, ('box',),
           'closed boxes, stacked or tipped'),
    Family('crate', 8, _t('man-made', 'hollow', 'compact', ('upright', 'lying'), _S, 'smooth'),
           (0.18, 0.50), (0.0, 0.05), 'train', made.crate, (), 'open-topped and slatted crates'),
    Family('bucket', 9, _t('man-made', 'hollow', 'compact', ('upright', 'lying'), _S, 'smooth'),
           (0.20, 0.50), (0.0, 0.1), 'test', made.bucket, (), 'buckets and pails'),
    Family('pipe', 10, _t('man-made', 'hollow', 'elongated', ('lying', 'upright'), _S,
                          'smooth'),
           (0.10, 0.50), (0.0, 0.2), 'train', made.pipe, (), 'pipes and tubes, open both ends'),
    Family('tire', 11, _t('man-made', 'hollow', 'compact', ('lying', 'upright', 'leaning'), _P,
                          'smooth'),
           (0.10, 0.60), (0.0, 0.25), 'train', made.tire, ('tire_a', 'tire_b'),
           'tires lying, standing, leaning or stacked'),
    Family('cinder_block', 12, _t('man-made', 'hollow', 'compact', ('upright', 'lying'), _P,
                                  'smooth'),
           (0.15, 0.46), (0.0, 0.15), 'train', made.cinder, ('cinder_block_a', 'cinder_block_b'),
           'cinder blocks, cores up or sideways, single or two'),
    Family('post', 13, _t('man-made', 'solid', 'elongated', ('upright', 'leaning'), _S,
                          'smooth'),
           (0.20, 0.60), (0.0, 0.05), 'train', made.post, (), 'posts and stakes'),
    Family('cone', 14, _t('man-made', 'hollow', 'compact', ('upright', 'lying'), _S, 'smooth'),
           (0.20, 0.60), (0.0, 0.0), 'train', made.cone, (), 'traffic cones, standing or knocked'
           ' over'),
    Family('coil', 15, _t('man-made', 'gappy', 'compact', ('lying', 'upright'), _S, 'smooth'),
           (0.10, 0.60), (0.0, 0.1), 'test', made.coil, (), 'rolled fencing and wire coils'),
    Family('pallet', 16, _t('man-made', 'gappy', 'flat', ('lying', 'leaning'), _P, 'smooth'),
           (0.10, 0.60), (0.0, 0.05), 'train', made.pallet, (), 'pallet sections, slatted'),
    Family('sack', 17, _t('man-made', 'solid', 'flat', ('lying',), _P, 'smooth'),
           (0.10, 0.50), (0.0, 0.1), 'test', made.sack, (), 'filled sacks and sandbags'),
    # Added after synth3 (its scenes draw only SYNTH3_FAMILIES): thin open structure
    Family('frame', 18, _t('man-made', 'gappy', 'compact', ('upright', 'lying', 'leaning'), _S,
                           'smooth'),
           (0.20, 0.60), (0.0, 0.05), 'train', opn.frame, (),
           'open frames of thin rods: stools, sawhorses, tripods'),
    Family('mesh', 19, _t('man-made', 'gappy', 'flat', ('upright', 'leaning', 'lying'), _S,
                          'smooth'),
           (0.20, 0.60), (0.0, 0.05), 'train', opn.mesh, (),
           'welded wire mesh: fence panels and wire cages'),
    # Closed loops of thin wire or hose: see-through structure with axes of its own
    Family('hoop', 21, _t('man-made', 'gappy', 'compact', ('upright', 'leaning', 'lying'), _P,
                          'smooth'),
           (0.10, 0.60), (0.0, 0.05), 'train', opn.hoop, (),
           'loops of wire and hose: hoops on feet or propped, tangles of bent loops'),
    # A shape prior, not a kind of object: random assemblies of solid, hollow and gappy parts
    Family('assembly', 20, _t('man-made', 'gappy', 'compact', ('upright', 'lying', 'leaning'),
                              _P, 'irregular'),
           (0.10, 0.60), (0.0, 0.1), 'train', build_assembly, (),
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


def keep_visible(obstacle: Obstacle, terrain: Terrain) -> Obstacle:
    """``obstacle`` raised, if need be, until it stands :data:`MIN_VISIBLE` above the ground
    beneath it: placing on the lowest ground under the footprint sinks it on the uphill side
    of a slope, and a buried instance could vanish there."""
    v = obstacle.vertices()
    above = float(np.max(v[:, 2] - terrain.height(v[:, 0], v[:, 1])))
    if above < MIN_VISIBLE:
        return replace(obstacle, z=obstacle.z + MIN_VISIBLE - above)
    return obstacle
