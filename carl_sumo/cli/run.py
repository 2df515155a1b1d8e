"""The commands that run controllers on events: ``simulate``, ``replay``, ``evaluate``, ``bench``."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from contextlib import nullcontext
from pathlib import Path
from typing import TYPE_CHECKING

from carl_sumo.cli.common import (NET_HELP, controller_option, net_option, add_common,
                                  add_impairments, add_plant, add_ray, add_warmup, check_ray, fmt,
                                  impairments_from, positive, ray_session, warmup_from,
                                  workers_for)
from carl_sumo.cli.scenario import (add_scenario, evaluate_scenarios, replay_with_scenario,
                                    simulate_with_scenario)
from carl_sumo.errors import InputError
from carl_sumo.progress import progress_mode
from carl_sumo.files import (atomic_path, check_output_file,
                             check_output_names, write_text_atomic)

if TYPE_CHECKING:
    from carl_sumo.control.channel import Impairments



def format_table(results: list[dict]) -> str:
    from carl_sumo.sim.metrics import METRIC_KEYS

    header = ["controller", "followers", "events", *METRIC_KEYS]
    rows = [[r["controller"], str(r["followers"]), str(len(r["events"])),
             *(fmt(r["metrics"][k]) for k in METRIC_KEYS)] for r in results]
    widths = [max([len(h), *(len(row[i]) for row in rows)]) for i, h in enumerate(header)]
    line = lambda cells: "  ".join(c.rjust(w) for c, w in zip(cells, widths))  # noqa: E731
    return "\n".join([line(header), line(["-" * w for w in widths]), *map(line, rows)])


def _simulate_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="run controllers on the events of a split; print metrics")
    add_common(p)
    p.add_argument("--controller", type=controller_option, default="idm",
                   help="product (the shipped real-plant CA-TD3; with --plant real) | idm | "
                        "krauss | sumo-cacc | idm-external | ploeg[:h=H:kp=KP:kd=KD] | "
                        "ploeg-tuned:h=H | mpf[:r=R:wJ=W:...] | mpf-tuned | mpc[:h=H:N=N:wq=..:"
                        "wv=..:wu=..:wj=..] (distributed MPC) | mpc-tuned | human | POLICY.pt "
                        "(a shipped one by its file name from any folder); several with commas")
    p.add_argument("--events", type=int, default=None, metavar="K", help="only the first K events")
    p.add_argument("--json", type=Path, default=None, metavar="OUT", help="write metrics as JSON")
    p.add_argument("--workers", type=int, default=None,
                   help="parallel SUMO processes (default: 2, or the number of cores if fewer; "
                        "with --ray: the cluster's CPUs)")
    add_ray(p)
    add_impairments(p)
    add_warmup(p)
    add_scenario(p)


def cmd_simulate(args: argparse.Namespace) -> None:
    from carl_sumo.data import load_events
    from carl_sumo.experiments.simulate import check_impairable, plant_of, resolve_controller, simulate

    positive(args.vehicles, "--vehicles")
    impairments = impairments_from(args)
    warmup_s = warmup_from(args)
    if args.json is not None:
        check_output_file(args.json, "--json")
    if args.events is not None:
        positive(args.events, "--events")
    names = [c.strip() for c in args.controller.split(",") if c.strip()]
    if not names:
        raise InputError(f"--controller {args.controller!r} names no controller; give one or "
                         "more of idm, krauss, sumo-cacc, idm-external, ploeg, ploeg-tuned:h=H, "
                         "human or a policy file, separated by commas")
    for name in names:  # fail on a bad controller or platoon length before any simulation runs
        check_impairable(name, impairments)
        _, controller = resolve_controller(name, plant_of(impairments))
        if controller is not None and args.scenario is None:  # --scenario: n/a rows instead
            controller.reset(args.vehicles)
    if args.workers is not None:
        positive(args.workers, "--workers")
    check_ray(args)
    events = [e.with_warmup(warmup_s) for e in load_events(args.data, args.split,
                                                             limit=args.events)]
    if args.scenario is not None:  # a manoeuvre in every event (carl_sumo.cli.scenario)
        return simulate_with_scenario(args, names, impairments, events)
    start = time.perf_counter()
    with ray_session(args, args.workers or os.cpu_count()):
        workers = workers_for(args, min(2, os.cpu_count() or 1))
        results = [simulate(name, events, args.vehicles, args.net, progress=progress_mode(),
                            workers=workers, impairments=impairments) for name in names]
    print(format_table(results))
    print(f"{len(events)} events of split {args.split} of {args.data}, "
          f"{time.perf_counter() - start:.1f} s")
    if args.json is not None:
        payload = {k: results[0][k] for k in ("metrics", "events", "controller", "followers")} \
            if len(results) == 1 else {"controllers": {r["controller"]: r for r in results}}
        write_text_atomic(args.json, json.dumps(payload, indent=2, allow_nan=True))


def _replay_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("replay", help="run one event and write SUMO FCD output")
    add_common(p, split_default="all")
    p.add_argument("--controller", type=controller_option, default="idm",
                   help="idm | krauss | sumo-cacc | idm-external | ploeg[:h=H:kp=KP:kd=KD] | "
                        "ploeg-tuned:h=H | POLICY.pt")
    p.add_argument("--event", required=True, help="event ID (stop_and_go with --data stop-and-go)")
    p.add_argument("--fcd", type=Path, required=True, help="FCD output file (.xml)")
    p.add_argument("--gui", action="store_true",
                   help="show the run in sumo-gui (needs a display; closes when you close it, or "
                        "at the end with --quit-on-end)")
    _gui_options(p)
    add_impairments(p)
    add_warmup(p)
    add_scenario(p)


def _gui_options(p: argparse.ArgumentParser) -> None:
    """The options of ``replay --gui`` (carl_sumo.sim.gui.GuiView)."""
    g = p.add_argument_group("sumo-gui (with --gui)")
    g.add_argument("--track", default=None, metavar="VEHICLE",
                   help="vehicle the view follows: leader, f0 (the head follower, default) .. fN-1")
    g.add_argument("--delay", type=float, default=None, metavar="MS",
                   help="delay between simulation steps in ms (default 100: real time)")
    g.add_argument("--zoom", type=float, default=None, metavar="PERCENT",
                   help="zoom in percent (default: the view fits the platoon with as much road "
                        "again around it)")
    g.add_argument("--quit-on-end", action="store_true",
                   help="close sumo-gui when the event ends (no end-of-simulation dialog)")
    g.add_argument("--screenshot", default=None, metavar="PNG[@TIME]",
                   help="save the view to PNG at simulated time TIME s (default 0: the start)")


def cmd_replay(args: argparse.Namespace) -> None:
    from carl_sumo.data import load_events
    from carl_sumo.experiments.simulate import replay

    from carl_sumo.sim.sumo import has_display, use_gui

    positive(args.vehicles, "--vehicles")
    impairments = impairments_from(args)
    warmup_s = warmup_from(args)
    check_output_file(args.fcd, "--fcd")
    view = gui_view_from(args, args.vehicles)
    (event,) = load_events(args.data, args.split, event_ids=[args.event])
    event = event.with_warmup(warmup_s)  # the FCD file has the warm-up, the metrics do not
    if args.scenario is not None:  # one manoeuvre, written as FCD (carl_sumo.cli.scenario)
        return replay_with_scenario(args, event, impairments, view)
    shot = view.screenshot if view is not None else None
    if shot is not None and view.screenshot_s > event.duration_s:
        raise InputError(f"--screenshot at {view.screenshot_s:g} s is after the end of event "
                         f"{event.event_id} ({event.duration_s:.1f} s)")
    if args.gui and not has_display():
        use_gui(True)  # raises the one-line "no display" error before anything runs
    # sumo-gui writes the screenshot to a temporary file (its suffix names the format)
    with atomic_path(shot, suffix=shot.suffix) if shot is not None else nullcontext() as tmp:
        if shot is not None:
            view.screenshot = tmp
        metrics = replay(args.controller, event, args.vehicles, args.fcd, args.net,
                         gui=view or False, impairments=impairments)
        if shot is not None and not tmp.is_file():
            raise InputError(f"sumo-gui saved no screenshot for {shot}; let the event run "
                             "to the screenshot's time")
    print(f"wrote {args.fcd}: event {event.event_id}, {args.vehicles} followers, "
          f"{event.duration_s:.1f} s" + (f" ({warmup_s:g} s of it warm-up, not scored)"
                                         if warmup_s else "")
          + f", controller {args.controller}" + (f"; view saved to {shot}" if shot else ""))
    print(", ".join(f"{k}={fmt(v)}" for k, v in metrics.items() if not k.startswith("n_")
                    and k != "event_id"))


def gui_view_from(args: argparse.Namespace, n_followers: int):
    """The GuiView of ``replay``'s options (None without --gui); InputError for gui options
    without --gui, a delay or zoom that is not positive, an unknown --track, a bad
    --screenshot."""
    from carl_sumo.sim.gui import GuiView, check_track, parse_screenshot

    given = [name for name, value in (("--track", args.track), ("--delay", args.delay),
                                      ("--zoom", args.zoom), ("--quit-on-end", args.quit_on_end),
                                      ("--screenshot", args.screenshot)) if value]
    if not args.gui:
        if given:
            raise InputError(f"{given[0]} is an option of sumo-gui: add --gui")
        return None
    if args.delay is not None and not 0 <= args.delay < math.inf:
        raise InputError(f"--delay must be a number of milliseconds >= 0, got {args.delay:g}")
    if args.zoom is not None and not 0 < args.zoom < math.inf:
        raise InputError(f"--zoom must be a positive percentage, got {args.zoom:g}")
    view = GuiView(track=args.track, zoom=args.zoom, quit_on_end=args.quit_on_end)
    if args.delay is not None:
        view.delay_ms = args.delay
    if args.screenshot is not None:
        view.screenshot, view.screenshot_s = parse_screenshot(args.screenshot)
        check_output_file(view.screenshot, "--screenshot")
    check_track(view, n_followers)
    return view


def _evaluate_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("evaluate", help="the paper's tables and figures, written to --out")
    p.add_argument("--suite", default="paper", choices=("paper", "real", "robustness",
                                                        "scenarios"),
                   help="paper (the paper's tables and figures: ideal plant, recorded start), "
                        "real (the same tables on the real plant from a 60 s settled start, with "
                        "ACC, the gains tuned for the plant and a string-stability table) or "
                        "robustness (controllers under V2V delay and loss and sensor noise, "
                        "docs/robustness.md) or scenarios (every controller through cut-in, "
                        "cut-out, join and merge on both plants, docs/scenarios.md)")
    p.add_argument("--out", type=Path, default=Path("results"), help="output directory")
    p.add_argument("--data", default=None,
                   help="NGSIM event table (default: ../shared/data/ngsim/ngsim_cf_events.csv.gz;"
                        " with --quick: the shipped default set)")
    p.add_argument("--quick", action="store_true",
                   help="a few events per table, 10 and 20 followers, one stop-and-go cycle")
    p.add_argument("--events", type=int, default=None, metavar="K",
                   help="only the first K events of each table (default: all; --quick: 2)")
    p.add_argument("--policies", type=Path, default=None,
                   help="directory of the policy files (default: policies/)")
    p.add_argument("--tables", default=None, metavar="NAME[,...]",
                   help="only these parts of --suite paper or real: table1 (the test split), "
                        "table2 (other platoon lengths), table3 (stop-and-go), cross_site, "
                        "string_stability (real only); default: all")
    p.add_argument("--net", type=net_option, default="i80.net.xml", help=NET_HELP)
    p.add_argument("--workers", type=int, default=None,
                   help="parallel SUMO processes (default: the number of cores; with --ray: the "
                        "cluster's CPUs)")
    add_ray(p)
    add_impairments(p)
    p.add_argument("--all-seeds", action="store_true",
                   help="run every model's seed files in every table (slower)")
    p.add_argument("--seeds", action="store_true",
                   help="run the seed files of CA-TD3, CA-DDPG, TD3 and DDPG too, in Table 1 "
                        "(and its 10-follower rows of Table 2), and compare them across seeds "
                        "(default: the shipped policy files only)")
    add_warmup(p)
    add_scenario(p)
    p.add_argument("--controller", type=controller_option, default=None,
                   metavar="MODULE:ATTR[,...]",
                   help="controllers of your own (module:attribute or file.py:attribute, "
                        "comma-separated): one more row in every table of --suite paper or real")


def extra_controllers(args: argparse.Namespace) -> tuple[str, ...]:
    """``evaluate --controller``'s names, each loaded once here (InputError, one line, for a
    name that is not module:attribute or does not load)."""
    from carl_sumo.control.external import is_external_name, load_external

    if args.controller is None:
        return ()
    if args.suite not in ("paper", "real"):
        raise InputError(f"--controller adds rows to --suite paper or real, not {args.suite}")
    names = tuple(n.strip() for n in args.controller.split(",") if n.strip())
    for name in names:
        if not is_external_name(name):
            raise InputError(f"evaluate --controller {name!r}: give module:attribute or "
                             "file.py:attribute (the built-in controllers and policies are "
                             "rows already)")
        load_external(name)
    return names


def cmd_evaluate(args: argparse.Namespace) -> None:
    if args.workers is not None:
        positive(args.workers, "--workers")
    if args.tables is not None and args.suite not in ("paper", "real"):
        raise InputError(f"--tables chooses tables of --suite paper or real, not {args.suite}")
    if args.suite == "scenarios":  # carl_sumo.cli.scenario
        check_output_names(args.out, "--out")
        return evaluate_scenarios(args, args.workers or min(2, os.cpu_count() or 1))
    if args.scenario is not None:
        raise InputError("--scenario is for --suite scenarios (or simulate and replay)")
    if args.suite == "real":  # the real plant and a settled start unless told otherwise
        from carl_sumo.experiments.suite import REAL_WARMUP_S

        if args.plant == "ideal" and args.fleet is None and args.vehicle_lag is None \
                and args.actuation_delay is None:
            args.plant = "real"
        if args.warmup == 0.0:
            args.warmup = REAL_WARMUP_S
    impairments = impairments_from(args)
    if impairments is not None and args.suite == "robustness":
        raise InputError("--suite robustness runs its own grid of impairments; leave out "
                         "--comm-* and --sensor-noise, or run --suite paper with them")
    if warmup_from(args) and args.suite == "robustness":
        raise InputError("--warmup is for --suite paper; the robustness suite keeps its own "
                         "protocol")
    args.controller = extra_controllers(args)
    check_output_names(args.out, "--out")
    check_ray(args)
    with ray_session(args, args.workers or os.cpu_count()):
        _run_evaluate(args, workers_for(args, os.cpu_count() or 1), impairments)


def _run_evaluate(args: argparse.Namespace, workers: int, impairments: Impairments | None
                  ) -> None:
    from carl_sumo.experiments.evaluate import evaluate

    if args.suite == "robustness":
        from carl_sumo.experiments.robustness import CONTROLLERS, run_robustness

        policies = args.policies or Path("policies")
        controllers = tuple(str(policies / Path(c).name) if c.endswith(".pt") else c
                            for c in CONTROLLERS)
        result = run_robustness(args.out, args.data, args.quick, args.events, args.net, workers,
                                controllers, progress=progress_mode(),
                                command="carl-sumo " + " ".join(sys.argv[1:]))
        print(f"wrote {args.out / 'robustness.md'}, robustness.csv ({len(result['rows'])} rows) "
              f"and {len(result['figures'])} figures; wall time {result['wall_time_s']:.0f} s")
        return
    result = evaluate(args.suite, args.out, args.data, args.quick, args.events, args.policies,
                      args.net, workers, progress=progress_mode(),
                      command="carl-sumo " + " ".join(sys.argv[1:]), all_seeds=args.all_seeds,
                      seeds=args.seeds, impairments=impairments, warmup_s=args.warmup,
                      extra=args.controller,
                      only=None if args.tables is None else
                      tuple(t.strip() for t in args.tables.split(",") if t.strip()))
    for key, rows in result["rows"].items():
        print(f"wrote {args.out / (key + '.md')} and .csv ({len(rows)} rows)")
    print(f"wrote {args.out / 'README.md'}, per_event.csv, timing.csv and "
          f"{len(result['figures'])} figures; wall time {result['wall_time_s']:.0f} s "
          f"({result['tasks']} tasks, {workers} workers)")


def _bench_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="env steps/s beside a bare libsumo loop")
    p.add_argument("--net", type=net_option, default="i80.net.xml", help=NET_HELP)
    p.add_argument("--sizes", default="10,20,100", help="platoon sizes, comma-separated")
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--training", action="store_true",
                   help="measure training throughput (parallel workers, updates) instead")
    add_plant(p)
    p.add_argument("--algo", default="ca-td3", help="with --training: the algorithm")
    p.add_argument("--vehicles", default="10,20",
                   help="with --training: platoon lengths, comma-separated (default 10,20)")
    p.add_argument("--envs", type=int, default=2, help="with --training: worker processes")
    p.add_argument("--smooth-jerk", type=float, default=0.0,
                   help="with --training: the actor smoothness terms of `train` (default 0), "
                        "which add one actor pass per update")
    p.add_argument("--smooth-accel", type=float, default=0.0, help="with --training: see above")
    p.add_argument("--update-every", type=int, default=1, metavar="K",
                   help="with --training: one update every K steps (default 1), as train's")
    p.add_argument("--batch-size", type=int, default=128,
                   help="with --training: transitions per update (default 128), as train's")


def cmd_bench(args: argparse.Namespace) -> None:
    from carl_sumo.experiments.bench import format_bench, format_training_bench, run_bench, run_training_bench

    if args.training:
        from carl_sumo.learn.agents import ALGOS

        if args.algo not in ALGOS:
            raise InputError(f"unknown algorithm {args.algo!r}; choose one of {', '.join(ALGOS)}")
        try:
            sizes = tuple(positive(int(s), "--vehicles") for s in args.vehicles.split(","))
        except ValueError:
            raise InputError(f"--vehicles must be integers separated by commas, got "
                             f"{args.vehicles!r}")
        rows = run_training_bench(args.algo, sizes, positive(args.envs, "--envs"),
                                  positive(args.steps, "--steps"), args.net, args.smooth_jerk,
                                  args.smooth_accel, positive(args.update_every, "--update-every"),
                                  positive(args.batch_size, "--batch-size"))
        print(format_training_bench(rows))
        return

    try:
        sizes = tuple(positive(int(s), "--sizes") for s in args.sizes.split(","))
    except ValueError:
        raise InputError(f"--sizes must be integers separated by commas, got {args.sizes!r}")
    from carl_sumo.control.channel import plant_from

    rows = run_bench(sizes, positive(args.steps, "--steps"), positive(args.rounds, "--rounds"),
                     args.net, plant_from(args))
    print(format_bench(rows))


