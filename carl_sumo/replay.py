"""Replay buffer of joint platoon transitions, stored as preallocated torch tensors.

A batch is gathered with one ``index_select`` per field straight into the tensors the networks
take (no numpy fancy indexing and numpy -> torch copy per field). Indices are drawn with the
caller's numpy generator, so a seeded run samples the same transitions as before.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

FIELDS = ("obs", "action", "reward", "next_obs", "done")


class ReplayBuffer:
    """Joint platoon transitions: obs (n, obs_dim), action (n,) (m/s²), reward (n,), next_obs,
    done; obs_dim 4, or 5 on a classical base (a_base)."""

    def __init__(self, capacity: int, n: int, obs_dim: int = 4):
        self.capacity, self.n, self.size, self.pos = capacity, n, 0, 0
        self.obs = torch.zeros((capacity, n, obs_dim))
        self.next_obs = torch.zeros((capacity, n, obs_dim))
        self.action = torch.zeros((capacity, n))
        self.reward = torch.zeros((capacity, n))
        self.done = torch.zeros(capacity)
        self._mask: torch.Tensor | None = None

    def add(self, obs, action, reward, next_obs, done) -> None:
        """Append one transition per environment (arrays stacked over environments)."""
        k, p = len(obs), self.pos
        for name, value in zip(FIELDS, (obs, action, reward, next_obs, done)):
            value = torch.from_numpy(np.asarray(value))
            if p + k <= self.capacity:
                getattr(self, name)[p:p + k] = value  # cast to float32 on the copy
            else:  # wraps around
                rows = torch.from_numpy((p + np.arange(k)) % self.capacity)
                getattr(self, name).index_copy_(0, rows, value.to(torch.float32))
        self.pos = (self.pos + k) % self.capacity
        self.size = min(self.size + k, self.capacity)

    def sample(self, batch_size: int, rng: np.random.Generator) -> dict[str, torch.Tensor]:
        """``batch_size`` transitions drawn uniformly with replacement, and an all-True mask."""
        idx = torch.from_numpy(rng.integers(0, self.size, size=batch_size))
        batch = {k: getattr(self, k).index_select(0, idx) for k in FIELDS}
        if self._mask is None or self._mask.shape[0] != batch_size:
            self._mask = torch.ones(batch_size, self.n, dtype=torch.bool)
        batch["mask"] = self._mask
        return batch

    def state(self) -> dict[str, Any]:
        s = self.size
        return {"capacity": self.capacity, "n": self.n, "size": s, "pos": self.pos,
                **{k: getattr(self, k)[:s].clone() for k in FIELDS}}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> "ReplayBuffer":
        buf = cls(int(state["capacity"]), int(state["n"]), int(state["obs"].shape[-1]))
        s = int(state["size"])
        for k in FIELDS:
            getattr(buf, k)[:s] = torch.as_tensor(state[k])
        buf.size, buf.pos = s, int(state["pos"])
        return buf
