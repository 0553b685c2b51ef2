"""Fine-tuning that may not grow more lenient on obstacles than the net it starts from.

Fine-tuning a model on a site's hybrid set (``train --init``) teaches it the site's vegetation;
with nothing else in the loss, the features it learns for "grass of this site is safe" also
raise the logits of obstacles the site data never showed, most of all shapes no training set
held. Binary cross-entropy cannot see that drift: on an obstacle sample the initial
net already calls surely unsafe its gradient is close to zero, so the margin can shrink freely
until the sample crosses.

:class:`LeniencyPenalty` adds, on every obstacle sample of a batch (label 0, whatever training
source it came from), ``weight * relu(logit - logit_init)^2``, where ``logit_init`` is the
initial net's logit on the same augmented input (frozen, eval mode). Safe samples are free, so
the net can move what the site data shows (its vegetation judged safe) but pays for every
obstacle it judges safer than the initial net did. Squared, so that a small drift (or dropout's
noise in training mode) costs little and the push stops once the net is no more lenient.

The trained net's logit is its training-mode one (dropout on), so the penalty charges dropout's
noise too, a little on every obstacle sample. That is deliberate: judged in eval mode on both
sides, the penalty leaves the fine-tuned net no room to learn the site's vegetation, and a copy
in training mode under the same dropout masks makes the loss unstable.
"""
from __future__ import annotations

import copy

import torch
import torch.nn.functional as F

from landing_zone.errors import ConfigError
from landing_zone.judging.ensemble import AnyNet

__all__ = ['LeniencyPenalty']


class LeniencyPenalty:
    """``weight * mean_batch([y = 0] * relu(logit - logit_init)^2)`` against a frozen copy of the
    initial net.

    Args:
        init: the net fine-tuning starts from (copied; the copy is frozen, in eval mode).
        weight: the penalty's weight beside the mean binary cross-entropy (> 0).
        device: where the copy runs (the training device).
    """

    def __init__(self, init: AnyNet, weight: float, device: torch.device) -> None:
        if not weight > 0:
            raise ConfigError(f'the leniency penalty weight must be positive, got {weight}')
        self.weight = float(weight)
        self.net = copy.deepcopy(init).to(device=device, memory_format=torch.channels_last_3d)
        self.net.eval()
        for p in self.net.parameters():
            p.requires_grad_(False)

    def __call__(self, x: torch.Tensor, y: torch.Tensor, logits: torch.Tensor) -> torch.Tensor:
        """The penalty of one batch.

        Args:
            x: (B, 1, D, H, W) the inputs the net being trained saw.
            y: (B,) labels, 1 safe, 0 unsafe.
            logits: (B,) its logits on them (with their graph).
        """
        with torch.no_grad():
            ref, _ = self.net(x)  # (B,)
        unsafe = (y == 0).to(logits.dtype)
        excess = F.relu(logits.float() - ref.float())
        return self.weight * (unsafe * excess.square()).mean()
