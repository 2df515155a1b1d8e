"""A soft head for the strongest classical CACC: how much of the head's room (benchmarks/
head_bound.py) a causal law takes, chosen on the training split.

The head of a chain (behind a human: no V2V) runs the Ploeg law as an ACC at ``ha`` with the
leader's measured acceleration fed forward. Its own gains (``pa``, ``da``) and the weight of
that feed-forward (``fa``) are options of every constant-time-gap law (docs/models.md); below
1 the head leaves more of the leader's motion to its slow spacing terms and lets its long gap
breathe. This runs the gap-traded multi-predecessor law (cars 0.5 s, head 2.3 s) with the heads of
:data:`HEADS` on all 773 training events (real plant, 10 followers, 60 s settled start) and
keeps the one with the least dampening among those string stable in theory (‖Γ_i‖∞ ≤ 1 on every
link, every class at the ends of its ranges, :func:`hinf`) with no more collisions and TTC < 1.5
s samples than the law itself (its 2 and 2 are the two events that start 0.05-0.08 m apart).

    python benchmarks/soft_head.py DATA [WORKERS]     # writes docs/results_real/soft_head_train.json
    python benchmarks/soft_head.py --theory           # the heads whose first link is string stable
    python benchmarks/soft_head.py --oracle DATA      # a head per event against one for all

The test split then scores the chosen law once (`carl-sumo simulate ... --controller LAW`).
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

import numpy as np

from carl_sumo.control.channel import plant_impairments
from carl_sumo.experiments.string_stability import analytic
from carl_sumo.sim.vehicle import REAL_COMM_DELAY_S, Plant
from carl_sumo.data import load_events
from carl_sumo.experiments.simulate import simulate
from carl_sumo.files import write_text_atomic

OUT = Path("docs/results_real/soft_head_train.json")
LAW = "mpf:h=0.5:kp=0.0445:kd=1:r=3:w1=0.5:w2=0.4:w3=0.1:aw=1:ha=2.3:{}ttc=2:rb=1:gn=6:op=2:ht=0.8"
"""The gap-traded law (docs/results.md), the head's options where ``{}`` is."""
HEADS = ((None, None, None), (None, 0.5, None), (None, 0.4, None), (0.02, 0.4, None),
         (0.01, 0.4, None), (0.005, 0.3, None), (None, None, 0.5), (None, None, 0.25),
         (None, 0.3, 0.5))
"""(pa, da, fa) of the head (None: the law's own kp = 0.0445, kd = 1, fa = 1): the string-stable
ones by the first link's theory (fa = 1, kd down to 0.4, 0.3 with kp 0.005), and three below
fa = 1, which amplify (what string stability costs)."""
KEYS = ("headway_s", "jerk_mps3", "dampening_ratio", "worst_successive_ratio",
        "ttc_lt_4s_count", "ttc_lt_1_5s_count", "collisions")
OMEGAS = np.geomspace(0.005, 3.0, 400)
"""Frequencies of the theory's ‖Γ‖∞ (rad/s): the head's amplification sits below 0.05."""


def name(pa: float | None, da: float | None, fa: float | None) -> str:
    """The gap-traded law with the head's kp ``pa``, kd ``da`` and feed-forward weight ``fa``."""
    head = "".join(f"{k}={v:g}:" for k, v in (("pa", pa), ("da", da), ("fa", fa)) if v is not None)
    return LAW.format(head)


def hinf(law: str, n: int = 10, first: int = 0) -> float:
    """The largest |Γ_i| of the law's exact discrete theory over its n links from link
    ``first`` on (0: the head's; 1: the links behind a follower), every class of the real plant
    at both ends of its lag and dead-time ranges (cars in a chain of cars, trucks of trucks:
    ``ht``), the 0.1 s V2V delay."""
    plant = plant_impairments("real").plant
    worst = 0.0
    for cls in plant.classes:
        for tau, dead in plant.class_corners(cls):
            corner = Plant(((cls, 1.0),), tau, dead * 0.1)
            theory = analytic(law, OMEGAS, corner, REAL_COMM_DELAY_S, n)
            worst = max(worst, float(np.max(np.asarray(theory["per_link"]["discrete"])[first:])))
    return worst


def chosen(rows: dict) -> str:
    """The least dampening among the string-stable laws no less safe than the gap-traded law."""
    ref = rows[name(None, None, None)]
    safe = [k for k, m in rows.items() if m["collisions"] <= ref["collisions"]
            and m["ttc_lt_1_5s_count"] <= ref["ttc_lt_1_5s_count"] and m["hinf"] <= 1.0]
    return min(safe, key=lambda k: rows[k]["dampening_ratio"])


def first_link_grid() -> list[tuple[float, float, float, float]]:
    """(pa, da, fa, ‖Γ_1‖∞) of the heads whose first link is string stable in theory, the head
    at ha = 2.3 s on every corner of both classes' ranges, on a grid of the three options."""
    import itertools

    from carl_sumo.control.transfer import gamma_discrete

    plant = plant_impairments("real").plant
    corners = [c for cls in plant.classes for c in plant.class_corners(cls)]
    out = []
    for pa, da, fa in itertools.product((0.0445, 0.03, 0.02, 0.01, 0.005),
                                        (1.0, 0.7, 0.5, 0.4, 0.3, 0.2), (1.0, 0.75, 0.5, 0.25)):
        worst = max(float(np.max(np.abs(gamma_discrete(OMEGAS, 2.3, pa, da, tau, dead,
                                                      first_link=True, lead_weight=fa))))
                    for tau, dead in corners)
        if worst <= 1.0:
            out.append((pa, da, fa, worst))
    return out


def oracle(data: str, events: int = 100) -> None:
    """Per event of the first ``events`` training events, which string-stable head of
    :data:`HEADS` has the least jerk and the least dampening: a choice per event against the
    best single head."""
    from collections import Counter

    evs = [e.with_warmup(60.0) for e in load_events(data, "train", limit=events)]
    heads = [h for h in HEADS if h[2] is None]
    runs = {h: simulate(name(*h), evs, 10, workers=1,
                        impairments=plant_impairments("real"))["events"] for h in heads}
    for key in ("jerk_mps3", "dampening_ratio"):
        best = [min(heads, key=lambda h: runs[h][i][key]) for i in range(len(evs))]
        fixed = {h: float(np.mean([r[key] for r in runs[h]])) for h in heads}
        top = min(fixed, key=fixed.get)
        print(f"{key}: per-event choice {np.mean([runs[b][i][key] for i, b in enumerate(best)]):.4f}"
              f", the best single head {top} {fixed[top]:.4f}; chosen per event: "
              f"{dict(Counter(best))}")


def main(data: str, workers: int = 1) -> None:
    events = [e.with_warmup(60.0) for e in load_events(data, "train")]
    rows = json.loads(OUT.read_text())["laws"] if OUT.exists() else {}
    for head in HEADS:
        law = name(*head)
        if law not in rows:
            start = time.perf_counter()
            m = simulate(law, events, 10, workers=workers,
                         impairments=plant_impairments("real"))["metrics"]
            rows[law] = {**{k: m[k] for k in KEYS}, "wall_s": time.perf_counter() - start}
        rows[law]["hinf"] = hinf(law)
        print(f"pa, da, fa = {head}: " + ", ".join(f"{k} {rows[law][k]:.4g}"
                                                   for k in (*KEYS, "hinf")), flush=True)
        write_text_atomic(OUT, json.dumps({"events": len(events), "laws": rows}, indent=1))
    best = chosen(rows)
    write_text_atomic(OUT, json.dumps({"events": len(events), "laws": rows, "chosen": best},
                                      indent=1))
    print("chosen:", best, rows[best])


if __name__ == "__main__":
    if sys.argv[1:2] == ["--theory"]:
        for row in first_link_grid():
            print("pa %g, da %g, fa %g: first link %.6f" % row)
    elif sys.argv[1:2] == ["--oracle"]:
        oracle(sys.argv[2])
    else:
        main(sys.argv[1], *(int(a) for a in sys.argv[2:]))
