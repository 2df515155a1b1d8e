"""Platoon environments in parallel worker processes, one libsumo each (spawn), stepped together.

:class:`VecPlatoon` steps ``num_envs`` :class:`carl_sumo.learn.env.PlatoonEnv` on arrays: actions
(num_envs, n) in, observations (num_envs, n, 4) out, so one batched policy call serves all
environments. An environment whose episode ends is reset at once; the observation that ended it is
returned separately (``final_obs``) for the replay buffer. :class:`RayVecPlatoon` is the same
vector with its environments in Ray actors (``train --ray``).
"""

from __future__ import annotations

import multiprocessing as mp
from pathlib import Path
from typing import Sequence

import numpy as np

from carl_sumo.control.channel import Impairments
from carl_sumo.config import BOUNDS, REWARD, ControlBounds, RewardConfig
from carl_sumo.data.events import Event
from carl_sumo.interrupts import die_with_parent
from carl_sumo.learn.reward import critical_cost
from carl_sumo.scale.workers import WorkerError


class EnvRunner:
    """One environment of a vector, in a worker process: reset and step on arrays, an episode
    that ends reset at once (the same in a spawned process and in a Ray actor)."""

    def __init__(self, events: Sequence[Event], n: int, net_path: str, seed: int,
                 reward: RewardConfig, base: str, observe_ahead: bool, bounds: ControlBounds,
                 shield_ttc_s: float, command_history: int = 0):
        from carl_sumo.learn.env import PlatoonEnv

        self.env = PlatoonEnv(events, n, net_path, reward=reward, base=base, bounds=bounds,
                              observe_ahead=observe_ahead, shield_ttc_s=shield_ttc_s,
                              command_history=command_history)
        self.paired = reward.paired_base  # a decision's reward less the base's on its episode
        self.hold = self.env.hold_steps  # steps (0.1 s) per decision: S/0.1 on a gh=S base
        self.env.reset_array(seed=seed)
        self._episode = (self.env.event, None)  # (event, impairments) of the episode under way

    def step(self, data: tuple[np.ndarray, Impairments | None]) -> tuple:
        """(next obs, reward, terminated, truncated, final obs, safety cost) of one step of
        ``data`` = (action, the impairments of the next episode if this one ends); the cost is
        :func:`carl_sumo.learn.reward.critical_cost` of the true state after the step. On a base
        that holds its decisions (``gh=S``, :attr:`PlatoonEnv.hold_steps`) a step is the S s of
        one decision (or what is left of the episode): the reward its mean, the cost its max."""
        action, next_impairments = data
        if self.hold == 1:  # a decision every step
            next_obs, reward, terminated, truncated, _ = self.env.step_array(action)
            cost, steps = critical_cost(self.env.true_observation), 1
        else:
            next_obs, reward, cost, terminated, truncated, steps = self._held(action)
        final = next_obs
        if self.paired:  # the base on the same event and fleet, as long: its mean reward
            reward = reward - self._base_reward(steps)
        if terminated or truncated:
            next_obs = self.env.reset_array(impairments=next_impairments)
            self._episode = (self.env.event, next_impairments)
        return next_obs, reward, terminated, truncated, final, cost

    def _held(self, action: np.ndarray) -> tuple:
        """(next obs, mean reward, max cost, terminated, truncated, steps) of one held decision:
        ``hold`` steps of ``action``, or what is left of the episode (a semi-MDP)."""
        rewards, costs = [], []
        for _ in range(self.hold):
            next_obs, reward, terminated, truncated, _ = self.env.step_array(action)
            rewards.append(reward)
            costs.append(critical_cost(self.env.true_observation))
            if terminated or truncated:
                break
        return (next_obs, np.mean(rewards, axis=0), np.max(costs, axis=0), terminated,
                truncated, len(rewards))

    def _base_reward(self, steps: int) -> np.ndarray:
        """The mean reward of the base alone (a_adj = 0) over the first ``steps`` steps of the
        episode under way (its event and impairments, so its fleet, noise and links), run again
        from its start (a collision ends it early)."""
        event, impairments = self._episode
        self.env.reset_array(event=event, impairments=impairments)
        zero, rewards = np.zeros(self.env.n_followers), []
        for _ in range(steps):
            _, reward, terminated, truncated, _ = self.env.step_array(zero)
            rewards.append(reward)
            if terminated or truncated:
                break
        return np.mean(rewards, axis=0)

    def reset(self, data: tuple[int, Impairments | None]) -> np.ndarray:
        """Start an episode: ``data`` = (seed, its impairments)."""
        seed, impairments = data
        obs = self.env.reset_array(seed=seed, impairments=impairments)
        self._episode = (self.env.event, impairments)
        return obs


def _worker(conn, *args) -> None:
    die_with_parent()  # no environment outlives a killed training run
    runner = EnvRunner(*args)
    while True:
        try:
            cmd, data = conn.recv()
        except EOFError:  # the training process has gone: nothing more to do
            return
        if cmd == "step":
            conn.send(runner.step(data))
        elif cmd == "reset":
            conn.send(runner.reset(data))
        elif cmd == "close":
            conn.close()
            return


class VecPlatoon:
    """``num_envs`` platoon environments in worker processes (``base``: their base model;
    ``observe_ahead``, ``bounds``, ``shield_ttc_s``: see :class:`carl_sumo.learn.env.PlatoonEnv`)."""

    def __init__(self, events: Sequence[Event], n_followers: int, net_path: str | Path,
                 num_envs: int = 2, seed: int = 0, reward: RewardConfig = REWARD,
                 base: str = "idm", observe_ahead: bool = False,
                 bounds: ControlBounds = BOUNDS, shield_ttc_s: float = 0.0,
                 command_history: int = 0):
        ctx = mp.get_context("spawn")
        self.num_envs, self.n = num_envs, n_followers
        self._conns, self._procs = [], []
        for i in range(num_envs):
            parent, child = ctx.Pipe()
            proc = ctx.Process(target=_worker, args=(child, list(events), n_followers,
                                                     str(net_path), seed * 1000 + i, reward, base,
                                                     observe_ahead, bounds, shield_ttc_s,
                                                     command_history),
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
        :meth:`carl_sumo.learn.env.PlatoonEnv.reset_array`); observations stacked over envs."""
        impairments = impairments or [None] * self.num_envs
        return np.stack(self._exchange([("reset", (seed * 1000 + i, impairments[i]))
                                        for i in range(self.num_envs)]))

    def step(self, actions: np.ndarray,
             next_impairments: Sequence[Impairments | None] | None = None):
        """Step every env; (obs, rewards, terminated, truncated, final_obs, costs) stacked over
        envs (costs: each vehicle's safety cost, :meth:`EnvRunner.step`). An env whose episode
        ends starts the next one at once, with its ``next_impairments``."""
        next_impairments = next_impairments or [None] * self.num_envs
        results = self._exchange([("step", (np.asarray(action, dtype=np.float64), imp))
                                  for action, imp in zip(actions, next_impairments)])
        obs, reward, term, trunc, final, cost = zip(*results)
        return (np.stack(obs), np.stack(reward), np.array(term), np.array(trunc),
                np.stack(final), np.stack(cost))

    def close(self) -> None:
        """Stop the worker processes."""
        for conn in self._conns:
            try:
                conn.send(("close", None))
            except (BrokenPipeError, OSError):
                pass
        for proc in self._procs:
            proc.join(timeout=5)
            if proc.is_alive():
                proc.terminate()


class RayVecPlatoon(VecPlatoon):
    """The same vector with each environment in a Ray actor (1 CPU, its own libsumo) on the Ray
    runtime this process is connected to (``train --ray``; :mod:`carl_sumo.scale.cluster`). The
    environments and their seeds are those of :class:`VecPlatoon`, so is every step."""

    def __init__(self, events: Sequence[Event], n_followers: int, net_path: str | Path,
                 num_envs: int = 2, seed: int = 0, reward: RewardConfig = REWARD,
                 base: str = "idm", observe_ahead: bool = False,
                 bounds: ControlBounds = BOUNDS, shield_ttc_s: float = 0.0,
                 command_history: int = 0):
        import ray

        from carl_sumo.scale.cluster import require_cpus

        require_cpus(num_envs, "--envs")  # else the actors would wait for CPUs for ever
        actor = ray.remote(num_cpus=1, max_restarts=0)(EnvRunner)
        self.num_envs, self.n = num_envs, n_followers
        net = str(Path(net_path).resolve()) if Path(net_path).exists() else str(net_path)
        events_ref = ray.put(list(events))
        self._actors = [actor.remote(events_ref, n_followers, net, seed * 1000 + i, reward, base,
                                     observe_ahead, bounds, shield_ttc_s, command_history)
                        for i in range(num_envs)]

    def _exchange(self, messages: list[tuple]) -> list:
        import ray
        from ray.exceptions import RayActorError

        calls = [getattr(actor, cmd).remote(data) for actor, (cmd, data)
                 in zip(self._actors, messages)]
        try:
            return ray.get(calls)
        except RayActorError as exc:
            raise WorkerError(f"a Ray SUMO environment actor died ({type(exc).__name__}); the "
                              "training stops here: continue it from its last checkpoint with "
                              "--resume") from None

    def close(self) -> None:
        """Stop the actors."""
        import ray

        for actor in self._actors:
            ray.kill(actor)
