"""What the stages' commands share: option types and help, and options made from a config
dataclass, so that each default and each help text is written once, on the dataclass field.

A field becomes ``--field-name`` with the field's default and ``metadata['help']``;
``metadata['choices']`` makes it a choice. Commands whose options need a heavy import to be
built (TrainConfig lives beside torch) are :class:`LazyCommand`: listed at once, built when run.
"""
from __future__ import annotations

import dataclasses
import inspect
import typing
from collections.abc import Callable, Mapping, Sequence
from enum import Enum
from typing import Annotated, Any, Literal, Optional

import typer
from typer.core import TyperCommand


class Engine(str, Enum):
    local = 'local'
    ray = 'ray'


class Device(str, Enum):
    cpu = 'cpu'
    cuda = 'cuda'


ENGINE_HELP = ('local: processes on this machine; ray: Ray tasks on a cluster (--address, '
               'else RAY_ADDRESS, else a local one); needs pip install \'landing_zone[ray]\'.')
ADDRESS_HELP = ('Ray cluster address (ray://HOST:10001, HOST:6379 or auto); default '
                'RAY_ADDRESS, else a local cluster of --workers CPUs.')
POINTS_HELP = 'PointCloud2 topic (fixed frame).'
POSE_HELP = ('Pose topic: PoseStamped of the sensor, or Odometry of the body (the type is read '
             'from the bag).')


def comma_list(text: str | None) -> tuple[str, ...]:
    """The items of a comma-separated option, stripped, empty ones dropped (None: none)."""
    return tuple(t.strip() for t in (text or '').split(',') if t.strip())


def obstacle_choice(kinds: str | None, families: str | None,
                    default_kinds: tuple[str, ...]) -> tuple[tuple[str, ...], tuple[str, ...]]:
    """``--kinds`` and ``--families`` as (kinds, families): the kinds given, else none where
    families are given, else ``default_kinds``."""
    fams = comma_list(families)
    chosen = comma_list(kinds) if kinds is not None else () if fams else default_kinds
    return chosen, fams


def config_options(cls: type, names: Sequence[str] | Mapping[str, str], *,
                   defaults: Mapping[str, Any] | None = None,
                   helps: Mapping[str, str] | None = None) -> list[inspect.Parameter]:
    """Typer options made from fields of the dataclass ``cls``.

    Args:
        cls: the config dataclass; each field named needs ``metadata['help']``.
        names: the fields, in the order shown; a mapping names the option (parameter) of
            each field where the two differ (``{'budget_samples': 'max_samples'}``).
        defaults: a command's own default for a field, where it differs from the dataclass's.
        helps: a command's own help for a field, where it says more than the dataclass's.
    """
    pairs = list(names.items()) if isinstance(names, Mapping) else [(n, n) for n in names]
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    out = []
    for param, name in pairs:
        f = fields[name]
        if 'help' not in f.metadata:
            raise TypeError(f'{cls.__name__}.{name} has no help text (metadata)')
        help_ = (helps or {}).get(name, f.metadata['help'])
        kind = hints[name]
        if 'choices' in f.metadata:
            kind = Literal[tuple(f.metadata['choices'])]  # type: ignore[misc]
        if defaults is not None and name in defaults:
            default = defaults[name]
        elif f.default is not dataclasses.MISSING:
            default = f.default
        else:  # a list: the option repeats, absent means the empty list
            default = None
            kind = Optional[kind]
        out.append(inspect.Parameter(param, inspect.Parameter.KEYWORD_ONLY, default=default,
                                     annotation=Annotated[kind, typer.Option(help=help_)]))
    return out


def with_options(func: Callable[..., Any], options: list[inspect.Parameter]
                 ) -> Callable[..., Any]:
    """``func`` whose ``**options`` typer fills with ``options`` (after its own parameters)."""
    sig = inspect.signature(func, eval_str=True)
    own = [p for p in sig.parameters.values() if p.kind is not inspect.Parameter.VAR_KEYWORD]
    func.__signature__ = sig.replace(parameters=own + options)  # type: ignore[attr-defined]
    return func


def config_values(cls: type, values: Mapping[str, Any]) -> dict[str, Any]:
    """The values of ``config_options`` as keyword arguments of ``cls`` (None lists: [])."""
    fields = {f.name: f for f in dataclasses.fields(cls)}
    return {k: (list(v or ()) if fields[k].default_factory is not dataclasses.MISSING else v)
            for k, v in values.items()}


def command_of(func: Callable[..., Any], name: str, help_: str) -> TyperCommand:
    """The click command typer makes of ``func``."""
    one = typer.Typer(add_completion=False, rich_markup_mode=None)
    one.command(name=name, help=help_)(func)
    cmd = typer.main.get_command(one)
    assert isinstance(cmd, TyperCommand)
    return cmd


class LazyCommand(TyperCommand):
    """A command listed by its name and help, whose options are built when it runs or shows
    its own help: ``landing-zone --help`` then imports nothing the options are made from."""

    def __init__(self, name: str, help_: str, build: Callable[[], TyperCommand]) -> None:
        super().__init__(name, help=help_, rich_markup_mode=None)
        self._build = build
        self._command: TyperCommand | None = None

    def command(self) -> TyperCommand:
        if self._command is None:
            self._command = self._build()
        return self._command

    def make_context(self, info_name: str | None, args: list[str], parent: Any = None,
                     **extra: Any) -> Any:
        return self.command().make_context(info_name, args, parent=parent, **extra)

    def get_params(self, ctx: Any) -> Any:
        return self.command().get_params(ctx)
