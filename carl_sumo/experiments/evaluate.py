"""The paper's experiment suite in SUMO: Tables 1-3 and a cross-site table, with figures.

``carl-sumo evaluate --suite paper --out results/`` runs every (model, table, platoon length,
seed) job on the shipped policies, in parallel worker processes (one libsumo each), and writes:

- per table a Markdown and a CSV file: every metric of :mod:`carl_sumo.sim.metrics` as the aggregate of
  the shipped policy file (``policies/<stem>.pt``) with a 95 % percentile-bootstrap interval over events
  (:func:`carl_sumo.sim.metrics.bootstrap_ci`), and, for models with several seeds
  (``policies/<stem>_seed<K>.pt``), the mean ± standard deviation across seeds of the per-seed
  aggregate;
- for Table 1, ``table1_ngsim_test_paired.csv`` (and a section of its Markdown): the paired
  comparisons of :data:`carl_sumo.experiments.suite.PAIRED_COMPARISONS`, each model minus its reference on the
  same events with a paired bootstrap interval (:func:`carl_sumo.sim.metrics.paired_difference`) and
  how many of the model's seeds beat the reference on jerk, dampening and speed; where both have
  several seeds, the comparison across seeds too (:func:`carl_sumo.sim.metrics.seed_comparison`:
  difference of the seed means, Welch's t, permutation p, and how many equally seeded pairs the
  model wins);
- per table with several seed files of a model, ``<table>_seeds.csv``: every seed's aggregate;
- ``per_event.csv`` (every job's per-event metrics, with the sample counts that weight the pooled
  means), ``timing.csv`` (wall and CPU seconds per
  job), the figures of :mod:`carl_sumo.experiments.figures` and ``README.md`` (all tables, figure links,
  command, machine, wall time, policy file hashes).

Jobs are split into chunks of events and the chunks of all jobs form one queue, longest first, so
that both cores stay busy to the end; Table 2's 10-follower rows reuse Table 1's runs.

The suite is split along its seams: :mod:`carl_sumo.experiments.suite` defines it (tables, models, events:
:func:`~carl_sumo.experiments.suite.plan_suite`) and its result types, this module runs it,
:mod:`carl_sumo.experiments.suite_stats` computes the tables' statistics, :mod:`carl_sumo.experiments.suite_report` writes
them and :mod:`carl_sumo.experiments.figures` draws the figures.
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from carl_sumo.control.channel import Impairments
from carl_sumo.config import SCENARIO
from carl_sumo.data.events import Event
from carl_sumo.errors import InputError
from carl_sumo.files import write_text_atomic
from carl_sumo.progress import Tracker
from carl_sumo.sim.metrics import acceleration_norms, metric_samples, score_event
from carl_sumo.experiments.suite import SAMPLE_KEYS, JobResult, Suite, plan_suite, table_cells
from carl_sumo.experiments.suite_report import suite_readme, write_tables


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
    from carl_sumo.experiments.simulate import event_trajectories

    start, cpu = time.perf_counter(), time.process_time()
    per_event, norms, series = [], [], {}
    samples: dict[str, list[np.ndarray]] = {k: [] for k in SAMPLE_KEYS}
    for event, traj in event_trajectories(task["controller"], task["events"], task["followers"],
                                          task["net"], impairments=task.get("impairments")):
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


def plan_tasks(suite: Suite, net: str) -> list[dict]:
    """The unique jobs (event set, controller, followers) of a suite, split into chunked tasks,
    longest first."""
    jobs: dict[tuple, dict] = {}
    for spec in suite.tables:
        for _, _, _, n_run, controllers in table_cells(spec, suite):
            for i, controller in enumerate(controllers):
                job = (spec.events.key, controller, n_run)
                flags = jobs.setdefault(job, {"samples": False, "series": False})
                if spec.figures and i == 0:
                    flags["samples"] = flags["series"] = True
    from carl_sumo.experiments.simulate import impairable

    tasks = []
    for job, flags in jobs.items():
        set_key, controller, n = job
        impairments = suite.impairments if suite.impairments is not None and \
            impairable(controller) else None
        events = suite.events[set_key]
        chunk = len(events) if controller == "human" else max(1, 400 // max(n, 10))
        wanted = {suite.figure_events[set_key]} if flags["series"] else set()
        for index, start in enumerate(range(0, len(events), chunk)):
            part = events[start:start + chunk]
            tasks.append({"job": job, "index": index, "controller": controller, "followers": n,
                          "events": part, "net": net, "samples": flags["samples"],
                          "series": wanted & {e.event_id for e in part},
                          "impairments": impairments,
                          "cost": _cost(controller, sum(e.n_samples for e in part), n)})
    tasks.sort(key=lambda t: -t["cost"])
    return tasks


def run_tasks(tasks: list[dict], workers: int | None = None, progress: bool = False
              ) -> dict[tuple, JobResult]:
    """Run tasks (longest first) in ``workers`` spawned processes (None: in this process);
    results merged per job, in the order of the plan (so the outputs do not depend on which
    task finished first)."""
    parts: dict[tuple, list[dict]] = {}
    bar = Tracker(len(tasks), "evaluate", "task", progress)
    if workers is None:
        from carl_sumo.scale.workers import worker_init

        worker_init()  # one torch thread: several fight over the cores for these small networks
        outputs = map(run_task, tasks)
    else:
        from carl_sumo.scale.workers import run_parallel

        outputs = run_parallel(run_task, [(t,) for t in tasks], workers, ordered=False,
                               describe=lambda a: f"task {a[0]['job']} (events chunk "
                                                  f"{a[0]['index']})")
    try:
        for out in outputs:
            parts.setdefault(out["job"], []).append(out)
            bar.update()
    finally:
        bar.close()
    results: dict[tuple, JobResult] = {}
    for job in dict.fromkeys(t["job"] for t in tasks):  # the plan's order, not the finishing one
        outs = parts[job]
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


def run_suite(suite: Suite, out_dir: Path, workers: int = 2, net: str | Path =
              "networks/i80.net.xml", progress: bool = False, command: str = "") -> dict:
    """Run a planned suite and write its tables, figures and README into ``out_dir``."""
    from carl_sumo.experiments import figures

    start = time.perf_counter()
    out_dir = Path(out_dir)
    if out_dir.exists() and not out_dir.is_dir():
        raise InputError(f"--out {out_dir} is a file; give a directory")
    tasks = plan_tasks(suite, str(net))
    parallel = workers if workers > 1 else None
    results = run_tasks(tasks, parallel, progress)
    simulated = time.perf_counter() - start
    out_dir.mkdir(parents=True, exist_ok=True)
    jobs = figures.figure_jobs(suite, results, out_dir)
    all_rows, sections = write_tables(suite, results, out_dir)
    if suite.name == "real" and suite.string_stability:
        from carl_sumo.experiments.string_stability import suite_table

        sections.append(suite_table(suite, out_dir, str(net), workers))
    if parallel is not None:
        from carl_sumo.scale.workers import run_parallel

        figure_files = list(run_parallel(figures.render, [(j,) for j in jobs], parallel,
                                         describe=lambda a: "a figure"))
    else:
        figure_files = [figures.render(j) for j in jobs]
    wall = time.perf_counter() - start
    cpu = sum(r.cpu_seconds for r in results.values())
    readme = suite_readme(suite, sections, figure_files, wall, simulated, cpu, workers,
                          len(tasks), command)
    write_text_atomic(out_dir / "README.md", readme)
    return {"rows": all_rows, "wall_time_s": wall, "simulation_s": simulated,
            "worker_cpu_s": cpu, "tasks": len(tasks), "figures": figure_files}


def evaluate(suite: str = "paper", out: Path = Path("results"), data: str | None = None,
             quick: bool = False, events: int | None = None, policies: Path | None = None,
             net: str | Path = "networks/i80.net.xml", workers: int = 2,
             progress: bool = False, command: str = "", all_seeds: bool = False,
             seeds: bool = False, impairments: Impairments | None = None,
             warmup_s: float = 0.0, extra: tuple[str, ...] = (),
             only: tuple[str, ...] | None = None) -> dict:
    """Plan and run a suite (see the module docstring); the table rows and timings. With
    ``impairments`` every controller that runs in carl-sumo (Ploeg, idm-external, the policies)
    has them; SUMO's native models and the recorded human run as they are. ``warmup_s``: every
    event runs that long first, unscored. ``extra``: controllers of the user's own
    (``module:attribute``, ``file.py:attribute``), one more row in every table. ``only``: the
    parts of the suite to run (:data:`carl_sumo.experiments.suite.TABLES`; None: all)."""
    plant = impairments.plant_key if impairments is not None else "ideal"
    planned = plan_suite(suite, data, quick, events, policies, net, all_seeds, seeds, warmup_s,
                         plant, extra, only)
    planned = replace(planned, impairments=impairments)
    return run_suite(planned, Path(out), workers, net, progress, command)
