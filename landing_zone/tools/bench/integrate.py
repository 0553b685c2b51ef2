"""`landing-zone bench integrate`: ray integration throughput on a realistic approach scene.

The scene: the default map (20 x 20 x 4 m at 5 cm, 400 x 400 x 80 voxels) centred on a patch of
gently rolling ground (a few sinusoids, +-0.25 m) with grass up to 0.3 m tall; the sensor hovers
8 m above the ground and 10 m back (-x) from the map's centre and every batch holds about 10,000
returns spread over the map, a third of them from grass. Timings exclude the first batches (numba
compilation, first touch of the pages); each figure is the median of several repeats over
``batches`` batches, with the best beside it, because the machine's cores are shared.

When the ``octomap`` module (octomap-python) imports, OctoMap's ``insertPointCloud`` runs on a
subset of the same returns at the same resolution, from the true sensor origin as
``octomap_server`` does, and the ratio is printed.
"""
from __future__ import annotations

import os
import time

import numpy as np

from landing_zone.config import MapConfig
from landing_zone.mapping.density_map import DensityMap
from landing_zone.mapping.raytrace import PARTS

BATCH = 10_000
SENSOR = np.array([-10.0, 0.0, 8.0])  # 10 m back, 8 m above the ground (near z = 0)
GRASS_FRACTION = 1 / 3
GRASS_HEIGHT = 0.3  # [m]


def ground_z(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Smooth relief: a few sinusoids of 3-12 m wavelength, +-0.25 m in all."""
    return (0.10 * np.sin(0.55 * x + 0.3) + 0.08 * np.sin(0.8 * y - 1.1)
            + 0.05 * np.sin(1.9 * x + 1.3 * y) + 0.02 * np.sin(3.1 * x - 2.3 * y + 0.7))


def make_batches(n_batches: int, seed: int, batch: int = BATCH,
                 half: float = 10.0) -> list[np.ndarray]:
    """Returns (float32, like a PointCloud2) on the ground and the grass of the map area."""
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n_batches):
        xy = rng.uniform(-half, half, (batch, 2))
        z = ground_z(xy[:, 0], xy[:, 1])
        grass = rng.random(batch) < GRASS_FRACTION
        z[grass] += rng.uniform(0.0, GRASS_HEIGHT, grass.sum())
        out.append(np.column_stack([xy, z]).astype(np.float32))
    return out


def _load() -> str:
    """The 1-minute load average: how busy the shared cores were (Linux only)."""
    try:
        with open('/proc/loadavg', encoding='utf-8') as f:
            return f'load average {f.read().split()[0]} on {os.cpu_count()} cores'
    except OSError:
        return 'load average unknown'


def _timed(fn, repeats: int) -> list[float]:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return times


def _throughput(batches: list[np.ndarray], repeats: int, **variant) -> tuple[list[float], dict]:
    """Returns/s (wall clock) of each repeat over all batches, on a fresh, warmed map each.

    ``extra['cpu_rates']`` holds returns per CPU-second of the process (all threads): unlike
    the wall clock, it does not count time the OS gave to other work on the shared cores.
    """
    rates = []
    cpu_rates = []
    for _ in range(repeats):
        dmap = DensityMap(MapConfig())
        for k, v in variant.items():
            setattr(dmap, k, v)
        dmap.integrate(batches[0], SENSOR)  # warm-up: compilation, caches
        dmap.clear()
        stats = None
        c0 = time.process_time()
        t0 = time.perf_counter()
        for pts in batches:
            s = dmap.integrate(pts, SENSOR)
            stats = s if stats is None else stats + s
        dt = time.perf_counter() - t0
        dc = time.process_time() - c0
        n = sum(len(b) for b in batches)
        rates.append(n / dt)
        cpu_rates.append(n / max(dc, 1e-9))
    return rates, {'stats': stats, 'map': dmap, 'cpu_rates': cpu_rates}


def _octomap_rate(points: np.ndarray, resolution: float) -> float | None:
    try:
        import octomap
    except ImportError:
        return None
    tree = octomap.OcTree(resolution)
    pts = points.astype(np.float64)
    tree.insertPointCloud(pts[:200], SENSOR)  # warm-up
    tree = octomap.OcTree(resolution)
    t0 = time.perf_counter()
    for chunk in np.array_split(pts, max(1, len(pts) // 500)):
        tree.insertPointCloud(chunk, SENSOR)
    return len(pts) / (time.perf_counter() - t0)


def run(batches: int = 30, seed: int = 0) -> dict:
    """Measure and print the integration benchmark; return its figures."""
    import numba

    batches = max(int(batches), 2)
    data = make_batches(batches, seed)
    repeats = 5
    threads = numba.get_num_threads()
    print(f'scene: {batches} batches x {BATCH} returns, map 20 x 20 x 4 m at 5 cm '
          f'(400 x 400 x 80), sensor 8 m up and 10 m back; numba threads: {threads}')
    print('note: the cores are shared with other work: medians of '
          f'{repeats} repeats, best in brackets; {_load()}')

    variants = [
        (f'{PARTS} parts taken by {threads} threads, sorted by 16-voxel XY cells (used)', {}),
        ('same, input order (no sort)', {'sort_tile': 0}),
        ('same, sorted by 8-voxel cells', {'sort_tile': 8}),
        ('same, sorted by 32-voxel cells', {'sort_tile': 32}),
        ('serial (parts in turn), sorted', {'parallel': False}),
    ]
    results: dict = {'returns_per_batch': BATCH, 'batches': batches, 'threads': threads,
                     'variants': {}}
    rows = []
    main = None
    for name, variant in variants:
        rates, extra = _throughput(data, repeats, **variant)
        med, best = float(np.median(rates)), float(np.max(rates))
        cpu = float(np.median(extra['cpu_rates']))
        results['variants'][name] = {'median': med, 'best': best, 'per_cpu_second': cpu}
        rows.append((name, med, best, cpu))
        if main is None:
            main = (med, best, extra)
    width = max(len(r[0]) for r in rows)
    print(f'\n{"variant":<{width}}  {"returns/s":>10} {"(best)":>9}  {"per CPU-s":>9}')
    for name, med, best, cpu in rows:
        print(f'{name:<{width}}  {med / 1e6:>9.2f}M ({best / 1e6:>5.2f}M)  {cpu / 1e6:>8.2f}M')

    med, best, extra = main
    stats, dmap = extra['stats'], extra['map']
    vox_per_ret = stats.voxels / max(stats.integrated, 1)
    results.update(returns_per_s=med, returns_per_s_best=best, voxels_per_return=vox_per_ret,
                   integrated_fraction=stats.integrated / max(stats.returns, 1))
    print(f'\nvoxels touched per return (passes + hit): {vox_per_ret:.1f}; '
          f'integrated {stats.integrated}/{stats.returns} returns, '
          f'{stats.outside_hits} ending outside the map')

    # scrolling: shift a filled map back and forth along x and along the diagonal
    scroll = {}
    for metres in (1.0, 5.0):
        step = int(round(metres / dmap.voxel_size))
        lo0 = dmap.lo.copy()
        times = []
        for k in range(6):
            # alternately along x and along the XY diagonal, forwards and backwards
            shift = np.array([step, step if k % 2 else 0, 0]) * (1 if k % 4 < 2 else -1)
            t0 = time.perf_counter()
            dmap.set_lo(lo0 + shift)
            times.append(time.perf_counter() - t0)
            dmap.set_lo(lo0)
        scroll[metres] = float(np.median(times)) * 1e3
    results['scroll_ms'] = scroll
    print('scroll (clears only the entering slabs; median over x and XY-diagonal shifts): '
          f'1 m {scroll[1.0]:.2f} ms, 5 m {scroll[5.0]:.2f} ms')

    # reading: what the tiler does every assessment
    for _ in range(2):
        dmap.counts()
        dmap.density()
    t_counts = float(np.median(_timed(dmap.counts, 5))) * 1e3
    t_dens = float(np.median(_timed(dmap.density, 5))) * 1e3
    results.update(read_counts_ms=t_counts, read_density_ms=t_dens)
    print(f'full read (400 x 400 x 80): counts {t_counts:.1f} ms, density {t_dens:.1f} ms')

    nvox = int(np.prod(dmap.shape))
    results['map_bytes'] = dmap.nbytes
    print(f'map memory: {dmap.nbytes / 1e6:.1f} MB = {dmap.nbytes / nvox:.2f} bytes per voxel '
          f'({dmap.cold_blocks} cold blocks in use)')

    sub = np.concatenate(data)[:3000]
    octo = _octomap_rate(sub, dmap.voxel_size)
    if octo is None:
        print('OctoMap: octomap-python not installed, no comparison')
    else:
        results['octomap_returns_per_s'] = octo
        results['octomap_ratio'] = med / octo
        print(f'OctoMap 1.10 insertPointCloud, full rays from the sensor, 5 cm, '
              f'{len(sub)} returns: {octo / 1e3:.1f}k returns/s; '
              f'this map is {med / octo:.0f}x faster')
    print(_load(), '(at the end)')
    target = 'met' if med >= 1e6 else 'NOT met'
    print(f'target >= 1,000,000 returns/s (aim 2,000,000): {target} ({med / 1e6:.2f}M median)')
    return results
