"""Labelled training and test patches: the paper's Table I sweeps, written as compact shards.

Usage::

    from landing_zone.sim.dataset import simulate_dataset, SceneDataset
    simulate_dataset('synth2', 'data/synth2', scenes=2000, workers=2, seed=0)
    ds = SceneDataset('data/synth2', split='train')
    scene = ds[0]            # points, origins (float32, tile frame), label (1 safe), params

or, on a machine with only numpy, scipy, numba, trimesh and embreex (no typer, no tqdm)::

    python -m landing_zone.sim simulate --dataset synth2 --out data/synth2

**The sweeps.** A *setting* is one combination of the sweep's axes; each setting is simulated
``instances`` times, half of them with one obstacle (label 0, unsafe), half without (label 1,
safe): instances come in pairs and a hash of (setting, pair) says which of the two gets the
obstacle. A scene's canonical index is ``setting * instances + instance``, settings in
row-major order of the axes as listed in :data:`SWEEPS`.

**The split.** A hash of the canonical index puts a fifth of the scenes into the test split.
Unsafe train scenes take their obstacle from the library's train group, unsafe test scenes from
its test group, so no obstacle model appears in both (synth1 has one model, the box, used by
both, as in the paper).

**Determinism.** Scene ``i`` draws all its randomness from ``SeedSequence([seed, dataset, i])``
and shard ``k`` holds the scenes ``k * shard_size ...`` of the selection, so the files do not
depend on the number of workers or on the order in which they finish; zip entries carry a
fixed time stamp, so the same seed gives the same bytes. Shards are written to a temporary
name and renamed, so an interrupted run leaves only whole shards, and a rerun with the same
arguments skips them.

**Format (version 1).** ``meta.json`` (dataset, seed, sweep, counts, obstacle split, shard
table) and ``shards/shard-NNNNN.npz`` (numpy arrays in a zip, no pickled objects) with, for the
S scenes of the shard and their N returns in total:

==================  ============  ===========================================================
``scene_index``     int64 (S,)    canonical index in the sweep
``label``           uint8 (S,)    1 safe, 0 unsafe
``split``           uint8 (S,)    0 train, 1 test
``point_offsets``   int64 (S+1,)  returns of scene s are ``point_offsets[s]:[s+1]``
``points_delta``    int16 (3, N)  return positions in millimetres relative to the tile centre,
                                  per coordinate the difference to the scene's previous return
                                  (modulo 2^16; the first from 0): consecutive returns are
                                  neighbours along a scan line, so the differences are small
                                  and compress to two thirds of the positions' size
``hit_class``       uint8 (N,)    what each return hit: 0 ground, 1 grass, 2 obstacle
``origin_index``    uint16 (N,)   row of the scene's origin table
``origin_offsets``  int64 (S+1,)  origin table of scene s is ``origins[origin_offsets[s]:...]``
``origins``         float32 (M,3) sensor origin of each scan line [m], tile frame
``origin_times``    float32 (M,)  start time of each scan line [s]
``params_json``     uint8 (B,)    UTF-8 JSON: a list of S parameter dicts
==================  ============  ===========================================================
"""
from __future__ import annotations

import io
import json
import math
import os
import sys
import time
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Iterable, Iterator

import numpy as np

from landing_zone.errors import DatasetError, SimulationError

__all__ = ['SWEEPS', 'Sweep', 'Scene', 'SceneDataset', 'simulate_dataset', 'generate_scene',
           'scene_plan', 'select_scenes', 'FORMAT_VERSION']

FORMAT_VERSION = 1
TEST_FRACTION = 0.2
_DATASET_CODES = {'synth1': 1, 'synth2': 2, 'synth3': 3}  # synth3: landing_zone.sim.synth3
_SPLITS = ('train', 'test', 'both')
_ZIP_DATE = (1980, 1, 1, 0, 0, 0)  # fixed zip time stamps: same seed, same bytes
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


@dataclass
class Scene:
    """One patch as the network's data pipeline sees it (tile centred at (0, 0), ground near 0).

    Attributes:
        points: (N, 3) float32 returns [m].
        origins: (N, 3) float32 sensor origin of each return [m].
        label: 1 safe, 0 unsafe.
        params: the scene's parameters (setting, obstacle, scan figures).
        hit_class: (N,) uint8 what each return hit (0 ground, 1 grass, 2 obstacle).
    """

    points: np.ndarray
    origins: np.ndarray
    label: int
    params: dict
    hit_class: np.ndarray | None = None


def _mix(x: np.ndarray | int) -> np.ndarray:
    """splitmix64 finaliser: a well-spread 64-bit hash of integers."""
    z = (np.asarray(x, dtype=np.uint64) + np.uint64(0x9E3779B97F4A7C15))
    with np.errstate(over='ignore'):
        z = (z ^ (z >> np.uint64(30))) * np.uint64(0xBF58476D1CE4E5B9)
        z = (z ^ (z >> np.uint64(27))) * np.uint64(0x94D049BB133111EB)
    return z ^ (z >> np.uint64(31))


def _get_sweep(dataset: str) -> Sweep:
    if dataset not in SWEEPS:
        raise SimulationError(f'unknown dataset {dataset!r}; choose from {", ".join(SWEEPS)}')
    return SWEEPS[dataset]


def scene_plan(dataset: str, index: int) -> dict[str, Any]:
    """What scene ``index`` of a sweep is, before any randomness: setting, label, split."""
    sweep = _get_sweep(dataset)
    if not 0 <= index < sweep.total:
        raise SimulationError(f'scene index {index} outside {dataset} (0..{sweep.total - 1})')
    s, j = divmod(index, sweep.instances)
    pair_bit = int(_mix(np.uint64(s) * np.uint64(1 << 20) + np.uint64(j // 2)) & np.uint64(1))
    unsafe = (j % 2) == pair_bit
    test = int(_mix(np.uint64(index) + np.uint64(0x5EED << 32)) % np.uint64(1000)) < int(
        1000 * TEST_FRACTION)
    plan = {'dataset': dataset, 'index': int(index), 'setting': int(s), 'instance': int(j),
            'split': 'test' if test else 'train', 'label': 0 if unsafe else 1}
    plan.update(sweep.setting(s))
    return plan


def select_scenes(dataset: str, scenes: int | None = None, split: str = 'both') -> np.ndarray:
    """Canonical indices to generate: the scenes of ``split``, subsampled evenly to ``scenes``."""
    sweep = _get_sweep(dataset)
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


def _choose_model(sweep: Sweep, split: str, rng: np.random.Generator) -> str:
    from landing_zone.sim.obstacles import models
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


def generate_scene(dataset: str, index: int, seed: int = 0, threads: int = 1
                   ) -> dict[str, Any]:
    """Simulate scene ``index`` of a sweep.

    Returns:
        A record: ``points_mm`` int16 (N, 3), ``hit_class`` uint8 (N,), ``origin_index`` uint16
        (N,), ``origins`` float32 (M, 3), ``origin_times`` float32 (M,), ``label``, ``split``,
        ``params`` (JSON-ready), ``rays`` (cast) and ``timings`` (seconds per stage).
    """
    if dataset == 'synth3':
        from landing_zone.sim.synth3 import generate_scene as generate_synth3
        return generate_synth3(index, seed, threads)
    from landing_zone.sim.grass import GrassConfig
    from landing_zone.sim.scene import PatchConfig, simulate_patch
    from landing_zone.sim.sensor import SensorConfig
    sweep = _get_sweep(dataset)
    plan = scene_plan(dataset, index)
    rng = scene_rng(dataset, index, seed)
    model = _choose_model(sweep, plan['split'], rng) if plan['label'] == 0 else None
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


def _write_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    """Write arrays as an .npz with fixed zip time stamps, atomically (temp file + rename)."""
    tmp = path.with_name(f'{path.name}.tmp-{os.getpid()}')
    with zipfile.ZipFile(tmp, 'w', compression=zipfile.ZIP_DEFLATED, compresslevel=1) as zf:
        for name, arr in arrays.items():
            buf = io.BytesIO()
            np.lib.format.write_array(buf, np.ascontiguousarray(arr), allow_pickle=False)
            info = zipfile.ZipInfo(f'{name}.npy', date_time=_ZIP_DATE)
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            zf.writestr(info, buf.getvalue(), compress_type=zipfile.ZIP_DEFLATED,
                        compresslevel=1)
    os.replace(tmp, path)


def _delta_encode(mm: np.ndarray) -> np.ndarray:
    """(N, 3) int16 -> (3, N) int16 differences to the previous row (wrapping)."""
    d = np.diff(mm.astype(np.int32), axis=0, prepend=np.zeros((1, 3), np.int32))
    return np.ascontiguousarray(d.T).astype(np.int16)  # wraps modulo 2^16, undone exactly


def _delta_decode(delta: np.ndarray) -> np.ndarray:
    """Inverse of :func:`_delta_encode`: the int16 running sum wraps back exactly."""
    return np.cumsum(delta, axis=1, dtype=np.int16).T


def _shard_arrays(records: list[dict[str, Any]]) -> dict[str, np.ndarray]:
    def offsets(key: str) -> np.ndarray:
        return np.concatenate([[0], np.cumsum([len(r[key]) for r in records])]).astype(np.int64)
    params = json.dumps([r['params'] for r in records], sort_keys=True,
                        separators=(',', ':')).encode()
    return {
        'scene_index': np.array([r['params']['index'] for r in records], dtype=np.int64),
        'label': np.array([r['label'] for r in records], dtype=np.uint8),
        'split': np.array([r['split'] == 'test' for r in records], dtype=np.uint8),
        'point_offsets': offsets('points_mm'),
        'points_delta': np.concatenate([_delta_encode(r['points_mm']) for r in records], axis=1),
        'hit_class': np.concatenate([r['hit_class'] for r in records]),
        'origin_index': np.concatenate([r['origin_index'] for r in records]),
        'origin_offsets': offsets('origins'),
        'origins': np.concatenate([r['origins'] for r in records]),
        'origin_times': np.concatenate([r['origin_times'] for r in records]),
        'params_json': np.frombuffer(params, dtype=np.uint8),
    }


def _shard_name(k: int) -> str:
    return f'shards/shard-{k:05d}.npz'


def _make_shard(task: tuple[str, str, int, int, list[int]]) -> tuple[int, int, int, float]:
    """Worker: simulate the scenes of one shard and write it. Returns (shard, scenes, rays, s)."""
    out, dataset, seed, k, indices = task
    t0 = time.perf_counter()
    records = [generate_scene(dataset, i, seed, threads=1) for i in indices]
    _write_npz(Path(out) / _shard_name(k), _shard_arrays(records))
    return k, len(records), sum(r['rays'] for r in records), time.perf_counter() - t0


def _shard_complete(path: Path, indices: list[int]) -> bool:
    """A finished shard: a readable zip whose scene_index matches the plan."""
    try:
        with np.load(path, allow_pickle=False) as z:
            return np.array_equal(z['scene_index'], np.asarray(indices, dtype=np.int64))
    except (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError):
        return False


class _Progress:
    """tqdm when it is installed (it is not on every dataset machine), else a plain line."""

    def __init__(self, total: int, initial: int, enabled: bool, desc: str) -> None:
        self.enabled = enabled
        self.total, self.n, self.t0, self.last = total, initial, time.perf_counter(), 0.0
        self.start_n = initial
        self.bar = None
        if enabled:
            try:
                from tqdm import tqdm
                self.bar = tqdm(total=total, initial=initial, desc=desc, unit='scene',
                                dynamic_ncols=True, smoothing=0.05)
            except ImportError:
                self.desc = desc

    def update(self, n: int) -> None:
        self.n += n
        if self.bar is not None:
            self.bar.update(n)
        elif self.enabled:
            now = time.perf_counter()
            if now - self.last >= 2.0 or self.n == self.total:
                self.last = now
                rate = (self.n - self.start_n) / max(now - self.t0, 1e-9)
                eta = (self.total - self.n) / rate if rate > 0 else float('inf')
                print(f'{self.desc}: {self.n}/{self.total} scenes, {rate:.1f} scenes/s, '
                      f'ETA {eta:.0f} s', file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def _plan_meta(dataset: str, seed: int, split: str, scenes: int | None, shard_size: int,
               selected: np.ndarray) -> dict[str, Any]:
    from landing_zone.sim.obstacles import models
    from landing_zone.sim.scene import PatchConfig
    sweep = _get_sweep(dataset)
    plans = [scene_plan(dataset, int(i)) for i in selected]
    counts = {s: {'safe': 0, 'unsafe': 0} for s in ('train', 'test')}
    for p in plans:
        counts[p['split']]['safe' if p['label'] == 1 else 'unsafe'] += 1
    shards = []
    for k in range(0, len(plans), shard_size):
        chunk = plans[k:k + shard_size]
        shards.append({'file': _shard_name(k // shard_size), 'scenes': len(chunk),
                       'first_index': chunk[0]['index'],
                       'test': ''.join('1' if p['split'] == 'test' else '0' for p in chunk),
                       'labels': ''.join(str(p['label']) for p in chunk)})
    kinds = sweep.kinds
    patch = PatchConfig()
    return {
        'format': 'landing_zone.sim.dataset', 'format_version': FORMAT_VERSION,
        'dataset': dataset, 'seed': int(seed), 'split': split,
        'scenes_requested': scenes, 'n_scenes': len(plans), 'shard_size': shard_size,
        'sweep': sweep.to_json(), 'test_fraction': TEST_FRACTION,
        'counts': counts,
        'obstacle_split': {'train': sorted(m.name for m in models(kinds, 'train')),
                           'test': sorted(m.name for m in models(kinds, 'test'))},
        'patch': {'tile_size': patch.tile_size, 'padding': patch.padding,
                  'column_below': patch.column_below, 'column_above': patch.column_above,
                  'frame': 'tile centre at (0, 0), nominal ground at z = 0',
                  'points_unit': 'mm (int16)'},
        'sensor': patch.sensor.to_dict(), 'terrain': patch.terrain.to_dict(),
        'grass': {k: v for k, v in patch.grass.to_dict().items()
                  if k in ('height_cv', 'inclination_std')},
        'shards': shards,
    }


def _plan_key(meta: dict[str, Any]) -> tuple:
    return (meta.get('format_version'), meta.get('dataset'), meta.get('seed'),
            meta.get('split'), meta.get('n_scenes'), meta.get('shard_size'),
            tuple(s['first_index'] for s in meta.get('shards', [])))


def _write_json(path: Path, obj: Any) -> None:
    tmp = path.with_name(path.name + '.tmp')
    tmp.write_text(json.dumps(obj, indent=1, sort_keys=True) + '\n', encoding='utf-8')
    os.replace(tmp, path)


def prepare_output(out: Path, meta: dict[str, Any], plan_key: Any) -> None:
    """Start or resume a dataset directory: refuse one that holds another plan (``plan_key``
    of the metadata differs), drop half-written shards, write ``meta`` marked incomplete.

    Raises:
        DatasetError: ``out`` holds another dataset, or its meta.json is unreadable.
    """
    meta_path = out / 'meta.json'
    if meta_path.exists():
        try:
            old = json.loads(meta_path.read_text(encoding='utf-8'))
        except (OSError, ValueError) as err:
            raise DatasetError(f'{meta_path} is unreadable: {err}') from err
        if plan_key(old) != plan_key(meta):
            split = f', split {old["split"]}' if 'split' in old else ''
            raise DatasetError(
                f'{out} already holds another dataset ({old.get("dataset")}, seed '
                f'{old.get("seed")}, {old.get("n_scenes")} scenes{split}); choose another '
                '--out or remove it')
    (out / 'shards').mkdir(parents=True, exist_ok=True)
    for stale in (out / 'shards').glob('*.tmp-*'):
        stale.unlink()  # a shard an interrupted run was writing
    meta['complete'] = False
    _write_json(meta_path, meta)


def simulate_dataset(dataset: str, out: str | os.PathLike, scenes: int | None = None,
                     workers: int | None = None, seed: int = 0, split: str = 'both',
                     shard_size: int = 32, progress: bool = True) -> dict[str, Any]:
    """Generate (or finish generating) a dataset directory.

    Args:
        dataset: ``synth1``, ``synth2`` or ``synth3`` (:mod:`landing_zone.sim.synth3`).
        out: directory (created; a rerun with the same arguments resumes).
        scenes: subsample the sweep evenly to this many scenes (None: the whole sweep); for
            synth3 the first this many (None: its default size).
        workers: processes (None: one per core; 1: in this process). Workers are forked;
            if this process has already cast rays (Embree's threads must not be forked), they
            are spawned, which needs the calling script's code under
            ``if __name__ == '__main__':`` as any spawning does.
        seed: the dataset's seed.
        split: ``train``, ``test`` or ``both``: which scenes to generate.
        shard_size: scenes per shard file.
        progress: show a progress bar (rate, ETA) on stderr.

    Returns:
        Summary: scenes, shards written and skipped, seconds, scenes/s, rays, bytes on disk.

    Raises:
        SimulationError: bad arguments (before any work).
        DatasetError: ``out`` holds a different dataset.
    """
    if dataset != 'synth3':
        _get_sweep(dataset)
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SimulationError(f'seed must be a non-negative integer, got {seed!r}')
    if workers is not None and (not isinstance(workers, (int, np.integer)) or workers < 1):
        raise SimulationError(f'workers must be a positive integer, got {workers!r}')
    if not isinstance(shard_size, (int, np.integer)) or shard_size < 1:
        raise SimulationError(f'shard_size must be a positive integer, got {shard_size!r}')
    if dataset == 'synth3':
        from landing_zone.sim import synth3
        selected = synth3.select_scenes(scenes, split)
        meta = synth3.plan_meta(seed, split, scenes, shard_size, selected)
    else:
        selected = select_scenes(dataset, scenes, split)
        meta = _plan_meta(dataset, seed, split, scenes, shard_size, selected)
    out = Path(out)
    meta_path = out / 'meta.json'
    prepare_output(out, meta, _plan_key)

    tasks, done = [], 0
    for k, shard in enumerate(meta['shards']):
        indices = [int(i) for i in selected[k * shard_size:(k + 1) * shard_size]]
        if _shard_complete(out / shard['file'], indices):
            done += len(indices)
        else:
            tasks.append((str(out), dataset, int(seed), k, indices))
    workers = min(workers or os.cpu_count() or 1, max(len(tasks), 1))
    t0 = time.perf_counter()
    rays = 0
    pool = None
    if workers > 1:
        import multiprocessing
        import threading

        from landing_zone.sim.raycast import embree_started
        # fork where it is safe: workers start in milliseconds and scripts need no
        # `if __name__ == '__main__'` guard. It is safe while this process runs no other
        # thread and has not started Embree (whose worker threads a child would inherit
        # half-alive): true for the command line, whose progress bar starts after the pool.
        safe = threading.active_count() == 1 and not embree_started()
        method = ('fork' if safe and 'fork' in multiprocessing.get_all_start_methods()
                  else 'spawn')
        pool = multiprocessing.get_context(method).Pool(workers)
    bar = _Progress(len(selected), done, progress, f'{dataset} -> {out}')
    try:
        results = (pool.imap_unordered(_make_shard, tasks) if pool is not None
                   else map(_make_shard, tasks))
        for _, n, r, _ in results:
            rays += r
            bar.update(n)
        if pool is not None:
            pool.close()
            pool.join()
    finally:
        bar.close()
        if pool is not None:
            pool.terminate()
    seconds = time.perf_counter() - t0
    meta['complete'] = True
    _write_json(meta_path, meta)
    nbytes = sum(f.stat().st_size for f in (out / 'shards').glob('*.npz'))
    generated = len(selected) - done
    return {'dataset': dataset, 'out': str(out), 'scenes': len(selected),
            'generated': generated, 'skipped': done, 'shards': len(meta['shards']),
            'seconds': seconds, 'scenes_per_s': generated / seconds if seconds > 0 else 0.0,
            'rays': rays, 'bytes': nbytes, 'workers': workers, 'counts': meta['counts']}


class SceneDataset:
    """The scenes of one split of a dataset directory, loaded lazily shard by shard.

    Args:
        root: directory written by :func:`simulate_dataset`.
        split: ``train``, ``test`` or ``all``.
        cache_shards: decoded shards kept in memory (least recently used dropped).

    Raises:
        DatasetError: the directory is missing, incomplete or of another format.
    """

    def __init__(self, root: str | os.PathLike, split: str = 'train',
                 cache_shards: int = 4) -> None:
        self.root = Path(root)
        if split not in ('train', 'test', 'all'):
            raise DatasetError(f"split must be 'train', 'test' or 'all', got {split!r}")
        meta_path = self.root / 'meta.json'
        if not meta_path.exists():
            raise DatasetError(f'{self.root} is no dataset directory (no meta.json)')
        try:
            self.meta = json.loads(meta_path.read_text(encoding='utf-8'))
        except (OSError, ValueError) as err:
            raise DatasetError(f'{meta_path} is unreadable: {err}') from err
        if self.meta.get('format_version') != FORMAT_VERSION:
            raise DatasetError(f'{self.root}: format version {self.meta.get("format_version")} '
                               f'(this code reads {FORMAT_VERSION})')
        if not self.meta.get('complete'):
            raise DatasetError(f'{self.root} is incomplete: rerun the same simulate command '
                               'to finish it')
        self.split = split
        self._index: list[tuple[int, int]] = []
        labels = []
        for k, shard in enumerate(self.meta['shards']):
            for j, (t, lab) in enumerate(zip(shard['test'], shard['labels'])):
                if split == 'all' or (t == '1') == (split == 'test'):
                    self._index.append((k, j))
                    labels.append(int(lab))
        self.labels = np.array(labels, dtype=np.int64)
        self._cache: dict[int, dict[str, Any]] = {}
        self._cache_size = max(1, cache_shards)

    def __len__(self) -> int:
        return len(self._index)

    def __repr__(self) -> str:
        return (f'SceneDataset({str(self.root)!r}, split={self.split!r}: {len(self)} scenes, '
                f'{int((self.labels == 0).sum())} unsafe)')

    def _shard(self, k: int) -> dict[str, Any]:
        if k in self._cache:
            self._cache[k] = self._cache.pop(k)  # most recently used goes last
            return self._cache[k]
        path = self.root / self.meta['shards'][k]['file']
        try:
            with np.load(path, allow_pickle=False) as z:
                data = {name: z[name] for name in z.files}
        except (OSError, ValueError, KeyError, zipfile.BadZipFile) as err:
            raise DatasetError(f'{path} is missing or corrupt: {err}') from err
        data['params'] = json.loads(data.pop('params_json').tobytes().decode())
        self._cache[k] = data
        while len(self._cache) > self._cache_size:
            self._cache.pop(next(iter(self._cache)))
        return data

    def __getitem__(self, i: int) -> Scene:
        if not -len(self) <= i < len(self):
            raise IndexError(f'scene {i} out of range ({len(self)} scenes)')
        k, j = self._index[i]
        z = self._shard(k)
        p0, p1 = z['point_offsets'][j], z['point_offsets'][j + 1]
        o0, o1 = z['origin_offsets'][j], z['origin_offsets'][j + 1]
        points = _delta_decode(z['points_delta'][:, p0:p1]).astype(np.float32) * np.float32(
            0.001)
        origins = z['origins'][o0:o1][z['origin_index'][p0:p1]]
        return Scene(points, origins, int(z['label'][j]), dict(z['params'][j]),
                     z['hit_class'][p0:p1].copy())

    def __iter__(self) -> Iterator[Scene]:
        for i in range(len(self)):
            yield self[i]

    def params(self, i: int) -> dict:
        """Parameters of scene ``i`` (loads its shard)."""
        return self[i].params


def iter_records(root: str | os.PathLike) -> Iterable[dict]:
    """Parameters of every scene of a dataset directory, in shard order (both splits)."""
    ds = SceneDataset(root, 'all')
    for k in range(len(ds.meta['shards'])):
        yield from ds._shard(k)['params']
