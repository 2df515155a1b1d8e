"""The best rule of the product's own design space: its base (``mpf-tuned`` with the learned-gap
terms ``gp=2:gl=0.5:gb=1:gh=1000``) whose one decision per run is the corner of the headway budget
(the head's gap as high as the budget lets it, every car at its 0.5 s floor, trucks at their own
0.8 s), with no learning. Did RL find more than that corner?

Run as an external controller by any command, e.g. the test split:

    carl-sumo simulate --data DATA --split test --plant real --warmup 60 --vehicles 10 \\
        --controller benchmarks/budget_corner.py:BudgetCorner --workers 2 --json OUT.json

The decision is the base's own (``PloegController.gap_target``): a learned term of +1 s for the
head and -1 s for each follower, shifted by one common amount to keep the budget, each at its
floor. The base is read from the shipped product's file, so the rule follows it.

    python benchmarks/budget_corner.py POLICY.pt ...   # how much of the room a policy's decision uses
    python benchmarks/budget_corner.py --oracle DATA EVENTS WORKERS   # the most a per-event choice gains
"""
from pathlib import Path

import numpy as np

from carl_sumo.control.cacc import ploeg_controller
from carl_sumo.learn.policy import read_policy_payload
from carl_sumo.resources import PRODUCT, policies_dir


def product_base() -> str:
    """The base law of the shipped product (its learned-gap options included)."""
    return read_policy_payload(Path(policies_dir()) / PRODUCT)["agent_config"]["base"]


class BudgetCorner:
    """The product's base with its one gap decision at the budget's corner (see the module)."""

    def __init__(self):
        self.law = ploeg_controller(product_base())
        self.corner = np.zeros(0)

    def reset(self, n_followers: int) -> None:
        self.law.reset(n_followers)
        self.corner = np.full(n_followers, -1.0)
        self.corner[0] = 1.0

    def know_vehicles(self, a_max_mps2, b_max_mps2) -> None:
        self.law.know_vehicles(a_max_mps2, b_max_mps2)

    def connect(self, impairments, event_id: str) -> None:
        self.law.connect(impairments, event_id)

    def acceleration(self, obs: np.ndarray) -> np.ndarray:
        return self.law.acceleration(obs, self.corner)


class BudgetShare(BudgetCorner):
    """The same base with its one decision a ``share`` of the way from the start (0) to the
    corner (1): every car ``share`` of the way to its floor, trucks at their own gap, the head
    given what that frees; held from the first step (the oracle below)."""

    share = 1.0

    def know_vehicles(self, a_max_mps2, b_max_mps2) -> None:
        super().know_vehicles(a_max_mps2, b_max_mps2)
        own, least = self.law.params.class_gaps(np.asarray(b_max_mps2))
        offsets = self.share * (least - own)
        offsets[0] = -offsets[1:].sum()
        self.law.hold_decision(offsets)

    def acceleration(self, obs: np.ndarray) -> np.ndarray:
        return self.law.acceleration(obs)


SHARES = (0.0, 0.25, 0.5, 0.75, 1.0)
for _s in SHARES:
    globals()[f"Share{round(100 * _s)}"] = type(f"Share{round(100 * _s)}", (BudgetShare,),
                                                 {"share": _s})


def oracle(data: str, events: int, workers: int) -> None:
    """On the first ``events`` training events (real plant, 10 followers, 60 s settled start):
    each share's jerk and dampening, and an oracle that picks per event the share with the
    least jerk: what any one-decision-per-run policy could gain over the corner at most, among
    these decisions."""
    from carl_sumo.control.channel import plant_impairments
    from carl_sumo.data import load_events
    from carl_sumo.experiments.simulate import simulate

    evs = [e.with_warmup(60.0) for e in load_events(data, "train", limit=events)]
    runs = {s: simulate(f"{__file__}:Share{round(100 * s)}", evs, 10, workers=workers,
                        impairments=plant_impairments("real"))["events"] for s in SHARES}
    for s, rows in runs.items():
        print(f"share {s:.2f}: jerk {np.mean([r['jerk_mps3'] for r in rows]):.4f}, dampening "
              f"{np.mean([r['dampening_ratio'] for r in rows]):.4f}, headway "
              f"{np.mean([r['headway_s'] for r in rows]):.3f} s")
    best = [min(SHARES, key=lambda s: runs[s][i]["jerk_mps3"]) for i in range(len(evs))]
    jerk = np.mean([runs[b][i]["jerk_mps3"] for i, b in enumerate(best)])
    damp = np.mean([runs[b][i]["dampening_ratio"] for i, b in enumerate(best)])
    print(f"oracle (least jerk per event): jerk {jerk:.4f}, dampening {damp:.4f}; the corner "
          f"best in {sum(b == 1.0 for b in best)} of {len(evs)} events")


def budget_used(policy: str) -> dict:
    """How much of the budget's room a held-gap policy's first decision uses on its validation
    events (the head's offset over the cars' total room to their floor), with the mean gaps of
    the head and of the cars it chose."""
    from carl_sumo.control.channel import plant_impairments
    from carl_sumo.experiments.held_gaps import decision_events, first_decisions
    from carl_sumo.resources import DEFAULT_NET

    n = int(read_policy_payload(Path(policy))["agent_config"]["n_vehicles"])
    events, _ = decision_events(policy)
    chosen, braking = first_decisions(policy, events, n, plant_impairments("real"),
                                      str(DEFAULT_NET))
    params = ploeg_controller(read_policy_payload(Path(policy))["agent_config"]["base"]).params
    used, heads, cars = [], [], []
    for off, b_max in zip(chosen, braking):
        own, least = params.class_gaps(b_max)
        room = float((own - least)[1:].sum())
        used.append(off[0] / room if room > 0 else np.nan)
        heads.append(own[0] + off[0])
        car = (own - least)[1:] > 0
        cars.append(float((own[1:] + off[1:])[car].mean()))
    return {"budget_used": float(np.nanmean(used)), "head_s": float(np.mean(heads)),
            "cars_s": float(np.mean(cars)), "events": len(events)}


if __name__ == "__main__":
    import sys

    if sys.argv[1:2] == ["--oracle"]:  # --oracle DATA EVENTS WORKERS
        oracle(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]))
        sys.exit(0)
    for path in sys.argv[1:]:
        r = budget_used(path)
        print(f"{path}: budget used {100 * r['budget_used']:.0f} % on {r['events']} events; "
              f"head {r['head_s']:.3f} s, cars {r['cars_s']:.3f} s")
