"""How long the distributed MPC (``mpc``, carl_sumo/control/mpc.py) takes per vehicle and step.

Runs the law on ``--events`` NGSIM events (evenly spaced over the split), ``--vehicles``
followers, the real plant (0.1 s V2V delay, the default fleet) and ``--warmup`` s, and reports
per vehicle and step, in µs: OSQP's own solve time (mean, p50, p95, p99, max; OSQP's
``info.solve_time``, the update of q and the bounds not included) and the wall time of the
whole law (its ``acceleration`` call over the platoon, divided by the followers: the data,
the prediction of the predecessor, the solve and the layers), and the wall time of the run with
SUMO, as wall and as CPU time (on a shared machine the wall times carry the waits for a core:
OSQP's ``solve_time`` is a wall time).

Usage: python benchmarks/mpc_solve.py DATA [--controller mpc] [--events 10] [--split test]
                                           [--vehicles 10] [--warmup 60]
"""
import argparse
import time

import numpy as np

from carl_sumo.control.channel import plant_impairments
from carl_sumo.control.mpc import mpc_controller
from carl_sumo.data import load_events
from carl_sumo.experiments.simulate import cached_sim, run_event
from carl_sumo.sim.sumo import DEFAULT_NET


class Timed:
    """The law with the wall and CPU time of every ``acceleration`` call kept (s per vehicle)."""

    def __init__(self, law):
        self.law, self.calls, self.cpu = law, [], []

    def __getattr__(self, name):
        return getattr(self.law, name)

    def acceleration(self, obs):
        start, cpu = time.perf_counter(), time.process_time()
        out = self.law.acceleration(obs)
        self.calls.append((time.perf_counter() - start) / obs.shape[0])
        self.cpu.append((time.process_time() - cpu) / obs.shape[0])
        return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("data")
    ap.add_argument("--controller", default="mpc")
    ap.add_argument("--events", type=int, default=10)
    ap.add_argument("--split", default="test")
    ap.add_argument("--vehicles", type=int, default=10)
    ap.add_argument("--warmup", type=float, default=60.0)
    args = ap.parse_args()
    events = load_events(args.data, args.split)
    events = [e.with_warmup(args.warmup) for e in
              events[::max(len(events) // args.events, 1)][:args.events]]
    law = mpc_controller(args.controller)
    law.timed = True
    timed = Timed(law)
    sim, imp = cached_sim(DEFAULT_NET, "external"), plant_impairments("real")
    run_event(sim, events[0], args.vehicles, timed, impairments=imp)  # set-up and compilation
    law.solve_s, timed.calls, timed.cpu = [], [], []
    start, cpu_start, steps = time.perf_counter(), time.process_time(), 0
    for e in events:
        traj = run_event(sim, e, args.vehicles, timed, impairments=imp)
        steps += (len(traj.leader_speed) + e.scored_from) * args.vehicles
    wall, cpu = time.perf_counter() - start, time.process_time() - cpu_start
    solve, call = np.array(law.solve_s) * 1e6, np.array(timed.calls) * 1e6
    call_cpu = np.array(timed.cpu) * 1e6
    print(f"{args.controller}: {len(events)} events of {args.split}, {args.vehicles} followers, "
          f"real plant, warm-up {args.warmup:g} s: {solve.size} solves")
    print("OSQP solve per vehicle step (µs): mean {:.1f}  p50 {:.1f}  p95 {:.1f}  p99 {:.1f}  "
          "max {:.1f}".format(solve.mean(), *np.percentile(solve, [50, 95, 99]), solve.max()))
    print("whole law per vehicle step (µs):  mean {:.1f}  p50 {:.1f}  p95 {:.1f}".format(
        call.mean(), *np.percentile(call, [50, 95])))
    print("whole law per vehicle step, CPU time (µs): mean {:.1f}  p50 {:.1f}  p95 {:.1f}".format(
        call_cpu.mean(), *np.percentile(call_cpu, [50, 95])))
    print(f"run with SUMO: {wall:.1f} s wall, {cpu:.1f} s CPU, "
          f"{cpu / max(steps, 1) * 1e6:.1f} µs CPU per vehicle step")


if __name__ == "__main__":
    main()
