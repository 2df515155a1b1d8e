"""Where learned policies spend their close calls: each policy and its base on the events its
training run validated on (the seed file's ``validation_events``), real plant, 10 followers,
TTC < 1.5 s samples and collisions on the named hard events (``--hard``, default
``carl_sumo/data/event_lists/val_hard_real.txt``) and on the others, and the events where the
policy has more than the base. Selection (``--select reward``) keeps a checkpoint only if it has
no more of either than the base on these events; a run that kept its base can be looked into
through its last actor (``carl-sumo export policies/seeds/STEM_seedK.ckpt --out last_seedK.pt``).

``--all-train``: every training event instead (the bar's 773, e.g. with ``--warmup 60``).

Usage: python benchmarks/close_calls.py DATA SEED_FILE.pt POLICY.pt [POLICY.pt ...]
       [--warmup 10] [--hard FILE] [--all-train]
About 15 s per policy on 1 core at --warmup 10 (94 validation events); 268 s for two
controllers on the 773 training events at --warmup 60.
"""
import argparse
import time

from carl_sumo.control.channel import plant_impairments
from carl_sumo.data import load_events
from carl_sumo.data.events import read_event_ids
from carl_sumo.experiments.simulate import event_trajectories
from carl_sumo.learn.policy import read_policy_payload
from carl_sumo.resources import EVENT_LISTS
from carl_sumo.sim.metrics import score_event


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("data")
    p.add_argument("seed_file", help="a seed file whose validation events and base are used")
    p.add_argument("policies", nargs="+")
    p.add_argument("--warmup", type=float, default=10.0, help="s of settling (training's: 10)")
    p.add_argument("--hard", default=str(EVENT_LISTS / "val_hard_real.txt"))
    p.add_argument("--all-train", action="store_true", help="every training event")
    args = p.parse_args()
    meta = read_policy_payload(args.seed_file)["metadata"]
    hard = set(read_event_ids(args.hard))
    ids = None if args.all_train else meta["validation_events"]
    events = [e.with_warmup(args.warmup) for e in load_events(args.data, "train", event_ids=ids)]
    start = time.perf_counter()
    runs = {name: {e.event_id: score_event(traj) for e, traj in event_trajectories(
        name, events, 10, impairments=plant_impairments("real"))}
        for name in [meta["base"], *args.policies]}
    which = "training" if args.all_train else "validation"
    print(f"{len(events)} {which} events of {args.seed_file} ({len(hard & set(runs[meta['base']]))}"
          f" of them in {args.hard}), --warmup {args.warmup:g}, real plant, 10 followers, "
          f"{time.perf_counter() - start:.0f} s")
    print("| controller | TTC < 1.5 s: hard events | others | collisions |\n|---|---|---|---|")
    for name, per_event in runs.items():
        hard_n = sum(m["ttc_lt_1_5s_count"] for k, m in per_event.items() if k in hard)
        other = sum(m["ttc_lt_1_5s_count"] for k, m in per_event.items() if k not in hard)
        print(f"| {name} | {hard_n:.0f} | {other:.0f} | "
              f"{sum(m['collisions'] for m in per_event.values()):.0f} |")
    base = runs[meta["base"]]
    for name in args.policies:
        worse = sorted(((k, m["ttc_lt_1_5s_count"] - base[k]["ttc_lt_1_5s_count"])
                        for k, m in runs[name].items()
                        if m["ttc_lt_1_5s_count"] > base[k]["ttc_lt_1_5s_count"]),
                       key=lambda x: -x[1])
        print(f"{name}: more than the base on {len(worse)} events, "
              + ", ".join(f"{k} +{d:.0f}" for k, d in worse[:5]))


if __name__ == "__main__":
    main()
