"""Every model parameter and default of carl-sumo, in one place, with units.

The values here are the paper's where it gives them; the rest are documented choices.
``routes/vtypes.add.xml`` carries the same IDM parameters for SUMO's native models.
"""

from __future__ import annotations

from dataclasses import dataclass

from carl_sumo.options import option

DT_S = 0.1
"""Simulation step and data sampling period (s)."""


@dataclass(frozen=True)
class IDMParams:
    """Intelligent Driver Model (Treiber et al. 2000), the paper's parameters."""

    accel_mps2: float = 3.0        # a: maximum acceleration (m/s²)
    decel_mps2: float = 2.0        # b: comfortable deceleration (m/s²)
    desired_speed_mps: float = 120.0 / 3.6  # v0: desired speed, 120 km/h (m/s)
    min_gap_m: float = 2.0         # s0: jam distance, bumper to bumper (m)
    time_headway_s: float = 1.5    # T: desired time headway (s)
    delta: float = 4.0             # δ: acceleration exponent (-)


@dataclass(frozen=True)
class ControlBounds:
    """Bounds on the acceleration a CACC vehicle may apply: a = clip(a_IDM + a_adj)."""

    acc_min_mps2: float = -9.0     # SUMO emergencyDecel of the vehicle types (m/s²)
    acc_max_mps2: float = 3.0      # IDM maximum acceleration a (m/s²)
    adj_max_mps2: float = 3.0      # |a_adj| bound of a learned adjustment (m/s²)


@dataclass(frozen=True)
class RewardConfig:
    """Reward r = w_gap·r_gap + w_safe·r_safe + w_comfort·r_comfort (Zhu et al. 2020 style).

    r_gap: lognormal pdf of the time headway h = d/v, parameters (μ, σ) fitted to NGSIM headways;
    r_safe: log(TTC/4) when 0 < TTC ≤ ttc_threshold_s, else 0;
    r_comfort: -min((jerk / jerk_scale)², 1), jerk = Δa/Δt;
    optionally -w_accel·a² (control effort; 0 = off, the paper's reward);
    optionally -w_spacing·min((e/v)², 1), e = d - s0 - h_s·v (m), the spacing error of a
    constant-time-gap policy with time gap h_s = spacing_gap_s (0 = off, the paper's reward),
    or with spacing_budget the platoon's mean e/v (a headway budget);
    optionally -w_critical for each step with 0 < TTC < 1.5 s (0 = off, the paper's reward);
    optionally -w_amplify·max(a_i² - a_{i-1}², 0) for a follower whose acceleration exceeds its
    predecessor's in magnitude (not the head: its predecessor is the human leader; 0 = off);
    a collision (bumper gap ≤ 0) ends the episode and adds collision_penalty.
    """

    w_gap: float = option(1.0, "weight of the headway term", "reward", low=0.0)
    w_safe: float = option(1.0, "weight of the TTC term", "reward", low=0.0)
    w_comfort: float = option(1.0, "weight of the jerk term", "reward", low=0.0)
    w_accel: float = option(0.0, "weight of the control-effort term -w·a² (0: off)", "reward",
                            low=0.0)
    w_spacing: float = option(0.0, "weight of the spacing term -w·min((e/v)², 1), e = d - 2 m - "
                              "h_s·v (0: off)", "reward", low=0.0)
    spacing_gap_s: float = option(0.8, "the spacing term's time gap h_s", "reward", unit="s",
                                  low=0.0, high=5.0, flag="spacing-gap")
    spacing_head_gap_s: float | None = option(None, "the head's h_s (none: --spacing-gap), e.g. "
                                              "a degraded CACC's ha", "reward", unit="s",
                                              low=0.0, high=5.0, flag="spacing-head-gap")
    spacing_heavy_gap_s: float | None = option(None, "h_s of a vehicle braking below 7 m/s² "
                                               "(none: --spacing-gap)", "reward", unit="s",
                                               low=0.0, high=5.0, flag="spacing-heavy-gap")
    spacing_budget: bool = option(False, "the spacing term prices the platoon's mean time-gap "
                                  "error, a headway budget (one follower may keep more than its "
                                  "h_s where another keeps less), instead of each follower's own",
                                  "reward")
    paired_base: bool = option(False, "on a base that holds its learned gap for whole episodes "
                               "(gh), a decision's reward is its mean reward less the base's "
                               "(a_adj = 0) on the same event and fleet, run first in the same "
                               "worker: common random numbers, an action-free baseline (twice "
                               "the simulation)", "reward")
    spacing_standstill_m: float = option(2.0, "the spacing term's standstill gap s0 (Ploeg's, "
                                         "control/cacc.py)", "reward", unit="m", cli=False)
    w_critical: float = option(0.0, "penalty per follower and step with a time to collision "
                               "below 1.5 s (0: off)", "reward", low=0.0)
    w_amplify: float = option(0.0, "weight of the amplification term -w·max(a_i² - a_(i-1)², 0) "
                              "(0: off)", "reward", low=0.0)
    headway_mu: float = option(0.4226, "μ of ln(h), h the time headway in s", "reward",
                               cli=False)
    headway_sigma: float = option(0.4366, "σ of ln(h)", "reward", cli=False)
    ttc_threshold_s: float = option(4.0, "TTC below which r_safe is negative", "reward",
                                    unit="s", cli=False)
    jerk_scale_mps3: float = option(60.0, "the jerk term's scale ((a_max - a_min)/dt of a "
                                    "±3 m/s² range)", "reward", unit="m/s³", low=0.0,
                                    open_low=True, flag="jerk-scale")
    collision_penalty: float = option(-100.0, "reward of a follower whose gap d ≤ 0 (the "
                                      "episode ends)", "reward", cli=False)


@dataclass(frozen=True)
class ScenarioConfig:
    """How a platoon is placed on the network."""

    ngsim_lane: int = 2            # NGSIM lane of the platoon (1 = leftmost, HOV)
    vehicle_length_m: float = 5.0  # length of every follower (m)
    start_margin_m: float = 10.0   # free road behind the last follower at t = 0 (m)
    end_margin_m: float = 50.0     # road left ahead of the leader at the end of an event (m)


IDM = IDMParams()
BOUNDS = ControlBounds()
REWARD = RewardConfig()
SCENARIO = ScenarioConfig()

HEADWAY_MIN_SPEED_MPS = 0.5
"""Samples slower than this are left out of the time-headway mean (h = d/v is undefined at 0)."""
