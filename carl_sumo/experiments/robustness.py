"""The robustness suite: controllers under V2V delay and loss and sensor noise
(``carl-sumo evaluate --suite robustness --out DIR``).

Every controller runs the NGSIM test split with 10 followers at each impairment setting of
:func:`settings` (:mod:`carl_sumo.control.channel`): message loss from 0 to 100 % at no delay, delay from
0 to 0.5 s without loss, the bursty point (30 % loss in bursts of 3 steps with 0.2 s delay),
and sensor noise, raw and filtered by the followers' trackers (:mod:`carl_sumo.control.sensors`). IDM
(computed in carl-sumo, ``idm-external``) sends no messages, so it runs only where its sensors
change: the perfect setting and the noisy ones. The paper configuration's nominal and robust
CA-TD3 (:data:`SEED_POLICIES`) run with their training seeds 0-4 (one recipe each): their cells
are seed means with a 95 % t interval over seeds. Every other cell is one file's aggregate over
events with a 95 % bootstrap interval over events (:func:`carl_sumo.sim.metrics.bootstrap_ci`).
Draws use impairment seed 0. Files that compute the same policy
(:func:`carl_sumo.learn.policy.policy_fingerprint`: the same configuration and actor weights, e.g.
robust seeds whose validation kept their warm start; at the settings with a perfect channel,
whatever they do on hearing no neighbour) run once per setting.

Writes ``robustness.md`` (with the targets of the robust policy checked), ``robustness.csv``,
``robustness_seeds.csv`` (every seed's run) and two figures (each metric against loss and against
delay). ``--quick``: the shipped default leader set, 2 events, four settings and 2 seeds.
"""

from __future__ import annotations

import csv
import io
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from carl_sumo.control.channel import BURSTY_CHANNEL, Impairments
from carl_sumo.data import load_events
from carl_sumo.errors import InputError
from carl_sumo.files import write_text_atomic
from carl_sumo.sim.metrics import bootstrap_ci
from carl_sumo.learn.policy import policy_fingerprint
from carl_sumo.experiments.simulate import check_impairable, simulate_jobs
from carl_sumo.experiments.suite import DEFAULT_NGSIM

LOSSES = (0.0, 0.1, 0.3, 0.5, 0.8, 1.0)
DELAYS_S = (0.0, 0.1, 0.2, 0.5)
CONTROLLERS = ("idm-external", "ploeg", "ploeg-tuned:h=0.8", "policies/ca_td3_10.pt",
               "policies/ca_td3_10_robust.pt", "policies/ca_td3_ploeg_10.pt")
"""IDM, the textbook Ploeg CACC, the tuned one the product runs on, the paper configuration's
CA-TD3 trained with a perfect channel and with randomised impairments (``--comm-randomize``),
and the product configuration's CA-TD3 (perfect channel)."""
SEED_POLICIES = ("ca_td3_10", "ca_td3_10_robust")
"""Policy stems whose seed files run (seeds 0-4; --quick: 0-1)."""
SEEDS = 5
T_975 = (float("nan"), 12.706, 4.303, 3.182, 2.776, 2.571, 2.447, 2.365, 2.306, 2.262, 2.228)
"""Student's t quantile 0.975 by degrees of freedom (0-10): the 95 % interval over seeds."""
BURSTY = "loss 0.3 in bursts of 3, delay 0.2 s"
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
    out += [Setting(BURSTY, BURSTY_CHANNEL),
            Setting("sensor noise", Impairments(sensor_noise=True)),
            Setting("sensor noise, filtered", Impairments(sensor_noise=True, sensor_filter=True))]
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
    runs = {c: seed_files(c, 2 if quick else SEEDS) for c in controllers}
    for name in controllers:
        check_impairable(name, Impairments(sensor_noise=True))
    jobs = [(setting, name, path) for setting in settings(quick) for name in controllers
            if not (name == "idm-external" and setting.channel_only)  # sends no messages
            for path in runs[name]]
    # files that compute the same policy (e.g. robust seeds that kept their warm start) run once;
    # on a perfect channel what a policy does on hearing nobody does not count
    paths = {path for names in runs.values() for path in names}
    same = {(path, links): policy_fingerprint(Path(path), links) if path.endswith(".pt") else path
            for path in paths for links in (True, False)}

    def key(setting: Setting, path: str) -> tuple[str, str]:
        return setting.label, same[path, not setting.impairments.perfect_channel]

    unique = {}
    for setting, _, path in jobs:
        unique.setdefault(key(setting, path), (setting, path))
    start = time.perf_counter()
    results = simulate_jobs([(path, setting.impairments if setting.label != "perfect" else None)
                             for setting, path in unique.values()], events, 10, net, workers,
                            chunks=max(1, min(2 * workers, len(events) // 20)), progress=progress)
    by_key = dict(zip(unique, results))
    per_job = {(setting.label, name, path): by_key[key(setting, path)]
               for setting, name, path in jobs}
    rows, seed_rows = [], []
    for setting in settings(quick):
        for name in controllers:
            per_file = [per_job[(setting.label, name, path)] for path in runs[name]
                        if (setting.label, name, path) in per_job]
            if not per_file:
                continue
            head = {"setting": setting.label, "controller": name,
                    "loss": setting.impairments.loss, "delay_s": setting.impairments.delay_s,
                    "burst": setting.impairments.burst,
                    "sensor_noise": setting.impairments.sensor_noise,
                    "sensor_filter": setting.impairments.sensor_filter, "events": len(events),
                    "seeds": len(per_file)}
            rows.append({**head, **_cell_values(per_file)})
            if len(per_file) > 1:
                seed_rows += [{**head, "policy": path, **{k: r["metrics"][k] for k in KEYS}}
                              for path, r in zip(runs[name], per_file)]
    wall = time.perf_counter() - start
    out.mkdir(parents=True, exist_ok=True)
    _write_csv(out / "robustness.csv", rows)
    if seed_rows:
        _write_csv(out / "robustness_seeds.csv", seed_rows)
    write_text_atomic(out / "robustness.md", _markdown(rows, data, len(events), wall, command))
    figures = _figures(out, rows)
    return {"rows": rows, "wall_time_s": wall, "figures": figures}


def seed_files(controller: str, k: int) -> list[str]:
    """The files a controller runs: a policy of :data:`SEED_POLICIES` its seed files 0 to k-1
    (``seeds/<stem>_seed<K>.pt`` beside it), anything else itself."""
    path = Path(controller)
    if path.suffix != ".pt" or path.stem not in SEED_POLICIES:
        return [controller]
    files = [path.parent / "seeds" / f"{path.stem}_seed{s}.pt" for s in range(k)]
    missing = [str(f) for f in files if not f.is_file()]
    if missing:
        raise InputError(f"seed file(s) {', '.join(missing)} missing; train them with "
                         f"`carl-sumo train --config recipes/{path.stem}.toml --seed K`")
    return [str(f) for f in files]


def _cell_values(per_file: list[dict]) -> dict[str, float]:
    """Each metric of KEYS with its interval: one file's aggregate with a bootstrap interval over
    events, or the mean over seed files with a 95 % t interval over seeds (and their std)."""
    if len(per_file) == 1:
        ci = bootstrap_ci(per_file[0]["events"])
        return {**{k: per_file[0]["metrics"][k] for k in KEYS},
                **{f"{k}_lo": ci[k][0] for k in KEYS}, **{f"{k}_hi": ci[k][1] for k in KEYS}}
    out: dict[str, float] = {}
    for k in KEYS:
        values = np.array([r["metrics"][k] for r in per_file], dtype=float)
        mean, std = float(values.mean()), float(values.std(ddof=1))
        half = T_975[min(len(values) - 1, len(T_975) - 1)] * std / np.sqrt(len(values))
        out.update({k: mean, f"{k}_lo": mean - half, f"{k}_hi": mean + half, f"{k}_std": std})
    return out


def _write_csv(path: Path, rows: list[dict]) -> None:
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=list(dict.fromkeys(k for r in rows for k in r)))
    writer.writeheader()
    writer.writerows(rows)
    write_text_atomic(path, buf.getvalue())


def _cell(row: dict, key: str) -> str:
    value, lo, hi = row[key], row[f"{key}_lo"], row[f"{key}_hi"]
    if isinstance(value, int) or key.endswith("count") or key == "collisions":
        return f"{int(value)}" if float(value).is_integer() else f"{value:.1f}"
    if lo != lo:  # nan: a single event
        return f"{value:.3f}"
    return f"{value:.3f} [{lo:.3f}, {hi:.3f}]"


def _markdown(rows: list[dict], data: str, n_events: int, wall: float, command: str) -> str:
    head = ("| setting | controller | seeds | headway (s) | jerk (m/s³) | speed (m/s) | TTC<4 s "
            "| TTC<1.5 s | dampening | collisions |\n|---|---|---|---|---|---|---|---|---|---|")
    lines = ["# Robustness: V2V delay and loss, sensor noise\n",
             f"command: `{command}`\n" if command else "",
             f"{n_events} events of the test split of {data}, 10 followers; wall time "
             f"{wall:.0f} s; impairment seed 0. Cells with one seed: the file's aggregate over "
             "events [95 % bootstrap interval over events]; with several: the mean over "
             "training seeds [95 % t interval over seeds].\n", head]
    for r in rows:
        lines.append(f"| {r['setting']} | `{r['controller']}` | {r['seeds']} | "
                     + " | ".join(_cell(r, k) for k in KEYS) + " |")
    lines += ["", *_targets(rows)]
    return "\n".join(lines) + "\n"


def _targets(rows: list[dict]) -> list[str]:
    """The robust policy's targets, checked on these rows (seed means): zero collisions and TTC <
    1.5 s samples at the bursty point with jerk and dampening at most IDM's; with every message
    lost no worse than IDM on the safety metrics; at every setting at most as many TTC < 1.5 s
    samples and collisions as the textbook Ploeg CACC."""
    robust = next((r["controller"] for r in rows if Path(r["controller"]).stem
                   == "ca_td3_10_robust"), None)
    cell = {(r["setting"], r["controller"]): r for r in rows}
    idm = cell.get(("perfect", "idm-external"))
    if robust is None or idm is None or (BURSTY, robust) not in cell:
        return []
    b, lost = cell[(BURSTY, robust)], cell.get(("loss 1", robust))
    safety = ("collisions", "ttc_lt_1_5s_count", "ttc_lt_4s_count")
    checks = [(f"{BURSTY}: no collision, no TTC < 1.5 s",
               b["collisions"] == 0 and b["ttc_lt_1_5s_count"] == 0,
               f"{b['collisions']:g} / {b['ttc_lt_1_5s_count']:g}"),
              (f"{BURSTY}: jerk and dampening at most IDM's",
               b["jerk_mps3"] <= idm["jerk_mps3"] and b["dampening_ratio"] <= idm["dampening_ratio"],
               f"{b['jerk_mps3']:.3f} / {b['dampening_ratio']:.3f} vs IDM {idm['jerk_mps3']:.3f}"
               f" / {idm['dampening_ratio']:.3f}")]
    if lost is not None:
        checks.append(("every message lost: no worse than IDM on collisions, TTC < 1.5 s, TTC < 4 s",
                       all(lost[k] <= idm[k] for k in safety),
                       " / ".join(f"{lost[k]:g}" for k in safety) + " vs IDM "
                       + " / ".join(f"{idm[k]:g}" for k in safety)))
    worse = [s for (s, c), r in cell.items() if c == robust and (s, "ploeg") in cell and any(
        r[k] > cell[(s, "ploeg")][k] for k in ("collisions", "ttc_lt_1_5s_count"))]
    checks.append(("at every setting at most `ploeg`'s collisions and TTC < 1.5 s samples",
                   not worse, "worse at: " + ", ".join(worse) if worse else "everywhere"))
    out = [f"## Targets of the robust policy (`{robust}`, seed means)\n",
           "| target | met | measured |", "|---|---|---|"]
    out += [f"| {name} | {'yes' if ok else 'no'} | {measured} |" for name, ok, measured in checks]
    return out


def _figures(out: Path, rows: list[dict]) -> list[str]:
    """Each metric against loss (no delay) and against delay (no loss), one line per
    controller."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from carl_sumo.experiments.figures import save_png

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
        save_png(fig, out / name, dpi=110)  # atomically; closes the figure
        written.append(name)
    return written
