"""What a cut-in met, for two controllers on the same events: for each event, when the human
was in the platoon lane (t_m, s), the speed of the follower behind it (m/s), the gap it was
left (m) and the smallest gap after it (m), and whether it collided. A cut-in starts at the first
step from its drawn time at which the gap has room (docs/scenarios.md), so a controller that
follows closer meets it later, at another speed: the events in which only one of two controllers
collides are read with this beside the criterion of ``benchmarks/scenarios_full_split.py``.

Real plant, 60 s settled start, 10 followers, scenario seed 0 (as the full-split tables); the
events of the test or the training split, by ID.

Usage: python benchmarks/cutin_entry.py DATA CONTROLLER_A CONTROLLER_B EVENT_ID[,EVENT_ID...]
"""
import sys

import numpy as np

from carl_sumo.control.channel import plant_impairments
from carl_sumo.data import load_events
from carl_sumo.manoeuvres.spec import ScenarioSpec
from carl_sumo.sim.sumo import DEFAULT_NET
from carl_sumo.experiments.suite import REAL_WARMUP_S
from carl_sumo.manoeuvres.runs import run_scenario_event, scenario_controller, scenario_sim


def entry(name: str, events: list, spec: ScenarioSpec) -> dict[str, dict]:
    """event ID -> what the cut-in met under controller ``name``."""
    follower_model, controller = scenario_controller(name, "real")
    sim = scenario_sim(str(DEFAULT_NET), follower_model)
    out = {}
    for event in events:
        trace = run_scenario_event(sim, event, 10, spec.draw(event, 10), controller,
                                   plant_impairments("real"))
        t = trace.done_step
        if t is None:
            out[event.event_id] = {"done": False}
            continue
        column = trace.column(trace.behind[0])
        gap = trace.gap[:, column]
        out[event.event_id] = {"done": True, "t_m_s": t * trace.dt,
                               "speed_mps": float(trace.speed[t, column]),
                               "gap_m": float(gap[t]), "min_gap_m": float(np.nanmin(gap[t:])),
                               "collided": trace.collisions > 0}
    return out


def main() -> None:
    data, a, b, ids = sys.argv[1], sys.argv[2], sys.argv[3], sys.argv[4].split(",")
    events = [e.with_warmup(REAL_WARMUP_S) for split in ("test", "train")
              for e in load_events(data, split) if e.event_id in ids]  # either split's IDs
    spec = ScenarioSpec("cut-in", seed=0)
    rows = {name: entry(name, events, spec) for name in (a, b)}
    print("| event | controller | t_m (s) | speed (m/s) | gap left (m) | smallest gap (m) | collides |")
    print("|---|---|---|---|---|---|---|")
    for event in events:
        for name in (a, b):
            r = rows[name][event.event_id]
            if not r["done"]:
                print(f"| `{event.event_id}` | {name} | not done | | | | |")
                continue
            print(f"| `{event.event_id}` | {name} | {r['t_m_s']:.1f} | {r['speed_mps']:.2f} | "
                  f"{r['gap_m']:.2f} | {r['min_gap_m']:.2f} | {'yes' if r['collided'] else 'no'} |")


if __name__ == "__main__":
    main()
