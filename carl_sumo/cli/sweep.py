"""``carl-sumo sweep``: its options and the command (:mod:`carl_sumo.cli.sweep_trials` runs it)."""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from carl_sumo.cli.common import check_ray, positive, ray_session


def _sweep_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sweep", help="seed and hyperparameter sweeps of train on Ray Tune "
                       "(a TOML spec; sweeps/, docs/scale.md)")
    p.add_argument("spec", type=Path, help="sweep spec (.toml), e.g. sweeps/ca_td3.toml")
    p.add_argument("--ray", default="local", metavar="ADDRESS",
                   help="local (default: a Ray runtime in this process with --workers CPUs), auto "
                        "(the cluster started here with `ray start --head`) or HOST:PORT of a "
                        "cluster's head; needs pip install -e '.[ray]'")
    p.add_argument("--workers", type=int, default=None,
                   help="with --ray local: its CPUs (default: the number of cores); trials at "
                        "once = CPUs / the spec's cpus_per_trial")
    p.add_argument("--out", type=Path, default=None,
                   help="folder of the trials' policy files (default: the spec's out)")
    p.add_argument("--results", type=Path, default=None,
                   help="folder of sweep.md, trials.csv, configs.csv and Tune's state (default: "
                        "the spec's results)")
    p.add_argument("--no-ship", action="store_true",
                   help="do not copy the best run to the spec's ship path")
    p.add_argument("--overwrite", action="store_true",
                   help="replace files that are there already (the shipped specs write into "
                        "policies/: without it the sweep refuses to overwrite them)")


def check_overwrite(spec, trials) -> None:
    """InputError, before anything runs, when the sweep would replace files that exist: the
    trials' policy files (and their curves and checkpoints) and the ship target."""
    from carl_sumo.errors import InputError

    targets = [Path(t.argv[t.argv.index("--out") + 1]) for t in trials]
    targets += [spec.ship] if spec.ship is not None else []
    there = [str(p) for t in targets for p in (t.with_suffix(s) for s in (".pt", ".csv", ".ckpt"))
             if p.exists()]
    if there:
        more = f" and {len(there) - 2} more" if len(there) > 2 else ""
        raise InputError(f"the sweep would overwrite {', '.join(there[:2])}{more}: pass "
                         "--overwrite to replace them, or --out DIR and --no-ship to write "
                         "elsewhere")


def cmd_sweep(args: argparse.Namespace) -> None:
    import time

    from carl_sumo.cli.sweep_trials import check_trials, load_spec, plan_trials, run_sweep
    from carl_sumo.cli.sweep_report import (best_config_runs, best_run, config_rows, trial_rows,
                                            write_report)

    if args.workers is not None:
        positive(args.workers, "--workers")
    spec = load_spec(args.spec, args.out, args.results)
    if args.no_ship:
        spec.ship = None
    trials = plan_trials(spec)
    if not args.overwrite:
        check_overwrite(spec, trials)
    check_trials(spec, trials)  # every trial's options, the outputs and the data, before Ray
    check_ray(args)
    start = time.perf_counter()
    with ray_session(args, args.workers or os.cpu_count()):
        outcome = run_sweep(spec, trials)
    wall = time.perf_counter() - start
    rows = trial_rows(trials, outcome, spec.select, spec.out)
    configs = config_rows(rows)
    written = write_report(spec.results, spec.path, spec.select, rows, configs, wall,
                           "carl-sumo " + " ".join(sys.argv[1:]))
    best = best_run(rows, configs)
    if spec.ship is not None and best is not None and spec.ship_string_stable:
        from carl_sumo.experiments.string_stability import string_stable_first

        runs = [{"path": r["policy"]} for r in best_config_runs(rows, configs)]
        best = string_stable_first(runs, spec.ship_string_stable)[0]["path"]
    if spec.ship is not None and best is not None:
        from carl_sumo.cli.sweep_trials import ship

        ship(Path(best), spec.ship)
        print(f"shipped {best} as {spec.ship}")
    print(f"{len(trials)} trials in {wall:.0f} s; best configuration "
          f"{configs[0]['config'] if configs else '-'}; wrote " + ", ".join(map(str, written)))
    failed = [r["trial"] for r in rows if r["status"] != "ok"]
    if failed:
        from carl_sumo.scale.workers import WorkerError

        raise WorkerError(f"{len(failed)} trial(s) did not finish ({', '.join(failed)}); see "
                          f"{spec.results / 'sweep.md'} and Tune's logs in {spec.results / 'tune'}")
