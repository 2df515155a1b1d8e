"""Replay buffer of joint platoon transitions, stored as preallocated torch tensors.

A batch is gathered with one ``index_select`` per field straight into the tensors the networks
take (no numpy fancy indexing and numpy -> torch copy per field). Indices are drawn with the
caller's numpy generator, so a seeded run samples the same transitions as before.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

FIELDS = ("obs", "action", "reward", "next_obs", "done", "cost")
LINK_FIELDS = ("link_mode", "link_held", "next_link_mode", "next_link_held")
"""With impaired training links: how each CA message arrived at o and at o' (modes (2, n) of
the forward and backward link, held messages (2, n, M))."""


class ReplayBuffer:
    """Joint platoon transitions: obs (n, obs_dim), action (n,) (m/s²), reward (n,), next_obs,
    done, cost (n,) (the safety cost, :func:`carl_sumo.learn.reward.critical_cost`); obs_dim
    4, or 5 on a classical base (a_base). ``message_dim`` > 0: also how the CA
    messages of width ``message_dim`` arrived (:data:`LINK_FIELDS`)."""

    def __init__(self, capacity: int, n: int, obs_dim: int = 4, message_dim: int = 0):
        self.capacity, self.n, self.size, self.pos = capacity, n, 0, 0
        self.message_dim = message_dim
        self.obs = torch.zeros((capacity, n, obs_dim))
        self.next_obs = torch.zeros((capacity, n, obs_dim))
        self.action = torch.zeros((capacity, n))
        self.reward = torch.zeros((capacity, n))
        self.done = torch.zeros(capacity)
        self.cost = torch.zeros((capacity, n))
        if message_dim:
            for prefix in ("", "next_"):
                setattr(self, prefix + "link_mode", torch.zeros((capacity, 2, n), dtype=torch.uint8))
                setattr(self, prefix + "link_held", torch.zeros((capacity, 2, n, message_dim)))
        self._mask: torch.Tensor | None = None
        self._drawn: np.ndarray | None = None  # with held-out rows: the rows that may be drawn
        self._held_below = 0

    @property
    def fields(self) -> tuple[str, ...]:
        return FIELDS + LINK_FIELDS if self.message_dim else FIELDS

    def add(self, obs, action, reward, next_obs, done, links=None, next_links=None,
            cost=None) -> None:
        """Append one transition per environment (arrays stacked over environments; no ``cost``:
        0); with link fields, ``links`` / ``next_links`` = (forward modes (k, n), forward held (k, n, M),
        backward modes, backward held) at o and o'."""
        k, p = len(obs), self.pos
        values = [obs, action, reward, next_obs, done,
                  np.zeros(np.shape(reward)) if cost is None else cost]
        if self.message_dim:
            for pair in (links, next_links):
                values += [np.stack([pair[0], pair[2]], 1), np.stack([pair[1], pair[3]], 1)]
        for name, value in zip(self.fields, values):
            value = torch.from_numpy(np.asarray(value))
            if p + k <= self.capacity:
                getattr(self, name)[p:p + k] = value  # cast to float32 on the copy
            else:  # wraps around
                rows = torch.from_numpy((p + np.arange(k)) % self.capacity)
                target = getattr(self, name)
                target.index_copy_(0, rows, value.to(target.dtype))
        self.pos = (self.pos + k) % self.capacity
        self.size = min(self.size + k, self.capacity)

    def hold_out(self, rows: np.ndarray) -> None:
        """Keep these rows (stored transitions) out of every later :meth:`sample`: the critic's
        held-out set (:mod:`carl_sumo.learn.calibration`). Rows stored later are all drawn."""
        held = np.zeros(self.size, dtype=bool)
        held[np.asarray(rows, dtype=np.int64)] = True
        self._drawn = np.flatnonzero(~held)  # the rows below size that may be drawn
        self._held_below = self.size

    def sample(self, batch_size: int, rng: np.random.Generator) -> dict[str, torch.Tensor]:
        """``batch_size`` transitions drawn uniformly with replacement (none of the rows held
        out, :meth:`hold_out`), and an all-True mask."""
        drawn = self._drawn
        if drawn is None:
            idx = torch.from_numpy(rng.integers(0, self.size, size=batch_size))
        else:  # positions among the allowed rows: those held out never come
            k = rng.integers(0, len(drawn) + self.size - self._held_below, size=batch_size)
            idx = torch.from_numpy(np.where(k < len(drawn), drawn[np.minimum(k, len(drawn) - 1)],
                                            k - len(drawn) + self._held_below))
        return self.rows(idx)

    def rows(self, idx: torch.Tensor) -> dict[str, torch.Tensor]:
        """The transitions of buffer rows ``idx`` as a batch (the fields, links, an all-True
        mask)."""
        batch_size = len(idx)
        batch = {k: getattr(self, k).index_select(0, idx) for k in FIELDS}
        if self.message_dim:
            for prefix in ("", "next_"):
                mode = getattr(self, prefix + "link_mode").index_select(0, idx).long()
                held = getattr(self, prefix + "link_held").index_select(0, idx)
                batch[prefix + "links"] = (mode[:, 0], held[:, 0], mode[:, 1], held[:, 1])
        if self._mask is None or self._mask.shape[0] != batch_size:
            self._mask = torch.ones(batch_size, self.n, dtype=torch.bool)
        batch["mask"] = self._mask
        return batch

    def state(self) -> dict[str, Any]:
        s = self.size
        return {"capacity": self.capacity, "n": self.n, "size": s, "pos": self.pos,
                "message_dim": self.message_dim,
                **{k: getattr(self, k)[:s].clone() for k in self.fields}}

    @classmethod
    def from_state(cls, state: dict[str, Any]) -> "ReplayBuffer":
        buf = cls(int(state["capacity"]), int(state["n"]), int(state["obs"].shape[-1]),
                  int(state.get("message_dim", 0)))
        s = int(state["size"])
        for k in buf.fields:
            if k in state:  # a checkpoint of an older carl-sumo has no cost: 0
                getattr(buf, k)[:s] = torch.as_tensor(state[k])
        buf.size, buf.pos = s, int(state["pos"])
        return buf
