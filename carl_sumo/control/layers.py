"""The safety layers over the Ploeg law (:mod:`carl_sumo.control.cacc`), each its own part.

The law gives every vehicle of a chain its acceleration a_i from its state; the layers then bound
it, each on its own, in this order (:func:`apply_layers`), on a chain's arrays (head first):

- :func:`reaction`: ``ttc=T`` (and ``rb=1``): a vehicle without a message (or an armed one)
  brakes when it closes in below the time to collision T;
- :func:`safe_speed`: ``gs=B`` / ``gn=B``: Gipps' safe speed for the vehicle ahead;
- :func:`opening`: ``op=B``: an armed vehicle at the front of its chain opens its gap;
- :func:`merge_point`: with ``gs``/``gn``, reach a zipper merge's point behind the vehicle ahead.

Each bounds ``out`` (m/s²) in place and writes the braking it applied into ``brake`` (m/s², inf:
none), which the vehicle's follower hears as its message; the law's state u is left as it is.
What each layer does and why: the module docstring of :mod:`carl_sumo.control.cacc`. The scenario
inputs (``armed``: vehicles whose layers act although they hear a message, ``merge_m``: distances
to a merge point) reach the layers only, not the law. A layer's parameter 0 turns it off.
"""

from __future__ import annotations

import math
import numpy as np
from numba import njit

REACTION_MARGIN_M = 1.0
"""The reaction layer brakes to keep this much bumper gap when closing in (m)."""
REACTION_LAG_S = 0.5
"""The reaction layer's allowance for dead time and powertrain lag: the gap it counts on is
reduced by the closing speed times this (s; a truck's lag is 0.4-0.6 s, docs/vehicles.md)."""
OPEN_GAP_S = 0.8
"""``op=B``: the time gap an armed vehicle at the front of its chain opens (s; an armed vehicle
stays armed until its spacing reaches it, carl_sumo.manoeuvres.simulation.JOIN_LINK_GAP_S)."""
OPEN_TIME_S = 3.0
"""``op=B``: the opening speed it asks for is the missing gap over this time (m / s)."""
OPEN_SPEED_TIME_S = 1.0
"""``op=B``: it reaches that opening speed with this time constant (s)."""
MERGE_MIN_SPEED_MPS = 0.5
"""Merge point: the speed below which the time to the merge point is taken at this speed (m/s),
so a vehicle at a near stop beside the merge point is bounded by a finite time."""


LAYERS = np.dtype([
    ("ttc_s", np.float64),            # reaction below this time to collision (s)
    ("margin_m", np.float64),         # the gap the reaction keeps (m)
    ("lag_s", np.float64),            # the reaction's and the safe speed's lag allowance (s)
    ("safe_braking", np.float64),     # gs/gn: the braking of Gipps' safe speed (m/s²)
    ("safe_armed_only", np.bool_),    # gn: only an armed vehicle at the front of its chain
    ("opening_braking", np.float64),  # op: the most braking that opens the gap (m/s²)
    ("standstill_m", np.float64),     # s0 of the opening and the merge point (m)
    ("acc_min", np.float64),          # the vehicle's bound (m/s²): no layer brakes harder
])
"""The numbers of a law's layers (0: a layer off): an array of one record (:func:`layer_params`;
numba takes an array at once, a tuple field by field, and this runs every step)."""


def layer_params(ttc_s: float, margin_m: float, lag_s: float, safe_braking: float,
                 safe_armed_only: bool, opening_braking: float, standstill_m: float,
                 acc_min: float) -> np.ndarray:
    """The kernel's ``layers``: a read-only array of one :data:`LAYERS` record."""
    out = np.array([(ttc_s, margin_m, lag_s, safe_braking, safe_armed_only, opening_braking,
                     standstill_m, acc_min)], dtype=LAYERS)
    out.flags.writeable = False
    return out


@njit(cache=True)
def without_message(i, pred_mode):
    """Vehicle ``i`` hears no message from ahead: the head, or a link that is down."""
    return i == 0 or pred_mode[i] == 2


@njit(cache=True)
def reaction(obs, out, brake, pred_mode, armed, a_ahead, u_min, layers):
    """``ttc``: below the time to collision p.ttc_s, (d - margin)/closing speed, a vehicle
    without a message (or an armed one) applies at most -c²/(2·(d - margin - lag·c)) -
    max(-a_ahead, 0), never below its own braking; ``brake`` holds it. Resets ``brake``."""
    p = layers[0]
    for i in range(obs.shape[0]):
        brake[i] = np.inf
        closing = -obs[i, 3]
        if (without_message(i, pred_mode) or armed[i]) and p.ttc_s > 0.0 and closing > 0.0 \
                and obs[i, 2] - p.margin_m < p.ttc_s * closing:
            room = obs[i, 2] - p.margin_m - p.lag_s * closing
            need = closing * closing / (2.0 * room) + max(-a_ahead[i], 0.0) if room > 0.0 \
                else np.inf
            out[i] = max(min(out[i], -need), p.acc_min, u_min[i])  # at most its own braking
            brake[i] = out[i]  # its follower hears the reaction's braking


@njit(cache=True)
def safe_speed(obs, out, brake, pred_mode, armed, u_min, layers):
    """``gs``/``gn``: a guarded vehicle faster than Gipps' safe speed v_safe applies at most
    (v_safe - v)/lag; ``gn`` guards only an armed vehicle at the front of its chain (its vehicle
    ahead a human), ``gs`` also every vehicle without a message."""
    p = layers[0]
    if not p.safe_braking > 0.0:
        return
    for i in range(obs.shape[0]):
        front_armed = i == 0 and armed[i]
        guarded = front_armed if p.safe_armed_only \
            else armed[i] or without_message(i, pred_mode)
        if guarded:
            v, v_ahead = obs[i, 0], max(obs[i, 0] + obs[i, 3], 0.0)
            bl = p.safe_braking * p.lag_s
            v_safe = -bl + math.sqrt(bl * bl + v_ahead * v_ahead
                                     + 2.0 * p.safe_braking * max(obs[i, 2] - p.margin_m, 0.0))
            if v > v_safe:
                out[i] = max(min(out[i], (v_safe - v) / p.lag_s), p.acc_min, u_min[i])
                brake[i] = min(brake[i], out[i])


@njit(cache=True)
def opening(obs, out, brake, armed, u_min, layers):
    """``op``: an armed vehicle at the front of its chain, short of s0 + OPEN_GAP_S·v, asks for
    the vehicle ahead to draw away at the missing gap over OPEN_TIME_S, applying at most
    (Δv - that)/OPEN_SPEED_TIME_S, never below -opening_braking."""
    p = layers[0]
    if not p.opening_braking > 0.0 or obs.shape[0] == 0 or not armed[0]:
        return
    short = p.standstill_m + OPEN_GAP_S * obs[0, 0] - obs[0, 2]
    if short > 0.0:
        a_open = max((obs[0, 3] - short / OPEN_TIME_S) / OPEN_SPEED_TIME_S, -p.opening_braking)
        if a_open < out[0]:
            out[0] = max(a_open, p.acc_min, u_min[0])
            brake[0] = min(brake[0], out[0])


@njit(cache=True)
def merge_point(obs, out, brake, merge_m, u_min, layers):
    """Merge point (with ``gs``/``gn``): a vehicle ``merge_m`` metres from it whose vehicle ahead
    is still on the other feeding lane applies at most 2·(d - s0 + Δv·t)/t², t = its distance
    over its speed."""
    p = layers[0]
    if not p.safe_braking > 0.0:
        return
    for i in range(obs.shape[0]):
        if merge_m[i] < np.inf:  # reach the merge point s0 behind the other
            t = merge_m[i] / max(obs[i, 0], MERGE_MIN_SPEED_MPS)
            a_merge = 2.0 * (obs[i, 2] - p.standstill_m + obs[i, 3] * t) / (t * t)
            if a_merge < out[i]:
                out[i] = max(a_merge, p.acc_min, u_min[i])
                brake[i] = min(brake[i], out[i])


@njit(cache=True)
def apply_layers(obs, out, brake, pred_mode, armed, a_ahead, merge_m, u_min, layers):
    """Every layer in turn on a chain's law output ``out`` (updated in place, as ``brake``)."""
    reaction(obs, out, brake, pred_mode, armed, a_ahead, u_min, layers)
    safe_speed(obs, out, brake, pred_mode, armed, u_min, layers)
    opening(obs, out, brake, armed, u_min, layers)
    merge_point(obs, out, brake, merge_m, u_min, layers)
