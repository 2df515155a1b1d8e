"""A single-agent Gymnasium environment for SB3, CleanRL and other single-agent libraries: the
whole platoon (``n_followers``, 1 by default: one follower behind the leader) as one agent.

- action: a_adj of every follower, ``Box(-adj_max, adj_max, (n,))`` in m/s² (added to IDM, or fed
  into a classical ``base``'s law, exactly as :class:`carl_sumo.learn.env.PlatoonEnv` does);
- observation: the followers' [v, a, d, Δv] (and a_base on a classical base), head first,
  flattened to ``(n·obs_dim,)`` float32;
- reward: the mean of the followers' rewards (the paper's, :mod:`carl_sumo.learn.reward`);
- an episode is one event (chosen with the reset's seed), ending at a collision (terminated) or
  the event's end (truncated).

Registered as ``carl_sumo/Platoon-v0`` by ``import carl_sumo``::

    import gymnasium, carl_sumo
    env = gymnasium.make("carl_sumo/Platoon-v0", n_followers=1)

libsumo runs one simulation per process: vector environments must run in subprocesses
(``gymnasium.vector.AsyncVectorEnv``, SB3's ``SubprocVecEnv``); making a second environment while
one is open in the same process is an InputError (close the first one). The API contract is
checked: a platoon of at least one follower, a finite action of the action space's shape, a
known ``event_id`` option, ``reset`` before the first step and after an episode ends, nothing
after ``close``: each of these is one clear InputError.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import weakref

import gymnasium
import numpy as np
from gymnasium import spaces

from carl_sumo import ENV_ID
from carl_sumo.data import load_events
from carl_sumo.data.events import Event
from carl_sumo.errors import InputError
from carl_sumo.learn.env import PlatoonEnv
from carl_sumo.sim.sumo import DEFAULT_NET

_OPEN: "weakref.WeakSet[PlatoonGymEnv]" = weakref.WeakSet()
"""The environments of this process that are not closed (libsumo holds one simulation)."""


def _another_open(env: object) -> bool:
    """Whether an environment other than ``env`` is open (after collecting unreachable ones)."""
    if not any(other is not env for other in _OPEN):
        return False
    import gc

    gc.collect()  # an environment nobody holds any more is not open
    return any(other is not env for other in _OPEN)


class PlatoonGymEnv(gymnasium.Env):
    """The platoon as one agent (see the module docstring); ``events`` or ``data``/``split``
    give the leaders, the other keyword arguments go to :class:`PlatoonEnv`."""

    metadata = {"render_modes": []}

    def __init__(self, n_followers: int = 1, events: Sequence[Event] | None = None,
                 data: str = "default", split: str = "train",
                 net_path: str | Path = DEFAULT_NET, **env_kwargs: Any):
        if isinstance(n_followers, bool) or not isinstance(n_followers, (int, np.integer)) \
                or n_followers < 1:
            raise InputError(f"n_followers must be a whole number of at least 1, got "
                             f"{n_followers!r}")
        if _another_open(self):
            raise InputError("another carl_sumo/Platoon-v0 environment is open in this process "
                             "(libsumo runs one simulation per process): close it first, or run "
                             "each environment in its own process (gymnasium.vector."
                             "AsyncVectorEnv, SB3's SubprocVecEnv)")
        self._closed, self._needs_reset = False, True
        events = list(events) if events is not None else load_events(data, split)
        self.platoon = PlatoonEnv(events, n_followers, net_path, **env_kwargs)
        self.n = n_followers
        high = float(self.platoon.action_space("cacc_0").high[0])
        obs_dim = self.platoon.observation_space("cacc_0").shape[0]
        self.action_space = spaces.Box(-high, high, shape=(n_followers,), dtype=np.float32)
        self.observation_space = spaces.Box(-np.inf, np.inf, shape=(n_followers * obs_dim,),
                                            dtype=np.float32)
        _OPEN.add(self)

    def _check_open(self, what: str) -> None:
        if self._closed:
            raise InputError(f"{what} after close(): make a new environment")

    def reset(self, *, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[np.ndarray, dict]:
        self._check_open("reset")
        super().reset(seed=seed)
        event = None
        if options and "event_id" in options:
            event = next((e for e in self.platoon.events if e.event_id == options["event_id"]),
                         None)
            if event is None:
                raise InputError(f"unknown event_id {options['event_id']!r}; this environment "
                                 f"has {len(self.platoon.events)} events, e.g. "
                                 f"{self.platoon.events[0].event_id!r}")
        obs = self.platoon.reset_array(int(self.np_random.integers(2 ** 31)), event)
        self._needs_reset = False
        return obs.astype(np.float32).ravel(), {"event_id": self.platoon.event.event_id}

    def step(self, action: np.ndarray) -> tuple[np.ndarray, float, bool, bool, dict]:
        self._check_open("step")
        if self._needs_reset:
            raise InputError("step before reset, or after the episode ended (terminated or "
                             "truncated): call reset() first")
        adjustment = np.asarray(action, dtype=np.float64)
        if adjustment.size != self.n or not np.all(np.isfinite(adjustment)):
            raise InputError(f"the action must be {self.n} finite number(s) (a_adj in m/s², "
                             f"the action space's shape), got {np.asarray(action).tolist()!r}")
        obs, rewards, terminated, truncated, accel = self.platoon.step_array(
            adjustment.reshape(self.n))
        self._needs_reset = bool(terminated or truncated)
        return (obs.astype(np.float32).ravel(), float(np.mean(rewards)), terminated, truncated,
                {"accelerations": accel})

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            _OPEN.discard(self)
            self.platoon.close()


if ENV_ID not in gymnasium.registry:  # registered by ``import carl_sumo`` already
    gymnasium.register(id=ENV_ID, entry_point="carl_sumo.learn.gym_env:PlatoonGymEnv")
