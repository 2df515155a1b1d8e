"""The generalisation bars of the real-plant recipes (docs/results.md, "The product on the real
plant"): controllers on the real plant from a 60 s settled start, under conditions that training
and selection did not use:

- ``train_10``: every training event (773; the safety bar: 0 collisions, no more TTC < 1.5 s
  samples than the base);
- ``test_20``: the test split with 20 followers; ``test_50``: its first 100 events with 50;
- ``fleet_70_trucks``: the test split, 10 followers, 70 % trucks (training drew 0-50 %);
- ``stop_and_go``: the synthetic stop-and-go leader, 10 followers;
- ``us101``: the US-101 events (cross-site), 10 followers.

Writes ``docs/results_real/generalise_<label>.json`` ({condition: {controller: metrics}}) and
prints one table per condition.

Usage: python benchmarks/real_plant_generalise.py LABEL CONTROLLER[,CONTROLLER...] [DATA [CONDITION,...]]
"""
import json
import sys
from pathlib import Path

from carl_sumo.control.channel import Impairments
from carl_sumo.data import load_events
from carl_sumo.experiments.simulate import simulate
from carl_sumo.files import write_text_atomic
from carl_sumo.sim.vehicle import REAL_COMM_DELAY_S, REAL_PLANT, Plant

OUT = Path("docs/results_real")
KEYS = ("headway_s", "jerk_mps3", "dampening_ratio", "worst_successive_ratio", "speed_mps",
        "ttc_lt_1_5s_count", "collisions")
REAL = Impairments(delay_s=REAL_COMM_DELAY_S, plant=REAL_PLANT)
TRUCKS = Impairments(delay_s=REAL_COMM_DELAY_S, plant=Plant((("car", 0.3), ("truck", 0.7))))


def conditions(data: str) -> dict:
    """{name: (events, followers, impairments)} of every condition."""
    def events(split: str, source: str = data):
        return [e.with_warmup(60.0) for e in load_events(source, split)]

    test = events("test")
    return {"train_10": (events("train"), 10, REAL),
            "test_20": (test, 20, REAL), "test_50": (test[:100], 50, REAL),
            "fleet_70_trucks": (test, 10, TRUCKS),
            "stop_and_go": (events("all", "stop-and-go"), 10, REAL),
            "us101": (events("us101"), 10, REAL)}


def main() -> None:
    label, names = sys.argv[1], sys.argv[2].split(",")
    data = sys.argv[3] if len(sys.argv) > 3 else "../shared/data/ngsim/ngsim_cf_events.csv.gz"
    path = OUT / f"generalise_{label}.json"
    rows = json.loads(path.read_text()) if path.exists() else {}
    only = sys.argv[4].split(",") if len(sys.argv) > 4 else None
    for cond, (events, n, imp) in conditions(data).items():
        if only is not None and cond not in only:
            continue
        for name in names:
            if name in rows.get(cond, {}):
                continue
            m = simulate(name, events, n, workers=2, impairments=imp)["metrics"]
            rows.setdefault(cond, {})[name] = {"events": len(events), **{k: m[k] for k in KEYS}}
            print(cond, name, rows[cond][name], flush=True)
            OUT.mkdir(parents=True, exist_ok=True)
            write_text_atomic(path, json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
