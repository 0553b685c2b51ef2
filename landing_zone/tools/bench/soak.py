"""`landing-zone bench soak --minutes N`: the node on a flight replayed in a loop, for minutes.

The ``assessor`` node runs in its own process (shipped model, default parameters, the shared
memory DDS profile), and ``landing-zone play`` in another plays the demo flight over and over at
its recorded rate, best effort, every pass re-stamped so the stamps keep increasing
(``--loops 0 --restamp``). Every ``SAMPLE`` seconds this process records the node's integration
rate and cloud-to-grid latency (from ``/diagnostics``, the node's own figures: from the arrival of
the oldest cloud a pass took in to the end of the pass) and its resident memory (``/proc``).

What must hold over a long run is that nothing drifts: the rate stays at the flight's, the
latency and the memory stay flat. The result is the least-squares slope of each against time
(per minute) with its value at the start, over the samples after the first minute (start-up
and the first pass over the site fill the map), and the accounting of every cloud published.
A reference run is ``--minutes 30`` on a quiet machine.
"""
from __future__ import annotations

import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np

from landing_zone.tools.bench.livenode import (NodeProcess, Observer, bench_domain, dds_env,
                                               load_line)

SAMPLE = 5.0  # seconds between samples
WARM = 60.0  # seconds left out of the slopes (the first pass over the site fills the map)
NODE_PARAMS = {'diagnostics_period': 1.0}
REMAP = {'points': '/lidar/points', 'sensor_pose': '/lidar/pose'}


def _slope(t: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """(value at the first sample, slope per minute) of a least-squares line."""
    ok = np.isfinite(y)
    if ok.sum() < 2:
        return float('nan'), float('nan')
    tm = (t[ok] - t[ok][0]) / 60.0
    slope, icept = np.polyfit(tm, y[ok], 1)
    return float(icept), float(slope)


def run(batches: int = 30, seed: int = 0, minutes: float | None = None) -> dict[str, Any]:
    """Soak for ``minutes`` (default 2); print the slopes, return the samples and figures."""
    from landing_zone.tools.bench.live import _flight, _model_params

    minutes = 2.0 if minutes is None else float(minutes)
    seconds = minutes * 60.0
    print(f'{load_line()} at the start; {minutes:g} min')
    domain = bench_domain()
    env = dds_env(domain, True)
    samples: list[tuple[float, float, float, float, float]] = []
    with tempfile.TemporaryDirectory(prefix='lz_bench_soak_') as tmpdir:
        tmp = Path(tmpdir)
        bag = _flight(tmp, seed)
        obs = Observer(domain)
        node = NodeProcess({**NODE_PARAMS, **_model_params(tmp, seed)}, env, tmp / 'node.log',
                           remap=REMAP)
        play = None
        try:
            ready = node.wait_ready()
            play = subprocess.Popen(
                [sys.executable, '-m', 'landing_zone', 'play', str(bag), '--loops', '0',
                 '--restamp', '--reliability', 'best_effort', '--duration', str(seconds),
                 '--wait', '30'], env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                text=True)
            t0 = time.monotonic()
            while play.poll() is None:
                time.sleep(SAMPLE)
                d = obs.last()
                rss, _ = node.memory_mb()
                samples.append((time.monotonic() - t0,
                                _num(d.get('integration rate [returns/s]')),
                                _num(d.get('cloud-to-grid latency, last [s]')),
                                _num(d.get('cloud-to-grid latency, max of last 100 [s]')), rss))
            out, err = play.communicate()
            if play.returncode != 0:
                raise RuntimeError(f'play failed: {err[-2000:]}')
            published = int(out.split(' on /lidar/points')[0].rsplit('(', 1)[1].split()[-1])

            def settled() -> bool:
                c = obs.counts()
                return sum(c.values()) >= published and obs.last().get('clouds queued') == '0'

            obs.wait_for(settled, timeout=30.0)
            time.sleep(1.5)
            counts = obs.counts()
            cpu = node.cpu_seconds()
        finally:
            if play is not None and play.poll() is None:
                play.kill()
            code = node.stop()
            obs.close()
        if code != 0:
            raise RuntimeError(f'the node exited with {code}:\n{node.text()[-3000:]}')
    a = np.array(samples, np.float64).reshape(-1, 5)
    keep = a[:, 0] >= min(WARM, seconds / 3)
    t = a[keep, 0]
    fits = {name: _slope(t, a[keep, col]) for name, col in
            (('rate', 1), ('latency', 2), ('latency_max', 3), ('rss', 4))}
    integrated = counts.pop('integrated', 0)
    drops = {k: v for k, v in counts.items() if v}
    unaccounted = published - integrated - sum(drops.values())
    print(f'node ready {ready:.1f} s; {published} clouds published over {minutes:g} min, '
          f'{integrated} integrated, dropped: '
          f'{", ".join(f"{k} {v}" for k, v in sorted(drops.items())) or "none"}, '
          f'unaccounted: {unaccounted}; node CPU {cpu / max(seconds, 1):.2f} cores on average')
    print(f'slopes over the samples after {min(WARM, seconds / 3):.0f} s ({int(keep.sum())} '
          f'samples every {SAMPLE:g} s):')
    print('| measure | at the start | slope per minute |')
    print('|---|---:|---:|')
    for label, key, scale, unit in (('integration rate', 'rate', 1e-3, 'k returns/s'),
                                    ('cloud-to-grid latency, last', 'latency', 1.0, 's'),
                                    ('cloud-to-grid latency, max of 100', 'latency_max', 1.0,
                                     's'),
                                    ('node RSS', 'rss', 1.0, 'MB')):
        v0, slope = fits[key]
        print(f'| {label} [{unit}] | {v0 * scale:.3f} | {slope * scale:+.4f} |')
    print(f'{load_line()} at the end')
    return {'minutes': minutes, 'published': published, 'integrated': integrated,
            'drops': drops, 'unaccounted': unaccounted, 'samples': a.tolist(),
            'fits': fits, 'ready_s': ready}


def _num(text: str | None) -> float:
    try:
        return float(text) if text is not None else float('nan')
    except ValueError:
        return float('nan')
