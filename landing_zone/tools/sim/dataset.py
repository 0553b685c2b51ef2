"""``landing-zone simulate --dataset synth1|synth2``: a Table I sweep simulated into shards.

Usage::

    from landing_zone.tools.sim.dataset import simulate_dataset
    from landing_zone.tools.sim.shards import SceneDataset
    simulate_dataset('synth2', 'data/synth2', scenes=2000, workers=2, seed=0)
    ds = SceneDataset('data/synth2', split='train')
    scene = ds[0]            # points, origins (float32, tile frame), label (1 safe), params

or from the command line::

    landing-zone simulate --dataset synth2 --out data/synth2

Which scenes and how each is made: :mod:`landing_zone.tools.sim.sweeps`; the files:
:mod:`landing_zone.tools.sim.shards`. Shard ``k`` holds the scenes ``k * shard_size ...`` of the
selection, so the files do not depend on the number of workers or on the order in which they
finish, and a rerun with the same arguments skips the shards already written.
"""
from __future__ import annotations

import json
import multiprocessing
import os
import threading
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from landing_zone.tools.engines import check_engine, run_tasks
from landing_zone.errors import SimulationError
from landing_zone.tools.sim import synth3
from landing_zone.tools.sim.raycast import embree_started
from landing_zone.tools.sim.shards import (FORMAT_VERSION, prepare_output, shard_arrays,
                                           shard_complete, shard_name, write_json, write_npz)
from landing_zone.tools.sim.sweeps import (TEST_FRACTION, generate_scene, get_sweep, scene_plan,
                                           select_scenes)
from landing_zone.tools.sim.vegetation import check_vegetation

__all__ = ['simulate_dataset', 'progress_bar']


def _make_shard(task: tuple[str, str, int, int, list[int], tuple[str, ...] | None, float,
                            tuple[str, ...] | None]) -> tuple[int, int, int, float]:
    """Worker: simulate the scenes of one shard and write it. Returns (shard, scenes, rays, s)."""
    out, dataset, seed, k, indices, families, edge, vegetation = task
    t0 = time.perf_counter()
    records = [generate_scene(dataset, i, seed, threads=1, families=families, edge=edge,
                              vegetation=vegetation)
               for i in indices]
    write_npz(Path(out) / shard_name(k), shard_arrays(records))
    return k, len(records), sum(r['rays'] for r in records), time.perf_counter() - t0


def progress_bar(total: int, initial: int, enabled: bool, desc: str) -> Any:
    """The scenes' progress bar on stderr (a no-op when not ``enabled``)."""
    from tqdm import tqdm
    return tqdm(total=total, initial=initial, desc=desc, unit='scene', dynamic_ncols=True,
                smoothing=0.05, disable=not enabled)


def _plan_meta(dataset: str, seed: int, split: str, scenes: int | None, shard_size: int,
               selected: np.ndarray) -> dict[str, Any]:
    from landing_zone.tools.sim.library import models
    from landing_zone.tools.sim.scene import PatchConfig
    sweep = get_sweep(dataset)
    plans = [scene_plan(dataset, int(i)) for i in selected]
    counts = {s: {'safe': 0, 'unsafe': 0} for s in ('train', 'test')}
    for p in plans:
        counts[p['split']]['safe' if p['label'] == 1 else 'unsafe'] += 1
    shards = []
    for k in range(0, len(plans), shard_size):
        chunk = plans[k:k + shard_size]
        shards.append({'file': shard_name(k // shard_size), 'scenes': len(chunk),
                       'first_index': chunk[0]['index'],
                       'test': ''.join('1' if p['split'] == 'test' else '0' for p in chunk),
                       'labels': ''.join(str(p['label']) for p in chunk)})
    kinds = sweep.kinds
    patch = PatchConfig()
    return {
        'format': 'landing_zone.tools.sim.dataset', 'format_version': FORMAT_VERSION,
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
            tuple(s['first_index'] for s in meta.get('shards', [])),
            tuple(meta.get('obstacle_families') or ()),
            tuple(meta.get('vegetation_families') or ()),
            json.dumps(meta.get('edge'), sort_keys=True))  # (its share and ranges)


def _check_args(dataset: str, families: Sequence[str] | None, edge: float,
                vegetation: Sequence[str] | None, engine: str, address: str | None, seed: int,
                workers: int | None, shard_size: int) -> None:
    """Refuse what cannot be simulated, before any work."""
    if dataset != 'synth3':
        get_sweep(dataset)
        if families is not None:
            raise SimulationError(f'--families is a synth3 option; {dataset} draws from its '
                                  'own obstacle library')
        if edge:
            raise SimulationError(f'--edge is a synth3 option; {dataset} places its obstacles '
                                  'as the paper does')
        if vegetation is not None:
            raise SimulationError(f'--vegetation is a synth3 option; {dataset} grows its own '
                                  'grass')
    check_engine(engine, address)
    if not isinstance(seed, (int, np.integer)) or seed < 0:
        raise SimulationError(f'seed must be a non-negative integer, got {seed!r}')
    if workers is not None and (not isinstance(workers, (int, np.integer)) or workers < 1):
        raise SimulationError(f'workers must be a positive integer, got {workers!r}')
    if not isinstance(shard_size, (int, np.integer)) or shard_size < 1:
        raise SimulationError(f'shard_size must be a positive integer, got {shard_size!r}')


def _plan(dataset: str, seed: int, split: str, scenes: int | None, shard_size: int,
          families: Sequence[str] | None, edge: float, vegetation: Sequence[str] | None
          ) -> tuple[np.ndarray, dict[str, Any], Any, float, Any]:
    """The scenes to make, the dataset's meta.json, and synth3's families, edge share and
    vegetation checked (as they are passed to the shards)."""
    if dataset == 'synth3':
        families = synth3.check_families(families)
        edge = synth3.check_edge(edge)
        vegetation = check_vegetation(vegetation)
        selected = synth3.select_scenes(scenes, split)
        meta = synth3.plan_meta(seed, split, scenes, shard_size, selected, families, edge,
                                vegetation)
    else:
        selected = select_scenes(dataset, scenes, split)
        meta = _plan_meta(dataset, seed, split, scenes, shard_size, selected)
    return selected, meta, families, edge, vegetation


def _start_method(engine: str, workers: int) -> str | None:
    """How local workers start: fork where it is safe: workers start in milliseconds and
    scripts need no ``if __name__ == '__main__'`` guard. It is safe while this process runs no
    other thread and has not started Embree (whose worker threads a child would inherit
    half-alive): true for the command line, whose progress bar starts after the pool."""
    if engine != 'local' or workers <= 1:
        return None
    safe = threading.active_count() == 1 and not embree_started()
    return 'fork' if safe and 'fork' in multiprocessing.get_all_start_methods() else 'spawn'


def simulate_dataset(dataset: str, out: str | os.PathLike, scenes: int | None = None,
                     workers: int | None = None, seed: int = 0, split: str = 'both',
                     shard_size: int = 32, progress: bool = True, engine: str = 'local',
                     address: str | None = None, families: Sequence[str] | None = None,
                     edge: float = 0.0, vegetation: Sequence[str] | None = None
                     ) -> dict[str, Any]:
    """Generate (or finish generating) a dataset directory.

    Args:
        dataset: ``synth1``, ``synth2`` or ``synth3`` (:mod:`landing_zone.tools.sim.synth3`).
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
        engine: ``local`` (processes here) or ``ray`` (one Ray task per shard; ``workers``
            CPUs of a local cluster unless ``address`` names one): the same files either way.
        address: the Ray cluster (:func:`landing_zone.tools.engines.run_tasks`).
        families: synth3 only: the obstacle families to draw from (None: synth3's own,
            :data:`~landing_zone.tools.sim.synth3.SYNTH3_FAMILIES`).
        edge: synth3 only: the share of pairs whose obstacle stands at the tile's edge
            (:mod:`landing_zone.tools.sim.synth3`).
        vegetation: synth3 only: the vegetation families to draw from (None: synth3's own,
            :data:`~landing_zone.tools.sim.vegetation.SYNTH3_VEGETATION`).

    Returns:
        Summary: scenes, shards written and skipped, seconds, scenes/s, rays, bytes on disk.

    Raises:
        SimulationError: bad arguments (before any work).
        EngineError: an unknown engine, Ray missing, or a worker that died.
        DatasetError: ``out`` holds a different dataset.
    """
    _check_args(dataset, families, edge, vegetation, engine, address, seed, workers, shard_size)
    selected, meta, families, edge, vegetation = _plan(dataset, seed, split, scenes, shard_size,
                                                       families, edge, vegetation)
    out = Path(out)
    meta_path = out / 'meta.json'
    prepare_output(out, meta, _plan_key)

    tasks, done = [], 0
    for k, shard in enumerate(meta['shards']):
        indices = [int(i) for i in selected[k * shard_size:(k + 1) * shard_size]]
        if shard_complete(out / shard['file'], indices):
            done += len(indices)
        else:
            tasks.append((str(out.resolve()), dataset, int(seed), k, indices, families, edge,
                          vegetation))
    workers = min(workers or os.cpu_count() or 1, max(len(tasks), 1))
    start_method = _start_method(engine, workers)
    t0 = time.perf_counter()
    rays = 0
    results = run_tasks(_make_shard, tasks, engine=engine, workers=workers, address=address,
                        start_method=start_method)
    bar = progress_bar(len(selected), done, progress, f'{dataset} -> {out}')
    try:
        for _, (_, n, r, _) in results:
            rays += r
            bar.update(n)
    finally:
        bar.close()
        results.close()
    for stale in (out / 'shards').glob('*.tmp-*'):
        stale.unlink()  # left by a worker that died mid-shard (its task was run again)
    seconds = time.perf_counter() - t0
    meta['complete'] = True
    write_json(meta_path, meta)
    nbytes = sum(f.stat().st_size for f in (out / 'shards').glob('*.npz'))
    generated = len(selected) - done
    return {'dataset': dataset, 'out': str(out), 'scenes': len(selected),
            'generated': generated, 'skipped': done, 'shards': len(meta['shards']),
            'seconds': seconds, 'scenes_per_s': generated / seconds if seconds > 0 else 0.0,
            'rays': rays, 'bytes': nbytes, 'workers': workers, 'counts': meta['counts']}
