"""`landing-zone bench engines`: the local engine beside a local Ray cluster, same machine.

Two jobs, each run on both engines with the same number of workers (the machine's cores):

* ``simulate``: a synth1 dataset of ``batches * 8`` scenes in shards of 8 (scenes/s), and
  whether both engines wrote the same bytes;
* ``evaluate-flights``: ``max(batches // 10, 2) * 2`` small simulated flights (10 m x 10 m,
  two obstacles each) replayed and scored with the shipped model (flights/s), and whether the
  figures are the same.

The Ray cluster is started once, before both jobs (its start-up is reported on its own line:
a cluster that is already up does not pay it); it starts its worker processes then, and they
import the pipeline on their first task, as each local worker does after it starts. The
engines run in the order local, ray, ray, local and each figure is the median of its two runs.
Timings vary with the load of a shared machine.
"""
from __future__ import annotations

import hashlib
import logging
import os
import tempfile
import time
from pathlib import Path

import numpy as np

from landing_zone.errors import EngineError


def _digest(root: Path) -> dict[str, str]:
    return {str(f.relative_to(root)): hashlib.sha256(f.read_bytes()).hexdigest()
            for f in sorted(root.rglob('*')) if f.is_file()}


def _figures(doc: dict) -> dict:
    return {'pooled': doc['pooled'],
            'flights': [{k: v for k, v in f.items() if k != 'seconds'} for f in doc['flights']]}


def run(batches: int = 30, seed: int = 0) -> dict:
    """Run both jobs on both engines; print the table and return the figures."""
    from landing_zone.tools.engines import require_ray
    from landing_zone.tools.evaluate.flights import evaluate_flights
    from landing_zone.tools.sim.dataset import simulate_dataset
    from landing_zone.tools.sim.flight import flight_config, simulate_flight

    try:
        ray = require_ray()
    except EngineError as err:
        print(f'  skipped: {err}')
        return {}
    workers = len(os.sched_getaffinity(0))
    scenes = max(batches, 2) * 8
    n_flights = max(batches // 10, 2) * 2
    out: dict = {'workers': workers, 'scenes': scenes, 'flights': n_flights}
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        bags = []
        for k in range(n_flights):
            cfg = flight_config('default', 'line', size=10.0, obstacles=2, seed=seed + k,
                                kinds=('rock', 'tire', 'cinder_block', 'box'))
            bags.append(simulate_flight(cfg, root / f'flight{k}.mcap').bag)
        t0 = time.perf_counter()
        ray.init(num_cpus=workers, include_dashboard=False, logging_level=logging.WARNING)
        out['ray_start_s'] = round(time.perf_counter() - t0, 2)
        runs: dict[str, list[dict[str, float]]] = {'local': [], 'ray': []}
        sim_dirs, flight_docs = {}, {}
        try:
            # ABBA: each engine runs once early and once late, so a change of the shared
            # machine's load over the run weighs on both alike
            for k, engine in enumerate(('local', 'ray', 'ray', 'local')):
                sim_dirs[engine] = root / f'synth1-{engine}-{k}'
                s = simulate_dataset('synth1', sim_dirs[engine], scenes=scenes, seed=seed,
                                     shard_size=8, workers=workers, progress=False,
                                     engine=engine)
                flight_docs[engine] = evaluate_flights(bags, engine=engine, workers=workers)
                runs[engine].append({'scenes_per_s': s['scenes_per_s'],
                                     'flights_per_s': flight_docs[engine]['flights_per_s']})
        finally:
            ray.shutdown()
        rates = {e: {key: round(float(np.median([r[key] for r in rs])), 3)
                     for key in ('scenes_per_s', 'flights_per_s')} for e, rs in runs.items()}
        out['runs'] = runs
        out['rates'] = rates
        out['same_bytes'] = _digest(sim_dirs['local']) == _digest(sim_dirs['ray'])
        out['same_figures'] = _figures(flight_docs['local']) == _figures(flight_docs['ray'])
    print(f'  {workers} workers each; synth1 {scenes} scenes (shards of 8), {n_flights} '
          'flights of 10 m x 10 m; Ray cluster start-up '
          f'{out["ray_start_s"]:.1f} s (not in the rates); median of two runs each')
    print('  | engine | scenes/s | flights/s | runs (scenes/s, flights/s) |')
    print('  |---|---:|---:|---|')
    for engine, r in rates.items():
        each = ', '.join(f'{x["scenes_per_s"]:.2f} / {x["flights_per_s"]:.3f}'
                         for x in runs[engine])
        print(f'  | {engine} | {r["scenes_per_s"]:.2f} | {r["flights_per_s"]:.3f} | {each} |')
    print(f'  same dataset bytes: {out["same_bytes"]}; same flight figures: '
          f'{out["same_figures"]}')
    return out
