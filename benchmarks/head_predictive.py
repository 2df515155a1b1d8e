"""How much of the head's room (benchmarks/head_bound.py) a head that only knows the leader's
past can take: a receding-horizon plan against the leader's speed as predicted from its last
10 s (issue 55: is anticipation from the past worth a learned design?).

The predictor: least squares of the leader's speed change over the next 1-10 s on its speed now
and its changes over the last 0.5-10 s (:data:`PAST`), fitted on training events that are not
scored here. Fitted on every other training event and tested on the rest it explains 51 % of
the variance of the change over 1 s, 36 % over 2 s, 22 % over 5 s and 19 % over 10 s
(``python benchmarks/head_predictive.py --predictability DATA``).

The head: every ``REPLAN`` steps it plans its next :data:`HORIZON` steps as a quadratic programme
(OSQP), least Σ a² + w_j Σ j² + w_s Σ (d - s0 - h·v)² against the predicted leader, never closer
than the floor the classical head kept (its smallest time gap, as the bound), applies the plan's
first ``REPLAN`` steps to a double integrator behind the real leader and plans again. With no
feasible plan it brakes at 3 m/s². Its ‖a_1‖/‖a_0‖, jerk, mean gap and smallest time gap against
the classical head's and the bound's on the same events.

    python benchmarks/head_predictive.py DATA [EVENTS] [W_S] [FLOOR_S] [PREDICT]
    # the first EVENTS training events; PREDICT 0: the leader predicted to keep its speed
    python benchmarks/head_predictive.py --sine W_S   # its first link's gain on a sine leader

Training events only (the first EVENTS scored, the predictor fitted on the others).
"""
from __future__ import annotations

import sys

import numpy as np
import osqp
from scipy import sparse

from benchmarks.head_bound import GAP_TRADE, MOVING_MPS, STANDSTILL_M, head_plan
from carl_sumo.control.channel import plant_impairments
from carl_sumo.data import load_events
from carl_sumo.experiments.simulate import event_trajectories
from carl_sumo.sim.metrics import acceleration_norms

PAST = (5, 10, 20, 30, 50, 70, 100)
"""How far back the predictor looks at the leader's speed change (steps of 0.1 s)."""
HORIZON = 100
"""Steps of each plan (10 s)."""
REPLAN = 5
"""Steps between two plans (0.5 s)."""
HEAD_GAP_S = 2.3
"""h of the plan's spacing term: the gap-traded law's head."""
JERK_WEIGHT = 1.0
"""w_j (s²)."""


def features(v: np.ndarray, t: int) -> np.ndarray:
    """The predictor's inputs at step ``t``: the speed now, its changes over :data:`PAST`, 1."""
    return np.array([v[t]] + [v[t] - v[max(t - p, 0)] for p in PAST] + [1.0])


def fit_predictor(events) -> np.ndarray:
    """Least-squares weights (inputs x :data:`HORIZON`) of the speed change 1..HORIZON steps
    ahead, from every 10th step of each event with a full horizon ahead."""
    X, Y = [], []
    for e in events:
        v = e.leader_speed_mps
        for t in range(0, len(v) - HORIZON, 10):
            X.append(features(v, t))
            Y.append(v[t + 1:t + 1 + HORIZON] - v[t])
    W, *_ = np.linalg.lstsq(np.array(X), np.array(Y), rcond=None)
    return W


def _plan(v_hat, v, d, a_prev, h_floor, w_s, dt):
    """The plan's accelerations (HORIZON,) from speed ``v``, gap ``d`` and the acceleration
    ``a_prev`` it applies now (the plan's first jerk is from it) behind ``v_hat`` (HORIZON + 1,),
    or None when no plan keeps the floor."""
    n = HORIZON + 1
    eye = sparse.eye(n, format="csc")
    diff = (sparse.eye(n - 1, n, k=1) - sparse.eye(n - 1, n)).tocsc() / dt
    jerk = (sparse.eye(n - 2, n - 1, k=1) - sparse.eye(n - 2, n - 1)).tocsc() / dt @ diff
    spacing = sparse.hstack([-HEAD_GAP_S * eye, eye])  # d - h v (its target s0)
    p_v = dt ** 2 * (diff.T @ diff + JERK_WEIGHT * (jerk.T @ jerk))
    P = 2.0 * (sparse.block_diag([p_v, sparse.csc_matrix((n, n))]) + w_s * spacing.T @ spacing)
    q = -2.0 * w_s * STANDSTILL_M * np.asarray(spacing.sum(axis=0)).ravel()
    start = np.zeros(2 * n)  # (a_0 - a_prev)/dt with a_0 = (v_1 - v_0)/dt
    start[0], start[1] = -1.0 / dt ** 2, 1.0 / dt ** 2
    P = P + 2.0 * JERK_WEIGHT * dt ** 2 * sparse.csc_matrix(np.outer(start, start))
    q = q - 2.0 * JERK_WEIGHT * dt ** 2 * (a_prev / dt) * start
    dyn = sparse.hstack([dt * sparse.eye(n - 1, n, k=1),
                         sparse.eye(n - 1, n, k=1) - sparse.eye(n - 1, n)])
    first = sparse.csc_matrix(([1.0, 1.0], ([0, 1], [0, n])), shape=(2, 2 * n))
    floor = sparse.hstack([-h_floor * eye, eye])
    speed = sparse.hstack([eye, sparse.csc_matrix((n, n))])
    A = sparse.vstack([dyn, first, floor, speed], format="csc")
    lo = np.concatenate([dt * v_hat[1:], [v, d], np.full(n, STANDSTILL_M), np.zeros(n)])
    hi = np.concatenate([dt * v_hat[1:], [v, d], np.full(n, np.inf), np.full(n, np.inf)])
    solver = osqp.OSQP()
    solver.setup(P=sparse.csc_matrix(P), q=q, A=A, l=lo, u=hi, verbose=False, eps_abs=1e-5,
                 eps_rel=1e-5, max_iter=20_000, polish=False)
    res = solver.solve()
    if res.info.status not in ("solved", "solved inaccurate"):
        return None
    return np.diff(res.x[:n]) / dt


def run_head(v0, v_start, d_start, h_floor, W, w_s, dt=0.1):
    """The predictive head's speeds and gaps behind the real leader speeds ``v0``."""
    n = v0.size
    v, d = np.empty(n), np.empty(n)
    v[0], d[0] = v_start, d_start
    plan, k, a, failed = None, 0, 0.0, 0
    for t in range(n - 1):
        if t % REPLAN == 0:
            v_hat = np.concatenate([[v0[t]], v0[t] + features(v0, t) @ W])
            plan, k = _plan(v_hat, v[t], d[t], a, h_floor, w_s, dt), 0
            if plan is None:  # below the floor already: plan from where it is
                failed += 1
                now = (d[t] - STANDSTILL_M) / max(v[t], MOVING_MPS)
                plan = _plan(v_hat, v[t], d[t], a, max(min(h_floor, now) - 0.1, 0.0), w_s, dt)
        a = -3.0 if plan is None else plan[k]
        k += 1
        v[t + 1] = max(v[t] + a * dt, 0.0)
        d[t + 1] = d[t] + dt * (v0[t + 1] - v[t + 1])
    return v, d, failed


def main(data: str, n_events: int = 100, w_s: float = 0.01, floor_s: float | None = None,
         predict: float = 1.0) -> None:
    """``predict`` 0: the same head planning against a leader that keeps its speed (what the
    predictor adds)."""
    train = load_events(data, "train")
    W = predict * fit_predictor(train[n_events:])
    events = [e.with_warmup(60.0) for e in train[:n_events]]
    rows = []
    for e, traj in event_trajectories(GAP_TRADE, events, 10, impairments=plant_impairments("real")):
        v0, v1, d1 = traj.leader_speed, traj.speed[:, 0], traj.gap[:, 0]
        moving = v1 > MOVING_MPS
        h_floor = max(float(np.min((d1[moving] - STANDSTILL_M) / v1[moving])), 0.0) \
            if moving.any() else 0.0
        if floor_s is not None:  # a floor of its own (the bound's too), below the law's
            h_floor = min(h_floor, floor_s)
        a0 = acceleration_norms(traj)[0]
        v, d, failed = run_head(v0, float(v1[0]), float(d1[0]), h_floor, W, w_s)
        bound = head_plan(v0, float(v1[0]), float(d1[0]), float(d1.mean()), h_floor, 1.0)
        gap_s = (d[v > MOVING_MPS] - STANDSTILL_M) / v[v > MOVING_MPS]
        rows.append({"law": acceleration_norms(traj)[1] / a0,
                     "predictive": float(np.sqrt(np.sum((np.diff(v) / 0.1) ** 2)) / a0),
                     "bound": float(np.sqrt(np.sum((np.diff(bound) / 0.1) ** 2)) / a0),
                     "jerk_law": float(np.mean(np.abs(np.diff(v1, n=2)))) / 0.01,
                     "jerk_predictive": float(np.mean(np.abs(np.diff(v, n=2)))) / 0.01,
                     "gap_law": float(d1.mean()), "gap_predictive": float(d.mean()),
                     "min_gap_s": float(gap_s.min()) if gap_s.size else np.nan,
                     "floor_s": h_floor, "failed": failed})
    m = {k: float(np.nanmean([r[k] for r in rows])) for k in rows[0]}
    print(f"first {len(rows)} training events, w_s = {w_s:g}, predictor x{predict:g}: ‖a1‖/‖a0‖ law {m['law']:.3f}, "
          f"predictive head {m['predictive']:.3f} ({100 * (m['predictive'] / m['law'] - 1):+.1f} "
          f"%), bound {m['bound']:.3f}; head jerk {m['jerk_law']:.4f} / {m['jerk_predictive']:.4f}"
          f" m/s³; mean gap {m['gap_law']:.1f} / {m['gap_predictive']:.1f} m; smallest time gap "
          f"{m['min_gap_s']:.2f} s (floor {m['floor_s']:.2f} s); plans without a feasible "
          f"solution {m['failed']:.1f} per event")


def sine_gains(w_s: float, omegas=(0.02, 0.05, 0.1, 0.2, 0.4, 0.8), dt: float = 0.1) -> dict:
    """The planning head (a leader predicted to keep its speed) behind a leader at 20 m/s ±
    0.5 m/s: its peak acceleration over the leader's at each ω (rad/s), after 120 s, over three
    periods (a first link's |Γ|; above 1: it amplifies)."""
    out = {}
    for om in omegas:
        t = np.arange(int((3 * 2 * np.pi / om + 120) / dt)) * dt
        v0 = 20.0 + 0.5 * np.sin(om * t)
        v, _, _ = run_head(v0, 20.0, STANDSTILL_M + HEAD_GAP_S * 20.0, 1.5,
                           np.zeros((len(PAST) + 2, HORIZON)), w_s)
        k = int(120 / dt)
        out[om] = float(np.abs(np.diff(v)[k:]).max() / np.abs(np.diff(v0)[k:]).max())
    return out


def predictability(data: str) -> None:
    """R² of the predictor on held-out training events (every other event), per horizon."""
    train = load_events(data, "train")
    W = fit_predictor(train[0::2])
    X, Y = [], []
    for e in train[1::2]:
        v = e.leader_speed_mps
        for t in range(0, len(v) - HORIZON, 10):
            X.append(features(v, t))
            Y.append(v[t + 1:t + 1 + HORIZON] - v[t])
    X, Y = np.array(X), np.array(Y)
    for k in (10, 20, 50, 100):
        y, p = Y[:, k - 1], X @ W[:, k - 1]
        print(f"{k / 10:g} s ahead: R² {1 - np.sum((y - p) ** 2) / np.sum(y ** 2):.3f}")


if __name__ == "__main__":
    if sys.argv[1:2] == ["--predictability"]:
        predictability(sys.argv[2])
    elif sys.argv[1:2] == ["--sine"]:  # --sine W_S
        print({om: round(g, 3) for om, g in sine_gains(float(sys.argv[2])).items()})
    else:
        main(sys.argv[1], *(int(a) if i == 0 else float(a) for i, a in enumerate(sys.argv[2:])))

