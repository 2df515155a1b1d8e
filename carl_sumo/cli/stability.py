"""The ``string-stability`` command: every link's gain against frequency, measured in SUMO and,
for the linear laws, in theory (:mod:`carl_sumo.experiments.string_stability`)."""

from __future__ import annotations

import argparse
import json
import os
from pathlib import Path

from carl_sumo.cli.common import (NET_HELP, add_impairments, controller_option, impairments_from,
                                  net_option, positive)
from carl_sumo.errors import InputError
from carl_sumo.files import check_output_file, write_text_atomic


def _string_stability_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("string-stability",
                       help="|a_i / a_(i-1)| against frequency behind a sinusoidal leader")
    p.add_argument("--controller", type=controller_option, required=True,
                   help="one or more controllers with commas: ploeg[:h=..], acc[:h=..], "
                        "ploeg-tuned:h=H, mpf[:r=R..], mpc[:h=H:N=N..] and mpc-tuned (measured "
                        "only), "
                        "idm-external, POLICY.pt")
    p.add_argument("--net", type=net_option, default="i80.net.xml", help=NET_HELP)
    p.add_argument("--vehicles", type=int, default=5, help="followers (default 5)")
    p.add_argument("--amplitude", type=float, default=0.5, metavar="MPS",
                   help="the leader's speed amplitude (m/s, default 0.5)")
    p.add_argument("--base-speed", type=float, default=20.0, metavar="MPS",
                   help="the leader's mean speed (m/s, default 20)")
    p.add_argument("--frequencies", type=int, default=24, metavar="K",
                   help="K log-spaced frequencies (default 24)")
    p.add_argument("--min-frequency", type=float, default=0.05, metavar="RAD_S",
                   help="lowest frequency (rad/s, default 0.05)")
    p.add_argument("--max-frequency", type=float, default=3.0, metavar="RAD_S",
                   help="highest frequency (rad/s, default 3)")
    p.add_argument("--json", type=Path, default=None, metavar="OUT", help="write the curves")
    p.add_argument("--plot", type=Path, default=None, metavar="PNG", help="a magnitude plot")
    p.add_argument("--workers", type=int, default=None, help="parallel SUMO processes")
    p.add_argument("--h-min-table", type=Path, default=None, metavar="DIR",
                   help="instead: the smallest string-stable time gap of ACC and CACC (the "
                        "gains of --controller, a ploeg or acc name) against lag 0.1-0.5 s and "
                        "V2V delay 0-0.3 s, measured and analytic, written to DIR (h_min.md, "
                        ".csv, .json, .png)")
    p.add_argument("--h-min-heard", type=Path, default=None, metavar="DIR",
                   help="instead: the smallest string-stable time gap against the vehicles "
                        "heard, r = 0-3 (acc, ploeg, mpf; the gains of --controller) and lag "
                        "0.1-0.6 s, V2V delay 0-0.2 s, measured and analytic, written to DIR "
                        "(h_min_heard.md, .csv, .json; docs/string_stability.md)")
    add_impairments(p)


MAX_FREQUENCIES = 1000
"""The most frequencies of one measured curve (each is a SUMO run of a minute or more)."""


def cmd_string_stability(args: argparse.Namespace) -> None:
    from carl_sumo.control.transfer import log_frequencies
    from carl_sumo.experiments.simulate import check_impairable
    from carl_sumo.experiments.string_stability import SineTest, check_run, string_stability

    positive(args.vehicles, "--vehicles")
    positive(args.frequencies, "--frequencies")
    if args.frequencies > MAX_FREQUENCIES:
        raise InputError(f"--frequencies must be at most {MAX_FREQUENCIES} (one SUMO run each), "
                         f"got {args.frequencies}")
    import math

    from carl_sumo.config import DT_S

    if not all(math.isfinite(f) for f in (args.min_frequency, args.max_frequency)):
        raise InputError(f"--min-frequency and --max-frequency must be finite; give "
                         f"frequencies in (0, {math.pi / DT_S / 10:.2f}] rad/s")
    if not 0 < args.min_frequency <= args.max_frequency:
        raise InputError("--min-frequency must be positive and at most --max-frequency")
    names = [c.strip() for c in args.controller.split(",") if c.strip()]
    if not names:
        raise InputError("--controller names no controller")
    impairments = impairments_from(args)
    if args.h_min_table is not None or args.h_min_heard is not None:
        return _h_min_table(args, names)
    for name in names:
        check_impairable(name, impairments)
    omegas = log_frequencies(args.frequencies, args.min_frequency, args.max_frequency)
    test = SineTest(args.base_speed, args.amplitude)
    for name in names:
        check_run(name, omegas, args.vehicles, test, args.net)
    for path, what in ((args.json, "--json"), (args.plot, "--plot")):
        if path is not None:
            check_output_file(path, what)
    workers = args.workers if args.workers is not None else min(2, os.cpu_count() or 1)
    positive(workers, "--workers")
    plant = impairments.plant if impairments is not None else None
    result = string_stability(names, plant, impairments, args.vehicles, omegas, test, args.net,
                              workers)
    for run in result["runs"]:
        worst = max(range(len(omegas)), key=lambda i: run["gain"][i])
        line = (f"{run['controller']:>24}  {run['class']:>6}  hinf {run['hinf']:.4f} at "
                f"{omegas[worst]:.3f} rad/s  ({'string stable' if run['hinf'] <= 1 else 'unstable'})")
        if "hinf_inner" in run:
            line += f"  links behind a follower {run['hinf_inner']:.4f}"
        if "analytic" in run:
            theory = run["analytic"]
            cont, disc = (max(max(theory[k][kind]) for k in ("first_link", "inner_links"))
                          for kind in ("continuous", "discrete"))
            line += f"  theory: continuous {cont:.4f}, discrete {disc:.4f}"
        if "decision" in run:  # a held-gap policy: the gaps it chose, held
            d = run["decision"]
            line += (f"  at its chosen gap offsets held, {len(d['offsets_s'])} followers (the "
                     f"smallest of {d['events']} events, s): "
                     + " ".join(f"{x:+.3f}" for x in d["offsets_s"]))
        print(line)
    if args.json is not None:
        write_text_atomic(args.json, json.dumps(result, indent=1))
    if args.plot is not None:
        from carl_sumo.experiments.string_stability import plot

        plot(result, args.plot)


def _h_min_table(args: argparse.Namespace, names: list[str]) -> None:
    from carl_sumo.control.cacc import is_ploeg_name, parse_ploeg
    from carl_sumo.experiments.string_stability import h_min_markdown, h_min_plot, h_min_table
    from carl_sumo.files import check_output_dir

    if len(names) != 1 or not is_ploeg_name(names[0]):
        raise InputError("--h-min-table and --h-min-heard take the gains of one ploeg or acc "
                         "--controller, e.g. "
                         "--controller ploeg:kp=0.2:kd=0.7")
    p = parse_ploeg(names[0])
    option = "--h-min-table" if args.h_min_table is not None else "--h-min-heard"
    check_output_dir(args.h_min_table or args.h_min_heard, option)
    workers = args.workers if args.workers is not None else min(2, os.cpu_count() or 1)
    positive(workers, "--workers")
    if args.h_min_heard is not None:  # r = 0-3 vehicles heard (carl_sumo.experiments.h_min_heard)
        from carl_sumo.experiments import h_min_heard

        rows = h_min_heard.table(p.kp, p.kd, args.net, workers)
        print(h_min_heard.write(rows, p.kp, p.kd, Path(args.h_min_heard)))
        return
    rows = h_min_table(p.kp, p.kd, args.net, workers)
    out = Path(args.h_min_table)
    out.mkdir(parents=True, exist_ok=True)
    table = h_min_markdown(rows, p.kp, p.kd)
    write_text_atomic(out / "h_min.md", table)
    write_text_atomic(out / "h_min.json", json.dumps(rows, indent=1))
    keys = list(rows[0])
    write_text_atomic(out / "h_min.csv", "\n".join([",".join(keys)] + [
        ",".join(str(r[k]) for k in keys) for r in rows]) + "\n")
    h_min_plot(rows, out / "h_min.png")
    print(table)
