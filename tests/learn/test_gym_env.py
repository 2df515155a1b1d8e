"""The single-agent Gymnasium environment passes Gymnasium's own checker, is registered, and is
deterministic for a seed."""

from __future__ import annotations

import gymnasium
import numpy as np
from gymnasium.utils.env_checker import check_env

import pytest

import carl_sumo  # registers carl_sumo/Platoon-v0
from carl_sumo.errors import InputError
from carl_sumo.learn.gym_env import PlatoonGymEnv

ENV_ID = carl_sumo.ENV_ID

from conftest import NET, braking_event


def test_the_platoon_as_one_agent_passes_gymnasiums_checker():
    env = PlatoonGymEnv(3, events=[braking_event()], net_path=NET)
    check_env(env, skip_render_check=True)
    assert env.observation_space.shape == (12,) and env.action_space.shape == (3,)
    env.close()


def test_it_is_registered_and_runs_an_episode():
    env = gymnasium.make(ENV_ID, events=[braking_event()], net_path=NET)
    obs, info = env.reset(seed=3)
    again, _ = env.reset(seed=3)
    assert np.array_equal(obs, again) and info["event_id"] == "brake"
    total, done = 0.0, False
    while not done:
        obs, reward, terminated, truncated, _ = env.step(np.zeros(1, dtype=np.float32))
        total += reward
        done = terminated or truncated
    assert truncated and not terminated and np.isfinite(total)
    env.close()


def test_the_api_contract_is_one_clear_error_each():
    with pytest.raises(InputError, match="n_followers must be"):
        gymnasium.make(ENV_ID, n_followers=0, events=[braking_event()], net_path=NET)
    env = gymnasium.make(ENV_ID, events=[braking_event()], net_path=NET)
    with pytest.raises(gymnasium.error.ResetNeeded):  # gymnasium's own order check
        env.step(np.zeros(1, dtype=np.float32))
    with pytest.raises(InputError, match="call reset"):
        env.unwrapped.step(np.zeros(1, dtype=np.float32))
    with pytest.raises(InputError, match="unknown event_id 'nope'"):
        env.reset(seed=0, options={"event_id": "nope"})
    env.reset(seed=0)
    for bad in (np.array([np.nan], dtype=np.float32), np.zeros(2, dtype=np.float32)):
        with pytest.raises(InputError, match="finite number"):
            env.step(bad)
    with pytest.raises(InputError, match="another carl_sumo/Platoon-v0 environment is open"):
        gymnasium.make(ENV_ID, events=[braking_event()], net_path=NET)
    done = False
    while not done:
        _, _, terminated, truncated, _ = env.step(np.zeros(1, dtype=np.float32))
        done = terminated or truncated
    with pytest.raises(InputError, match="after the episode ended"):
        env.step(np.zeros(1, dtype=np.float32))
    env.close()
    with pytest.raises(InputError, match="after close"):
        env.reset(seed=0)
    second = gymnasium.make(ENV_ID, events=[braking_event()], net_path=NET)  # the first is closed
    second.reset(seed=1)
    second.close()
