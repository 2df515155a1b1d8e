import numpy as np
import pytest
from pettingzoo.test import parallel_api_test

from carl_sumo.config import ControlBounds
from carl_sumo.learn.env import PlatoonEnv
from carl_sumo.learn.reward import platoon_reward

from conftest import NET, braking_event


def test_pettingzoo_parallel_api():
    env = PlatoonEnv([braking_event()], n_followers=3, net_path=NET)
    parallel_api_test(env, num_cycles=60)


def test_any_platoon_length_and_episode_end():
    for n in (1, 7):
        env = PlatoonEnv([braking_event(n=60)], n_followers=n, net_path=NET)
        obs, infos = env.reset(seed=1)
        assert len(obs) == n and obs["cacc_0"].shape == (4,)
        steps = 0
        while env.agents:
            obs, rewards, terms, truncs, infos = env.step(
                {a: np.zeros(1, np.float32) for a in env.agents})
            steps += 1
        assert steps == 59 and all(truncs.values()) and not any(terms.values())


def test_collision_terminates_with_penalty():
    # an adjustment large enough to override IDM's braking drives the head into the leader
    env = PlatoonEnv([braking_event(gap=3.0)], n_followers=2, net_path=NET,
                     bounds=ControlBounds(adj_max_mps2=1e12))
    env.reset(seed=0)
    done = False
    for _ in range(100):
        obs, rewards, terms, truncs, _ = env.step({a: np.array([1e11], np.float32)
                                                  for a in env.agents})
        if any(terms.values()):
            done = True
            break
    assert done and min(rewards.values()) < -50.0 and env.agents == []


def test_adjustment_changes_the_applied_acceleration():
    env = PlatoonEnv([braking_event()], n_followers=2, net_path=NET)
    env.reset_array(seed=0)
    _, _, _, _, a_zero = env.step_array(np.zeros(2))
    env.reset_array(seed=0)
    _, _, _, _, a_adj = env.step_array(np.array([0.5, -0.5]))
    assert np.allclose(a_adj - a_zero, [0.5, -0.5])


def test_classical_base_at_zero_adjustment_is_that_controller():
    """base=ploeg with a_adj = 0 applies exactly the Ploeg CACC; a_adj enters its law, so the
    first step moves by dt/h·a_adj; the fifth observation column previews the base's command."""
    from carl_sumo.control.cacc import ploeg_controller

    env = PlatoonEnv([braking_event()], n_followers=3, net_path=NET, base="ploeg:h=0.8")
    reference = ploeg_controller("ploeg:h=0.8")
    obs = env.reset_array(seed=0)
    reference.reset(3)
    for _ in range(30):
        expected = reference.acceleration(obs)
        assert np.allclose(obs[:, 4], expected, atol=1e-12)
        obs, _, _, _, applied = env.step_array(np.zeros(3))
        assert np.allclose(applied, expected, atol=1e-12)
    env.reset_array(seed=0)
    _, _, _, _, a_zero = env.step_array(np.zeros(3))
    env.reset_array(seed=0)
    _, _, _, _, a_adj = env.step_array(np.array([0.2, -0.2, 0.1]))
    assert np.allclose(a_adj - a_zero, np.array([0.2, -0.2, 0.1]) * 0.1 / 0.8)


def test_a_held_gap_decision_is_one_step_of_its_seconds():
    """A base whose learned gap is held ``gh=S`` s makes one vector step S s of simulation (a
    semi-MDP): the reward is the mean of its 0.1 s steps, the cost their max, the same
    trajectory as the env stepped every 0.1 s with that term."""
    from carl_sumo.config import BOUNDS, REWARD
    from carl_sumo.learn.vec_env import EnvRunner

    base = "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4:gp=2:gl=0.5:gh=0.5"
    env = PlatoonEnv([braking_event()], n_followers=3, net_path=NET, base=base)
    env.reset_array(seed=0)
    term = np.array([0.4, -0.2, -0.2])
    rewards = [env.step_array(term)[1] for _ in range(5)]
    after = env._obs.copy()  # libsumo: one simulation per process, so the runner comes second
    runner = EnvRunner([braking_event()], 3, str(NET), 0, REWARD, base, False, BOUNDS, 0.0)
    assert runner.env.hold_steps == env.hold_steps == 5
    obs, reward, terminated, truncated, final, cost = runner.step((term, None))
    assert runner.env.sim.k == 5 and not (terminated or truncated)
    np.testing.assert_allclose(reward, np.mean(rewards, axis=0), atol=1e-12)
    np.testing.assert_allclose(obs, after, atol=1e-12)
    assert cost.shape == (3,)


def test_a_paired_decision_is_measured_against_the_base_on_its_own_episode():
    """``paired_base``: a decision held for the whole episode gets its mean reward less the
    base's (a_adj = 0) on the same event, run again from its start: 0 for the base itself; a
    base that would not hold a decision for the whole episode is refused before training."""
    from dataclasses import replace

    from carl_sumo.config import BOUNDS, REWARD
    from carl_sumo.errors import InputError
    from carl_sumo.learn.train_config import TrainConfig, held_out_split
    from carl_sumo.learn.vec_env import EnvRunner

    base = "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4:gp=2:gl=0.5:gh=1000"
    event, term = braking_event(), np.array([0.6, -0.1, -0.1])
    env = PlatoonEnv([event], n_followers=3, net_path=NET, base=base)
    means = []
    for action in (term, np.zeros(3)):
        env.reset_array(seed=0)
        rewards, done = [], False
        while not done:
            _, reward, terminated, truncated, _ = env.step_array(action)
            rewards.append(reward)
            done = terminated or truncated
        means.append(np.mean(rewards, axis=0))
    paired = replace(REWARD, paired_base=True)
    runner = EnvRunner([event], 3, str(NET), 0, paired, base, False, BOUNDS, 0.0)
    _, reward, _, truncated, _, _ = runner.step((term, None))
    assert truncated and runner.env.sim.k == 0  # one decision was the episode; the next began
    np.testing.assert_allclose(reward, means[0] - means[1], atol=1e-12)
    assert np.all(runner.step((np.zeros(3), None))[1] == 0.0)
    cfg = TrainConfig(base=base.replace("gh=1000", "gh=5"), paired_base=True, eval_events=1)
    with pytest.raises(InputError, match="gh of at least"):
        held_out_split([braking_event(event_id=f"e{i}") for i in range(3)], cfg)


def test_unknown_base_is_refused():
    import pytest

    from carl_sumo.errors import InputError

    with pytest.raises(InputError, match="unknown base model 'krauss'"):
        PlatoonEnv([braking_event()], n_followers=2, net_path=NET, base="krauss")


def test_the_env_runs_through_rllibs_pettingzoo_wrapper():
    """RLlib users plug the ParallelEnv in through Ray's wrapper: it builds, resets and steps,
    with the env's spaces per agent (skipped without the Ray extra)."""
    pytest.importorskip("ray")
    pytest.importorskip("tree")  # RLlib's own dependency (dm-tree), part of the extra
    from ray.rllib.env.multi_agent_env import MultiAgentEnv
    from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv

    from carl_sumo.data import load_events

    env = ParallelPettingZooEnv(PlatoonEnv(load_events("default", "train")[:2], 3, NET))
    assert isinstance(env, MultiAgentEnv)
    obs, _ = env.reset(seed=0)
    assert sorted(obs) == ["cacc_0", "cacc_1", "cacc_2"]
    assert all(env.observation_space[a].contains(o) for a, o in obs.items())
    for _ in range(20):
        actions = {a: np.full(1, -0.5, np.float32) for a in obs}  # all brake gently
        obs, rewards, terminated, truncated, _ = env.step(actions)
    assert set(rewards) == {"cacc_0", "cacc_1", "cacc_2"}
    assert terminated["__all__"] is False and truncated["__all__"] is False
    assert all(np.isfinite(r) for r in rewards.values())
    env.close()


def test_the_spacing_term_holds_each_truck_at_its_own_gap():
    from dataclasses import replace

    from carl_sumo.config import REWARD
    from carl_sumo.sim.vehicle import Plant

    cfg = replace(REWARD, w_spacing=1.0, spacing_gap_s=0.6, spacing_head_gap_s=1.4,
                  spacing_heavy_gap_s=0.8)
    env = PlatoonEnv([braking_event(n=40)], 4, NET, reward=cfg,
                     plant=Plant((("car", 0.5), ("truck", 0.5))))
    env.reset_array(seed=3)
    b_max = env.sim.powertrains.b_max
    assert (b_max[1:] < 7.0).any() and (b_max[1:] >= 7.0).any()  # trucks and cars behind the head
    _, rewards, _, _, accel = env.step_array(np.zeros(4))  # first step: prev a = a
    with_trucks, _ = platoon_reward(env.true_observation, accel, cfg, b_max)
    without, _ = platoon_reward(env.true_observation, accel, cfg)
    np.testing.assert_allclose(rewards, with_trucks)
    assert not np.allclose(rewards, without)
