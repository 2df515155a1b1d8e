"""The paper's experiment suite in SUMO: Tables 1-3 and a cross-site table, with figures.

``carl-sumo evaluate --suite paper --out results/`` runs every (model, table, platoon length,
seed) job on the shipped policies, in parallel worker processes (one libsumo each), and writes:

- per table a Markdown and a CSV file: every metric of :mod:`carl_sumo.metrics` as the aggregate of
  the shipped policy file (``policies/<stem>.pt``) with a 95 % percentile-bootstrap interval over events
  (:func:`carl_sumo.metrics.bootstrap_ci`), and, for models with several seeds
  (``policies/<stem>_seed<K>.pt``), the mean ± standard deviation across seeds of the per-seed
  aggregate;
- for Table 1, ``table1_ngsim_test_paired.csv`` (and a section of its Markdown): the paired
  comparisons of :data:`PAIRED_COMPARISONS`, each model minus its reference on the same events
  with a paired bootstrap interval (:func:`carl_sumo.metrics.paired_difference`) and how many of
  the model's seeds beat the reference on jerk, dampening and speed; where both have several seeds,
  the comparison across seeds too (:func:`carl_sumo.metrics.seed_comparison`: difference of the
  seed means, Welch's t, permutation p, and how many equally seeded pairs the model wins);
- per table with several seed files of a model, ``<table>_seeds.csv``: every seed's aggregate;
- ``per_event.csv`` (every job's per-event metrics, with the sample counts that weight the pooled
  means), ``timing.csv`` (wall and CPU seconds per
  job), the figures of :mod:`carl_sumo.figures` and ``README.md`` (all tables, figure links,
  command, machine, wall time, policy file hashes).

Jobs are split into chunks of events and the chunks of all jobs form one queue, longest first, so
that both cores stay busy to the end; Table 2's 10-follower rows reuse Table 1's runs.

Tables (``--quick``: the shipped default leader set, 2 events per table, 10 and 20 followers in
Table 2, a one-cycle stop-and-go leader, and the default set's train split standing in for US-101):

1. NGSIM test split, 10 followers: human, IDM, Krauss, the classical CACCs (SUMO's CACC, the
   textbook Ploeg curve over :data:`TEXTBOOK_GAPS` and the tuned Ploeg frontier of
   ``policies/ploeg_tuned.json``), MADDPG, DDPG, CA-DDPG, TD3, CA-TD3;
2. generalization: every model on 10, 20 and 50 followers (MADDPG on its own length only);
3. the stop-and-go leader, 10 followers;
4. cross-site: the US-101 sample (no model was trained on it), 10 followers.

By default only the shipped policy files run. ``seeds`` (``--seeds``) adds the seed files of
CA-TD3, CA-DDPG, TD3 and DDPG (:data:`SEED_MODELS`) in Table 1 and in Table 2 at 10 followers;
``all_seeds`` (``--all-seeds``) runs every model's seed files in every row.
"""

from __future__ import annotations

import csv
import io
import math
import os
import platform
import re
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from carl_sumo.config import SCENARIO
from carl_sumo.data import load_events
from carl_sumo.data.events import Event
from carl_sumo.data.synthetic import stop_and_go_event
from carl_sumo.errors import InputError
from carl_sumo.files import write_text_atomic
from carl_sumo.metrics import (BETTER, METRIC_KEYS, POOLED_WEIGHTS, acceleration_norms,
                               aggregate, bootstrap_ci, metric_samples, paired_difference,
                               score_event, seed_comparison)
from carl_sumo.sumo import REPO_ROOT, check_fits, lane_route

DEFAULT_NGSIM = Path("../shared/data/ngsim/ngsim_cf_events.csv.gz")
"""The NGSIM event table, relative to the directory carl-sumo runs in (the repository root)."""

SUITES = ("paper",)

METRIC_LABELS = {
    "headway_s": "headway (s)", "jerk_mps3": "jerk (m/s³)", "speed_mps": "speed (m/s)",
    "ttc_lt_4s_count": "TTC<4 s", "ttc_lt_1_5s_count": "TTC<1.5 s",
    "dampening_ratio": "dampening", "worst_successive_ratio": "worst successive",
    "collisions": "collisions",
}
SAMPLE_KEYS = ("headway_s", "speed_mps", "jerk_mps3")
N_BOOT = 2000


@dataclass(frozen=True)
class Model:
    """A row of the tables: a built-in controller or a policy stem with its seed files."""

    key: str                      # "idm", "human", or a policy stem such as "ca_td3_10"
    name: str                     # "IDM (SUMO)", "CA-TD3", ...
    files: tuple[str, ...] = ()   # policy files, the shipped file first
    seeds: tuple[int, ...] = ()   # their training seeds
    trained_on: int | None = None  # platoon length it was trained on
    fixed_length: int | None = None  # MADDPG: the only length it runs

    @property
    def controllers(self) -> tuple[str, ...]:
        """Controller names of its runs: the policy files, or the built-in name."""
        return self.files or (self.key,)

    def runs_on(self, n: int) -> bool:
        return self.fixed_length is None or self.fixed_length == n


BUILTIN_MODELS = {"human": "human (recorded)", "idm": "IDM (SUMO)", "krauss": "Krauss (SUMO)",
                  "sumo-cacc": "CACC (SUMO)"}
TEXTBOOK_GAPS = (0.6, 0.8, 1.0, 1.2, 1.5)
"""Time gaps h (s) of the textbook Ploeg curve (kp = 0.2, kd = 0.7) in every table."""


def is_classical(key: str) -> bool:
    """Whether a model key is a built-in (not learned) controller."""
    return key in BUILTIN_MODELS or key.startswith(("ploeg:", "ploeg-tuned:"))


ALGO_NAMES = {"ca-td3": "CA-TD3", "ca-ddpg": "CA-DDPG", "td3": "TD3", "ddpg": "DDPG",
              "maddpg": "MADDPG"}


@dataclass(frozen=True)
class EventSet:
    """Where a table's leaders come from."""

    key: str          # "ngsim_test", "stop_and_go", ...
    data: str         # an event table, "default" or "stop-and-go"
    split: str
    limit: int | None = None
    note: str = ""


@dataclass(frozen=True)
class TableSpec:
    key: str                       # file stem
    title: str
    events: EventSet
    followers: tuple[int, ...]
    models: tuple[str, ...]        # model keys, in row order
    figures: bool = False          # collect samples and trajectories for the figures
    seed_lengths: tuple[int, ...] | None = None  # lengths whose rows run the seed files too
    # (None: every length; the others run the shipped file only)
    seed_models: tuple[str, ...] | None = None  # models whose seed files run (None: every model)
    paired: tuple[tuple[str, str], ...] = ()  # (model, reference) pairs compared event by event


@dataclass
class Suite:
    """A planned suite: tables, models, the events of each event set, the figure events."""

    tables: list[TableSpec]
    models: dict[str, Model]
    events: dict[str, list[Event]]
    figure_events: dict[str, str]  # event-set key -> the event drawn in the time figures
    data: str
    quick: bool


@dataclass
class JobResult:
    """What one (event set, controller, platoon length) job produced, merged over its chunks."""

    per_event: list[dict] = field(default_factory=list)
    norms: list[np.ndarray] = field(default_factory=list)       # acceleration_norms per event
    samples: dict[str, list[np.ndarray]] = field(default_factory=dict)
    series: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)
    seconds: float = 0.0        # wall time its chunks took in the workers (s)
    cpu_seconds: float = 0.0    # CPU time of those chunks (s)


PAIRED_COMPARISONS = (("ca_td3_10", "idm"), ("ca_ddpg_10", "idm"), ("ca_td3_10", "td3_1"),
                      ("ca_ddpg_10", "ddpg_1"), ("td3_1", "idm"), ("ddpg_1", "idm"),
                      ("maddpg_10", "idm"), ("ca_td3_10", "ploeg:h=1.5"),
                      ("ca_ddpg_10", "ploeg:h=1.5"))
"""Table 1's paired comparisons: the quality bar's (CA models against IDM and against their
plain variants), the other learned models against IDM, and the CA models against the textbook
Ploeg CACC at h = 1.5 s, which follows at the same mean headway (1.75 s)."""
SEED_MODELS = tuple(dict.fromkeys(key for pair in PAIRED_COMPARISONS
                                  if not is_classical(pair[1]) for key in pair))
"""Models whose seed files ``--seeds`` runs: the policy pairs of :data:`PAIRED_COMPARISONS`,
which Table 1 compares across seeds (each CA model with its plain variant). ``--all-seeds`` runs every model's seed files in every row."""
PAIRED_KEYS = ("headway_s", "jerk_mps3", "speed_mps", "dampening_ratio")


# ------------------------------------------------------------------------------------ planning
def classical_models(tuned_file: Path | None = None) -> dict[str, str]:
    """Key (controller name) -> row name of the classical CACCs: SUMO's CACC, the textbook
    Ploeg curve and the tuned Ploeg frontier (every h with safe tuned gains)."""
    from carl_sumo.cacc import TUNED_FILE, read_tuned

    models = {"sumo-cacc": BUILTIN_MODELS["sumo-cacc"]}
    models.update({f"ploeg:h={h:g}": f"Ploeg h={h:g} s" for h in TEXTBOOK_GAPS})
    entries = read_tuned(tuned_file or TUNED_FILE)
    models.update({f"ploeg-tuned:h={h}": f"Ploeg tuned h={h} s"
                   for h, e in sorted(entries.items(), key=lambda kv: float(kv[0]))
                   if e.get("kp") is not None})
    return models



def default_data(quick: bool) -> str:
    """``--data`` when not given: the NGSIM table if it is where it belongs; ``default`` (quick)."""
    if quick:
        return "default"
    if DEFAULT_NGSIM.is_file():
        return str(DEFAULT_NGSIM)
    raise InputError(f"the NGSIM event table is not at {DEFAULT_NGSIM} (relative to {Path.cwd()});"
                     " pass --data PATH of ngsim_cf_events.csv.gz, or run --quick")


def policy_dir(path: Path | None) -> Path:
    """The directory of the shipped policies: ``path``, ``./policies`` or the repository's."""
    if path is not None:
        if not Path(path).is_dir():
            raise InputError(f"policy directory {path} does not exist; give --policies DIR with "
                             "the shipped policy files (ca_td3_10.pt, ...)")
        return Path(path)
    return Path("policies") if Path("policies").is_dir() else REPO_ROOT / "policies"


def discover_model(stem: str, directory: Path) -> Model:
    """A policy model: ``<stem>.pt`` (the shipped run) and every ``<stem>_seed<K>.pt`` beside it.

    Files whose training seed repeats one already found are left out (the same run twice).
    """
    from carl_sumo.policy import read_policy_payload

    shipped = directory / f"{stem}.pt"
    if not shipped.is_file():
        raise InputError(f"policy {shipped} does not exist; the paper suite needs the shipped "
                         "policies (restore them from git, or pass --policies DIR)")
    pattern = re.compile(rf"{re.escape(stem)}_seed(\d+)\.pt")
    extra = sorted((p for p in directory.glob(f"{stem}_seed*.pt") if pattern.fullmatch(p.name)),
                   key=lambda p: int(pattern.fullmatch(p.name).group(1)))
    files, seeds = [], []
    algo, trained, fixed = "", None, None
    for path in [shipped, *extra]:
        payload = read_policy_payload(path)  # the metadata only: no network is built here
        cfg, meta = payload["agent_config"], payload.get("metadata") or {}
        seed = meta.get("seed")
        if seed is None:
            seed = int(pattern.fullmatch(path.name).group(1)) if path != shipped else 0
        seed = int(seed)
        if seed in seeds:
            continue
        if not algo:
            algo = str(cfg["algo"])
            n_cfg = int(cfg.get("n_vehicles", 1))
            trained = int(meta.get("trained_vehicles", n_cfg))
            fixed = n_cfg if algo == "maddpg" else None
        elif cfg["algo"] != algo:
            raise InputError(f"policy {path} is {cfg['algo']}, but {shipped} is {algo}; a "
                             "seed file must be the same algorithm as its shipped policy")
        files.append(str(path))
        seeds.append(seed)
    return Model(stem, ALGO_NAMES.get(algo, algo), tuple(files), tuple(seeds), trained, fixed)


def _events(es: EventSet, quick: bool) -> list[Event]:
    if es.data == "stop-and-go":
        return [stop_and_go_event(cycles=1, cruise_s=5.0) if quick else stop_and_go_event()]
    return load_events(es.data, es.split, limit=es.limit)


def figure_event(events: Sequence[Event]) -> str:
    """The event drawn in the time figures: the largest leader speed range among events of at
    least 30 s (among all events if none is that long)."""
    long = [e for e in events if e.duration_s >= 30.0] or list(events)
    return max(long, key=lambda e: float(np.ptp(e.leader_speed_mps))).event_id


def plan_suite(suite: str = "paper", data: str | None = None, quick: bool = False,
               events: int | None = None, policies: Path | None = None,
               net: str | Path = "networks/i80.net.xml", all_seeds: bool = False,
               seeds: bool = False) -> Suite:
    """Resolve data, events, policies and tables; InputError on anything missing or wrong.

    ``seeds``: the seed files of :data:`SEED_MODELS` run in Table 1 and in Table 2 at 10 followers
    (those are Table 1's runs), not in Table 3 or the cross-site table; ``all_seeds`` runs every model's
    seed files in every row (slower); with neither, no seed file runs (the shipped policies
    alone)."""
    if all_seeds and seeds:
        raise InputError("--all-seeds and --seeds exclude each other; give one")
    if suite not in SUITES:
        raise InputError(f"unknown suite {suite!r}; choose one of {', '.join(SUITES)}")
    if events is not None and events < 1:
        raise InputError(f"--events must be at least 1, got {events}")
    data = str(data) if data is not None else default_data(quick)
    limit = events if events is not None else (2 if quick else None)
    directory = policy_dir(policies)

    test = EventSet("ngsim_test", data, "test", limit)
    if data == "default":
        cross = EventSet("cross_site", data, "train", limit,
                         note="the shipped default set has no US-101 events; its train split "
                              "stands in for the cross-site table")
    else:
        cross = EventSet("cross_site", data, "us101", limit)
    sg = EventSet("stop_and_go", "stop-and-go", "test", None,
                  note="one synthetic leader: 25 m/s, " + ("one braking (--quick)" if quick else
                                                           "three brakings") + " at -5 m/s² to 1 m/s")
    classical = classical_models()
    table1_models = ("human", "idm", "krauss", *classical, "maddpg_10", "ddpg_1", "ca_ddpg_10",
                     "td3_1", "ca_td3_10")
    seed_models = None if all_seeds else SEED_MODELS if seeds else ()
    table2_models = ("idm", "krauss", *classical, "maddpg_10", "maddpg_20", "ddpg_1", "td3_1",
                     "ca_ddpg_10", "ca_td3_10", "ca_ddpg_20", "ca_td3_20")
    tables = [
        TableSpec("table1_ngsim_test", "Table 1: NGSIM test split, 10 followers", test, (10,),
                  table1_models, figures=True, paired=PAIRED_COMPARISONS,
                  seed_models=seed_models),
        TableSpec("table2_generalization", "Table 2: generalization to other platoon lengths",
                  test, (10, 20) if quick else (10, 20, 50), table2_models,
                  seed_lengths=None if all_seeds else (10,), seed_models=seed_models),
        TableSpec("table3_stop_and_go", "Table 3: stop-and-go leader, 10 followers", sg, (10,),
                  table1_models[1:], figures=True, seed_lengths=None if all_seeds else ()),
        TableSpec("cross_site_us101", "Cross-site: US-101 (no model was trained on it), "
                  "10 followers", cross, (10,), table1_models,
                  seed_lengths=None if all_seeds else ()),
    ]
    models: dict[str, Model] = {}
    for spec in tables:
        for key in spec.models:
            if key not in models:
                models[key] = Model(key, {**BUILTIN_MODELS, **classical}[key]) \
                    if is_classical(key) else discover_model(key, directory)
    event_sets = {spec.events.key: spec.events for spec in tables}
    loaded = {key: _events(es, quick) for key, es in event_sets.items()}
    if not loaded["cross_site"]:
        raise InputError(f"{data} has no {cross.split} events for the cross-site table")
    route = lane_route(net)
    for spec in tables:  # a network too short fails here, before any worker starts
        for e in loaded[spec.events.key]:
            check_fits(route, e, max(spec.followers))
    figures = {spec.events.key: figure_event(loaded[spec.events.key]) for spec in tables
               if spec.figures}
    return Suite(tables, models, loaded, figures, data, quick)


# ----------------------------------------------------------------------------------- running
def _series(event: Event, traj) -> dict[str, np.ndarray]:
    """Time, front-bumper position, speed and acceleration of the leader (column 0) and the
    followers of one run (s, m, m/s, m/s²); positions from the leader's and the gaps."""
    T, n = traj.speed.shape
    speed = np.concatenate([traj.leader_speed[:T, None], traj.speed], axis=1)
    pos = np.empty((T, n + 1))
    pos[:, 0] = event.leader_pos_m[:T]
    length = event.leader_length_m
    for i in range(n):
        pos[:, i + 1] = pos[:, i] - length - traj.gap[:, i]
        length = SCENARIO.vehicle_length_m
    acc = np.diff(speed, axis=0) / traj.dt
    return {"t": (np.arange(T) * traj.dt).astype(np.float32), "pos": pos.astype(np.float32),
            "speed": speed.astype(np.float32), "acc": acc.astype(np.float32)}


def run_task(task: dict[str, Any]) -> dict[str, Any]:
    """Run one chunk of a job in this process (a worker): metrics, norms, samples, series."""
    from carl_sumo.simulate import event_trajectories

    start, cpu = time.perf_counter(), time.process_time()
    per_event, norms, series = [], [], {}
    samples: dict[str, list[np.ndarray]] = {k: [] for k in SAMPLE_KEYS}
    for event, traj in event_trajectories(task["controller"], task["events"], task["followers"],
                                          task["net"]):
        per_event.append(score_event(traj))
        norms.append(acceleration_norms(traj))
        if task["samples"]:
            for key, values in metric_samples(traj).items():
                samples[key].append(values.astype(np.float32))
        if event.event_id in task["series"]:
            series[event.event_id] = _series(event, traj)
    return {"job": task["job"], "index": task["index"], "per_event": per_event, "norms": norms,
            "samples": samples if task["samples"] else {}, "series": series,
            "seconds": time.perf_counter() - start, "cpu_seconds": time.process_time() - cpu}


def _cost(controller: str, n_steps: int, followers: int) -> float:
    """Rough CPU cost of a task, for scheduling the longest first."""
    if controller == "human":
        return 0.001 * n_steps
    per_vehicle = 0.15
    if controller.endswith(".pt"):
        per_vehicle = 0.6 if Path(controller).name.startswith("ca_") else 0.25
    return n_steps * (1.0 + per_vehicle * followers)


def _table_cells(spec: TableSpec, suite: Suite):
    """(model key, model, platoon length, followers simulated, controllers run) of every row of
    a table: the lengths a model can run (the recorded human follower is always one vehicle),
    with the seed files where ``spec.seed_lengths`` allows."""
    for key in spec.models:
        model = suite.models[key]
        for n in spec.followers:
            if model.runs_on(n):
                yield key, model, n, 1 if key == "human" else n, _controllers_run(spec, model, n)


def _controllers_run(spec: TableSpec, model: Model, n: int) -> tuple[str, ...]:
    """A model's controllers in a table at length n: all its seed files where
    ``spec.seed_lengths`` allows, the shipped one elsewhere."""
    spread = (spec.seed_lengths is None or n in spec.seed_lengths) and (
        spec.seed_models is None or model.key in spec.seed_models)
    return model.controllers if spread else model.controllers[:1]


def plan_tasks(suite: Suite, net: str) -> list[dict]:
    """The unique jobs (event set, controller, followers) of a suite, split into chunked tasks,
    longest first."""
    jobs: dict[tuple, dict] = {}
    for spec in suite.tables:
        for _, _, _, n_run, controllers in _table_cells(spec, suite):
            for i, controller in enumerate(controllers):
                job = (spec.events.key, controller, n_run)
                flags = jobs.setdefault(job, {"samples": False, "series": False})
                if spec.figures and i == 0:
                    flags["samples"] = flags["series"] = True
    tasks = []
    for job, flags in jobs.items():
        set_key, controller, n = job
        events = suite.events[set_key]
        chunk = len(events) if controller == "human" else max(1, 400 // max(n, 10))
        wanted = {suite.figure_events[set_key]} if flags["series"] else set()
        for index, start in enumerate(range(0, len(events), chunk)):
            part = events[start:start + chunk]
            tasks.append({"job": job, "index": index, "controller": controller, "followers": n,
                          "events": part, "net": net, "samples": flags["samples"],
                          "series": wanted & {e.event_id for e in part},
                          "cost": _cost(controller, sum(e.n_samples for e in part), n)})
    tasks.sort(key=lambda t: -t["cost"])
    return tasks


def run_tasks(tasks: list[dict], pool=None, progress: bool = False) -> dict[tuple, JobResult]:
    """Run tasks (longest first) in a worker pool, or in this process; results merged per job."""
    parts: dict[tuple, list[dict]] = {}
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=len(tasks), desc="evaluate", unit="task", leave=False)
    if pool is None:
        from carl_sumo.simulate import _worker_init

        _worker_init()  # one torch thread: several fight over the cores for these small networks
        outputs = map(run_task, tasks)
    else:
        outputs = pool.imap_unordered(run_task, tasks)
    try:
        for out in outputs:
            parts.setdefault(out["job"], []).append(out)
            if bar is not None:
                bar.update()
    finally:
        if bar is not None:
            bar.close()
    results: dict[tuple, JobResult] = {}
    for job, outs in parts.items():
        res = JobResult(samples={k: [] for k in SAMPLE_KEYS})
        for out in sorted(outs, key=lambda o: o["index"]):
            res.per_event += out["per_event"]
            res.norms += out["norms"]
            for key, values in out["samples"].items():
                res.samples[key] += values
            res.series.update(out["series"])
            res.seconds += out["seconds"]
            res.cpu_seconds += out["cpu_seconds"]
        results[job] = res
    return results


# ------------------------------------------------------------------------------------- tables
def table_rows(spec: TableSpec, suite: Suite, results: dict[tuple, JobResult]) -> list[dict]:
    """One row per (model, platoon length): shipped file's aggregate, bootstrap CI, spread over
    seeds."""
    rows = []
    for key, model, _, n_run, controllers in _table_cells(spec, suite):
        runs = [results[(spec.events.key, c, n_run)] for c in controllers]
        main = runs[0].per_event
        agg = aggregate(main)
        ci = bootstrap_ci(main, n_boot=N_BOOT)
        per_seed = [aggregate(r.per_event) for r in runs]
        row: dict[str, Any] = {
            "table": spec.key, "model": model.name, "policy": Path(model.files[0]).stem
            if model.files else model.key, "trained_on": model.trained_on or "",
            "followers": n_run, "events": len(main),
            "seeds": len(controllers) if model.files else ""}
        for m in METRIC_KEYS:
            values = np.array([s[m] for s in per_seed], float)
            row[m] = agg[m]
            row[f"{m}_lo"], row[f"{m}_hi"] = ci[m]
            row[f"{m}_seed_mean"] = float(np.mean(values)) if model.files else math.nan
            row[f"{m}_seed_std"] = float(np.std(values, ddof=1)) if len(values) > 1 \
                else math.nan
        rows.append(row)
    return rows


def paired_rows(spec: TableSpec, suite: Suite, results: dict[tuple, JobResult]) -> list[dict]:
    """One row per (model, reference) pair of ``spec.paired`` and platoon length: the shipped
    files' difference of each of :data:`PAIRED_KEYS` with its paired bootstrap interval, and how many
    of the model's seeds are better than the reference (lower jerk and dampening, higher
    speed)."""
    rows = []
    for key, ref in spec.paired:
        model, reference = suite.models[key], suite.models[ref]
        for n in spec.followers:
            if not (model.runs_on(n) and reference.runs_on(n)):
                continue
            runs = [results[(spec.events.key, c, n)].per_event
                    for c in _controllers_run(spec, model, n)]
            ref_runs = [results[(spec.events.key, c, n)].per_event
                        for c in _controllers_run(spec, reference, n)]
            base = ref_runs[0]
            diff = paired_difference(runs[0], base, PAIRED_KEYS, n_boot=N_BOOT)
            base_agg, seed_aggs = aggregate(base), [aggregate(r) for r in runs]
            ref_aggs = [aggregate(r) for r in ref_runs]
            row: dict[str, Any] = {"table": spec.key, "model": model.name, "reference":
                                   reference.name, "followers": n, "events": len(base),
                                   "seeds": len(runs), "reference_seeds": len(ref_runs)}
            ref_by_seed = dict(zip(reference.seeds, ref_aggs))
            matched = [(agg, ref_by_seed[s]) for s, agg in zip(model.seeds, seed_aggs)
                       if s in ref_by_seed]
            row["matched_seeds"] = len(matched)
            for m in PAIRED_KEYS:
                row[f"d_{m}"], row[f"d_{m}_lo"], row[f"d_{m}_hi"] = diff[m]
                if m in BETTER:
                    row[f"{m}_seeds_better"] = sum(
                        BETTER[m] * (agg[m] - base_agg[m]) > 0 for agg in seed_aggs)
                    row[f"seed_d_{m}"], row[f"seed_t_{m}"], row[f"seed_p_{m}"] = \
                        seed_comparison([a[m] for a in seed_aggs], [a[m] for a in ref_aggs])
                    row[f"{m}_matched_better"] = sum(
                        BETTER[m] * (a[m] - r[m]) > 0 for a, r in matched)
            rows.append(row)
    return rows


def seed_rows(spec: TableSpec, suite: Suite, results: dict[tuple, JobResult]) -> list[dict]:
    """One row per (model with several seed files, platoon length, seed): that seed's aggregate
    of every metric (the runs behind the "spread across seeds" rows)."""
    rows = []
    for _, model, _, n_run, controllers in _table_cells(spec, suite):
        if len(controllers) < 2:
            continue
        for i, (path, seed) in enumerate(zip(controllers, model.seeds)):
            per_event = results[(spec.events.key, path, n_run)].per_event
            rows.append({"table": spec.key, "model": model.name, "policy": Path(path).stem,
                         "seed": seed, "shipped": i == 0, "followers": n_run,
                         "events": len(per_event), **aggregate(per_event)})
    return rows


SEED_COLUMNS = ["table", "model", "policy", "seed", "shipped", "followers", "events",
                *METRIC_KEYS]


PAIRED_COLUMNS = ["table", "model", "reference", "followers", "events", "seeds",
                  "reference_seeds", "matched_seeds"] + [
    f"d_{m}{suffix}" for m in PAIRED_KEYS for suffix in ("", "_lo", "_hi")] + [
    f"{m}_seeds_better" for m in BETTER] + [
    f"seed_{s}_{m}" for m in BETTER for s in ("d", "t", "p")] + [
    f"{m}_matched_better" for m in BETTER]


def paired_markdown(rows: list[dict]) -> str:
    """The paired comparisons as Markdown, under a table's own section."""
    labels = [f"Δ {METRIC_LABELS[m]}" for m in PAIRED_KEYS]
    lines = ["Paired comparisons (model − reference on the same events, shipped files; "
             f"[95 % paired bootstrap interval, {N_BOOT} resamples of the events]; seeds better: "
             "how many of the model's seeds beat the reference on jerk / dampening / speed):", "",
             "| model | reference | " + " | ".join(labels) + " | seeds better |",
             "|" + "---|" * (3 + len(labels))]
    for r in rows:
        cells = [f"{r[f'd_{m}']:+.3f} [{r[f'd_{m}_lo']:+.3f}, {r[f'd_{m}_hi']:+.3f}]"
                 for m in PAIRED_KEYS]
        better = " / ".join(f"{r[f'{m}_seeds_better']}" for m in
                            ("jerk_mps3", "dampening_ratio", "speed_mps"))
        lines.append(f"| {r['model']} | {r['reference']} | " + " | ".join(cells)
                     + f" | {better} of {r['seeds']} |")
    across = [r for r in rows if r["seeds"] > 1 and r["reference_seeds"] > 1]
    if across:
        order = ("jerk_mps3", "dampening_ratio", "speed_mps")
        lines += ["", "Across seeds (every seed file of both models on the same events: difference "
                  "of the seed means, Welch's t, two-sided permutation p over the seed labels; "
                  "matched: seeds trained with the same seed number where the model is better):",
                  "", "| model | reference | seeds | " + " | ".join(
                      f"{METRIC_LABELS[m]}: Δ mean, t, p" for m in order) + " | matched better |",
                  "|" + "---|" * (4 + len(order))]
        for r in across:
            cells = [f"{r[f'seed_d_{m}']:+.3f}, {r[f'seed_t_{m}']:+.1f}, {r[f'seed_p_{m}']:.3f}"
                     for m in order]
            matched = " / ".join(str(r[f"{m}_matched_better"]) for m in order)
            lines.append(f"| {r['model']} | {r['reference']} | {r['seeds']} vs "
                         f"{r['reference_seeds']} | " + " | ".join(cells)
                         + f" | {matched} of {r['matched_seeds']} |")
    return "\n".join(lines) + "\n"


CSV_COLUMNS = ["table", "model", "policy", "trained_on", "followers", "events", "seeds"] + [
    f"{m}{suffix}" for m in METRIC_KEYS for suffix in ("", "_lo", "_hi", "_seed_mean",
                                                       "_seed_std")]


def _num(value: float, count: bool) -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return "nan"
    return f"{value:.0f}" if count else f"{value:.3f}"


def _cell(row: dict, m: str) -> str:
    count = m.endswith("_count") or m == "collisions"
    value, lo, hi = row[m], row[f"{m}_lo"], row[f"{m}_hi"]
    if math.isnan(lo):
        return _num(value, count)
    return f"{_num(value, count)} [{_num(lo, count)}, {_num(hi, count)}]"


def markdown_table(spec: TableSpec, rows: list[dict], note: str = "") -> str:
    """A table as Markdown: the cells, then the spread across seeds where a model has several."""
    header = ["model", "policy", "trained on", "followers", "events", "seeds",
              *(METRIC_LABELS[m] for m in METRIC_KEYS)]
    lines = [f"### {spec.title}", ""]
    if note:
        lines += [f"Leaders: {note}.", ""]
    lines += ["| " + " | ".join(header) + " |", "|" + "---|" * len(header)]
    for r in rows:
        seeds = f"n={r['seeds']}" if r["seeds"] != "" else "—"
        lines.append("| " + " | ".join([r["model"], f"`{r['policy']}`", str(r["trained_on"]) or "—",
                                        str(r["followers"]), str(r["events"]), seeds,
                                        *(_cell(r, m) for m in METRIC_KEYS)]) + " |")
    lines += ["", "Cells: the shipped policy's value over all events [95 % bootstrap "
              f"interval over events, {N_BOOT} resamples]; no interval with a single event."]
    multi = [r for r in rows if r["seeds"] != "" and r["seeds"] > 1]
    if multi:
        lines += ["", "Spread across seeds (mean ± standard deviation of the per-seed value, "
                  "n seeds):", "",
                  "| model | policy | followers | seeds | "
                  + " | ".join(METRIC_LABELS[m] for m in METRIC_KEYS) + " |",
                  "|" + "---|" * (4 + len(METRIC_KEYS))]
        for r in rows:
            if r["seeds"] == "":
                continue
            cells = [f"{r[f'{m}_seed_mean']:.3f} ± {r[f'{m}_seed_std']:.3f}" if r["seeds"] > 1
                     else "—" for m in METRIC_KEYS]
            lines.append(f"| {r['model']} | `{r['policy']}` | {r['followers']} | "
                         f"n={r['seeds']} | " + " | ".join(cells) + " |")
    else:
        lines += ["", "Every learned model has one seed (n=1), so there is no spread across seeds."]
    return "\n".join(lines) + "\n"


def csv_text(rows: list[dict], columns: list[str]) -> str:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=columns, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})
    return buffer.getvalue()


WEIGHT_KEYS = tuple(dict.fromkeys(POOLED_WEIGHTS.values()))  # samples behind pooled means


def per_event_rows(suite: Suite, results: dict[tuple, JobResult]) -> list[dict]:
    """Every job's per-event metrics, with the sample counts that weight the pooled means (so
    :func:`carl_sumo.metrics.aggregate` of a subset of rows gives that subset's aggregate)."""
    seed_of = {c: (m.key, s) for m in suite.models.values() for c, s in zip(m.files, m.seeds)}
    rows = []
    for (set_key, controller, n), res in results.items():
        model, seed = seed_of.get(controller, (controller, ""))
        for e in res.per_event:
            rows.append({"event_set": set_key, "model": model, "seed": seed, "followers": n,
                         **{k: e[k] for k in ("event_id", *METRIC_KEYS, *WEIGHT_KEYS)}})
    return rows


def machine() -> str:
    """A one-line description of this machine (cores, processor, OS, Python)."""
    cpu = platform.processor() or platform.machine()
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return (f"{os.cpu_count()} cores ({cpu}), {platform.system()} {platform.release()}, "
            f"Python {platform.python_version()}")


def run_suite(suite: Suite, out_dir: Path, workers: int = 2, net: str | Path =
              "networks/i80.net.xml", progress: bool = False, command: str = "") -> dict:
    """Run a planned suite and write its tables, figures and README into ``out_dir``."""
    from carl_sumo import figures
    from carl_sumo.simulate import worker_pool

    start = time.perf_counter()
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"--out {out_dir} is a file; give a directory")
    tasks = plan_tasks(suite, str(net))
    pool = worker_pool(workers) if workers > 1 else None
    try:
        results = run_tasks(tasks, pool, progress)
        simulated = time.perf_counter() - start
        out_dir.mkdir(parents=True, exist_ok=True)
        jobs = figures.figure_jobs(suite, results, out_dir)
        drawing = pool.map_async(figures.render, jobs) if pool is not None else None
        all_rows, sections = _write_tables(suite, results, out_dir)  # while the figures draw
        figure_files = drawing.get() if drawing is not None else [figures.render(j) for j in jobs]
    finally:
        if pool is not None:
            pool.terminate()
            pool.join()
    wall = time.perf_counter() - start
    cpu = sum(r.cpu_seconds for r in results.values())
    readme = suite_readme(suite, sections, figure_files, wall, simulated, cpu, workers,
                          len(tasks), command)
    write_text_atomic(out_dir / "README.md", readme)
    return {"rows": all_rows, "wall_time_s": wall, "simulation_s": simulated,
            "worker_cpu_s": cpu, "tasks": len(tasks), "figures": figure_files}


def _write_tables(suite: Suite, results: dict[tuple, JobResult],
                  out_dir: Path) -> tuple[dict[str, list[dict]], list[str]]:
    """Every table (.md, .csv) and per_event.csv; the rows and Markdown sections."""
    all_rows, sections = {}, []
    for spec in suite.tables:
        rows = table_rows(spec, suite, results)
        all_rows[spec.key] = rows
        md = markdown_table(spec, rows, spec.events.note)
        links = f"CSV: [`{spec.key}.csv`]({spec.key}.csv)"
        if spec.paired:
            pairs = paired_rows(spec, suite, results)
            md += "\n" + paired_markdown(pairs)
            write_text_atomic(out_dir / f"{spec.key}_paired.csv", csv_text(pairs, PAIRED_COLUMNS))
            links += f", [`{spec.key}_paired.csv`]({spec.key}_paired.csv)"
        seeds = seed_rows(spec, suite, results)
        if seeds:
            write_text_atomic(out_dir / f"{spec.key}_seeds.csv", csv_text(seeds, SEED_COLUMNS))
            links += f", [`{spec.key}_seeds.csv`]({spec.key}_seeds.csv) (every seed)"
        write_text_atomic(out_dir / f"{spec.key}.md", md)
        write_text_atomic(out_dir / f"{spec.key}.csv", csv_text(rows, CSV_COLUMNS))
        sections.append(md + f"\n{links}\n")
    timing = [{"event_set": k[0], "controller": k[1], "followers": k[2],
               "events": len(r.per_event), "seconds": round(r.seconds, 2),
               "cpu_seconds": round(r.cpu_seconds, 2)}
              for k, r in sorted(results.items(), key=lambda kv: -kv[1].seconds)]
    write_text_atomic(out_dir / "timing.csv", csv_text(timing, list(timing[0])))
    per_event = per_event_rows(suite, results)
    write_text_atomic(out_dir / "per_event.csv",
                      csv_text(per_event, ["event_set", "model", "seed", "followers", "event_id",
                                           *METRIC_KEYS, *WEIGHT_KEYS]))
    return all_rows, sections


def _sha(path: str) -> str:
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:12]


def _load() -> str:
    """The 1, 5 and 15 min load averages (other processes on the machine slow the suite)."""
    try:
        return ", ".join(f"{x:.1f}" for x in os.getloadavg())
    except OSError:
        return "unknown"


def suite_readme(suite: Suite, sections: list[str], figure_files: list[tuple[str, str]],
                 wall: float, simulated: float, cpu: float, workers: int, n_tasks: int,
                 command: str) -> str:
    n_events = {k: len(v) for k, v in suite.events.items()}
    lines = ["# carl-sumo evaluate: the paper suite" + (" (--quick)" if suite.quick else ""), "",
             f"- command: `{command}`" if command else "- command: (Python API)",
             f"- data: `{suite.data}`; events per table: "
             + ", ".join(f"{k} {v}" for k, v in n_events.items()),
             f"- machine: {machine()}",
             f"- wall time: {wall:.0f} s ({simulated:.0f} s simulating {n_tasks} tasks in "
             f"{workers} worker process(es), the rest tables, bootstrap and figures; the "
             f"simulations took {cpu:.0f} s of CPU time; per job: `timing.csv`)",
             f"- load average when it ended: {_load()}",
             "- metric definitions: `docs/metrics.md` of carl-sumo; the human row is the "
             "recorded NGSIM follower alone (1 follower)",
             "- policy files (sha256, first 12 hex digits): " + ", ".join(
                 f"`{Path(f).name}` {_sha(f)}" for m in suite.models.values() for f in m.files),
             "- figure event (time series, time-space): "
             + ", ".join(f"{k}: `{v}`" for k, v in suite.figure_events.items()), ""]
    for text in sections:
        lines += [text, ""]
    lines += ["## Figures", ""]
    for name, caption in figure_files:
        lines += [f"**{caption}** (`{name}`)", "", f"![{caption}]({name})", ""]
    return "\n".join(lines)


def evaluate(suite: str = "paper", out: Path = Path("results"), data: str | None = None,
             quick: bool = False, events: int | None = None, policies: Path | None = None,
             net: str | Path = "networks/i80.net.xml", workers: int = 2,
             progress: bool = False, command: str = "", all_seeds: bool = False,
             seeds: bool = False) -> dict:
    """Plan and run a suite (see the module docstring); the table rows and timings."""
    planned = plan_suite(suite, data, quick, events, policies, net, all_seeds, seeds)
    return run_suite(planned, Path(out), workers, net, progress, command)


