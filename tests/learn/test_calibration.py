"""Issue 55's training regime: the critic's criterion on held-out transitions, the burn-in that
ends when it stops improving, the behaviour-regularised actor, and what a run records of them
(the first actor update, the step kept, the selection score per validation, where the wall time
went)."""

import math
import numpy as np
import pandas as pd
import pytest
import torch

from carl_sumo.errors import InputError
from carl_sumo.experiments.bench import cruise_event
from carl_sumo.learn.agents import Agent, AgentConfig
from carl_sumo.learn.calibration import (Calibration, horizon_steps, realised_returns,
                                         spearman, steps_needed)
from carl_sumo.learn.policy import load_policy, policy_card
from carl_sumo.learn.replay_buffer import ReplayBuffer
from carl_sumo.learn.train import TrainConfig, train

from conftest import NET


def test_realised_returns_stop_at_episode_ends_and_count_only_where_the_horizon_is_whole():
    gamma = 0.5  # horizon 4 steps
    reward = np.ones((10, 1))
    done = np.zeros(10, dtype=bool)
    done[3] = True  # a collision ends the first episode: its returns are exact
    ends = done.copy()
    ends[9] = True  # the data end cuts the second
    g, usable = realised_returns(reward, done, ends, gamma)
    assert horizon_steps(gamma) == 4
    np.testing.assert_allclose(g[:4, 0], [1.875, 1.75, 1.5, 1.0])
    np.testing.assert_allclose(g[9, 0], 1.0)
    assert usable.tolist() == [True] * 4 + [True, True, True, False, False, False]


def test_spearman_is_one_for_any_increasing_map_and_minus_one_reversed():
    x = np.array([0.3, -2.0, 5.0, 1.0, 0.0])
    assert spearman(x, np.exp(x)) == pytest.approx(1.0)
    assert spearman(x, -x ** 3) == pytest.approx(-1.0)
    assert math.isnan(spearman(x[:1], x[:1]))


def test_calibration_ends_after_patience_checks_without_improvement():
    cal = Calibration("rank", patience=2, actor_from=5_000)
    values = [0.2, 0.5, 0.502, 0.51, 0.509, 0.512]  # +0.002 is not an improvement, +0.008 is
    released = [cal.check(1_000 + 100 * i, {"critic_rank": v}) for i, v in enumerate(values)]
    assert released == [False] * 5 + [True] and cal.actor_from == 1_500
    td = Calibration("td", patience=1, actor_from=5_000)
    assert not td.check(100, {"critic_td": 1.0}) and not td.check(200, {"critic_td": 0.9})
    assert td.check(300, {"critic_td": 0.895}) and td.actor_from == 300  # under 1 % lower


def test_held_out_rows_are_never_drawn():
    buf = ReplayBuffer(100, 2, 5)
    for _ in range(5):  # 10 rows
        buf.add(np.zeros((2, 2, 5)), np.zeros((2, 2)), np.zeros((2, 2)), np.zeros((2, 2, 5)),
                np.zeros(2))
    buf.obs[:10, 0, 0] = torch.arange(10.0)
    buf.hold_out(np.array([2, 3, 7]))
    buf.add(np.full((2, 2, 5), 10.0), np.zeros((2, 2)), np.zeros((2, 2)), np.zeros((2, 2, 5)),
            np.zeros(2))
    drawn = buf.sample(4_000, np.random.default_rng(0))["obs"][:, 0, 0]
    assert set(drawn.long().tolist()) == {0, 1, 4, 5, 6, 8, 9, 10}


def _batch(n=3, size=32, seed=0):
    g = torch.Generator().manual_seed(seed)
    return {"obs": torch.rand(size, n, 5, generator=g) * 10,
            "next_obs": torch.rand(size, n, 5, generator=g) * 10,
            "action": torch.rand(size, n, generator=g) - 0.5,
            "reward": torch.rand(size, n, generator=g), "done": torch.zeros(size),
            "mask": torch.ones(size, n, dtype=torch.bool)}


def test_a_behaviour_regularised_actor_stays_nearer_its_start():
    """On a residual start (a_adj = 0) a small alpha holds the actor near 0, where the plain
    -Q objective moves it; alpha 0 is the plain objective exactly."""
    drift, threads = {}, torch.get_num_threads()
    torch.set_num_threads(1)  # tiny nets: threads only contend
    for alpha in (0.0, 0.05):
        torch.manual_seed(0)
        agent = Agent(AgentConfig(algo="ca-td3", n_vehicles=3, base="ploeg:h=0.8", hidden=16,
                                  message_dim=4, actor_lr=1e-2))
        agent.anchor(alpha)
        assert (agent.start_actor is None) == (alpha == 0)
        for i in range(20):
            agent.update(_batch(seed=i))
        with torch.no_grad():
            x = _batch(seed=99)["obs"]
            drift[alpha] = float(agent._act(agent.actor, x, None).abs().mean())
    torch.set_num_threads(threads)
    assert agent.actor_updates == 10  # every second update (policy delay 2)
    assert drift[0.05] < 0.5 * drift[0.0]


def test_a_calibrated_regularised_run_records_its_start_its_criterion_and_its_time(tmp_path):
    cfg = TrainConfig(algo="ca-td3", n_vehicles=3, steps=400, seed=0, num_envs=2,
                      base="ploeg:h=0.8", learning_starts=200, critic_burn_in=150,
                      critic_holdout=0.25, critic_calibration="td", calibration_every=20,
                      calibration_patience=2, bc_alpha=2.5, gamma=0.9, eval_every=100,
                      eval_events=1, checkpoint_every=400, net=str(NET),
                      out=str(tmp_path / "c.pt"), gate_string_stable="real").check()
    lines = []
    result = train(cfg, [cruise_event(150, 12.0, 20.0)], progress=False, log=lines.append)
    training = result["training"]
    checks = training["critic_calibration"]["checks"]
    assert checks and checks[0][0] == 220 and all(s < training["actor_from_step"] for s, _ in checks)
    assert training["actor_from_step"] <= 350
    assert training["actor_from_step"] < training["first_actor_update_step"] \
        <= training["actor_from_step"] + 3
    wall = training["wall_s"]
    assert wall["simulation"] > 0 and wall["validation"] > 0 and wall["updates"] > 0
    assert wall["total"] == pytest.approx(sum(v for k, v in wall.items() if k != "total"), abs=0.2)
    assert any(line.startswith("critic hold-out: ") for line in lines)
    assert lines[-1].startswith("wall time ") and "simulation" in lines[-1]
    curve = pd.read_csv(tmp_path / "c.csv")
    assert list(curve["step"]) == [100, 200, 300, 400]
    assert curve["score"].notna().all()
    assert curve["critic_td"].isna().tolist() == [True, True, False, False]  # from the hold-out
    assert curve["critic_rank"].between(-1, 1).sum() == 2
    _, meta = load_policy(tmp_path / "c.pt")
    assert meta["training"] == training and meta["step"] in (0, 100, 200, 300, 400)
    candidate = load_policy(tmp_path / "c.candidates" / "step000400.pt")[1]
    assert candidate["step"] == 400 and candidate["training"] == training
    card = policy_card(tmp_path / "c.pt")
    assert f"RL's first actor update at step {training['first_actor_update_step']}" in card
    assert f"step kept {meta['step']}" in card and "critic calibrated by td" in card


@pytest.mark.parametrize("options, message", [
    ("--critic-calibration rank --critic-burn-in 500", "--critic-calibration measures"),
    ("--critic-holdout 0.2 --learning-starts 100", "--learning-starts 250 or more"),
    ("--calibration-patience 5", "give it too"),
    ("--bc-alpha -1", "--bc-alpha must be"),
    ("--critic-calibration loss", "unknown --critic-calibration"),
])
def test_bad_regime_options_are_one_line_and_exit_status_2(capsys, tmp_path, options, message):
    from carl_sumo.cli import main

    code = main(["train", "--steps", "2000", "--out", str(tmp_path / "x.pt"), *options.split()])
    err = capsys.readouterr().err
    assert code == 2 and message in err, err
    assert len(err.strip().splitlines()) == 1 and not (tmp_path / "x.pt").exists()


def test_the_regime_is_off_by_default():
    cfg = TrainConfig()
    assert (cfg.critic_holdout, cfg.critic_calibration, cfg.bc_alpha) == (0.0, "off", 0.0)
    assert steps_needed(0.2, 0.98) == 3 * 50 + 100
    with pytest.raises(InputError, match="--critic-holdout"):
        TrainConfig(critic_holdout=0.2, learning_starts=200, steps=1_000).check()
