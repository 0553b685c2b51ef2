"""synth3: labelled patches drawn from every family of obstacle, vegetation, terrain and sensor.

synth1 and synth2 are the paper's Cartesian sweeps over one obstacle library, one kind of grass,
near-flat ground and one scanner; synth3 draws every patch from the families of
:mod:`landing_zone.tools.sim.families` (obstacles), :mod:`landing_zone.tools.sim.vegetation`
(ground cover),
:data:`TERRAIN_FAMILIES` and :data:`SENSOR_FAMILIES` (the nodding line scanner hovering as in
synth2, or a pass of a pushbroom line, spinning multi-beam, rosette or elliptical scanner,
:mod:`landing_zone.tools.sim.flyover`), at 1000-5000 returns/m^2 from 4-20 m up (spinning scanners
4-12 m).

**The plan.** Scenes come in pairs (``index // 2``) that share everything drawn before any
world exists (:func:`scene_plan`): the split, the obstacle family and instance, the vegetation
family and its parameters, the terrain, the sensor and where it flies. One scene of a pair holds
the obstacle (label 0), the other does not (label 1); which one is a hash of the pair. So every
family's scenes are balanced, the safe scene is drawn as its unsafe twin is (nothing but the
obstacle tells them apart), and dropping a family drops whole pairs. In three of ten pairs the
blades grow to 60-110 % of the obstacle's visible height (``hide``), in both scenes of the pair.

**The split.** A hash of the pair puts a quarter of the pairs into the test split. Train pairs
draw their obstacle from the train families
(:data:`~landing_zone.tools.sim.families.TRAIN_FAMILIES`
among the dataset's) and from the train instances (index = pair number); test pairs from every
family and from its test instances (index = ``TEST_BASE`` + pair number). So the test split
holds families never trained on and, for the others, instances whose seed streams training never
saw.

**Its obstacle families** are :data:`SYNTH3_FAMILIES`, the 17 families the dataset was made
with, fixed so that its scenes stay what they were as families are added. ``families`` (``landing-
zone simulate --dataset synth3 --families frame,mesh``) draws from other families instead, with
the same split rule (train pairs from the train families among them); such a dataset records its
families in ``meta.json`` and mixes their codes into every seed, so it shares no draw with the
default one.

**Obstacles at the tile's edge** (``edge``, ``landing-zone simulate --dataset synth3 --edge
0.5``): in that share of the pairs both scenes hold the obstacle at one edge of the tile, the same
instance turned the same way: in the unsafe scene its part standing 10 cm or more above the
ground (its upper half, if lower) reaches 5-30 cm into the tile (:data:`EDGE_REACH`); in the
safe one the whole of it stands 15-30 cm beyond the edge (:data:`EDGE_GAP`), where the
network's 30 cm of context still sees it (an obstacle in the next tile, as on every site).
Closer than 15 cm the 10 cm pooled input barely tells beyond from in, and safe scenes there
teach the net to hedge on every tile. Elsewhere a safe scene holds no obstacle and an unsafe one's
obstacle reaches at least half its radius in, so without these pairs the net never learns where
a neighbour's obstacle ends. Such a dataset records the share in ``meta.json`` and mixes it into
every seed, as other ``families`` are.

**Leave one family out.** Every scene's ``params`` name its ``family`` (obstacle; the safe twin
names its pair's), ``vegetation``, ``terrain`` and ``sensor``, and ``meta.json`` lists them per
shard, so a trainer can drop a family without reading a shard
(:mod:`landing_zone.tools.evaluate.lofo`,
``landing-zone train --hold-out obstacle:FAMILY``) and ``landing-zone evaluate --by-family``
reports each family of the test split.

**Format, determinism, resuming**: as synth1/synth2 (:mod:`landing_zone.tools.sim.dataset`); scene
``i`` draws its world from ``SeedSequence([seed, 3, i])``, its pair's plan from
``SeedSequence([seed, 3, pair, PLAN])`` (with other ``families``, their codes appended to both;
with ``edge``, its word and the share in thousandths after them; with other ``vegetation``
families, e.g. the meadow prior, its word and their indices last).
"""
from __future__ import annotations

import math
from typing import Any, Sequence

import numpy as np

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.families import TEST_BASE, get_family
from landing_zone.tools.sim.hashing import mix
from landing_zone.tools.sim.scene import PatchConfig
from landing_zone.tools.sim.shards import FORMAT_VERSION, shard_name
from landing_zone.tools.sim.vegetation import SAFE_SHRUB_HEIGHT, SYNTH3_VEGETATION, \
    VEGETATION_FAMILIES, check_vegetation, draw_vegetation

__all__ = ['SYNTH3_CODE', 'SYNTH3_FAMILIES', 'synth3_train_families', 'check_families',
           'TERRAIN_FAMILIES', 'SENSOR_FAMILIES', 'DEFAULT_SCENES', 'MAX_SCENES',
           'TEST_FRACTION', 'scene_plan', 'select_scenes', 'plan_meta',
           'FAMILY_AXES', 'check_edge', 'EDGE_GAP', 'EDGE_REACH', 'EDGE_TALL', 'variant_key']

SYNTH3_CODE = 3  # the dataset's word in every seed
_PLAN = 0x91A4  # the plan's word
_EDGE = 0xED6E  # the word of a dataset with obstacles at the tile's edge
_VEGETATION = 0x7E6E  # the word of a dataset of other vegetation families
EDGE_GAP = (0.15, 0.3)  # [m] a safe scene's obstacle stands this far beyond the tile's edge
EDGE_REACH = (0.05, 0.3)  # [m] an unsafe one's reaches this far in
EDGE_TALL = 0.10  # [m] what reaches in: the part this high above ground (or its top half)
TEST_FRACTION = 0.25
DEFAULT_SCENES = 40_000
MAX_SCENES = 1 << 24
HIDE_SHARE = 0.3  # pairs whose blades grow to hide the obstacle
TERRAIN_FAMILIES = {'flat': 0.4, 'sloped': 0.35, 'rough': 0.25}
SENSOR_FAMILIES = {'nodding': 0.3, 'line': 0.2, 'spinning': 0.15, 'rosette': 0.15,
                   'elliptical': 0.2}
FAMILY_AXES = ('obstacle', 'vegetation', 'terrain', 'sensor')  # the hold-out axes
# The obstacle families synth3 was made with (frozen: families added later draw no scene of it)
SYNTH3_FAMILIES = ('rock', 'slab', 'rubble', 'log', 'stump', 'brush', 'box', 'crate', 'bucket',
                   'pipe', 'tire', 'cinder_block', 'post', 'cone', 'coil', 'pallet', 'sack')
_DENSITY = (1000.0, 5000.0)  # returns per m^2, log-uniform


def _choice(rng: np.random.Generator, weights: dict[str, float]) -> str:
    keys = list(weights)
    p = np.array([weights[k] for k in keys])
    return keys[int(rng.choice(len(keys), p=p / p.sum()))]


def _r(v: float, digits: int = 4) -> float:
    return round(float(v), digits)


def _pair_split(pair: int) -> str:
    h = int(mix(np.uint64(pair) + np.uint64(0x53_3D << 32)) % np.uint64(1000))
    return 'test' if h < int(1000 * TEST_FRACTION) else 'train'


def _pair_unsafe_member(pair: int) -> int:
    return int(mix(np.uint64(pair) * np.uint64(0x9E37) + np.uint64(3)) & np.uint64(1))


def _terrain_plan(rng: np.random.Generator) -> dict[str, Any]:
    fam = _choice(rng, TERRAIN_FAMILIES)
    if fam == 'flat':
        return {'family': fam, 'amplitude': _r(rng.uniform(0.02, 0.05)),
                'wavelength': _r(rng.uniform(1.5, 3.0)), 'octaves': 2, 'spacing': 0.1,
                'slope': 0.0, 'azimuth': 0.0}
    if fam == 'sloped':
        return {'family': fam, 'amplitude': _r(rng.uniform(0.01, 0.04)),
                'wavelength': _r(rng.uniform(2.0, 4.0)), 'octaves': 2, 'spacing': 0.1,
                'slope': _r(rng.uniform(3.0, 12.0)), 'azimuth': _r(rng.uniform(0, 2 * math.pi))}
    return {'family': fam, 'amplitude': _r(rng.uniform(0.02, 0.05)),
            'wavelength': _r(rng.uniform(0.3, 0.8)), 'octaves': 3, 'spacing': 0.05,
            'slope': _r(rng.uniform(0.0, 4.0)), 'azimuth': _r(rng.uniform(0, 2 * math.pi))}


def _sensor_plan(rng: np.random.Generator) -> dict[str, Any]:
    fam = _choice(rng, SENSOR_FAMILIES)
    density = _r(math.exp(rng.uniform(math.log(_DENSITY[0]), math.log(_DENSITY[1]))), 1)
    heading = _r(rng.uniform(0, 2 * math.pi))
    # Scanners are set up as a survey would be: the spacing of returns along a scan line (or
    # trace) about that between lines, 1 / sqrt(density), and a pass at 3-12 m/s. (A fixed
    # pulse rate and angular step would, at low density from low up, fly tens of metres per
    # second with lines 15 cm apart: obstacles between the lines never seen.)
    spacing = 1.0 / math.sqrt(density)
    speed = rng.uniform(3.0, 12.0)
    if fam == 'nodding':  # hovering beside the tile, as in synth2
        h = _r(rng.uniform(4.0, 20.0), 3)
        dep = math.radians(rng.uniform(20.0, 65.0))
        offset = h / math.tan(dep)
        res = float(np.clip(math.degrees(spacing / math.hypot(h, offset)), 0.02, 0.41))
        return {'family': fam, 'density': density, 'height': h, 'offset': _r(-offset, 3),
                'resolution': _r(res)}
    if fam == 'line':
        h, tilt = _r(rng.uniform(4.0, 20.0), 3), _r(rng.uniform(20.0, 45.0), 2)
        slant = h / math.cos(math.radians(tilt))
        swath = h * math.tan(math.radians(40.0)) / math.cos(math.radians(tilt))
        res = float(np.clip(math.degrees(spacing / slant), 0.01, 0.5))
        prr = float(np.clip(density * speed * 2.0 * swath, 50_000.0, 3_000_000.0))
        return {'family': fam, 'density': density, 'height': h, 'tilt': tilt,
                'prr': _r(prr, 0), 'resolution': _r(res, 5),
                'cross': _r(rng.uniform(-0.8, 0.8) * swath, 3), 'heading': heading}
    if fam == 'spinning':
        h = _r(rng.uniform(4.0, 12.0), 3)
        return {'family': fam, 'density': density, 'height': h, 'tilt': 45.0,
                'beams': int(rng.choice([16, 32])), 'beam_fov': _r(rng.uniform(25.0, 40.0), 2),
                'spin_rate': _r(rng.uniform(10.0, 20.0), 2),
                'prr': _r(rng.uniform(300_000.0, 1_200_000.0), 0),
                'cross': _r(rng.uniform(-0.8, 0.8) * h, 3), 'heading': heading}
    if fam == 'rosette':
        h, tilt = _r(rng.uniform(4.0, 20.0), 3), _r(rng.uniform(0.0, 30.0), 2)
        return {'family': fam, 'density': density, 'height': h, 'tilt': tilt, 'fov': 70.0,
                'prr': _r(rng.uniform(100_000.0, 240_000.0), 0),
                'cross': _r(rng.uniform(-0.6, 0.6) * h * math.tan(math.radians(30.0)), 3),
                'heading': heading}
    h, tilt = _r(rng.uniform(4.0, 20.0), 3), _r(rng.uniform(0.0, 25.0), 2)
    fov = _r(rng.uniform(30.0, 60.0), 2)
    swath = 2.0 * h * math.tan(math.radians(0.5 * fov))
    # The ellipse's front arcs follow each other speed / spin_rate apart (the back arcs fall
    # between them): 3 cm.
    return {'family': fam, 'density': density, 'height': h, 'tilt': tilt, 'fov': fov,
            'spin_rate': _r(np.clip(speed / 0.03, 60.0, 500.0), 2),
            'prr': _r(np.clip(density * speed * swath, 50_000.0, 3_000_000.0), 0),
            'cross': _r(rng.uniform(-0.8, 0.8) * 0.5 * swath, 3), 'heading': heading}


def _check_index(index: int) -> int:
    if not isinstance(index, (int, np.integer)) or not 0 <= int(index) < MAX_SCENES:
        raise SimulationError(f'scene index {index!r} outside synth3 (0..{MAX_SCENES - 1})')
    return int(index)


def _train_among(names: Sequence[str]) -> tuple[str, ...]:
    """The train families among ``names``, in their order (what a train pair draws from)."""
    return tuple(n for n in names if get_family(n).split == 'train')


def synth3_train_families() -> tuple[str, ...]:
    """The train families among :data:`SYNTH3_FAMILIES` (what its train split draws)."""
    return _train_among(SYNTH3_FAMILIES)


def check_families(families: Sequence[str] | None) -> tuple[str, ...] | None:
    """``families`` as the plan takes them: None for synth3's own (:data:`SYNTH3_FAMILIES`, also
    when they are named in their order), else the names in the order given.

    Raises:
        SimulationError: an unknown or repeated family, or none of them a train family.
    """
    if families is None:
        return None
    names = tuple(str(f) for f in families)
    if not names or len(set(names)) != len(names):
        raise SimulationError(f'synth3 families must be distinct names, got {list(names)}')
    if not _train_among(names):  # (an unknown name is refused here, by name)
        raise SimulationError(f'synth3 families {", ".join(names)}: none is a train family, '
                              'so no train pair could draw one')
    return None if names == SYNTH3_FAMILIES else names


def check_edge(edge: float) -> float:
    """``edge`` (the share of pairs at the tile's edge) as the plan takes it: rounded to
    thousandths.

    Raises:
        SimulationError: not a number from 0 to 1.
    """
    if (isinstance(edge, bool) or not isinstance(edge, (int, float, np.floating))
            or not 0.0 <= float(edge) <= 1.0):
        raise SimulationError(f'synth3 --edge must be a share from 0 to 1, got {edge!r}')
    return round(float(edge), 3)


def variant_key(families: tuple[str, ...] | None, edge: float,
                vegetation: tuple[str, ...] | None = None) -> list[int]:
    """What a dataset other than synth3's own mixes into every seed (nothing for its own)."""
    key = [] if families is None else [get_family(n).code for n in families]
    key += [_EDGE, int(round(1000 * edge))] if edge > 0 else []
    return key + ([_VEGETATION] + [VEGETATION_FAMILIES.index(n) for n in vegetation]
                  if vegetation is not None else [])


def scene_plan(index: int, seed: int = 0, families: Sequence[str] | None = None,
               edge: float = 0.0, vegetation: Sequence[str] | None = None) -> dict[str, Any]:
    """Everything scene ``index`` is before its world is drawn (JSON-ready); ``families``:
    the obstacle families to draw from (None: :data:`SYNTH3_FAMILIES`); ``edge``: the share of
    pairs whose obstacle stands at the tile's edge (the plan's ``edge``: which side, where
    along it, how far beyond it in the safe scene, how far in in the unsafe one);
    ``vegetation``: the vegetation families to draw from (None: synth3's own six)."""
    index = _check_index(index)
    fams = check_families(families)
    edge = check_edge(edge)
    vegs = check_vegetation(vegetation)
    pair = index // 2
    split = _pair_split(pair)
    unsafe = (index % 2) == _pair_unsafe_member(pair)
    rng = np.random.default_rng(np.random.SeedSequence([int(seed), SYNTH3_CODE, pair, _PLAN]
                                                       + variant_key(fams, edge, vegs)))
    every = SYNTH3_FAMILIES if fams is None else fams
    pool = _train_among(every) if split == 'train' else every
    family = pool[int(rng.integers(len(pool)))]
    veg_pool = SYNTH3_VEGETATION if vegs is None else vegs
    veg = veg_pool[int(rng.integers(len(veg_pool)))]
    plan = {'dataset': 'synth3', 'index': index, 'pair': pair, 'split': split,
            'label': 0 if unsafe else 1, 'family': family,
            'instance': pair + (TEST_BASE if split == 'test' else 0),
            'vegetation': draw_vegetation(veg, rng),
            'hide': _r(rng.uniform(0.6, 1.1)) if rng.uniform() < HIDE_SHARE else None,
            'terrain': _terrain_plan(rng), 'sensor': _sensor_plan(rng),
            'inside': bool(rng.uniform() < 0.5)}
    if edge > 0 and rng.uniform() < edge:  # (drawn after all else: the other draws stay)
        plan['edge'] = {'side': int(rng.integers(4)), 'along': _r(rng.uniform(-0.45, 0.45)),
                        'gap': _r(rng.uniform(*EDGE_GAP)),
                        'reach': _r(rng.uniform(*EDGE_REACH)),
                        'yaw': _r(rng.uniform(0.0, 2.0 * math.pi))}
    return plan


def families_of(plan: dict[str, Any]) -> dict[str, str]:
    """The family on each hold-out axis of a plan (or of a scene's params)."""
    return {'obstacle': plan['family'], 'vegetation': plan['vegetation']['family'],
            'terrain': plan['terrain']['family'], 'sensor': plan['sensor']['family']}


def select_scenes(scenes: int | None = None, split: str = 'both') -> np.ndarray:
    """Canonical indices: the first ``scenes`` (default :data:`DEFAULT_SCENES`) of ``split``."""
    if split not in ('train', 'test', 'both'):
        raise SimulationError(f"split must be one of train, test, both, got {split!r}")
    n = DEFAULT_SCENES if scenes is None else scenes
    if not isinstance(n, (int, np.integer)) or not 1 <= n <= MAX_SCENES // 2:
        raise SimulationError(f'--scenes must be a positive integer (at most '
                              f'{MAX_SCENES // 2}), got {scenes!r}')
    if split == 'both':
        return np.arange(n, dtype=np.int64)
    out = []
    pair = 0
    while len(out) < n:
        if _pair_split(pair) == split:
            out += [2 * pair, 2 * pair + 1]
        pair += 1
    return np.asarray(out[:n], dtype=np.int64)


def plan_meta(seed: int, split: str, scenes: int | None, shard_size: int,
              selected: np.ndarray, families: Sequence[str] | None = None,
              edge: float = 0.0, vegetation: Sequence[str] | None = None) -> dict[str, Any]:
    """meta.json of a synth3 directory (the synth2 layout, plus the families of every scene;
    with other ``families``, their names under ``obstacle_families``; with ``edge``, the share
    and its ranges under ``edge``; with other ``vegetation``, its names under
    ``vegetation_families``)."""
    chosen = check_families(families)
    edge = check_edge(edge)
    vegs = check_vegetation(vegetation)
    every = SYNTH3_FAMILIES if chosen is None else chosen
    train = _train_among(every)
    plans = [scene_plan(int(i), seed, chosen, edge, vegs) for i in selected]
    counts = {s: {'safe': 0, 'unsafe': 0} for s in ('train', 'test')}
    for p in plans:
        counts[p['split']]['safe' if p['label'] == 1 else 'unsafe'] += 1
    shards = []
    for k in range(0, len(plans), shard_size):
        chunk = plans[k:k + shard_size]
        fams = [families_of(p) for p in chunk]
        shards.append({'file': shard_name(k // shard_size), 'scenes': len(chunk),
                       'first_index': chunk[0]['index'],
                       'test': ''.join('1' if p['split'] == 'test' else '0' for p in chunk),
                       'labels': ''.join(str(p['label']) for p in chunk),
                       'families': {a: [f[a] for f in fams] for a in FAMILY_AXES}})
    patch = PatchConfig()
    return {
        'format': 'landing_zone.tools.sim.dataset', 'format_version': FORMAT_VERSION,
        'dataset': 'synth3', 'seed': int(seed), 'split': split, 'scenes_requested': scenes,
        'n_scenes': len(plans), 'shard_size': shard_size, 'test_fraction': TEST_FRACTION,
        'counts': counts,
        **({'obstacle_families': list(chosen)} if chosen is not None else {}),
        **({'vegetation_families': list(vegs)} if vegs is not None else {}),
        **({'edge': {'share': edge, 'gap': list(EDGE_GAP), 'reach': list(EDGE_REACH),
                     'tall': EDGE_TALL, 'pairs': sum('edge' in p for p in plans) // 2}}
           if edge > 0 else {}),
        'obstacle_split': {'train': list(train),
                           'test': [n for n in every if n not in train],
                           'instances': 'train: index < TEST_BASE, test: TEST_BASE + pair'},
        'families': {'obstacle': {n: get_family(n).to_json() for n in every},
                     'vegetation': list(SYNTH3_VEGETATION if vegs is None else vegs),
                     'terrain': TERRAIN_FAMILIES, 'sensor': SENSOR_FAMILIES,
                     'safe_shrub_height': SAFE_SHRUB_HEIGHT, 'hide_share': HIDE_SHARE,
                     'density': list(_DENSITY)},
        'patch': {'tile_size': patch.tile_size, 'padding': patch.padding,
                  'column_below': patch.column_below, 'column_above': patch.column_above,
                  'frame': 'tile centre at (0, 0), nominal ground at z = 0',
                  'points_unit': 'mm (int16)'},
        'shards': shards,
    }
