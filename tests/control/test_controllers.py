import math

import numpy as np

from carl_sumo.config import BOUNDS, IDM
from carl_sumo.control.controllers import ZeroAdjustment, idm_acceleration, total_acceleration

from conftest import NET, braking_event


def test_idm_hand_computed():
    # v = 10, d = 20, Δv = -2 (closing): s* = 2 + 10*1.5 + 10*2/(2*sqrt(6)) = 21.0825
    s_star = 2.0 + 15.0 + 20.0 / (2.0 * math.sqrt(6.0))
    expected = 3.0 * (1.0 - (10.0 / (120 / 3.6)) ** 4 - (s_star / 20.0) ** 2)
    assert math.isclose(float(idm_acceleration(10.0, 20.0, -2.0)), expected, rel_tol=1e-12)
    # free road at v0: no acceleration
    assert abs(float(idm_acceleration(IDM.desired_speed_mps, 1e9, 0.0))) < 1e-9
    # standstill at the jam distance s0: a = -a_max·(s0/s0)² + a_max = 0
    assert abs(float(idm_acceleration(0.0, IDM.min_gap_m, 0.0))) < 1e-12


def test_total_acceleration_clips_adjustment_and_total():
    obs = np.array([[10.0, 0.0, 30.0, 0.0], [10.0, 0.0, 0.5, -5.0], [0.0, 0.0, 100.0, 0.0]])
    a = total_acceleration(obs, np.array([10.0, 0.0, 10.0]))
    base = idm_acceleration(obs[:, 0], obs[:, 2], obs[:, 3])
    assert math.isclose(a[0], min(base[0] + BOUNDS.adj_max_mps2, BOUNDS.acc_max_mps2))
    assert a[1] == BOUNDS.acc_min_mps2  # hard braking is bounded below
    assert a[2] == BOUNDS.acc_max_mps2


def test_zero_adjustment_is_plain_idm():
    c = ZeroAdjustment()
    c.reset(3)
    obs = np.array([[10.0, 0.0, 30.0, 1.0]] * 3)
    assert np.array_equal(total_acceleration(obs, c.adjustment(obs)),
                          np.clip(idm_acceleration(obs[:, 0], obs[:, 2], obs[:, 3]), -9, 3))


def test_the_safety_shield_stops_positive_adjustments_only_when_closing_in_fast():
    from carl_sumo.control.controllers import shield_adjustment

    # rows [v, a, d, Δv]: closing at 5 m/s with 10 m (TTC 2 s), closing with TTC 8 s, opening
    obs = np.array([[20.0, 0.0, 10.0, -5.0], [20.0, 0.0, 40.0, -5.0], [20.0, 0.0, 5.0, 1.0]])
    adj = np.array([0.8, 0.8, 0.8])
    np.testing.assert_array_equal(shield_adjustment(obs, adj, 4.0), [0.0, 0.8, 0.8])
    np.testing.assert_array_equal(shield_adjustment(obs, -adj, 4.0), -adj)  # braking stays
    np.testing.assert_array_equal(shield_adjustment(obs, adj, 0.0), adj)  # 0: off
    np.testing.assert_array_equal(shield_adjustment(obs, adj, 1.5), adj)


def test_a_shielded_policy_is_shielded_in_training_and_in_simulation(tmp_path):
    from carl_sumo.learn.agents import Agent, AgentConfig
    from carl_sumo.control.controllers import applied_acceleration
    from carl_sumo.learn.env import PlatoonEnv
    from carl_sumo.learn.policy import load_controller, save_policy

    import torch

    agent = Agent(AgentConfig(algo="ca-td3", n_vehicles=3, shield_ttc_s=6.0))
    last = [m for m in agent.actor.modules() if isinstance(m, torch.nn.Linear)][-1]
    with torch.no_grad():  # a policy that always pushes forward: a_adj = 3·tanh(0.5)
        last.weight[-1:].zero_()
        last.bias[-1:].fill_(0.5)
    save_policy(agent, tmp_path / "s.pt", {})
    controller = load_controller(tmp_path / "s.pt")
    event = braking_event(v0=12.0)  # the leader brakes: the push closes in on it
    env = PlatoonEnv([event], 3, NET, shield_ttc_s=6.0)
    obs = env.reset_array(event=event)
    controller.reset(3)
    closing = np.array([[15.0, 0.0, 8.0, -4.0]] * 3)  # TTC 2 s: a push forward is refused
    assert np.all(controller.adjustment(closing) <= 0.0)
    assert np.any(agent.act(closing) > 0.0)  # what the actor alone would do
    shielded = 0
    for _ in range(150):
        expected = applied_acceleration(controller, obs)
        shielded += int(np.sum((-obs[:, 3] > 0) & (obs[:, 2] < 6.0 * -obs[:, 3])))
        obs, _, _, _, accel = env.step_array(agent.act(obs))
        np.testing.assert_allclose(accel, expected, atol=1e-5)
    assert shielded > 0
