"""Impairments in training (carl_sumo.learn.randomize): the channel-aware actor pass, the per-episode
draws, the replay buffer's link fields, noisy sensors in the environment, and short
``--comm-randomize`` and fixed-impairment runs."""

from dataclasses import replace

import numpy as np
import pytest
import torch

from carl_sumo.learn.agents import Agent, AgentConfig, normalise
from carl_sumo.experiments.bench import cruise_event
from carl_sumo.control.channel import FALLBACK, HELD, LIVE, PERFECT_SHARE, Impairments, random_impairments
from carl_sumo.learn.env import PlatoonEnv
from carl_sumo.learn.inference import CompiledActor, _communication_aware_act_channel
from carl_sumo.learn.policy import load_policy
from carl_sumo.learn.randomize import RandomisedChannels
from carl_sumo.learn.replay_buffer import ReplayBuffer
from carl_sumo.learn.reward import platoon_reward
from carl_sumo.learn.train import TrainConfig, train

from conftest import NET, braking_event


def _links(rng, batch, n, m=16):
    return (torch.from_numpy(rng.integers(0, 3, (batch, n))),
            torch.from_numpy(rng.normal(0, 0.5, (batch, n, m))).float(),
            torch.from_numpy(rng.integers(0, 3, (batch, n))),
            torch.from_numpy(rng.normal(0, 0.5, (batch, n, m))).float())


def test_the_channel_aware_pass_is_the_fused_pass_when_every_message_is_live():
    torch.manual_seed(0)
    net = Agent(AgentConfig(algo="ca-td3", n_vehicles=6)).actor
    x = torch.randn(7, 6, 4)
    live = (torch.zeros(7, 6, dtype=torch.long), torch.randn(7, 6, 16),
            torch.zeros(7, 6, dtype=torch.long), torch.randn(7, 6, 16))
    assert torch.allclose(net(x), net.forward_over(x, live)[0], atol=1e-5)


def test_the_channel_aware_pass_matches_the_compiled_actor_on_impaired_links():
    torch.manual_seed(1)
    agent = Agent(AgentConfig(algo="ca-td3", n_vehicles=8))
    rng = np.random.default_rng(2)
    obs = np.column_stack([rng.uniform(5, 15, 8), rng.normal(0, 1, 8), rng.uniform(5, 40, 8),
                           rng.normal(0, 1, 8)])
    links = list(_links(rng, 1, 8))
    links[0] = torch.tensor([[LIVE, HELD, FALLBACK, LIVE, HELD, FALLBACK, LIVE, LIVE]])
    links[2] = torch.tensor([[LIVE, FALLBACK, HELD, LIVE, LIVE, HELD, FALLBACK, HELD]])
    expected = _communication_aware_act_channel(
        obs, agent.cfg.adj_max, links[0][0].numpy(), links[1][0].double().numpy(),
        links[2][0].numpy(), links[3][0].double().numpy(), *CompiledActor(agent)._weights)
    action, sent_f, sent_b = agent.act_over(obs[None], [t.numpy() for t in links], None)
    for got, want in zip((action[0], sent_f[0], sent_b[0]), expected):
        np.testing.assert_allclose(got, want, atol=1e-5)
    # an impaired link changes the action, so the actor's inputs really are the received ones
    assert not np.allclose(action[0], agent.act(obs), atol=1e-4)


def test_gradients_flow_through_live_links_only():
    torch.manual_seed(3)
    net = Agent(AgentConfig(algo="ca-td3", n_vehicles=3)).actor
    x = torch.randn(1, 3, 4, requires_grad=True)
    held = torch.zeros(1, 3, 16)
    cut = torch.full((1, 3), FALLBACK)  # nobody hears anybody: three independent vehicles
    net.forward_over(x, (cut, held, cut, held))[0][0, 0].sum().backward()
    assert x.grad[0, 0].abs().sum() > 0 and x.grad[0, 1:].abs().sum() == 0


def test_episode_draws_are_valid_reproducible_and_a_quarter_perfect():
    draws = [random_impairments(np.random.default_rng([5, k])) for k in range(2000)]
    again = [random_impairments(np.random.default_rng([5, k])) for k in range(2000)]
    assert draws == again
    perfect = np.mean([not d.active for d in draws])
    assert abs(perfect - PERFECT_SHARE) < 0.03
    assert {round(d.delay_s, 1) for d in draws} == {0.0, 0.1, 0.2, 0.3, 0.4, 0.5}
    impaired = [d for d in draws if d.active]
    assert 0.45 < np.mean([d.sensor_noise for d in impaired]) < 0.55
    assert 0.45 < np.mean([d.burst > 1 for d in impaired]) < 0.55
    assert max(d.loss for d in draws) > 0.95


def test_each_environment_gets_fresh_impairments_and_links_when_its_episode_ends():
    channels = RandomisedChannels(num_envs=2, n=4, message_dim=3, seed=0)
    first, upcoming = list(channels.current), list(channels.upcoming)
    modes, held = channels.receive()[0], channels.receive()[1]
    assert modes.shape == (2, 4) and held.shape == (2, 4, 3)
    channels.send(np.ones((2, 4, 3)), np.ones((2, 4, 3)))
    channels.episodes_ended(np.array([False, True]))
    assert channels.current[0] == first[0] and channels.current[1] == upcoming[1]
    assert channels.links[1].k == 0 and channels.links[0].k == 1


def test_channel_only_randomisation_draws_the_same_channels_with_clean_sensors():
    from dataclasses import replace

    from carl_sumo.learn.train import validation_conditions

    both = RandomisedChannels(num_envs=2, n=4, message_dim=3, seed=0)
    channel = RandomisedChannels(num_envs=2, n=4, message_dim=3, seed=0, sensor_noise=False)
    for _ in range(50):
        for a, b in zip(both.upcoming, channel.upcoming):
            assert replace(a, sensor_noise=False) == b and not b.sensor_noise
        both.episodes_ended(np.array([True, True]))
        channel.episodes_ended(np.array([True, True]))
    assert any(imp.sensor_noise for imp in both.current)
    noisy, clean = (validation_conditions(TrainConfig(comm_randomize=True, val_impaired=True,
                                                      randomize_sensors=r))[1]
                    for r in (True, False))
    assert noisy.sensor_noise and clean == replace(noisy, sensor_noise=False)


def test_the_replay_buffer_keeps_how_messages_arrived_and_restores_them():
    rng = np.random.default_rng(4)
    buf = ReplayBuffer(10, 3, 4, message_dim=2)
    for _ in range(4):  # wraps around once
        links = [t.numpy() for t in _links(rng, 3, 3, 2)]
        buf.add(rng.normal(size=(3, 3, 4)), rng.normal(size=(3, 3)), rng.normal(size=(3, 3)),
                rng.normal(size=(3, 3, 4)), np.zeros(3, np.float32), links, links)
    batch = buf.sample(5, np.random.default_rng(0))
    f_mode, f_held, b_mode, b_held = batch["links"]
    assert f_mode.dtype == torch.long and f_mode.shape == (5, 3) and b_held.shape == (5, 3, 2)
    restored = ReplayBuffer.from_state(buf.state())
    again = restored.sample(5, np.random.default_rng(0))
    for a, b in zip(batch["next_links"], again["next_links"]):
        assert torch.equal(a, b)


def test_noisy_sensors_change_what_the_env_sees_not_what_it_rewards():
    event = braking_event(n=80)
    clean, noisy = PlatoonEnv([event], 3, NET), PlatoonEnv([event], 3, NET)
    o_clean = clean.reset_array(seed=0)
    o_noisy = noisy.reset_array(seed=0, impairments=Impairments(sensor_noise=True, seed=1))
    assert np.allclose(o_clean[:, :2], o_noisy[:, :2])  # speed and acceleration are exact
    assert not np.allclose(o_clean[:, 2:], o_noisy[:, 2:])  # gap and relative speed are not
    seen, rewards, _, _, accel = noisy.step_array(np.zeros(3))
    true = noisy.sim.observation()
    on_true, _ = platoon_reward(true, accel, noisy.reward_cfg)  # first step: prev a = a
    on_seen, _ = platoon_reward(np.ascontiguousarray(seen[:, :4]), accel, noisy.reward_cfg)
    np.testing.assert_allclose(rewards, on_true)
    assert not np.allclose(rewards, on_seen)


@pytest.mark.parametrize("algo", ["ca-td3", "td3"])
def test_a_randomised_run_trains_on_impaired_messages(tmp_path, algo):
    events = [cruise_event(150, 15.0, 30.0)]
    cfg = TrainConfig(algo=algo, n_vehicles=3, steps=160, seed=0, num_envs=2,
                      learning_starts=60, eval_every=160, eval_events=1, checkpoint_every=160,
                      net=str(NET), smooth_jerk=0.05, comm_randomize=True, val_impaired=True,
                      out=str(tmp_path / "r.pt"))
    train(cfg, events, progress=False)
    agent, meta = load_policy(tmp_path / "r.pt")
    assert meta["comm_randomize"] is True and meta["val_impaired"] is True
    assert len(meta["validation_events"]) == 1  # one event, scored under two conditions
    state = torch.load(tmp_path / "r.ckpt", weights_only=False)["buffer"]
    if algo == "ca-td3":  # held and missing messages were met and stored
        assert {HELD, FALLBACK} <= set(state["link_mode"].unique().tolist())
    else:
        assert state["message_dim"] == 0


def test_a_run_under_fixed_impairments_trains_on_them_and_validates_under_them(tmp_path):
    from carl_sumo.learn.train import validation_conditions

    events = [cruise_event(150, 15.0, 30.0)]
    cfg = TrainConfig(algo="ca-td3", n_vehicles=3, steps=120, seed=0, num_envs=2,
                      learning_starts=60, eval_every=120, eval_events=1, checkpoint_every=120,
                      net=str(NET), comm_loss=1.0, impairment_seed=3, val_impaired=True,
                      out=str(tmp_path / "f.pt"))
    assert validation_conditions(cfg)[1] == Impairments(loss=1.0, seed=0)
    channels = RandomisedChannels(2, 3, 16, seed=0, fixed=cfg.fixed_impairments)
    assert all(replace(imp, seed=3) == cfg.fixed_impairments for imp in channels.current)
    assert channels.current[0].seed != channels.current[1].seed  # each episode its own draws
    train(cfg, events, progress=False)
    _, meta = load_policy(tmp_path / "f.pt")
    assert meta["impairments"]["loss"] == 1.0 and meta["comm_randomize"] is False
    state = torch.load(tmp_path / "f.ckpt", weights_only=False)["buffer"]
    assert set(state["link_mode"].unique().tolist()) == {FALLBACK}  # every message lost


def test_validation_under_impairments_scores_each_event_twice_on_the_true_state():
    from carl_sumo.learn.selection import VALIDATION_IMPAIRMENTS, BaseOnly, validate_events

    event = braking_event(n=80)
    env = PlatoonEnv([event], 3, NET)
    agent = Agent(AgentConfig(algo="ca-td3", n_vehicles=3))
    _, clean = validate_events(agent, env, [event])
    _, both = validate_events(agent, env, [event], (None, VALIDATION_IMPAIRMENTS))
    assert len(both) == 2 and both[0] == clean[0]
    assert both[1]["jerk_mps3"] > clean[0]["jerk_mps3"]  # noisy gaps: a rougher ride
    _, base = validate_events(BaseOnly(), env, [event], (None, VALIDATION_IMPAIRMENTS))
    assert len(base) == 2


def test_validation_helpers_give_the_numbers_of_one_process():
    """--val-workers: the runs dealt out to a helper process (its own SUMO) score exactly as in
    one process, on a randomised real fleet under impairments, for a CA actor and the base."""
    import dataclasses

    from carl_sumo.control.channel import plant_impairments
    from carl_sumo.learn.selection import (VALIDATION_IMPAIRMENTS, BaseOnly, Validation,
                                           ValidationHelper, validate_events)

    events = [dataclasses.replace(braking_event(n=60 + 10 * i), event_id=f"e{i}")
              for i in range(3)]
    base = "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4"
    agent = Agent(AgentConfig(algo="ca-td3", n_vehicles=3, base=base))
    torch.manual_seed(0)
    for p in agent.actor.parameters():  # a moving actor, not the zero residual
        p.data.normal_(0, 0.3)
    conditions = (plant_impairments("real"), dataclasses.replace(
        VALIDATION_IMPAIRMENTS, plant=plant_impairments("real").plant))
    env = PlatoonEnv(events, 3, NET, base=base)
    helped = Validation(PlatoonEnv(events, 3, NET, base=base),
                        [ValidationHelper(dict(events=events, n_followers=3, net_path=str(NET),
                                               base=base))])
    try:
        for who in (agent, BaseOnly()):
            alone = validate_events(who, env, events, conditions)
            assert helped.run(who, events, conditions) == alone and len(alone[1]) == 6
    finally:
        helped.close()
