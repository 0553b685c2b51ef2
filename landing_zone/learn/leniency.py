"""Fine-tuning that may not grow more lenient on obstacles than the net it starts from.

Fine-tuning a model on a site's hybrid set (``train --init``) teaches it the site's vegetation;
with nothing else in the loss, the features it learns for "grass of this site is safe" also
raise the logits of obstacles the site data never showed, most of all shapes no training set
held (measured: the obstacle tiles of synth3's test families passed at P(safe) >= 0.9 rose from
49 to 114 of 773). Binary cross-entropy cannot see that drift: on an obstacle sample the initial
net already calls surely unsafe its gradient is close to zero, so the margin can shrink freely
until the sample crosses.

:class:`LeniencyPenalty` adds, on every obstacle sample of a batch (label 0, whatever training
source it came from), ``weight * relu(logit - logit_init)^2``, where ``logit`` and
``logit_init`` are the trained and the initial net's logits on the same augmented input, both
in eval mode. Safe samples are free, so the net can move what the site data shows (its
vegetation judged safe) but pays for every obstacle it judges safer than the initial net did.
Squared, so that a small drift costs little and the push stops once the net is no more lenient.

Both logits are the eval-mode ones, the function the robot runs: the penalty is zero until the
weights move and measures their drift alone. The training-mode logits (dropout 0.5 after every
layer) are no measure of it: against the frozen eval-mode copy they sat 1.36 below on thin
obstacles (std 3.4), so the penalty charged dropout's noise (0.16 per obstacle sample at weight
1 before any step); and with both nets in training mode under the same dropout masks, the
masked sub-networks' logits reached +-60 and their squared difference diverged within a few
hundred batches at lr 0.001 (docs/EXPERIMENTS.md, sessions 18-19). The cost: one more forward
and backward pass of the obstacle samples.
"""
from __future__ import annotations

import copy

import torch
import torch.nn.functional as F

from landing_zone.errors import ConfigError
from landing_zone.judging.ensemble import AnyNet

__all__ = ['LeniencyPenalty']


class LeniencyPenalty:
    """``weight * mean_batch([y = 0] * relu(logit - logit_init)^2)``, both logits in eval mode,
    against a frozen copy of the initial net.

    Args:
        init: the net fine-tuning starts from (copied; the copy is frozen, in eval mode).
        weight: the penalty's weight beside the mean binary cross-entropy (> 0).
        device: where the copy runs (the training device).
    """

    def __init__(self, init: AnyNet, weight: float, device: torch.device) -> None:
        if not weight > 0:
            raise ConfigError(f'the leniency penalty weight must be positive, got {weight}')
        self.weight = float(weight)
        self.net = copy.deepcopy(init).to(device)
        self.net.eval()
        for p in self.net.parameters():
            p.requires_grad_(False)

    def __call__(self, net: AnyNet, x: torch.Tensor, y: torch.Tensor) -> torch.Tensor:
        """The penalty of one batch, with the graph of ``net``'s eval-mode pass over its
        obstacle samples (``net`` is left in the mode it was in).

        Args:
            net: the net being trained.
            x: (B, 1, D, H, W) the inputs it saw.
            y: (B,) labels, 1 safe, 0 unsafe.
        """
        unsafe = y == 0
        if not bool(unsafe.any()):
            return x.new_zeros(())
        xu = x[unsafe]  # (U, 1, D, H, W)
        with torch.no_grad():
            ref, _ = self.net(xu)  # (U,)
        mode = net.training
        net.eval()
        try:
            logits, _ = net(xu)  # (U,)
        finally:
            net.train(mode)
        excess = F.relu(logits.float() - ref.float())
        return self.weight * excess.square().sum() / len(x)
