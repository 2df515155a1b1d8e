"""Would the paper configuration follow closer and smoother if its adjustment entered through a
filter? (issue 21). The best any actor could do on the IDM base is to copy a classical CACC:
a_adj = a_Ploeg - a_IDM (``carl_sumo.learn.imitation``, the head hearing nothing). Here that perfect
teacher drives in SUMO with its adjustment applied at once (TAU = 0, the paper's action) or
through a first-order filter of time constant TAU s, z += (dt/TAU)·(a_adj - z), a = a_IDM + z;
10 followers, recorded start, the first K events of a split, beside IDM and the CACC itself.

Usage (from the repository root, the NGSIM data beside it):
    python benchmarks/idm_filtered_adjustment.py train 150 ploeg:h=1.1:kp=2.278:kd=10.6313 3 0,0.3,1
(the last two arguments: the adjustment bound in m/s², the time constants in s).
"""
import sys

import numpy as np

from carl_sumo.control.cacc import ploeg_controller
from carl_sumo.config import DT_S
from carl_sumo.control.controllers import ZeroAdjustment, adjustment_bounds
from carl_sumo.data import load_events
from carl_sumo.learn.imitation import teacher_adjustment
from carl_sumo.sim.metrics import aggregate, score_event
from carl_sumo.experiments.simulate import cached_sim, run_event
from carl_sumo.sim.sumo import DEFAULT_NET

DATA = "../shared/data/ngsim/ngsim_cf_events.csv.gz"
KEYS = ("headway_s", "jerk_mps3", "speed_mps", "dampening_ratio", "worst_successive_ratio",
        "ttc_lt_1_5s_count", "collisions")


class FilteredTeacher:
    """IDM + z, z the teacher's adjustment through a first-order filter (TAU = 0: none)."""

    def __init__(self, teacher: str, adj_max: float, tau_s: float):
        self.teacher, self.adj_max, self.tau_s = ploeg_controller(teacher), adj_max, tau_s
        self.bounds = adjustment_bounds(adj_max)
        self.name = f"{teacher} through IDM, |a_adj| <= {adj_max:g}, filter {tau_s:g} s"

    def reset(self, n_followers: int) -> None:
        self.z = np.zeros(n_followers)

    def adjustment(self, obs: np.ndarray) -> np.ndarray:
        target = teacher_adjustment(self.teacher, obs[None, :, :4], self.adj_max)[0]
        self.z = target if self.tau_s == 0 else self.z + (DT_S / self.tau_s) * (target - self.z)
        return self.z


if __name__ == "__main__":
    split, n_events, teacher, adj_max, taus = sys.argv[1:6]
    events = load_events(DATA, split)[:int(n_events)]
    sim = cached_sim(DEFAULT_NET, "external")
    controllers = [ZeroAdjustment(), ploeg_controller(teacher)] + [
        FilteredTeacher(teacher, float(adj_max), float(tau)) for tau in taus.split(",")]
    for controller in controllers:
        m = aggregate([score_event(run_event(sim, e, 10, controller)) for e in events])
        print(f"{getattr(controller, 'name', teacher)}: "
              + "  ".join(f"{k} {m[k]:.4f}" for k in KEYS), flush=True)
