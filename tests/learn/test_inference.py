"""The compiled actor (carl_sumo.learn.inference) gives Agent.act's numbers for every algorithm."""

from pathlib import Path

import numpy as np
import pytest
import torch

from carl_sumo.learn.agents import ALGOS, Agent, AgentConfig
from carl_sumo.errors import InputError
from carl_sumo.learn.inference import CompiledActor
from carl_sumo.learn.policy import load_controller, load_policy

TOLERANCE_MPS2 = 1e-5
SHIPPED_CA_POLICY = Path(__file__).resolve().parents[2] / "policies" / "ca_td3_10.pt"


def random_platoon(rng: np.random.Generator, n: int) -> np.ndarray:
    """Observations (n, 4) [v, a, d, Δv] over wide ranges, gaps beyond the 150 m clip included."""
    return np.column_stack([rng.uniform(0, 35, n), rng.uniform(-4, 3, n),
                            rng.uniform(-1, 250, n), rng.uniform(-10, 10, n)])


@pytest.mark.parametrize("algo", ALGOS)
def test_compiled_actor_matches_agent_act(algo):
    torch.manual_seed(1)
    rng = np.random.default_rng(1)
    fixed = 6
    agent = Agent(AgentConfig(algo=algo, n_vehicles=fixed))
    with torch.no_grad():  # larger weights than the default init: tanh far from linear
        for p in agent.actor.parameters():
            p.mul_(2.0)
    compiled = CompiledActor(agent)
    lengths = [fixed] if algo == "maddpg" else [1, 2, 6, 10, 23]
    for n in lengths:
        for _ in range(5):
            obs = random_platoon(rng, n)
            got = compiled(obs)
            assert got.shape == (n,) and got.dtype == np.float64
            np.testing.assert_allclose(got, agent.act(obs), rtol=0, atol=TOLERANCE_MPS2)


def test_compiled_maddpg_refuses_other_lengths():
    compiled = CompiledActor(Agent(AgentConfig(algo="maddpg", n_vehicles=4)))
    with pytest.raises(InputError, match="trained for 4 vehicles"):
        compiled(np.ones((5, 4)))


def test_shipped_ca_policy_matches_and_controller_uses_it():
    agent, _ = load_policy(SHIPPED_CA_POLICY)
    controller = load_controller(SHIPPED_CA_POLICY)
    rng = np.random.default_rng(2)
    for n in (1, 10, 20):
        controller.reset(n)
        for _ in range(3):
            obs = random_platoon(rng, n)
            np.testing.assert_allclose(controller.adjustment(obs), agent.act(obs), rtol=0,
                                       atol=TOLERANCE_MPS2)


def test_compiled_actor_keeps_a_smaller_adjustment_bound():
    torch.manual_seed(0)
    agent = Agent(AgentConfig(algo="ca-td3", adj_max=1.0))
    for p in agent.actor.parameters():
        p.data *= 5.0  # saturate tanh so the bound shows
    obs = np.random.default_rng(0).uniform([0, -1, 1, -3], [30, 1, 80, 3], (10, 4))
    out = CompiledActor(agent)(obs)
    assert np.abs(out).max() <= 1.0 and np.abs(out).max() > 0.9
    assert np.allclose(out, agent.act(obs), atol=1e-5)


def test_a_fading_message_mixes_in_the_actors_own_boundary_message():
    """Past the timeout the compiled CA actor hears w·held + (1 - w)·its boundary message."""
    from carl_sumo.control.channel import FALLBACK, HELD, Impairments, PlatoonLinks
    from carl_sumo.learn.inference import _communication_aware_act_channel

    torch.manual_seed(3)
    agent = Agent(AgentConfig(algo="ca-td3", n_vehicles=3))
    with torch.no_grad():
        agent.actor.forward_boundary.normal_()
        agent.actor.backward_boundary.normal_()
    compiled = CompiledActor(agent)
    obs = random_platoon(np.random.default_rng(3), 3)
    links = PlatoonLinks(3, compiled.message_dim, Impairments(loss=1.0, timeout_s=0.1, fade_s=0.1),
                         "e")
    message = np.linspace(-0.5, 0.5, compiled.message_dim)
    for channel in (links.forward, links.backward):
        channel.held[:] = message
        channel.sent_at[:] = -2  # age 2 at step 0: T = F = 1 step, so w = 0.5
    got = compiled.act_over(obs, links)
    fb, bb = compiled._weights[0], compiled._weights[1]
    held_f = np.tile(0.5 * message + 0.5 * fb, (3, 1))
    held_b = np.tile(0.5 * message + 0.5 * bb, (3, 1))
    mode = np.full(3, HELD)
    expected, _, _ = _communication_aware_act_channel(obs, compiled.adj_max, mode, held_f, mode,
                                                      held_b, *compiled._weights)
    np.testing.assert_allclose(got, expected, rtol=0, atol=1e-12)
    alone, _, _ = _communication_aware_act_channel(obs, compiled.adj_max, np.full(3, FALLBACK),
                                                   held_f, np.full(3, FALLBACK), held_b,
                                                   *compiled._weights)
    assert not np.allclose(got[1], alone[1])  # the middle vehicle still hears half a message
