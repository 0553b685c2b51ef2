"""`landing-zone bench insert`: how fast insert-obstacles rewrites a flight.

The flight is the demo's (``simulate_flight(FlightConfig(seed))``: the default 20 x 20 m site
with grass and six obstacles, about 1.5 M returns in 358 clouds). Six more obstacles of the
test group are inserted into its safe tiles; the figure is returns per second of the whole
command (both passes over the bag, placement, ray casting, rewriting and writing the output
bag and labels), best of ``batches // 10`` runs (1 to 3; the machine is shared), with its
breakdown by stage.
"""
from __future__ import annotations

import tempfile
from pathlib import Path
from typing import Any


def run(batches: int = 30, seed: int = 0) -> dict[str, Any]:
    """Time insert-obstacles on the demo flight; print a table, return the figures."""
    from landing_zone.tools.sim.insert import insert_obstacles
    from landing_zone.tools.sim.flight import simulate_flight
    from landing_zone.tools.sim.flight_settings import FlightConfig

    repeats = max(1, min(3, batches // 10))
    with tempfile.TemporaryDirectory(prefix='lz_bench_insert_') as tmpdir:
        tmp = Path(tmpdir)
        flight = simulate_flight(FlightConfig(seed=seed), tmp / 'site.mcap')
        runs = [insert_obstacles(flight.bag, tmp / f'out{k}.mcap', count=6, seed=seed)
                for k in range(repeats)]
    best = min(runs, key=lambda r: r.seconds)
    t = best.timings
    out = {
        'clouds': best.clouds,
        'returns': best.returns,
        'obstacles': len(best.obstacles),
        'altered_returns': best.altered,
        'altered_clouds': best.altered_clouds,
        'seconds': round(best.seconds, 3),
        'seconds_runs': [round(r.seconds, 3) for r in runs],
        'returns_per_second': round(best.returns / best.seconds),
        'seconds_by_stage': {k: round(v, 3) for k, v in t.items()},
    }
    print(f'demo flight: {best.clouds} clouds, {best.returns:,} returns; {out["obstacles"]} '
          f'obstacles inserted, {best.altered:,} returns moved onto them in '
          f'{best.altered_clouds} clouds')
    print('| measure | value |')
    print('|---|---|')
    print(f'| insert-obstacles rate | {out["returns_per_second"]:,} returns/s '
          f'({best.seconds:.2f} s; runs: {", ".join(f"{s:.2f}" for s in out["seconds_runs"])}) |')
    print(f'| by stage | read + poses {t["read"]:.2f} s, placement {t["place"]:.2f} s, copy '
          f'and rewrite {t["write"]:.2f} s (of which prefilter + casting + rewriting clouds '
          f'{t["alter"]:.2f} s) |')
    return out
