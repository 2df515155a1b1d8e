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

from carl_sumo.cli.common import (add_common, add_event_choice, add_impairments, add_ray,
                                 add_warmup, check_ray, fmt, impairments_from, positive,
                                 ray_session, warmup_from)
from carl_sumo.errors import InputError
from carl_sumo.files import check_output_dir, check_output_file


def _add_reward_options(p: argparse.ArgumentParser) -> None:
    """The reward's weights (defaults: carl_sumo.config.REWARD)."""
    p.add_argument("--w-gap", type=float, default=None, help="reward weight of the headway term")
    p.add_argument("--w-safe", type=float, default=None, help="reward weight of the TTC term")
    p.add_argument("--w-comfort", type=float, default=None, help="reward weight of the jerk term")
    p.add_argument("--w-accel", type=float, default=None,
                   help="weight of the optional control-effort term -w·a² (default 0: off)")
    p.add_argument("--w-spacing", type=float, default=None,
                   help="weight of the optional spacing term -w·min((e/v)², 1), e = d - 2 m - "
                        "h_s·v (default 0: off)")
    p.add_argument("--w-critical", type=float, default=None,
                   help="penalty per follower and step with a time to collision below 1.5 s, "
                        "the metric's bar (default 0: off)")
    p.add_argument("--w-amplify", type=float, default=None, help="weight of the optional "
                   "amplification term -w·max(a_i² - a_(i-1)², 0), a in m/s² (default 0: off)")
    p.add_argument("--lagrange-lr", type=float, default=None,
                   help="RCPO: price close calls at a learned multiplier that rises while they "
                        "are more frequent than the base's (learn/constraint.py; default 0: off)")
    p.add_argument("--spacing-gap", type=float, default=None, help="spacing term's h_s (s; 0.8)")
    p.add_argument("--spacing-head-gap", type=float, default=None,
                   help="the head's h_s (s; default: --spacing-gap), e.g. a degraded CACC's ha")
    p.add_argument("--spacing-heavy-gap", type=float, default=None,
                   help="h_s of a vehicle braking below 7 m/s² (s; default: --spacing-gap), ht")
    p.add_argument("--jerk-scale", type=float, default=None, help="the jerk scale (m/s³)")


MAX_TRAIN_VEHICLES = 200
"""The longest platoon ``train`` accepts (its replay buffer grows with the platoon)."""


def _check_learning_values(args: argparse.Namespace) -> None:
    """InputError for a learning option outside its range (before any allocation or run)."""
    if args.vehicles > MAX_TRAIN_VEHICLES:
        raise InputError(f"--vehicles {args.vehicles} is more than {MAX_TRAIN_VEHICLES}; a "
                         "shared-weight policy trained on a shorter platoon runs any length")
    for name in ("actor_lr", "critic_lr", "imitate_lr"):
        value = getattr(args, name, None)
        if value is not None and not (math.isfinite(value) and value > 0):
            raise InputError(f"--{name.replace('_', '-')} must be a positive learning rate, "
                             f"got {value}")
    if args.gamma is not None and not (math.isfinite(args.gamma) and 0 < args.gamma <= 1):
        raise InputError(f"--gamma is a discount per step in (0, 1], got {args.gamma}")
    _check_ranges(args)


_RANGES = {  # option: (lowest, highest, whether the bounds are allowed), finite in any case
    "noise": (0.0, math.inf, True), "w_gap": (0.0, math.inf, True),
    "w_safe": (0.0, math.inf, True), "w_comfort": (0.0, math.inf, True),
    "w_accel": (0.0, math.inf, True), "w_spacing": (0.0, math.inf, True),
    "w_critical": (0.0, math.inf, True), "w_amplify": (0.0, math.inf, True),
    "lagrange_lr": (0.0, math.inf, True), "smooth_jerk": (0.0, math.inf, True),
    "spacing_gap": (0.0, 5.0, True), "spacing_head_gap": (0.0, 5.0, True),
    "spacing_heavy_gap": (0.0, 5.0, True), "smooth_accel": (0.0, math.inf, True),
    "adj_l2": (0.0, math.inf, True),
    "adj_max": (0.0, math.inf, False), "jerk_scale": (0.0, math.inf, False),
    "noise_correlation": (0.0, 1.0, None), "critic_burn_in": (0, math.inf, True),
    "braking_events": (0, math.inf, True), "seed": (0, math.inf, True),
    "val_seed": (0, math.inf, True), "impairment_seed": (0, math.inf, True),
    "hidden": (1, math.inf, True), "message_dim": (1, math.inf, True),
    "eval_events": (1, math.inf, True), "oversample_times": (1, math.inf, True)}
"""The ranges of train's numeric options (None: the lowest bound is allowed, not the highest)."""


def _check_ranges(args: argparse.Namespace) -> None:
    """InputError, one line, for a training option outside :data:`_RANGES` (before any run)."""
    for name, (low, high, closed) in _RANGES.items():
        value = getattr(args, name, None)
        if value is None:
            continue
        inside = math.isfinite(value) and (low <= value if closed is not False else low < value) \
            and (value <= high if closed else value < high)
        if not inside:
            bounds = ("[" if closed is not False else "(") + f"{low:g}, " + (
                f"{high:g}]" if closed and high < math.inf else f"{high:g})")
            raise InputError(f"--{name.replace('_', '-')} must be a finite number in {bounds}, "
                             f"got {value}")


def check_train_args(args: argparse.Namespace) -> Path:
    """InputError for any bad ``train`` option (before anything runs); the policy file path."""
    from carl_sumo.learn.agents import ALGOS, AgentConfig

    if args.algo not in ALGOS:
        raise InputError(f"unknown algorithm {args.algo!r}; choose one of {', '.join(ALGOS)}")
    for name in ("vehicles", "steps", "envs", "eval_every", "checkpoint_every"):
        positive(getattr(args, name), "--" + name.replace("_", "-"))
    for name in ("update_every", "batch_size", "imitate_updates"):
        if getattr(args, name) is not None:
            positive(getattr(args, name), "--" + name.replace("_", "-"))
    _check_learning_values(args)
    if args.base is not None:
        from carl_sumo.control.controllers import check_base

        check_base(args.base)
    if args.shield_ttc is not None and not (math.isfinite(args.shield_ttc)
                                            and args.shield_ttc >= 0):
        raise InputError(f"--shield-ttc must be a time to collision of 0 s or more (0: off), "
                         f"got {args.shield_ttc}")
    if args.tau is not None and not (math.isfinite(args.tau) and 0 < args.tau <= 1):
        raise InputError(f"--tau is the target networks' soft-update rate per update, in (0, 1], "
                         f"got {args.tau}")
    if args.scale_rates:
        every = args.update_every or 1
        scaled_tau = every * (args.tau or AgentConfig.tau)
        if every == 1:
            raise InputError("--scale-rates multiplies the rates by --update-every K; give "
                             "--update-every 2 or more, or leave --scale-rates out")
        if scaled_tau > 1:
            raise InputError(f"--scale-rates: --tau times --update-every is {scaled_tau:g}, "
                             "above 1; give a smaller --tau or --update-every")
    warmup_from(args)
    if args.comm_fallback is not None or args.comm_off:  # AgentConfig says what is wrong
        AgentConfig(algo=args.algo, comm_fallback=args.comm_fallback or "boundary",
                    comm_off=bool(args.comm_off))
    if args.plant_randomize and (args.comm_randomize or impairments_from(args) is not None):
        raise InputError("--plant-randomize draws every episode's plant and channel itself; "
                         "leave out --comm-randomize, --plant and the --comm-* options")
    if args.randomize_sensors is False and not args.comm_randomize:
        raise InputError("--no-sensor-randomize narrows --comm-randomize; give both, or neither")
    if impairments_from(args) is not None and args.comm_randomize:
        raise InputError("--comm-randomize draws every episode's impairments itself; give it or "
                         "fixed --comm-*/--sensor-noise options, not both")
    if args.init is not None:
        if args.resume is not None or args.imitate is not None:
            raise InputError("--init starts a new run from a policy; --resume continues a run "
                             "and --imitate starts from a teacher: give one of them")
        from carl_sumo.learn.policy import read_policy_payload

        read_policy_payload(args.init)
    if args.imitate_target is not None and (args.imitate is None or (args.base or "idm") == "idm"):
        raise InputError("--imitate-target is for --imitate on an ACC base (--base acc:...)")
    if args.imitate is not None:
        from carl_sumo.learn.imitation import check_teacher_base, teacher

        teacher(args.imitate)
        check_teacher_base(args.imitate, args.base or "idm")
    starts = args.learning_starts
    if starts is not None and (starts < 0 or starts >= args.steps):
        raise InputError(f"--learning-starts {starts} leaves no training step in --steps "
                         f"{args.steps}; give fewer learning starts or more steps")
    return check_output_file(args.out or Path("policies") / f"{args.algo.replace('-', '_')}.pt",
                             "--out")


def train_config(args: argparse.Namespace, out: Path, command: str):
    """The :class:`carl_sumo.learn.train.TrainConfig` of parsed ``train`` options."""
    from carl_sumo.learn.train import TrainConfig

    return TrainConfig(algo=args.algo, n_vehicles=args.vehicles, steps=args.steps, seed=args.seed,
                      num_envs=args.envs, learning_starts=args.learning_starts,
                      eval_every=args.eval_every, checkpoint_every=args.checkpoint_every,
                      net=args.net, data=args.data, split=args.split, out=str(out),
                      command=command,
                      **{k: getattr(args, k) for k in TRAIN_OVERRIDES if getattr(args, k) is not None})


def _add_robust_training_options(p: argparse.ArgumentParser) -> None:
    """Training for impaired V2V and sensors (carl_sumo.learn.randomize): fixed impairments in every
    episode (the --comm-* options of simulate), or randomised ones."""
    add_impairments(p)
    p.add_argument("--comm-randomize", action="store_true", default=None,
                   help="robust training: every episode draws its own V2V delay (0-0.5 s), loss "
                        "(0-100 %%, in bursts half the time) and sensor noise (half the time), "
                        "a quarter of them perfect; the actor learns on the messages as they "
                        "arrive (see docs/robustness.md)")
    p.add_argument("--no-sensor-randomize", dest="randomize_sensors", action="store_false",
                   default=None,
                   help="with --comm-randomize: randomise the V2V channel only, clean sensors "
                        "in every episode (the same channel draws)")
    p.add_argument("--val-impaired", action="store_true", default=None,
                   help="validate every event also with 30 %% loss in bursts of 3 steps, 0.2 s "
                        "delay and sensor noise (clean sensors with --no-sensor-randomize; with "
                        "fixed --comm-* options: under those), and keep the checkpoint that is "
                        "best over both")
    p.add_argument("--plant-randomize", action="store_true", default=None,
                   help="every episode its own fleet (0-50 %% trucks), lags (per class, or one "
                        "0.05-0.8 s lag and 0-0.3 s dead time for all), V2V delay (0-0.3 s) and "
                        "message loss (0-30 %%); validation on the real plant (docs/vehicles.md)")
    p.add_argument("--comm-off", action="store_true", default=None,
                   help="CA models: cut the V2V messages (every vehicle hears only the boundary "
                        "messages), the communication ablation; part of the policy file")
    p.add_argument("--comm-fallback", default=None, metavar="{boundary,base}",
                   help="what a CA vehicle does at run time when it hears no neighbour past "
                        "--comm-timeout: boundary (default: it acts as a chain end) or base (it "
                        "also drops its adjustment, fading out with the messages, and drives on "
                        "its base, as Ploeg's CACC drops to ACC); part of the policy file")


def _add_learning_options(p: argparse.ArgumentParser) -> None:
    """The networks, the optimisers and their update schedule, and the exploration."""
    p.add_argument("--update-every", type=int, default=None, metavar="K",
                   help="one round of updates every K steps instead of every step (default 1); "
                        "give --scale-rates too to learn as much per env step")
    p.add_argument("--scale-rates", action="store_true", default=None,
                   help="with --update-every K: multiply --actor-lr, --critic-lr and --tau by "
                        "K, so the networks move as far per env step as with an update every "
                        "step (with K = 3: the same learning, measured, at a third of the "
                        "updates; docs/bench.md)")
    p.add_argument("--batch-size", type=int, default=None,
                   help="transitions per gradient update (default 128)")
    p.add_argument("--lr-decay", action="store_true", default=None,
                   help="the learning rates fall linearly from their values at "
                        "--learning-starts to 0 at --steps (default: constant)")
    p.add_argument("--message-dim", type=int, default=None, help="V2V message width (CA models)")
    p.add_argument("--hidden", type=int, default=None, help="hidden layer width")
    p.add_argument("--actor-lr", type=float, default=None, help="actor learning rate")
    p.add_argument("--critic-lr", type=float, default=None, help="critic learning rate")
    p.add_argument("--tau", type=float, default=None,
                   help="soft-update rate of the target networks per update (default 0.005)")
    p.add_argument("--noise", type=float, default=None,
                   help="exploration noise std as a fraction of the a_adj bound")
    p.add_argument("--noise-correlation", type=float, default=None,
                   help="AR(1) coefficient of the exploration noise per step (0 = white)")
    p.add_argument("--gamma", type=float, default=None, help="discount per 0.1 s step (0.98)")
    p.add_argument("--adj-max", type=float, default=None,
                   help="bound of the learned adjustment |a_adj| (m/s², default 3)")
    p.add_argument("--smooth-jerk", type=float, default=None,
                   help="actor loss weight on the policy's jerk, per (m/s³)² (default 0)")
    p.add_argument("--smooth-accel", type=float, default=None,
                   help="actor loss weight on the policy's acceleration, per (m/s²)² (default 0)")
    p.add_argument("--adj-l2", type=float, default=None,
                   help="actor loss weight on the adjustment itself, W·a_adj² per (m/s²)²: keeps "
                        "the learned term near its base (default 0)")


def _train_parser(sub: argparse._SubParsersAction) -> None:
    # train options
    p = sub.add_parser("train", help="train a CA-RL (or baseline) agent inside SUMO")
    add_common(p, split_default="train")
    p.add_argument("--algo", default="ca-td3", help="ca-td3 | ca-ddpg | td3 | ddpg | maddpg")
    p.add_argument("--steps", type=int, default=20_000, help="vector steps (all envs at once)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--envs", type=int, default=2, help="parallel SUMO worker processes")
    add_ray(p, "the --envs SUMO environments (as Ray actors; the same steps)")
    p.add_argument("--learning-starts", type=int, default=1_000)
    p.add_argument("--eval-every", type=int, default=2_000)
    p.add_argument("--checkpoint-every", type=int, default=5_000)
    p.add_argument("--out", type=Path, default=None, help="policy file (default policies/ALGO.pt)")
    p.add_argument("--resume", type=Path, default=None, help="checkpoint (.ckpt) to continue")
    p.add_argument("--tensorboard", type=Path, default=None, metavar="DIR",
                   help="also log validation metrics, reward, actor and critic losses and Q "
                        "estimates to TensorBoard in DIR (the [tb] extra: tensorboardX)")
    p.add_argument("--progress-every", type=float, default=30.0, metavar="S",
                   help="without a terminal: one progress line on stderr every S seconds "
                        "(default 30)")
    p.add_argument("--select", default=None, choices=("margin", "comfort", "metrics", "reward"),
                   help="how the best validation checkpoint is kept: margin (default: the "
                        "largest smallest z of the improvement over the base on jerk, dampening "
                        "and speed), comfort (the same on jerk and dampening only, at most 5 %% "
                        "above the base's headway), metrics (jerk and dampening relative to the "
                        "base, speed at least the base's) or reward")
    p.add_argument("--gate-string-stable", default=None, choices=("ideal", "real"),
                   help="keep every validated checkpoint in <out>.candidates/; --out is then "
                        "the best-scoring one string stable on this plant (8 frequencies)")
    p.add_argument("--braking-events", type=int, default=None, metavar="N",
                   help="add N synthetic hard-braking leaders (15-30 m/s, -3 to -6 m/s²) to the "
                        "training events, a quarter of them to the validation events (default 0)")
    p.add_argument("--critic-burn-in", type=int, default=None, metavar="STEPS",
                   help="steps after --learning-starts that train the critics only, the actor "
                        "staying as it is (residual policy learning's burn-in; default 0)")
    p.add_argument("--observe-ahead", action="store_true", default=None,
                   help="IDM base: each vehicle also observes the acceleration of the vehicle "
                        "ahead over the last step, as its own radar measures it (what Ploeg's "
                        "CACC feeds forward); the head's is the NGSIM leader's")
    p.add_argument("--shield-ttc", type=float, default=None, metavar="S",
                   help="safety shield: a follower closing in with a time to collision below S "
                        "seconds gets no positive adjustment (the learned term may only brake "
                        "more there); part of the policy, in training and wherever it runs "
                        "(default 0: off)")
    _add_robust_training_options(p)
    add_warmup(p)
    p.add_argument("--imitate", default=None, metavar="TEACHER",
                   help="warm start: the platoons drive with this teacher plus exploration noise for "
                        "--learning-starts steps, then the actor is fitted to it before RL: a Ploeg "
                        "CACC on the IDM base, on an ACC base the CACC with its gains (--base "
                        "acc:h=0.8:kp=0.3:kd=1.5 --imitate ploeg:h=0.8:kp=0.3:kd=1.5), or on a CACC "
                        "base two-ahead:c=C (C of the command two ahead fed forward, docs/training.md)")
    p.add_argument("--imitate-target", choices=("realised", "command"), default=None,
                   help="on an ACC base, what the copied feed-forward carries: the predecessor's "
                        "realised acceleration (default) or its command a_base")
    p.add_argument("--imitate-updates", type=int, default=None,
                   help="behaviour-cloning gradient steps of --imitate (default 4000)")
    p.add_argument("--init", default=None, metavar="POLICY.pt", help="warm start from a trained "
                   "policy of the same configuration: its actor drives from the first step and is "
                   "the first candidate; the critics start fresh (give --critic-burn-in)")
    p.add_argument("--base", default=None,
                   help="base model under the learned adjustment: idm (default, the paper's) or "
                        "a classical CACC such as ploeg-tuned:h=0.8 (the actor starts at a_adj = 0)")
    _add_reward_options(p)
    _add_learning_options(p)
    add_event_choice(p)


TRAIN_OVERRIDES = ("select", "gate_string_stable", "w_gap", "w_safe", "w_comfort", "w_accel",
                   "w_spacing", "w_critical", "w_amplify", "lagrange_lr", "spacing_gap",
                   "spacing_head_gap", "spacing_heavy_gap", "jerk_scale", "message_dim", "hidden",
                   "actor_lr", "critic_lr", "tau", "noise", "noise_correlation", "smooth_jerk",
                   "smooth_accel", "adj_l2", "eval_events", "val_seed", "val_source", "val_events",
                   "oversample", "oversample_times", "gamma", "adj_max", "base", "critic_burn_in",
                   "braking_events", "update_every", "scale_rates", "lr_decay", "batch_size",
                   "imitate", "imitate_target", "imitate_updates", "init", "observe_ahead",
                   "shield_ttc", "comm_fallback", "comm_randomize", "randomize_sensors",
                   "val_impaired", "comm_delay", "comm_loss", "comm_burst", "comm_timeout",
                   "comm_fade", "warmup", "sensor_noise", "sensor_filter", "impairment_seed",
                   "plant", "fleet", "vehicle_lag", "actuation_delay", "plant_randomize",
                   "comm_off", "exclude_events")
"""Training options that, when given, override the defaults of TrainConfig."""


def cmd_train(args: argparse.Namespace) -> None:
    from carl_sumo.data import load_events
    from carl_sumo.experiments.string_stability import keep_string_stable
    from carl_sumo.learn.train import train

    out = check_train_args(args)
    check_ray(args)
    if not (math.isfinite(args.progress_every) and args.progress_every > 0):
        raise InputError(f"--progress-every must be a positive number of seconds, got "
                         f"{args.progress_every:g}")
    if args.tensorboard is not None:
        from carl_sumo.learn.report import check_tensorboard

        check_tensorboard()
        check_output_dir(args.tensorboard, "--tensorboard")
    events = load_events(args.data, args.split)
    cfg = train_config(args, out, "carl-sumo " + " ".join(sys.argv[1:]))
    with ray_session(args, args.envs):
        if args.ray is not None:
            from carl_sumo.scale.cluster import require_cpus

            require_cpus(args.envs, "--envs")
        result = train(cfg, events, resume=args.resume,
                       progress=True if sys.stderr.isatty() else args.progress_every,
                       rollouts="processes" if args.ray is None else "ray",
                       tensorboard=args.tensorboard)
    if cfg.gate_string_stable is not None:
        keep_string_stable(out, cfg.select, cfg.gate_string_stable)  # says what it kept
    val = result["validation"]
    print(f"wrote {out} (best validation score {result['best_score']:.4f}); "
          f"wall time {result['wall_time_s']:.0f} s; last validation: "
          + ", ".join(f"{k}={fmt(v)}" for k, v in val.items()))


def _tune_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("tune", help="tune a classical CACC's or ACC's gains on the training events")
    p.add_argument("controller", choices=("ploeg", "acc"),
                   help="ploeg (CACC) or acc (the same law, radar only)")
    add_common(p, split_default="train")
    p.add_argument("--gaps", default=None,
                   help="time gaps h to tune (s), commas (default 0.6,0.8,1.0,1.2; acc: "
                        "2,2.5,3,3.5)")
    p.add_argument("--kp", default="0.1,0.15,0.2,0.3,0.45,0.675,1.0125",
                   help="starting grid of kp (1/s²)")
    p.add_argument("--kd", default="0.5,0.7,1.0,1.4,2.1,3.15,4.725",
                   help="starting grid of kd (1/s)")
    p.add_argument("--reuse", type=Path, default=None,
                   help="an earlier result file on the same events: its gains are not run again")
    p.add_argument("--headway-tolerance", type=float, default=0.05,
                   help="safe: mean headway at most this fraction above the textbook gains' "
                        "(default 0.05)")
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


def cmd_tune(args: argparse.Namespace) -> None:
    from carl_sumo.control.cacc import tuned_file_for
    from carl_sumo.experiments.tune import TuneConfig, format_result, grid_figure, parse_values, tune_ploeg

    positive(args.vehicles, "--vehicles")
    positive(args.workers, "--workers")
    if args.events is not None:
        positive(args.events, "--events")
    if args.max_extensions < 0:
        raise InputError("--max-extensions must not be negative")
    if not (math.isfinite(args.headway_tolerance) and args.headway_tolerance >= 0):
        raise InputError(f"--headway-tolerance must be a non-negative fraction, got "
                         f"{args.headway_tolerance}")
    impairments = impairments_from(args)
    gaps = args.gaps or ("2,2.5,3,3.5" if args.controller == "acc" else "0.6,0.8,1.0,1.2")
    cfg = TuneConfig(gaps_s=parse_values(gaps, "--gaps"), kp=parse_values(args.kp, "--kp"),
                     kd=parse_values(args.kd, "--kd"), n_followers=args.vehicles,
                     headway_tolerance=args.headway_tolerance,
                     max_extensions=args.max_extensions, data=args.data, split=args.split,
                     net=str(args.net), workers=args.workers,
                     command="carl-sumo " + " ".join(sys.argv[1:]), law=args.controller,
                     impairments=impairments, warmup_s=warmup_from(args),
                     string_stable=impairments is not None and impairments.plant is not None)
    out = args.out or tuned_file_for(cfg.law, cfg.plant_key)
    check_output_file(out, "--out")
    from carl_sumo.sim.sumo import lane_route

    lane_route(args.net)  # a missing or broken network fails before any worker starts
    payload = tune_ploeg(cfg, Path(out), args.events, progress=sys.stderr.isatty(),
                         log=lambda line: print(line, file=sys.stderr, flush=True),
                         reuse=args.reuse)
    figure = grid_figure(payload, Path(out).with_suffix(".png"))
    print(format_result(payload))
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


def cmd_policy_info(args: argparse.Namespace) -> None:
    from carl_sumo.learn.policy import policy_card, policy_table

    if args.table:
        print(policy_table(args.paths))
        return
    cards = [policy_card(path) for path in args.paths]  # all checked before anything is printed
    print("\n".join(cards))


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
                        "followers, 8 frequencies 0.05-3 rad/s, a synthetic leader: no test "
                        "event); runs are checked in rank order until one passes, about a "
                        "minute each on the real plant")


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

