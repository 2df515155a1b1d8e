"""The figures of ``carl-sumo evaluate`` (PNG, matplotlib without a display).

- ``fig_ecdf_ngsim_test.png``: empirical distribution functions of time headway, speed and |jerk|
  per model over every follower sample of the Table 1 runs;
- ``fig_timeseries_ngsim.png`` / ``fig_timeseries_stop_and_go.png``: position, speed and
  acceleration against time of the leader and every follower, three panels per model in a grid
  of up to four models a row, one legend;
- ``fig_time_space_ngsim.png`` / ``fig_time_space_stop_and_go.png``: time-space diagrams of the
  platoon (front-bumper position against time, coloured by speed), one panel per model;
- ``fig_frontier_ngsim_test.png``: mean |jerk| and dampening ratio against mean time headway on
  the Table 1 runs: the textbook and tuned Ploeg CACCs as curves over their time gaps, every other
  model as a point (who follows closer for the same comfort and string stability); labels are
  moved apart, and a point far off the rest sits on the axis edge with its value;
- ``fig_accel_norm_profile.png``: per-vehicle acceleration norm ‖a_i‖₂ / ‖a_0‖₂ along the
  platoon (vehicle 0 = the leader), mean over events, for each platoon length of Table 2 and for
  the stop-and-go leader: a string-stable platoon stays at or below 1 and decreases along it.

The per-model figures draw the classical CACCs of :data:`CLASSICAL_SHOWN` only (the frontier
figure draws them all). Every file is written to a temporary name and renamed into place.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from carl_sumo.experiments.suite import data_tag
from carl_sumo.files import atomic_path
from carl_sumo.sim.metrics import aggregate

if TYPE_CHECKING:  # pragma: no cover
    from carl_sumo.experiments.suite import JobResult, Suite

ECDF_POINTS = 2000
"""Sample ranks at which an ECDF is drawn."""

CLASSICAL_SHOWN = ("sumo-cacc", "ploeg:h=1", "ploeg-tuned:h=1")
"""The classical CACCs drawn in the per-model figures: SUMO's, and Ploeg's at h = 1 s."""

CURVES = {"ploeg:": "Ploeg textbook (kp 0.2, kd 0.7)", "ploeg-tuned:": "Ploeg tuned"}
"""Model-key prefixes drawn as curves over the time gap in the frontier figure."""

SAMPLE_LABELS = {"headway_s": "time headway (s)", "speed_mps": "speed (m/s)",
                 "jerk_mps3": "|jerk| (m/s³)"}


def pyplot():
    """matplotlib.pyplot on the file-only Agg backend (no display needed)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_png(fig, path: Path, dpi: int = 90, **savefig_kw) -> Path:
    """Write a figure as PNG through a temporary file (never half-written), then close it."""
    path = Path(path)
    try:
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png", dpi=dpi, **savefig_kw)
    finally:
        pyplot().close(fig)
    return path


def _colors(n: int) -> list:
    """n distinct colours: matplotlib's tab10, then black, greys and tab20's light shades."""
    plt = pyplot()
    base = [plt.get_cmap("tab10")(i) for i in range(10)] + ["black", "dimgray", "darkgray"] + [
        plt.get_cmap("tab20")(i) for i in range(1, 20, 2)]
    return [base[i % len(base)] for i in range(n)]


def ecdf_points(values: np.ndarray, points: int = ECDF_POINTS) -> tuple[np.ndarray, np.ndarray]:
    """(x, F(x)) of the empirical distribution function at up to ``points`` sample ranks: exact
    values of the ECDF, thinned so that a million samples draw as fast as a thousand."""
    values = np.sort(values[np.isfinite(values)])
    n = values.size
    if n == 0:
        return values, values
    ranks = np.unique(np.linspace(0, n - 1, min(points, n)).round().astype(int))
    return values[ranks], (ranks + 1) / n


def ecdf_curves(samples: dict[str, np.ndarray]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Thinned ECDF points of each sample kind (|jerk| below 1e-3 m/s³ drawn at 1e-3: log axis)."""
    curves = {}
    for key, values in samples.items():
        values = np.asarray(values, np.float64)
        if key == "jerk_mps3":
            values = np.maximum(values, 1e-3)
        curves[key] = ecdf_points(values)
    return curves


def ecdf_figure(curves: dict[str, dict[str, tuple[np.ndarray, np.ndarray]]], path: Path,
                title: str, colors: dict[str, Any] | None = None) -> None:
    """ECDFs of headway, speed and |jerk|: ``curves[model][key]`` = (x, F(x)), one line each."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.4), layout="constrained")
    colors = colors or dict(zip(curves, _colors(len(curves))))
    for ax, key in zip(axes, SAMPLE_LABELS):
        for model, per_key in curves.items():
            x, y = per_key.get(key, (np.empty(0), np.empty(0)))
            if not x.size:
                continue
            ax.step(x, y, where="post", color=colors[model], label=model, lw=1.3,
                    ls="--" if model.startswith("human") else "-")
        if key == "jerk_mps3":
            ax.set_xscale("log")
        elif key == "headway_s":
            ax.set_xlim(0, 6)
        ax.set_xlabel(SAMPLE_LABELS[key])
        ax.set_ylabel("fraction of samples ≤ x")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8, loc="lower right")
    fig.suptitle(title)
    save_png(fig, path)


QUANTITIES = (("pos", "position (m)"), ("speed", "speed (m/s)"), ("acc", "acceleration (m/s²)"))
"""The rows of a model's block in the time-series figure."""


def timeseries_figure(series: dict[str, dict[str, np.ndarray]], path: Path, title: str,
                      max_cols: int = 4) -> None:
    """Position, speed and acceleration against time: one block of three panels per model, the
    blocks wrapped into a grid of at most ``max_cols`` columns; one legend for the figure."""
    save_png(timeseries_canvas(series, title, max_cols), path)


def timeseries_canvas(series: dict[str, dict[str, np.ndarray]], title: str, max_cols: int = 4):
    """The matplotlib figure of :func:`timeseries_figure`."""
    plt = pyplot()
    models = list(series)
    cols = max(1, min(max_cols, len(models)))
    block_rows = (len(models) + cols - 1) // cols
    fig, axes = plt.subplots(3 * block_rows, cols, figsize=(3.6 * cols, 6.6 * block_rows + 0.8),
                             sharex=True, squeeze=False, layout="constrained")
    cmap = plt.get_cmap("viridis")
    handles: dict[str, Any] = {}
    for index, model in enumerate(models):
        s, row0, col = series[model], 3 * (index // cols), index % cols
        n = s["speed"].shape[1]
        for q, (key, label) in enumerate(QUANTITIES):
            ax = axes[row0 + q, col]
            if index:  # one scale per quantity across all models
                ax.sharey(axes[q, 0])
            t = s["t"][1:] if key == "acc" else s["t"]
            for i in range(n):
                name = "leader" if i == 0 else (f"follower {i}" if i in (1, n - 1) else None)
                line, = ax.plot(t, s[key][:, i], lw=1.6 if i == 0 else 0.9,
                                color="black" if i == 0 else cmap((i - 1) / max(n - 2, 1)))
                if name is not None and q == 0:
                    handles.setdefault(name, line)
            ax.grid(alpha=0.3)
            if col == 0:
                ax.set_ylabel(label)
        axes[row0, col].set_title(model, fontsize=10)
        axes[row0 + 2, col].set_xlabel("time (s)")
        axes[row0 + 2, col].xaxis.set_tick_params(labelbottom=True)
    for index in range(len(models), block_rows * cols):
        for q in range(3):
            axes[3 * (index // cols) + q, index % cols].set_visible(False)
    order = sorted(handles, key=lambda k: (k != "leader", int(k.split()[-1]) if k != "leader"
                                            else 0))
    fig.legend([handles[k] for k in order], order, loc="outside lower center",
               ncol=len(order), fontsize=8)
    fig.suptitle(title)
    return fig


def time_space_figure(series: dict[str, dict[str, np.ndarray]], path: Path, title: str) -> None:
    """Time-space diagram per model: each vehicle's position against time, coloured by speed."""
    plt = pyplot()
    from matplotlib.collections import LineCollection

    models = list(series)
    cols = min(4, len(models))
    rows = (len(models) + cols - 1) // cols
    fig, axes = plt.subplots(rows, cols, figsize=(4.2 * cols, 3.6 * rows), sharex=True,
                             sharey=True, squeeze=False, layout="constrained")
    vmax = max(float(s["speed"].max()) for s in series.values())
    norm = plt.Normalize(0.0, vmax)
    line = None
    for ax, model in zip(axes.flat, models):
        s = series[model]
        for i in range(s["pos"].shape[1]):
            points = np.stack([s["t"], s["pos"][:, i]], axis=1)
            segments = np.stack([points[:-1], points[1:]], axis=1)
            line = LineCollection(segments, cmap="turbo_r", norm=norm, lw=1.6 if i == 0 else 1.0)
            line.set_array(s["speed"][:-1, i])
            ax.add_collection(line)
        ax.autoscale()
        ax.set_title(model, fontsize=10)
        ax.grid(alpha=0.3)
    for ax in axes.flat[len(models):]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel("time (s)")
    for ax in axes[:, 0]:
        ax.set_ylabel("position (m)")
    if line is not None:
        fig.colorbar(line, ax=axes, label="speed (m/s)", shrink=0.8)
    fig.suptitle(title)
    save_png(fig, path)


def norm_profile_figure(panels: list[tuple[str, dict[str, np.ndarray]]], path: Path,
                        colors: dict[str, Any] | None = None) -> None:
    """‖a_i‖/‖a_0‖ against vehicle index i (0 = leader), one panel per (title, {model: profile})."""
    plt = pyplot()
    fig, axes = plt.subplots(1, len(panels), figsize=(4.6 * len(panels) + 1.8, 4.2),
                             squeeze=False, layout="constrained")
    names = list(dict.fromkeys(m for _, profiles in panels for m in profiles))
    color = colors or dict(zip(names, _colors(len(names))))
    for ax, (title, profiles) in zip(axes[0], panels):
        for model, profile in profiles.items():
            ax.plot(np.arange(profile.size), profile, marker="o", ms=2.5, lw=1.2,
                    color=color[model], label=model)
        ax.axhline(1.0, color="black", lw=0.8, ls=":")
        ax.xaxis.get_major_locator().set_params(integer=True)
        ax.set_title(title, fontsize=10)
        ax.set_xlabel("vehicle (0 = leader)")
        ax.grid(alpha=0.3)
    axes[0, 0].set_ylabel("‖a_i‖₂ / ‖a_0‖₂ (mean over events)")
    handles = {}
    for ax in axes[0]:
        for handle, label in zip(*ax.get_legend_handles_labels()):
            handles.setdefault(label, handle)
    fig.legend(list(handles.values()), list(handles), fontsize=8, loc="outside right center")
    save_png(fig, path)


def _shown(key: str) -> bool:
    return not key.startswith(tuple(CURVES)) or key in CLASSICAL_SHOWN


def outliers(values: list[float], max_out: int = 2) -> set[int]:
    """Indices of values so far from the rest that drawing them would squash it: the largest
    (or smallest) value while its gap to the next exceeds the whole spread of the others, at most
    ``max_out`` at each end."""
    order = [i for i in np.argsort(values).tolist() if np.isfinite(values[i])]
    out: set[int] = set()
    for end in (-1, 0):
        for _ in range(max_out):
            rest = [i for i in order if i not in out]
            if len(rest) < 4:
                break
            if end == -1:  # the largest against the spread of the others
                far, near, spread = rest[-1], rest[-2], values[rest[-2]] - values[rest[0]]
            else:
                far, near, spread = rest[0], rest[1], values[rest[-1]] - values[rest[1]]
            if abs(values[far] - values[near]) <= max(spread, 1e-12):
                break
            out.add(far)
    return out


def declutter(ax, texts: list, marker_px: float = 3.5) -> None:
    """Move annotations (offset in points) up or down until none overlaps an earlier one or a
    data point of the axes (a box of ``marker_px`` pixels around it)."""
    from matplotlib.transforms import Bbox

    fig = ax.figure
    renderer = fig.canvas.get_renderer()
    placed = [Bbox.from_extents(x - marker_px, y - marker_px, x + marker_px, y + marker_px)
              for line in ax.lines for x, y in ax.transData.transform(line.get_xydata())]
    for text in texts:
        box = text.get_window_extent(renderer)
        step = box.height * 72.0 / fig.dpi + 1.0
        for k in range(1, 12):
            if not any(box.overlaps(other) for other in placed):
                break
            dx, dy = text.xyann
            text.xyann = (dx, dy + (k if k % 2 else -k) * step)  # up, down, further up, ...
            box = text.get_window_extent(renderer)
        placed.append(box)


def _frontier_panel(ax, points: list[dict[str, Any]], key: str) -> list:
    """One panel of the frontier figure: the curves (labelled by time gap) and the points, the
    axes fitted to all but the outliers, which sit on their edge with their values."""
    texts = []
    for (curve, style), (xy, ha) in zip(zip(CURVES.values(), ("o--", "s-")),
                                        (((4, 4), "left"), ((4, -10), "left"))):
        pts = sorted((p for p in points if p["curve"] == curve), key=lambda p: p["headway_s"])
        if pts:
            ax.plot([p["headway_s"] for p in pts], [p[key] for p in pts], style, label=curve,
                    color="0.35" if style == "o--" else "black", ms=5)
            texts += [ax.annotate(p["label"].rsplit(" ", 2)[-2], (p["headway_s"], p[key]),
                                  textcoords="offset points", xytext=xy, ha=ha, fontsize=7)
                      for p in pts]
    singles = [p for p in points if p["curve"] is None]
    markers = "DovP^<>sXh*dp"  # cycled: the real suite has more single points than markers
    styles = {p["label"]: (c, markers[i % len(markers)])
              for i, (p, c) in enumerate(zip(singles, _colors(len(singles))))}
    for p in singles:
        color, marker = styles[p["label"]]
        ax.plot(p["headway_s"], p[key], marker, color=color, ms=7, label=p["label"])
    return texts + _edge_outliers(ax, points, key, styles)


def _edge_outliers(ax, points: list[dict[str, Any]], key: str, styles: dict) -> list:
    """Fit each axis to the points but its :func:`outliers`; draw those on the edge they lie
    beyond, labelled with their values; the labels."""
    xs = [float(p["headway_s"]) for p in points]
    ys = [float(p[key]) for p in points]
    box, far = [], set()
    for values, set_limits in ((xs, ax.set_xlim), (ys, ax.set_ylim)):
        out = outliers(values)
        kept = [v for i, v in enumerate(values) if i not in out and np.isfinite(v)] or [0.0]
        pad = 0.08 * (max(kept) - min(kept) or 1.0)
        box.append((min(kept) - pad, max(kept) + pad))
        if out:
            set_limits(*box[-1])
        far |= out
    texts = []
    for i in sorted(far):
        (x_lo, x_hi), (y_lo, y_hi) = box
        x, y = min(max(xs[i], x_lo), x_hi), min(max(ys[i], y_lo), y_hi)
        color, marker = styles.get(points[i]["label"], ("black", "o"))
        ax.plot(x, y, marker, color=color, ms=7, clip_on=False)
        arrows = ("→" if xs[i] > x_hi else "←" if xs[i] < x_lo else "") + \
            ("↑" if ys[i] > y_hi else "↓" if ys[i] < y_lo else "")
        shown = f"{ys[i]:.2f}" if x == xs[i] else f"{xs[i]:.2f} s, {ys[i]:.2f}"
        texts.append(ax.annotate(f"{points[i]['label']}: {shown} {arrows}", (x, y),
                                 textcoords="offset points", fontsize=7,
                                 xytext=(-6 if x < xs[i] else 6, -10 if y < ys[i] else 4),
                                 ha="right" if x < xs[i] else "left"))
    return texts


def frontier_figure(points: list[dict[str, Any]], path: Path, title: str) -> None:
    """Jerk and dampening against headway: ``points`` with label, curve (or None), headway_s,
    jerk_mps3, dampening_ratio; points of one curve are joined in order of headway. Labels do
    not overlap; a point far off the rest is drawn on the axis edge with its value."""
    plt = pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(13, 5.2), layout="constrained")
    panels = []
    for ax, key, ylabel in ((axes[0], "jerk_mps3", "mean |jerk| (m/s³)"),
                            (axes[1], "dampening_ratio", "dampening ratio ‖a_i‖/‖a_0‖")):
        panels.append((ax, _frontier_panel(ax, points, key)))
        ax.set_xlabel("mean time headway (s)")
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    handles, labels = axes[0].get_legend_handles_labels()
    fig.legend(handles, labels, fontsize=8, loc="outside right center")
    fig.suptitle(title)
    fig.canvas.draw()  # the final layout, so that the labels' boxes are where they will be
    for ax, texts in panels:
        declutter(ax, texts)
    save_png(fig, path)


def mean_profile(norms: list[np.ndarray]) -> np.ndarray:
    """Mean over events of ‖a_i‖/‖a_0‖ (events whose leader never accelerates are left out)."""
    ratios = [n / n[0] for n in norms if n[0] > 0]
    if not ratios:
        return np.full(norms[0].size if norms else 1, np.nan)
    size = min(r.size for r in ratios)  # all equal unless an episode ended in a collision
    return np.mean([r[:size] for r in ratios], axis=0)


FIGURE_FUNCTIONS = {"ecdf": ecdf_figure, "timeseries": timeseries_figure,
                    "time_space": time_space_figure, "norm_profile": norm_profile_figure,
                    "frontier": frontier_figure}


def figure_jobs(suite: "Suite", results: dict[tuple, "JobResult"],
                out_dir: Path) -> list[dict[str, Any]]:
    """The figures of a suite run as small picklable jobs for :func:`render` (data reduced)."""
    jobs: list[dict[str, Any]] = []
    by_key = {spec.key: spec for spec in suite.tables}
    tag = data_tag(suite.data)  # the leader data the file names say
    t1, t2, t3 = (by_key.get(f"table1_{tag}_test"), by_key.get("table2_generalization"),
                  by_key.get("table3_stop_and_go"))  # None: not run (evaluate --tables)
    label = {key: model_label(m) for key, m in suite.models.items()}
    shown = [label[key] for key in suite.models if _shown(key)]
    colors = dict(zip(shown, _colors(len(shown))))

    def first_run(spec, key, n):
        model = suite.models[key]
        return results.get((spec.events.key, model.controllers[0], 1 if key == "human" else n))

    def add(kind: str, name: str, caption: str, *args) -> None:
        jobs.append({"kind": kind, "path": Path(out_dir) / name, "caption": caption,
                     "args": args})

    if t1 is not None:
        curves = {}
        for key in filter(_shown, t1.models):
            res = first_run(t1, key, t1.followers[0])
            curves[label[key]] = ecdf_curves({k: np.concatenate(v) if v else np.empty(0)
                                              for k, v in res.samples.items()})
        add("ecdf", f"fig_ecdf_{tag}_test.png",
            "ECDFs of time headway, speed and |jerk| per model (Table 1 runs)", curves,
            f"Empirical distributions, {t1.title} ({len(suite.events[t1.events.key])} events)",
            colors)

    for spec, where_tag in ((t1, tag), (t3, "stop_and_go")):
        if spec is None:
            continue
        event_id = suite.figure_events[spec.events.key]
        series = {}
        for key in filter(_shown, spec.models):
            res = first_run(spec, key, spec.followers[0])
            if res is not None and event_id in res.series:
                series[label[key]] = res.series[event_id]
        where = f"event {event_id}" if spec is t1 else "stop-and-go leader"
        add("timeseries", f"fig_timeseries_{where_tag}.png",
            f"Position, speed and acceleration against time, {where}", series,
            f"Position, speed and acceleration, {where}, {spec.followers[0]} followers")
        add("time_space", f"fig_time_space_{where_tag}.png",
            f"Time-space diagram of the platoon, {where}",
            {k: v for k, v in series.items() if not k.startswith("human")},
            f"Time-space diagram of the platoon, {where}")

    panels = []
    for n in t2.followers if t2 is not None else ():
        profiles = {label[key]: mean_profile(first_run(t2, key, n).norms)
                    for key in filter(_shown, t2.models) if suite.models[key].runs_on(n)}
        panels.append((f"{'NGSIM' if tag == 'ngsim' else tag} test, {n} followers", profiles))
    if t3 is not None:
        panels.append((f"stop-and-go, {t3.followers[0]} followers",
                       {label[key]: mean_profile(first_run(t3, key, t3.followers[0]).norms)
                        for key in filter(_shown, t3.models)}))
    if panels:
        add("norm_profile", "fig_accel_norm_profile.png",
            "Acceleration norm along the platoon, ‖a_i‖₂/‖a_0‖₂, mean over events (string "
            "stability at a glance; model (length trained on))", panels, colors)
    if t1 is None:
        return jobs

    points = []
    for key in (k for k in t1.models if k != "human"):  # one recorded vehicle, not a platoon
        agg = aggregate(first_run(t1, key, t1.followers[0]).per_event)
        curve = next((name for prefix, name in CURVES.items() if key.startswith(prefix)), None)
        points.append({"label": label[key], "curve": curve, **agg})
    add("frontier", f"fig_frontier_{tag}_test.png",
        "Mean |jerk| and dampening ratio against mean time headway (Table 1 runs): the Ploeg "
        "CACC's textbook and tuned curves over their time gap h, every other model a point",
        points, f"Following closer for the same comfort, {t1.title}")
    return jobs


def render(job: dict[str, Any]) -> tuple[str, str]:
    """Draw and write one figure job (in any process); (file name, caption)."""
    data, *rest = job["args"]
    FIGURE_FUNCTIONS[job["kind"]](data, job["path"], *rest)
    return job["path"].name, job["caption"]


def model_label(model) -> str:
    """A model's name in the figures: the algorithm and, for a policy, the length trained on."""
    return model.name if model.trained_on is None else f"{model.name} ({model.trained_on})"
