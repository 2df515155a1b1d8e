"""Is there room for the V2V messages? The robust CACC with the two-ahead feed-forward of
``train --imitate two-ahead:c=C`` (carl_sumo/learn/imitation.py), run as a classical law with the
delays a message has: a_adj,i(t) = C·(a_base,i-2(t - 0.2 s) - a_base,i-1(t - 0.1 s)) for i ≥ 2,
two hops and one of the 0.1 s V2V delay. Only messages relayed along the chain carry
a_base,i-2: this is what a communication-aware actor could copy and a CA-off actor could not.

For each C: headway, jerk, dampening, TTC < 1.5 s samples and collisions on ``--events`` random
training events (seed 0), 10 followers, the real plant, ``--warmup 60``; and ‖Γ‖∞ per class of the
fleet at 0.5 and 2 m/s (5 followers, 12 frequencies 0.05-3 rad/s), as ``carl-sumo
string-stability`` measures it. Training events only: C is chosen here, the test split is for
the learned policies.

By default the law runs as the named classical controller ``mpf:<base>:r=2:w2=C``
(carl_sumo/control/feed_forward.py; C = 0: the base): it relays the base's state u (or its
reaction's braking) rather than its applied command, and has no washout (``wo`` of the base is for
a learned term) nor the imitation target's clip. ``--as-adjustment`` runs it as before, as a
learned-style adjustment a_adj on the base (with its ``wo``), the numbers docs/results.md cites.

Usage: python benchmarks/two_ahead.py DATA [--base NAME] [--events 48] [--c 0 0.1 0.2 ...]
                                          [--as-adjustment]
About 5 s per C for 48 events and 5 s per C for the frequency test on 1 core.
"""
import argparse
import time
from dataclasses import replace

import numpy as np

from carl_sumo.control.channel import plant_impairments
from carl_sumo.control.controllers import adjustment_bounds
from carl_sumo.control.transfer import log_frequencies
from carl_sumo.data import load_events
from carl_sumo.errors import InputError
from carl_sumo.experiments.string_stability import SineTest, equilibrium_gap, link_gains, \
    plant_cases
from carl_sumo.learn.env import PlatoonEnv
from carl_sumo.learn.imitation import TARGET_FRACTION
from carl_sumo.learn.selection import validate_events
from carl_sumo.sim.metrics import aggregate

ADJ_MAX_MPS2 = 1.0  # the real recipes' --adj-max
PRODUCT_BASE = "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2:rb=1:wo=5"


class TwoAheadLaw:
    """a_adj of the two-ahead law from each step's observations (n, 5), with the hops' delays:
    the command two ahead as it was 2 steps ago, the predecessor's 1 step ago."""

    def __init__(self, weight: float):
        self.weight, self.history = weight, []

    def act(self, obs: np.ndarray) -> np.ndarray:
        if self.history and self.history[-1].shape != obs.shape:  # a new run
            self.history = []
        self.history = (self.history + [obs.copy()])[-3:]
        if len(self.history) < 3:
            return np.zeros(len(obs))
        two, one = self.history[0], self.history[1]  # 2 steps and 1 step ago
        target = np.zeros(len(obs))
        target[2:] = self.weight * (two[:-2, 4] - one[1:-1, 4])
        bound = TARGET_FRACTION * ADJ_MAX_MPS2  # as the imitation target's
        return np.clip(target, -bound, bound)


def named_law(base: str, weight: float) -> str:
    """``mpf:<base without wo>:r=2:w2=C`` (the base itself at C = 0)."""
    options = [part for part in base.split(":")[1:] if not part.startswith("wo=")]
    if weight == 0:
        return ":".join(["ploeg"] + options)
    return ":".join(["mpf"] + options + ["r=2", f"w2={weight:g}"])


def training_events(data: str, n_events: int) -> list:
    events = load_events(data, "train")
    pick = np.sort(np.random.default_rng(0).choice(len(events), n_events, replace=False))
    return [events[i].with_warmup(60.0) for i in pick]


def named_row(data: str, base: str, n_events: int, weight: float) -> tuple[dict, float, str]:
    """The named law's metrics on the events and its ‖Γ‖∞ (where), as ``carl-sumo simulate`` and
    ``string-stability`` measure them."""
    from carl_sumo.experiments.simulate import simulate
    from carl_sumo.experiments.string_stability import string_stability

    name, real = named_law(base, weight), plant_impairments("real")
    m = simulate(name, training_events(data, n_events), 10, impairments=real)["metrics"]
    worst, where = 0.0, ""
    omegas = log_frequencies(12, 0.05, 3.0)
    for amplitude in (0.5, 2.0):
        try:
            result = string_stability([name], real.plant, real, 5, omegas,
                                      SineTest(amplitude_mps=amplitude))
        except InputError as exc:  # a collision at some frequency
            return m, float("inf"), str(exc)
        for run in result["runs"]:
            if run["hinf"] > worst:
                k = int(np.argmax(run["gain"]))
                worst, where = run["hinf"], f"{run['class']}, {amplitude:g} m/s, " \
                                            f"{omegas[k]:.3f} rad/s"
    return m, worst, where


def events_row(data: str, base: str, n_events: int, weight: float) -> dict:
    events = training_events(data, n_events)
    env = PlatoonEnv(events, 10, base=base, bounds=adjustment_bounds(ADJ_MAX_MPS2))
    _, per_event = validate_events(TwoAheadLaw(weight), env, events, (plant_impairments("real"),))
    return aggregate(per_event)


def hinf(base: str, weight: float, n: int = 5) -> tuple[float, str]:
    """The largest link gain over the fleet's classes, both amplitudes and 12 frequencies."""
    real = plant_impairments("real")
    worst, where = 0.0, ""
    for amplitude in (0.5, 2.0):
        test = SineTest(amplitude_mps=amplitude)
        for cls, case in plant_cases(real.plant):
            for omega in log_frequencies(12, 0.05, 3.0):
                event = test.event(omega, equilibrium_gap(base, test.base_speed_mps))
                env = PlatoonEnv([event], n, base=base, bounds=adjustment_bounds(ADJ_MAX_MPS2))
                law = TwoAheadLaw(weight)
                obs = env.reset_array(event=event, impairments=replace(real, plant=case))
                speeds, leader, done = [env.true_observation[:, 0]], [env.sim.leader_speed], False
                while not done:
                    obs, _, terminated, truncated, _ = env.step_array(law.act(obs))
                    if terminated:
                        return float("inf"), f"collision at {omega:.3f} rad/s, {cls}"
                    speeds.append(env.true_observation[:, 0])
                    leader.append(env.sim.leader_speed)
                    done = truncated
                gain = float(link_gains(np.array(leader), np.array(speeds), omega, test).max())
                if gain > worst:
                    worst, where = gain, f"{cls}, {amplitude:g} m/s, {omega:.3f} rad/s"
    return worst, where


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("data")
    p.add_argument("--base", default=PRODUCT_BASE)
    p.add_argument("--events", type=int, default=48)
    p.add_argument("--c", type=float, nargs="+", default=[0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6])
    p.add_argument("--as-adjustment", action="store_true",
                   help="run the law as an adjustment on the base, as before the named law")
    args = p.parse_args()
    how = "as an adjustment" if args.as_adjustment else f"as {named_law(args.base, 0.3)} (C = 0.3)"
    print(f"base {args.base}, the law {how}, {args.events} training events, real plant, "
          "--warmup 60, 10 followers")
    print("| C | headway (s) | jerk (m/s³) | dampening | TTC < 1.5 s | collisions | ‖Γ‖∞ (where) |"
          "\n|---|---|---|---|---|---|---|")
    for weight in args.c:
        start = time.perf_counter()
        if args.as_adjustment:
            m = events_row(args.data, args.base, args.events, weight)
            worst, where = hinf(args.base, weight)
        else:
            m, worst, where = named_row(args.data, args.base, args.events, weight)
        print(f"| {weight:g} | {m['headway_s']:.3f} | {m['jerk_mps3']:.4f} | "
              f"{m['dampening_ratio']:.4f} | {m['ttc_lt_1_5s_count']} | {m['collisions']} | "
              f"{worst:.4f} ({where}) |  <!-- {time.perf_counter() - start:.0f} s -->", flush=True)


if __name__ == "__main__":
    main()
