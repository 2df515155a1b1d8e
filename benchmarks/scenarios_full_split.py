"""Issue 35's criterion on the full NGSIM test split: the product CA-RL against its own tuned
CACC through every manoeuvre, 10 followers, scenario seed 0; manoeuvre columns paired over the
events in which both did the manoeuvre (as ``evaluate --suite scenarios``). Real plant
(``--plant real --warmup 60``): the product ``policies/ca_td3_real_10.pt`` against the law it
learned on, ``mpf-tuned`` (what RL added in manoeuvres; the former product's tables, against the
tuned CACC at h = 0.8 s and at the product's own gaps, were made with ``--base`` and
``--product``, docs/scenarios.md); ideal plant (the recorded start):
``policies/ca_td3_ploeg_10.pt`` against ``ploeg-tuned:h=0.8``.

Beside each table, the bar event by event (:mod:`carl_sumo.manoeuvres.criterion`): the
product's collisions and TTC < 1.5 s events where the base has none, and its peak deceleration
and settle time minus the base's with a paired bootstrap interval.

Writes ``docs/results_scenarios/full_split_<PLANT>.md`` (a table per manoeuvre) and
``full_split_<PLANT>.json`` (the aggregates, no per-event rows); ``--base``/``--product`` run
another pair, ``--stem`` names the files, ``--kinds`` runs some manoeuvres only, and ``--wait S``
lets an entering vehicle (cut-in, join) wait at most S s after its drawn time for room
(``--wait 0``: both controllers meet it at the same moment or not at all); ``--options`` adds
``--scenario`` keys to every manoeuvre (``--options signal=2:lc=3``: a signalled, gradual
cut-in); ``--split train`` runs the training split instead, where a design is chosen before the
test split scores it once. 5 minutes (real: 69 s of cut-ins, 214 s for the rest) and 2 (ideal:
97 s) on 2 free cores.

Usage: python benchmarks/scenarios_full_split.py DATA [real|ideal] [--base NAME --product PT
       --stem STEM --kinds cut-in,join --wait S --options KEY=VALUE[:KEY=VALUE] --split train]
"""
import argparse
import json
import time
from pathlib import Path

from carl_sumo.control.channel import plant_impairments
from carl_sumo.data import load_events
from carl_sumo.files import write_text_atomic
from dataclasses import replace

from carl_sumo.errors import InputError
from carl_sumo.manoeuvres.spec import KINDS, parse_scenario
from carl_sumo.sim.sumo import DEFAULT_NET
from carl_sumo.experiments.suite import REAL_WARMUP_S
from carl_sumo.manoeuvres.tables import (markdown_scenario_table, paired,
                                             result_of, run_jobs)
from carl_sumo.manoeuvres.criterion import criterion_lines, manoeuvre_criterion

OUT = Path("docs/results_scenarios")
CONTROLLERS = {"real": ("mpf-tuned", "policies/ca_td3_real_10.pt"),
               "ideal": ("ploeg-tuned:h=0.8", "policies/ca_td3_ploeg_10.pt")}
N_FOLLOWERS = 10


def main(data: str, plant: str, controllers: tuple[str, str], stem: str,
         kinds: tuple[str, ...] = KINDS, wait_s: float | None = None, options: str = "",
         split: str = "test") -> None:
    events = load_events(data, split)
    if plant == "real":
        events = [e.with_warmup(REAL_WARMUP_S) for e in events]
    imp = plant_impairments(plant)
    start = time.perf_counter()
    tables, lines = {}, []
    for kind in kinds:
        spec = parse_scenario(f"{kind}:{options}" if options else kind)
        if wait_s is not None and kind in ("cut-in", "join"):
            spec = replace(spec, wait_s=wait_s)
        rows = run_jobs([(name, spec, imp, events) for name in controllers], N_FOLLOWERS,
                        str(DEFAULT_NET), workers=2, chunks=2)
        results = paired([result_of(name, spec, r, N_FOLLOWERS)
                          for name, r in zip(controllers, rows)])
        crit = manoeuvre_criterion(results[1], results[0])
        tables[kind] = [{k: v for k, v in r.items() if k != "events"} for r in results]
        tables[kind].append({"criterion": crit})
        n = results[0]["manoeuvre"].get("paired_events")
        table = markdown_scenario_table(results).replace(
            "the same with its reaction layer ttc=2 s",
            "Ploeg h=0.8 s, aw=1, ha=1.4 s, ttc=2 s (the base)")
        lines += [f"## {kind}, {plant} plant ({n} paired events)", "", table, "",
                  f"{controllers[1]} against {controllers[0]}:", "", *criterion_lines(crit), ""]
        print(f"{kind}: {time.perf_counter() - start:.0f} s", flush=True)
    wall = time.perf_counter() - start
    start_text = "60 s settled start" if plant == "real" else "the recorded start"
    head = [f"# Scenarios on the full NGSIM {split} split, {plant} plant ({len(events)} events)", "",
            f"`python benchmarks/scenarios_full_split.py {data} {plant} --base {controllers[0]} "
            f"--product {controllers[1]} --stem {stem}"
            + (f" --kinds {','.join(kinds)}" if kinds != KINDS else "")
            + (f" --wait {wait_s:g}" if wait_s is not None else "")
            + (f" --options {options}" if options else "")
            + (f" --split {split}" if split != "test" else "") + f"` ({wall:.0f} s), 10 "
            f"followers, {start_text}, scenario seed 0. Manoeuvre columns are paired over "
            "the events in which both controllers did the manoeuvre; `done` is each one's own "
            "count.", ""]
    write_text_atomic(OUT / f"{stem}.md", "\n".join(head + lines))
    write_text_atomic(OUT / f"{stem}.json", json.dumps(
        {"data": data, "plant": plant, "split": split, "events": len(events),
         "wait_s": wait_s, "options": options, "wall_time_s": wall, "tables": tables},
        indent=2, allow_nan=True, default=float))


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("data")
    parser.add_argument("plant", nargs="?", default="real", choices=sorted(CONTROLLERS))
    parser.add_argument("--base", help="the reference controller (default: the plant's base)")
    parser.add_argument("--product", help="the product policy file (default: the plant's)")
    parser.add_argument("--stem", help="output file stem (default: full_split_PLANT)")
    parser.add_argument("--kinds", default=",".join(KINDS), help="manoeuvres, comma-separated")
    parser.add_argument("--wait", type=float, default=None, metavar="S",
                        help="an entering vehicle waits at most S s after its time for room")
    parser.add_argument("--options", default="", metavar="KEY=VALUE[:KEY=VALUE]",
                        help="--scenario keys for every manoeuvre, e.g. signal=2:lc=3")
    parser.add_argument("--split", default="test", choices=("test", "train"),
                        help="the events: the test split (scored once), or the training split "
                             "(where a design is chosen)")
    args = parser.parse_args()
    kinds = tuple(args.kinds.split(","))
    if not set(kinds) <= set(KINDS) or (args.wait is not None and args.wait < 0):
        parser.error(f"--kinds takes {', '.join(KINDS)}; --wait takes 0 s or more")
    for kind in kinds:
        try:
            parse_scenario(f"{kind}:{args.options}" if args.options else kind)
        except InputError as exc:
            parser.error(str(exc))
    base, product = CONTROLLERS[args.plant]
    main(args.data, args.plant, (args.base or base, args.product or product),
         args.stem or f"full_split_{args.plant}", kinds, args.wait, args.options, args.split)
