"""Benchmarking: the project's own performance figures (`landing-zone bench`)."""
from __future__ import annotations

from pathlib import Path
from typing import Annotated, Optional

import typer

app = typer.Typer()


@app.command(help='Run the project\'s performance benchmarks and print their figures.\n\n'
                  'Examples:\n\n  landing-zone bench\n\n  landing-zone bench integrate\n\n'
                  '  landing-zone bench integrate --batches 50\n\n'
                  '  landing-zone bench live\n\n  landing-zone bench soak --minutes 30\n\n'
                  '  landing-zone bench engines  (local processes beside a local Ray cluster)\n\n'
                  '  landing-zone bench assess --model candidate.safetensors')
def bench(
    which: Annotated[Optional[list[str]], typer.Argument(
        help='Benchmarks to run (integrate, simulate, assess, replay, insert, live, soak, '
             'engines); default all but live, soak and engines.')] = None,
    batches: Annotated[int, typer.Option(
        help='Batches of returns per measurement (live: 3 per second of each rate).')] = 30,
    seed: Annotated[int, typer.Option(help='Seed of the benchmark scenes.')] = 0,
    minutes: Annotated[Optional[float], typer.Option(
        help='Length of the soak [min] (default 2).', min=0.1)] = None,
    model: Annotated[Optional[list[Path]], typer.Option(
        help='assess: also time this model\'s judgement of the map and of a strip, as the '
             'assessor runs it (with NAME.ood.safetensors beside it, else a random reference '
             'of its size); repeat for more.')] = None,
) -> None:
    from landing_zone.tools import bench as bench_mod
    bench_mod.run(which or [], batches=batches, seed=seed, minutes=minutes,
                  models=tuple(str(m) for m in model or ()))
