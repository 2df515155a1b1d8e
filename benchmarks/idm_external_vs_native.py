"""How closely `idm-external` (IDM in Python, applied through libsumo) matches SUMO's native IDM.

    python benchmarks/idm_external_vs_native.py --data ../shared/data/ngsim/ngsim_cf_events.csv.gz

Prints the largest speed and gap differences over all followers, samples and events, and the
largest leader replay error (SUMO's leader position and speed against the recording).
"""

from __future__ import annotations

import argparse

import numpy as np

from carl_sumo.control.controllers import ZeroAdjustment
from carl_sumo.data import load_events
from carl_sumo.experiments.simulate import run_event
from carl_sumo.sim.sumo import DEFAULT_NET, PlatoonSim


def leader_replay_error(sim: PlatoonSim, event, n: int) -> tuple[float, float]:
    sim.reset(event, n)
    worst_x = worst_v = 0.0
    while not sim.done:
        sim.step()
        worst_x = max(worst_x, abs(sim.leader_sumo_position() - sim.leader_pos))
        worst_v = max(worst_v, abs(sim.leader_sumo_speed() - sim.leader_speed))
    return worst_x, worst_v


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", default="default")
    parser.add_argument("--split", default="test")
    parser.add_argument("--vehicles", type=int, default=10)
    args = parser.parse_args()
    events = load_events(args.data, args.split)
    native, external = PlatoonSim(DEFAULT_NET, "idm"), PlatoonSim(DEFAULT_NET, "external")
    dv = dgap = replay_x = replay_v = 0.0
    for event in events:
        a = run_event(native, event, args.vehicles, None)
        b = run_event(external, event, args.vehicles, ZeroAdjustment())
        steps = min(len(a.speed), len(b.speed))
        dv = max(dv, float(np.abs(a.speed[:steps] - b.speed[:steps]).max()))
        dgap = max(dgap, float(np.abs(a.gap[:steps] - b.gap[:steps]).max()))
        x, v = leader_replay_error(native, event, args.vehicles)
        replay_x, replay_v = max(replay_x, x), max(replay_v, v)
    print(f"{len(events)} events, {args.vehicles} followers")
    print(f"idm vs idm-external: max |speed difference| {dv:.3e} m/s, max |gap difference| "
          f"{dgap:.3e} m")
    print(f"leader replay: max |position error| {replay_x:.3e} m, max |speed error| "
          f"{replay_v:.3e} m/s")


if __name__ == "__main__":
    main()
