"""The Communication-Aware module: any length, messages both ways, gradients, masking; the fused
pass against the original per-vehicle loop."""

import copy

import pytest
import torch

from carl_sumo.learn.ca_scan import ca_forward
from carl_sumo.learn.models import CommunicationAware


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


# --------------------------------------------------------------------- fused pass vs reference
def reference_ca(net: CommunicationAware, x: torch.Tensor,
                 mask: torch.Tensor | None = None) -> torch.Tensor:
    """The original per-vehicle loop of CommunicationAware.forward (before the fused pass):
    autograd through every layer of every vehicle."""
    batch, n, _ = x.shape
    if mask is None:
        mask = torch.ones(batch, n, dtype=torch.bool)
    m = mask.unsqueeze(-1)
    message = net.forward_boundary.expand(batch, -1)
    forward_messages = [message] * n
    for i in range(n - 1, -1, -1):  # tail -> head
        new = net.forward_net(torch.cat([x[:, i], message], dim=-1))
        message = torch.where(m[:, i], new, net.forward_boundary.expand(batch, -1))
        forward_messages[i] = message
    message = net.backward_boundary.expand(batch, -1)
    outputs = []
    for i in range(n):  # head -> tail
        out = net.backward_net(torch.cat([forward_messages[i], message], dim=-1))
        message = torch.tanh(out[:, : net.message_dim])
        outputs.append(out[:, net.message_dim:])
    return torch.stack(outputs, dim=1)


def _random_nets(g: int, in_dim: int, seed: int) -> list[CommunicationAware]:
    torch.manual_seed(seed)
    nets = [CommunicationAware(in_dim, 1) for _ in range(g)]  # the agents' sizes (16, 64)
    with torch.no_grad():  # boundaries are zero at init; make them matter
        for net in nets:
            net.forward_boundary.normal_()
            net.backward_boundary.normal_()
    return nets


def _shorter_platoons(batch: int, n: int) -> torch.Tensor:
    """Masks of platoons of lengths 1..n, padded at the tail."""
    lengths = torch.arange(batch) % n + 1
    return torch.arange(n).unsqueeze(0) < lengths.unsqueeze(1)


def _outputs_and_grads(forward, nets, x, mask, weight):
    """Outputs (G, batch, n, 1) and the gradients of x and of every parameter of a
    weighted-sum loss."""
    x = x.detach().clone().requires_grad_(True)
    for net in nets:
        net.zero_grad()
    out = forward(nets, x, mask)
    (out.squeeze(-1) * weight).sum().backward()
    return out.detach(), [x.grad] + [p.grad.clone() for net in nets for p in net.parameters()]


def _reference(nets, x, mask):
    return torch.stack([reference_ca(net, x, mask) for net in nets])


@pytest.mark.parametrize("n,padded", [(1, False), (10, False), (10, True), (23, True)])
def test_fused_pass_matches_reference_loop_with_gradients(n, padded):
    """Actor-shaped (G = 1) and twin-critic-shaped (G = 2) fused passes give the reference loop's
    outputs (same float32 weights) to 1e-5, and their gradients of weights, boundaries and inputs
    match the reference's in float64 to 1e-5 (the float32 reference itself can be 1e-3 off where
    a ReLU input rounds across zero) and exactly in float64."""
    for g, in_dim in ((1, 4), (2, 5)):
        nets = _random_nets(g, in_dim, seed=n + g)
        x = torch.randn(16, n, in_dim)
        mask = _shorter_platoons(16, n) if padded else None
        weight = torch.randn(16, n)  # a loss that weighs every output differently
        fused, fused_grads = _outputs_and_grads(ca_forward, nets, x, mask, weight)
        assert fused.shape == (g, 16, n, 1)
        ref32, _ = _outputs_and_grads(_reference, nets, x, mask, weight)
        torch.testing.assert_close(fused, ref32, rtol=0, atol=1e-5)
        nets64 = [copy.deepcopy(net).double() for net in nets]
        ref64, ref_grads = _outputs_and_grads(_reference, nets64, x.double(), mask,
                                              weight.double())
        for a, b in zip(fused_grads, ref_grads):
            torch.testing.assert_close(a.double(), b, rtol=1e-4, atol=1e-5)
        got64, grads64 = _outputs_and_grads(ca_forward, nets64, x.double(), mask,
                                            weight.double())
        torch.testing.assert_close(got64, ref64, rtol=0, atol=1e-12)
        for a, b in zip(grads64, ref_grads):
            torch.testing.assert_close(a, b, rtol=1e-9, atol=1e-12)


@torch.no_grad()
def test_fused_pass_without_gradients_matches_reference_on_padded_platoons():
    nets = _random_nets(1, 4, seed=3)
    x = torch.randn(32, 12, 4) * 3.0
    mask = _shorter_platoons(32, 12)
    got = nets[0](x, mask)
    torch.testing.assert_close(got, reference_ca(nets[0], x, mask), rtol=0, atol=1e-5)
    for row in (0, 4, 11):  # a padded row's real vehicles act as the shorter platoon alone
        length = int(mask[row].sum())
        torch.testing.assert_close(got[row, :length], nets[0](x[row:row + 1, :length])[0],
                                   rtol=0, atol=1e-5)


def test_detached_params_give_input_gradients_only():
    nets = _random_nets(1, 5, seed=4)
    x = torch.randn(8, 6, 5, requires_grad=True)
    ca_forward(nets, x, detach_params=True).sum().backward()
    assert x.grad is not None and x.grad.abs().sum() > 0
    assert all(p.grad is None for p in nets[0].parameters())
    x_ref = x.detach().clone().requires_grad_(True)
    reference_ca(nets[0], x_ref).sum().backward()
    torch.testing.assert_close(x.grad, x_ref.grad, rtol=1e-4, atol=1e-5)


def test_a_budgeted_gap_policys_critic_does_not_see_the_platoons_common_mode():
    """``gp=T:gb=1``: the law removes the platoon's common gap offset, so the critics see each
    action less the platoon's mean (over the vehicles present): Q is the same when every action
    moves alike, and is not without the budget."""
    import torch

    from carl_sumo.learn.agents import Agent, AgentConfig

    base = "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4:gp=2:gl=0.5:gb=1"
    torch.manual_seed(0)
    budgeted = Agent(AgentConfig(algo="ca-td3", n_vehicles=3, base=base, adj_max=1.0, hidden=16))
    free = Agent(AgentConfig(algo="ca-td3", n_vehicles=3, base=base.replace(":gb=1", ""),
                             adj_max=1.0, hidden=16))
    assert budgeted.cfg.common_mode_void and not free.cfg.common_mode_void
    x = torch.randn(4, 3, budgeted.cfg.obs_dim)
    a = torch.rand(4, 3) - 0.5
    mask = torch.ones(4, 3, dtype=torch.bool)
    for agent, same in ((budgeted, True), (free, False)):
        q, moved = (agent._q([agent.critic1], x, act, mask) for act in (a, a + 0.3))
        assert torch.allclose(q, moved, atol=1e-6) == same
    mask[:, 2] = False  # two vehicles present: their common mode is theirs alone
    shifted = a.clone()
    shifted[:, :2] += 0.3
    q, moved = (budgeted._q([budgeted.critic1], x, act, mask) for act in (a, shifted))
    assert torch.allclose(q[..., :2], moved[..., :2], atol=1e-6)
