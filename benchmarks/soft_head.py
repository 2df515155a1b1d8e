"""A soft head for the strongest classical CACC: how much of the head's room (benchmarks/
head_bound.py) a causal law takes, chosen on the training split.

The head of a chain (behind a human: no V2V) runs the Ploeg law as an ACC at ``ha`` with the
leader's measured acceleration fed forward. Its own gains (``pa``, ``da``) and the weight of
that feed-forward (``fa``) are options of every constant-time-gap law (docs/models.md); below
1 the head leaves more of the leader's motion to its slow spacing terms and lets its long gap
breathe. This runs the gap-traded multi-predecessor law (cars 0.5 s, head 2.3 s) with a grid of
(``da``, ``fa``) on all 773 training events (real plant, 10 followers, 60 s settled start) and
keeps the one with the least dampening among those with no more collisions and TTC < 1.5 s
samples than the law itself (its 2 and 2 are the two events that start 0.05-0.08 m apart).

    python benchmarks/soft_head.py DATA [WORKERS]     # writes docs/results_real/soft_head_train.json

The test split then scores the chosen law once (`carl-sumo simulate ... --controller LAW`).
"""
from __future__ import annotations

import json
import sys
import time
from pathlib import Path

from carl_sumo.control.channel import plant_impairments
from carl_sumo.data import load_events
from carl_sumo.experiments.simulate import simulate
from carl_sumo.files import write_text_atomic

OUT = Path("docs/results_real/soft_head_train.json")
LAW = "mpf:h=0.5:kp=0.0445:kd=1:r=3:w1=0.5:w2=0.4:w3=0.1:aw=1:ha=2.3:{}ttc=2:rb=1:gn=6:op=2:ht=0.8"
"""The gap-traded law (docs/results.md), the head's options where ``{}`` is."""
DA = (1.0, 0.3, 0.2)
"""The head's kd (1/s; 1: the law's own)."""
FA = (1.0, 0.5, 0.25)
"""The weight of the leader's measured acceleration in the head's law (1: the law's own)."""
KEYS = ("headway_s", "jerk_mps3", "dampening_ratio", "worst_successive_ratio",
        "ttc_lt_4s_count", "ttc_lt_1_5s_count", "collisions")


def name(da: float, fa: float) -> str:
    """The gap-traded law with the head's kd ``da`` and feed-forward weight ``fa``."""
    head = (f"da={da:g}:" if da != 1.0 else "") + (f"fa={fa:g}:" if fa != 1.0 else "")
    return LAW.format(head)


def chosen(rows: dict) -> str:
    """The least dampening among the laws no less safe than the gap-traded law itself."""
    ref = rows[name(1.0, 1.0)]
    safe = [k for k, m in rows.items() if m["collisions"] <= ref["collisions"]
            and m["ttc_lt_1_5s_count"] <= ref["ttc_lt_1_5s_count"]]
    return min(safe, key=lambda k: rows[k]["dampening_ratio"])


def main(data: str, workers: int = 1) -> None:
    events = [e.with_warmup(60.0) for e in load_events(data, "train")]
    rows = json.loads(OUT.read_text())["laws"] if OUT.exists() else {}
    for da in DA:
        for fa in FA:
            law = name(da, fa)
            if law in rows:
                continue
            start = time.perf_counter()
            m = simulate(law, events, 10, workers=workers,
                         impairments=plant_impairments("real"))["metrics"]
            rows[law] = {**{k: m[k] for k in KEYS}, "wall_s": time.perf_counter() - start}
            print(f"da={da:g} fa={fa:g}: " + ", ".join(f"{k} {rows[law][k]:.4g}" for k in KEYS),
                  flush=True)
            write_text_atomic(OUT, json.dumps({"events": len(events), "laws": rows}, indent=1))
    best = chosen(rows)
    write_text_atomic(OUT, json.dumps({"events": len(events), "laws": rows, "chosen": best},
                                      indent=1))
    print("chosen:", best, rows[best])


if __name__ == "__main__":
    main(sys.argv[1], *(int(a) for a in sys.argv[2:]))
