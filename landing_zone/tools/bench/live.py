"""`landing-zone bench live`: the node against a sensor stream at rising rates.

The ``assessor`` node runs in its own process (the shipped model, default parameters, the
shipped Fast DDS profile ``config/fastdds_shm.xml``), and an outside publisher process
(:mod:`landing_zone.tools.bench.live_publisher`) sends clouds made from the demo flight at rates
from 0.1 to 2 M returns/s (10k-100k returns per cloud, 10-20 Hz, poses at 100 Hz), once with
best-effort publishers (what LiDAR drivers use) and once with reliable ones. Each rate plays for
``batches / 3`` seconds (at least 5). Per rate it prints:

* **integrated**: the share of the clouds published that the node integrated;
* **unaccounted**: clouds published minus ``clouds integrated`` minus every ``dropped clouds:
  REASON`` count the node reports (docs/INTERFACES.md §1); it must be zero at every rate;
* **latency**: per cloud, from its publish to the arrival (in this process) of the first grid
  that includes it: median and 99th percentile. A grid is due every ``assessment_period``
  (1 s) of stamp time, so half a period of waiting is in the median by design;
* the node's **CPU** (cores, from ``/proc``: user + system over the step) and **RSS**.

Then a smaller table compares the DDS settings the choice rests on: Fast DDS's built-in
transports against the shared-memory profile, best effort and reliable, at 1 M returns/s.

:func:`run` takes the rates, the publishers' reliabilities and node parameters to measure one
setting alone (``run(rates=[parse_rate('1M')], reliabilities=('best_effort',),
compare_dds=False, params={'eager_interval': 0.0})``).

The machine is shared: the load average is printed before and after. The summary states what
the issue's goals ask: >= 99 % integrated up to 300k returns/s with both reliabilities, no
cloud unaccounted for, and the live capacity (the highest rate with >= 95 % integrated).
"""
from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from landing_zone.tools.bench.livenode import (NodeProcess, Observer, bench_domain, dds_env,
                                               load_line)

# (returns per cloud, clouds per second): 0.1 to 2 M returns/s
RATES = [(10_000, 10), (20_000, 10), (15_000, 20), (25_000, 20), (35_000, 20), (50_000, 20),
         (75_000, 20), (100_000, 20)]
# the node's settings for the benchmark (the rest: defaults)
NODE_PARAMS = {'diagnostics_period': 0.25, 'idle_flush': 0.5}
REMAP = {'points': '/lidar/points', 'sensor_pose': '/lidar/pose'}


def _flight(tmp: Path, seed: int) -> Path:
    from landing_zone.tools.sim.flight import simulate_flight
    from landing_zone.tools.sim.flight_settings import FlightConfig
    return simulate_flight(FlightConfig(seed=seed), tmp / 'site.mcap').bag


def _model_params(tmp: Path, seed: int) -> dict[str, Any]:
    from landing_zone.tools.bench.replay import _model
    path, which = _model(tmp, seed)
    return {'model.path': str(path)} if which != 'shipped' else {}


def _step(node: NodeProcess, obs: Observer, env: dict[str, str], bag: Path, tmp: Path,
          points: int, hz: int, seconds: float, reliability: str, seed: int) -> dict[str, Any]:
    """One rate: publish, let the node settle, compare what it counted with what was sent."""
    before = obs.counts()
    n_grids = len(obs.grids)
    cpu0, t0 = node.cpu_seconds(), time.monotonic()
    out = tmp / f'pub_{points}_{hz}_{reliability}.json'
    proc = subprocess.run(
        [sys.executable, '-m', 'landing_zone.tools.bench.live_publisher', '--bag', str(bag),
         '--points', str(points), '--hz', str(hz), '--seconds', str(seconds),
         '--reliability', reliability, '--seed', str(seed), '--out', str(out)],
        env=env, capture_output=True, text=True, timeout=seconds + 180)
    if proc.returncode != 0:
        raise RuntimeError(f'the publisher failed:\n{proc.stderr[-2000:]}')
    pub = json.loads(out.read_text())
    cpu1, t1 = node.cpu_seconds(), time.monotonic()
    rss, peak = node.memory_mb()
    published = pub['published']

    def settled() -> bool:
        c = obs.counts()
        return sum(c.values()) - sum(before.values()) >= published \
            and obs.last().get('clouds queued') == '0'

    obs.wait_for(settled, timeout=30.0)
    time.sleep(0.6)  # one more diagnostics period: the final counts
    after = obs.counts()
    delta = {k: after.get(k, 0) - before.get(k, 0) for k in after}
    integrated = delta.pop('integrated', 0)
    drops = {k: v for k, v in delta.items() if v}
    grids = obs.grids[n_grids:]
    lat = _latencies(pub['stamps'], pub['times'], grids)
    return {
        'returns_per_s': points * hz, 'points': points, 'hz': hz, 'reliability': reliability,
        'published': published, 'integrated': integrated,
        'integrated_share': integrated / published if published else 0.0,
        'drops': drops, 'unaccounted': published - integrated - sum(drops.values()),
        'latency_median_s': float(np.median(lat)) if len(lat) else None,
        'latency_p99_s': float(np.percentile(lat, 99)) if len(lat) else None,
        'cpu_cores': (cpu1 - cpu0) / (t1 - t0), 'rss_mb': rss, 'rss_peak_mb': peak,
        'publisher_late_s': pub['late_s'],
    }


def _latencies(stamps: list[int], times: list[float], grids: list[tuple[int, float]]
               ) -> np.ndarray:
    """Per cloud: arrival of the first grid (after its publish) whose stamp reaches its own."""
    if not grids:
        return np.zeros(0)
    g_stamp = np.array([g[0] for g in grids], np.int64)
    g_time = np.array([g[1] for g in grids])
    # a grid's stamp is the newest cloud it includes; later grids include it as well, so the
    # first grid at or after the cloud's stamp (by stamp) is the one it first appears in
    reach = np.maximum.accumulate(g_stamp)
    out = []
    for s, t in zip(stamps, times):
        i = int(np.searchsorted(reach, s))
        if i < len(grids):
            out.append(g_time[i] - t)
    return np.asarray(out)


def _sweep(env: dict[str, str], bag: Path, tmp: Path, seconds: float, seed: int,
           rates: list[tuple[int, int]], reliabilities: tuple[str, ...],
           model: dict[str, Any], tag: str) -> tuple[list[dict[str, Any]], float]:
    domain = int(env['ROS_DOMAIN_ID'])
    obs = Observer(domain)
    node = NodeProcess({**NODE_PARAMS, **model}, env, tmp / f'node_{tag}.log', remap=REMAP)
    rows = []
    try:
        ready = node.wait_ready()
        obs.wait_for(lambda: bool(obs.last()), timeout=10.0)
        for reliability in reliabilities:
            for points, hz in rates:
                rows.append(_step(node, obs, env, bag, tmp, points, hz, seconds, reliability,
                                  seed))
    finally:
        code = node.stop()
        obs.close()
    if code != 0:
        raise RuntimeError(f'the node exited with {code}:\n{node.text()[-3000:]}')
    return rows, ready


def _fmt_row(r: dict[str, Any]) -> str:
    drops = ', '.join(f'{k} {v}' for k, v in sorted(r['drops'].items())) or '-'
    lat = (f'{r["latency_median_s"]:.2f} / {r["latency_p99_s"]:.2f}'
           if r['latency_median_s'] is not None else 'n/a')
    return (f'| {r["returns_per_s"] / 1e6:.2f} M | {r["points"] // 1000}k x {r["hz"]} Hz | '
            f'{r["reliability"]} | {r["published"]} | {100 * r["integrated_share"]:.1f} % | '
            f'{drops} | {r["unaccounted"]} | {lat} | {r["cpu_cores"]:.2f} | '
            f'{r["rss_mb"]:.0f} ({r["rss_peak_mb"]:.0f}) |')


def parse_rate(text: str) -> tuple[int, int]:
    """``'50000x20'`` (returns per cloud x clouds per second) or ``'1M'`` / ``'0.3M'`` (returns
    per second, at 20 Hz) -> (returns per cloud, Hz)."""
    t = text.strip().lower()
    if 'x' in t:
        points, hz = t.split('x', 1)
        return int(float(points)), int(hz)
    per_s = float(t[:-1]) * 1e6 if t.endswith('m') else float(t)
    return int(round(per_s / 20)), 20


def run(batches: int = 30, seed: int = 0, rates: list[tuple[int, int]] | None = None,
        reliabilities: tuple[str, ...] = ('best_effort', 'reliable'), compare_dds: bool = True,
        params: dict[str, Any] | None = None) -> dict[str, Any]:
    """Both sweeps and the DDS comparison; print the tables, return the figures.

    Args:
        batches: 3 per second of each rate (at least 5 s).
        seed: the flight's and the model's.
        rates: (returns per cloud, Hz) to step through; default :data:`RATES`.
        reliabilities: the publishers' QoS reliabilities to sweep.
        compare_dds: also compare the DDS settings at 1 M returns/s.
        params: node parameters over :data:`NODE_PARAMS` (``assessment_period``, ...).
    """
    seconds = max(5.0, batches / 3)
    print(f'{load_line()} at the start; {seconds:.0f} s per rate')
    domain = bench_domain()
    model_extra = dict(params or {})
    with tempfile.TemporaryDirectory(prefix='lz_bench_live_') as tmpdir:
        tmp = Path(tmpdir)
        bag = _flight(tmp, seed)
        model = {**_model_params(tmp, seed), **model_extra}
        rows, ready = _sweep(dds_env(domain, True), bag, tmp, seconds, seed, rates or RATES,
                             reliabilities, model, 'shm')
        compare = []
        for profile in (False, True) if compare_dds else ():
            r, _ = _sweep(dds_env(domain, profile), bag, tmp, min(seconds, 5.0), seed,
                          [(50_000, 20)], ('best_effort', 'reliable'), model,
                          f'cmp{int(profile)}')
            for row in r:
                row['transport'] = 'shared memory profile' if profile else 'Fast DDS built-in'
            compare += r
    print(f'node ready {ready:.1f} s after start (model, snapshot, warm-up); DDS domain {domain}')
    print('| returns/s | clouds | publisher | published | integrated | dropped (by reason) '
          '| unaccounted | latency median / p99 [s] | node CPU [cores] | RSS (peak) [MB] |')
    print('|---|---|---|---:|---:|---|---:|---|---:|---|')
    for r in rows:
        print(_fmt_row(r))
    print('\nDDS settings at 1 M returns/s (50k x 20 Hz):')
    print('| transport | publisher | integrated | dropped (by reason) | unaccounted |')
    print('|---|---|---:|---|---:|')
    for r in compare:
        drops = ', '.join(f'{k} {v}' for k, v in sorted(r['drops'].items())) or '-'
        print(f'| {r["transport"]} | {r["reliability"]} | {100 * r["integrated_share"]:.1f} % '
              f'| {drops} | {r["unaccounted"]} |')
    summary = _summary(rows)
    print(f'\n{load_line()} at the end')
    print(f'>= 99 % integrated up to: best effort {summary["best_effort_99"] / 1e6:.2f} M, '
          f'reliable {summary["reliable_99"] / 1e6:.2f} M returns/s (goal: 0.3 M); '
          f'live capacity (>= 95 %): {summary["capacity_95"] / 1e6:.2f} M returns/s '
          f'(goal: 1 M); unaccounted clouds: {summary["unaccounted"]} (goal: 0)')
    return {'rows': rows, 'dds': compare, 'ready_s': ready, **summary}


def _summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    def up_to(rel: str | None, share: float) -> float:
        best = 0.0
        for r in sorted((r for r in rows if rel is None or r['reliability'] == rel),
                        key=lambda r: r['returns_per_s']):
            if r['integrated_share'] < share:
                break
            best = r['returns_per_s']
        return best

    return {'best_effort_99': up_to('best_effort', 0.99), 'reliable_99': up_to('reliable', 0.99),
            'capacity_95': min(up_to('best_effort', 0.95), up_to('reliable', 0.95)),
            'unaccounted': int(sum(abs(r['unaccounted']) for r in rows))}
