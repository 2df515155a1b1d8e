"""A table per manoeuvre and plant: every controller through cut-in, cut-out, join and merge
(``carl-sumo evaluate --suite scenarios``, :mod:`carl_sumo.manoeuvres.runs`).

Each (manoeuvre, plant) table has one row per controller of :data:`PLANT_CONTROLLERS`, run on the
same events with the same drawn manoeuvre (``--scenario-seed``). The ``done`` column counts the
events in which the manoeuvre happened (an entering vehicle waits for a gap with room: a platoon
that keeps short gaps at low speed may never offer one); every other manoeuvre column is taken
over the events in which it happened for every controller of the table (paired), so that the
rows compare the same manoeuvres. The whole-run columns are over all events.
"""

from __future__ import annotations

import json
import time
from pathlib import Path
from typing import Sequence

from carl_sumo.control.channel import Impairments, plant_impairments
from carl_sumo.control.ploeg_names import PRESETS
from carl_sumo.data.events import Event
# The real plant's tables start settled, as ``evaluate --suite real``: from the recorded gap,
# plain runs (no manoeuvre) of the tuned CACC on the real fleet have 16 collisions in the 53
# default test events, on the ideal plant none.
from carl_sumo.experiments.suite import (PRODUCT_BASE_LABEL, PRODUCT_MPC, PRODUCT_MPF,
                                        REAL_WARMUP_S)
from carl_sumo.files import write_text_atomic
from carl_sumo.resources import PRODUCT
from carl_sumo.scale.workers import run_parallel
from carl_sumo.manoeuvres.metrics import aggregate_manoeuvres
from carl_sumo.sim.metrics import aggregate
from carl_sumo.manoeuvres.spec import KINDS, ScenarioSpec
from carl_sumo.manoeuvres.runs import NotApplicable, check_scenario, scenario_scores

ROBUST_AW = "ploeg:h=0.8:kp=0.0445:kd=1:aw=1"
"""The robust real-plant CACC (``ploeg-tuned:h=0.8``'s gains on the real plant) with anti-windup:
each vehicle's state, its V2V message, within its own class's limits."""
ROBUST_HA = ROBUST_AW + ":ha=1.4"
""":data:`ROBUST_AW` as a degraded CACC: a vehicle that hears no V2V message (the first follower,
the follower behind a cut-in human, a merge's second platoon before it links) runs the law as an
ACC at the time gap 1.4 s."""
ROBUST_TTC = ROBUST_HA + ":ttc=2"
""":data:`ROBUST_HA` with its reaction layer: a vehicle that hears no message brakes at once when
its time to collision drops below 2 s (:mod:`carl_sumo.control.cacc`)."""
PRODUCT_BASE = PRESETS["product-base"]
"""The one-predecessor CACC at the real-plant product's gaps, h = 0.6 s and trucks at 0.8 s, with
its layers: the law the product's start (:data:`carl_sumo.experiments.suite.PRODUCT_MPF`) adds
the feed-forward of the vehicles ahead to."""
PLANT_CONTROLLERS = {
    "ideal": ("idm", "sumo-cacc", "acc:h=2.5:kp=0.45:kd=1.5", "ploeg-tuned:h=0.8",
              "ca_td3_10.pt", "ca_td3_ploeg_10.pt", "maddpg_10.pt"),
    "real": ("idm-external", "acc-tuned:h=2.5", "ploeg-tuned:h=0.8", ROBUST_AW, ROBUST_HA,
             ROBUST_TTC, "ca_td3_10.pt", "ca_td3_ploeg_10.pt", PRODUCT_BASE, PRODUCT_MPF,
             PRODUCT, PRODUCT_MPC, "maddpg_10.pt"),
}
"""The controllers of each plant's tables (policy files in the policies folder): SUMO's IDM (run
by carl-sumo on the real plant, whose vehicles SUMO's models cannot drive) and SUMO's CACC (the
ideal plant only), the ACC at h = 2.5 s with the gains tuned for the fleet, the tuned Ploeg CACC
at h = 0.8 s (the gains tuned for each plant; on the real plant also with anti-windup,
:data:`ROBUST_AW`, that as a degraded CACC, :data:`ROBUST_HA`, and that with its reaction
layer, :data:`ROBUST_TTC`), the paper's CA-TD3 on IDM, CA-TD3 on the tuned CACC of the ideal
plant, the CACC at h = 0.6 s with its layers (``gn=6``, ``op=2``, trucks at 0.8 s, ``ht=0.8``),
:data:`PRODUCT_BASE`, that law with the feed-forward of the vehicles ahead tuned for the fleet
(:data:`carl_sumo.experiments.suite.PRODUCT_MPF`, ``carl-sumo tune mpf``), the real-plant
product that learned on it (:data:`carl_sumo.resources.PRODUCT`), the distributed MPC tuned for
the fleet at the same gap (:data:`carl_sumo.experiments.suite.PRODUCT_MPC`, ``carl-sumo tune
mpc``), and MADDPG (n/a: fixed size)."""
LABELS = {"idm": "IDM (SUMO)", "idm-external": "IDM (carl-sumo, on the plant)",
          "sumo-cacc": "CACC (SUMO)", "acc:h=2.5:kp=0.45:kd=1.5": "ACC h=2.5 s (fleet gains)",
          "acc-tuned:h=2.5": "ACC tuned h=2.5 s", "ploeg-tuned:h=0.8": "Ploeg tuned h=0.8 s",
          "ca_td3_10.pt": "CA-TD3 on IDM (paper)", "ca_td3_ploeg_10.pt": "CA-TD3 product (ideal)",
          ROBUST_AW: "Ploeg tuned h=0.8 s, aw=1",
          ROBUST_HA: "Ploeg tuned h=0.8 s, aw=1, degraded ha=1.4 s",
          ROBUST_TTC: "the same with its reaction layer ttc=2 s",
          PRODUCT_BASE: PRODUCT_BASE_LABEL,
          PRODUCT_MPF: "multi-predecessor CACC tuned for the fleet on the product's base",
          PRODUCT: "CA-TD3 product (real, learned on mpf-tuned, h=0.6 s, trucks 0.8 s)",
          PRODUCT_MPC: "distributed MPC tuned for the fleet, h=0.6 s, trucks 0.8 s",
          "maddpg_10.pt": "MADDPG"}
TABLE_COLUMNS = (
    ("done", "done", "{}"), ("min gap (m)", "min_gap_m", "{:.2f}"),
    ("mean min gap (m)", "mean_min_gap_m", "{:.2f}"), ("min TTC (s)", "min_ttc_s", "{:.2f}"),
    ("TTC<1.5 s events", "ttc_lt_1_5s_events", "{}"),
    ("peak decel (m/s²)", "peak_decel_mps2", "{:.2f}"),
    ("max peak decel (m/s²)", "max_peak_decel_mps2", "{:.2f}"),
    ("peak jerk (m/s³)", "peak_jerk_mps3", "{:.1f}"), ("settle (s)", "settle_s", "{:.1f}"),
    ("overshoot (%)", "overshoot", "{:.1%}"), ("collisions after", "collisions", "{}"),
)
"""Manoeuvre columns: (header, key of aggregate_manoeuvres, format)."""
RUN_COLUMNS = (("headway (s)", "headway_s", "{:.3f}"), ("jerk (m/s³)", "jerk_mps3", "{:.3f}"),
               ("dampening", "dampening_ratio", "{:.3f}"), ("run collisions", "collisions", "{}"))
"""Whole-run columns beside them."""


def check_controllers(names: Sequence[str], spec: ScenarioSpec, events: Sequence[Event],
                      n_followers: int, net: str, impairments: Impairments | None,
                      strict: bool) -> dict[str, str]:
    """{name: why not} of the controllers that cannot run the scenario; every other error (and
    with ``strict`` that one too) raised now, before any simulation."""
    skipped: dict[str, str] = {}
    for name in names:
        try:
            check_scenario(name, spec, events, n_followers, net, impairments)
        except NotApplicable as exc:
            if strict:
                raise
            skipped[name] = str(exc).split(" (")[0]
    return skipped


Job = tuple[str, ScenarioSpec, "Impairments | None", Sequence[Event]]
"""One controller, manoeuvre spec, plant and its events."""


def run_jobs(jobs: Sequence[Job], n_followers: int, net: str, workers: int,
             chunks: int) -> list[list[dict]]:
    """Per-event rows of every (controller, spec, impairments, events) job, in one pool of
    ``workers`` processes, each job's events in ``chunks`` tasks; rows back in event order."""
    items, spans = [], []
    for name, spec, imp, events in jobs:
        k = max(1, min(chunks, len(events)))
        spans.append((len(items), len(items) + k, {e.event_id: i for i, e in enumerate(events)}))
        items += [(name, list(events[i::k]), n_followers, net, spec, imp) for i in range(k)]
    if workers <= 1:
        results = [scenario_scores(*item) for item in items]
    else:
        results = list(run_parallel(scenario_scores, items, workers,
                                    describe=lambda a: f"{a[0]} {a[4].kind} from "
                                                       f"{a[1][0].event_id}"))
    return [sorted((r for part in results[lo:hi] for r in part),
                   key=lambda r: order[r["event_id"]]) for lo, hi, order in spans]


def result_of(name: str, spec: ScenarioSpec, rows: list[dict], n_followers: int) -> dict:
    return {"controller": name, "followers": n_followers, "scenario": spec.kind,
            "metrics": aggregate(rows),
            "manoeuvre": aggregate_manoeuvres([r["manoeuvre_metrics"] for r in rows]),
            "events": rows}


def paired(results: list[dict]) -> list[dict]:
    """The results with their manoeuvre columns over the events every controller that ran did
    the manoeuvre in (``done`` stays each controller's own count, ``paired_events`` is added)."""
    ran = [r for r in results if "not_applicable" not in r]
    if not ran:
        return results
    common = set.intersection(*({e["event_id"] for e in r["events"]
                                 if e["manoeuvre_metrics"]["done"]} for r in ran))
    out = []
    for r in results:
        if "not_applicable" in r:
            out.append(r)
            continue
        agg = aggregate_manoeuvres([e["manoeuvre_metrics"] for e in r["events"]
                                    if e["event_id"] in common])
        agg["done"], agg["events"] = r["manoeuvre"]["done"], r["manoeuvre"]["events"]
        out.append({**r, "manoeuvre": {**agg, "paired_events": len(common)}})
    return out


def _cell(value, form: str) -> str:
    if isinstance(value, float) and value != value:
        return "nan"
    if isinstance(value, float) and value == float("inf"):
        return "inf"
    return form.format(value)


def scenario_rows(results: list[dict], labels: dict[str, str] | None = None
                  ) -> tuple[list[str], list[list[str]]]:
    """(header, rows) of a scenario table: one row per controller (``n/a: ...`` where it cannot
    run the scenario)."""
    labels = labels or {}
    plain = any("plain" in r for r in results)
    header = ["controller", "events", *(h for h, _, _ in TABLE_COLUMNS),
              *(h for h, _, _ in RUN_COLUMNS)] + (["plain-run collisions"] if plain else [])
    rows = []
    for r in results:
        name = labels.get(Path(r["controller"]).name, r["controller"])
        if "not_applicable" in r:
            rows.append([name, r["not_applicable"]] + [""] * (len(header) - 2))
            continue
        m, w = r["manoeuvre"], r["metrics"]
        rows.append([name, str(m["events"]), *(_cell(m[k], f) for _, k, f in TABLE_COLUMNS),
                     *(_cell(w[k], f) for _, k, f in RUN_COLUMNS)]
                    + ([str(r["plain"]["collisions"]) if "plain" in r else "-"] if plain else []))
    return header, rows


def format_scenario_table(results: list[dict]) -> str:
    """A plain-text table (what ``simulate --scenario`` prints)."""
    header, rows = scenario_rows(results)
    widths = [max([len(h), *(len(row[i]) for row in rows)]) for i, h in enumerate(header)]
    line = lambda cells: "  ".join(c.rjust(w) for c, w in zip(cells, widths))  # noqa: E731
    return "\n".join([line(header), line(["-" * w for w in widths]), *map(line, rows)])


def markdown_scenario_table(results: list[dict]) -> str:
    header, rows = scenario_rows(results, LABELS)
    lines = ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    return "\n".join(lines + ["| " + " | ".join(row) + " |" for row in rows])


def run_scenario_tables(out: Path, events: Sequence[Event], n_followers: int, net: str,
                        workers: int, policies: Path, kinds: Sequence[str] = KINDS,
                        plants: Sequence[str] = ("ideal", "real"), seed: int = 0,
                        command: str = "", real_warmup_s: float = REAL_WARMUP_S) -> dict:
    """Every table, written to ``out/scenarios.md`` and ``out/scenarios.json``; returns
    ``{"tables": {"KIND PLANT": results}, "wall_time_s"}``. Everything is checked first. The
    ideal plant starts at the recorded gap, the real one settled (``real_warmup_s``)."""
    start = time.perf_counter()
    plan, jobs = [], []
    for kind in kinds:
        spec = ScenarioSpec(kind, seed=seed)
        for plant in plants:
            imp = plant_impairments(plant)
            plant_events = [e.with_warmup(real_warmup_s) for e in events] if plant == "real" \
                else list(events)
            names = [str(policies / c) if c.endswith(".pt") else c
                     for c in PLANT_CONTROLLERS[plant]]
            skipped = check_controllers(names, spec, plant_events, n_followers, net, imp, False)
            plan.append((kind, plant, spec, names, skipped))
            jobs += [(name, spec, imp, plant_events) for name in names if name not in skipped]
    rows = iter(run_jobs(jobs, n_followers, net, workers, chunks=max(1, workers)))
    plain = plain_runs(jobs, n_followers, net, workers)
    tables = {}
    for kind, plant, spec, names, skipped in plan:
        tables[f"{kind} {plant}"] = paired([
            {"controller": n, "not_applicable": skipped[n]} if n in skipped
            else {**result_of(n, spec, next(rows), n_followers), "plain": plain[(n, plant)]}
            for n in names])
    figures = example_figures(out, tables, events, n_followers, net, policies, kinds, seed)
    wall = time.perf_counter() - start
    _write(out, tables, events, n_followers, seed, command, wall, figures, real_warmup_s)
    return {"tables": tables, "wall_time_s": wall, "figures": figures}


def plain_runs(jobs: Sequence[Job], n_followers: int, net: str, workers: int
               ) -> dict[tuple[str, str], dict]:
    """{(controller, plant): whole-run metrics without a manoeuvre} on the same events and
    plant (:func:`carl_sumo.experiments.simulate.simulate_jobs`): what the controller does there
    anyway, beside what it does with the manoeuvre."""
    from carl_sumo.experiments.simulate import score_events, simulate_jobs

    out: dict[tuple[str, str], dict] = {}
    for plant in ("ideal", "real"):
        todo = {(name, id(imp)): (name, imp, events) for name, _, imp, events in jobs
                if (imp is None) == (plant == "ideal")}
        if not todo:
            continue
        names = sorted({name for name, _ in todo})
        imp, events = next(iter(todo.values()))[1:]
        if workers <= 1:  # in this process: a pool of one costs a process start
            metrics = [aggregate(score_events(name, events, n_followers, net, False, imp))
                       for name in names]
        else:
            metrics = [r["metrics"] for r in simulate_jobs(
                [(name, imp) for name in names], events, n_followers, net, workers,
                chunks=max(1, workers))]
        out.update({(name, plant): m for name, m in zip(names, metrics)})
    return out


EXAMPLE_CONTROLLER = "ca_td3_ploeg_10.pt"
"""The controller of each scenario's example replay (the product on the ideal plant)."""


def example_figures(out: Path, tables: dict, events: Sequence[Event], n_followers: int,
                    net: str, policies: Path, kinds: Sequence[str], seed: int
                    ) -> dict[str, str]:
    """{kind: event ID} of one replay per manoeuvre (FCD in ``out/fcd``, a time-space figure
    ``out/<kind>.png``) with :data:`EXAMPLE_CONTROLLER` on the ideal plant, on the first event
    in which every controller of the ideal table did the manoeuvre."""
    from carl_sumo.manoeuvres.figures import manoeuvre_examples

    chosen = {}
    for kind in kinds:
        results = [r for r in tables.get(f"{kind} ideal", []) if "events" in r]
        if not results:
            continue
        done = set.intersection(*({e["event_id"] for e in r["events"]
                                   if e["manoeuvre_metrics"]["done"]} for r in results))
        event = next((e for e in events if e.event_id in done), None)
        if event is None:
            continue
        manoeuvre_examples(out, event, n_followers, net, str(policies / EXAMPLE_CONTROLLER),
                           [kind], seed)
        chosen[kind] = event.event_id
    return chosen


def _write(out: Path, tables: dict, events: Sequence[Event], n_followers: int, seed: int,
           command: str, wall_s: float, figures: dict[str, str], real_warmup_s: float) -> None:
    out.mkdir(parents=True, exist_ok=True)
    lines = ["# Controllers through manoeuvres", "",
             f"`{command}`: {len(events)} events, {n_followers} followers, scenario seed {seed}, "
             f"the ideal plant from the recorded start, the real plant from a "
             f"{real_warmup_s:g} s settled start, "
             f"wall time {wall_s:.0f} s. Manoeuvre columns over the events in which every "
             "controller of the table did the manoeuvre (paired); `done`: each controller's "
             "own count. What the columns mean: docs/scenarios.md.", ""]
    for key, results in tables.items():
        paired_n = next((r["manoeuvre"].get("paired_events") for r in results
                         if "manoeuvre" in r), 0)
        lines += [f"## {key} plant ({paired_n} paired events)", "",
                  markdown_scenario_table(results), ""]
        kind = key.split()[0]
        if key.endswith("ideal") and kind in figures:
            lines += [f"![{kind}]({kind}.png)", "",
                      f"{kind} in event {figures[kind]} with {EXAMPLE_CONTROLLER} (ideal plant); "
                      f"its FCD: `fcd/{kind}.xml`.", ""]
    write_text_atomic(out / "scenarios.md", "\n".join(lines))
    slim = {k: [{key: v for key, v in r.items() if key != "events"} for r in results]
            for k, results in tables.items()}
    write_text_atomic(out / "scenarios.json", json.dumps(
        {"command": command, "events": [e.event_id for e in events], "followers": n_followers,
         "scenario_seed": seed, "tables": slim,
         "per_event": {k: {r["controller"]: r["events"] for r in results if "events" in r}
                       for k, results in tables.items()}},
        indent=1, allow_nan=True, default=float))
