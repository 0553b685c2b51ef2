"""The leniency penalty of fine-tuning: obstacle samples judged safer than the initial net pay."""
import pytest
import torch

from landing_zone.errors import ConfigError
from landing_zone.judging.net import SafetyNet, SafetyNetConfig
from landing_zone.learn.leniency import LeniencyPenalty


def nets(dropout=0.5):
    torch.manual_seed(0)
    init = SafetyNet(SafetyNetConfig('C3-F4-P4-D8', dropout=dropout))
    init.train()  # as in training: dropout on
    return init, torch.randn(6, 1, 32, 32, 32), torch.tensor([0, 1, 0, 1, 0, 1])


class Shifted(torch.nn.Module):
    """A net whose logits are another's plus a fixed shift per sample (a drift of the weights)."""

    def __init__(self, net, shift):
        super().__init__()
        self.net, self.shift, self.rows = net, shift, None

    def forward(self, x):
        logits, _ = self.net(x)
        return logits + self.shift[self.rows], None


def test_no_penalty_for_the_initial_net_itself_whatever_dropout_draws():
    init, x, y = nets()
    pen = LeniencyPenalty(init, 1.0, torch.device('cpu'))
    for _ in range(3):  # dropout's noise is not charged: both nets are judged in eval mode
        assert float(pen(init, x, y).detach()) == 0.0
    assert init.training  # the trained net is left in training mode


def test_only_obstacle_samples_judged_safer_pay():
    init, x, y = nets()
    pen = LeniencyPenalty(init, 2.0, torch.device('cpu'))
    shift = torch.tensor([1.0, 5.0, -1.0, 5.0, 0.5, 5.0], requires_grad=True)
    net = Shifted(init, shift)
    net.rows = y == 0  # the penalty runs the net on the obstacle samples only
    loss = pen(net, x, y)
    assert float(loss) == pytest.approx(2.0 * (1.0 + 0.25) / 6)  # safe samples free
    loss.backward()
    assert shift.grad[1] == 0 and shift.grad[2] == 0 and shift.grad[0] > 0


def test_a_batch_without_obstacles_costs_nothing():
    init, x, _ = nets()
    pen = LeniencyPenalty(init, 1.0, torch.device('cpu'))
    assert float(pen(init, x, torch.ones(6, dtype=torch.long))) == 0.0


def test_the_initial_net_is_a_frozen_copy_and_the_gradient_reaches_the_weights():
    init, x, y = nets()
    pen = LeniencyPenalty(init, 1.0, torch.device('cpu'))
    with torch.no_grad():
        init.head.bias.add_(3.0)  # the net being trained moves (every logit +3), the copy not
    assert all(not p.requires_grad for p in pen.net.parameters())
    assert not pen.net.training
    loss = pen(init, x, y)
    assert float(loss.detach()) > 0
    loss.backward()
    assert any(p.grad is not None and bool(p.grad.abs().sum() > 0) for p in init.parameters())


def test_a_weight_must_be_positive():
    init, _, _ = nets()
    with pytest.raises(ConfigError, match='positive'):
        LeniencyPenalty(init, 0.0, torch.device('cpu'))
