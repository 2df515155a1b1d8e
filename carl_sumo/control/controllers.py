"""Follower control: the base acceleration, the controller interface for a_adj, the residual sum.

On the IDM base (the paper's) a CACC follower applies
``a = clip(a_IDM(o) + clip(a_adj, ±adj_max), acc_min, acc_max)``. On a classical base named as in
:mod:`carl_sumo.control.cacc` (e.g. ``ploeg-tuned:h=1``, see :func:`base_controller`) the learned a_adj
enters that controller's law as a feed-forward term (:class:`carl_sumo.control.cacc.PloegController`). The
adjustment comes from a :class:`Controller`, which receives the observations of every follower of
the platoon at once (rows ordered head to tail), so a communication-aware policy can pass messages
along the platoon. The per-step arithmetic is compiled with numba: it runs in the 0.1 s SUMO loop
millions of times, where NumPy's per-call overhead on 10-element arrays would dominate.
"""

from __future__ import annotations

import math
from dataclasses import replace
from functools import lru_cache
from typing import Protocol

import numpy as np
from numba import njit

from carl_sumo.control.cacc import PloegController, is_ploeg_name, ploeg_controller
from carl_sumo.config import BOUNDS, DT_S, IDM, ControlBounds, IDMParams
from carl_sumo.errors import InputError

IDM_BASE = "idm"
"""The name of the paper's base model: a_base = a_IDM(o)."""

_EPS = 1e-6  # smallest gap in the IDM interaction term (m), as SUMO's NUMERICAL_EPS


@njit(cache=True)
def _idm(v: float, s: float, dv: float, a: float, b: float, v0: float, s0: float, t: float,
         delta: float) -> float:
    s_star = s0 + max(v * t - v * dv / (2.0 * math.sqrt(a * b)), 0.0)
    ratio = s_star / max(s, _EPS)
    return a * (1.0 - (v / v0) ** delta - ratio * ratio)


@njit(cache=True)
def _total_acceleration(obs, adj, a, b, v0, s0, t, delta, acc_min, acc_max, adj_max):
    n = obs.shape[0]
    out = np.empty(n)
    for i in range(n):
        base = _idm(obs[i, 0], obs[i, 2], obs[i, 3], a, b, v0, s0, t, delta)
        out[i] = min(max(base + min(max(adj[i], -adj_max), adj_max), acc_min), acc_max)
    return out


@lru_cache(maxsize=16)
def _params(p: IDMParams, bounds: ControlBounds) -> tuple[float, ...]:
    return (p.accel_mps2, p.decel_mps2, p.desired_speed_mps, p.min_gap_m, p.time_headway_s,
            p.delta, bounds.acc_min_mps2, bounds.acc_max_mps2, bounds.adj_max_mps2)


def idm_acceleration(speed: np.ndarray, gap: np.ndarray, rel_speed: np.ndarray,
                     p: IDMParams = IDM) -> np.ndarray:
    """IDM acceleration (m/s²) from speed v (m/s), bumper gap s (m), Δv = v_pred - v (m/s).

    a = a_max·[1 - (v/v0)^δ - (s*/s)²],  s* = s0 + max(0, v·T - v·Δv / (2·sqrt(a_max·b))),
    the same expression as SUMO's ``MSCFModel_IDM`` with one update per step. Unclipped.
    """
    speed, gap, rel_speed = np.broadcast_arrays(*(np.asarray(x, float) for x in
                                                  (speed, gap, rel_speed)))
    return np.array([_idm(v, s, dv, p.accel_mps2, p.decel_mps2, p.desired_speed_mps, p.min_gap_m,
                          p.time_headway_s, p.delta) for v, s, dv in
                     zip(speed.ravel(), gap.ravel(), rel_speed.ravel())]).reshape(speed.shape)


def total_acceleration(obs: np.ndarray, adjustment: np.ndarray, p: IDMParams = IDM,
                       bounds: ControlBounds = BOUNDS) -> np.ndarray:
    """a = clip(a_IDM(o) + clip(a_adj, ±adj_max), acc_min, acc_max) per follower (m/s²).

    ``obs`` rows are [v, a, d, Δv] (shape (n, 4), float64); ``adjustment`` has shape (n,).
    """
    return _total_acceleration(obs, np.asarray(adjustment, dtype=np.float64), *_params(p, bounds))


def adjustment_bounds(adj_max: float) -> ControlBounds:
    """The vehicle bounds with the learned adjustment bounded by ``adj_max`` (m/s²) instead of
    the default: a policy's own bound (its tanh output never exceeds it), so that a policy
    trained with ``--adj-max`` above 3 m/s² is applied as it was trained."""
    return replace(BOUNDS, adj_max_mps2=max(float(adj_max), BOUNDS.adj_max_mps2))


@njit(cache=True)
def _shield(obs, adj, ttc_s):
    out = adj.copy()
    for i in range(obs.shape[0]):
        closing = -obs[i, 3]  # v_i - v_pred (m/s)
        if closing > 0.0 and obs[i, 2] < ttc_s * closing and out[i] > 0.0:
            out[i] = 0.0
    return out


def shield_adjustment(obs: np.ndarray, adjustment: np.ndarray, ttc_s: float) -> np.ndarray:
    """The learned adjustment with a safety shield: a follower closing in on the vehicle ahead
    with a time to collision d/(v - v_pred) below ``ttc_s`` (s) may not be pushed forward by it
    (a_adj > 0 becomes 0); it may still brake more. ``ttc_s`` 0: no shield. ``obs`` rows
    [v, a, d, Δv, ...] (m/s, m/s², m, m/s), ``adjustment`` (m/s², shape (n,))."""
    adjustment = np.asarray(adjustment, dtype=np.float64)
    if ttc_s <= 0.0:
        return adjustment
    return _shield(np.ascontiguousarray(obs, dtype=np.float64), adjustment, float(ttc_s))


def base_controller(name: str) -> PloegController | None:
    """The controller giving a_base for a base name: None for IDM (computed from o alone by
    :func:`total_acceleration`), a fresh :class:`PloegController` (it has state) for a Ploeg
    name; InputError for anything else, or a bad option or missing tuned gains."""
    if name == IDM_BASE:
        return None
    if is_ploeg_name(name):
        return ploeg_controller(name)
    raise InputError(f"unknown base model {name!r}; choose idm or a Ploeg CACC "
                     "(ploeg, ploeg:h=H:kp=KP:kd=KD, ploeg-tuned:h=H)")


def decision_steps(base: PloegController | None) -> int:
    """Simulation steps (0.1 s) per decision of the learned term on ``base`` (None: IDM): S/0.1
    for a base whose learned gap is held ``gh=S`` s (:mod:`carl_sumo.control.cacc`), else 1."""
    return 1 if base is None else base.hold_steps


def hold_steps(name: str) -> int:
    """:func:`decision_steps` of the base named ``name``."""
    return decision_steps(base_controller(name))


def check_base(name: str) -> str:
    """``name`` if it names a base model (``idm`` or a Ploeg controller name); InputError if not."""
    base_controller(name)
    return name


class AheadAcceleration:
    """a_ahead (m/s², shape (n,)): the acceleration of the vehicle directly ahead of each
    follower over the last step, as the follower measures it itself (the change of v + Δv, its
    radar's speed of the vehicle ahead): for a follower behind another follower that is the
    predecessor's a (o's second column), for the head the NGSIM leader's (0 at the first step).
    It is what a single-predecessor CACC such as Ploeg's feeds forward (``--observe-ahead``).
    Call it exactly once per observation, in order; :meth:`reset` at every episode start."""

    def __init__(self) -> None:
        self._leader_speed: float | None = None

    def reset(self) -> None:
        self._leader_speed = None

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        leader_speed = float(obs[0, 0] + obs[0, 3])
        a_lead = 0.0 if self._leader_speed is None else (leader_speed - self._leader_speed) / DT_S
        self._leader_speed = leader_speed
        return np.concatenate([[a_lead], obs[:-1, 1]])


class CommandHistory:
    """The vehicles' own last k commands (m/s², columns (n, k), the latest first; 0 before the
    first step): what the base law with its learned term sent to the powertrain, which a lagged
    plant with dead time has not realised yet (Lin et al. 2019: a car-follower under actuator lag
    and delay needs its recent commands in its state; ``train --command-history K``). With
    ``ids`` the rows belong to vehicle IDs (mixed traffic, where the CACC vehicles of a step
    change); :meth:`reset` at every episode start, :meth:`push` once per step."""

    def __init__(self, k: int):
        self.k = k
        self._rows = np.zeros((0, k))
        self._by_id: dict[str, np.ndarray] = {}

    def reset(self, n: int = 0) -> None:
        self._rows = np.zeros((n, self.k))
        self._by_id = {}

    def columns(self, ids: list[str] | None = None) -> np.ndarray:
        """The history (n, k) of the platoon, or of the vehicles ``ids`` in that order."""
        if ids is None:
            return self._rows
        return np.array([self._by_id.get(v, np.zeros(self.k)) for v in ids]).reshape(-1, self.k)

    def push(self, command: np.ndarray, ids: list[str] | None = None) -> None:
        """Record this step's commands (n,) (of the vehicles ``ids``)."""
        if ids is None:
            self._rows[:, 1:] = self._rows[:, :-1]
            self._rows[:, 0] = command
            return
        for v, u in zip(ids, np.asarray(command, float).tolist()):
            row = self._by_id.get(v, np.zeros(self.k))
            self._by_id[v] = np.concatenate([[u], row[:-1]])


class Controller(Protocol):
    """Computes the acceleration adjustment a_adj of every follower of a platoon."""

    name: str

    def reset(self, n_followers: int) -> None:
        """Called at the start of each episode with the platoon length."""

    def adjustment(self, obs: np.ndarray) -> np.ndarray:
        """a_adj (m/s², shape (n,)) from the observations (shape (n, 4), head first)."""


class AccelerationController(Protocol):
    """A controller that sets the whole acceleration (a classical CACC, or a learned adjustment
    on a classical base), not an adjustment of IDM."""

    name: str

    def reset(self, n_followers: int) -> None:
        """Called at the start of each episode with the platoon length."""

    def acceleration(self, obs: np.ndarray) -> np.ndarray:
        """a (m/s², shape (n,), within the bounds) from the observations (shape (n, 4))."""


def applied_acceleration(controller: Controller | AccelerationController,
                         obs: np.ndarray) -> np.ndarray:
    """The acceleration (m/s², shape (n,)) a controller makes the followers apply this step:
    its own for an :class:`AccelerationController`, a_IDM + a_adj for a :class:`Controller`
    (within the controller's ``bounds`` when it has them, e.g. a policy trained with a larger
    adjustment bound, else :data:`carl_sumo.config.BOUNDS`)."""
    if hasattr(controller, "acceleration"):
        return controller.acceleration(obs)
    return total_acceleration(obs, controller.adjustment(obs),
                              bounds=getattr(controller, "bounds", BOUNDS))


class ZeroAdjustment:
    """Plain IDM: no adjustment (the ``idm-external`` controller)."""

    name = "idm-external"

    def reset(self, n_followers: int) -> None:
        self._zeros = np.zeros(n_followers)

    def adjustment(self, obs: np.ndarray) -> np.ndarray:
        return self._zeros
