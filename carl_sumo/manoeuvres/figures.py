"""One manoeuvre per scenario, replayed as SUMO FCD output and drawn as a time-space figure with
the manoeuvre marked (``evaluate --suite scenarios``; the FCD files are what SUMO's
``plot_trajectories.py`` reads)."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from carl_sumo.control.channel import Impairments
from carl_sumo.data.events import Event
from carl_sumo.experiments.figures import pyplot, save_png
from carl_sumo.manoeuvres.spec import ScenarioSpec
from carl_sumo.sim.sumo import LaneRoute
from carl_sumo.manoeuvres.runs import replay_scenario

ROLE_STYLE = {"leader": ("black", 2.0), "human": ("red", 2.0), "joiner": ("green", 2.0)}


def fcd_tracks(fcd_path: Path, route: LaneRoute) -> dict[str, dict[str, np.ndarray]]:
    """{vehicle: {"t": s, "x": route coordinate of the front bumper m, "in_lane": bool}} from an
    FCD file, for vehicles on the route's edges (any lane; ``in_lane``: the platoon's lane)."""
    starts = dict(zip(route.edges, route.lane_starts))
    lanes = set(route.lanes)
    rows: dict[str, list[tuple[float, float, bool]]] = {}
    for step in ET.parse(fcd_path).getroot():
        t = float(step.get("time"))
        for v in step:
            lane = v.get("lane", "")
            edge = lane.rsplit("_", 1)[0]
            if edge in starts:
                rows.setdefault(v.get("id"), []).append(
                    (t, starts[edge] + float(v.get("pos")), lane in lanes))
    return {vid: {"t": np.array([r[0] for r in rs]), "x": np.array([r[1] for r in rs]),
                  "in_lane": np.array([r[2] for r in rs])} for vid, rs in rows.items()}


def manoeuvre_figure(tracks: dict[str, dict[str, np.ndarray]], path: Path, title: str,
                     t_m: float | None) -> None:
    """Position against time of every vehicle: solid in the platoon lane, dotted beside it; the
    leader black, a human who cuts in red, a joiner green; the manoeuvre's time marked."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(7.5, 4.5), layout="constrained")
    for vid, tr in tracks.items():
        color, width = ROLE_STYLE.get(vid, ("tab:blue", 1.0))
        for inside, style in ((True, "-"), (False, ":")):
            x = np.where(tr["in_lane"] == inside, tr["x"], np.nan)
            ax.plot(tr["t"], x, style, color=color, lw=width,
                    label=vid if inside and vid in ROLE_STYLE else None)
    if t_m is not None:
        ax.axvline(t_m, color="gray", ls="--", lw=1.0, label=f"manoeuvre done ({t_m:.1f} s)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("position along the road (m)")
    ax.set_title(title, fontsize=10)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8, loc="upper left")
    save_png(fig, path)


def manoeuvre_examples(out: Path, event: Event, n_followers: int, net: str, controller: str,
                       kinds: list[str], seed: int = 0,
                       impairments: Impairments | None = None) -> list[Path]:
    """For each manoeuvre kind: ``out/fcd/<kind>.xml`` (SUMO FCD) and ``out/<kind>.png``."""
    from carl_sumo.manoeuvres.simulation import ScenarioSim

    route = ScenarioSim(net, "external").route
    written = []
    (out / "fcd").mkdir(parents=True, exist_ok=True)
    for kind in kinds:
        spec = ScenarioSpec(kind, seed=seed)
        fcd = out / "fcd" / f"{kind}.xml"
        row = replay_scenario(controller, event, n_followers, fcd, net, spec,
                              impairments=impairments)
        m = row["manoeuvre_metrics"]
        png = out / f"{kind}.png"
        manoeuvre_figure(fcd_tracks(fcd, route), png,
                         f"{row['manoeuvre']}, {Path(controller).name}, event {event.event_id}\n"
                         f"min gap {m['min_gap_m']:.2f} m, min TTC {m['min_ttc_s']:.2f} s, "
                         f"peak decel {m['peak_decel_mps2']:.2f} m/s²", row["done_time_s"])
        written += [fcd, png]
    return written

