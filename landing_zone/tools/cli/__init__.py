"""The `landing-zone` command line (also `python -m landing_zone`).

One module per stage: run (demo, replay, play), sim, recorded (insert-obstacles), learn,
calibrate, evaluate, bench. Each
command parses its options and calls one library function. What a command needs beyond the
robot's install (the simulator, the training, matplotlib, Ray) is imported inside it, so that
`landing-zone --help` is instant and `landing-zone replay` runs on the robot. Errors the core
raises on bad input (:class:`landing_zone.errors.LandingZoneError`) end the program with one
line on stderr and exit status 2, never a traceback.
"""
from __future__ import annotations

import sys
from typing import Annotated, Any

import typer

from landing_zone.errors import LandingZoneError
from landing_zone.tools.cli import bench, calibrate, evaluate, learn, recorded, run, sim

__all__ = ['app', 'main', 'command']

app = typer.Typer(
    name='landing-zone',
    help='Landing zone detection from LiDAR with a 3D CNN.\n\n'
         'Examples:\n\n'
         '  landing-zone demo\n\n'
         '  landing-zone simulate-flight --out site.mcap --seed 3\n\n'
         '  landing-zone replay site.mcap --out assessed.mcap --report report.json\n\n'
         '  landing-zone insert-obstacles site.mcap --out hybrid.mcap --count 6\n\n'
         '  landing-zone simulate --dataset synth2 --out data/synth2 --scenes 2000\n\n'
         '  landing-zone train --data data/synth2 --out model.safetensors\n\n'
         '  landing-zone evaluate --data data/synth2 --baselines --json results.json\n\n'
         '  landing-zone bench integrate\n\n'
         'Each command\'s --help shows its options and more examples.',
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
    rich_markup_mode=None,
)
# the stages in the order the help lists them; learn's LAZY commands lead its own
STAGES = (run, sim, recorded, learn, calibrate, evaluate, bench)
for _stage in STAGES:
    app.add_typer(_stage.app)


def _version(value: bool) -> None:
    if value:
        from landing_zone import __version__

        print(f'landing-zone {__version__}')
        raise typer.Exit()


@app.callback()
def _root(
    version: Annotated[bool, typer.Option(
        '--version', help='Print the version and exit.', callback=_version, is_eager=True)]
    = False,
) -> None:
    # A callback keeps typer in command-group mode and carries the root options.
    pass


def command() -> Any:
    """The click group of every command, the lazily built ones in their stage's place."""
    group = typer.main.get_command(app)
    first_learn = learn.app.registered_commands[0].name
    ordered = {}
    for name, cmd in group.commands.items():
        if name == first_learn:
            ordered.update((lazy.name, lazy) for lazy in learn.LAZY)
        ordered[name] = cmd
    group.commands = ordered
    return group


def main(argv: list[str] | None = None) -> None:
    """Console entry point: run the app, turning core errors into one line and exit 2."""
    try:
        command().main(args=argv, prog_name='landing-zone', standalone_mode=True)
    except LandingZoneError as err:
        print(f'landing-zone: error: {err}', file=sys.stderr)
        sys.exit(2)
    except KeyboardInterrupt:
        print('landing-zone: interrupted', file=sys.stderr)
        sys.exit(130)


if __name__ == '__main__':
    main()
