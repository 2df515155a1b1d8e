"""Variants of the Ploeg CACC's information and spacing, measured beside the law itself (issue 21:
where could a learned adjustment find comfort that the tuned law leaves?). Each runs in SUMO on the
first K events of a split (or the stop-and-go leader: split ``stop-and-go``), 10 followers,
recorded start, and prints the suite's metrics.

- ``head-filter TAU``: the first follower hears the leader's acceleration through a first-order
  filter of time constant TAU s (0: as the law, the raw acceleration; -1: none, an ACC head);
- ``multi-hop BETA``: every follower also hears the leader's acceleration, broadcast:
  u_in = (1 - BETA)·u_{i-1} + BETA·a_lead (0: the law);
- ``gap-ramp TC [P]``: joining; each follower's spacing reference starts at its recorded gap and
  reaches s0 + h·v with time constant TC·i^P s for the i-th follower (a gap-closing manoeuvre;
  P = 0, the default: the same for all; P > 0: slower down the chain).
- ``gap-smooth T [P]``: the same joining along a smooth (quintic, rest-to-rest) path that ends
  after T·i^P s; only a gap above the reference is closed slowly.
- ``ff-gain K``: every follower feeds forward K times what it hears (K = 1: the law).

Usage (from the repository root, the NGSIM data beside it):
    python benchmarks/ploeg_variants.py train 150 ploeg-tuned:h=0.8 head-filter 0,0.3,1,-1
    python benchmarks/ploeg_variants.py train 150 ploeg-tuned:h=0.8 multi-hop 0,0.3,0.6,1
    python benchmarks/ploeg_variants.py train 150 ploeg-tuned:h=0.8 gap-ramp 3,10,30
    python benchmarks/ploeg_variants.py train 150 ploeg-tuned:h=0.8 gap-ramp 1,2,3 0.667
    python benchmarks/ploeg_variants.py train 150 ploeg-tuned:h=0.8 ff-gain 0.5,0.7,0.85
"""
import sys

import numpy as np

from carl_sumo.control.cacc import CRUISE_GAIN_PER_S, PloegController, parse_ploeg
from carl_sumo.config import DT_S, IDM
from carl_sumo.data import load_events
from carl_sumo.sim.metrics import aggregate, score_event
from carl_sumo.experiments.simulate import cached_sim, run_event
from carl_sumo.sim.sumo import DEFAULT_NET

DATA = "../shared/data/ngsim/ngsim_cf_events.csv.gz"
KEYS = ("headway_s", "jerk_mps3", "speed_mps", "dampening_ratio", "worst_successive_ratio",
        "ttc_lt_4s_count", "ttc_lt_1_5s_count", "collisions")


class Variant(PloegController):
    """The Ploeg law (carl_sumo.control.cacc) with one of the variants above, in plain Python."""

    def __init__(self, params, variant: str, value: float, exponent: float = 0.0):
        super().__init__(params)
        self.variant, self.value, self.exponent = variant, value, exponent

    def reset(self, n: int) -> None:
        super().reset(n)
        self.lead_filtered, self.offset, self.t = 0.0, None, 0.0

    def _joining(self, error):
        """The part of the first step's spacing error (m, per follower) that the spacing
        reference still holds this step: decaying with TC·i^P (gap-ramp), or closed along a
        quintic path of T·i^P s, a gap below the reference opening at once (gap-smooth)."""
        times = self.value * np.arange(1, len(error) + 1) ** self.exponent  # s
        if self.offset is None:
            self.offset = error if self.variant == "gap-ramp" else np.maximum(error, 0)
        if self.variant == "gap-ramp":
            held, self.offset = self.offset, self.offset * np.exp(-DT_S / times)
            return held
        x = np.minimum(self.t / times, 1)
        self.t += DT_S
        return self.offset * (1 - x ** 3 * (10 - 15 * x + 6 * x ** 2))

    def step(self, obs, u, u_lead, adjustment=None, pred_mode=None, pred_held=None):
        p, b = self.params, self.bounds
        head_in = u_lead
        if self.variant == "head-filter" and self.value < 0:
            head_in = 0.0
        elif self.variant == "head-filter" and self.value > 0:
            self.lead_filtered += (DT_S / self.value) * (u_lead - self.lead_filtered)
            head_in = self.lead_filtered
        gaps = obs[:, 2].copy()
        if self.variant in ("gap-ramp", "gap-smooth"):
            gaps -= self._joining(gaps - p.standstill_gap_m - p.time_gap_s * obs[:, 0])
        out = np.empty(len(u))
        u_pred = head_in
        for i in range(len(u)):
            e = gaps[i] - p.standstill_gap_m - p.time_gap_s * obs[i, 0]
            e_dot = obs[i, 3] - p.time_gap_s * obs[i, 1]
            u_in = u_pred
            if self.variant == "multi-hop" and i > 0:
                u_in = (1 - self.value) * u_pred + self.value * u_lead
            if self.variant == "ff-gain":
                u_in = self.value * u_in
            u_old = u[i]
            u[i] = min(u_old + (DT_S / p.time_gap_s) * (-u_old + p.kp * e + p.kd * e_dot + u_in),
                       CRUISE_GAIN_PER_S * (IDM.desired_speed_mps - obs[i, 0]))
            u_pred = u_old
            out[i] = min(max(u[i], b.acc_min_mps2), b.acc_max_mps2)
        return out


if __name__ == "__main__":
    split, n_events, name, variant, values = sys.argv[1:6]
    exponent = float(sys.argv[6]) if len(sys.argv) > 6 else 0.0
    events = (load_events("stop-and-go") if split == "stop-and-go"  # the Table 3 leader
              else load_events(DATA, split))[:int(n_events)]
    sim = cached_sim(DEFAULT_NET, "external")
    for value in (float(v) for v in values.split(",")):
        controller = Variant(parse_ploeg(name), variant, value, exponent)
        m = aggregate([score_event(run_event(sim, e, 10, controller)) for e in events])
        print(f"{name} {variant}={value:g} P={exponent:g}: "
              + "  ".join(f"{k} {m[k]:.4f}" for k in KEYS), flush=True)
