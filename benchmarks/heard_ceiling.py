"""What hearing more of the platoon buys: a ceiling for what a V2V message about the vehicles
ahead can add to the real-plant laws (issue 55, the communication bar).

The product's base already feeds forward the commands of r = 3 vehicles ahead (``mpf-tuned``);
a learned message can at most tell a vehicle what the platoon ahead of it does now. This runs
the multi-predecessor law hearing every vehicle ahead (r = 9 in a platoon of 10; weights that
decay with distance) against r = 3 at both classical points of the real plant (``mpf-tuned``,
cars 0.6 s, head 1.4 s; the gap-traded law, cars 0.5 s, head 2.3 s), on the training events
(real plant, 10 followers, 60 s settled start), with each law's exact discrete ‖Γ‖∞ (every
class at the ends of its ranges, 0.1 s V2V delay, the links behind a follower: the head's is the
same law in every row; ``soft_head.hinf``), and writes
``docs/results_real/heard_ceiling_train.json``.

    python benchmarks/heard_ceiling.py DATA [WORKERS] [EVENTS]   # EVENTS: the first K (all: 773)
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from soft_head import hinf

from carl_sumo.data import load_events
from carl_sumo.experiments.simulate import simulate
from carl_sumo.files import write_text_atomic
from carl_sumo.sim.vehicle import REAL_COMM_DELAY_S, REAL_PLANT
from carl_sumo.control.channel import Impairments

OUT = Path("docs/results_real/heard_ceiling_train.json")
POINTS = {"mpf-tuned": (0.6, 1.4), "gap-traded": (0.5, 2.3)}
"""The laws' car gap h and head gap ha (s); trucks keep 0.8 s."""
LAW = "mpf:h={h}:ha={ha}:kp=0.0445:kd=1:aw=1:ttc=2:rb=1:gn=6:op=2:ht=0.8:{weights}"
DECAYS = (0.4, 0.55, 0.6, 0.65, 0.7)
"""Every vehicle ahead heard, the k-th with a weight proportional to DECAY**k (-)."""


def decaying(q: float, r: int = 9) -> tuple[float, ...]:
    """Weights of r commands proportional to q**k, to 3 decimals, summing to 1 (w1 takes the
    rounding)."""
    w = [q ** k for k in range(r)]
    w = [round(x / sum(w), 3) for x in w]
    return (round(1 - sum(w[1:]), 3), *w[1:])


WEIGHTS = {"r=3 (tuned)": (0.5, 0.4, 0.1), **{f"r=9, decay {q:g}": decaying(q) for q in DECAYS}}
"""Weights of the commands of the vehicles ahead, the nearest first."""
KEYS = ("headway_s", "jerk_mps3", "dampening_ratio", "worst_successive_ratio",
        "ttc_lt_1_5s_count", "collisions")


def law(point: str, weights: tuple[float, ...]) -> str:
    h, ha = POINTS[point]
    ws = ":".join(f"w{i + 1}={w:g}" for i, w in enumerate(weights))
    return LAW.format(h=h, ha=ha, weights=f"r={len(weights)}:{ws}")


def main(data: str, workers: int = 1, first: int | None = None) -> None:
    events = [e.with_warmup(60.0) for e in load_events(data, "train")][:first]
    imp = Impairments(delay_s=REAL_COMM_DELAY_S, plant=REAL_PLANT)
    rows = json.loads(OUT.read_text()) if OUT.exists() else {}
    for point in POINTS:
        for label, weights in WEIGHTS.items():
            key = f"{point}, {label}, {len(events)} events"
            if key not in rows:
                name = law(point, weights)
                m = simulate(name, events, 10, workers=workers, impairments=imp)["metrics"]
                rows[key] = {"law": name, **{k: m[k] for k in KEYS}, "hinf_followers": hinf(name, first=1)}
                write_text_atomic(OUT, json.dumps(rows, indent=1))
            r, ref = rows[key], rows[f"{point}, r=3 (tuned), {len(events)} events"]
            print(f"{key}: headway {r['headway_s']:.3f} s, jerk {r['jerk_mps3']:.4f} "
                  f"({r['jerk_mps3'] / ref['jerk_mps3'] - 1:+.1%}), dampening "
                  f"{r['dampening_ratio']:.4f} ({r['dampening_ratio'] / ref['dampening_ratio'] - 1:+.1%}), "
                  f"TTC < 1.5 s {r['ttc_lt_1_5s_count']}, collisions {r['collisions']}, "
                  f"‖Γ‖∞ behind a follower {r['hinf_followers']:.6f}", flush=True)


if __name__ == "__main__":
    if len(sys.argv) < 2:
        sys.exit(__doc__)
    main(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 1,
         int(sys.argv[3]) if len(sys.argv) > 3 else None)
