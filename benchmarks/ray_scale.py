"""Ray against the local process pool, and Ray tasks on two nodes (docs/scale.md).

``overhead``: the README's ``simulate`` command (403 NGSIM test events, 10 followers; its four
controllers, or ``--controller``) run as a whole command, alternately with the local pool (``--workers 2``) and through a local Ray runtime
with 2 CPUs (``--ray local --workers 2``), ``--rounds`` times each; wall times, their medians and
the ratio, and whether the metrics are identical. ``tasks``: the cost of one task once the
workers are up (a warm pool or a warm Ray runtime, 8 tasks of 20 events each) and the start-up of
each. ``two-node``: a two-node Ray cluster on this machine (``ray.cluster_utils.Cluster``, 1 CPU
per node), the same command joined to it with ``--ray HOST:PORT``, and the tasks per node.

    python benchmarks/ray_scale.py overhead [--rounds 3] [--controller idm-external]
    python benchmarks/ray_scale.py tasks
    python benchmarks/ray_scale.py two-node
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

DATA = "../shared/data/ngsim/ngsim_cf_events.csv.gz"
README_CONTROLLERS = "idm,krauss,idm-external,human"


def command(controllers: str) -> list[str]:
    """The README's simulate command (403 NGSIM test events, 10 followers) for controllers."""
    return ["simulate", "--net", "networks/i80.net.xml", "--controller", controllers, "--data",
            DATA, "--split", "test", "--vehicles", "10"]


def run_cli(extra: list[str], out: Path, controllers: str = README_CONTROLLERS
            ) -> tuple[float, str]:
    """Wall time (s) of one ``simulate`` command in a fresh process, and its stderr."""
    start = time.perf_counter()
    proc = subprocess.run([sys.executable, "-m", "carl_sumo", *command(controllers),
                           "--json", str(out),
                           *extra], capture_output=True, text=True, timeout=900)
    wall = time.perf_counter() - start
    if proc.returncode != 0:
        raise SystemExit(proc.stderr)
    return wall, proc.stderr


def overhead(rounds: int, controllers: str) -> None:
    walls: dict[str, list[float]] = {"pool": [], "ray": []}
    with tempfile.TemporaryDirectory() as tmp:
        for r in range(rounds):
            for name, extra in (("pool", ["--workers", "2"]),
                                ("ray", ["--workers", "2", "--ray", "local"])):
                wall, _ = run_cli(extra, Path(tmp) / f"{name}{r}.json", controllers)
                walls[name].append(wall)
                print(f"round {r + 1} {name}: {wall:.1f} s", flush=True)
        same = all(json.loads((Path(tmp) / f"ray{r}.json").read_text())
                   == json.loads((Path(tmp) / "pool0.json").read_text()) for r in range(rounds))
    pool, ray = statistics.median(walls["pool"]), statistics.median(walls["ray"])
    print(f"median wall: local pool {pool:.1f} s, Ray local {ray:.1f} s, ratio {ray / pool:.3f}; "
          f"metrics identical: {same}")


def tasks() -> None:
    """Per-task cost with warm workers, and the start-up of the pool and of Ray."""
    from carl_sumo.scale import cluster
    from carl_sumo.data import load_events
    from carl_sumo.experiments.simulate import _score_events
    from carl_sumo.scale.workers import run_parallel

    events = load_events(DATA, "test")[:160]
    items = [("idm-external", events[i::8], 10, "networks/i80.net.xml") for i in range(8)]

    def timed(label: str) -> float:
        start = time.perf_counter()
        list(run_parallel(_score_events, items, 2))
        wall = time.perf_counter() - start
        print(f"{label}: 8 tasks of 20 events in {wall:.2f} s ({wall * 2 / 8:.2f} s per task "
              "on 2 workers)", flush=True)
        return wall

    cold_pool = timed("local pool, started inside")  # each run_parallel starts its own pool
    start = time.perf_counter()
    cluster.connect("local", 2)
    print(f"Ray local runtime started in {time.perf_counter() - start:.2f} s", flush=True)
    cold_ray = timed("Ray, first run (workers import carl_sumo)")
    warm_ray = timed("Ray, warm workers")
    start = time.perf_counter()
    cluster.disconnect()
    print(f"Ray shut down in {time.perf_counter() - start:.2f} s; start-up per run: pool "
          f"{cold_pool - warm_ray:.2f} s, Ray workers {cold_ray - warm_ray:.2f} s")


def two_node() -> None:
    from ray.cluster_utils import Cluster

    two = Cluster(initialize_head=True, head_node_args={"num_cpus": 1,
                                                        "include_dashboard": False})
    try:
        two.add_node(num_cpus=1)
        two.wait_for_nodes()
        print(f"two-node cluster at {two.address}", flush=True)
        with tempfile.TemporaryDirectory() as tmp:
            wall, err = run_cli(["--ray", two.address], Path(tmp) / "two.json")
        print(f"carl-sumo simulate --ray {two.address}: {wall:.1f} s")
        print("\n".join(line for line in err.splitlines() if line.startswith("ray:")))
    finally:
        two.shutdown()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("what", choices=("overhead", "tasks", "two-node"))
    parser.add_argument("--rounds", type=int, default=3)
    parser.add_argument("--controller", default=README_CONTROLLERS,
                        help="overhead: the controllers (default: the README's four)")
    args = parser.parse_args()
    if args.what == "overhead":
        overhead(args.rounds, args.controller)
    elif args.what == "tasks":
        tasks()
    else:
        two_node()


if __name__ == "__main__":
    main()
