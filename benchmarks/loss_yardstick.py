"""What V2V loss costs the classical laws on the real plant: the yardstick of a learned design
that carries what a vehicle's neighbours heard when its own message is lost (issue 55).

Every law holds a lost message for its timeout (1 s), fades it over 1 s into its fallback, then
drives as an ACC at ``ha`` (docs/robustness.md, the channel); with ``df=1`` it feeds forward
the acceleration ahead its radar measures in place of the lost message (a degraded CACC). This
runs ``mpf-tuned``, the gap-traded law and ``product-base``, and the first two with ``df=1``, on
all 773 training events (real plant, its 0.1 s V2V
delay, 10 followers, 60 s settled start) with Gilbert-Elliott losses of 0-50 % in bursts of 5
steps (0.5 s) on average, and writes ``docs/results_real/loss_<SPLIT>.json``.

    python benchmarks/loss_yardstick.py DATA [WORKERS] [SPLIT]   # SPLIT: train (default) or test

On the training split it sizes a design; ``test`` scores the laws once on the test split
(``docs/results_real/loss_test.json``).
"""
from __future__ import annotations

import json
import sys
from pathlib import Path

from carl_sumo.control.channel import Impairments
from carl_sumo.control.ploeg_names import PRESETS
from carl_sumo.data import load_events
from carl_sumo.experiments.simulate import simulate
from carl_sumo.files import write_text_atomic
from carl_sumo.sim.vehicle import REAL_COMM_DELAY_S, REAL_PLANT

OUT = "docs/results_real/loss_{}.json"
MPF_TUNED = ("mpf:h=0.6:kp=0.0445:kd=1:r=3:w1=0.5:w2=0.4:w3=0.1:aw=1:ha=1.4:ttc=2:rb=1:gn=6:op=2:"
             "ht=0.8")
"""``mpf-tuned`` by its full name (an option can be added to it)."""
GAP_TRADED = ("mpf:h=0.5:kp=0.0445:kd=1:r=3:w1=0.5:w2=0.4:w3=0.1:aw=1:ha=2.3:ttc=2:rb=1:gn=6:op=2:"
              "ht=0.8")
"""The gap-traded law (docs/baselines.md): cars 0.5 s, head 2.3 s."""
LAWS = {"mpf-tuned": "mpf-tuned", "gap-traded": GAP_TRADED,
        "product-base": PRESETS["product-base"], "mpf-tuned df=1": MPF_TUNED + ":df=1",
        "gap-traded df=1": GAP_TRADED + ":df=1"}
LOSSES = (0.0, 0.1, 0.3, 0.5)
"""The share of messages lost (-)."""
BURST = 5.0
"""The mean length of a loss burst (steps of 0.1 s)."""
KEYS = ("headway_s", "jerk_mps3", "dampening_ratio", "ttc_lt_1_5s_count", "collisions")


def main(data: str, workers: int = 1, split: str = "train") -> None:
    events = [e.with_warmup(60.0) for e in load_events(data, split)]
    out = Path(OUT.format(split))
    rows = json.loads(out.read_text()) if out.exists() else {}
    for label, law in LAWS.items():
        for loss in LOSSES:
            key = f"{label} loss {loss:g}"
            if key not in rows:
                imp = Impairments(delay_s=REAL_COMM_DELAY_S, plant=REAL_PLANT, loss=loss,
                                  burst=BURST if loss else 1.0)
                m = simulate(law, events, 10, workers=workers, impairments=imp)["metrics"]
                rows[key] = {k: m[k] for k in KEYS}
                write_text_atomic(out, json.dumps(rows, indent=1))
            r = rows[key]
            print(f"{key}: headway {r['headway_s']:.3f} s, jerk {r['jerk_mps3']:.4f}, dampening "
                  f"{r['dampening_ratio']:.4f}, TTC < 1.5 s {r['ttc_lt_1_5s_count']}, collisions "
                  f"{r['collisions']}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1], *(int(a) if i == 0 else a for i, a in enumerate(sys.argv[2:])))
