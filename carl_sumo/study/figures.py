"""Figures of a mixed-traffic study: each metric against the penetration rate, time-space maps."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from carl_sumo.experiments.figures import pyplot, save_png
from carl_sumo.study.results import RunResult

PANELS = (("throughput_vph", "throughput (veh/h)"), ("speed_mps", "mean speed (m/s)"),
          ("headway_s", "mean headway (s)"), ("ttc_lt_4s_per_vh", "TTC < 4 s (samples/veh-h)"),
          ("ttc_lt_1_5s_per_vh", "TTC < 1.5 s (samples/veh-h)"), ("jerk_mps3", "mean |jerk| (m/s³)"),
          ("collisions", "collisions"), ("co2_g_per_km", "CO2 (g/veh-km)"),
          ("fuel_g_per_km", "fuel (g/veh-km)"))


def plot_metrics(rows: list[dict[str, float]], path: Path, controller: str) -> Path:
    """A 3x3 grid: every study metric (mean ± sd over seeds) against the penetration rate."""
    plt = pyplot()
    p = np.array([r["penetration"] for r in rows])
    fig, axes = plt.subplots(3, 3, figsize=(12, 9))
    for ax, (key, label) in zip(axes.ravel(), PANELS):
        mean = np.array([r[key] for r in rows])
        sd = np.array([r[key + "_sd"] for r in rows])
        ax.errorbar(p, mean, yerr=sd, marker="o", capsize=3)
        ax.set_xlabel("CACC penetration rate p")
        ax.set_title(label, fontsize=10)
        ax.grid(alpha=0.3)
    fig.suptitle(f"Mixed traffic on the I-80-like freeway, CACC controller {controller} "
                 "(mean ± sd over seeds)")
    fig.tight_layout()
    return save_png(fig, path, dpi=110, bbox_inches="tight")


def plot_heatmap(result: RunResult, path: Path, ngsim_lane: int) -> Path:
    """Time-space map of the mean speed (m/s) along one lane of the mainline, one run."""
    plt = pyplot()
    grid = np.array(result.heatmap, dtype=float)
    t0, t1, x0, x1 = result.heatmap_extent
    fig, ax = plt.subplots(figsize=(10, 4.5))
    image = ax.imshow(grid.T, origin="lower", aspect="auto", extent=(t0, t1, x0, x1),
                      cmap="RdYlGn", vmin=0.0, vmax=34.0, interpolation="nearest")
    fig.colorbar(image, ax=ax, label="mean speed (m/s)")
    ax.set_xlabel("simulated time (s)")
    ax.set_ylabel("position along the mainline (m)")
    ax.set_title(f"NGSIM lane {ngsim_lane}, p = {result.penetration:g}, seed {result.seed} "
                 "(white: no vehicle)")
    fig.tight_layout()
    return save_png(fig, path, dpi=110, bbox_inches="tight")
