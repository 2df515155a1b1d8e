"""The ``carl-sumo`` command line.

Bad input (missing or malformed files, unknown options, events, controllers, a network too short)
ends with one line ``carl-sumo: error: ...`` on stderr and exit status 2; nothing is half-written.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from carl_sumo.cli_common import (Parser, add_common, add_impairments, add_ray, add_warmup,
                                   check_ray, fmt, impairments_from, positive, ray_session,
                                   warmup_from, workers_for)
from carl_sumo.cli_policies import (_export_parser, _policy_info_parser, _rank_parser,
                                    _train_parser, _tune_parser, cmd_export, cmd_policy_info,
                                    cmd_rank, cmd_train, cmd_tune)
from carl_sumo.cli_sweep import _sweep_parser, cmd_sweep
from carl_sumo.errors import InputError
from carl_sumo.files import check_output_dir, check_output_file, write_text_atomic
from carl_sumo.workers import WorkerError

if TYPE_CHECKING:
    from carl_sumo.channel import Impairments

EXIT_BAD_INPUT = 2


_Parser = Parser  # a usage error is one line and exit status 2


def format_table(results: list[dict]) -> str:
    from carl_sumo.metrics import METRIC_KEYS

    header = ["controller", "followers", "events", *METRIC_KEYS]
    rows = [[r["controller"], str(r["followers"]), str(len(r["events"])),
             *(fmt(r["metrics"][k]) for k in METRIC_KEYS)] for r in results]
    widths = [max([len(h), *(len(row[i]) for row in rows)]) for i, h in enumerate(header)]
    line = lambda cells: "  ".join(c.rjust(w) for c, w in zip(cells, widths))  # noqa: E731
    return "\n".join([line(header), line(["-" * w for w in widths]), *map(line, rows)])


def _simulate_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("simulate", help="run controllers on the events of a split; print metrics")
    add_common(p)
    p.add_argument("--controller", default="idm",
                   help="idm | krauss | sumo-cacc | idm-external | ploeg[:h=H:kp=KP:kd=KD] | "
                        "ploeg-tuned:h=H | human | POLICY.pt; several with commas")
    p.add_argument("--events", type=int, default=None, metavar="K", help="only the first K events")
    p.add_argument("--json", type=Path, default=None, metavar="OUT", help="write metrics as JSON")
    p.add_argument("--workers", type=int, default=None,
                   help="parallel SUMO processes (default: 2, or the number of cores if fewer; "
                        "with --ray: the cluster's CPUs)")
    add_ray(p)
    add_impairments(p)
    add_warmup(p)


def cmd_simulate(args: argparse.Namespace) -> None:
    from carl_sumo.data import load_events
    from carl_sumo.simulate import check_impairable, resolve_controller, simulate

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
        _, controller = resolve_controller(name)
        if controller is not None:
            controller.reset(args.vehicles)
        check_impairable(name, impairments)
    if args.workers is not None:
        positive(args.workers, "--workers")
    check_ray(args)
    events = [e.with_warmup(warmup_s) for e in load_events(args.data, args.split,
                                                             limit=args.events)]
    start = time.perf_counter()
    with ray_session(args, args.workers or os.cpu_count()):
        workers = workers_for(args, min(2, os.cpu_count() or 1))
        results = [simulate(name, events, args.vehicles, args.net, progress=sys.stderr.isatty(),
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
    p.add_argument("--controller", default="idm",
                   help="idm | krauss | sumo-cacc | idm-external | ploeg[:h=H:kp=KP:kd=KD] | "
                        "ploeg-tuned:h=H | POLICY.pt")
    p.add_argument("--event", required=True, help="event ID (stop_and_go with --data stop-and-go)")
    p.add_argument("--fcd", type=Path, required=True, help="FCD output file (.xml)")
    p.add_argument("--gui", action="store_true",
                   help="show the run in sumo-gui (needs a display; closes when you close it)")
    add_impairments(p)
    add_warmup(p)


def cmd_replay(args: argparse.Namespace) -> None:
    from carl_sumo.data import load_events
    from carl_sumo.simulate import replay

    from carl_sumo.sumo import has_display, use_gui

    positive(args.vehicles, "--vehicles")
    impairments = impairments_from(args)
    warmup_s = warmup_from(args)
    check_output_file(args.fcd, "--fcd")
    if args.gui and not has_display():
        use_gui(True)  # raises the one-line "no display" error before anything runs
    (event,) = load_events(args.data, args.split, event_ids=[args.event])
    event = event.with_warmup(warmup_s)  # the FCD file has the warm-up, the metrics do not
    metrics = replay(args.controller, event, args.vehicles, args.fcd, args.net, gui=args.gui,
                     impairments=impairments)
    print(f"wrote {args.fcd}: event {event.event_id}, {args.vehicles} followers, "
          f"{event.duration_s:.1f} s" + (f" ({warmup_s:g} s of it warm-up, not scored)"
                                         if warmup_s else "")
          + f", controller {args.controller}")
    print(", ".join(f"{k}={fmt(v)}" for k, v in metrics.items() if not k.startswith("n_")
                    and k != "event_id"))


def _evaluate_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("evaluate", help="the paper's tables and figures, written to --out")
    p.add_argument("--suite", default="paper", choices=("paper", "robustness"),
                   help="paper (the paper's tables and figures) or robustness (controllers under "
                        "V2V delay and loss and sensor noise, docs/robustness.md)")
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
    p.add_argument("--net", default="networks/i80.net.xml", help="SUMO network (.net.xml)")
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


def cmd_evaluate(args: argparse.Namespace) -> None:
    if args.workers is not None:
        positive(args.workers, "--workers")
    impairments = impairments_from(args)
    if impairments is not None and args.suite == "robustness":
        raise InputError("--suite robustness runs its own grid of impairments; leave out "
                         "--comm-* and --sensor-noise, or run --suite paper with them")
    if warmup_from(args) and args.suite == "robustness":
        raise InputError("--warmup is for --suite paper; the robustness suite keeps its own "
                         "protocol")
    check_output_dir(args.out, "--out")
    check_ray(args)
    with ray_session(args, args.workers or os.cpu_count()):
        _run_evaluate(args, workers_for(args, os.cpu_count() or 1), impairments)


def _run_evaluate(args: argparse.Namespace, workers: int, impairments: Impairments | None
                  ) -> None:
    from carl_sumo.evaluate import evaluate

    if args.suite == "robustness":
        from carl_sumo.robustness import CONTROLLERS, run_robustness

        policies = args.policies or Path("policies")
        controllers = tuple(str(policies / Path(c).name) if c.endswith(".pt") else c
                            for c in CONTROLLERS)
        result = run_robustness(args.out, args.data, args.quick, args.events, args.net, workers,
                                controllers, progress=sys.stderr.isatty(),
                                command="carl-sumo " + " ".join(sys.argv[1:]))
        print(f"wrote {args.out / 'robustness.md'}, robustness.csv ({len(result['rows'])} rows) "
              f"and {len(result['figures'])} figures; wall time {result['wall_time_s']:.0f} s")
        return
    result = evaluate(args.suite, args.out, args.data, args.quick, args.events, args.policies,
                      args.net, workers, progress=sys.stderr.isatty(),
                      command="carl-sumo " + " ".join(sys.argv[1:]), all_seeds=args.all_seeds,
                      seeds=args.seeds, impairments=impairments, warmup_s=args.warmup)
    for key, rows in result["rows"].items():
        print(f"wrote {args.out / (key + '.md')} and .csv ({len(rows)} rows)")
    print(f"wrote {args.out / 'README.md'}, per_event.csv, timing.csv and "
          f"{len(result['figures'])} figures; wall time {result['wall_time_s']:.0f} s "
          f"({result['tasks']} tasks, {workers} workers)")


def _bench_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("bench", help="env steps/s beside a bare libsumo loop")
    p.add_argument("--net", default="networks/i80.net.xml")
    p.add_argument("--sizes", default="10,20,100", help="platoon sizes, comma-separated")
    p.add_argument("--steps", type=int, default=2000)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--training", action="store_true",
                   help="measure training throughput (parallel workers, updates) instead")
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
    from carl_sumo.bench import format_bench, format_training_bench, run_bench, run_training_bench

    if args.training:
        from carl_sumo.agents import ALGOS

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
    rows = run_bench(sizes, positive(args.steps, "--steps"), positive(args.rounds, "--rounds"),
                     args.net)
    print(format_bench(rows))


def _study_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("study", help="mixed human/CACC traffic on the freeway against the "
                       "CACC penetration rate: tables and figures")
    p.add_argument("--net", default="networks/i80.net.xml", help="SUMO network (.net.xml)")
    p.add_argument("--controller", default="idm-external",
                   help="CACC controller: idm-external | sumo-cacc | ploeg[:h=H:kp=KP:kd=KD] | "
                        "ploeg-tuned:h=H | POLICY.pt (not MADDPG)")
    p.add_argument("--penetration", default="0,0.25,0.5,0.75,1",
                   help="CACC penetration rates in [0, 1], comma-separated")
    p.add_argument("--duration", type=float, default=900.0, help="measured simulated time (s)")
    p.add_argument("--warmup", type=float, default=300.0,
                   help="simulated time before measuring (s)")
    p.add_argument("--seeds", type=int, default=3, help="number of seeds (0, 1, ...) per rate")
    p.add_argument("--v2v-range", type=float, default=300.0,
                   help="V2V range between consecutive CACC vehicles (m)")
    p.add_argument("--human-sigma", type=float, default=0.0, metavar="SIGMA",
                   help="human driver imperfection from 0 to 1: SUMO's sigma for the Krauss "
                        "humans and a desired-speed spread (speedDev = 0.2·SIGMA) for all "
                        "humans (default 0: deterministic humans)")
    add_impairments(p)
    p.add_argument("--demand-scale", type=float, default=1.0,
                   help="multiplies the default demand (2000 veh/h/lane, on-ramp 500 veh/h)")
    p.add_argument("--krauss-share", type=float, default=0.5,
                   help="share of human drivers with SUMO's Krauss model (rest IDM)")
    p.add_argument("--detector-pos", type=float, default=5000.0,
                   help="position of the induction loops on i80_main (m from its start)")
    p.add_argument("--heatmap-lane", type=int, default=6,
                   help="NGSIM lane of the time-space speed maps (1 = leftmost, 6 = rightmost)")
    p.add_argument("--workers", type=int, default=None,
                   help="parallel SUMO processes (default: 2, or the number of cores if fewer; "
                        "with --ray: the cluster's CPUs)")
    add_ray(p)
    p.add_argument("--fcd", action="store_true",
                   help="also write SUMO FCD output (1 s period, gzip) of the first seed per rate")
    p.add_argument("--out", type=Path, default=Path("results/study"), help="output folder")


def _rates(text: str) -> tuple[float, ...]:
    try:
        rates = tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        raise InputError(f"--penetration must be numbers in [0, 1] separated by commas, got "
                         f"{text!r}") from None
    if not rates or any(not 0.0 <= r <= 1.0 for r in rates):
        raise InputError(f"--penetration must be numbers in [0, 1] separated by commas, got "
                         f"{text!r}")
    return tuple(sorted(set(rates)))


def cmd_study(args: argparse.Namespace) -> None:
    from dataclasses import replace

    from carl_sumo.study import StudyConfig, resolve_study_controller, run_study, write_outputs
    from carl_sumo.study_results import markdown_table, summarise
    from carl_sumo.sumo import lane_route
    from carl_sumo.traffic import DEFAULT_DEMAND

    rates = _rates(args.penetration)
    if not (math.isfinite(args.human_sigma) and 0 <= args.human_sigma <= 1):
        raise InputError(f"--human-sigma is SUMO's driver imperfection from 0 to 1, got "
                         f"{args.human_sigma}")
    for name, value in (("--duration", args.duration), ("--v2v-range", args.v2v_range),
                        ("--demand-scale", args.demand_scale)):
        if not (math.isfinite(value) and value > 0):
            raise InputError(f"{name} must be a positive number, got {value}")
    if not (math.isfinite(args.warmup) and args.warmup >= 0):
        raise InputError(f"--warmup must be a non-negative number of seconds, got {args.warmup}")
    positive(args.seeds, "--seeds")
    if args.workers is not None:
        positive(args.workers, "--workers")
    check_output_dir(args.out, "--out")
    check_ray(args)
    lane_route(args.net, args.heatmap_lane)  # checks the network and the lane
    if not 0.0 <= args.detector_pos:
        raise InputError(f"--detector-pos must be non-negative, got {args.detector_pos}")
    demand = replace(DEFAULT_DEMAND.scaled(args.demand_scale), krauss_share=args.krauss_share)
    cfg = StudyConfig(controller=args.controller, penetrations=rates,
                      seeds=tuple(range(args.seeds)), duration_s=args.duration,
                      warmup_s=args.warmup, v2v_range_m=args.v2v_range,
                      detector_pos_m=args.detector_pos, heatmap_lane=args.heatmap_lane,
                      net=str(args.net), demand=demand, fcd=args.fcd, workers=1,
                      human_sigma=args.human_sigma, impairments=impairments_from(args))
    kind, _ = resolve_study_controller(cfg.controller)
    if cfg.impairments is not None and kind != "external":
        raise InputError(f"{cfg.controller}: impairments (--comm-*, --sensor-noise) apply to "
                         "CACC vehicles controlled in carl-sumo (idm-external, ploeg, a policy "
                         "file), not to SUMO's own CACC")
    _check_detector(cfg)
    start = time.perf_counter()
    with ray_session(args, args.workers or os.cpu_count()):
        cfg = replace(cfg, workers=workers_for(args, min(2, os.cpu_count() or 1)))
        results = run_study(cfg, args.out, progress=sys.stderr.isatty())
    wall = time.perf_counter() - start
    written = write_outputs(cfg, results, args.out, "carl-sumo " + " ".join(sys.argv[1:]), wall)
    print(markdown_table(summarise(results)))
    print(f"{len(results)} runs in {wall:.0f} s wall; wrote " + ", ".join(str(p) for p in written))


def _check_detector(cfg) -> None:
    import sumolib

    from carl_sumo.traffic import MAIN_EDGE

    net = sumolib.net.readNet(cfg.net)
    if not net.hasEdge(MAIN_EDGE):
        raise InputError(f"network {cfg.net} has no edge {MAIN_EDGE}; the study needs the "
                         "I-80-like network (networks/i80.net.xml)")
    length = net.getEdge(MAIN_EDGE).getLength()
    if cfg.detector_pos_m > length:
        raise InputError(f"--detector-pos {cfg.detector_pos_m:g} m is beyond the end of "
                         f"{MAIN_EDGE} ({length:.0f} m)")


def _net_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("net", help="network tools")
    net_sub = p.add_subparsers(dest="net_command", required=True, parser_class=_Parser)
    b = net_sub.add_parser("build", help="regenerate networks/i80.net.xml with netconvert")
    b.add_argument("--config", type=Path, default=None, help="netconvert .netccfg")
    b.add_argument("--out", type=Path, default=None)


def cmd_net(args: argparse.Namespace) -> None:
    from carl_sumo.network import NET_FILE, NET_SOURCES, build_network

    out = check_output_file(args.out or NET_FILE, "--out")
    out = build_network(args.config or NET_SOURCES, out)
    print(f"wrote {out}")


def _data_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("data", help="leader data tools")
    data_sub = p.add_subparsers(dest="data_command", required=True, parser_class=_Parser)
    d = data_sub.add_parser("list", help="list the events of a split")
    d.add_argument("--data", default="default")
    d.add_argument("--split", default="all")
    d = data_sub.add_parser("make-default", help="regenerate the shipped default leader set")
    d.add_argument("--net", default="networks/i80.net.xml")
    d.add_argument("--out", type=Path, default=None)
    d.add_argument("--seed", type=int, default=42)


def cmd_data(args: argparse.Namespace) -> None:
    if args.data_command == "list":
        from carl_sumo.data import load_events

        for e in load_events(args.data, args.split):
            print(f"{e.event_id}\t{e.source}\t{e.duration_s:.1f} s\t"
                  f"mean leader speed {e.leader_speed_mps.mean():.2f} m/s")
    else:
        from carl_sumo.data import DEFAULT_EVENTS
        from carl_sumo.data.default_set import make_default_set

        out = check_output_file(args.out or DEFAULT_EVENTS, "--out")
        table = make_default_set(Path(args.net), Path(out), seed=args.seed)
        print(f"wrote {out}: {table['event_id'].nunique()} events")


def build_parser() -> argparse.ArgumentParser:
    """The parser of ``carl-sumo``: each subcommand's options are defined beside the command
    (``_<command>_parser`` above ``cmd_<command>``, here or in :mod:`carl_sumo.cli_policies`)."""
    parser = _Parser(prog="carl-sumo", description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True, parser_class=_Parser)
    for add in (_simulate_parser, _replay_parser, _evaluate_parser, _train_parser, _sweep_parser,
                _tune_parser, _export_parser, _policy_info_parser, _rank_parser, _bench_parser, _study_parser,
                _net_parser, _data_parser):
        add(sub)
    return parser


COMMANDS = {"simulate": cmd_simulate, "evaluate": cmd_evaluate, "train": cmd_train,
            "policy-info": cmd_policy_info, "export": cmd_export, "tune": cmd_tune,
            "sweep": cmd_sweep,
            "replay": cmd_replay,
            "bench": cmd_bench, "rank": cmd_rank, "net": cmd_net, "study": cmd_study,
            "data": cmd_data}


def main(argv: list[str] | None = None) -> int:
    try:
        args = build_parser().parse_args(argv)
        COMMANDS[args.command](args)
    except InputError as exc:
        print(f"carl-sumo: error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except WorkerError as exc:  # a worker process died twice on the same task
        print(f"carl-sumo: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("carl-sumo: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # the reader went away (`carl-sumo rank ... | head`): not an error
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())
        return 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
