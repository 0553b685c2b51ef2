"""Sets of simulated flights for judging the product where it acts: one obstacle family a flight.

Two sets, drawn by one plan with different families:

* ``heldout``: the yardstick. Obstacle families and vegetation no shipped training ever saw
  (:data:`HELDOUT_OBSTACLES`, :data:`HELDOUT_VEGETATION`), on flat, sloped and rough ground,
  under every scan pattern, flown from 5 to 22 m at 1500 to 4500 returns/m^2. Nothing is ever
  tuned on it; figures are published from a seed used for nothing else.
* ``development``: the training families and synth3's vegetation under the same spread of
  ground and scanners, for tuning what sits after the network (thresholds, calibration,
  normalisation) without touching the held-out families.

Each flight crosses one obstacle family with one vegetation (every pair ``repeats`` times), so
the figures split cleanly by family. Everything else (scan pattern, height, density, slope,
roughness, the site's seed) is drawn from the set's seed and the flight's index, so the same
seed makes the same flights on any machine and a set can be resumed: flights already written
are kept.
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from landing_zone.errors import SimulationError
from landing_zone.tools.sim.families import TEST_FAMILIES
from landing_zone.tools.sim.flight_settings import SCAN
from landing_zone.tools.sim.vegetation import SYNTH3_VEGETATION

__all__ = ['HELDOUT_OBSTACLES', 'HELDOUT_VEGETATION', 'DEVELOPMENT_OBSTACLES', 'SETS',
           'PlannedFlight', 'plan', 'simulate_set']

# Never in the shipped model's training (synth3's train families, then frame and mesh): the
# four test families, thin wire loops and random assemblies of parts.
HELDOUT_OBSTACLES = TEST_FAMILIES + ('hoop', 'assembly')
# Never in its training (synth3's six vegetation families): the flight presets' grass
# structures and the meadow, forb and canopy priors.
HELDOUT_VEGETATION = ('clumped', 'tall', 'bushy', 'mixed', 'meadow', 'forb', 'canopy')
DEVELOPMENT_OBSTACLES = ('rock', 'slab', 'rubble', 'log', 'brush', 'box', 'crate', 'pipe',
                         'tire', 'cinder_block', 'post', 'cone', 'pallet', 'frame', 'mesh')
SETS = {'heldout': (HELDOUT_OBSTACLES, HELDOUT_VEGETATION),
        'development': (DEVELOPMENT_OBSTACLES, SYNTH3_VEGETATION)}
OBSTACLES = 10  # per 20 m x 20 m site
SIZE = 20.0


@dataclass(frozen=True)
class PlannedFlight:
    """One flight of a set: what :func:`landing_zone.tools.sim.flight.flight_config` takes."""

    name: str
    family: str
    vegetation: str
    scan_pattern: str
    height: float
    density: float
    slope: float
    slope_azimuth: float  # [rad]
    roughness: float
    seed: int

    def to_json(self) -> dict[str, Any]:
        return dict(self.__dict__)


def plan(which: str, seed: int, repeats: int = 2) -> list[PlannedFlight]:
    """The flights of set ``which`` drawn from ``seed``.

    Raises:
        SimulationError: an unknown set, a negative seed or fewer than one repeat.
    """
    if which not in SETS:
        raise SimulationError(f'unknown flight set {which!r}; choose from {", ".join(SETS)}')
    if not isinstance(seed, int) or seed < 0:
        raise SimulationError(f'the set\'s seed must be a non-negative integer, got {seed!r}')
    if not isinstance(repeats, int) or repeats < 1:
        raise SimulationError(f'repeats must be a positive integer, got {repeats!r}')
    families, vegetations = SETS[which]
    rng = np.random.default_rng(np.random.SeedSequence([seed, sorted(SETS).index(which)]))
    scans = tuple(SCAN)
    out = []
    for r in range(repeats):
        for fi, family in enumerate(families):
            for vi, vegetation in enumerate(vegetations):
                k = len(out)
                slope = float(rng.choice([0.0, 0.0, 4.0, 8.0, 12.0]))
                out.append(PlannedFlight(
                    name=f'{k:03d}_{family}_{vegetation}', family=family,
                    vegetation=vegetation,
                    # every scan pattern under every family and every vegetation
                    scan_pattern=scans[(fi + vi + r) % len(scans)],
                    height=round(float(rng.uniform(5.0, 22.0)), 1),
                    density=round(float(rng.uniform(1500.0, 4500.0)), -1),
                    slope=slope,
                    slope_azimuth=round(float(rng.uniform(-math.pi, math.pi)), 3),
                    roughness=round(float(rng.uniform(0.02, 0.10)), 3),
                    seed=int(rng.integers(0, 2**31 - 1))))
    return out


def _simulate_one(task: dict[str, Any]) -> str:
    from landing_zone.tools.sim.flight import flight_config, simulate_flight

    f = PlannedFlight(**task['flight'])
    cfg = flight_config(f.vegetation, f.scan_pattern, density=f.density, size=SIZE,
                        obstacles=OBSTACLES, kinds=(), families=(f.family,), slope=f.slope,
                        slope_azimuth=f.slope_azimuth, amplitude=f.roughness,
                        height=f.height, seed=f.seed)
    simulate_flight(cfg, task['out'], overwrite=True, threads=1)
    return task['out']


def simulate_set(which: str, seed: int, out: str | os.PathLike[str], *, repeats: int = 2,
                 workers: int | None = None, engine: str = 'local',
                 address: str | None = None) -> list[Path]:
    """Write set ``which`` to ``out`` (one ``NAME.mcap`` and ``NAME.labels.json`` a flight, and
    ``flights.json``, the plan); flights already there from the same plan are kept.

    Returns:
        The bags of the set, in the plan's order.

    Raises:
        SimulationError: a bad set or seed, or ``out`` holds another plan.
    """
    from landing_zone.tools.engines import check_engine, run_tasks

    check_engine(engine, address)
    flights = plan(which, seed, repeats)
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    doc = {'set': which, 'seed': seed, 'repeats': repeats,
           'flights': [f.to_json() for f in flights]}
    manifest = out / 'flights.json'
    if manifest.exists():
        if json.loads(manifest.read_text(encoding='utf-8')) != doc:
            raise SimulationError(f'{out} holds another flight set ({manifest}): choose '
                                  'another directory')
    else:
        manifest.write_text(json.dumps(doc, indent=1) + '\n', encoding='utf-8')
    bags = [out / f'{f.name}.mcap' for f in flights]
    todo = [{'flight': f.to_json(), 'out': str(b)} for f, b in zip(flights, bags)
            if not (b.exists() and b.with_name(f'{f.name}.labels.json').exists())]
    for _ in run_tasks(_simulate_one, todo, engine=engine, workers=workers, address=address,
                       start_method='spawn'):
        pass
    return bags
