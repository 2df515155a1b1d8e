"""``--scenario`` of ``simulate`` and ``replay``: controllers through a cut-in, cut-out, join or
merge (:mod:`carl_sumo.manoeuvres.spec`, :mod:`carl_sumo.manoeuvres.runs`)."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from carl_sumo.cli.common import fmt
from carl_sumo.files import write_text_atomic

if TYPE_CHECKING:
    from carl_sumo.control.channel import Impairments
    from carl_sumo.data.events import Event

SCENARIO_HELP = ("a manoeuvre in every event: cut-in | cut-out | join | merge, optionally with "
                 "its values fixed, e.g. cut-in:k=3:t=8:f=0.5 (k: position, 0 = the leader; "
                 "t: time, s; f: share of the gap behind an entering vehicle, in (0, 1); merge:"
                 "gap=M, m; cut-in:leave=S: the human leaves again S s later; lc=S: lane "
                 "changes take S s, 0 = one step, the default; cut-in/join:wait=S: the "
                 "entering vehicle waits at most S s after t for room, wait=0: at t or not at "
                 "all); what is not fixed "
                 "is drawn per event (docs/scenarios.md)")


def add_scenario(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default=None, metavar="KIND[:k=K][:t=T][:f=F][:lc=S]",
                   help=SCENARIO_HELP)
    p.add_argument("--scenario-seed", type=int, default=0,
                   help="seed of the manoeuvre values drawn per event (default 0)")


def simulate_with_scenario(args: argparse.Namespace, names: list[str],
                           impairments: Impairments | None, events: list[Event]) -> None:
    """``simulate --scenario``: the table per controller, and ``--json``."""
    from carl_sumo.manoeuvres.spec import parse_scenario
    from carl_sumo.manoeuvres.tables import (check_controllers, format_scenario_table,
                                                 result_of, run_jobs)

    spec = parse_scenario(args.scenario, args.scenario_seed)
    skipped = check_controllers(names, spec, events, args.vehicles, args.net, impairments,
                                strict=len(names) == 1)
    start = time.perf_counter()
    workers = max(1, min(args.workers or min(2, os.cpu_count() or 1), len(events) // 5))
    ran = [name for name in names if name not in skipped]
    rows = iter(run_jobs([(name, spec, impairments, events) for name in ran], args.vehicles,
                         args.net, workers, chunks=workers))
    results = [{"controller": name, "not_applicable": skipped[name]} if name in skipped
               else result_of(name, spec, next(rows), args.vehicles) for name in names]
    print(format_scenario_table(results))
    print(f"{spec.kind} in {len(events)} events of split {args.split} of {args.data}, "
          f"{args.vehicles} followers, {time.perf_counter() - start:.1f} s")
    if args.json is not None:
        write_text_atomic(args.json, json.dumps({"scenario": args.scenario,
                                                 "scenario_seed": args.scenario_seed,
                                                 "controllers": results}, indent=2,
                                                allow_nan=True, default=float))


def replay_with_scenario(args: argparse.Namespace, event: Event,
                         impairments: Impairments | None, view=None) -> None:
    """``replay --scenario``: one event with its manoeuvre, as FCD output; ``view``: the
    sumo-gui view of ``--gui`` (carl_sumo.sim.gui.GuiView; no ``--screenshot`` here)."""
    from carl_sumo.errors import InputError
    from carl_sumo.manoeuvres.spec import parse_scenario
    from carl_sumo.manoeuvres.runs import replay_scenario

    spec = parse_scenario(args.scenario, args.scenario_seed)
    if getattr(args, "screenshot", None):
        raise InputError("--screenshot is for replays without --scenario; watch the manoeuvre "
                         "with --gui, or plot its FCD file")
    row = replay_scenario(args.controller, event, args.vehicles, args.fcd, args.net, spec,
                          gui=view or bool(args.gui), impairments=impairments)
    m = row["manoeuvre_metrics"]
    print(f"wrote {args.fcd}: event {event.event_id}, {args.vehicles} followers, "
          f"{row['manoeuvre']}, controller {args.controller}")
    print(", ".join(f"{k}={fmt(v) if isinstance(v, (int, float)) else v}" for k, v in m.items()
                    if not k.endswith("_by_vehicle")), file=sys.stdout)


def evaluate_scenarios(args: argparse.Namespace, workers: int) -> None:
    """``evaluate --suite scenarios``: a table per manoeuvre (``--scenario KIND``: that one)
    and plant (ideal and real) with every controller, written to ``--out``; ``--quick``: 4
    events, 6 followers, a 10 s settled start on the real plant instead of 60 s."""
    from carl_sumo.data import load_events
    from carl_sumo.errors import InputError
    from carl_sumo.manoeuvres.spec import KINDS, parse_scenario
    from carl_sumo.experiments.suite import REAL_WARMUP_S
    from carl_sumo.manoeuvres.tables import run_scenario_tables

    if args.plant != "ideal" or args.fleet or args.vehicle_lag is not None \
            or args.actuation_delay is not None or args.comm_delay is not None \
            or args.comm_loss or args.sensor_noise or args.warmup:
        raise InputError("--suite scenarios runs every table on the ideal and the real plant "
                         "from the recorded start; leave out --plant, --fleet, --comm-*, "
                         "--sensor-noise and --warmup")
    kinds = KINDS if args.scenario is None else (parse_scenario(args.scenario).kind,)
    if args.scenario is not None and ":" in args.scenario:
        raise InputError("--suite scenarios draws every manoeuvre per event; give --scenario "
                         "KIND alone (or run simulate --scenario with fixed values)")
    limit = args.events if args.events is not None else (4 if args.quick else None)
    events = load_events(args.data or "default", "test", limit=limit)
    n = 6 if args.quick else 10
    result = run_scenario_tables(args.out, events, n, args.net, workers,
                                 args.policies or Path("policies"), kinds,
                                 seed=args.scenario_seed,
                                 command="carl-sumo " + " ".join(sys.argv[1:]),
                                 real_warmup_s=10.0 if args.quick else REAL_WARMUP_S)
    print(f"wrote {args.out / 'scenarios.md'} and scenarios.json ({len(result['tables'])} "
          f"tables); wall time {result['wall_time_s']:.0f} s")
