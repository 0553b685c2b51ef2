"""The safety CNN: a 3D ConvNet built from the paper's shorthand (:mod:`.spec`).

A spec such as ``C7-F32-P2-C5-F64-P2-D512`` reads left to right: ``C7-F32`` a 7^3 convolution
with 32 filters (valid padding, stride 1) and a ReLU, ``P2`` a 2^3 max-pool, ``D512`` a dense
layer of 512 units and a ReLU; a final linear unit gives the logit of P(safe); ``S2-F4``, a 2^3
convolution of stride 2, halves the side from all 8 voxels of each block where ``P2`` keeps
their maximum (:mod:`.spec`). Dropout (0.5 by default) follows every convolution but a strided
one and every dense layer in training. The file reads top-down, as nanoGPT's model.py: the
blocks, the config, the net. Checkpoints are in :mod:`.checkpoint`, inference in
:mod:`.inference`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from torch import nn
from torch.nn import functional as F

from landing_zone.errors import ConfigError
from landing_zone.judging.spec import Layer, format_spec, layer_shapes, parse_spec

__all__ = [
    'DEFAULT_SPEC',
    'PAPER_SPEC',
    'FAST_SPEC',
    'SafetyNetConfig',
    'SafetyNet',
    'judge',
]

# The paper's best network (its Table II); models/paper_C7-F32-P2-C5-F64-P2-D512.safetensors.
PAPER_SPEC = 'C7-F32-P2-C5-F64-P2-D512'
# The shipped net, for small on-board CPUs: it max-pools the input to 10 cm first (a hit
# anywhere in a 2^3 block survives), so it costs 11 MMAC per tile against the paper net's 382:
# a full map fits the on-board time budget on a small CPU (`landing-zone bench assess`).
FAST_SPEC = 'P2-C5-F32-P2-C3-F64-D128'
DEFAULT_SPEC = FAST_SPEC


# --- blocks ------------------------------------------------------------------------------------

class ConvBlock(nn.Module):
    """Valid k^3 convolution (stride 1, or s for a spec's ``S`` token), ReLU, dropout."""

    def __init__(self, in_ch: int, out_ch: int, kernel: int, dropout: float,
                 stride: int = 1) -> None:
        super().__init__()
        self.conv = nn.Conv3d(in_ch, out_ch, kernel, stride=stride)
        self.drop = nn.Dropout(dropout) if dropout > 0 else nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        # (B, C_out, (D-k)//s+1, (H-k)//s+1, (W-k)//s+1)
        out: torch.Tensor = self.drop(F.relu(self.conv(x)))
        return out


class PoolBlock(nn.Module):
    """p^3 max-pool (floor mode); P1 is the identity."""

    def __init__(self, size: int) -> None:
        super().__init__()
        self.size = size

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.size == 1:
            return x
        return F.max_pool3d(x, self.size)  # (B, C, D//p, H//p, W//p)


class DenseBlock(nn.Module):
    """Fully connected layer, ReLU, dropout."""

    def __init__(self, in_features: int, out_features: int, dropout: float) -> None:
        super().__init__()
        self.fc = nn.Linear(in_features, out_features)
        self.drop = nn.Dropout(dropout) if dropout > 0 else nn.Identity()

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out: torch.Tensor = self.drop(F.relu(self.fc(x)))  # (B, out)
        return out


# --- config ------------------------------------------------------------------------------------

@dataclass
class SafetyNetConfig:
    """What it takes to rebuild a net (stored in every checkpoint)."""

    spec: str = DEFAULT_SPEC  # the paper's shorthand, see parse_spec
    input_size: int = 32  # voxels per side of the input cube: tile voxels + 2 * padding
    dropout: float = 0.5  # dropout after every conv / dense layer in training (0 = none)

    def validate(self) -> list[Layer]:
        if not 0.0 <= self.dropout < 1.0:
            raise ConfigError(f'dropout must lie in [0, 1), got {self.dropout}')
        return parse_spec(self.spec, self.input_size)


# --- the net -----------------------------------------------------------------------------------

class SafetyNet(nn.Module):
    """The 3D CNN: input (B, 1, S, S, S) of ``2 * density - 1``, output the logit of P(safe).

    Attributes:
        config: the :class:`SafetyNetConfig` it was built from.
        layers: the parsed spec.
        temperature: calibration temperature; P(safe) = sigmoid(logit / temperature + offset).
        offset: calibration offset (0 unless fitted on families the net never saw, see
            :mod:`landing_zone.tools.learn.recalibrate`).
    """

    def __init__(self, config: SafetyNetConfig | None = None) -> None:
        super().__init__()
        self.config = config if config is not None else SafetyNetConfig()
        self.layers = self.config.validate()
        self.config.spec = format_spec(self.layers)
        self.temperature = 1.0
        self.offset = 0.0
        shapes = layer_shapes(self.layers, self.config.input_size, self.config.spec)
        features: list[nn.Module] = []
        dense: list[nn.Module] = []
        ch, side = 1, self.config.input_size
        for layer, (out_ch, out_side) in zip(self.layers, shapes):
            if layer.kind == 'conv':
                # a strided convolution stands where a pool would: no dropout after it (a
                # block's few channels are all there is of its 8 voxels)
                features.append(ConvBlock(ch, layer.filters, layer.size,
                                          self.config.dropout if layer.stride == 1 else 0.0,
                                          layer.stride))
            elif layer.kind == 'pool':
                features.append(PoolBlock(layer.size))
            else:
                dense.append(DenseBlock(ch * side ** 3, layer.size, self.config.dropout))
            ch, side = out_ch, out_side
        self.features = nn.Sequential(*features)
        self.dense = nn.Sequential(*dense)
        self.head = nn.Linear(ch * side ** 3, 1)
        self._init_weights()

    def _init_weights(self) -> None:
        # Glorot-uniform weights and zero biases (the Theano/Lasagne-era default the paper's
        # nets were trained from). He initialisation with SGD at lr 0.01 killed the dense
        # layer's ReLUs within tens of steps when its fan-in is large (C5-F8-P2-D32: 22k).
        for m in self.modules():
            if isinstance(m, (nn.Conv3d, nn.Linear)):
                nn.init.xavier_uniform_(m.weight)
                assert m.bias is not None  # both layer types are built with a bias
                nn.init.zeros_(m.bias)

    @property
    def spec(self) -> str:
        return self.config.spec

    @property
    def input_pool(self) -> int:
        """Edge of the max-pool the spec opens with (1: none). The tiler can hand over its
        cubes pooled already (``embed(x, pooled=True)``): a quarter of the network's time, and
        an eighth of the memory the tiler writes."""
        first = self.layers[0]
        return first.size if first.kind == 'pool' else 1

    def embed(self, x: torch.Tensor, pooled: bool = False) -> torch.Tensor:
        """The penultimate features (B, F): what the head reads (the last dense layer's
        output; the flattened conv features for a spec without one).

        Args:
            x: (B, 1, S, S, S) inputs; with ``pooled``, (B, 1, S/p, S/p, S/p) inputs already
                max-pooled by the spec's opening pool ``p`` (:attr:`input_pool`).
            pooled: skip the opening pool (the caller did it).
        """
        side = self.config.input_size // (self.input_pool if pooled else 1)
        assert x.dim() == 5 and tuple(x.shape[1:]) == (1, side, side, side), \
            f'expected (B, 1, {side}, {side}, {side}), got {tuple(x.shape)}'
        blocks = list(self.features)
        if pooled:
            assert self.input_pool > 1, 'pooled inputs for a spec that does not open with a pool'
            blocks = blocks[1:]
        if self.training:
            for block in blocks:
                x = block(x)
        else:
            # Inference: a convolution followed by a pool is pooled before its ReLU. ReLU is
            # monotone, so max(relu(a)) == relu(max(a)) exactly, on 1/p^3 of the values
            # (dropout is the identity in eval mode).
            k = 0
            while k < len(blocks):
                block = blocks[k]
                after = blocks[k + 1] if k + 1 < len(blocks) else None
                if isinstance(block, ConvBlock) and isinstance(after, PoolBlock) \
                        and after.size > 1:
                    x = F.relu(F.max_pool3d(block.conv(x), after.size))
                    k += 2
                else:
                    x = block(x)
                    k += 1
        x = x.reshape(x.shape[0], -1)  # (B, C * D' * H' * W')
        out: torch.Tensor = self.dense(x)  # (B, units)
        return out

    def forward(self, x: torch.Tensor, targets: torch.Tensor | None = None,
                pooled: bool = False) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Logits (B,) of P(safe), and the mean binary cross-entropy if targets (1 = safe);
        ``pooled`` as in :meth:`embed`."""
        return judge(self, x, targets, pooled)

    def flops(self) -> int:
        """Multiply-adds of one forward pass for one volume."""
        total = 0
        ch, side = 1, self.config.input_size
        shapes = layer_shapes(self.layers, self.config.input_size, self.config.spec)
        for layer, (out_ch, out_side) in zip(self.layers, shapes):
            if layer.kind == 'conv':
                total += out_side ** 3 * out_ch * ch * layer.size ** 3
            elif layer.kind == 'dense':
                total += ch * side ** 3 * out_ch
            ch, side = out_ch, out_side
        return total + ch * side ** 3

    def num_params(self) -> int:
        return sum(p.numel() for p in self.parameters())


def judge(net: Any, x: torch.Tensor, targets: torch.Tensor | None = None,
          pooled: bool = False) -> tuple[torch.Tensor, torch.Tensor | None]:
    """The forward pass every safety net shares (a :class:`SafetyNet` or an ensemble of them):
    the logits (B,) of its ``head`` over its ``embed``, and the mean binary cross-entropy if
    targets (1 = safe)."""
    logits: torch.Tensor = net.head(net.embed(x, pooled)).squeeze(1)  # (B,)
    loss = None
    if targets is not None:
        loss = F.binary_cross_entropy_with_logits(logits.float(), targets.float())
    return logits, loss
