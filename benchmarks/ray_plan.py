"""Planned wall times on 1, 8 and 64 nodes from measured per-task costs (docs/scale.md).

Suite: the tasks of ``evaluate --suite paper --all-seeds`` (every model's seed files in every
table: 15 seeds for the main models) as the evaluate plan makes them, each costing its share
(by planned work) of its job's worker CPU seconds in a measured run (``--timing``: the
``timing.csv`` of an ``evaluate --suite paper --seeds`` run; a seed file's job costs what the
model's shipped file cost on the same events and platoon length; CPU seconds, since the wall
time of a task on a shared machine includes waiting for the CPU). Sweep: 5 algorithms × 5 seeds × 3 recipes, each
trial costing the training wall time recorded in the shipped seed files' curves of that
algorithm (``policies/seeds/*.csv``, median over seeds; trained two at a time on a 2-core
machine). Both are scheduled longest first on 2 slots per node (nodes like the measuring one),
plus the fixed costs given (s): ``--start`` (Ray start and worker start-up), ``--driver`` (the
suite's tables and figures), ``--trial-setup`` (a trial's start and baseline validation).

    python benchmarks/ray_plan.py --timing RESULTS/timing.csv --start S --driver S --trial-setup S
"""

from __future__ import annotations

import argparse
import csv
import heapq
import statistics
from pathlib import Path

NODES = (1, 8, 64)
SLOTS_PER_NODE = 2
SWEEP_STEMS = {"ca-td3": "ca_td3_10", "ca-ddpg": "ca_ddpg_10", "maddpg": "maddpg_10",
               "td3": "td3_1", "ddpg": "ddpg_1"}


def makespan(costs: list[float], slots: int) -> float:
    """Wall time (s) of tasks run longest first on ``slots`` parallel slots."""
    loads = [0.0] * slots
    heapq.heapify(loads)
    for cost in sorted(costs, reverse=True):
        heapq.heappush(loads, heapq.heappop(loads) + cost)
    return max(loads)


def suite_costs(timing: Path) -> list[float]:
    """Per-task cost (s) of the --all-seeds suite from a measured run's per-job seconds."""
    from carl_sumo.experiments.evaluate import plan_tasks
    from carl_sumo.experiments.suite import plan_suite

    measured = {}
    for row in csv.DictReader(open(timing)):
        key = (row["event_set"], Path(row["controller"]).name.split("_seed")[0].removesuffix(".pt"),
               int(row["followers"]))
        measured.setdefault(key, float(row["cpu_seconds"]))  # the shipped file's (listed first)
    tasks = plan_tasks(plan_suite("paper", None, False, None, None, "networks/i80.net.xml",
                                  True, False), "networks/i80.net.xml")
    planned: dict[tuple, float] = {}
    for t in tasks:
        planned[t["job"]] = planned.get(t["job"], 0.0) + t["cost"]
    costs, missing = [], set()
    for t in tasks:
        set_key, controller, n = t["job"]
        key = (set_key, Path(str(controller)).name.split("_seed")[0].removesuffix(".pt"), n)
        if key not in measured:
            missing.add(key)
            continue
        costs.append(measured[key] * t["cost"] / planned[t["job"]])
    if missing:
        raise SystemExit(f"no measured job for {sorted(missing)[:3]} ...")
    print(f"suite --all-seeds: {len(tasks)} tasks, {sum(costs):.0f} s of task time; "
          f"longest task {max(costs):.1f} s")
    return costs


def sweep_costs(seeds_dir: Path) -> list[float]:
    """5 algorithms × 5 seeds × 3 recipes: per-trial training wall time (s)."""
    costs = []
    for algo, stem in SWEEP_STEMS.items():
        walls = [float(list(csv.DictReader(open(p)))[-1]["wall_s"])
                 for p in sorted(seeds_dir.glob(f"{stem}_seed*.csv"))]
        per_trial = statistics.median(walls)
        print(f"{algo}: {per_trial:.0f} s per run (median of {len(walls)} shipped seeds, {stem})")
        costs += [per_trial] * (5 * 3)
    return costs


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--timing", type=Path, required=True)
    parser.add_argument("--seeds-dir", type=Path, default=Path("policies/seeds"))
    parser.add_argument("--start", type=float, required=True)
    parser.add_argument("--driver", type=float, required=True)
    parser.add_argument("--trial-setup", type=float, required=True)
    args = parser.parse_args()
    suite = suite_costs(args.timing)
    sweep = sweep_costs(args.seeds_dir)
    print("| nodes (2 CPUs each) | suite --all-seeds | 5 × 5 × 3 sweep |")
    print("|---|---|---|")
    for nodes in NODES:
        slots = nodes * SLOTS_PER_NODE
        s = makespan(suite, slots) + args.start + args.driver
        rounds = -(-len(sweep) // slots)
        w = makespan(sweep, slots) + args.start + rounds * args.trial_setup
        print(f"| {nodes} | {s:.0f} s ({s / 60:.1f} min) | {w:.0f} s ({w / 3600:.2f} h) |")


if __name__ == "__main__":
    main()
