"""How much of the NGSIM leader's motion could a platoon's head absorb at all, at the gaps the
strongest classical CACC keeps? A bound for every design that smooths at the head (issue 55).

The dampening ratio (docs/metrics.md) is the mean over followers of ‖a_i‖₂ / ‖a_0‖₂, and behind
a string-stable chain each follower moves at most as much as the one ahead, so the chain's head
(the first follower, behind a human: no V2V) decides most of it. A controller at the head that
knew the leader's whole future could not do better than the plan that minimises

    Σ_k a_k² + w · Σ_k ((a_{k+1} - a_k)/dt)²      (its acceleration's energy, and jerk at weight w)

over the event, from the classical head's own start (speed, gap), with no gap below the classical
head's own smallest time gap (d_k ≥ s0 + h_floor·v_k: never closer than it came) and the same
mean gap (Σ d_k ≤ Σ d_k of the classical head: the same headway). The vehicle is a double
integrator: realised accelerations are the plan's own, so lag and dead time, which only smooth
what a command can realise, are left out and the number is a lower bound for any controller at
the head on the real plant, learned or classical, causal or not. A quadratic programme per event
(OSQP, sparse: the speeds and gaps are variables with the sampled dynamics as equalities).

Against it: the head of the classical law run in SUMO on the same events (real plant, 60 s
settled start, 10 followers), its ‖a_1‖/‖a_0‖ and its mean |jerk|. What that leaves for a
head that anticipates (its ratio minus the bound's) is the room a state-dependent head has; the
platoon's dampening moves by about that room times the chain's own transmission (its followers'
ratios over the head's, measured and printed).

    python benchmarks/head_bound.py DATA [EVENTS] [LAW]   # first EVENTS training events (100)

Default LAW: the gap-traded multi-predecessor law (cars 0.5 s, head 2.3 s), the best classical
CACC at the product's headway (docs/results.md). Training events only: this chooses a design.
"""
from __future__ import annotations

import sys

import numpy as np
import osqp
from scipy import sparse

from carl_sumo.control.channel import plant_impairments
from carl_sumo.data import load_events
from carl_sumo.experiments.simulate import event_trajectories
from carl_sumo.sim.metrics import acceleration_norms

GAP_TRADE = "mpf:h=0.5:kp=0.0445:kd=1:r=3:w1=0.5:w2=0.4:w3=0.1:aw=1:ha=2.3:ttc=2:rb=1:gn=6:op=2:ht=0.8"
STANDSTILL_M = 2.0
"""s0 of the floor d ≥ s0 + h_floor·v (m), the laws' standstill gap."""
MOVING_MPS = 1.0
"""The classical head's smallest time gap is taken over samples at least this fast (m/s)."""
JERK_WEIGHTS = (0.0, 0.1, 1.0)
"""w of the objective (s²): acceleration energy alone, and with its jerk."""


def head_plan(v0: np.ndarray, v_start: float, d_start: float, mean_gap_m: float,
              h_floor_s: float, jerk_weight: float, dt: float = 0.1) -> np.ndarray:
    """The head's speeds (N,) of least Σ a² + w Σ j² behind leader speeds ``v0`` (N,), from
    ``v_start``/``d_start``, with d ≥ s0 + h_floor·v, v ≥ 0 and mean gap ≤ ``mean_gap_m``.
    Variables [v (N), d (N)]; a_k = (v_{k+1} - v_k)/dt; d_{k+1} = d_k + dt·(v0_{k+1} - v_{k+1})
    (the position update of SUMO's Euler step)."""
    n = v0.size
    eye = sparse.eye(n, format="csc")
    diff = (sparse.eye(n - 1, n, k=1) - sparse.eye(n - 1, n)).tocsc() / dt  # a = D v
    jerk = (sparse.eye(n - 2, n - 1, k=1) - sparse.eye(n - 2, n - 1)).tocsc() / dt @ diff
    p_v = 2.0 * dt ** 2 * (diff.T @ diff + jerk_weight * (jerk.T @ jerk))  # scaled by dt²
    P = sparse.block_diag([p_v, sparse.csc_matrix((n, n))], format="csc")
    q = np.zeros(2 * n)
    # dynamics: d_{k+1} - d_k + dt·v_{k+1} = dt·v0_{k+1}
    dyn = sparse.hstack([dt * sparse.eye(n - 1, n, k=1),
                         sparse.eye(n - 1, n, k=1) - sparse.eye(n - 1, n)])
    first = sparse.csc_matrix(([1.0, 1.0], ([0, 1], [0, n])), shape=(2, 2 * n))
    floor = sparse.hstack([-h_floor_s * eye, eye])  # d - h v ≥ s0
    mean = sparse.csc_matrix(np.concatenate([np.zeros(n), np.full(n, 1.0 / n)])[None, :])  # mean d
    speed = sparse.hstack([eye, sparse.csc_matrix((n, n))])
    A = sparse.vstack([dyn, first, floor, mean, speed], format="csc")
    lo = np.concatenate([dt * v0[1:], [v_start, d_start], np.full(n, STANDSTILL_M), [-np.inf],
                         np.zeros(n)])
    hi = np.concatenate([dt * v0[1:], [v_start, d_start], np.full(n, np.inf), [mean_gap_m],
                         np.full(n, np.inf)])
    solver = osqp.OSQP()
    solver.setup(P=P, q=q, A=A, l=lo, u=hi, verbose=False, eps_abs=1e-5, eps_rel=1e-5,
                 max_iter=400_000, polish=True)
    res = solver.solve()
    if res.info.status not in ("solved", "solved inaccurate"):
        raise RuntimeError(f"head plan: OSQP {res.info.status}")
    return np.asarray(res.x[:n])


def _jerk(v: np.ndarray, dt: float) -> float:
    return float(np.mean(np.abs(np.diff(v, n=2) / dt ** 2)))


def event_bound(traj, dt: float = 0.1) -> dict:
    """The classical head's and the bound's ratios and jerks on one event's trajectory."""
    v0, v1, d1 = traj.leader_speed, traj.speed[:, 0], traj.gap[:, 0]
    moving = v1 > MOVING_MPS
    h_floor = float(np.min((d1[moving] - STANDSTILL_M) / v1[moving])) if moving.any() else 0.0
    h_floor = max(h_floor, 0.0)
    norms = acceleration_norms(traj)
    row = {"event_id": traj.event_id, "h_floor_s": h_floor, "law_head": norms[1] / norms[0],
           "law_platoon": float(np.mean(norms[1:] / norms[0])),
           "law_head_jerk": _jerk(v1, dt), "law_platoon_jerk": float(np.mean(
               np.abs(np.diff(traj.speed, n=2, axis=0) / dt ** 2)))}
    a0 = norms[0]
    for w in JERK_WEIGHTS:
        v = head_plan(v0, float(v1[0]), float(d1[0]), float(d1.mean()), h_floor, w, dt)
        row[f"bound_head_w{w:g}"] = float(np.sqrt(np.sum((np.diff(v) / dt) ** 2)) / a0)
        row[f"bound_jerk_w{w:g}"] = _jerk(v, dt)
    return row


def main(data: str, n_events: int = 100, law: str = GAP_TRADE) -> None:
    events = [e.with_warmup(60.0) for e in load_events(data, "train", limit=n_events)]
    rows = []
    for e, traj in event_trajectories(law, events, 10, impairments=plant_impairments("real")):
        rows.append(event_bound(traj))  # run_event returns the scored part
    mean = {k: float(np.mean([r[k] for r in rows])) for k in rows[0] if k != "event_id"}
    print(f"{law} on the first {len(rows)} training events (real plant, 10 followers, 60 s "
          f"settled start)")
    print(f"classical head: ‖a1‖/‖a0‖ {mean['law_head']:.3f}, jerk {mean['law_head_jerk']:.4f} "
          f"m/s³; platoon dampening {mean['law_platoon']:.3f}, jerk "
          f"{mean['law_platoon_jerk']:.4f}; its smallest time gap (the floor) "
          f"{mean['h_floor_s']:.2f} s on average")
    for w in JERK_WEIGHTS:
        print(f"bound, w = {w:g} s²: head ‖a1‖/‖a0‖ {mean[f'bound_head_w{w:g}']:.3f} "
              f"({100 * (mean[f'bound_head_w{w:g}'] / mean['law_head'] - 1):+.1f} %), jerk "
              f"{mean[f'bound_jerk_w{w:g}']:.4f} m/s³ "
              f"({100 * (mean[f'bound_jerk_w{w:g}'] / mean['law_head_jerk'] - 1):+.1f} %)")


if __name__ == "__main__":
    main(sys.argv[1], *(int(a) if i == 0 else a for i, a in enumerate(sys.argv[2:])))
