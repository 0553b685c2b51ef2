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

For synth3 (:mod:`landing_zone.tools.sim.synth3`), ``batches`` scenes of its first pairs (every
family, in proportion), the same figures plus the median ms per scene of each sensor family
and what one *training sample* of these scenes costs: re-voxelizing an augmented copy (yaw,
z shift, edge cut) and the shipped net's forward + backward + SGD step per sample in batches
of 20 (fp32, this process's torch threads), the two figures a leave-one-family-out training
budget is made of.

Measured timings vary with the load of a shared machine: each figure is over all the scenes.
"""
from __future__ import annotations

import os
import tempfile
import time
from pathlib import Path

import numpy as np

from landing_zone.tools.sim.shards import shard_arrays, write_npz
from landing_zone.tools.sim.sweeps import SWEEPS, generate_scene, select_scenes


def _one(dataset: str, scenes: int, seed: int) -> dict:
    if dataset == 'synth3':
        from landing_zone.tools.sim.synth3 import DEFAULT_SCENES
        from landing_zone.tools.sim.synth3 import select_scenes as select3
        idx, sweep_total = select3(scenes), DEFAULT_SCENES
    else:
        idx, sweep_total = select_scenes(dataset, scenes), SWEEPS[dataset].total
    generate_scene(dataset, int(idx[0]), seed)  # warm up (library, Embree device)
    records, times = [], []
    t_all, c_all = time.perf_counter(), time.process_time()
    for i in idx:
        t0 = time.perf_counter()
        records.append(generate_scene(dataset, int(i), seed, threads=1))
        times.append(time.perf_counter() - t0)
    total = time.perf_counter() - t_all
    # CPU time as well: on a shared machine the wall time also counts other people's work.
    cpu_ms = 1000 * (time.process_time() - c_all) / len(records)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / 'shard.npz'
        write_npz(path, shard_arrays(records))
        nbytes = path.stat().st_size
    rays = sum(r['rays'] for r in records)
    stages = {k: sum(r['timings'][k] for r in records) for k in records[0]['timings']}
    rate = len(records) / total
    cores = os.cpu_count() or 1
    by_sensor: dict[str, list[float]] = {}
    if dataset == 'synth3':
        for r, t in zip(records, times):
            by_sensor.setdefault(r['params']['sensor']['family'], []).append(t)
    extra = {'ms_per_scene_by_sensor': {k: 1000 * float(np.median(v))
                                        for k, v in sorted(by_sensor.items())}} if by_sensor \
        else {}
    if dataset == 'synth3':
        extra.update(_training_sample(records, seed))
    return {
        **extra, 'cpu_ms_per_scene': cpu_ms,
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


def _training_sample(records: list[dict], seed: int) -> dict:
    """ms per augmented re-voxelization and per training step and sample, on these scenes."""
    import torch

    from landing_zone.config import MapConfig, TileConfig
    from landing_zone.judging.net import DEFAULT_SPEC, SafetyNet, SafetyNetConfig
    from landing_zone.judging.tiles import tile_voxels
    from landing_zone.tools.learn.samples import AugmentedVolumes
    from landing_zone.tools.learn.scenes import ScenePack
    from landing_zone.tools.sim.shards import Scene
    scenes = [Scene(r['points_mm'].astype(np.float32) * np.float32(0.001),
                    r['origins'][r['origin_index']], r['label'], r['params']) for r in records]
    pack = ScenePack.from_scenes(scenes)
    mcfg, tcfg = MapConfig(), TileConfig()
    vols = AugmentedVolumes(pack, mcfg, tcfg, seed, True, 0.3, True, 0.3)
    vols[(0, 0, 0)]  # compile
    t0, c0 = time.perf_counter(), time.process_time()
    xs = [vols[(0, i, 1)][0] for i in range(len(pack))]
    voxel_ms = 1000 * (time.perf_counter() - t0) / len(pack)
    voxel_cpu_ms = 1000 * (time.process_time() - c0) / len(pack)
    side = tile_voxels(mcfg.voxel_size, tcfg) + 2 * tcfg.padding
    torch.manual_seed(seed)
    net = SafetyNet(SafetyNetConfig(DEFAULT_SPEC, input_size=side)).to(
        memory_format=torch.channels_last_3d).train()
    opt = torch.optim.SGD(net.parameters(), lr=0.01, momentum=0.9)
    x = torch.stack((xs * (20 // len(xs) + 1))[:20]).contiguous(
        memory_format=torch.channels_last_3d)
    y = torch.tensor([float(i % 2) for i in range(20)])
    steps, cpu = [], []
    for k in range(11):
        t0, c0 = time.perf_counter(), time.process_time()
        _, loss = net(x, y)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        opt.step()
        if k:  # the first step warms up
            steps.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
    step_ms = 1000 * float(np.median(steps)) / 20
    return {'voxelize_ms_per_sample': voxel_ms, 'voxelize_cpu_ms_per_sample': voxel_cpu_ms,
            'step_ms_per_sample': step_ms,
            'step_cpu_ms_per_sample': 1000 * float(np.median(cpu)) / 20,
            'torch_threads': torch.get_num_threads()}


def run(batches: int = 30, seed: int = 0) -> dict:
    """Simulate ``batches`` scenes of each sweep; print and return the figures."""
    out = {}
    for dataset in ('synth1', 'synth2', 'synth3'):
        r = _one(dataset, max(int(batches), 2), seed)
        out[dataset] = r
        share = ', '.join(f'{k} {100 * v:.0f}%' for k, v in r['stage_share'].items())
        print(f'{dataset}: {r["scenes"]} scenes in {r["seconds"]:.1f} s on one core: '
              f'{r["scenes_per_s_core"]:.2f} scenes/s (median {r["ms_per_scene_median"]:.0f} '
              f'ms, max {r["ms_per_scene_max"]:.0f} ms; CPU {r["cpu_ms_per_scene"]:.0f} ms per '
              f'scene), {r["returns_per_scene"]:,.0f} returns per scene')
        print(f'  rays: {r["rays_per_s_core"] / 1e3:,.0f} k/s end to end, '
              f'{r["embree_rays_per_s"] / 1e6:.2f} M/s inside Embree; time: {share}')
        print(f'  {r["mb_per_1000_scenes"]:.0f} MB per 1000 scenes; whole sweep '
              f'({r["sweep_scenes"]:,} scenes, {r["sweep_gb"]:.1f} GB): '
              f'{r["sweep_minutes_this_machine"]:.0f} min on this machine\'s {r["cores"]} '
              f'cores, {r["sweep_minutes_16_cores"]:.1f} min on 16 cores')
        if 'ms_per_scene_by_sensor' in r:
            print('  median ms per scene by sensor: ' + ', '.join(
                f'{k} {v:.0f}' for k, v in r['ms_per_scene_by_sensor'].items()))
            print(f'  training sample: re-voxelizing an augmented copy '
                  f'{r["voxelize_ms_per_sample"]:.1f} ms (CPU '
                  f'{r["voxelize_cpu_ms_per_sample"]:.1f}), forward + backward + SGD of the '
                  f'shipped net {r["step_ms_per_sample"]:.2f} ms per sample (CPU '
                  f'{r["step_cpu_ms_per_sample"]:.2f}; batch 20, {r["torch_threads"]} threads)')
    return out
