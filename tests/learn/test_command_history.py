"""The vehicle's own recent commands in its observation (``--command-history K``, Lin et al.
2019): the environment, a policy file's controller and training agree on them."""

import numpy as np
import pytest
import torch

from carl_sumo.control.controllers import adjustment_bounds
from carl_sumo.errors import InputError
from carl_sumo.learn.agents import Agent, AgentConfig
from carl_sumo.learn.env import PlatoonEnv
from carl_sumo.learn.policy import load_controller, load_policy, save_policy
from carl_sumo.learn.train_config import TrainConfig

from conftest import NET, braking_event

BASE = "ploeg:h=0.8:kp=0.2:kd=1"


def test_the_last_commands_follow_a_base_and_its_command():
    """Columns 5.. are the last k applied commands, the latest first, 0 before the first step."""
    env = PlatoonEnv([braking_event()], n_followers=3, net_path=NET, base=BASE,
                     command_history=3, bounds=adjustment_bounds(1.0))
    obs = env.reset_array(seed=0)
    assert obs.shape == (3, 8) and np.all(obs[:, 5:] == 0.0)
    applied = []
    for k in range(6):
        obs, _, _, _, accel = env.step_array(np.full(3, 0.1 * (k % 2)))
        applied.insert(0, accel)
        expected = np.column_stack((applied + [np.zeros(3)] * 3)[:3])
        assert np.array_equal(obs[:, 5:], expected)


def _moving_agent(k: int) -> Agent:
    """A CA-TD3 agent on BASE whose output depends on its inputs (the residual start is 0)."""
    agent = Agent(AgentConfig(algo="ca-td3", n_vehicles=3, base=BASE, adj_max=1.0,
                              command_history=k))
    torch.manual_seed(0)
    with torch.no_grad():
        for p in agent.actor.parameters():
            p.add_(0.3 * torch.randn_like(p))
    return agent


def test_a_policy_file_remembers_its_commands_as_training_did(tmp_path):
    """The controller that runs a policy file in simulate rebuilds the history the training
    environment gave it: the same commands, step by step; and the history moves its action."""
    agent = _moving_agent(4)
    save_policy(agent, tmp_path / "h.pt", {})
    loaded, _ = load_policy(tmp_path / "h.pt")
    assert loaded.cfg.command_history == 4 and loaded.cfg.obs_dim == 9
    controller = load_controller(tmp_path / "h.pt")
    env = PlatoonEnv([braking_event()], 3, NET, base=BASE, command_history=4,
                     bounds=adjustment_bounds(1.0))
    obs = env.reset_array(seed=0)
    controller.reset(3)
    moved = False
    for _ in range(40):
        action = agent.act(obs)
        blank = obs.copy()
        blank[:, 5:] = 0.0
        moved |= bool(np.abs(agent.act(blank) - action).max() > 1e-6)
        expected = controller.acceleration(obs[:, :4])
        obs, _, _, _, applied = env.step_array(action)
        assert np.allclose(applied, expected, atol=1e-4)  # float32 actor
    assert moved


def test_a_command_history_needs_a_classical_base():
    with pytest.raises(InputError, match="classical base"):
        TrainConfig(command_history=2).check()
    with pytest.raises(InputError, match="classical base"):
        PlatoonEnv([braking_event()], 3, NET, command_history=2)
