"""A safety constraint on training: the Lagrange multiplier of the close-call cost (RCPO).

Reward Constrained Policy Optimization (Tessler, Mankowitz and Mannor, ICLR 2019) trains on the
penalised reward r - λ·c and raises the multiplier λ by dual ascent while the policy's cost rate
is above the rate the constraint allows, lowering it (not below 0) while it is under:

    λ ← clip(λ + η·(c̄ - α), 0, λ_max)      once per vector step, from ``learning_starts`` on,

with c the per-vehicle, per-step safety cost of :func:`carl_sumo.learn.reward.critical_cost`
(1 for 0 < TTC < 1.5 s or a collision), c̄ its mean over the step's vehicles and environments,
and η ``train --lagrange-lr``. The replay buffer stores c apart from r, so every update prices
old transitions at the current λ. The allowed rate α is measured, not chosen: the cost rate of
the steps before ``learning_starts``, when the base drives with the same exploration noise on the
same training events (0 if there are none). So the constraint reads "no more close calls than
the base", the bar the trained policy is selected and judged by.
"""

from __future__ import annotations

import numpy as np
import torch

LAGRANGE_MAX = 10.0
"""The largest λ (per unit of cost): ten times the critical-TTC term of the real-plant recipes
(``--w-critical 1``, as much as the spacing term's cap), so a constraint the exploration noise
alone breaks cannot drive the penalty, and the critic's scale, without bound."""


class CostMultiplier:
    """λ of the module docstring; ``lr`` = η (0: off, λ stays 0)."""

    def __init__(self, lr: float, learning_starts: int, state: dict | None = None):
        self.lr, self.learning_starts = float(lr), int(learning_starts)
        self.value, self._sum, self._count = 0.0, 0.0, 0
        if state:
            self.value = float(state["value"])
            self._sum, self._count = float(state["sum"]), int(state["count"])

    @property
    def target(self) -> float:
        """α: the cost rate measured before ``learning_starts`` (0 without those steps)."""
        return self._sum / self._count if self._count else 0.0

    @property
    def active(self) -> bool:
        return self.lr > 0

    def observe(self, step: int, cost: np.ndarray) -> None:
        """The costs of vector step ``step`` (any shape): before ``learning_starts`` they
        measure α, from then on they move λ."""
        if not self.active:
            return
        if step < self.learning_starts:
            self._sum += float(np.sum(cost))
            self._count += int(np.size(cost))
            return
        self.value = float(np.clip(self.value + self.lr * (float(np.mean(cost)) - self.target),
                                   0.0, LAGRANGE_MAX))

    def penalise(self, batch: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """A replay batch with its reward r - λ·c (the batch itself while λ = 0)."""
        if self.value > 0:
            batch["reward"] = batch["reward"] - self.value * batch["cost"]
        return batch

    def logged(self) -> dict[str, float]:
        """What the learning curve records of it: λ (nothing while off)."""
        return {"lagrange": self.value} if self.active else {}

    def state(self) -> dict[str, float]:
        """What a checkpoint keeps, so that a resumed run goes on with the same λ and α."""
        return {"value": self.value, "target": self.target, "sum": self._sum,
                "count": self._count}
