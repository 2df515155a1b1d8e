"""What ``carl-sumo evaluate`` writes: the tables as Markdown and CSV, and the suite's README.

- per table ``<table>.md`` and ``<table>.csv`` (the rows of :func:`carl_sumo.experiments.suite_stats.table_rows`),
  ``<table>_paired.csv`` and a Markdown section for its paired comparisons,
  ``<table>_seeds.csv`` where a model has several seed files;
- ``per_event.csv`` (every job's per-event metrics, with the sample counts that weight the pooled
  means) and ``timing.csv`` (wall and CPU seconds per job);
- ``README.md``: all tables, the figure links, the command, the machine, the wall time and the
  policy file hashes (:func:`suite_readme`).

Every file is written whole or not at all (:func:`carl_sumo.files.write_text_atomic`).
"""

from __future__ import annotations

import csv
import io
import math
import os
import platform
from pathlib import Path

from carl_sumo.files import write_text_atomic
from carl_sumo.sim.metrics import METRIC_KEYS
from carl_sumo.experiments.suite import JobResult, Suite, TableSpec
from carl_sumo.experiments.suite_stats import (CSV_COLUMNS, N_BOOT, PAIRED_COLUMNS, PAIRED_KEYS, SEED_COLUMNS,
                                   WEIGHT_KEYS, paired_rows, per_event_rows, seed_rows,
                                   table_rows)


METRIC_LABELS = {
    "headway_s": "headway (s)", "jerk_mps3": "jerk (m/s³)", "speed_mps": "speed (m/s)",
    "ttc_lt_4s_count": "TTC<4 s", "ttc_lt_1_5s_count": "TTC<1.5 s",
    "dampening_ratio": "dampening", "worst_successive_ratio": "worst successive",
    "collisions": "collisions",
}


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


def csv_text(rows: list[dict], columns: list[str]) -> str:
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=columns, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for row in rows:
        writer.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in row.items()})
    return buffer.getvalue()


def write_tables(suite: Suite, results: dict[tuple, JobResult],
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


def _sha(path: str) -> str:
    import hashlib

    return hashlib.sha256(Path(path).read_bytes()).hexdigest()[:12]


def _load() -> str:
    """The 1, 5 and 15 min load averages (other processes on the machine slow the suite)."""
    try:
        return ", ".join(f"{x:.1f}" for x in os.getloadavg())
    except OSError:
        return "unknown"


def _impairments(imp) -> str:
    """One line of the impairments a suite ran with."""
    return (f"delay {imp.delay_s:g} s, loss {imp.loss:g} (bursts of {imp.burst:g} steps), "
            f"timeout {imp.timeout_s:g} s, fade {imp.fade_s:g} s, "
            f"sensor noise {'on' if imp.sensor_noise else 'off'}, impairment seed {imp.seed}"
            + (f"; vehicle dynamics: fleet {imp.plant.describe()} (`docs/vehicles.md`)"
               if imp.plant is not None else ""))


def suite_readme(suite: Suite, sections: list[str], figure_files: list[tuple[str, str]],
                 wall: float, simulated: float, cpu: float, workers: int, n_tasks: int,
                 command: str) -> str:
    n_events = {k: len(v) for k, v in suite.events.items()}
    lines = [f"# carl-sumo evaluate: the {suite.name} suite" + (" (--quick)" if suite.quick else ""),
             "",
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
             *([f"- impairments (`docs/robustness.md`): {_impairments(suite.impairments)} for "
                "every controller that runs in carl-sumo (Ploeg, the policies); SUMO's native "
                "models (IDM, Krauss, CACC) and the human row run without them"]
               if suite.impairments is not None else []),
             *([f"- warm-up: every event first runs {suite.warmup_s:g} s with the leader at its "
                "initial speed, unscored (`--warmup`, `docs/metrics.md`)"]
               if suite.warmup_s else []),
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
