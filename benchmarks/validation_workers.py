"""Validation's wall time in one process against ``--val-workers 2`` (a helper process with its
own SUMO runs every other event), side by side in one run, with the same numbers checked.

A training run of the product's recipe spends most of its wall time validating (docs/training.md,
"Where the time goes"): 24 held-out events of the real plant every 500 steps, in the training
process, while the environment workers wait. This runs that validation on ``--events`` training
events (evenly spaced) of the recipe's base and plant, ``--repeats`` times each way, alternating
(so that a change of load on a shared machine falls on both), and prints the wall and CPU time of
each and the ratio. The numbers of both ways must be equal (the script stops otherwise).

Usage: python benchmarks/validation_workers.py DATA [--events 24] [--repeats 2]
                                               [--recipe recipes/ca_td3_real_10.toml]
"""
import argparse
import time

import numpy as np

from carl_sumo.control.ploeg_names import expand_preset
from carl_sumo.data import load_events
from carl_sumo.learn.env import PlatoonEnv
from carl_sumo.learn.recipe import read_recipe
from carl_sumo.learn.train_config import TrainConfig
from carl_sumo.resources import NETWORKS, shipped
from carl_sumo.learn.selection import BaseOnly, ValidationHelper, validate_events
from carl_sumo.learn.train_config import validation_conditions


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("data")
    p.add_argument("--events", type=int, default=24)
    p.add_argument("--repeats", type=int, default=2)
    p.add_argument("--recipe", default="recipes/ca_td3_real_10.toml")
    args = p.parse_args()
    cfg = TrainConfig(**read_recipe(args.recipe))
    events = load_events(args.data, "train")
    events = [events[i].with_warmup(cfg.warmup)
              for i in np.linspace(0, len(events) - 1, args.events).astype(int)]
    kwargs = dict(events=events, n_followers=cfg.n_vehicles, net_path=shipped(cfg.net, NETWORKS),
                  base=expand_preset(cfg.base),
                  shield_ttc_s=cfg.shield_ttc)
    env, helper = PlatoonEnv(**kwargs), ValidationHelper(kwargs)
    conditions = validation_conditions(cfg)
    times = {1: [], 2: []}
    results = {}
    try:
        validate_events(BaseOnly(), env, events[:1], conditions, [helper])  # both started
        for _ in range(args.repeats):
            for workers in (1, 2):
                wall, cpu = time.perf_counter(), time.process_time()
                results[workers] = validate_events(BaseOnly(), env, events, conditions,
                                                   [helper] if workers == 2 else [])
                times[workers].append((time.perf_counter() - wall, time.process_time() - cpu))
    finally:
        helper.close()
    np.testing.assert_equal(results[1], results[2])
    for workers, rows in times.items():
        wall = np.mean([w for w, _ in rows])
        cpu = np.mean([c for _, c in rows])
        print(f"--val-workers {workers}: {wall:.1f} s of wall ({cpu:.1f} s of CPU in this "
              f"process) for {len(events)} events x {len(conditions)} condition(s)")
    ratio = np.mean([w for w, _ in times[1]]) / np.mean([w for w, _ in times[2]])
    print(f"one process / two processes: {ratio:.2f}x (the same numbers)")


if __name__ == "__main__":
    main()
