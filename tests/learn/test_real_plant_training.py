"""Training on the real plant: randomised fleets per episode, validation on the real plant, and
the communication ablation (CA-off: the CA messages cut, in training, validation and at run
time)."""

from __future__ import annotations

import numpy as np
import pytest

from carl_sumo.control.channel import Impairments
from carl_sumo.errors import InputError
from carl_sumo.learn.agents import AgentConfig
from carl_sumo.learn.policy import load_controller, load_policy
from carl_sumo.learn.randomize import (RANDOM_DEAD_STEPS, RANDOM_DELAY_STEPS, RANDOM_LAG_S,
                                       RANDOM_LOSS, RANDOM_TRUCK_SHARE,
                                       random_plant_impairments)
from carl_sumo.learn.train import TrainConfig, train
from carl_sumo.learn.train_config import validation_conditions
from carl_sumo.sim.vehicle import REAL_PLANT

from conftest import NET, braking_event


def test_random_plants_stay_in_their_ranges_and_vary():
    rng = np.random.default_rng(0)
    draws = [random_plant_impairments(rng) for _ in range(200)]
    for imp in draws:
        assert RANDOM_LOSS[0] <= imp.loss <= RANDOM_LOSS[1]
        assert RANDOM_DELAY_STEPS[0] <= imp.delay_steps <= RANDOM_DELAY_STEPS[1]
        trucks = dict(imp.plant.fleet).get("truck", 0.0)
        assert RANDOM_TRUCK_SHARE[0] <= trucks <= RANDOM_TRUCK_SHARE[1]
        if imp.plant.lag_s is not None:
            assert RANDOM_LAG_S[0] <= imp.plant.lag_s <= RANDOM_LAG_S[1]
            assert imp.plant.dead_time_s <= RANDOM_DEAD_STEPS[1] * 0.1 + 1e-9
    assert len({imp.delay_s for imp in draws}) == RANDOM_DELAY_STEPS[1] + 1
    assert any(imp.plant.lag_s is None for imp in draws)
    assert any(imp.plant.lag_s is not None for imp in draws)


def test_a_randomised_run_validates_on_the_real_plant():
    (condition,) = validation_conditions(TrainConfig(plant_randomize=True))
    assert condition.plant == REAL_PLANT and condition.delay_s == 0.1


def test_comm_off_is_for_ca_models():
    with pytest.raises(InputError):
        AgentConfig(algo="td3", comm_off=True)
    assert AgentConfig(comm_off=True).message_impairments(None).loss == 1.0
    assert AgentConfig().message_impairments(None) is None


def _tiny(tmp_path, name: str, **options) -> str:
    out = tmp_path / f"{name}.pt"
    cfg = TrainConfig(algo="ca-td3", n_vehicles=3, steps=60, seed=0, num_envs=1,
                      learning_starts=20, eval_every=60, eval_events=1, checkpoint_every=60,
                      net=str(NET), out=str(out), **options)
    train(cfg, [braking_event(), braking_event(event_id="brake2", v0=14.0)], progress=False)
    return str(out)


def test_a_comm_off_policy_hears_nothing_at_run_time(tmp_path):
    path = _tiny(tmp_path, "off", comm_off=True, plant_randomize=True)
    agent, meta = load_policy(path)
    assert agent.cfg.comm_off and meta["algo"] == "ca-td3"
    off = load_controller(path)
    off.reset(4)
    obs = np.array([[20.0, 0.3, 30.0, 0.5], [20.0, -0.2, 25.0, -0.4], [19.0, 0.0, 35.0, 1.0],
                    [21.0, 0.1, 20.0, -1.0]])
    # the same actor with every message lost on its links acts the same
    lost = load_controller(path)
    lost.agent = agent
    lost.reset(4)
    lost.connect(Impairments(loss=1.0), "x")
    assert np.array_equal(off.adjustment(obs), lost.adjustment(obs))
    heard = off._actor(obs)  # the same actor hearing its neighbours: another action
    assert not np.allclose(heard, lost.adjustment(obs))
