"""Metrics of a run with a manoeuvre (:mod:`carl_sumo.manoeuvres.spec`): the manoeuvre's own and the
whole run's.

A :class:`ScenarioTrace` holds, every 0.1 s, each vehicle that was in the platoon lane behind the
leader (columns; NaN while it is elsewhere): speed (m/s), bumper gap to its predecessor there (m)
and the predecessor's speed (m/s). t_m = ``done_step``: the step the manoeuvre was complete (the
entering vehicle in the platoon lane, the leaving one out of it, the merge's link made). The
vehicles **behind it** are those in the platoon lane behind the entering vehicle, behind the gap
the leaving one left, or the merge's second platoon (a joiner at the tail: the joiner itself);
the **first** of them is the one directly behind.

Per manoeuvre (:func:`manoeuvre_metrics`), over the samples from t_m on:

- ``min_gap_m``: the smallest bumper gap of a vehicle behind it (m);
- ``min_ttc_s``: the smallest TTC = gap / (v - v_pred) of a vehicle behind it while it closes in
  (v > v_pred) (s; inf if none closes in);
- ``peak_decel_mps2`` / ``peak_jerk_mps3``: the largest deceleration max(-a) and |jerk| of the
  vehicles behind it (per vehicle in ``peak_decel_by_vehicle`` / ``peak_jerk_by_vehicle``), with
  a_k = (v_{k+1} - v_k)/dt and j_k = (a_{k+1} - a_k)/dt as :mod:`carl_sumo.sim.metrics`; from
  ``start_step`` on where the manoeuvre has one (a signalled cut-in: the human's first signal,
  from when the follower behind may brake for him), else from t_m;
- ``settle_s``: how long after t_m the first vehicle's bumper gap d stays within 10 % of its
  steady state d_ss, the mean gap over the run's last 2 s (s; NaN when less than 4 s follow t_m).
  The gap, not the time gap d/v: a follower that brakes to a near stop behind a cut-in has a time
  gap without meaning; a change of the leader's speed in those last seconds moves d_ss with it;
- ``overshoot``: how far that gap passes d_ss on the other side from where it started, as a share
  of d_ss (a gap that opens after a cut-in: (max d - d_ss)/d_ss; one that closes after a cut-out
  or a merge: (d_ss - min d)/d_ss; 0 if it does not pass);
- ``collisions``: vehicles whose gap reached 0 or less from t_m on (the run ends there; a
  collision before the manoeuvre counts in the whole run's, not here).

Over the whole run (:func:`whole_run_metrics`): the keys of :mod:`carl_sumo.sim.metrics` over the
platoon's CACC vehicles (followers and a joiner) while they are in the platoon lane, from the
event's ``scored_from`` on; the dampening ratio over the members present in every scored sample;
``worst_successive_ratio`` is NaN (the order of the chain changes).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from carl_sumo.config import DT_S, HEADWAY_MIN_SPEED_MPS
from carl_sumo.sim.metrics import METRIC_KEYS

SETTLE_BAND = 0.1
"""A gap is settled within this share of its steady state (-)."""
STEADY_WINDOW_S = 2.0
"""The steady state is the mean gap over the run's last this many seconds (s)."""
MANOEUVRE_KEYS = ("done", "min_gap_m", "min_ttc_s", "peak_decel_mps2", "peak_jerk_mps3",
                  "settle_s", "overshoot", "collisions")


@dataclass
class ScenarioTrace:
    """What one event with a manoeuvre produced (see the module docstring); arrays (T, m)."""

    event_id: str
    manoeuvre: str
    leader_speed: np.ndarray
    vehicles: list[str]
    members: list[str]
    speed: np.ndarray
    gap: np.ndarray
    pred_speed: np.ndarray
    done_step: int | None
    behind: list[str] = field(default_factory=list)
    collisions: int = 0
    scored_from: int = 0
    dt: float = DT_S
    start_step: int | None = None

    def column(self, vid: str) -> int:
        return self.vehicles.index(vid)


def _acc(speed: np.ndarray, dt: float) -> np.ndarray:
    return np.diff(speed, axis=0) / dt


def settle_and_overshoot(series: np.ndarray, dt: float = DT_S) -> tuple[float, float]:
    """(settle time s, overshoot share) of one series from t_m on (see the module docstring;
    NaN samples are left out); NaN, NaN when fewer samples than two steady-state windows."""
    series = np.asarray(series, float)
    valid = np.flatnonzero(np.isfinite(series))
    window = int(round(STEADY_WINDOW_S / dt))
    if len(valid) < 2 * window:
        return float("nan"), float("nan")
    x = series[valid]
    steady = float(np.mean(x[-window:]))
    outside = valid[np.abs(x - steady) > SETTLE_BAND * abs(steady)]
    settle = 0.0 if outside.size == 0 else float((outside[-1] + 1) * dt)
    if steady <= 0:
        return settle, float("nan")
    if x[0] < steady:
        overshoot = max(0.0, float(x.max()) - steady) / steady
    else:
        overshoot = max(0.0, steady - float(x.min())) / steady
    return settle, overshoot


def manoeuvre_metrics(trace: ScenarioTrace) -> dict:
    """The manoeuvre's metrics (module docstring); NaN values when it did not happen."""
    nan = float("nan")
    done = trace.done_step is not None
    out: dict = {"done": int(done), "collisions": int(trace.collisions) if done else 0}
    behind = [trace.column(v) for v in trace.behind if v in trace.vehicles]
    if trace.done_step is None or not behind:
        out.update(min_gap_m=nan, min_ttc_s=nan, peak_decel_mps2=nan, peak_jerk_mps3=nan,
                   settle_s=nan, overshoot=nan, peak_decel_by_vehicle={},
                   peak_jerk_by_vehicle={})
        return out
    t = trace.done_step
    gap = trace.gap[t:, behind]
    closing = trace.speed[t:, behind] - trace.pred_speed[t:, behind]
    with np.errstate(divide="ignore", invalid="ignore"):
        ttc = np.where(closing > 0, gap / closing, np.inf)
    t0 = t if trace.start_step is None else min(trace.start_step, t)
    acc = _acc(trace.speed[:, behind], trace.dt)[t0:]
    jerk = np.abs(np.diff(_acc(trace.speed[:, behind], trace.dt), axis=0))[t0:] / trace.dt
    decel = {trace.vehicles[c]: _finite_max(-acc[:, j], floor=0.0) for j, c in enumerate(behind)}
    jerks = {trace.vehicles[c]: _finite_max(jerk[:, j]) for j, c in enumerate(behind)}
    settle, overshoot = settle_and_overshoot(trace.gap[t:, behind[0]], trace.dt)
    out.update(min_gap_m=_finite_min(gap), min_ttc_s=_finite_min(ttc[ttc > 0], empty=np.inf),
               peak_decel_mps2=max(decel.values()), peak_jerk_mps3=_finite_max(
                   np.array(list(jerks.values()))),
               settle_s=settle, overshoot=overshoot, peak_decel_by_vehicle=decel,
               peak_jerk_by_vehicle=jerks)
    return out


def _finite_min(x: np.ndarray, empty: float = float("nan")) -> float:
    x = np.asarray(x, float)
    x = x[~np.isnan(x)]
    return float(x.min()) if x.size else empty


def _finite_max(x: np.ndarray, floor: float | None = None) -> float:
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if not x.size:
        return float("nan")
    return float(max(x.max(), floor)) if floor is not None else float(x.max())


def whole_run_metrics(trace: ScenarioTrace) -> dict:
    """The whole run's metrics over the platoon's CACC vehicles (module docstring), with the
    sample counts :func:`carl_sumo.sim.metrics.aggregate` pools them by."""
    cols = [trace.column(v) for v in trace.members if v in trace.vehicles]
    first = min(trace.scored_from, len(trace.leader_speed) - 1)
    v = trace.speed[first:, cols]
    d = trace.gap[first:, cols]
    pred = trace.pred_speed[first:, cols]
    moving = np.isfinite(v) & (v > HEADWAY_MIN_SPEED_MPS)
    headway = d[moving] / v[moving]
    acc = _acc(v, trace.dt)
    jerk = np.abs(np.diff(acc, axis=0)) / trace.dt
    jerk = jerk[np.isfinite(jerk)]
    closing = v - pred
    with np.errstate(divide="ignore", invalid="ignore"):
        ttc = np.where(closing > 0, d / closing, np.inf)
    valid = np.isfinite(ttc) & (ttc > 0)
    leader_norm = float(np.sqrt(np.sum(_acc(trace.leader_speed[first:], trace.dt) ** 2)))
    whole = np.all(np.isfinite(v), axis=0)
    norms = np.sqrt(np.sum(acc[:, whole] ** 2, axis=0))
    speeds = v[np.isfinite(v)]
    nan = float("nan")
    out = {
        "event_id": trace.event_id,
        "headway_s": float(headway.mean()) if headway.size else nan,
        "jerk_mps3": float(jerk.mean()) if jerk.size else nan,
        "speed_mps": float(speeds.mean()) if speeds.size else nan,
        "ttc_lt_4s_count": int(np.sum(valid & (ttc < 4.0))),
        "ttc_lt_1_5s_count": int(np.sum(valid & (ttc < 1.5))),
        "dampening_ratio": float(np.mean(norms / leader_norm)) if leader_norm > 0 and norms.size
        else nan,
        "worst_successive_ratio": nan,
        "collisions": int(trace.collisions),
        "n_headway": int(headway.size), "n_jerk": int(jerk.size), "n_speed": int(speeds.size),
    }
    assert set(METRIC_KEYS) <= set(out)
    return out


def aggregate_manoeuvres(per_event: list[dict]) -> dict[str, float]:
    """Manoeuvre metrics over events: how many were done, the smallest gap and TTC, how many
    events had a TTC below 1.5 s, the mean (and largest) peak deceleration and jerk, the mean
    settle time (over the events that settle) and overshoot, the summed collisions."""
    done = [e for e in per_event if e["done"]]

    def values(key: str) -> np.ndarray:
        x = np.array([e[key] for e in done], float)
        return x[~np.isnan(x)]

    def mean(key: str) -> float:
        x = values(key)
        x = x[np.isfinite(x)]
        return float(x.mean()) if x.size else float("nan")

    gaps, ttcs = values("min_gap_m"), values("min_ttc_s")
    decel, jerk = values("peak_decel_mps2"), values("peak_jerk_mps3")
    nan = float("nan")
    return {
        "events": len(per_event), "done": len(done),
        "min_gap_m": float(gaps.min()) if gaps.size else nan,
        "mean_min_gap_m": float(gaps.mean()) if gaps.size else nan,
        "min_ttc_s": float(ttcs.min()) if ttcs.size else nan,
        "ttc_lt_1_5s_events": int(np.sum(ttcs < 1.5)),
        "peak_decel_mps2": mean("peak_decel_mps2"),
        "max_peak_decel_mps2": float(decel.max()) if decel.size else nan,
        "peak_jerk_mps3": mean("peak_jerk_mps3"),
        "max_peak_jerk_mps3": float(jerk.max()) if jerk.size else nan,
        "settle_s": mean("settle_s"),
        "overshoot": mean("overshoot"),
        "collisions": int(sum(e["collisions"] for e in per_event)),
    }
