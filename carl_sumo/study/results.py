"""What a mixed-traffic study produces: each run's result, the summary per penetration rate, and
its table, below both the study loop (:mod:`carl_sumo.study.run`) and its figures
(:mod:`carl_sumo.study.figures`). The metrics are defined in :mod:`carl_sumo.study.run`.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from carl_sumo.files import write_text_atomic

METRICS = ("throughput_vph", "speed_mps", "headway_s", "ttc_lt_4s_per_vh", "ttc_lt_1_5s_per_vh",
           "jerk_mps3", "collisions", "co2_g_per_km", "fuel_g_per_km")
RUN_EXTRA = ("mean_vehicles", "max_vehicles", "cacc_share", "mean_chain_length",
             "max_chain_length", "sim_speed", "sumo_share")


@dataclass
class RunResult:
    penetration: float
    seed: int
    metrics: dict[str, float]
    heatmap: list[list[float]] = field(default_factory=list)  # mean speed (m/s), [time][space]
    heatmap_extent: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 0.0)  # t0, t1, x0, x1
    run_dir: str = ""


def run_name(penetration: float, seed: int) -> str:
    return f"p{penetration:g}_seed{seed}"


def summarise(results: list[RunResult]) -> list[dict[str, float]]:
    """One row per penetration rate: mean and standard deviation over seeds of every metric."""
    rows = []
    for p in sorted({r.penetration for r in results}):
        group = [r for r in results if r.penetration == p]
        row: dict[str, float] = {"penetration": p, "runs": len(group)}
        for key in (*METRICS, *RUN_EXTRA):
            values = np.array([r.metrics[key] for r in group], dtype=float)
            row[key] = float(np.mean(values))
            row[key + "_sd"] = float(np.std(values, ddof=1)) if len(values) > 1 else 0.0
        rows.append(row)
    return rows


TABLE_COLUMNS = (("penetration", "p", "{:g}"), ("throughput_vph", "throughput (veh/h)", "{:.0f}"),
                 ("speed_mps", "mean speed (m/s)", "{:.2f}"), ("headway_s", "headway (s)", "{:.3f}"),
                 ("ttc_lt_4s_per_vh", "TTC<4 s (/veh-h)", "{:.1f}"),
                 ("ttc_lt_1_5s_per_vh", "TTC<1.5 s (/veh-h)", "{:.2f}"),
                 ("jerk_mps3", "jerk (m/s³)", "{:.3f}"), ("collisions", "collisions", "{:.1f}"),
                 ("co2_g_per_km", "CO2 (g/veh-km)", "{:.1f}"),
                 ("fuel_g_per_km", "fuel (g/veh-km)", "{:.1f}"),
                 ("mean_vehicles", "vehicles on net", "{:.0f}"),
                 ("mean_chain_length", "mean chain", "{:.2f}"),
                 ("sim_speed", "sim s / wall s", "{:.2f}"))


def markdown_table(rows: list[dict[str, float]]) -> str:
    """The per-rate table in Markdown: mean ± sd over seeds."""
    header = "| " + " | ".join(h for _, h, _ in TABLE_COLUMNS) + " |"
    lines = [header, "|" + "---|" * len(TABLE_COLUMNS)]
    for row in rows:
        cells = []
        for key, _, fmt in TABLE_COLUMNS:
            value = row[key]
            if isinstance(value, float) and math.isnan(value):
                cells.append("-")
                continue
            cell = fmt.format(value)
            sd = row.get(key + "_sd")
            if key != "penetration" and sd and row["runs"] > 1 and not math.isnan(sd):
                cell += " ± " + fmt.format(sd)
            cells.append(cell)
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_csv(path: Path, rows: list[dict]) -> Path:
    """Rows (dicts with the same keys) as a CSV file, written atomically."""
    buffer = io.StringIO()
    writer = csv.DictWriter(buffer, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    return write_text_atomic(path, buffer.getvalue())
