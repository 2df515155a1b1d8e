"""``carl-sumo sweep SPEC.toml``: seed and hyperparameter sweeps of ``train`` on Ray Tune.

A spec (TOML) names fixed ``train`` options and the options searched over::

    name = "ca_td3_10"            # trial files: OUT/NAME[_OPTIONVALUE...]_seedK.pt (.csv, .ckpt)
    out = "policies/seeds"        # folder of the trials' policy files and curves
    results = "results/sweeps/ca_td3_10"  # sweep.md, trials.csv, configs.csv, Tune's state
    search = "grid"               # grid: every combination; random: `samples` draws of [random]
    cpus_per_trial = 1            # Ray CPUs a trial holds (its --envs processes come on top)
    max_failures = 3              # times a trial whose worker or node died resumes
    ship = "policies/ca_td3_10.pt"  # optional: the best run is copied here (with its curve)
    ship_string_stable = "real"   # optional: ship the best-scoring run of the best configuration
                                  # that is string stable on this plant (rank --string-stable)

    recipe = "../recipes/paper_ca_td3_10.toml"  # the recipe every trial trains (relative to
                                  # the spec; `carl-sumo train --config`), or none

    [train]                       # options over the recipe's: a recipe key, or a flag without
    steps = 10000                 # its dashes (`carl-sumo train --help`)
    init = "policies/seeds/ca_td3_10_seed{seed}.pt"  # {seed}: the trial's seed

    [grid]                        # lists: every combination runs (a configuration per non-seed
    seed = [0, 1, 2]              # combination; its seeds are its repetitions)

    [random]                      # search = "random": {uniform|loguniform|randint = [lo, hi]}
    actor_lr = {loguniform = [3e-5, 3e-4]}   # or {choice = [...]}, drawn with random_seed

Each trial is one ``train`` run (validation on its held-out events included) in a Ray Tune trial;
its atomic checkpoints (``--checkpoint-every``) are Tune's checkpoints, so a trial whose worker
process or node dies resumes from its last one. The spec is checked whole (every trial's options
parsed, outputs writable, data readable) before Ray starts. :mod:`carl_sumo.cli.sweep_report` writes
the tables and picks the best configuration by validation only.
"""

from __future__ import annotations

import itertools
import logging
import os
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from carl_sumo.errors import InputError
from carl_sumo.files import atomic_path, check_output_dir

SPEC_KEYS = {"name", "out", "results", "search", "samples", "random_seed", "cpus_per_trial",
             "max_failures", "ship", "ship_string_stable", "recipe", "train", "grid", "random"}
NOT_SWEPT = {"out", "resume", "ray"}
"""``train`` options a spec may not set: the sweep names the files and runs the trials."""
DISTRIBUTIONS = ("uniform", "loguniform", "randint", "choice")


@dataclass
class Trial:
    """One ``train`` run of a sweep."""

    name: str          # file stem: OUT/NAME.pt
    config: str        # its configuration (the name without the seed)
    seed: int
    values: dict[str, Any]  # the searched options' values (seed included)
    argv: list[str]    # `carl-sumo train` arguments


@dataclass
class SweepSpec:
    """A parsed spec file (see the module docstring)."""

    path: Path
    name: str
    out: Path
    results: Path
    search: str = "grid"
    samples: int = 1
    random_seed: int = 0
    cpus_per_trial: float = 1.0
    max_failures: int = 3
    ship: Path | None = None
    ship_string_stable: str | None = None  # "ideal" or "real" (see the module docstring)
    recipe: Path | None = None  # the recipe file of every trial (train --config)
    train: dict[str, Any] = field(default_factory=dict)
    grid: dict[str, list] = field(default_factory=dict)
    random: dict[str, dict] = field(default_factory=dict)

    @property
    def select(self) -> str:
        """The validation rule that picks the best run (the trials' ``--select``)."""
        if "select" in self.train:
            return str(self.train["select"])
        if self.recipe is not None:
            from carl_sumo.learn.recipe import read_recipe

            return str(read_recipe(self.recipe).get("select", "margin"))
        return "margin"


def _fail(path: Path, message: str) -> InputError:
    return InputError(f"sweep spec {path}: {message}")


def load_spec(path: Path, out: Path | None = None, results: Path | None = None) -> SweepSpec:
    """Read and check a spec file (InputError, one line, for anything wrong in it)."""
    import tomllib

    path = Path(path)
    try:
        raw = tomllib.loads(path.read_text())
    except OSError as exc:
        raise InputError(f"cannot read sweep spec {path} ({exc.strerror}); give a .toml file "
                         "such as sweeps/ca_td3.toml") from None
    except tomllib.TOMLDecodeError as exc:
        raise _fail(path, f"not valid TOML ({exc})") from None
    unknown = sorted(set(raw) - SPEC_KEYS)
    if unknown:
        raise _fail(path, f"unknown key(s) {', '.join(unknown)}; a spec has "
                          f"{', '.join(sorted(SPEC_KEYS))}")
    name = raw.get("name")
    if not isinstance(name, str) or not name or "/" in name:
        raise _fail(path, "give name = \"STEM\" (the trials' file stem, no folders)")
    spec = SweepSpec(path, name, Path(out or raw.get("out", f"results/sweeps/{name}/runs")),
                     Path(results or raw.get("results", f"results/sweeps/{name}")))
    for key, kind in (("search", str), ("samples", int), ("random_seed", int),
                      ("cpus_per_trial", (int, float)), ("max_failures", int),
                      ("train", dict), ("grid", dict), ("random", dict)):
        if key in raw:
            if not isinstance(raw[key], kind) or isinstance(raw[key], bool):
                raise _fail(path, f"{key} has the wrong type ({type(raw[key]).__name__})")
            setattr(spec, key, raw[key])
    spec.ship = Path(raw["ship"]) if "ship" in raw else None
    if "recipe" in raw:
        if not isinstance(raw["recipe"], str):
            raise _fail(path, "give recipe = \"PATH\" (a recipe file, relative to the spec)")
        spec.recipe = Path(os.path.relpath(path.parent / raw["recipe"]))
        if not spec.recipe.is_file():
            raise _fail(path, f"recipe {spec.recipe} does not exist")
    spec.ship_string_stable = raw.get("ship_string_stable")
    if spec.ship_string_stable not in (None, "ideal", "real"):
        raise _fail(path, f"ship_string_stable = {spec.ship_string_stable!r}: give \"ideal\" or "
                          "\"real\" (the plant of the frequency test), or leave it out")
    _check_search(spec)
    return spec


def _check_search(spec: SweepSpec) -> None:
    path = spec.path
    if spec.search not in ("grid", "random"):
        raise _fail(path, f"search = {spec.search!r}: choose grid or random")
    if spec.samples < 1 or spec.cpus_per_trial <= 0 or spec.max_failures < 0:
        raise _fail(path, "samples must be at least 1, cpus_per_trial positive, max_failures "
                          "0 or more")
    if spec.search == "grid" and spec.random:
        raise _fail(path, "a [random] table needs search = \"random\"")
    for key, values in spec.grid.items():
        if not isinstance(values, list) or not values:
            raise _fail(path, f"grid.{key} must be a non-empty list of values")
    for key, dist in spec.random.items():
        if not (isinstance(dist, dict) and len(dist) == 1 and next(iter(dist)) in DISTRIBUTIONS):
            raise _fail(path, f"random.{key} must be one of {{uniform|loguniform|randint = "
                              f"[lo, hi]}} or {{choice = [...]}}")
        kind, bounds = next(iter(dist.items()))
        if kind != "choice" and not (isinstance(bounds, list) and len(bounds) == 2
                                     and bounds[0] < bounds[1]
                                     and (kind != "loguniform" or bounds[0] > 0)):
            raise _fail(path, f"random.{key}: {kind} needs [lo, hi] with lo < hi"
                              + (" and lo > 0" if kind == "loguniform" else ""))
    overlap = (set(spec.grid) | set(spec.random)) & set(spec.train)
    barred = (set(spec.grid) | set(spec.random) | set(spec.train)) & NOT_SWEPT
    if overlap or barred:
        raise _fail(path, f"option(s) {', '.join(sorted(overlap | barred))}: an option is either "
                          "fixed ([train]) or searched ([grid], [random]), and out, resume and "
                          "ray belong to the sweep")


def _draws(spec: SweepSpec) -> list[dict[str, Any]]:
    """The random configurations (``samples`` draws with ``random_seed``; [{}] for a grid)."""
    if spec.search == "grid":
        return [{}]
    rng = np.random.default_rng(spec.random_seed)
    draws = []
    for _ in range(spec.samples):
        draw = {}
        for key, dist in sorted(spec.random.items()):
            kind, arg = next(iter(dist.items()))
            draw[key] = (arg[int(rng.integers(len(arg)))] if kind == "choice" else
                         int(rng.integers(arg[0], arg[1] + 1)) if kind == "randint" else
                         float(np.exp(rng.uniform(np.log(arg[0]), np.log(arg[1]))))
                         if kind == "loguniform" else float(rng.uniform(arg[0], arg[1])))
        draws.append(draw)
    return draws


def _argv(options: dict[str, Any]) -> list[str]:
    """``train`` arguments of options (``key = true`` is ``--key``, ``false`` ``--no-key``)."""
    argv = []
    for key, value in options.items():
        flag = "--" + key.replace("_", "-")
        if isinstance(value, bool):
            argv.append(flag if value else "--no-" + flag[2:])
        else:
            argv += [flag, str(value)]
    return argv


def _label(value: Any) -> str:
    return f"{value:.4g}" if isinstance(value, float) else str(value)


def plan_trials(spec: SweepSpec) -> list[Trial]:
    """Every trial of the spec: each random draw times each grid combination."""
    keys = list(spec.grid)
    trials = []
    for draw in _draws(spec):
        for combo in itertools.product(*(spec.grid[k] for k in keys)):
            values = {**dict(zip(keys, combo)), **draw}
            seed = int(values.get("seed", spec.train.get("seed", 0)))
            tag = "".join(f"_{k.replace('_', '-')}{_label(v)}" for k, v in values.items()
                          if k != "seed")
            config = spec.name + tag
            options = {k: v.replace("{seed}", str(seed)) if isinstance(v, str) else v
                       for k, v in {**spec.train, **values, "seed": seed}.items()}
            recipe = ["--config", str(spec.recipe)] if spec.recipe is not None else []
            trials.append(Trial(f"{config}_seed{seed}", config, seed, values,
                                recipe + _argv(options) + ["--out", str(spec.out / f"{config}_seed{seed}.pt")]))
    names = [t.name for t in trials]
    if len(set(names)) != len(names):
        raise _fail(spec.path, "two trials would write the same file (a repeated value?)")
    return trials


def check_trials(spec: SweepSpec, trials: list[Trial]) -> None:
    """Parse every trial's ``train`` arguments and check its options, the outputs, the network
    and the data (InputError naming the spec) before anything runs."""
    from carl_sumo.cli.policies import check_train_args, train_parser
    from carl_sumo.data import load_events
    from carl_sumo.sim.sumo import lane_route

    check_output_dir(spec.out, "out")
    check_output_dir(spec.results, "results")
    if spec.ship is not None:
        from carl_sumo.files import check_output_file

        check_output_file(spec.ship, "ship")
    loaded, nets = set(), set()
    for trial in trials:
        try:
            args = train_parser().parse_args(["train", *trial.argv])
            cfg, _ = check_train_args(args)
            if cfg.net not in nets:
                lane_route(cfg.net)
                nets.add(cfg.net)
            if (cfg.data, cfg.split) not in loaded:
                load_events(cfg.data, cfg.split)
                loaded.add((cfg.data, cfg.split))
        except InputError as exc:
            raise _fail(spec.path, f"trial {trial.name}: {exc}") from None


def run_trial(config: dict[str, Any]) -> None:
    """A Tune trial: one ``train`` run from the driver's folder, resumed from Tune's checkpoint
    when the trial restarts, each atomic checkpoint handed to Tune as it is written."""
    from ray import tune

    from carl_sumo.cli.policies import check_train_args, stability_check, train_parser
    from carl_sumo.data import load_events
    from carl_sumo.learn.train import train

    for name in ("ray.train", "ray.tune"):  # no line per checkpoint on the driver's console
        logging.getLogger(name).setLevel(logging.WARNING)
    config = config["trial"]
    if os.path.isdir(config["cwd"]):
        os.chdir(config["cwd"])
    args = train_parser().parse_args(["train", *config["argv"]])
    out = Path(args.out)
    resume, resumed_at = _restore(tune.get_checkpoint(), out)

    def report(step: int) -> None:
        with tempfile.TemporaryDirectory() as tmp:
            for suffix in (".ckpt", ".csv", ".pt"):
                if out.with_suffix(suffix).exists():
                    shutil.copy2(out.with_suffix(suffix), Path(tmp) / f"run{suffix}")
            tune.report({"step": step, "resumed_at": resumed_at},
                        checkpoint=tune.Checkpoint.from_directory(tmp))

    cfg, _ = check_train_args(args, "carl-sumo train " + " ".join(config["argv"]))
    result = train(cfg, load_events(cfg.data, cfg.split), resume=resume, progress=False,
                   log=lambda *_: None, on_checkpoint=report, stability_check=stability_check(cfg))
    if cfg.gate_string_stable is not None and not cfg.trust_string_stable:
        from carl_sumo.experiments.string_stability import keep_string_stable

        keep_string_stable(out, cfg.select, cfg.gate_string_stable)
    tune.report({"step": cfg.steps, "resumed_at": resumed_at, "done": 1,
                 "best_score": float(result["best_score"])})


def _restore(checkpoint, out: Path) -> tuple[Path | None, int]:
    """Put a Tune checkpoint's files back beside ``out`` (atomically): the checkpoint to resume
    from (None without one) and its step (-1)."""
    if checkpoint is None:
        return None, -1
    with checkpoint.as_directory() as folder:
        for suffix in (".ckpt", ".csv", ".pt"):
            saved = Path(folder) / f"run{suffix}"
            if saved.exists():
                with atomic_path(out.with_suffix(suffix)) as tmp:
                    shutil.copy2(saved, tmp)
    from carl_sumo.learn.policy import load_torch

    ckpt = out.with_suffix(".ckpt")
    return ckpt, int(load_torch(ckpt, "checkpoint")["step"])


def run_sweep(spec: SweepSpec, trials: list[Trial]) -> dict[str, dict[str, Any]]:
    """Run the trials with Ray Tune on the connected Ray runtime; per trial name its last
    reported metrics and, for a trial that failed for good, ``error``."""
    os.environ.setdefault("RAY_AIR_NEW_OUTPUT", "0")  # verbose=0: Tune prints nothing
    from ray import tune

    cwd = os.getcwd()
    configs = [{"name": t.name, "argv": t.argv, "cwd": cwd} for t in trials]
    tuner = tune.Tuner(
        tune.with_resources(run_trial, {"cpu": spec.cpus_per_trial}),
        param_space={"trial": tune.grid_search(configs)},
        tune_config=tune.TuneConfig(num_samples=1, trial_dirname_creator=_dirname),
        run_config=tune.RunConfig(
            name="tune", storage_path=str(spec.results.resolve()), verbose=0,
            failure_config=tune.FailureConfig(max_failures=spec.max_failures),
            checkpoint_config=tune.CheckpointConfig(num_to_keep=1)))
    outcome: dict[str, dict[str, Any]] = {}
    for result in tuner.fit():
        name = result.config["trial"]["name"]
        outcome[name] = dict(result.metrics or {})
        if result.error is not None:
            outcome[name]["error"] = str(result.error).strip().splitlines()[-1]
    return outcome


def _dirname(trial) -> str:
    return f"{trial.config['trial']['name']}_{trial.trial_id}"


def ship(best: Path, target: Path) -> None:
    """Copy the best run's policy file and curve to ``target`` (.pt) and its .csv, atomically
    ."""
    for suffix in (".pt", ".csv"):
        with atomic_path(target.with_suffix(suffix)) as tmp:
            shutil.copy2(best.with_suffix(suffix), tmp)
