"""Platoon environments in parallel worker processes, one libsumo each (spawn), stepped together.

:class:`VecPlatoon` steps ``num_envs`` :class:`carl_sumo.env.PlatoonEnv` on arrays: actions
(num_envs, n) in, observations (num_envs, n, 4) out, so one batched policy call serves all
environments. An environment whose episode ends is reset at once; the observation that ended it is
returned separately (``final_obs``) for the replay buffer.
"""

from __future__ import annotations

import multiprocessing as mp
from pathlib import Path
from typing import Sequence

import numpy as np

from carl_sumo.channel import Impairments
from carl_sumo.config import BOUNDS, REWARD, ControlBounds, RewardConfig
from carl_sumo.data.events import Event
from carl_sumo.workers import WorkerError


def _worker(conn, events: Sequence[Event], n: int, net_path: str, seed: int,
            reward: RewardConfig, base: str, observe_ahead: bool, bounds: ControlBounds,
            shield_ttc_s: float) -> None:
    from carl_sumo.env import PlatoonEnv

    env = PlatoonEnv(events, n, net_path, reward=reward, base=base, bounds=bounds,
                     observe_ahead=observe_ahead, shield_ttc_s=shield_ttc_s)
    rng_seed = seed
    env.reset_array(seed=rng_seed)
    while True:
        cmd, data = conn.recv()
        if cmd == "step":
            action, next_impairments = data
            next_obs, reward, terminated, truncated, _ = env.step_array(action)
            final = next_obs
            if terminated or truncated:
                next_obs = env.reset_array(impairments=next_impairments)
            conn.send((next_obs, reward, terminated, truncated, final))
        elif cmd == "reset":
            reset_seed, impairments = data
            conn.send(env.reset_array(seed=reset_seed, impairments=impairments))
        elif cmd == "close":
            conn.close()
            return


class VecPlatoon:
    """``num_envs`` platoon environments in worker processes (``base``: their base model;
    ``observe_ahead``, ``bounds``, ``shield_ttc_s``: see :class:`carl_sumo.env.PlatoonEnv`)."""

    def __init__(self, events: Sequence[Event], n_followers: int, net_path: str | Path,
                 num_envs: int = 2, seed: int = 0, reward: RewardConfig = REWARD,
                 base: str = "idm", observe_ahead: bool = False,
                 bounds: ControlBounds = BOUNDS, shield_ttc_s: float = 0.0):
        ctx = mp.get_context("spawn")
        self.num_envs, self.n = num_envs, n_followers
        self._conns, self._procs = [], []
        for i in range(num_envs):
            parent, child = ctx.Pipe()
            proc = ctx.Process(target=_worker, args=(child, list(events), n_followers,
                                                     str(net_path), seed * 1000 + i, reward, base,
                                                     observe_ahead, bounds, shield_ttc_s),
                               daemon=True)
            proc.start()
            child.close()
            self._conns.append(parent)
            self._procs.append(proc)

    def _exchange(self, messages: list[tuple]) -> list:
        """Send one message to each worker and return their answers; WorkerError (one line) if
        a worker process has died."""
        try:
            for conn, message in zip(self._conns, messages):
                conn.send(message)
            return [conn.recv() for conn in self._conns]
        except (EOFError, BrokenPipeError, ConnectionResetError):
            dead = [i for i, proc in enumerate(self._procs) if not proc.is_alive()]
            raise WorkerError(f"SUMO environment worker(s) {dead or '?'} died (exit code "
                              f"{[self._procs[i].exitcode for i in dead]}); the training stops "
                              "here: continue it from its last checkpoint with --resume") from None

    def reset(self, seed: int, impairments: Sequence[Impairments | None] | None = None
              ) -> np.ndarray:
        """Start every env's episode (``impairments``: each one's, see
        :meth:`carl_sumo.env.PlatoonEnv.reset_array`); observations stacked over envs."""
        impairments = impairments or [None] * self.num_envs
        return np.stack(self._exchange([("reset", (seed * 1000 + i, impairments[i]))
                                        for i in range(self.num_envs)]))

    def step(self, actions: np.ndarray,
             next_impairments: Sequence[Impairments | None] | None = None):
        """Step every env; (obs, rewards, terminated, truncated, final_obs) stacked over envs.
        An env whose episode ends starts the next one at once, with its ``next_impairments``."""
        next_impairments = next_impairments or [None] * self.num_envs
        results = self._exchange([("step", (np.asarray(action, dtype=np.float64), imp))
                                  for action, imp in zip(actions, next_impairments)])
        obs, reward, term, trunc, final = zip(*results)
        return (np.stack(obs), np.stack(reward), np.array(term), np.array(trunc),
                np.stack(final))

    def close(self) -> None:
        for conn in self._conns:
            try:
                conn.send(("close", None))
            except (BrokenPipeError, OSError):
                pass
        for proc in self._procs:
            proc.join(timeout=5)
            if proc.is_alive():
                proc.terminate()
