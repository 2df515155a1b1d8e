"""The hardest training events for a base controller, as an event ID list for
``carl-sumo train --val-events``: every event of the training split run with the base (10
followers), ranked by its collisions, then its TTC < 1.5 s samples, then its TTC < 4 s samples;
the top K are written one ID per line, each with its counts as a comment.

Validation on 64 random training events never met the few events on which learned policies
spend their close calls; validating on these as well lets safety-first selection see them.
Only training events are run, so the test split stays unseen.

``--exclude POLICY.pt``: leave out the events a training run validated on (its metadata's
``validation_events``), for a list of hard events to train on (``train --oversample``).

Usage: python benchmarks/hard_events.py DATA BASE OUT [--plant real|ideal] [--top K]
       [--exclude POLICY.pt]
e.g.   python benchmarks/hard_events.py ../shared/data/ngsim/ngsim_cf_events.csv.gz \\
           ploeg:h=0.8:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2:rb=1 \\
           carl_sumo/data/event_lists/val_hard_real.txt --top 32
About 1 minute on 2 cores for the 773 training events on the real plant (57 s measured).
"""
import argparse
import time
from pathlib import Path

from carl_sumo.control.channel import plant_impairments
from carl_sumo.data import load_events
from carl_sumo.experiments.simulate import simulate
from carl_sumo.experiments.suite import REAL_WARMUP_S
from carl_sumo.files import check_output_file, write_text_atomic
from carl_sumo.learn.policy import read_policy_payload

RANK_KEYS = ("collisions", "ttc_lt_1_5s_count", "ttc_lt_4s_count")


def hardest(per_event: list[dict], top: int) -> list[dict]:
    """The ``top`` events with the most collisions, then TTC < 1.5 s, then TTC < 4 s samples."""
    return sorted(per_event, key=lambda m: tuple(-m[k] for k in RANK_KEYS))[:top]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("data")
    p.add_argument("base")
    p.add_argument("out")
    p.add_argument("--plant", choices=("real", "ideal"), default="real")
    p.add_argument("--top", type=int, default=32)
    p.add_argument("--exclude", default=None, metavar="POLICY.pt",
                   help="leave out the events this training run validated on")
    args = p.parse_args()
    check_output_file(args.out, "OUT")
    events = load_events(args.data, "train")
    if args.exclude:
        held = set(read_policy_payload(Path(args.exclude))["metadata"]["validation_events"])
        events = [e for e in events if e.event_id not in held]
    if args.plant == "real":
        events = [e.with_warmup(REAL_WARMUP_S) for e in events]
    start = time.perf_counter()
    result = simulate(args.base, events, 10, workers=2, impairments=plant_impairments(args.plant))
    lines = [f"# the {args.top} hardest of {len(events)} training events for {args.base} on the "
             f"{args.plant} plant (10 followers): collisions, TTC < 1.5 s, TTC < 4 s samples",
             f"# python benchmarks/hard_events.py {args.data} {args.base} {args.out} "
             f"--plant {args.plant} --top {args.top}"
             + (f" --exclude {args.exclude}" if args.exclude else "")]
    lines += [f"{m['event_id']}  # " + ", ".join(str(m[k]) for k in RANK_KEYS)
              for m in hardest(result["events"], args.top)]
    write_text_atomic(Path(args.out), "\n".join(lines) + "\n")
    print(f"{args.out}: {args.top} events in {time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
