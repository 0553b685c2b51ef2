"""The `landing-zone` command line (also `python -m landing_zone`).

Each command parses its options and calls one library function; heavy imports (torch, numba,
rosbags) happen inside the commands so that `landing-zone --help` is instant. Errors the core
raises on bad input (:class:`landing_zone.errors.LandingZoneError`) end the program with one
line on stderr and exit status 2, never a traceback.
"""
from __future__ import annotations

import sys
from enum import Enum
from pathlib import Path
from typing import Annotated, Optional

import typer

from landing_zone.errors import LandingZoneError

app = typer.Typer(
    name='landing-zone',
    help='Landing zone detection from LiDAR with a 3D CNN.\n\n'
         'Examples:\n\n'
         '  landing-zone demo\n\n'
         '  landing-zone simulate-flight --out site.mcap --seed 3\n\n'
         '  landing-zone replay site.mcap --out assessed.mcap --report report.json\n\n'
         '  landing-zone simulate --dataset synth2 --out data/synth2 --scenes 2000\n\n'
         '  landing-zone train --data data/synth2 --arch C7-F32-P2-C5-F64-P2-D512 '
         '--out model.safetensors\n\n'
         '  landing-zone evaluate --data data/synth2 --baselines --json results.json\n\n'
         '  landing-zone bench integrate',
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)


class DatasetName(str, Enum):
    synth1 = 'synth1'
    synth2 = 'synth2'
    hybrid = 'hybrid'


@app.callback()
def _root() -> None:
    # A callback keeps typer in command-group mode even while few commands exist.
    pass


# --- bench ------------------------------------------------------------------------------------

@app.command(help='Run the project\'s performance benchmarks and print their figures.\n\n'
                  'Examples:\n\n  landing-zone bench\n\n  landing-zone bench integrate\n\n'
                  '  landing-zone bench integrate --batches 50')
def bench(
    which: Annotated[Optional[list[str]], typer.Argument(
        help='Benchmarks to run (integrate, simulate, assess, replay, insert); default all.')]
        = None,
    batches: Annotated[int, typer.Option(help='Batches of returns per measurement.')] = 30,
    seed: Annotated[int, typer.Option(help='Seed of the benchmark scenes.')] = 0,
) -> None:
    from landing_zone import bench as bench_mod
    bench_mod.run(which or [], batches=batches, seed=seed)


def main(argv: list[str] | None = None) -> None:
    """Console entry point: run the app, turning core errors into one line and exit 2."""
    try:
        app(args=argv, prog_name='landing-zone', standalone_mode=True)
    except LandingZoneError as err:
        print(f'landing-zone: error: {err}', file=sys.stderr)
        sys.exit(2)
    except KeyboardInterrupt:
        print('landing-zone: interrupted', file=sys.stderr)
        sys.exit(130)


if __name__ == '__main__':
    main()
