"""The tables of ``carl-sumo sweep``: per trial, per configuration, and the best configuration.

- ``trials.csv``: every trial's kept checkpoint (the policy file its ``train`` run wrote) with its
  validation metrics, the selection score of the spec's ``--select`` rule, safety, the run's
  training wall time (its curve's last ``wall_s``),
  whether it resumed from a checkpoint after its worker died, and its status;
- ``configs.csv``: per configuration (the searched options but the seed) the mean ± standard
  deviation over its seeds of the score and the validation metrics, and the comparison across
  seeds with the best configuration (:func:`carl_sumo.sim.metrics.seed_comparison`: difference of
  the seed means, Welch's t, permutation p);
- ``sweep.md``: both as Markdown, and the best configuration, chosen by its mean validation score
  only (never a test-split number), with its best run (:func:`carl_sumo.learn.selection.rank_runs`).
"""

from __future__ import annotations

import csv
import io
import math
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from carl_sumo.files import write_text_atomic
from carl_sumo.sim.metrics import seed_comparison

METRICS = ("val_reward", "headway_s", "jerk_mps3", "speed_mps", "dampening_ratio", "collisions")
"""The validation metrics of the tables (the kept checkpoint's, on the held-out events)."""
COMPARED = ("score", "jerk_mps3", "dampening_ratio", "speed_mps")
"""What each configuration is compared on with the best one, across seeds."""
TRIAL_COLUMNS = ["trial", "config", "seed", "status", "score", "unsafe", *METRICS, "wall_s",
                 "resumed_at", "policy"]


def trial_rows(trials: Sequence, outcome: dict[str, dict[str, Any]], select: str,
               out: Path) -> list[dict[str, Any]]:
    """One row per trial from its policy file's stored validation (NaN where it has none)."""
    from carl_sumo.errors import InputError
    from carl_sumo.learn.policy import read_policy_payload
    from carl_sumo.learn.selection import rank_runs

    rows = []
    for trial in trials:
        path = out / f"{trial.name}.pt"
        got = outcome.get(trial.name, {})
        row: dict[str, Any] = {"trial": trial.name, "config": trial.config, "seed": trial.seed,
                               "status": "failed: " + got["error"] if "error" in got else "ok",
                               "score": math.nan, "unsafe": "", "wall_s": math.nan,
                               "resumed_at": got.get("resumed_at", -1), "policy": str(path)}
        row.update({m: math.nan for m in METRICS})
        try:
            meta = read_policy_payload(path).get("metadata") or {}
            ranked = rank_runs([path], select)[0]
        except InputError:
            if row["status"] == "ok":
                row["status"] = "no policy file"
            rows.append(row)
            continue
        val = meta.get("validation") or {}
        row.update({"score": ranked["score"], "unsafe": ranked["unsafe"],
                    "wall_s": _last_wall(path.with_suffix(".csv")),
                    **{m: float(val.get(m, math.nan)) for m in METRICS}})
        rows.append(row)
    return rows


def _last_wall(curve: Path) -> float:
    """The training wall time (s) in the last row of a run's learning curve (NaN without one)."""
    try:
        rows = list(csv.DictReader(open(curve)))
        return float(rows[-1]["wall_s"]) if rows else math.nan
    except (OSError, KeyError, ValueError):
        return math.nan


def config_rows(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Per configuration: mean and std over seeds, and the comparison with the best one (the
    highest mean validation score; listed first)."""
    groups: dict[str, list[dict]] = {}
    for r in rows:
        if r["status"] == "ok":
            groups.setdefault(r["config"], []).append(r)
    if not groups:
        return []
    table = []
    for config, runs in groups.items():
        row: dict[str, Any] = {"config": config, "seeds": len(runs)}
        for m in ("score", *METRICS):
            values = np.array([r[m] for r in runs], float)
            row[f"{m}_mean"] = float(np.mean(values))
            row[f"{m}_std"] = float(np.std(values, ddof=1)) if len(values) > 1 else math.nan
        row["unsafe_runs"] = sum(bool(r["unsafe"]) for r in runs)
        table.append(row)
    table.sort(key=lambda r: (-r["score_mean"], r["config"]))
    best = groups[table[0]["config"]]
    for row in table:
        runs = groups[row["config"]]
        for m in COMPARED:
            d, t, p = seed_comparison([r[m] for r in runs], [r[m] for r in best])
            row[f"d_{m}"], row[f"t_{m}"], row[f"p_{m}"] = d, t, p
    return table


CONFIG_COLUMNS = ["config", "seeds", *(f"{m}_{s}" for m in ("score", *METRICS)
                                       for s in ("mean", "std")), "unsafe_runs",
                  *(f"{s}_{m}" for m in COMPARED for s in ("d", "t", "p"))]


def _csv(rows: list[dict], columns: list[str]) -> str:
    out = io.StringIO()
    writer = csv.DictWriter(out, columns, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})
    return out.getvalue()


def _pm(row: dict, m: str) -> str:
    mean, std = row[f"{m}_mean"], row[f"{m}_std"]
    return f"{mean:.3f}" + ("" if math.isnan(std) else f" ± {std:.3f}")


def markdown(spec_path: Path, select: str, trials: list[dict], configs: list[dict],
             best_run: str | None, wall_s: float, command: str) -> str:
    """``sweep.md``: the configurations (best first), the trials, and how they were chosen."""
    lines = [f"# Sweep {spec_path}", "", f"`{command}`: {len(trials)} trials, "
             f"{sum(r['status'] == 'ok' for r in trials)} finished, wall time {wall_s:.0f} s.",
             "", f"Score: the `--select {select}` validation score of each run's kept checkpoint "
             "(held-out training events; no test-split number). A configuration's score is the "
             "mean over its seeds; Δ, t and p compare its seeds with the best configuration's "
             "(difference of means, Welch's t, permutation p).", "",
             "| config | seeds | score | jerk (m/s³) | dampening | speed (m/s) | headway (s) | "
             "unsafe runs | Δ score | p (score) |", "|---" * 10 + "|"]
    for c in configs:
        lines.append(f"| {c['config']} | {c['seeds']} | {_pm(c, 'score')} | "
                     f"{_pm(c, 'jerk_mps3')} | {_pm(c, 'dampening_ratio')} | "
                     f"{_pm(c, 'speed_mps')} | {_pm(c, 'headway_s')} | {c['unsafe_runs']} | "
                     f"{c['d_score']:.3f} | {c['p_score']:.3g} |")
    if configs:
        lines += ["", f"Best configuration: **{configs[0]['config']}**; its best run: "
                      f"`{best_run}`."]
    lines += ["", "| trial | seed | status | score | unsafe | jerk | dampening | speed | "
                  "headway | wall (s) | resumed at step |", "|---" * 11 + "|"]
    for r in trials:
        lines.append(f"| {r['trial']} | {r['seed']} | {r['status']} | {r['score']:.3f} | "
                     f"{'yes' if r['unsafe'] is True else 'no' if r['unsafe'] is False else ''}"
                     f" | {r['jerk_mps3']:.3f} | {r['dampening_ratio']:.3f} | "
                     f"{r['speed_mps']:.3f} | {r['headway_s']:.3f} | {r['wall_s']:.0f} | "
                     f"{r['resumed_at'] if r['resumed_at'] >= 0 else ''} |")
    return "\n".join(lines) + "\n"


def best_config_runs(trials: list[dict], configs: list[dict]) -> list[dict]:
    """The finished runs of the best configuration, highest score first (ties: lower seed)."""
    if not configs:
        return []
    runs = [r for r in trials if r["config"] == configs[0]["config"] and r["status"] == "ok"]
    return sorted(runs, key=lambda r: (-r["score"], r["seed"]))


def best_run(trials: list[dict], configs: list[dict]) -> str | None:
    """The policy file of the best configuration's highest-scoring run (ties: lower seed)."""
    runs = best_config_runs(trials, configs)
    return runs[0]["policy"] if runs else None


def write_report(results: Path, spec_path: Path, select: str, trials: list[dict],
                 configs: list[dict], wall_s: float, command: str) -> list[Path]:
    """Write trials.csv, configs.csv and sweep.md into ``results``; their paths."""
    best = best_run(trials, configs)
    return [write_text_atomic(results / "trials.csv", _csv(trials, TRIAL_COLUMNS)),
            write_text_atomic(results / "configs.csv", _csv(configs, CONFIG_COLUMNS)),
            write_text_atomic(results / "sweep.md", markdown(spec_path, select, trials, configs,
                                                             best, wall_s, command))]
