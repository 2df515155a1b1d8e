"""What time gaps a learned spacing policy (a base named with ``gp=T``, docs/models.md) keeps:
on the NGSIM test events, real plant, 10 followers, 60 s settled start, each follower's time-gap
gap h_i + δ_i (s; δ_i its learned offset, floored at its class's least gap as the law does)
averaged over the scored steps, by position and by class (cars, trucks: largest braking below
7 m/s²), with its spread over time (the mean over events of its std within one).
About 4 CPU minutes per policy on the 403 test events.

Usage: python benchmarks/learned_gaps.py DATA POLICY.pt [POLICY.pt ...] [--events N]
"""
import argparse

import numpy as np

from carl_sumo.control.channel import plant_impairments
from carl_sumo.control.ploeg_names import HEAVY_BRAKING_MPS2
from carl_sumo.data import load_events
from carl_sumo.experiments.simulate import cached_sim, resolve_controller, run_event
from carl_sumo.experiments.suite import REAL_WARMUP_S
from carl_sumo.resources import DEFAULT_NET


class Recorder:
    """A learned policy on a ``gp`` base that records its base's gap offsets at every step."""

    def __init__(self, controller):
        self.controller, self.offsets, self.b_max = controller, [], None

    def __getattr__(self, name):
        return getattr(self.controller, name)

    def reset(self, n: int) -> None:
        self.controller.reset(n)
        self.offsets = []

    def know_vehicles(self, a_max, b_max) -> None:
        self.b_max = np.asarray(b_max)
        self.controller.know_vehicles(a_max, b_max)

    def acceleration(self, obs):
        out = self.controller.acceleration(obs)
        own, least = self.controller.base.params.class_gaps(self.b_max)
        self.offsets.append(np.maximum(own + self.controller.base.gap_off, least))
        return out


def gaps(policy: str, events: list) -> dict:
    """Per follower: the mean time gap (s) and its mean std within an event; per class the
    mean."""
    impairments = plant_impairments("real")
    _, controller = resolve_controller(policy, "real")
    if controller.base.params.gap_policy_s is None:
        raise SystemExit(f"{policy}: its base has no learned spacing policy (gp=T)")
    rec, sim = Recorder(controller), cached_sim(DEFAULT_NET, "external")
    means, stds, heavy = [], [], []
    for e in events:
        run_event(sim, e, 10, rec, impairments=impairments)
        scored = np.array(rec.offsets)[max(e.scored_from - 1, 0):]  # step k: sample k + 1
        if len(scored):
            means.append(scored.mean(axis=0))
            stds.append(scored.std(axis=0))
            heavy.append(rec.b_max < HEAVY_BRAKING_MPS2)
    means, stds, heavy = np.array(means), np.array(stds), np.array(heavy)
    chain = np.zeros_like(heavy)
    chain[:, 1:] = True
    return {"position": means.mean(axis=0), "std": stds.mean(axis=0),
            "head": means[:, 0].mean(), "cars": means[chain & ~heavy].mean(),
            "trucks": means[chain & heavy].mean() if (chain & heavy).any() else float("nan")}


def main(data: str, policies: list[str], n_events: int | None) -> None:
    events = [e.with_warmup(REAL_WARMUP_S) for e in load_events(data, "test")][:n_events]
    for policy in policies:
        g = gaps(policy, events)
        print(f"{policy} ({len(events)} events): mean time gap of the head {g['head']:.3f} s, "
              f"the cars in the chain {g['cars']:.3f} s, the trucks {g['trucks']:.3f} s")
        print("  per follower: " + " ".join(f"{x:.3f}" for x in g["position"]))
        print("  its std within an event: " + " ".join(f"{x:.3f}" for x in g["std"]))


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data")
    parser.add_argument("policies", nargs="+")
    parser.add_argument("--events", type=int, default=None, help="the first N test events")
    args = parser.parse_args()
    main(args.data, args.policies, args.events)
