"""The paper's shorthand for a 3D ConvNet (``C7-F32-P2-C5-F64-P2-D512``): parse and check it.

Read left to right: ``C7-F32`` a 7^3 convolution with 32 filters (valid padding, stride 1) and a
ReLU, ``P2`` a 2^3 max-pool, ``D512`` a dense layer of 512 units and a ReLU; a final linear
unit (added by :class:`~landing_zone.judging.net.SafetyNet`) gives the logit of P(safe).
Beyond the paper, ``S2-F4`` is a 2^3 convolution with stride 2 and 4 filters and a ReLU: it
halves the side as ``P2`` does, but where the pool keeps the largest of each block's 8 voxels,
its filters are learnt functions of all 8 (how the returns lie inside each 10 cm block).
"""
from __future__ import annotations

import re
from dataclasses import dataclass

from landing_zone.errors import ConfigError

__all__ = ['Layer', 'parse_spec', 'format_spec', 'layer_shapes']


@dataclass(frozen=True)
class Layer:
    """One layer of a spec: ``kind`` 'conv' (size = kernel, filters; ``stride`` 1 for ``C``,
    the kernel for ``S``), 'pool' or 'dense'."""

    kind: str
    size: int
    filters: int = 0
    stride: int = 1

    def __str__(self) -> str:
        if self.kind == 'conv':
            return f'{"C" if self.stride == 1 else "S"}{self.size}-F{self.filters}'
        return f'{"P" if self.kind == "pool" else "D"}{self.size}'


_TOKEN = re.compile(r'([CSFPD])([1-9][0-9]*)')
_LIMITS = {'C': 64, 'S': 64, 'F': 4096, 'P': 64, 'D': 65536}
_EXAMPLE = 'e.g. C7-F32-P2-C5-F64-P2-D512'


def parse_spec(spec: str, input_size: int | None = None) -> list[Layer]:
    """Parse the paper's shorthand into layers; with ``input_size``, check the shapes too.

    Args:
        spec: tokens joined by '-': ``C<k>`` then ``F<filters>`` (a convolution), ``S<k>``
            then ``F<filters>`` (a convolution of stride k), ``P<p>`` (max-pool),
            ``D<units>`` (dense); convolutions and pools come before dense layers.
        input_size: voxels per side of the input cube; checks that no layer shrinks it to 0.

    Raises:
        ConfigError: naming the bad token and why.
    """
    if not isinstance(spec, str) or not spec.strip():
        raise ConfigError(f'architecture spec must be a non-empty string like {_EXAMPLE}, got '
                          f'{spec!r}')
    tokens = spec.strip().split('-')
    layers: list[Layer] = []
    pending_conv: tuple[str, int] | None = None  # the letter and kernel of a C or S token
    for pos, tok in enumerate(tokens, 1):
        m = _TOKEN.fullmatch(tok)
        where = f'token {pos} {tok!r} of spec {spec!r}'
        if m is None:
            raise ConfigError(f'bad {where}: expected C<kernel>, S<kernel>, F<filters>, '
                              f'P<pool> or D<units> with a positive integer ({_EXAMPLE})')
        letter, value = m.group(1), int(m.group(2))
        if value > _LIMITS[letter]:
            raise ConfigError(f'bad {where}: {letter} must be at most {_LIMITS[letter]}')
        if pending_conv is not None and letter != 'F':
            raise ConfigError(f'bad {where}: a convolution {"".join(map(str, pending_conv))} '
                              f'must be followed by its filter count F<n>')
        if letter == 'F':
            if pending_conv is None:
                raise ConfigError(f'bad {where}: F<filters> must follow a convolution C<k> or '
                                  f'S<k>')
            kind, kernel = pending_conv
            layers.append(Layer('conv', kernel, value, kernel if kind == 'S' else 1))
            pending_conv = None
        elif letter in 'CS':
            if layers and layers[-1].kind == 'dense':
                raise ConfigError(f'bad {where}: convolutions must come before dense layers')
            pending_conv = (letter, value)
        elif letter == 'P':
            if layers and layers[-1].kind == 'dense':
                raise ConfigError(f'bad {where}: pooling must come before dense layers')
            layers.append(Layer('pool', value))
        else:
            layers.append(Layer('dense', value))
    if pending_conv is not None:
        raise ConfigError(f'bad spec {spec!r}: the last convolution '
                          f'{"".join(map(str, pending_conv))} lacks its filter count F<n>')
    if input_size is not None:
        layer_shapes(layers, input_size, spec)
    return layers


def format_spec(layers: list[Layer]) -> str:
    """The canonical spec string of a list of layers (``parse_spec`` round-trips through it)."""
    return '-'.join(str(layer) for layer in layers)


def layer_shapes(layers: list[Layer], input_size: int, spec: str = '') -> list[tuple[int, int]]:
    """(channels, side) after each layer, checking that every layer keeps at least a voxel."""
    if input_size < 1:
        raise ConfigError(f'input size must be at least 1 voxel, got {input_size}')
    ch, side = 1, input_size
    out = []
    pos = 0
    for layer in layers:
        token = pos + 1  # the C of a convolution, or the layer's one token
        pos += 2 if layer.kind == 'conv' else 1
        if layer.kind == 'conv':
            side, ch = (side - layer.size) // layer.stride + 1, layer.filters
        elif layer.kind == 'pool':
            side = side // layer.size
        else:
            ch, side = layer.size, 1
        if side < 1:
            raise ConfigError(f'bad token {token} {str(layer).split("-")[0]!r} of spec {spec!r}: '
                              f'it shrinks the {input_size}^3 input to nothing')
        out.append((ch, side))
    return out
