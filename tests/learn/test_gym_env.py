"""The single-agent Gymnasium environment passes Gymnasium's own checker, is registered, and is
deterministic for a seed."""

from __future__ import annotations

import gymnasium
import numpy as np
from gymnasium.utils.env_checker import check_env

import carl_sumo.learn.gym_env  # noqa: F401  (registers carl_sumo/Platoon-v0)
from carl_sumo.learn.gym_env import ENV_ID, PlatoonGymEnv

from conftest import NET, braking_event


def test_the_platoon_as_one_agent_passes_gymnasiums_checker():
    env = PlatoonGymEnv(3, events=[braking_event()], net_path=NET)
    check_env(env, skip_render_check=True)
    assert env.observation_space.shape == (12,) and env.action_space.shape == (3,)


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
