"""How well the critics know the start policy, measured on held-out transitions, and the critic
burn-in that ends when that stops improving (issue 55; Silver et al. 2018 burn in the critic
until its loss settles before a residual actor moves).

**Held out** (``train --critic-holdout F``). At ``--learning-starts`` the data stored so far is
the start policy's (the base plus exploration noise, or the ``--imitate`` teacher's). It is cut
into blocks of :data:`BLOCK_STEPS` vector steps per environment and every round(1/F)-th block
(the middle one of each group) is kept out of the critics' training for the whole run
(:meth:`carl_sumo.learn.replay_buffer.ReplayBuffer.hold_out`). A block is far longer than the
discount's horizon, so the critic has not seen the held-out transitions' neighbours.

**The criterion**, measured on them at every validation (the learning curve's ``critic_td`` and
``critic_rank``) and at every check of a calibration burn-in:

- ``critic_td``: the mean squared TD error of critic 1 over transitions and vehicles,
  (Q1(o, a) - y)², y = r + γ·(1 - done)·min Q_target(o', π_target(o')) (no target noise);
- ``critic_rank``: Spearman's rank correlation of Q1(o, a) with the return realised after
  (o, a), G = Σ_k γ^k r_(t+k) along the transition's own episode, over all (transition, vehicle)
  pairs. Only transitions whose episode goes on for :func:`horizon_steps` more stored steps (or
  ends in a collision) count, so that G is not cut short by the end of the data or of an event.

**Calibration** (``--critic-calibration td|rank``): after ``--learning-starts`` the critics alone
train, the actor staying as it is, until the chosen criterion has not improved for
``--calibration-patience`` checks in a row (checked every ``--calibration-every`` steps; an
improvement: a TD error lower by more than :data:`TD_TOLERANCE` of the best, a rank correlation
higher by more than :data:`RANK_TOLERANCE`), at most ``--critic-burn-in`` steps.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from carl_sumo.learn.agents import Agent, normalise
from carl_sumo.learn.replay_buffer import ReplayBuffer

BLOCK_STEPS = 50
"""Vector steps per held-out block (5 s; the discount's horizon at γ = 0.98 is 5 s)."""

TD_TOLERANCE = 0.01
"""A calibration check improves the TD error when it is below the best by more than this
fraction of it."""

RANK_TOLERANCE = 0.005
"""A calibration check improves the rank correlation when it is above the best by more than
this."""

MAX_HORIZON_STEPS = 200
"""The longest stretch of episode a held-out transition needs after it (steps)."""

CRITERIA = ("td", "rank")


def horizon_steps(gamma: float) -> int:
    """Steps of episode a held-out transition needs after it for its realised return to count:
    2/(1 - γ) (where γ^k leaves about 13 % of the weight at γ = 0.98), at most
    :data:`MAX_HORIZON_STEPS`."""
    return int(min(MAX_HORIZON_STEPS, math.ceil(2.0 / max(1.0 - gamma, 1e-9))))


def held_block_every(fraction: float) -> int:
    """Every how many blocks one is held out for ``--critic-holdout`` ``fraction``."""
    return max(2, round(1.0 / fraction))


def steps_needed(fraction: float, gamma: float) -> int:
    """The fewest ``--learning-starts`` steps with one held-out block whose transitions have
    :func:`horizon_steps` of data after them."""
    k = held_block_every(fraction)
    return (k // 2 + 1) * BLOCK_STEPS + horizon_steps(gamma)


def realised_returns(reward: np.ndarray, done: np.ndarray, ends: np.ndarray, gamma: float
                     ) -> tuple[np.ndarray, np.ndarray]:
    """(discounted returns (T, n), usable (T,)) of one environment's consecutive transitions:
    ``reward`` (T, n), ``done`` (T,) a collision ended the episode there, ``ends`` (T,) the
    episode ended there (a collision, the event's end, or the end of the data). Usable: the
    transitions with at least :func:`horizon_steps` steps after them before an end that is not a
    collision."""
    steps = len(reward)
    returns = np.zeros_like(reward, dtype=np.float64)
    left = np.zeros(steps)  # steps to an end that cuts the return short (inf: a collision first)
    after, cut = np.zeros(reward.shape[1]), math.inf
    for t in range(steps - 1, -1, -1):
        if ends[t]:
            after, cut = np.zeros(reward.shape[1]), math.inf if done[t] else 0.0
        after = reward[t] + gamma * after
        cut += 1.0
        returns[t], left[t] = after, cut
    return returns, left >= horizon_steps(gamma)


@dataclass
class CriticProbe:
    """The held-out transitions (buffer rows) and their realised returns (rows, n)."""

    rows: np.ndarray
    returns: np.ndarray

    @classmethod
    def build(cls, buffer: ReplayBuffer, upto: int, num_envs: int, gamma: float,
              fraction: float) -> "CriticProbe":
        """The probe of the first ``upto`` stored rows (``--learning-starts`` times the
        environments; rows are step-major: row = step·num_envs + env). May hold no row, where
        no held-out block has the episode it needs after it."""
        k = held_block_every(fraction)
        rows, returns = [], []
        for env in range(num_envs):
            idx = np.arange(env, upto, num_envs)
            if len(idx) == 0:
                continue
            obs, next_obs = buffer.obs[idx].numpy(), buffer.next_obs[idx].numpy()
            done = buffer.done[idx].numpy() > 0.5
            ends = np.ones(len(idx), dtype=bool)  # the last stored step ends the data
            ends[:-1] = done[:-1] | (next_obs[:-1] != obs[1:]).any(axis=(1, 2))
            g, usable = realised_returns(buffer.reward[idx].numpy(), done, ends, gamma)
            held = (np.arange(len(idx)) // BLOCK_STEPS) % k == k // 2
            rows.append(idx[held & usable])
            returns.append(g[held & usable])
        n = buffer.reward.shape[1]
        return cls(np.concatenate(rows) if rows else np.zeros(0, dtype=np.int64),
                   np.concatenate(returns) if returns else np.zeros((0, n)))

    @torch.no_grad()
    def measure(self, agent: Agent, buffer: ReplayBuffer) -> dict[str, float]:
        """``critic_td`` and ``critic_rank`` (the module docstring) of the agent as it is now."""
        if len(self.rows) == 0:
            return {"critic_td": math.nan, "critic_rank": math.nan}
        batch = buffer.rows(torch.from_numpy(self.rows))
        x, next_x, mask = normalise(batch["obs"]), normalise(batch["next_obs"]), batch["mask"]
        q = agent._q([agent.critic1], x, batch["action"], mask)[0]
        next_action = agent._act_normalised(agent.actor_target, next_x, mask,
                                            links=batch.get("next_links"))
        targets = [agent.critic1_target] + ([agent.critic2_target] if agent.cfg.twin else [])
        y = batch["reward"] + agent.cfg.gamma * (1.0 - batch["done"]).unsqueeze(-1) * \
            agent._q(targets, next_x, next_action, mask).amin(0)
        return {"critic_td": float(((q - y) ** 2).mean()),
                "critic_rank": spearman(q.numpy().ravel(), self.returns.ravel())}


def spearman(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman's rank correlation of two samples (NaN with fewer than 2 or no spread)."""
    if len(a) < 2:
        return math.nan
    ra = np.argsort(np.argsort(a, kind="stable"), kind="stable").astype(np.float64)
    rb = np.argsort(np.argsort(b, kind="stable"), kind="stable").astype(np.float64)
    ra, rb = ra - ra.mean(), rb - rb.mean()
    denom = math.sqrt(float((ra ** 2).sum() * (rb ** 2).sum()))
    return float((ra * rb).sum() / denom) if denom > 0 else math.nan


@dataclass
class Calibration:
    """When the actor may move: from ``actor_from`` (a vector step; at first the latest,
    ``--learning-starts`` + ``--critic-burn-in``), brought forward by :meth:`check` when the
    ``criterion`` (td, rank or off) stops improving. ``checks``: (step, value) of every check."""

    criterion: str
    patience: int
    actor_from: int
    best: float = math.nan
    since_best: int = 0
    checks: list[tuple[int, float]] = field(default_factory=list)

    @property
    def active(self) -> bool:
        return self.criterion in CRITERIA

    def check(self, step: int, measured: dict[str, float]) -> bool:
        """Record the criterion after ``step`` steps; True (and ``actor_from`` = ``step``) when
        it has not improved for ``patience`` checks in a row."""
        value = measured[f"critic_{self.criterion}"]
        self.checks.append((step, value))
        better = math.isnan(self.best) or (
            value < self.best * (1.0 - TD_TOLERANCE) if self.criterion == "td"
            else value > self.best + RANK_TOLERANCE)
        if better and math.isfinite(value):
            self.best, self.since_best = value, 0
        else:
            self.since_best += 1
        if self.since_best >= self.patience and step < self.actor_from:
            self.actor_from = step
            return True
        return False

    def state(self) -> list[float]:
        return [float(self.actor_from), self.best, float(self.since_best)]

    def restore(self, state: list[float]) -> None:
        self.actor_from, self.best, self.since_best = int(state[0]), state[1], int(state[2])
