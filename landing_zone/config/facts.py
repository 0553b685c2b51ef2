"""The facts of a parameter (:class:`Param`), the dataclass field that carries them, and the
checks they give."""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from typing import Any

from landing_zone.errors import ConfigError

__all__ = ['Param', 'param']


@dataclass(frozen=True)
class Param:
    """The facts of one parameter.

    Attributes:
        description: what it does, one phrase (the descriptor's text, the YAML comment).
        unit: SI unit, '' for none.
        range: (lo, hi) of allowed values, both included unless ``open_lo`` / ``open_hi``;
            None: no range (strings, arrays).
        open_lo: ``lo`` itself is not allowed.
        open_hi: ``hi`` itself is not allowed.
        read_only: fixed once the node runs (it sizes the map, the tiles or the network).
        name: the parameter's name when it is not the field's own (``region_center``).
    """

    description: str
    unit: str = ''
    range: tuple[float, float] | None = None
    open_lo: bool = False
    open_hi: bool = False
    read_only: bool = False
    name: str = ''

    @property
    def text(self) -> str:
        """Description with unit and read-only mark, as the node and the YAML show it."""
        unit = f' [{self.unit}]' if self.unit else ''
        return f'{self.description}{unit}' + (' (read-only)' if self.read_only else '')

    def check(self, name: str, value: Any) -> None:
        """Raise :class:`ConfigError` naming ``name`` if ``value`` is outside the range."""
        if self.range is None:
            return
        lo, hi = self.range
        try:
            v = float(value)
        except (TypeError, ValueError):
            raise ConfigError(f'{name} must be a number, got {value!r}') from None
        ok = math.isfinite(v) and (v > lo if self.open_lo else v >= lo) and (
            v < hi if self.open_hi else v <= hi)
        if not ok:
            if lo == 0 and self.open_lo and math.isinf(hi):
                raise ConfigError(f'{name} must be a positive number, got {value!r}')
            left, right = '(' if self.open_lo else '[', ')' if self.open_hi else ']'
            raise ConfigError(f'{name} must lie in {left}{lo:g}, {hi:g}{right}, got {value!r}')


def param(default: Any, description: str, unit: str = '',
          range: tuple[float, float] | None = None, *, open_lo: bool = False,
          open_hi: bool = False, read_only: bool = False, name: str = '') -> Any:
    """A dataclass field with its :class:`Param` facts as metadata."""
    return field(default=default, metadata={'param': Param(
        description, unit, range, open_lo, open_hi, read_only, name)})


def _check_fields(obj: Any, prefix: str) -> None:
    for f in dataclasses.fields(obj):
        p = f.metadata.get('param')
        if p is not None:  # named as the node names it (snapshot.period, not snapshot_period)
            p.check(p.name or prefix + f.name, getattr(obj, f.name))


def _from_names(cls: Any, flat: dict[str, Any]) -> Any:
    """An instance of a flat config class from the parameters named as its fields' facts say
    (``snapshot.path`` for ``snapshot_path``), validated."""
    kwargs = {}
    for f in dataclasses.fields(cls):
        p = f.metadata.get('param')
        name = (p.name if p is not None and p.name else f.name)
        if name in flat:
            kwargs[f.name] = flat[name]
    obj = cls(**kwargs)
    obj.validate()
    return obj
