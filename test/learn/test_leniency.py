"""The leniency penalty of fine-tuning: obstacle samples judged safer than the initial net pay."""
import pytest
import torch

from landing_zone.errors import ConfigError
from landing_zone.judging.net import SafetyNet, SafetyNetConfig
from landing_zone.tools.learn.leniency import LeniencyPenalty


def nets(dropout=0.0):
    torch.manual_seed(0)
    init = SafetyNet(SafetyNetConfig('C3-F4-P4-D8', dropout=dropout))
    return init, torch.randn(6, 1, 32, 32, 32), torch.tensor([0, 1, 0, 1, 0, 1])


def test_no_penalty_for_the_initial_net_itself():
    init, x, y = nets()
    pen = LeniencyPenalty(init, 1.0, torch.device('cpu'))
    logits, _ = init(x)
    assert float(pen(x, y, logits).detach()) == 0.0


def test_dropout_noise_is_charged_in_training_mode():
    # as documented: the trained net's training-mode logits against the eval-mode copy
    init, x, _ = nets(dropout=0.5)
    y = torch.zeros(len(x), dtype=torch.long)  # every sample an obstacle
    pen = LeniencyPenalty(init, 1.0, torch.device('cpu'))
    init.train()
    assert float(pen(x, y, init(x)[0]).detach()) > 0.0
    init.eval()
    assert float(pen(x, y, init(x)[0]).detach()) == 0.0


def test_only_obstacle_samples_judged_safer_pay():
    init, x, y = nets()
    pen = LeniencyPenalty(init, 2.0, torch.device('cpu'))
    ref, _ = init(x)
    logits = (ref.detach() + torch.tensor([1.0, 5.0, -1.0, 5.0, 0.5, 5.0])).requires_grad_()
    loss = pen(x, y, logits)
    assert float(loss) == pytest.approx(2.0 * (1.0 + 0.25) / 6)  # safe samples free
    loss.backward()
    assert logits.grad[1] == 0 and logits.grad[2] == 0 and logits.grad[0] > 0


def test_the_initial_net_is_a_frozen_copy():
    init, x, y = nets()
    pen = LeniencyPenalty(init, 1.0, torch.device('cpu'))
    with torch.no_grad():
        for p in init.parameters():
            p.add_(1.0)  # the net being trained moves; the reference does not
    assert all(not p.requires_grad for p in pen.net.parameters())
    assert not pen.net.training
    assert float(pen(x, y, init(x)[0]).detach()) > 0


def test_a_weight_must_be_positive():
    init, _, _ = nets()
    with pytest.raises(ConfigError, match='positive'):
        LeniencyPenalty(init, 0.0, torch.device('cpu'))
