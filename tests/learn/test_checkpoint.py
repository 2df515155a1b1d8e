"""Files written before the package layout (flat modules) still load: every shipped policy file,
and a training checkpoint written by the flat-layout code (``tests/fixtures``: a 40-step CA-TD3
run of 2 vehicles, message width 4, hidden width 8, made with the commit before the move)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import torch

from carl_sumo.learn.agents import Agent
from carl_sumo.learn.checkpoint import read_checkpoint, restore_checkpoint
from carl_sumo.learn.policy import load_policy
from carl_sumo.learn.train import export_policy
from carl_sumo.learn.train_config import TrainConfig

REPO = Path(__file__).resolve().parents[2]
OLD_CHECKPOINT = REPO / "tests" / "fixtures" / "ca_td3_pre_layout.ckpt"
SHIPPED = sorted((REPO / "policies").glob("*.pt")) + sorted((REPO / "policies" / "seeds").glob("*.pt"))


@pytest.mark.parametrize("path", SHIPPED, ids=lambda p: p.name)
def test_every_shipped_policy_file_loads_and_acts(path):
    agent, meta = load_policy(path)
    n = agent.cfg.n_vehicles if agent.cfg.algo == "maddpg" else 3
    obs = np.tile([[20.0, 0.0, 25.0, 0.0, 0.0][:agent.cfg.obs_dim]], (n, 1))
    assert np.all(np.isfinite(agent.act(obs)))
    assert meta["algo"] == agent.cfg.algo


def test_a_checkpoint_of_the_flat_layout_restores_and_exports(tmp_path):
    state = read_checkpoint(OLD_CHECKPOINT)
    assert state["step"] == 40
    cfg = TrainConfig(**state["train_config"])
    agent = Agent(cfg.agent_config())
    rng = np.random.default_rng(0)
    buffer, step, best, wall = restore_checkpoint(OLD_CHECKPOINT, cfg, agent, rng)
    assert step == 40 and buffer.size == 40 and agent.updates > 0
    assert torch.equal(agent.state_dict()["actor.forward_boundary"],
                       state["agent"]["actor.forward_boundary"])
    meta = export_policy(OLD_CHECKPOINT, tmp_path / "exported.pt")
    assert meta["exported_from"] == "ca_td3_pre_layout.ckpt at step 40"
    loaded, _ = load_policy(tmp_path / "exported.pt")
    obs = np.tile([[10.0, 0.0, 20.0, 0.0]], (2, 1))
    assert np.allclose(loaded.act(obs), agent.act(obs))
