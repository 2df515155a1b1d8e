"""Warm start by imitation and the a_ahead observation: the teacher is Ploeg's law, a cloned
actor reproduces it, and a policy that observes the acceleration ahead sees the same numbers in
training and in simulation."""

import numpy as np
import pytest
import torch

from carl_sumo.learn.agents import Agent, AgentConfig
from carl_sumo.experiments.bench import cruise_event
from carl_sumo.control.cacc import ploeg_controller
from carl_sumo.control.controllers import AheadAcceleration, adjustment_bounds, applied_acceleration, \
    idm_acceleration
from carl_sumo.learn.env import PlatoonEnv
from carl_sumo.errors import InputError
from carl_sumo.learn.imitation import TwoAhead, check_teacher_base, predecessor_adjustment, \
    target_adjustment, teacher, teacher_acceleration, teacher_adjustment
from carl_sumo.learn.policy import load_controller, load_policy
from carl_sumo.learn.train import TrainConfig, train

from conftest import NET, braking_event

TEACHER = "ploeg:h=1.1:kp=2.278:kd=10.6313"


def test_the_teacher_label_is_ploegs_law_on_a_platoon_that_follows_it():
    """Run the stateful Ploeg CACC; at every step the label read from the observations (the
    applied accelerations as states, a_ahead for the head) is what the controller applies."""
    env = PlatoonEnv([braking_event(v0=12.0)], 4, NET, base=TEACHER)
    law, ahead, label = ploeg_controller(TEACHER), AheadAcceleration(), teacher(TEACHER)
    obs = env.reset_array()
    done, k = False, 0
    while not done:
        seen = np.column_stack([obs[:, :4], ahead(obs)])
        expected = teacher_acceleration(label, seen, with_ahead=True)
        obs, _, term, trunc, accel = env.step_array(np.zeros(4))
        if k >= 10:  # after the start, where the controller's state may sit beyond the bounds
            np.testing.assert_allclose(expected, accel, atol=1e-9)
        done, k = term or trunc, k + 1
    assert k > 50


def test_the_head_hears_nothing_without_a_ahead_and_targets_respect_the_bound():
    ploeg = teacher(TEACHER)
    obs = np.array([[8.0, 0.0, 2 + 1.1 * 8, 0.0, 1.0], [8.0, 1.0, 2 + 1.1 * 8, 0.0, 0.0]])
    with_lead = teacher_acceleration(ploeg, obs, with_ahead=True)
    without = teacher_acceleration(ploeg, obs[:, :4])
    assert with_lead[0] == pytest.approx(0.1 / 1.1 * 1.0)  # dt/h · a_lead at equilibrium
    assert without[0] == pytest.approx(0.0)
    assert with_lead[1] == without[1]  # behind the head: the predecessor's a, either way
    target = teacher_adjustment(ploeg, obs[:, :4], 1.0)
    a_idm = idm_acceleration(obs[:, 0], obs[:, 2], obs[:, 3])
    assert np.all(np.abs(target) <= 0.95 + 1e-12) and np.all(without - a_idm > 0.95)
    with pytest.raises(InputError, match="Ploeg"):
        teacher("idm")


def test_behaviour_cloning_fits_the_teachers_targets():
    rng = np.random.default_rng(0)
    obs = np.column_stack([rng.uniform(5, 15, 4000), rng.uniform(-1, 1, 4000),
                           rng.uniform(8, 30, 4000), rng.uniform(-2, 2, 4000),
                           rng.uniform(-1, 1, 4000)]).reshape(1000, 4, 5)
    target = teacher_adjustment(teacher(TEACHER), obs, 3.0, with_ahead=True)
    torch.manual_seed(0)
    agent = Agent(AgentConfig(algo="ca-td3", n_vehicles=4, observe_ahead=True))
    x, y = torch.as_tensor(obs, dtype=torch.float32), torch.as_tensor(target, dtype=torch.float32)
    mse = agent.imitate(x, y, 1500, 1e-3, 128, rng)
    assert mse < 0.05 * float(y.var())  # the CA actor passes a_{i-1} along the platoon
    acted = agent.act(obs[:50])
    assert np.abs(acted - target[:50]).mean() < 0.2
    for a, b in zip(agent.actor.parameters(), agent.actor_target.parameters()):
        assert torch.equal(a, b)


def test_a_ahead_is_the_leaders_then_the_predecessors_acceleration():
    env = PlatoonEnv([braking_event(v0=12.0)], 3, NET, observe_ahead=True)
    obs = env.reset_array()
    assert obs.shape == (3, 5) and np.all(obs[:, 4] == 0.0)
    leader_before = env.sim.leader_speed
    obs, *_ = env.step_array(np.array([0.5, -0.2, 0.1]))
    assert obs[0, 4] == pytest.approx((env.sim.leader_speed - leader_before) / 0.1, abs=1e-6)
    np.testing.assert_allclose(obs[1:, 4], obs[:-1, 1])
    with pytest.raises(InputError, match="IDM base"):
        PlatoonEnv([braking_event()], 3, NET, base="ploeg:h=1", observe_ahead=True)
    with pytest.raises(InputError, match="IDM base"):
        AgentConfig(base="ploeg:h=1", observe_ahead=True)


def test_an_imitating_run_keeps_the_cloned_actor_and_simulates_as_it_validated(tmp_path):
    """--imitate --observe-ahead --adj-max 6 end to end: the run keeps a policy, whose file
    knows its observation and bound, and which `simulate`'s controller applies with the same
    a_ahead and the same bound as training did."""
    events = [cruise_event(150, 12.0, 20.0)]
    cfg = TrainConfig(algo="ca-td3", n_vehicles=3, steps=200, seed=0, num_envs=2,
                      learning_starts=120, critic_burn_in=40, eval_every=200, eval_events=1,
                      checkpoint_every=200, net=str(NET), adj_max=6.0, noise=0.02,
                      observe_ahead=True, imitate=TEACHER, imitate_updates=300,
                      out=str(tmp_path / "im.pt"))
    train(cfg, events, progress=False, log=lambda *_: None)
    agent, meta = load_policy(tmp_path / "im.pt")
    assert agent.cfg.observe_ahead and agent.cfg.adj_max == 6.0
    assert meta["observation"].endswith("a_ahead m/s^2]")
    controller = load_controller(tmp_path / "im.pt")
    assert controller.bounds == adjustment_bounds(6.0)
    env = PlatoonEnv(events, 3, NET, bounds=adjustment_bounds(6.0), observe_ahead=True)
    obs = env.reset_array(event=events[0])
    controller.reset(3)
    for _ in range(40):
        expected = applied_acceleration(controller, obs[:, :4])
        obs, _, _, _, accel = env.step_array(agent.act(obs))
        np.testing.assert_allclose(accel, expected, atol=1e-5)


@pytest.mark.parametrize("base, imitate", [
    ("ploeg:h=0.8", TEACHER),                               # a CACC base: nothing to add
    ("acc:h=0.8:kp=0.1:kd=1", "ploeg:h=0.8:kp=0.2:kd=1"),   # other gains than the ACC's
    ("acc:h=0.8:kp=0.1:kd=1", "acc:h=0.8:kp=0.1:kd=1"),     # the ACC itself
])
def test_imitate_is_refused_where_the_teacher_is_not_base_plus_adjustment(tmp_path, base, imitate):
    cfg = TrainConfig(algo="ca-td3", base=base, imitate=imitate, net=str(NET),
                      out=str(tmp_path / "x.pt"))
    with pytest.raises(InputError, match="--imitate"):
        train(cfg, [cruise_event(100)], progress=False)
    assert not (tmp_path / "x.pt").exists()


def test_on_an_acc_base_the_predecessors_acceleration_makes_it_the_cacc_with_its_gains():
    """The ACC (radar only) driven with a_adj,i = a_{i-1} (the target of --imitate on an ACC base)
    applies what the CACC with the same gains applies, where the CACC hears its predecessor's
    applied acceleration: the two runs stay identical step by step."""
    acc, cacc = "acc:h=0.8:kp=0.1:kd=1", "ploeg:h=0.8:kp=0.1:kd=1"
    check_teacher_base(cacc, acc)  # accepted
    env = PlatoonEnv([braking_event(v0=12.0)], 4, NET, base=acc)
    law = ploeg_controller(cacc)
    law.reset(4)
    obs = env.reset_array()
    done, k = False, 0
    while not done:
        target = predecessor_adjustment(obs, adj_max=3.0)
        held = np.concatenate([[0.0], np.clip(obs[:-1, 1], -2.85, 2.85)])
        assert np.array_equal(target, held)
        expected = law.step(np.ascontiguousarray(obs[:, :4]), law.u, 0.0, None,
                            np.ones(4, dtype=np.int64), held)  # hears a_{i-1} as its message
        obs, _, term, trunc, accel = env.step_array(target)
        np.testing.assert_allclose(accel, expected, atol=1e-9)
        done, k = term or trunc, k + 1
    assert k > 50


def test_on_an_acc_base_the_command_target_feeds_forward_the_predecessors_a_base():
    """--imitate-target command: the target of follower i is o_{i-1}'s fifth column (its base's
    command), not its realised acceleration; the head gets 0; both clipped alike."""
    rng = np.random.default_rng(0)
    obs = rng.normal(size=(3, 4, 5))
    obs[1, 2, 4] = 9.0  # beyond the bound: clipped
    command = predecessor_adjustment(obs, adj_max=2.0, target="command")
    realised = predecessor_adjustment(obs, adj_max=2.0)
    bound = 0.95 * 2.0
    assert np.array_equal(command[..., 0], np.zeros(3))
    np.testing.assert_array_equal(command[..., 1:], np.clip(obs[..., :-1, 4], -bound, bound))
    np.testing.assert_array_equal(realised[..., 1:], np.clip(obs[..., :-1, 1], -bound, bound))
    assert command[1, 3] == bound


def test_an_unknown_imitation_target_is_refused():
    with pytest.raises(InputError, match="imitation target 'comand'"):
        predecessor_adjustment(np.zeros((1, 3, 5)), adj_max=2.0, target="comand")


def test_the_two_ahead_target_feeds_forward_the_command_two_ahead_less_the_predecessors():
    """--imitate two-ahead:c=C: follower i's target is C·(a_base,i-2 - a_base,i-1) from o's fifth
    column, 0 for the first two followers, clipped to 0.95·adj_max; numbers by hand."""
    two = teacher("two-ahead:c=0.5")
    assert two == TwoAhead(0.5)
    check_teacher_base("two-ahead:c=0.5", "ploeg:h=0.6:kp=0.0445:kd=1:wo=5")  # accepted
    obs = np.zeros((2, 4, 5))
    obs[0, :, 4] = [1.0, 0.4, -0.2, 0.1]
    obs[1, :, 4] = [0.0, 3.0, -3.0, 0.0]
    target = target_adjustment(two, obs, adj_max=1.0, base="ploeg:h=0.6")
    np.testing.assert_allclose(target[0], [0.0, 0.0, 0.5 * (1.0 - 0.4), 0.5 * (0.4 + 0.2)])
    np.testing.assert_allclose(target[1], [0.0, 0.0, -0.95, 0.95])  # -0.5·3 and 0.5·6: clipped


def test_a_two_ahead_run_copies_the_target_with_its_messages(tmp_path):
    """--imitate two-ahead on a CACC base end to end: the cloned CA actor's a_adj follows the
    target (which needs the command two vehicles ahead) on a braking platoon."""
    from carl_sumo.learn.policy import load_controller

    base = "ploeg:h=0.8:kp=0.2:kd=1"
    cfg = TrainConfig(algo="ca-td3", base=base, imitate="two-ahead:c=0.5", imitate_updates=800,
                      n_vehicles=4, steps=300, learning_starts=250, eval_every=300, eval_events=1,
                      adj_max=1.0, net=str(NET), out=str(tmp_path / "two.pt"))
    train(cfg, [braking_event(v0=12.0, n=150), braking_event(v0=14.0, n=150, event_id="b2")],
          progress=False)
    agent, _ = load_policy(tmp_path / "two.pt")
    env = PlatoonEnv([braking_event(v0=13.0, n=150)], 4, NET, base=base,
                     bounds=adjustment_bounds(1.0))
    obs, errors, targets = env.reset_array(), [], []
    for _ in range(120):
        action = agent.act(obs)
        target = target_adjustment(TwoAhead(0.5), obs, 1.0)
        errors.append(action - target), targets.append(target)
        obs = env.step_array(action)[0]
    errors, targets = np.array(errors), np.array(targets)
    assert np.abs(targets[:, 2:]).max() > 0.05  # there is something to copy
    assert np.sqrt(np.mean(errors ** 2)) < 0.5 * np.sqrt(np.mean(targets ** 2))
