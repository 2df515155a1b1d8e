"""How the distributed MPC's default weights were chosen: laws by name on evenly spaced
training events, 10 followers, the real plant, a 60 s warm-up (training split only: the test
split is scored once, with the chosen law).

Prints, per law, the headway (s), jerk (m/s³), dampening, collisions and TTC < 1.5 s / < 4 s
sample counts over the events, and the wall time.

Usage: python benchmarks/mpc_weights.py DATA [--events 40] NAME [NAME ...]
       (a NAME is any controller name or preset, e.g. product-base mpc mpc:wu=2:wj=0.2)
"""
import argparse
import time

from carl_sumo.control.channel import plant_impairments
from carl_sumo.control.classical import classical_controller
from carl_sumo.control.ploeg_names import expand_preset
from carl_sumo.data import load_events
from carl_sumo.experiments.simulate import cached_sim, run_event
from carl_sumo.sim.metrics import aggregate, score_event
from carl_sumo.sim.sumo import DEFAULT_NET


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data")
    ap.add_argument("names", nargs="+")
    ap.add_argument("--events", type=int, default=40)
    args = ap.parse_args()
    events = load_events(args.data, "train")
    events = [e.with_warmup(60.0) for e in
              events[::max(len(events) // args.events, 1)][:args.events]]
    imp, sim = plant_impairments("real"), cached_sim(DEFAULT_NET, "external")
    for name in args.names:
        name = expand_preset(name)
        law, start = classical_controller(name, imp.plant_key), time.perf_counter()
        m = aggregate([score_event(run_event(sim, e, 10, law, impairments=imp)) for e in events])
        print(f"{name}: headway {m['headway_s']:.3f} jerk {m['jerk_mps3']:.3f} dampening "
              f"{m['dampening_ratio']:.3f} collisions {m['collisions']} TTC<1.5 "
              f"{m['ttc_lt_1_5s_count']} TTC<4 {m['ttc_lt_4s_count']} "
              f"({time.perf_counter() - start:.0f} s)", flush=True)


if __name__ == "__main__":
    main()
