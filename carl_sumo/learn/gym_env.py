"""A single-agent Gymnasium environment for SB3, CleanRL and other single-agent libraries: the
whole platoon (``n_followers``, 1 by default: one follower behind the leader) as one agent.

- action: a_adj of every follower, ``Box(-adj_max, adj_max, (n,))`` in m/s² (added to IDM, or fed
  into a classical ``base``'s law, exactly as :class:`carl_sumo.learn.env.PlatoonEnv` does);
- observation: the followers' [v, a, d, Δv] (and a_base on a classical base), head first,
  flattened to ``(n·obs_dim,)`` float32;
- reward: the mean of the followers' rewards (the paper's, :mod:`carl_sumo.learn.reward`);
- an episode is one event (chosen with the reset's seed), ending at a collision (terminated) or
  the event's end (truncated).

Registered as ``carl_sumo/Platoon-v0`` on import::

    import gymnasium, carl_sumo.learn.gym_env
    env = gymnasium.make("carl_sumo/Platoon-v0", n_followers=1)

libsumo runs one simulation per process: vector environments must run in subprocesses
(``gymnasium.vector.AsyncVectorEnv``, SB3's ``SubprocVecEnv``); stepping a second live instance in
the same process ends with one clear InputError.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import gymnasium
import numpy as np
from gymnasium import spaces

from carl_sumo.data import load_events
from carl_sumo.data.events import Event
from carl_sumo.learn.env import PlatoonEnv
from carl_sumo.sim.sumo import DEFAULT_NET

ENV_ID = "carl_sumo/Platoon-v0"


class PlatoonGymEnv(gymnasium.Env):
    """The platoon as one agent (see the module docstring); ``events`` or ``data``/``split``
    give the leaders, the other keyword arguments go to :class:`PlatoonEnv`."""

    metadata = {"render_modes": []}

    def __init__(self, n_followers: int = 1, events: Sequence[Event] | None = None,
                 data: str = "default", split: str = "train",
                 net_path: str | Path = DEFAULT_NET, **env_kwargs: Any):
        events = list(events) if events is not None else load_events(data, split)
        self.platoon = PlatoonEnv(events, n_followers, net_path, **env_kwargs)
        self.n = n_followers
        high = float(self.platoon.action_space("cacc_0").high[0])
        obs_dim = self.platoon.observation_space("cacc_0").shape[0]
        self.action_space = spaces.Box(-high, high, shape=(n_followers,), dtype=np.float32)
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(n_followers * obs_dim,),
                                            dtype=np.float32)

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict]:
        super().reset(seed=seed)
        event = None
        if options and "event_id" in options:
            event = next(e for e in self.platoon.events if e.event_id == options["event_id"])
        obs = self.platoon.reset_array(int(self.np_random.integers(2 ** 31)), event)
        return obs.astype(np.float32).ravel(), {"event_id": self.platoon.event.event_id}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        adjustment = np.asarray(action, dtype=np.float64).reshape(self.n)
        obs, rewards, terminated, truncated, accel = self.platoon.step_array(adjustment)
        return (obs.astype(np.float32).ravel(), float(np.mean(rewards)), terminated, truncated,
                {"accelerations": accel})

    def close(self) -> None:
        self.platoon.close()


if ENV_ID not in gymnasium.registry:
    gymnasium.register(id=ENV_ID, entry_point="carl_sumo.learn.gym_env:PlatoonGymEnv")
