"""The statistics of the suite's tables, from the runs of :mod:`carl_sumo.experiments.evaluate`.

- :func:`table_rows`: per (model, platoon length) every metric of :mod:`carl_sumo.sim.metrics` as the
  aggregate of the shipped policy file with a 95 % percentile-bootstrap interval over events
  (:func:`carl_sumo.sim.metrics.bootstrap_ci`) and, for models with several seed files, the mean ±
  standard deviation across seeds of the per-seed aggregate;
- :func:`paired_rows`: the paired comparisons of a table (for Table 1,
  :data:`carl_sumo.experiments.suite.PAIRED_COMPARISONS`), each model minus its reference on the same events
  with a paired bootstrap interval (:func:`carl_sumo.sim.metrics.paired_difference`) and how many of
  the model's seeds beat the reference on jerk, dampening and speed; where both have several
  seeds, the comparison across seeds too (:func:`carl_sumo.sim.metrics.seed_comparison`: difference of
  the seed means, Welch's t, permutation p, and how many equally seeded pairs the model wins);
- :func:`seed_rows`: every seed's aggregate; :func:`per_event_rows`: every job's per-event metrics.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from carl_sumo.sim.metrics import (BETTER, METRIC_KEYS, POOLED_WEIGHTS, aggregate, bootstrap_ci,
                               paired_difference, seed_comparison)
from carl_sumo.experiments.suite import JobResult, Suite, TableSpec, controllers_run, table_cells


N_BOOT = 2000
PAIRED_KEYS = ("headway_s", "jerk_mps3", "speed_mps", "dampening_ratio")


def table_rows(spec: TableSpec, suite: Suite, results: dict[tuple, JobResult]) -> list[dict]:
    """One row per (model, platoon length): shipped file's aggregate, bootstrap CI, spread over
    seeds."""
    rows = []
    for key, model, _, n_run, controllers in table_cells(spec, suite):
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
                    for c in controllers_run(spec, model, n)]
            ref_runs = [results[(spec.events.key, c, n)].per_event
                        for c in controllers_run(spec, reference, n)]
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
    for _, model, _, n_run, controllers in table_cells(spec, suite):
        if len(controllers) < 2:
            continue
        for i, (path, seed) in enumerate(zip(controllers, model.seeds)):
            per_event = results[(spec.events.key, path, n_run)].per_event
            rows.append({"table": spec.key, "model": model.name, "policy": Path(path).stem,
                         "seed": seed, "shipped": i == 0, "followers": n_run,
                         "events": len(per_event), **aggregate(per_event)})
    return rows


CSV_COLUMNS = ["table", "model", "policy", "trained_on", "followers", "events", "seeds"] + [
    f"{m}{suffix}" for m in METRIC_KEYS for suffix in ("", "_lo", "_hi", "_seed_mean",
                                                       "_seed_std")]


SEED_COLUMNS = ["table", "model", "policy", "seed", "shipped", "followers", "events",
                *METRIC_KEYS]


PAIRED_COLUMNS = ["table", "model", "reference", "followers", "events", "seeds",
                  "reference_seeds", "matched_seeds"] + [
    f"d_{m}{suffix}" for m in PAIRED_KEYS for suffix in ("", "_lo", "_hi")] + [
    f"{m}_seeds_better" for m in BETTER] + [
    f"seed_{s}_{m}" for m in BETTER for s in ("d", "t", "p")] + [
    f"{m}_matched_better" for m in BETTER]


WEIGHT_KEYS = tuple(dict.fromkeys(POOLED_WEIGHTS.values()))  # samples behind pooled means


def per_event_rows(suite: Suite, results: dict[tuple, JobResult]) -> list[dict]:
    """Every job's per-event metrics, with the sample counts that weight the pooled means (so
    :func:`carl_sumo.sim.metrics.aggregate` of a subset of rows gives that subset's aggregate)."""
    seed_of = {c: (m.key, s) for m in suite.models.values() for c, s in zip(m.files, m.seeds)}
    rows = []
    for (set_key, controller, n), res in results.items():
        model, seed = seed_of.get(controller, (controller, ""))
        for e in res.per_event:
            rows.append({"event_set": set_key, "model": model, "seed": seed, "followers": n,
                         **{k: e[k] for k in ("event_id", *METRIC_KEYS, *WEIGHT_KEYS)}})
    return rows
