"""An ensemble of safety CNNs judged as one net: the mean of its members' logits.

Why: members trained on different subsets of the families (the fold models of
:func:`landing_zone.tools.evaluate.lofo.family_folds`) disagree where a tile looks like a family
some of them never saw, and their mean logit is then less sure there; the price is that each
member saw fewer families than one model trained on all of them.

A :class:`SafetyEnsemble` offers what the rest of the code asks of a
:class:`~landing_zone.judging.net.SafetyNet` (``embed``, ``head``, ``forward``, ``spec``,
``input_pool``, ``temperature`` and ``offset``), so the tiler,
:class:`~landing_zone.judging.inference.Predictor`, the OOD signal, calibration and evaluation
take either:

* the logit is the mean of the members' raw logits; the ensemble has one calibration of its own
  (``temperature``, ``offset``), fitted on it (each member's own calibration is not used);
* the features are the members' penultimate features side by side, ``(B, K * F)``, so an OOD
  reference of the ensemble measures every member's view of a tile;
* checkpoints hold the members' weights under ``members.K.`` and the member count in the
  metadata (:mod:`landing_zone.judging.checkpoint`).
"""
from __future__ import annotations

from typing import Sequence, Union

import torch
from torch import nn

from landing_zone.errors import ConfigError
from landing_zone.judging.net import SafetyNet, SafetyNetConfig, judge

__all__ = ['SafetyEnsemble', 'EnsembleHead', 'AnyNet', 'MAX_MEMBERS']

MAX_MEMBERS = 16  # a sanity bound on what a checkpoint may ask to build


class EnsembleHead(nn.Module):
    """The members' output layers side by side: ``(B, K * F)`` features to ``(B, 1)``, the mean
    of the K logits. Holds no parameters of its own (the heads stay the members')."""

    def __init__(self, heads: Sequence[nn.Linear]) -> None:
        super().__init__()
        self._heads = tuple(heads)  # a tuple: not registered twice in the state dict
        self.per_member = int(heads[0].in_features)
        self.in_features = self.per_member * len(heads)

    def forward(self, features: torch.Tensor) -> torch.Tensor:
        parts = torch.split(features, self.per_member, dim=1)  # K x (B, F)
        logits = torch.stack([h(f) for h, f in zip(self._heads, parts)], 0)  # (K, B, 1)
        out: torch.Tensor = logits.mean(0)  # (B, 1)
        return out


class SafetyEnsemble(nn.Module):
    """K safety CNNs of one architecture judged as one net (see the module docstring).

    Args:
        members: the nets, all of one spec and input size (their own calibration is ignored).

    Raises:
        ConfigError: no members, too many, or members of different architectures.
    """

    def __init__(self, members: Sequence[SafetyNet]) -> None:
        super().__init__()
        if not 1 <= len(members) <= MAX_MEMBERS:
            raise ConfigError(f'an ensemble has 1 to {MAX_MEMBERS} members, got {len(members)}')
        first = members[0].config
        for k, m in enumerate(members):
            if (m.config.spec, m.config.input_size) != (first.spec, first.input_size):
                raise ConfigError(f'ensemble member {k} is {m.config.spec} on '
                                  f'{m.config.input_size}^3 inputs, member 0 {first.spec} on '
                                  f'{first.input_size}^3: members must share an architecture')
        self.members = nn.ModuleList(members)
        self._nets: tuple[SafetyNet, ...] = tuple(members)  # typed views of the same modules
        self.config = SafetyNetConfig(first.spec, first.input_size, first.dropout)
        self.layers = members[0].layers
        self.temperature = 1.0
        self.offset = 0.0
        self.head = EnsembleHead([m.head for m in members])

    @property
    def spec(self) -> str:
        return self.config.spec

    @property
    def size(self) -> int:
        """Number of members."""
        return len(self.members)

    @property
    def input_pool(self) -> int:
        """As :attr:`SafetyNet.input_pool` (every member opens alike)."""
        return self._nets[0].input_pool

    def embed(self, x: torch.Tensor, pooled: bool = False) -> torch.Tensor:
        """The members' penultimate features side by side, ``(B, K * F)``."""
        return torch.cat([m.embed(x, pooled) for m in self._nets], dim=1)

    def forward(self, x: torch.Tensor, targets: torch.Tensor | None = None,
                pooled: bool = False) -> tuple[torch.Tensor, torch.Tensor | None]:
        """Mean logit (B,) of the members, and the mean binary cross-entropy if targets."""
        return judge(self, x, targets, pooled)

    def flops(self) -> int:
        """Multiply-adds of one forward pass for one volume (every member)."""
        return sum(m.flops() for m in self._nets) + self.size

    def num_params(self) -> int:
        return sum(p.numel() for p in self.parameters())


AnyNet = Union[SafetyNet, SafetyEnsemble]
