"""`landing-zone bench`: the project's performance benchmarks.

One module per benchmark under :mod:`landing_zone.tools.bench`, each with
``run(batches: int, seed: int) -> dict`` that prints its own table and returns its figures.
Every report starts with the machine it ran on, since figures mean nothing without it.
"""
from __future__ import annotations

import importlib
import os
import platform

from landing_zone.errors import ConfigError

NAMES = ('integrate', 'simulate', 'assess', 'replay', 'insert', 'live', 'soak', 'engines')
# What a bare `landing-zone bench` runs: the live ones need minutes and DDS, and engines a Ray
# cluster, so only by name.
DEFAULT = ('integrate', 'simulate', 'assess', 'replay', 'insert')


def machine_line() -> str:
    """One line naming the CPU, its core count and the Python/torch-free software versions."""
    cpu = platform.processor() or platform.machine()
    try:
        with open('/proc/cpuinfo', encoding='utf-8') as f:
            for line in f:
                if line.startswith('model name'):
                    cpu = line.split(':', 1)[1].strip()
                    break
    except OSError:
        pass
    return f'machine: {cpu}, {os.cpu_count()} cores, Python {platform.python_version()}'


def run(which: list[str], batches: int = 30, seed: int = 0,
        minutes: float | None = None, models: tuple[str, ...] = ()) -> dict[str, dict]:
    """Run the named benchmarks (default: :data:`DEFAULT`); ``minutes`` is the soak's length,
    ``models`` candidate model files the assess benchmark times beside the shipped one."""
    unknown = [w for w in which if w not in NAMES]
    if unknown:
        raise ConfigError(f'unknown benchmark {unknown[0]!r}; choose from {", ".join(NAMES)}')
    print(machine_line())
    results = {}
    for name in which or DEFAULT:
        try:
            module = importlib.import_module(f'landing_zone.tools.bench.{name}')
        except ModuleNotFoundError as err:
            if err.name != f'landing_zone.tools.bench.{name}':
                raise
            print(f'\n[{name}] not available yet')
            continue
        print(f'\n[{name}]')
        if name == 'soak':
            results[name] = module.run(batches=batches, seed=seed, minutes=minutes)
        elif name == 'assess':
            results[name] = module.run(batches=batches, seed=seed, models=models)
        else:
            results[name] = module.run(batches=batches, seed=seed)
    return results
