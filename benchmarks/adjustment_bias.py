"""The learned term's steady part: mean a_adj (m/s²) of policy files over NGSIM test events on
the real plant (10 followers, 60 s settled start), beside their headway. On a CACC base a steady
a_adj moves the steady spacing error by a_adj/kp (22 m per m/s² at kp = 0.0445), which is what
the washout ``wo=T`` removes (docs/vehicles.md). About 10 s per policy and 40 events on 1 core.

Usage: python benchmarks/adjustment_bias.py DATA POLICY.pt [POLICY.pt ...] [--events 40]
"""
import argparse

import numpy as np

from carl_sumo.control.channel import plant_impairments
from carl_sumo.data import load_events
from carl_sumo.experiments.simulate import event_trajectories
from carl_sumo.experiments.suite import REAL_WARMUP_S
from carl_sumo.learn import policy
from carl_sumo.sim.metrics import score_event


def main(data: str, paths: list[str], n_events: int) -> None:
    recorded: list[np.ndarray] = []
    adjustment = policy.PolicyController.adjustment

    def recording(self, obs):
        out = adjustment(self, obs)
        recorded.append(np.array(out))
        return out

    policy.PolicyController.adjustment = recording
    events = [e.with_warmup(REAL_WARMUP_S) for e in load_events(data, "test")][:n_events]
    print(f"{'policy':60s} {'mean a_adj':>10s} {'mean |a_adj|':>12s} {'headway s':>9s}")
    for path in paths:
        recorded.clear()
        headway = [score_event(traj)["headway_s"] for _, traj in
                   event_trajectories(path, events, 10, impairments=plant_impairments("real"))]
        a = np.concatenate(recorded)
        print(f"{path:60s} {a.mean():+10.4f} {np.abs(a).mean():12.4f} {np.mean(headway):9.3f}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data")
    parser.add_argument("policies", nargs="+")
    parser.add_argument("--events", type=int, default=40, help="the first N test events")
    args = parser.parse_args()
    main(args.data, args.policies, args.events)
