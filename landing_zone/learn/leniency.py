"""Fine-tuning that may not grow more lenient on obstacles than the net it starts from.

Fine-tuning a model on a site's hybrid set (``train --init``) teaches it the site's vegetation;
with nothing else in the loss, the features it learns for "grass of this site is safe" also
raise the logits of obstacles the site data never showed, most of all shapes no training set
held (measured: the obstacle tiles of synth3's test families passed at P(safe) >= 0.9 rose from
49 to 114 of 773). Binary cross-entropy cannot see that drift: on an obstacle sample the initial
net already calls surely unsafe its gradient is close to zero, so the margin can shrink freely
until the sample crosses.

:class:`LeniencyPenalty` adds, on every obstacle sample of a batch (label 0, whatever training
source it came from), ``weight * relu(logit - logit_init)^2``, where ``logit_init`` is the
initial net's logit on the same augmented input. Safe samples are free, so the net can move
what the site data shows (its vegetation judged safe) but pays for every obstacle it judges
safer than the initial net did. Squared, so that a small drift costs little and the push stops
once the net is no more lenient.

The frozen copy runs in training mode with the same dropout masks as the net being trained (the
random state of the net's forward pass replayed, :meth:`LeniencyPenalty.rng_state`), so the two
are the same sub-network and the penalty is zero until the weights move. Against the eval-mode
copy it was not: training-mode logits of edge15 sat 1.36 below its eval-mode logits on thin
obstacles (std 3.4), so the penalty charged dropout's noise (0.16 per obstacle sample at weight 1
before any step; docs/EXPERIMENTS.md, session 18).
"""
from __future__ import annotations

import copy

import torch
import torch.nn.functional as F

from landing_zone.errors import ConfigError
from landing_zone.judging.ensemble import AnyNet

__all__ = ['LeniencyPenalty', 'RngState']

RngState = tuple[torch.Tensor, torch.Tensor | None]  # (CPU generator, the CUDA device's or None)


class LeniencyPenalty:
    """``weight * mean_batch([y = 0] * relu(logit - logit_init)^2)`` against a frozen copy of the
    initial net, evaluated with the dropout masks of the net being trained.

    Args:
        init: the net fine-tuning starts from, as the training builds it (copied; the copy is
            frozen and stays in training mode, so it must have the same layers, dropout and
            memory layout).
        weight: the penalty's weight beside the mean binary cross-entropy (> 0).
        device: where the copy runs (the training device).
    """

    def __init__(self, init: AnyNet, weight: float, device: torch.device) -> None:
        if not weight > 0:
            raise ConfigError(f'the leniency penalty weight must be positive, got {weight}')
        self.weight = float(weight)
        self.device = device
        # as is, memory layout too: dropout draws its mask in memory order
        self.net = copy.deepcopy(init).to(device)
        self.net.train()  # dropout on, replaying the trained net's masks (no batch norm here)
        for p in self.net.parameters():
            p.requires_grad_(False)

    def rng_state(self) -> RngState:
        """The random state to take right before the trained net's forward pass."""
        cuda = torch.cuda.get_rng_state(self.device) if self.device.type == 'cuda' else None
        return torch.get_rng_state(), cuda

    def __call__(self, x: torch.Tensor, y: torch.Tensor, logits: torch.Tensor,
                 rng: RngState) -> torch.Tensor:
        """The penalty of one batch.

        Args:
            x: (B, 1, D, H, W) the inputs the net being trained saw.
            y: (B,) labels, 1 safe, 0 unsafe.
            logits: (B,) its logits on them (with their graph).
            rng: :meth:`rng_state` taken right before that forward pass.
        """
        cpu, cuda = rng
        devices = [self.device] if cuda is not None else []
        # fork_rng: the replay leaves the training's random stream where the forward left it
        with torch.no_grad(), torch.random.fork_rng(devices=devices):
            torch.set_rng_state(cpu)
            if cuda is not None:
                torch.cuda.set_rng_state(cuda, self.device)
            ref, _ = self.net(x)  # (B,)
        unsafe = (y == 0).to(logits.dtype)
        excess = F.relu(logits.float() - ref.float())
        return self.weight * (unsafe * excess.square()).mean()
