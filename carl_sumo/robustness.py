"""The robustness suite: controllers under V2V delay and loss and sensor noise
(``carl-sumo evaluate --suite robustness --out DIR``).

Every controller runs the NGSIM test split with 10 followers at each impairment setting of
:func:`settings` (:mod:`carl_sumo.channel`): message loss from 0 to 100 % at no delay, delay from
0 to 0.5 s without loss, the bursty point (30 % loss in bursts of 3 steps with 0.2 s delay),
and sensor noise alone and with the bursty point. IDM (computed in carl-sumo, ``idm-external``)
sends no messages, so it runs only where its sensors change: the perfect setting and the noisy
ones. Each cell is the shipped file's aggregate over events with a 95 % bootstrap interval over
events (:func:`carl_sumo.metrics.bootstrap_ci`); draws use impairment seed 0.

Writes ``robustness.md``, ``robustness.csv`` and two figures (each metric against loss and
against delay). ``--quick``: the shipped default leader set, 2 events and four settings.
"""

from __future__ import annotations

import csv
import io
import time
from dataclasses import dataclass
from pathlib import Path

from carl_sumo.channel import Impairments
from carl_sumo.data import load_events
from carl_sumo.errors import InputError
from carl_sumo.files import write_text_atomic
from carl_sumo.metrics import bootstrap_ci
from carl_sumo.simulate import simulate
from carl_sumo.suite import DEFAULT_NGSIM

LOSSES = (0.0, 0.1, 0.3, 0.5, 0.8, 1.0)
DELAYS_S = (0.0, 0.1, 0.2, 0.5)
CONTROLLERS = ("idm-external", "ploeg", "ploeg-tuned:h=0.8", "policies/ca_td3_10.pt",
               "policies/ca_td3_ploeg_10.pt")
"""IDM, the textbook Ploeg CACC, the tuned one the product runs on, the paper configuration's
CA-TD3 and the product configuration's CA-TD3 (trained with a perfect channel)."""
KEYS = ("headway_s", "jerk_mps3", "speed_mps", "ttc_lt_4s_count", "ttc_lt_1_5s_count",
        "dampening_ratio", "collisions")


@dataclass(frozen=True)
class Setting:
    label: str
    impairments: Impairments

    @property
    def channel_only(self) -> bool:
        """Whether only V2V changes here (a controller without messages runs as at 'perfect')."""
        return not self.impairments.sensor_noise and self.label != "perfect"


def settings(quick: bool = False) -> list[Setting]:
    """The impairment settings of the suite, in table order."""
    out = [Setting("perfect", Impairments())]
    out += [Setting(f"loss {p:g}", Impairments(loss=p)) for p in LOSSES[1:]]
    out += [Setting(f"delay {d:g} s", Impairments(delay_s=d)) for d in DELAYS_S[1:]]
    bursty = Impairments(delay_s=0.2, loss=0.3, burst=3.0)
    out += [Setting("loss 0.3 in bursts of 3, delay 0.2 s", bursty),
            Setting("sensor noise", Impairments(sensor_noise=True)),
            Setting("sensor noise, loss 0.3 in bursts of 3, delay 0.2 s",
                    Impairments(delay_s=0.2, loss=0.3, burst=3.0, sensor_noise=True))]
    if quick:
        keep = {"perfect", "loss 0.3", "delay 0.2 s", "sensor noise"}
        out = [s for s in out if s.label in keep]
    return out


def run_robustness(out: Path, data: str | None = None, quick: bool = False,
                   events_limit: int | None = None, net: str = "networks/i80.net.xml",
                   workers: int = 2, controllers: tuple[str, ...] = CONTROLLERS,
                   progress: bool = False, command: str = "") -> dict:
    """Run the suite and write its table and figures into ``out``; returns the rows."""
    data = data or ("default" if quick else str(DEFAULT_NGSIM))
    if not quick and not Path(data).is_file():
        raise InputError(f"the robustness suite runs the NGSIM test split: {data} does not "
                         "exist; give --data PATH, or --quick for the shipped default set")
    missing = [c for c in controllers if c.endswith(".pt") and not Path(c).is_file()]
    if missing:
        raise InputError(f"policy file(s) {', '.join(missing)} missing; run from the repository "
                         "root or train them first")
    limit = events_limit or (2 if quick else None)
    events = load_events(data, "test", limit=limit)
    start = time.perf_counter()
    rows = []
    for setting in settings(quick):
        for name in controllers:
            if name == "idm-external" and setting.channel_only:
                continue  # no messages: the same run as at "perfect"
            result = simulate(name, events, 10, net, progress=progress, workers=workers,
                              impairments=setting.impairments if setting.label != "perfect"
                              else None)
            ci = bootstrap_ci(result["events"])
            rows.append({"setting": setting.label, "controller": name,
                         "loss": setting.impairments.loss,
                         "delay_s": setting.impairments.delay_s,
                         "burst": setting.impairments.burst,
                         "sensor_noise": setting.impairments.sensor_noise,
                         "events": len(events),
                         **{k: result["metrics"][k] for k in KEYS},
                         **{f"{k}_lo": ci[k][0] for k in KEYS},
                         **{f"{k}_hi": ci[k][1] for k in KEYS}})
    wall = time.perf_counter() - start
    out.mkdir(parents=True, exist_ok=True)
    _write_csv(out / "robustness.csv", rows)
    write_text_atomic(out / "robustness.md", _markdown(rows, data, len(events), wall, command))
    figures = _figures(out, rows)
    return {"rows": rows, "wall_time_s": wall, "figures": figures}


def _write_csv(path: Path, rows: list[dict]) -> None:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(rows[0]))
    writer.writeheader()
    writer.writerows(rows)
    write_text_atomic(path, buf.getvalue())


def _cell(row: dict, key: str) -> str:
    value, lo, hi = row[key], row[f"{key}_lo"], row[f"{key}_hi"]
    if isinstance(value, int) or key.endswith("count") or key == "collisions":
        return f"{int(value)}"
    if lo != lo:  # nan: a single event
        return f"{value:.3f}"
    return f"{value:.3f} [{lo:.3f}, {hi:.3f}]"


def _markdown(rows: list[dict], data: str, n_events: int, wall: float, command: str) -> str:
    head = ("| setting | controller | headway (s) | jerk (m/s³) | speed (m/s) | TTC<4 s | TTC<1.5 s "
            "| dampening | collisions |\n|---|---|---|---|---|---|---|---|---|")
    lines = [f"# Robustness: V2V delay and loss, sensor noise\n",
             f"command: `{command}`\n" if command else "",
             f"{n_events} events of the test split of {data}, 10 followers; wall time "
             f"{wall:.0f} s. Cells: aggregate over events [95 % bootstrap interval over events]; "
             "one training seed per policy (the shipped file), impairment seed 0.\n", head]
    for r in rows:
        lines.append(f"| {r['setting']} | `{r['controller']}` | "
                     + " | ".join(_cell(r, k) for k in KEYS) + " |")
    return "\n".join(lines) + "\n"


def _figures(out: Path, rows: list[dict]) -> list[str]:
    """Each metric against loss (no delay) and against delay (no loss), one line per
    controller."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    written = []
    for axis, label, pick in (
            ("loss", "message loss probability", lambda r: r["delay_s"] == 0),
            ("delay_s", "message delay (s)", lambda r: r["loss"] == 0)):
        fig, axes = plt.subplots(1, 4, figsize=(16, 3.6))
        for ax, key, name in zip(axes, ("jerk_mps3", "dampening_ratio", "ttc_lt_1_5s_count",
                                        "headway_s"),
                                 ("jerk (m/s³)", "dampening ratio", "TTC < 1.5 s samples",
                                  "headway (s)")):
            for controller in dict.fromkeys(r["controller"] for r in rows):
                points = sorted((r[axis], r[key]) for r in rows if r["controller"] == controller
                                and not r["sensor_noise"] and r["burst"] == 1 and pick(r))
                if controller == "idm-external":  # no messages: flat at its perfect value
                    xs = sorted({r[axis] for r in rows if pick(r) and not r["sensor_noise"]
                                 and r["burst"] == 1})
                    points = [(x, points[0][1]) for x in xs] if points else []
                if points:
                    ax.plot(*zip(*points), marker="o",
                            label=Path(controller).stem if controller.endswith(".pt")
                            else controller)
            ax.set_xlabel(label)
            ax.set_ylabel(name)
            ax.grid(alpha=0.3)
        axes[0].legend(fontsize=7)
        fig.tight_layout()
        name = f"robustness_vs_{'loss' if axis == 'loss' else 'delay'}.png"
        fig.savefig(out / name, dpi=110)
        plt.close(fig)
        written.append(name)
    return written
