"""The safety constraint of training (RCPO): the close-call cost, its multiplier, and a real
training run in SUMO that stores the cost and moves the multiplier by it."""

from dataclasses import replace

import numpy as np
import pandas as pd
import pytest
import torch

from carl_sumo.config import REWARD
from carl_sumo.data.events import Event
from carl_sumo.learn.constraint import LAGRANGE_MAX, CostMultiplier
from carl_sumo.learn.reward import critical_cost, platoon_reward
from carl_sumo.learn.train import TrainConfig, train

from conftest import NET


def test_the_cost_is_the_critical_terms_samples_and_collisions():
    # closing at 10 m/s: TTC 1.4 s (a close call), 1.5 s and 2 s (not); opening: not; a collision
    obs = np.array([[20.0, 0.0, 14.0, -10.0], [20.0, 0.0, 15.0, -10.0], [20.0, 0.0, 20.0, -10.0],
                    [20.0, 0.0, 5.0, 1.0], [20.0, 0.0, -0.1, -10.0]])
    assert critical_cost(obs).tolist() == [1.0, 0.0, 0.0, 0.0, 1.0]
    rng = np.random.default_rng(0)
    obs = np.column_stack([rng.uniform(0, 30, 500), rng.uniform(-3, 3, 500),
                           rng.uniform(0.01, 40, 500), rng.uniform(-15, 15, 500)])
    plain, _ = platoon_reward(obs, obs[:, 1].copy())
    priced, _ = platoon_reward(obs, obs[:, 1].copy(), replace(REWARD, w_critical=1.0))
    assert 20 < critical_cost(obs).sum() < 480
    assert np.allclose(plain - priced, critical_cost(obs))  # no collision among them


def test_the_multiplier_measures_the_base_then_rises_and_falls_by_dual_ascent():
    lagrange = CostMultiplier(lr=2.0, learning_starts=2)
    lagrange.observe(0, np.array([[1.0, 0.0], [0.0, 0.0]]))
    lagrange.observe(1, np.zeros((2, 2)))
    assert lagrange.target == pytest.approx(1 / 8) and lagrange.value == 0.0
    lagrange.observe(2, np.array([[1.0, 1.0], [0.0, 0.0]]))  # c̄ = 0.5
    assert lagrange.value == pytest.approx(2.0 * (0.5 - 1 / 8))
    lagrange.observe(3, np.zeros((2, 2)))
    assert lagrange.value == pytest.approx(0.75 - 0.25)
    for step in range(4, 8):
        lagrange.observe(step, np.zeros((2, 2)))
    assert lagrange.value == 0.0  # not below 0
    for step in range(8, 40):
        lagrange.observe(step, np.ones((2, 2)))
    assert lagrange.value == LAGRANGE_MAX
    batch = {"reward": torch.tensor([[1.0, 1.0]]), "cost": torch.tensor([[0.0, 1.0]])}
    assert lagrange.penalise(batch)["reward"].tolist() == [[1.0, 1.0 - LAGRANGE_MAX]]
    again = CostMultiplier(2.0, 2, lagrange.state())
    assert again.state() == lagrange.state()
    off = CostMultiplier(0.0, 2)
    off.observe(5, np.ones(4))
    assert not off.active and off.value == 0.0


def test_a_constrained_run_stores_its_close_calls_and_prices_them(tmp_path):
    """Followers start 8 m behind a leader they close in on at 8 m/s (TTC 1 s): every short
    episode starts with close calls. The buffer holds each step's cost beside its reward, α is
    the cost rate before learning starts, and λ is the dual ascent over the costs after it."""
    v = np.full(30, 10.0)
    event = Event("closing", "test", "test", np.arange(30) * 1.0, v, 5.0, v + 8.0,
                  np.full(30, 8.0))
    cfg = TrainConfig(algo="td3", n_vehicles=2, steps=120, seed=0, num_envs=2,
                      learning_starts=40, eval_every=120, eval_events=1, checkpoint_every=120,
                      lagrange_lr=5.0, net=str(NET), out=str(tmp_path / "p.pt"))
    train(cfg, [event], progress=False)
    state = torch.load(tmp_path / "p.ckpt", weights_only=True)
    cost = state["buffer"]["cost"].numpy().reshape(120, 2, 2)  # (step, env, vehicle)
    assert cost.sum() > 0
    value, target, _, count = state["rollouts"]["lagrange"].tolist()
    assert count == 40 * 4 and target == pytest.approx(cost[:40].mean())
    expected = 0.0
    for step_cost in cost[40:]:
        expected = min(max(expected + 5.0 * (step_cost.mean() - target), 0.0), LAGRANGE_MAX)
    assert value == pytest.approx(expected) and value > 0
    curve = pd.read_csv(tmp_path / "p.csv")
    assert curve["lagrange"].iloc[-1] == pytest.approx(value, abs=1e-4)
