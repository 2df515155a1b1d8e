"""The Communication-Aware module: any length, messages both ways, gradients, masking."""

import torch

from carl_sumo.models import CommunicationAware


def test_one_set_of_weights_runs_any_platoon_length():
    torch.manual_seed(0)
    net = CommunicationAware(4, 1, message_dim=8, hidden=16)
    for n in (1, 3, 10, 50):
        assert net(torch.randn(2, n, 4)).shape == (2, n, 1)


@torch.no_grad()
def test_action_depends_on_vehicles_ahead_and_behind():
    torch.manual_seed(0)
    net = CommunicationAware(4, 1, message_dim=8, hidden=16)
    x = torch.randn(1, 5, 4)
    base = net(x)[0, 2, 0]
    ahead, behind = x.clone(), x.clone()
    ahead[0, 0] += 1.0     # the head, ahead of vehicle 2
    behind[0, 4] += 1.0    # the tail, behind vehicle 2
    assert abs(float(net(ahead)[0, 2, 0] - base)) > 1e-6
    assert abs(float(net(behind)[0, 2, 0] - base)) > 1e-6


def test_gradients_reach_both_networks_and_boundaries():
    net = CommunicationAware(4, 1, message_dim=8, hidden=16)
    net(torch.randn(3, 4, 4)).sum().backward()
    for name, p in net.named_parameters():
        assert p.grad is not None and p.grad.abs().sum() > 0, name


@torch.no_grad()
def test_padding_with_mask_leaves_real_vehicles_unchanged():
    torch.manual_seed(1)
    net = CommunicationAware(4, 1, message_dim=8, hidden=16)
    x = torch.randn(1, 3, 4)
    padded = torch.cat([x, torch.randn(1, 4, 4)], dim=1)
    mask = torch.tensor([[True] * 3 + [False] * 4])
    assert torch.allclose(net(padded, mask)[:, :3], net(x), atol=1e-6)
