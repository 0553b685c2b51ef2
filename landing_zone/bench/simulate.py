"""`landing-zone bench simulate`: dataset scenes per second, rays per second, sweep projections.

For synth1 and synth2, ``batches`` scenes spread evenly over the sweep (so every grass density,
resolution and viewpoint is represented in proportion) are simulated one after the other in
this process with a single-threaded Embree device, as a dataset worker does. Reported:

* scenes/s of one core (end to end: planning, terrain, grass, obstacle, BVH build, scanning);
* rays/s of one core, end to end and inside Embree alone;
* where the time goes (plan, world, BVH, scan with its cast share);
* bytes on disk per 1000 scenes (the scenes written as one shard);
* the projected time of the whole sweep on this machine's cores and on 16 cores, assuming
  workers scale linearly (they share nothing but the disk).

Measured timings vary with the load of a shared machine: each figure is over all the scenes.
"""
from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

from landing_zone.sim.shards import shard_arrays, write_npz
from landing_zone.sim.sweeps import SWEEPS, generate_scene, select_scenes


def _one(dataset: str, scenes: int, seed: int) -> dict:
    idx = select_scenes(dataset, scenes)
    generate_scene(dataset, int(idx[0]), seed)  # warm up (library, Embree device)
    records, times = [], []
    t_all = time.perf_counter()
    for i in idx:
        t0 = time.perf_counter()
        records.append(generate_scene(dataset, int(i), seed, threads=1))
        times.append(time.perf_counter() - t0)
    total = time.perf_counter() - t_all
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / 'shard.npz'
        write_npz(path, shard_arrays(records))
        nbytes = path.stat().st_size
    rays = sum(r['rays'] for r in records)
    stages = {k: sum(r['timings'][k] for r in records) for k in records[0]['timings']}
    rate = len(records) / total
    sweep_total = SWEEPS[dataset].total
    cores = os.cpu_count() or 1
    return {
        'scenes': len(records), 'seconds': total, 'scenes_per_s_core': rate,
        'ms_per_scene_median': 1000 * sorted(times)[len(times) // 2],
        'ms_per_scene_max': 1000 * max(times),
        'rays': rays, 'rays_per_s_core': rays / total,
        'embree_rays_per_s': rays / stages['cast'] if stages['cast'] > 0 else 0.0,
        'returns_per_scene': sum(len(r['points_mm']) for r in records) / len(records),
        'stage_share': {k: v / total for k, v in stages.items()},
        'mb_per_1000_scenes': nbytes / len(records) * 1000 / 1e6,
        'sweep_scenes': sweep_total,
        'sweep_minutes_this_machine': sweep_total / (rate * cores) / 60, 'cores': cores,
        'sweep_minutes_16_cores': sweep_total / (rate * 16) / 60,
        'sweep_gb': nbytes / len(records) * sweep_total / 1e9,
    }


def run(batches: int = 30, seed: int = 0) -> dict:
    """Simulate ``batches`` scenes of each sweep; print and return the figures."""
    out = {}
    for dataset in ('synth1', 'synth2'):
        r = _one(dataset, max(int(batches), 2), seed)
        out[dataset] = r
        share = ', '.join(f'{k} {100 * v:.0f}%' for k, v in r['stage_share'].items())
        print(f'{dataset}: {r["scenes"]} scenes in {r["seconds"]:.1f} s on one core: '
              f'{r["scenes_per_s_core"]:.2f} scenes/s (median {r["ms_per_scene_median"]:.0f} '
              f'ms, max {r["ms_per_scene_max"]:.0f} ms), {r["returns_per_scene"]:,.0f} returns '
              f'per scene')
        print(f'  rays: {r["rays_per_s_core"] / 1e3:,.0f} k/s end to end, '
              f'{r["embree_rays_per_s"] / 1e6:.2f} M/s inside Embree; time: {share}')
        print(f'  {r["mb_per_1000_scenes"]:.0f} MB per 1000 scenes; whole sweep '
              f'({r["sweep_scenes"]:,} scenes, {r["sweep_gb"]:.1f} GB): '
              f'{r["sweep_minutes_this_machine"]:.0f} min on this machine\'s {r["cores"]} '
              f'cores, {r["sweep_minutes_16_cores"]:.1f} min on 16 cores')
    return out
