"""The paper's Table I sweeps: which scenes a synth dataset holds and how each is simulated.

**The sweeps.** A *setting* is one combination of the sweep's axes; each setting is simulated
``instances`` times, half of them with one obstacle (label 0, unsafe), half without (label 1,
safe): instances come in pairs and a hash of (setting, pair) says which of the two gets the
obstacle. A scene's canonical index is ``setting * instances + instance``, settings in
row-major order of the axes as listed in :data:`SWEEPS`.

**The split.** A hash of the canonical index puts a fifth of the scenes into the test split.
Unsafe train scenes take their obstacle from the library's train group, unsafe test scenes from
its test group, so no obstacle model appears in both (synth1 has one model, the box, used by
both, as in the paper).

Scene ``i`` draws all its randomness from ``SeedSequence([seed, dataset, i])``
(:func:`scene_rng`), so it does not depend on which worker makes it.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.hashing import mix
from landing_zone.tools.sim.library import models
from landing_zone.tools.sim.synth3_scene import generate_scene as generate_synth3

__all__ = ['SWEEPS', 'Sweep', 'TEST_FRACTION', 'scene_plan', 'select_scenes', 'scene_rng',
           'generate_scene', 'choose_model', 'get_sweep']

TEST_FRACTION = 0.2
_DATASET_CODES = {'synth1': 1, 'synth2': 2, 'synth3': 3}  # synth3: landing_zone.tools.sim.synth3
_SPLITS = ('train', 'test', 'both')
# Obstacle kinds of synth2 are drawn with these weights, then a model of the kind uniformly.
_KIND_WEIGHTS = {'rock': 0.5, 'tire': 0.25, 'cinder_block': 0.25}


@dataclass(frozen=True)
class Sweep:
    """One dataset of Table I.

    Attributes:
        name: ``synth1`` or ``synth2``.
        axes: ordered (parameter, values) pairs; the settings are their Cartesian product.
        fixed: parameters that do not vary.
        instances: scenes per setting (half unsafe).
        kinds: obstacle kinds of the unsafe scenes.
    """

    name: str
    axes: tuple[tuple[str, tuple[float, ...]], ...]
    fixed: tuple[tuple[str, float], ...]
    instances: int
    kinds: tuple[str, ...]

    @property
    def n_settings(self) -> int:
        return math.prod(len(v) for _, v in self.axes)

    @property
    def total(self) -> int:
        return self.n_settings * self.instances

    def setting(self, s: int) -> dict[str, float]:
        """Parameter values of setting ``s`` (row-major over the axes)."""
        values = {}
        for name, options in reversed(self.axes):
            s, k = divmod(s, len(options))
            values[name] = options[k]
        out = dict(self.fixed)
        out.update({name: values[name] for name, _ in self.axes})
        return out

    def to_json(self) -> dict:
        return {'axes': {k: list(v) for k, v in self.axes}, 'fixed': dict(self.fixed),
                'instances': self.instances, 'settings': self.n_settings, 'total': self.total,
                'obstacle_kinds': list(self.kinds)}


_BOTH_AXES = (('grass_height', (0.1, 0.2, 0.3)), ('sensor_offset', (-5.0, -10.0)),
              ('sensor_height', (4.0, 8.0)))
SWEEPS = {
    'synth1': Sweep(
        'synth1',
        (('grass_density', tuple(float(d) for d in range(100, 1201, 100))),
         ('resolution', (0.05, 0.1, 0.2, 0.41))) + _BOTH_AXES,
        (('blade_width', 0.005),), 20, ('box',)),
    'synth2': Sweep(
        'synth2',
        (('grass_density', tuple(float(d) for d in range(100, 1601, 100)) + (1800.0,)),
         ('blade_width', (0.003, 0.005, 0.008))) + _BOTH_AXES,
        (('resolution', 0.1),), 40, ('rock', 'tire', 'cinder_block')),
}


def get_sweep(dataset: str) -> Sweep:
    if dataset not in SWEEPS:
        raise SimulationError(f'unknown dataset {dataset!r}; choose from {", ".join(SWEEPS)}')
    return SWEEPS[dataset]


def scene_plan(dataset: str, index: int) -> dict[str, Any]:
    """What scene ``index`` of a sweep is, before any randomness: setting, label, split."""
    sweep = get_sweep(dataset)
    if not 0 <= index < sweep.total:
        raise SimulationError(f'scene index {index} outside {dataset} (0..{sweep.total - 1})')
    s, j = divmod(index, sweep.instances)
    pair_bit = int(mix(np.uint64(s) * np.uint64(1 << 20) + np.uint64(j // 2)) & np.uint64(1))
    unsafe = (j % 2) == pair_bit
    test = int(mix(np.uint64(index) + np.uint64(0x5EED << 32)) % np.uint64(1000)) < int(
        1000 * TEST_FRACTION)
    plan = {'dataset': dataset, 'index': int(index), 'setting': int(s), 'instance': int(j),
            'split': 'test' if test else 'train', 'label': 0 if unsafe else 1}
    plan.update(sweep.setting(s))
    return plan


def select_scenes(dataset: str, scenes: int | None = None, split: str = 'both') -> np.ndarray:
    """Canonical indices to generate: the scenes of ``split``, subsampled evenly to ``scenes``."""
    sweep = get_sweep(dataset)
    if split not in _SPLITS:
        raise SimulationError(f"split must be one of {', '.join(_SPLITS)}, got {split!r}")
    idx = np.arange(sweep.total, dtype=np.int64)
    if split != 'both':
        is_test = np.array([scene_plan(dataset, int(i))['split'] == 'test' for i in idx])
        idx = idx[is_test == (split == 'test')]
    if scenes is not None:
        if not isinstance(scenes, (int, np.integer)) or scenes < 1:
            raise SimulationError(f'--scenes must be a positive integer, got {scenes!r}')
        if scenes < len(idx):
            pick = np.floor((np.arange(scenes) + 0.5) * len(idx) / scenes).astype(np.int64)
            idx = idx[pick]
    return idx


def choose_model(sweep: Sweep, split: str, rng: np.random.Generator) -> str:
    if sweep.kinds == ('box',):
        return 'box'
    kinds = list(sweep.kinds)
    weights = np.array([_KIND_WEIGHTS.get(k, 1.0) for k in kinds])
    kind = kinds[int(rng.choice(len(kinds), p=weights / weights.sum()))]
    names = sorted(m.name for m in models((kind,), split))
    return names[int(rng.integers(len(names)))]


def scene_rng(dataset: str, index: int, seed: int) -> np.random.Generator:
    """The random generator of one scene (independent of every other scene's)."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), _DATASET_CODES[dataset],
                                                         int(index)]))


def generate_scene(dataset: str, index: int, seed: int = 0, threads: int = 1,
                   families: Sequence[str] | None = None, edge: float = 0.0,
                   vegetation: Sequence[str] | None = None) -> dict[str, Any]:
    """Simulate scene ``index`` of a sweep (``families``: synth3's obstacle families, None its
    own; ``edge``: synth3's share of pairs at the tile's edge; ``vegetation``: synth3's
    vegetation families, None its own).

    Returns:
        A record: ``points_mm`` int16 (N, 3), ``hit_class`` uint8 (N,), ``origin_index`` uint16
        (N,), ``origins`` float32 (M, 3), ``origin_times`` float32 (M,), ``label``, ``split``,
        ``params`` (JSON-ready), ``rays`` (cast) and ``timings`` (seconds per stage).
    """
    if dataset == 'synth3':
        return generate_synth3(index, seed, threads, families, edge, vegetation)
    from landing_zone.tools.sim.grass import GrassConfig
    from landing_zone.tools.sim.scene import PatchConfig, simulate_patch
    from landing_zone.tools.sim.sensor import SensorConfig
    sweep = get_sweep(dataset)
    plan = scene_plan(dataset, index)
    rng = scene_rng(dataset, index, seed)
    model = choose_model(sweep, plan['split'], rng) if plan['label'] == 0 else None
    config = PatchConfig(
        grass=GrassConfig(density=plan['grass_density'], blade_width=plan['blade_width'],
                          height_mean=plan['grass_height']),
        sensor=SensorConfig(angular_resolution=plan['resolution']),
        sensor_offset=plan['sensor_offset'], sensor_height=plan['sensor_height'],
        obstacle=model)
    patch = simulate_patch(config, rng, threads=threads)
    ret = patch.scan.returns
    mm = np.rint(ret.points * 1000.0)
    if np.any(np.abs(mm) > np.iinfo(np.int16).max):
        raise SimulationError(f'scene {index}: a return lies more than 32 m from the tile')
    if len(ret.line_times) > np.iinfo(np.uint16).max:
        raise SimulationError(f'scene {index}: more than 65535 scan lines')
    params = dict(plan)
    params.update({
        'obstacle': patch.obstacle.to_json() if patch.obstacle is not None else None,
        'n_returns': int(len(ret)), 'density': round(patch.scan.density, 1),
        'nod_rate': round(patch.scan.nod_rate, 3), 'sweeps': patch.scan.sweeps,
        'scan_time': round(patch.scan.duration, 4), 'n_blades': patch.world.n_blades,
        'seed': int(seed)})
    return {'points_mm': mm.astype(np.int16), 'hit_class': ret.labels.astype(np.uint8),
            'origin_index': ret.line.astype(np.uint16),
            'origins': ret.line_origins.astype(np.float32),
            'origin_times': ret.line_times.astype(np.float32),
            'label': plan['label'], 'split': plan['split'], 'params': params,
            'rays': patch.scan.rays,
            # Not stored (they vary run to run): for benchmarks.
            'timings': dict(patch.timings, cast=patch.scan.cast_seconds)}
