"""Where a controller damps: each follower's ‖a_i‖₂/‖a_0‖₂ (a_0: the leader), averaged over the
NGSIM test events on the real plant (10 followers, 60 s settled start), and each follower's
ratio to the one ahead. The mean of the profile is the dampening ratio of docs/metrics.md.
About 3-4 CPU minutes per controller on the 403 test events.

Usage: python benchmarks/per_follower_dampening.py DATA CONTROLLER [CONTROLLER ...] [--events N]
(CONTROLLER: a name such as mpf-tuned, or a policy file)
"""
import argparse

import numpy as np

from carl_sumo.control.channel import plant_impairments
from carl_sumo.data import load_events
from carl_sumo.experiments.simulate import event_trajectories
from carl_sumo.experiments.suite import REAL_WARMUP_S
from carl_sumo.sim.metrics import acceleration_norms


def profile(controller: str, events: list) -> np.ndarray:
    """Mean over events of ‖a_i‖/‖a_0‖ for each follower i = 1..10 (events whose leader never
    accelerates are left out)."""
    ratios = []
    for _, traj in event_trajectories(controller, events, 10,
                                      impairments=plant_impairments("real")):
        norms = acceleration_norms(traj)
        if norms[0] > 0:
            ratios.append(norms[1:] / norms[0])
    return np.mean(ratios, axis=0)


def main(data: str, controllers: list[str], n_events: int | None) -> None:
    events = [e.with_warmup(REAL_WARMUP_S) for e in load_events(data, "test")][:n_events]
    for name in controllers:
        p = profile(name, events)
        links = np.r_[p[0], p[1:] / p[:-1]]
        print(f"{name} ({len(events)} events): dampening {p.mean():.4f}")
        print("  per follower: " + " ".join(f"{x:.3f}" for x in p))
        print("  to the one ahead: " + " ".join(f"{x:.3f}" for x in links))


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data")
    parser.add_argument("controllers", nargs="+")
    parser.add_argument("--events", type=int, default=None, help="the first N test events")
    args = parser.parse_args()
    main(args.data, args.controllers, args.events)
