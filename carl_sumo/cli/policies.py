"""``carl-sumo`` commands that make and inspect policies: train, tune, export, policy-info, rank.

Each subcommand's options are defined beside the command (``_<command>_parser`` above
``cmd_<command>``); :mod:`carl_sumo.cli` assembles the parser.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path

from carl_sumo.cli.common import (add_common, add_impairments, add_ray, add_warmup, check_ray,
                                 fmt, impairments_from, positive, ray_session, warmup_from)
from carl_sumo.cli.config_options import add_config_options
from carl_sumo.control.ploeg_names import expand_preset
from carl_sumo.errors import InputError
from carl_sumo.files import check_output_dir, check_output_file


def check_train_args(args: argparse.Namespace, command: str = ""):
    """The checked :class:`carl_sumo.learn.train_config.TrainConfig` of parsed ``train``
    options (its recipe, then the options given) and the policy file path; InputError, one
    line, for any bad option or unusable output (before anything runs)."""
    from carl_sumo.cli.config_options import config_from_args

    cfg = config_from_args(args, command, TRAIN_CONVERTERS)
    if args.resume is not None and (cfg.init is not None or cfg.imitate is not None):
        raise InputError("--init starts a new run from a policy; --resume continues a run "
                         "and --imitate starts from a teacher: give one of them")
    out = check_output_file(Path(cfg.policy_path), "--out")
    for suffix in (".ckpt", ".csv", ".png"):  # the files written beside it
        check_output_file(out.with_suffix(suffix), "--out")
    if cfg.gate_string_stable is not None:
        check_output_dir(out.with_suffix(".candidates"), "--out")
    return cfg, out


TRAIN_CONVERTERS = {"base": expand_preset}
"""Training options read by a function of the command line rather than their type (besides the
shipped files found by name: :func:`carl_sumo.cli.config_options.field_converters`)."""


def _train_parser(sub: argparse._SubParsersAction) -> None:
    # train options
    p = sub.add_parser("train", help="train a CA-RL (or baseline) agent inside SUMO",
                       description="Train a CA-RL (or baseline) agent inside SUMO. Options come "
                       "from a recipe (--config) and the command line, which overrides it; "
                       "each is defined once, as a field of TrainConfig (carl_sumo/learn/"
                       "train_config.py) or of the RewardConfig, AgentConfig and Impairments "
                       "it gathers (docs/recipes.md).")
    p.add_argument("--config", type=Path, default=None, metavar="RECIPE.toml",
                   help="a recipe file (recipes/*.toml; see docs/recipes.md); options given "
                        "here override its values")
    p.add_argument("--print-config", action="store_true",
                   help="print the resolved configuration as a recipe and exit (trains nothing)")
    p.add_argument("--resume", type=Path, default=None, help="checkpoint (.ckpt) to continue")
    add_ray(p, "the --envs SUMO environments (as Ray actors; the same steps)")
    p.add_argument("--tensorboard", type=Path, default=None, metavar="DIR",
                   help="also log validation metrics, reward, actor and critic losses and Q "
                        "estimates to TensorBoard in DIR (the [tb] extra: tensorboardX)")
    p.add_argument("--progress-every", type=float, default=30.0, metavar="S",
                   help="without a terminal: one progress line on stderr every S seconds "
                        "(default 30)")
    add_config_options(p, TRAIN_CONVERTERS)


def stability_check(cfg):
    """``--trust-string-stable``'s check (a policy file's worst ‖Γ‖∞ on the gate's plant, at
    the gate's frequencies and amplitudes, :func:`carl_sumo.experiments.string_stability.
    worst_hinf`); None without the option."""
    if not cfg.trust_string_stable:
        return None
    from carl_sumo.experiments.string_stability import plant_impairments, worst_hinf

    impairments = plant_impairments(cfg.gate_string_stable)
    return lambda path: worst_hinf(str(path), impairments, net=cfg.net)


def cmd_train(args: argparse.Namespace) -> None:
    from carl_sumo.data import load_events
    from carl_sumo.experiments.string_stability import keep_string_stable
    from carl_sumo.learn.recipe import recipe_toml
    from carl_sumo.learn.train import train

    cfg, out = check_train_args(args, "carl-sumo " + " ".join(sys.argv[1:]))
    if args.print_config:
        print(recipe_toml(cfg), end="")
        return
    check_ray(args)
    if not (math.isfinite(args.progress_every) and args.progress_every > 0):
        raise InputError(f"--progress-every must be a positive number of seconds, got "
                         f"{args.progress_every:g}")
    if args.tensorboard is not None:
        from carl_sumo.learn.report import check_tensorboard

        check_tensorboard()
        check_output_dir(args.tensorboard, "--tensorboard")
    events = load_events(cfg.data, cfg.split)
    with ray_session(args, cfg.num_envs):
        if args.ray is not None:
            from carl_sumo.scale.cluster import require_cpus

            require_cpus(cfg.num_envs, "--envs")
        result = train(cfg, events, resume=args.resume,
                       progress=True if sys.stderr.isatty() else args.progress_every,
                       rollouts="processes" if args.ray is None else "ray",
                       tensorboard=args.tensorboard, stability_check=stability_check(cfg))
    if cfg.trust_string_stable:  # each kept checkpoint was checked as it was validated
        print(f"{out}: kept the best-scoring checkpoint that was string stable when validated "
              f"(--trust-string-stable)", file=sys.stderr)
    elif cfg.gate_string_stable is not None:
        keep_string_stable(out, cfg.select, cfg.gate_string_stable)  # says what it kept
    val = result["validation"]
    kept = (f"the best string-stable checkpoint; the best score before the gate "
            f"{result['best_score']:.4f}" if cfg.gate_string_stable is not None else
            f"best validation score {result['best_score']:.4f}")
    print(f"wrote {out} ({kept}); "
          f"wall time {result['wall_time_s']:.0f} s; last validation: "
          + ", ".join(f"{k}={fmt(v)}" for k, v in val.items()))
    print(compare_with_base(out))


def compare_with_base(path: Path) -> str:
    """One line: the kept policy's validation metrics against its base's on the same events."""
    from carl_sumo.learn.policy import read_policy_payload

    meta = read_policy_payload(path).get("metadata") or {}
    val, base = meta.get("validation") or {}, meta.get("validation_base") or {}
    shared = [k for k in ("headway_s", "jerk_mps3", "speed_mps", "dampening_ratio",
                          "ttc_lt_1_5s_count", "collisions") if k in val and k in base]
    if not shared:
        return f"{path}: no validation of its base ({meta.get('base', 'idm')}) to compare with"
    return (f"kept policy vs its base ({meta.get('base', 'idm')}) on the validation events: "
            + ", ".join(f"{k} {fmt(val[k])} vs {fmt(base[k])}" for k in shared))


def _tune_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("tune", help="tune a classical CACC's or ACC's gains, the multi-"
                                    "predecessor CACC's weights or the distributed MPC's "
                                    "weights, on the training events")
    p.add_argument("controller", choices=("ploeg", "acc", "mpf", "mpc"),
                   help="ploeg (CACC) or acc (the same law, radar only): their gains kp, kd; "
                        "mpf: the feed-forward weights of r = 2, 3 vehicles ahead on --base; "
                        "mpc: the MPC's weights, judged against --base")
    add_common(p, split_default="train")
    p.add_argument("--gaps", default=None,
                   help="time gaps h to tune (s), commas (default 0.6,0.8,1.0,1.2; acc: "
                        "2,2.5,3,3.5; mpf: the base's)")
    p.add_argument("--kp", default=None,
                   help="starting grid of kp (1/s²; default 0.1,0.15,0.2,0.3,0.45,0.675,1.0125)")
    p.add_argument("--kd", default=None,
                   help="starting grid of kd (1/s; default 0.5,0.7,1.0,1.4,2.1,3.15,4.725)")
    p.add_argument("--base", default=None,
                   help="mpf: the base law whose weights are tuned; mpc: the reference law the "
                        "objective and safety are relative to (default product-base, without "
                        "its washout wo)")
    p.add_argument("--heard", default=None,
                   help="mpf: vehicles heard r of the grid, commas (default 2,3)")
    p.add_argument("--w2", default=None,
                   help="mpf: starting grid of w2, the weight two ahead (default 0.1,...,0.5)")
    p.add_argument("--w3", default=None,
                   help="mpf: starting grid of w3, the weight three ahead (default 0.1,0.2)")
    from carl_sumo.experiments.tune_mpc import GRID_HELP

    for axis, text in GRID_HELP.items():
        p.add_argument(f"--{axis}", default=None, help=f"mpc: {text}")
    p.add_argument("--reuse", type=Path, default=None,
                   help="an earlier result file on the same events: its gains are not run again")
    p.add_argument("--headway-tolerance", type=float, default=0.05,
                   help="safe: mean headway at most this fraction above the textbook gains' "
                        "(mpf: the base's; default 0.05)")
    p.add_argument("--max-extensions", type=int, default=3,
                   help="times the grid may grow beyond an edge where the best point lies")
    p.add_argument("--events", type=int, default=None, metavar="K", help="only the first K events")
    p.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1),
                   help="parallel SUMO processes")
    p.add_argument("--out", type=Path, default=None,
                   help="result file (default policies/ploeg_tuned.json on the ideal plant, "
                        "else policies/<law>_tuned_<plant>.json)")
    add_impairments(p)
    add_warmup(p)


def _tune_config(args: argparse.Namespace):
    """The checked :class:`carl_sumo.experiments.tune.TuneConfig` of ``tune``'s options, and
    for ``mpf`` its :class:`carl_sumo.experiments.tune_mpf.MpfGrid`, for ``mpc`` its
    :class:`carl_sumo.experiments.tune_mpc.MpcGrid` (None otherwise)."""
    from carl_sumo.control.cacc import parse_ploeg
    from carl_sumo.experiments.tune import TuneConfig, parse_values
    from carl_sumo.experiments.tune_mpc import AXES as MPC_AXES, MpcGrid
    from carl_sumo.experiments.tune_mpf import HEARD, W2, W3, DEFAULT_BASE, MpfGrid

    positive(args.vehicles, "--vehicles")
    positive(args.workers, "--workers")
    if args.events is not None:
        positive(args.events, "--events")
    if args.max_extensions < 0:
        raise InputError("--max-extensions must not be negative")
    if not (math.isfinite(args.headway_tolerance) and args.headway_tolerance >= 0):
        raise InputError(f"--headway-tolerance must be a non-negative fraction, got "
                         f"{args.headway_tolerance}")
    mpf, mpc = args.controller == "mpf", args.controller == "mpc"
    own = {"mpf": ("--base", "--heard", "--w2", "--w3"),
           "mpc": ("--base",) + tuple(f"--{a}" for a in MPC_AXES),
           "gains": ("--kp", "--kd", "--reuse")}
    mine = own["mpf" if mpf else "mpc" if mpc else "gains"]
    given = [o for group in own.values() for o in group
             if o not in mine and getattr(args, o[2:]) is not None]
    if given:
        raise InputError(f"{', '.join(dict.fromkeys(given))}: not an option of `carl-sumo tune "
                         f"{args.controller}`")
    grid = None
    if mpf:
        heard = parse_values(args.heard or ",".join(map(str, HEARD)), "--heard")
        if any(r != int(r) for r in heard):
            raise InputError(f"--heard must be whole numbers, got {args.heard}")
        grid = MpfGrid(args.base or DEFAULT_BASE, tuple(int(r) for r in heard),
                       parse_values(args.w2 or ",".join(map(str, W2)), "--w2"),
                       parse_values(args.w3 or ",".join(map(str, W3)), "--w3"))
        grid.check(args.vehicles)
    if mpc:
        start = MpcGrid()
        grid = MpcGrid(args.base or DEFAULT_BASE, **{
            a: parse_values(getattr(args, a), f"--{a}") if getattr(args, a) is not None
            else getattr(start, a) for a in MPC_AXES})
        grid.check()
    impairments = impairments_from(args)
    gaps = args.gaps or ("2,2.5,3,3.5" if args.controller == "acc" else
                         f"{grid.base_params().time_gap_s:g}" if mpf else
                         f"{parse_ploeg(grid.reference_law()).time_gap_s:g}" if mpc else
                         "0.6,0.8,1.0,1.2")
    cfg = TuneConfig(gaps_s=parse_values(gaps, "--gaps"),
                     kp=parse_values(args.kp or "0.1,0.15,0.2,0.3,0.45,0.675,1.0125", "--kp"),
                     kd=parse_values(args.kd or "0.5,0.7,1.0,1.4,2.1,3.15,4.725", "--kd"),
                     n_followers=args.vehicles, headway_tolerance=args.headway_tolerance,
                     max_extensions=args.max_extensions, data=args.data, split=args.split,
                     net=str(args.net), workers=args.workers,
                     command="carl-sumo " + " ".join(sys.argv[1:]), law=args.controller,
                     impairments=impairments, warmup_s=warmup_from(args),
                     string_stable=impairments is not None and impairments.plant is not None)
    return cfg, grid


def cmd_tune(args: argparse.Namespace) -> None:
    from carl_sumo.control.cacc import tuned_file_for
    from carl_sumo.experiments import tune, tune_mpc, tune_mpf

    cfg, grid = _tune_config(args)
    out = args.out or tuned_file_for(cfg.law, cfg.plant_key)
    check_output_file(out, "--out")
    from carl_sumo.sim.sumo import lane_route

    lane_route(args.net)  # a missing or broken network fails before any worker starts
    log = lambda line: print(line, file=sys.stderr, flush=True)  # noqa: E731
    if grid is not None:
        module = tune_mpc if cfg.law == "mpc" else tune_mpf
        payload = getattr(module, f"tune_{cfg.law}")(cfg, grid, Path(out), args.events, log=log)
        print(module.format_result(payload))
        print(f"wrote {out}: {len(payload['grid'])} weight sets on {payload['events']} events "
              f"of split {cfg.split}, {payload['wall_time_s']:.0f} s")
        return
    payload = tune.tune_ploeg(cfg, Path(out), args.events, progress=sys.stderr.isatty(),
                              log=log, reuse=args.reuse)
    figure = tune.grid_figure(payload, Path(out).with_suffix(".png"))
    print(tune.format_result(payload))
    print(f"wrote {out} and {figure}: {len(payload['grid'])} gains on {payload['events']} events "
          f"of split {cfg.split}, {payload['wall_time_s']:.0f} s")


def _export_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("export", help="write the current actor of a training checkpoint as a policy")
    p.add_argument("checkpoint", type=Path)
    p.add_argument("--out", type=Path, required=True)


def cmd_export(args: argparse.Namespace) -> None:
    from carl_sumo.learn.train import export_policy

    check_output_file(args.out, "--out")
    meta = export_policy(args.checkpoint, args.out)
    print(f"wrote {args.out} ({meta['exported_from']})")


def _policy_info_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("policy-info", help="print the Markdown card of policy files")
    p.add_argument("paths", nargs="+", type=Path)
    p.add_argument("--table", action="store_true",
                   help="one Markdown table row per file (with its seed files in seeds/) "
                        "instead of a card each")
    p.add_argument("--recipe", action="store_true",
                   help="print each file's training configuration as a recipe (TOML) that "
                        "`carl-sumo train --config` re-trains it with")
    p.add_argument("--index", action="store_true",
                   help="print the index of a folder of shipped policies (PATHS: the folder; "
                        "policies/README.md is this index)")


def cmd_policy_info(args: argparse.Namespace) -> None:
    from carl_sumo.learn.policy import policy_card, policy_table

    if args.index:
        print(policy_index(args.paths[0]), end="")
        return
    if args.recipe:
        texts = [policy_recipe(path) for path in args.paths]  # all read before printing
        print("\n".join(texts), end="")
        return
    if args.table:
        print(policy_table(args.paths))
        return
    cards = [policy_card(path) for path in args.paths]  # all checked before anything is printed
    print("\n".join(cards))


PRODUCT_GROUP = ("ca_td3_real_10", "ca_td3_real_nocomm_10", "td3_real_10")
"""The real-plant product (CA-TD3 learning on the tuned multi-predecessor law, 160,000
transitions per seed) and its ablations with the same start, inputs and budget: the V2V messages
cut, and plain TD3."""
PAPER_GROUP = ("ca_td3_10", "ca_ddpg_10", "td3_1", "ddpg_1", "maddpg_10", "ca_td3_20",
               "ca_ddpg_20", "maddpg_20", "ca_td3_10_robust", "ca_td3_ploeg_10")
"""The paper's reproduction set on the ideal plant, its robust variant and the ideal-plant
product configuration."""


def policy_index(folder: Path) -> str:
    """The Markdown index of a folder of shipped policies: how to run and re-train them, then
    one table row per file (from its metadata and its recipe's description), the product and
    its ablations first, the paper's set, then any other policy file in the folder."""
    from carl_sumo.learn.policy import read_policy_payload

    folder = Path(folder)
    if not folder.is_dir():
        raise InputError(f"--index {folder}: not a folder; give the folder of the policies")
    stems = sorted(p.stem for p in folder.glob("*.pt"))

    def row(stem: str) -> str:
        meta = read_policy_payload(folder / f"{stem}.pt").get("metadata") or {}
        recipe = Path("recipes") / f"{stem}.toml"
        about = ""
        if recipe.is_file():
            import tomllib

            about = tomllib.loads(recipe.read_text()).get("description", "")
        val, base = meta.get("validation") or {}, meta.get("validation_base") or {}
        jerk = (f"{val['jerk_mps3']:.3f} / {base['jerk_mps3']:.3f}"
                if "jerk_mps3" in val and "jerk_mps3" in base else "–")
        seeds = len(list((folder / "seeds").glob(f"{stem}_seed*.pt")))
        gate = meta.get("string_stability_gate") or {}
        kept = f"{gate['candidate']} of {meta.get('steps')}" if "candidate" in gate else "best"
        return (f"| `{stem}.pt` | {about.replace('|', '/')} | {meta.get('algo', '?')} | "
                f"{seeds} (shipped: {meta.get('seed')}) | {kept} | {jerk} | "
                + (f"`recipes/{stem}.toml` |" if recipe.is_file() else "– |"))

    head = ["| file | what it is | algorithm | seeds (shipped) | checkpoint kept (of steps) | "
            "validation jerk, policy / base (m/s³) | recipe |", "|---|---|---|---|---|---|---|"]
    groups = [("The real-plant product and its ablations", [s for s in PRODUCT_GROUP if s in stems]),
              ("The paper's reproduction set (ideal plant)", [s for s in PAPER_GROUP if s in stems]),
              ("Other policies", [s for s in stems if s not in PRODUCT_GROUP + PAPER_GROUP])]
    lines = ["# Shipped policies", "",
             "Generated by `carl-sumo policy-info --index policies` (a test checks it); do not edit.",
             "",
             "- Run one by name from any folder: `carl-sumo simulate --controller product --plant "
             "real`, or `--controller ca_td3_10.pt` (a shipped file's name).",
             "- Each `<stem>.pt` is the run that validation ranks first (`carl-sumo rank`, on "
             "held-out training events) among `seeds/<stem>_seed<K>.pt`; `<stem>.csv` is its "
             "learning curve; `carl-sumo policy-info FILE` prints its card.",
             "- Re-train one: `carl-sumo train --config recipes/<stem>.toml --seed K`; "
             "`carl-sumo policy-info --recipe FILE` prints the configuration it was trained with.",
             "- `*_tuned*.json`: classical gains tuned for a plant (`carl-sumo tune`). The event "
             "lists the recipes name (`val_hard_real.txt` ...) are package data: "
             "`carl_sumo/data/event_lists/`, found by file name from any folder.",
             "- A checkpoint kept at step 1000 of a recipe with `imitate` is the copy of its "
             "teacher made before any RL update: its numbers are the teacher's, not a learned "
             "result (docs/training.md)."]
    for title, members in groups:
        if members:
            lines += ["", f"## {title}", "", *head, *map(row, members)]
    return "\n".join(lines) + "\n"


def policy_recipe(path: Path) -> str:
    """The recipe (TOML) that re-trains a policy file: its stored configuration, or for a file
    from before configurations were stored, the configuration of its recorded command."""
    import shlex

    from carl_sumo.learn.policy import read_policy_payload
    from carl_sumo.learn.recipe import config_from_stored, recipe_toml

    meta = read_policy_payload(path).get("metadata") or {}
    if isinstance(meta.get("config"), dict):
        cfg = config_from_stored(meta["config"])
    elif str(meta.get("command", "")).startswith("carl-sumo train "):
        args = train_parser().parse_args(shlex.split(meta["command"])[1:])
        cfg, _ = check_train_args(args)
    else:
        raise InputError(f"{path} records no training configuration (no `carl-sumo train` "
                         "command); it was not trained by `carl-sumo train`")
    return recipe_toml(cfg, f"re-trains {Path(path).name}")


def _rank_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("rank", help="rank runs of one model (several seeds) by their stored "
                       "validation score, best first")
    p.add_argument("paths", nargs="+", type=Path, help="policy files of one algorithm")
    p.add_argument("--select", default="margin", choices=("margin", "comfort", "metrics", "reward"),
                   help="the rule of `train --select` (default margin)")
    p.add_argument("--best-only", action="store_true",
                   help="print only the path of the best run (for scripts)")
    p.add_argument("--string-stable", choices=("ideal", "real"),
                   help="the best run must also be string stable on this plant: ‖Γ‖∞ <= 1 on "
                        "every class of its fleet at leader amplitudes 0.5 and 2 m/s (5 "
                        "followers, 24 frequencies 0.05-3 rad/s, a synthetic leader: no test "
                        "event); runs are checked in rank order until one passes, a few "
                        "minutes each on the real plant")


def cmd_rank(args: argparse.Namespace) -> None:
    from carl_sumo.learn.selection import rank_runs

    rows = rank_runs(args.paths, args.select)
    if args.string_stable:
        from carl_sumo.experiments.string_stability import string_stable_first

        rows = string_stable_first(rows, args.string_stable)
    if args.best_only:
        print(rows[0]["path"])
        return
    inputs = [k for k in rows[0] if k not in ("path", "seed", "score", "unsafe", "hinf")]
    hinf = ["worst ‖Γ‖∞"] if args.string_stable else []
    print("| rank | file | seed | score | unsafe | " + " | ".join(inputs + hinf) + " |")
    print("|---" * (5 + len(inputs) + len(hinf)) + "|")
    for i, r in enumerate(rows, 1):
        cells = [f"{r[k]:.3f}" for k in inputs] + \
            ([f"{r['hinf']:.4f}" if "hinf" in r else "not checked"] if hinf else [])
        print(f"| {i} | `{Path(r['path']).name}` | {r['seed']} | {r['score']:.3f} | "
              f"{'yes' if r['unsafe'] else 'no'} | " + " | ".join(cells) + " |")
    print(f"best: {rows[0]['path']}")



def train_parser():
    """The parser of ``carl-sumo train`` alone (a usage error: InputError)."""
    from carl_sumo.cli.common import Parser

    parser = Parser(prog="carl-sumo")
    _train_parser(parser.add_subparsers(dest="command", required=True, parser_class=Parser))
    return parser
