"""``--scenario`` of ``simulate`` and ``replay``: controllers through a cut-in, cut-out, join or
merge (:mod:`carl_sumo.sim.scenario`, :mod:`carl_sumo.study.scenarios`)."""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from typing import TYPE_CHECKING

from carl_sumo.cli.common import fmt
from carl_sumo.files import write_text_atomic

if TYPE_CHECKING:
    from carl_sumo.control.channel import Impairments
    from carl_sumo.data.events import Event

SCENARIO_HELP = ("a manoeuvre in every event: cut-in | cut-out | join | merge, optionally with "
                 "its values fixed, e.g. cut-in:k=3:t=8:f=0.5 (k: position, 0 = the leader; "
                 "t: time, s; f: share of the gap behind an entering vehicle, in (0, 1); merge:"
                 "gap=M, m); what is not fixed is drawn per event (docs/scenarios.md)")

TABLE_COLUMNS = (
    ("done", "done", "{}"), ("min gap (m)", "min_gap_m", "{:.2f}"),
    ("mean min gap (m)", "mean_min_gap_m", "{:.2f}"), ("min TTC (s)", "min_ttc_s", "{:.2f}"),
    ("TTC<1.5 s events", "ttc_lt_1_5s_events", "{}"),
    ("peak decel (m/s²)", "peak_decel_mps2", "{:.2f}"),
    ("max peak decel (m/s²)", "max_peak_decel_mps2", "{:.2f}"),
    ("peak jerk (m/s³)", "peak_jerk_mps3", "{:.1f}"), ("settle (s)", "settle_s", "{:.1f}"),
    ("overshoot (%)", "overshoot", "{:.1%}"), ("collisions", "collisions", "{}"),
)
"""Manoeuvre columns of a scenario table: (header, key of aggregate_manoeuvres, format)."""
RUN_COLUMNS = (("headway (s)", "headway_s", "{:.3f}"), ("jerk (m/s³)", "jerk_mps3", "{:.3f}"),
               ("dampening", "dampening_ratio", "{:.3f}"))
"""Whole-run columns beside them."""


def add_scenario(p: argparse.ArgumentParser) -> None:
    p.add_argument("--scenario", default=None, metavar="KIND[:k=K][:t=T][:f=F]",
                   help=SCENARIO_HELP)
    p.add_argument("--scenario-seed", type=int, default=0,
                   help="seed of the manoeuvre values drawn per event (default 0)")


def _cell(value, form: str) -> str:
    if value is None:
        return "-"
    if isinstance(value, float) and value != value:
        return "nan"
    if isinstance(value, float) and value == float("inf"):
        return "inf"
    return form.format(value)


def scenario_rows(results: list[dict]) -> tuple[list[str], list[list[str]]]:
    """(header, rows) of a scenario table: one row per controller (``n/a: ...`` where it cannot
    run the scenario)."""
    header = ["controller", "events", *(h for h, _, _ in TABLE_COLUMNS),
              *(h for h, _, _ in RUN_COLUMNS)]
    rows = []
    for r in results:
        if "not_applicable" in r:
            rows.append([r["controller"], r["not_applicable"]] + [""] * (len(header) - 2))
            continue
        m, w = r["manoeuvre"], r["metrics"]
        rows.append([r["controller"], str(m["events"]),
                     *(_cell(m[k], f) for _, k, f in TABLE_COLUMNS),
                     *(_cell(w[k], f) for _, k, f in RUN_COLUMNS)])
    return header, rows


def format_scenario_table(results: list[dict]) -> str:
    header, rows = scenario_rows(results)
    widths = [max([len(h), *(len(row[i]) for row in rows)]) for i, h in enumerate(header)]
    line = lambda cells: "  ".join(c.rjust(w) for c, w in zip(cells, widths))  # noqa: E731
    return "\n".join([line(header), line(["-" * w for w in widths]), *map(line, rows)])


def markdown_scenario_table(results: list[dict]) -> str:
    header, rows = scenario_rows(results)
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(row) + " |" for row in rows])


def run_scenario_controllers(names: list[str], spec, events: list[Event], n_followers: int,
                             net: str, impairments: Impairments | None, workers: int,
                             strict: bool) -> list[dict]:
    """Every controller's scenario result; all checked before any simulation (InputError; a
    controller that cannot run it is a ``not_applicable`` row, or an error when ``strict``)."""
    from carl_sumo.study.scenarios import NotApplicable, check_scenario, simulate_scenario

    skipped: dict[str, str] = {}
    for name in names:
        try:
            check_scenario(name, spec, events, n_followers, net, impairments)
        except NotApplicable as exc:
            if strict:
                raise
            skipped[name] = str(exc).split(" (")[0]
    return [{"controller": name, "not_applicable": skipped[name]} if name in skipped else
            simulate_scenario(name, events, n_followers, net, spec, impairments, workers)
            for name in names]


def simulate_with_scenario(args: argparse.Namespace, names: list[str],
                           impairments: Impairments | None, events: list[Event]) -> None:
    """``simulate --scenario``: the table per controller, and ``--json``."""
    from carl_sumo.sim.scenario import parse_scenario

    spec = parse_scenario(args.scenario, args.scenario_seed)
    start = time.perf_counter()
    workers = args.workers or min(2, os.cpu_count() or 1)
    results = run_scenario_controllers(names, spec, events, args.vehicles, args.net, impairments,
                                       workers, strict=len(names) == 1)
    print(format_scenario_table(results))
    print(f"{spec.kind} in {len(events)} events of split {args.split} of {args.data}, "
          f"{args.vehicles} followers, {time.perf_counter() - start:.1f} s")
    if args.json is not None:
        write_text_atomic(args.json, json.dumps({"scenario": args.scenario,
                                                 "scenario_seed": args.scenario_seed,
                                                 "controllers": results}, indent=2,
                                                allow_nan=True, default=float))


def replay_with_scenario(args: argparse.Namespace, event: Event,
                         impairments: Impairments | None) -> None:
    """``replay --scenario``: one event with its manoeuvre, as FCD output."""
    from carl_sumo.sim.scenario import parse_scenario
    from carl_sumo.study.scenarios import replay_scenario

    spec = parse_scenario(args.scenario, args.scenario_seed)
    row = replay_scenario(args.controller, event, args.vehicles, args.fcd, args.net, spec,
                          gui=bool(args.gui), impairments=impairments)
    m = row["manoeuvre_metrics"]
    print(f"wrote {args.fcd}: event {event.event_id}, {args.vehicles} followers, "
          f"{row['manoeuvre']}, controller {args.controller}")
    print(", ".join(f"{k}={fmt(v) if isinstance(v, (int, float)) else v}" for k, v in m.items()
                    if not k.endswith("_by_vehicle")), file=sys.stdout)
