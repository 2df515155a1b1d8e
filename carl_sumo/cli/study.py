"""The ``study`` command: mixed human/CACC traffic against the CACC penetration rate."""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from carl_sumo.cli.common import (NET_HELP, controller_option, net_option, add_impairments,
                                  add_ray, check_ray, impairments_from, positive, ray_session,
                                  workers_for)
from carl_sumo.errors import InputError
from carl_sumo.progress import progress_mode
from carl_sumo.files import check_output_names

if TYPE_CHECKING:
    pass


def _study_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("study", help="mixed human/CACC traffic on the freeway against the "
                       "CACC penetration rate: tables and figures")
    p.add_argument("--net", type=net_option, default="i80.net.xml", help=NET_HELP)
    p.add_argument("--controller", type=controller_option, default="idm-external",
                   help="CACC controller: idm-external | sumo-cacc | ploeg[:h=H:kp=KP:kd=KD] | "
                        "ploeg-tuned:h=H | POLICY.pt (not MADDPG) | module:attribute | "
                        "file.py:attribute (a controller of your own, see README)")
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


MAX_STUDY_S = 86400.0
"""The longest simulated time of one study run (s): a day of traffic."""
MAX_STUDY_SEEDS = 1000
"""The most seeds per penetration rate."""


def cmd_study(args: argparse.Namespace) -> None:
    from dataclasses import replace

    from carl_sumo.study.run import StudyConfig, resolve_study_controller, run_study, write_outputs
    from carl_sumo.study.results import markdown_table, summarise
    from carl_sumo.sim.sumo import lane_route
    from carl_sumo.sim.traffic import DEFAULT_DEMAND

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
    if args.warmup + args.duration > MAX_STUDY_S:
        raise InputError(f"--warmup plus --duration must be at most {MAX_STUDY_S:g} s (a day of "
                         f"traffic), got {args.warmup + args.duration:g}")
    positive(args.seeds, "--seeds")
    if args.seeds > MAX_STUDY_SEEDS:
        raise InputError(f"--seeds must be at most {MAX_STUDY_SEEDS} (one run of "
                         f"{args.duration:g} s each per rate), got {args.seeds}")
    if args.workers is not None:
        positive(args.workers, "--workers")
    check_output_names(args.out, "--out")
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
    kind, _ = resolve_study_controller(cfg.controller, cfg.plant_key)
    if cfg.impairments is not None and kind != "external":
        raise InputError(f"{cfg.controller}: impairments (--comm-*, --sensor-noise) apply to "
                         "CACC vehicles controlled in carl-sumo (idm-external, ploeg, a policy "
                         "file, module:attribute), not to SUMO's own CACC")
    _check_detector(cfg)
    start = time.perf_counter()
    with ray_session(args, args.workers or os.cpu_count()):
        cfg = replace(cfg, workers=workers_for(args, min(2, os.cpu_count() or 1)))
        results = run_study(cfg, args.out, progress=progress_mode())
    wall = time.perf_counter() - start
    written = write_outputs(cfg, results, args.out, "carl-sumo " + " ".join(sys.argv[1:]), wall)
    print(markdown_table(summarise(results)))
    print(f"{len(results)} runs in {wall:.0f} s wall; wrote " + ", ".join(str(p) for p in written))


def _check_detector(cfg) -> None:
    import sumolib

    from carl_sumo.sim.traffic import MAIN_EDGE

    net = sumolib.net.readNet(cfg.net)
    if not net.hasEdge(MAIN_EDGE):
        raise InputError(f"network {cfg.net} has no edge {MAIN_EDGE}; the study needs the "
                         "I-80-like network (i80.net.xml)")
    length = net.getEdge(MAIN_EDGE).getLength()
    if cfg.detector_pos_m > length:
        raise InputError(f"--detector-pos {cfg.detector_pos_m:g} m is beyond the end of "
                         f"{MAIN_EDGE} ({length:.0f} m)")


