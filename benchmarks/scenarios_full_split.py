"""Issue 35's criterion on the full NGSIM test split: the product CA-RL against its own tuned
CACC through every manoeuvre, 10 followers, scenario seed 0; manoeuvre columns paired over the
events in which both did the manoeuvre (as ``evaluate --suite scenarios``). Real plant
(``--plant real --warmup 60``): ``policies/ca_td3_real_react_10.pt`` against the reaction-layer
base ``ploeg:h=0.8:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2``; ideal plant (the recorded start):
``policies/ca_td3_ploeg_10.pt`` against ``ploeg-tuned:h=0.8``.

Writes ``docs/results_scenarios/full_split_<PLANT>.md`` (a table per manoeuvre) and
``full_split_<PLANT>.json`` (the aggregates, no per-event rows). About 40 minutes on 2 cores.

Usage: python benchmarks/scenarios_full_split.py DATA [real|ideal]
"""
import json
import sys
import time
from pathlib import Path

from carl_sumo.data import load_events
from carl_sumo.files import write_text_atomic
from carl_sumo.sim.scenario import KINDS, ScenarioSpec
from carl_sumo.sim.sumo import DEFAULT_NET
from carl_sumo.study.scenario_tables import (REAL_WARMUP_S, ROBUST_TTC,
                                             markdown_scenario_table, paired,
                                             plant_impairments, result_of, run_jobs)

OUT = Path("docs/results_scenarios")
CONTROLLERS = {"real": (ROBUST_TTC, "policies/ca_td3_real_react_10.pt"),
               "ideal": ("ploeg-tuned:h=0.8", "policies/ca_td3_ploeg_10.pt")}
N_FOLLOWERS = 10


def main(data: str, plant: str = "real") -> None:
    events = load_events(data, "test")
    if plant == "real":
        events = [e.with_warmup(REAL_WARMUP_S) for e in events]
    imp, controllers = plant_impairments(plant), CONTROLLERS[plant]
    start = time.perf_counter()
    tables, lines = {}, []
    for kind in KINDS:
        spec = ScenarioSpec(kind, seed=0)
        rows = run_jobs([(name, spec, imp, events) for name in controllers], N_FOLLOWERS,
                        str(DEFAULT_NET), workers=2, chunks=2)
        results = paired([result_of(name, spec, r, N_FOLLOWERS)
                          for name, r in zip(controllers, rows)])
        tables[kind] = [{k: v for k, v in r.items() if k != "events"} for r in results]
        n = results[0]["manoeuvre"].get("paired_events")
        table = markdown_scenario_table(results).replace(
            "the same with its reaction layer ttc=2 s",
            "Ploeg h=0.8 s, aw=1, ha=1.4 s, ttc=2 s (the base)")
        lines += [f"## {kind}, {plant} plant ({n} paired events)", "", table, ""]
        print(f"{kind}: {time.perf_counter() - start:.0f} s", flush=True)
    wall = time.perf_counter() - start
    stem = f"full_split_{plant}"
    start_text = "60 s settled start" if plant == "real" else "the recorded start"
    head = [f"# Scenarios on the full NGSIM test split, {plant} plant ({len(events)} events)", "",
            f"`python benchmarks/scenarios_full_split.py {data} {plant}` ({wall:.0f} s), 10 "
            f"followers, {start_text}, scenario seed 0. Manoeuvre columns are paired over "
            "the events in which both controllers did the manoeuvre; `done` is each one's own "
            "count.", ""]
    write_text_atomic(OUT / f"{stem}.md", "\n".join(head + lines))
    write_text_atomic(OUT / f"{stem}.json", json.dumps(
        {"data": data, "plant": plant, "events": len(events),
         "wall_time_s": wall, "tables": tables}, indent=2, allow_nan=True, default=float))


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2] if len(sys.argv) > 2 else "real")
