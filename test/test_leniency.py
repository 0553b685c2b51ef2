"""The leniency penalty of fine-tuning: obstacle samples judged safer than the initial net pay."""
import pytest
import torch

from landing_zone.errors import ConfigError
from landing_zone.judging.net import SafetyNet, SafetyNetConfig
from landing_zone.learn.leniency import LeniencyPenalty


def nets(dropout=0.0):
    torch.manual_seed(0)
    init = SafetyNet(SafetyNetConfig('C3-F4-P4-D8', dropout=dropout))
    return init, torch.randn(6, 1, 32, 32, 32), torch.tensor([0, 1, 0, 1, 0, 1])


def forward(pen, net, x):
    """The training step's order: the random state taken, then the trained net's forward."""
    rng = pen.rng_state()
    return net(x)[0], rng


@pytest.mark.parametrize('dropout', [0.0, 0.5])
def test_no_penalty_for_the_initial_net_itself(dropout):
    init, x, y = nets(dropout)
    init.train()
    pen = LeniencyPenalty(init, 1.0, torch.device('cpu'))
    logits, rng = forward(pen, init, x)
    # with dropout the copy replays the same masks: the same sub-network, no noise charged
    assert float(pen(x, y, logits, rng).detach()) == 0.0


def test_the_replay_uses_the_forward_pass_masks_and_leaves_the_random_stream_alone():
    init, x, y = nets(0.5)
    init.train()
    pen = LeniencyPenalty(init, 1.0, torch.device('cpu'))
    logits, rng = forward(pen, init, x)
    after = torch.get_rng_state()
    pen(x, y, logits, rng)
    assert torch.equal(torch.get_rng_state(), after)
    # another state gives other masks, so other logits: the replay is what pairs them
    assert not torch.equal(pen.net(x)[0].detach(), logits.detach())
    # paired, a drift of the logits is charged exactly, not blurred by dropout's noise
    shifted = logits.detach() + 0.5
    assert float(pen(x, y, shifted, rng)) == pytest.approx(1.0 * 0.25 * 3 / 6)


def test_only_obstacle_samples_judged_safer_pay():
    init, x, y = nets()
    pen = LeniencyPenalty(init, 2.0, torch.device('cpu'))
    ref, rng = forward(pen, init, x)
    logits = (ref.detach() + torch.tensor([1.0, 5.0, -1.0, 5.0, 0.5, 5.0])).requires_grad_()
    loss = pen(x, y, logits, rng)
    assert float(loss) == pytest.approx(2.0 * (1.0 + 0.25) / 6)  # safe samples free
    loss.backward()
    assert logits.grad[1] == 0 and logits.grad[2] == 0 and logits.grad[0] > 0


def test_the_initial_net_is_a_frozen_copy():
    init, x, y = nets(0.5)
    init.train()
    pen = LeniencyPenalty(init, 1.0, torch.device('cpu'))
    with torch.no_grad():
        for p in init.parameters():
            p.add_(1.0)  # the net being trained moves; the reference does not
    assert all(not p.requires_grad for p in pen.net.parameters())
    assert pen.net.training  # dropout on, the masks replayed
    logits, rng = forward(pen, init, x)
    assert float(pen(x, y, logits, rng).detach()) > 0


def test_a_weight_must_be_positive():
    init, _, _ = nets()
    with pytest.raises(ConfigError, match='positive'):
        LeniencyPenalty(init, 0.0, torch.device('cpu'))
