"""The paper's per-vehicle reward (parameters in :class:`carl_sumo.config.RewardConfig`).

r = w_gap·r_gap + w_safe·r_safe + w_comfort·r_comfort, per follower and step:
r_gap = lognormal pdf of the time headway h = d/v (μ = 0.4226, σ = 0.4366; largest at
exp(μ - σ²) ≈ 1.26 s), r_safe = log(TTC/4 s) for 0 < TTC ≤ 4 s (else 0), r_comfort =
-min((jerk/jerk_scale)², 1) (jerk_scale 60 m/s³ by default: the normalised jerk lies in [-1, 1]
for accelerations within ±3 m/s²), and ``collision_penalty`` for a follower whose gap d ≤ 0.
An optional control-effort term -w_accel·a² (a in m/s²; w_accel = 0, i.e. off, by default) is
this project's addition: it rewards attenuating the leader's accelerations (string stability).
So is the optional spacing term -w_spacing·min((e/v)², 1) (off by default): e = d - s0 - h_s·v is
the spacing error of a constant-time-gap policy (m), e/v its time-gap error (s, v floored at 1 m/s);
with ``spacing_budget`` every follower is priced the platoon's mean e/v instead (a headway budget:
a learned gap policy may give one follower more than its h_s where another keeps less);
the head (row 0, which hears no message from a human leader) may have its own time gap h_head
(the degraded CACC's ``ha``, control/cacc.py), and so may a heavy vehicle, one whose own largest
braking is below 7 m/s² (the law's ``ht``, control/cacc.py; the head keeps h_head).
It holds a learned term on a CACC base at a chosen time gap instead of the human headway.
So is the optional critical-TTC term -w_critical per follower and step with 0 < TTC < 1.5 s (off
by default): the samples that the metric ``ttc_lt_1_5s_count`` counts (sim/metrics.py), priced
in the reward where r_safe's log(TTC/4 s) is only -0.98 at 1.5 s.
So is the optional amplification term -w_amplify·max(a_i² - a_{i-1}², 0) (off by default): a
follower that accelerates or brakes harder than its predecessor (a in m/s², the realised ones)
passes a disturbance on larger, the per-step form of string stability's ‖a_i‖ ≤ ‖a_{i-1}‖. The
head (row 0) has none: its predecessor is the human leader, whose acceleration it does not hear.
Compiled with numba because it runs every 0.1 s step.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numba import njit

from carl_sumo.config import DT_S, REWARD, RewardConfig
from carl_sumo.control.ploeg_names import HEAVY_BRAKING_MPS2

_SQRT_2PI = math.sqrt(2.0 * math.pi)
CRITICAL_TTC_S = 1.5
"""The time to collision below which the critical-TTC term applies (s): the metric's bar."""


@njit(cache=True)
def _headway_reward(h: float, mu: float, sigma: float) -> float:
    h = max(h, 1e-3)
    z = (math.log(h) - mu) / sigma
    return math.exp(-0.5 * z * z) / (h * sigma * _SQRT_2PI)


@njit(cache=True)
def _platoon_reward(obs, prev_acc, gap_s, w_gap, w_safe, w_comfort, w_accel, w_spacing,
                    budget, standstill_m, mu, sigma, ttc_max, jerk_scale, penalty, dt,
                    w_critical, critical_ttc, w_amplify):
    n = obs.shape[0]
    reward = np.empty(n)
    collided = np.zeros(n, dtype=np.bool_)
    mean_error_s = 0.0  # budget: the platoon's mean time-gap error (s)
    if budget and n > 0:
        for i in range(n):
            mean_error_s += (obs[i, 2] - standstill_m - gap_s[i] * obs[i, 0]) / max(obs[i, 0], 1.0)
        mean_error_s /= n
    for i in range(n):
        v, a, d, dv = obs[i, 0], obs[i, 1], obs[i, 2], obs[i, 3]
        r = w_gap * _headway_reward(d / max(v, 0.1), mu, sigma)
        if dv < 0.0:
            ttc = max(d, 1e-3) / -dv
            if ttc <= ttc_max:
                r += w_safe * math.log(ttc / ttc_max)
            if d > 0.0 and ttc < critical_ttc:
                r -= w_critical
        jerk = (a - prev_acc[i]) / dt / jerk_scale
        r -= w_comfort * min(jerk * jerk, 1.0) + w_accel * a * a
        if w_spacing > 0.0:
            gap_error_s = mean_error_s if budget else \
                (d - standstill_m - gap_s[i] * v) / max(v, 1.0)
            r -= w_spacing * min(gap_error_s * gap_error_s, 1.0)
        if w_amplify > 0.0 and i > 0:
            excess = a * a - obs[i - 1, 1] * obs[i - 1, 1]
            if excess > 0.0:
                r -= w_amplify * excess
        if d <= 0.0:
            collided[i] = True
            r += penalty
        reward[i] = r
    return reward, collided


@lru_cache(maxsize=16)
def _params(cfg: RewardConfig) -> tuple[float, ...]:
    return (cfg.w_gap, cfg.w_safe, cfg.w_comfort, cfg.w_accel, cfg.w_spacing,
            cfg.spacing_budget, cfg.spacing_standstill_m, cfg.headway_mu, cfg.headway_sigma,
            cfg.ttc_threshold_s, cfg.jerk_scale_mps3, cfg.collision_penalty, DT_S,
            cfg.w_critical, CRITICAL_TTC_S, cfg.w_amplify)


def critical_cost(obs: np.ndarray) -> np.ndarray:
    """The safety cost of each follower's step (-): 1 for a close call, 0 < TTC < 1.5 s (the
    samples the critical-TTC term prices and ``ttc_lt_1_5s_count`` counts), or a collision
    (d ≤ 0), else 0; ``obs`` rows [v, a, d, Δv] as they are (the true ones, shape (..., 4))."""
    d, dv = obs[..., 2], obs[..., 3]
    close = (d > 0.0) & (dv < 0.0) & (np.maximum(d, 1e-3) < -dv * CRITICAL_TTC_S)
    return (close | (d <= 0.0)).astype(np.float64)


def headway_reward(headway_s: float, cfg: RewardConfig = REWARD) -> float:
    """Lognormal pdf of the time headway h (s)."""
    return _headway_reward(float(headway_s), cfg.headway_mu, cfg.headway_sigma)


def spacing_gaps(cfg: RewardConfig, n: int, b_max_mps2: np.ndarray | None = None) -> np.ndarray:
    """Each follower's time gap h_s in the spacing term (s, shape (n,)): the head's
    ``spacing_head_gap_s``, a heavy vehicle's (largest braking ``b_max_mps2`` below 7 m/s²; None:
    no vehicle is heavy) ``spacing_heavy_gap_s``, every other ``spacing_gap_s`` (None: h_s)."""
    gaps = np.full(n, cfg.spacing_gap_s)
    if cfg.spacing_heavy_gap_s is not None and b_max_mps2 is not None:
        gaps[np.asarray(b_max_mps2) < HEAVY_BRAKING_MPS2] = cfg.spacing_heavy_gap_s
    if n and cfg.spacing_head_gap_s is not None:
        gaps[0] = cfg.spacing_head_gap_s
    return gaps


def platoon_reward(obs: np.ndarray, prev_acc: np.ndarray, cfg: RewardConfig = REWARD,
                   b_max_mps2: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Reward of each follower after a step, and which followers collided (d ≤ 0).

    ``obs`` rows are [v, a, d, Δv] after the step (float64, shape (n, 4)); ``prev_acc`` is a
    before it (m/s²); ``b_max_mps2`` each follower's largest braking (m/s², for a heavy
    vehicle's spacing gap; None: none is heavy).
    """
    gaps = spacing_gaps(cfg, obs.shape[0], b_max_mps2)
    return _platoon_reward(obs, prev_acc, gaps, *_params(cfg))
