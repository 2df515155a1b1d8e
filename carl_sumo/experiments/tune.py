"""``carl-sumo tune ploeg|acc``: a constant-time-gap law's gains tuned on the training events, in
SUMO, for one plant (the ideal plant, or a fleet with lag and V2V delay: ``--plant real`` ...).

With a plant (``string_stable``), a point must also be string stable on every class of the fleet:
‖Γ‖∞ ≤ 1 over the links behind a follower (a CACC's V2V links), for each class at both ends of
its lag and dead-time ranges, computed with the exact discrete-time transfer function of the law
(:func:`carl_sumo.control.transfer.robust_hinf`, which the measurement in SUMO matches to 1e-4);
gains that are not are not simulated. One gain set serves the whole fleet (robust tuning).

For each time gap h, a grid of (kp, kd) runs on every training event (10 followers by default)
through the same SUMO loop as ``simulate``. A point is **safe** when it is at least as safe as
the textbook gains at the same h on the same events:

- no collision on any event, and
- no more samples with TTC < 1.5 s (all followers, all events) than the textbook gains, and
- a mean time headway at most ``headway_tolerance`` above the textbook gains' (a tuned controller
  must still follow at its time gap, not buy comfort with distance).

Among safe points the chosen one minimises the objective

    J = jerk / jerk_textbook + dampening / dampening_textbook

(mean |jerk| in m/s³ and the dampening ratio, each relative to the textbook gains kp = 0.2,
kd = 0.7 at the same h and on the same events; J = 2 at the textbook). When the best safe point
lies on an edge of the grid that can still grow, the grid is extended one step beyond that edge
(kp and kd multiplied or divided by ``GROWTH``) and searched again, up to ``max_extensions`` times,
so the search is shown not to stop at its edge (``interior`` in the result says whether it did).

The result file (``policies/ploeg_tuned.json``) holds the chosen gains per h with their metrics,
every grid point (which gains collide), the command, data, split, objective and date.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from datetime import date
from pathlib import Path
from typing import Callable

from carl_sumo.control.cacc import TEXTBOOK, TUNED_FILE, PloegParams
from carl_sumo.control.channel import Impairments
from carl_sumo.control.transfer import robust_hinf
from carl_sumo.errors import InputError
from carl_sumo.sim.metrics import METRIC_KEYS, aggregate
from carl_sumo.files import write_text_atomic
from carl_sumo.sim.sumo import DEFAULT_NET

GROWTH = 1.5
"""Factor by which the grid grows beyond an edge (kp·1.5 or kp/1.5, the same for kd)."""

OBJECTIVE = ("J = jerk/jerk_textbook + dampening/dampening_textbook at the same h, on the "
             "training events; lower is better")


@dataclass(frozen=True)
class TuneConfig:
    """What ``carl-sumo tune ploeg`` searches and on which events (units in the names)."""

    gaps_s: tuple[float, ...] = (0.6, 0.8, 1.0, 1.2)
    kp: tuple[float, ...] = (0.1, 0.15, 0.2, 0.3, 0.45, 0.675, 1.0125)  # x1.5 steps
    kd: tuple[float, ...] = (0.5, 0.7, 1.0, 1.4, 2.1, 3.15, 4.725)
    n_followers: int = 10
    headway_tolerance: float = 0.05     # allowed rise of the mean headway over the textbook's (-)
    max_extensions: int = 3
    data: str = ""
    split: str = "train"
    net: str = str(DEFAULT_NET)
    workers: int = 2
    command: str = ""
    law: str = "ploeg"                  # ploeg (CACC) or acc (radar only)
    impairments: Impairments | None = None  # the plant (fleet) and V2V channel tuned for
    warmup_s: float = 0.0               # every event first settles this long (s)
    string_stable: bool = False         # also require hinf <= 1 on every class of the fleet

    @property
    def plant_key(self) -> str:
        return self.impairments.plant_key if self.impairments is not None else "ideal"

    def params(self, h: float, kp: float, kd: float) -> PloegParams:
        return PloegParams(h, kp, kd, feed_forward=self.law == "ploeg")

    def robust_hinf(self, h: float, kp: float, kd: float) -> float:
        """‖Γ‖∞ of the exact discrete law over the links behind a follower (a CACC's V2V links)
        of every class of the fleet at both ends of its ranges, each in a platoon of its own
        class (:func:`carl_sumo.control.transfer.robust_hinf`)."""
        imp = self.impairments
        plant = imp.plant if imp is not None else None
        corners = plant.corners() if plant is not None else [(0.0, 0)]
        return robust_hinf(h, kp, kd, corners, imp.delay_steps if imp is not None else 0,
                           cacc=self.law == "ploeg")


@dataclass
class GridPoint:
    h: float
    kp: float
    kd: float
    metrics: dict[str, float] = field(default_factory=dict)
    max_ttc15_event: int = 0
    colliding_events: int = 0
    objective: float = math.nan
    safe: bool = False
    hinf: float = math.nan            # robust ‖Γ‖∞ (TuneConfig.robust_hinf), with string_stable


# ------------------------------------------------------------------------------- running
_EVENTS: list = []
_INIT_ERROR: Exception | None = None
"""What a pool worker's start-up raised: its first task raises it again, so the command stops
with it (a ``multiprocessing.Pool`` would replace a worker whose initializer fails, forever)."""


def _worker_init(data: str, split: str, limit: int | None, warmup_s: float = 0.0,
                 pool: bool = False) -> None:
    """The events of a tuning worker (``pool``: a pool's process, which dies with its command)
    or of this process."""
    from carl_sumo.data import load_events
    from carl_sumo.scale.workers import pool_worker_init, worker_init

    global _EVENTS, _INIT_ERROR
    try:
        pool_worker_init() if pool else worker_init()
        _EVENTS = [e.with_warmup(warmup_s) for e in load_events(data, split, limit=limit)]
    except Exception as exc:  # noqa: BLE001 - handed to the command by the first task
        if not pool:
            raise
        _INIT_ERROR = exc


def _run_point(task: tuple) -> tuple[str, list[dict]]:
    """Per-event metrics of one controller name on a slice of this worker's events."""
    from carl_sumo.experiments.simulate import score_events

    if _INIT_ERROR is not None:
        raise _INIT_ERROR
    name, start, stop, n, net, impairments = task
    return name, score_events(name, _EVENTS[start:stop], n, net, impairments=impairments)


def _score(point: GridPoint, per_event: list[dict]) -> None:
    point.metrics = aggregate(per_event)
    point.max_ttc15_event = max(int(e["ttc_lt_1_5s_count"]) for e in per_event)
    point.colliding_events = sum(1 for e in per_event if e["collisions"] > 0)


class Runner:
    """Evaluates grid points on all events in a pool of worker processes (or in this one)."""

    def __init__(self, cfg: TuneConfig, n_events: int, limit: int | None,
                 progress: Callable[[int], None] | None):
        self.cfg, self.n_events, self.progress = cfg, n_events, progress
        workers = max(1, min(cfg.workers, n_events))
        self.chunks = [(i * n_events // (2 * workers), (i + 1) * n_events // (2 * workers))
                       for i in range(2 * workers)]
        self.chunks = [c for c in self.chunks if c[1] > c[0]]
        if workers > 1:
            import multiprocessing as mp

            self.pool = mp.get_context("spawn").Pool(
                workers, initializer=_worker_init,
                initargs=(cfg.data, cfg.split, limit, cfg.warmup_s, True))
        else:
            self.pool = None
            _worker_init(cfg.data, cfg.split, limit, cfg.warmup_s)

    def run(self, points: list, namer: Callable[[object], str] | None = None) -> None:
        """Score every point on all events (its ``metrics``); ``namer``: its controller name
        (default: the gains of a :class:`GridPoint` under ``cfg.law``)."""
        namer = namer or (lambda p: self.cfg.params(p.h, p.kp, p.kd).name())
        names = {namer(p): p for p in points}
        tasks = [(name, a, b, self.cfg.n_followers, self.cfg.net, self.cfg.impairments)
                 for name in names for a, b in self.chunks]
        parts: dict[str, list[tuple[int, list[dict]]]] = {name: [] for name in names}
        outputs = self.pool.imap(_run_point, tasks) if self.pool is not None \
            else map(_run_point, tasks)
        for task, (name, per_event) in zip(tasks, outputs):
            parts[name].append((task[1], per_event))
            if len(parts[name]) == len(self.chunks):
                _score(names[name], [e for _, chunk in sorted(parts[name], key=lambda x: x[0])
                                     for e in chunk])
                if self.progress is not None:
                    self.progress(1)

    def close(self, failed: bool = False) -> None:
        """Stop the pool: after its tasks, or at once when the run ``failed``."""
        if self.pool is not None:
            self.pool.terminate() if failed else self.pool.close()
            self.pool.join()


# -------------------------------------------------------------------------------- search
def judge(point: GridPoint, reference: GridPoint, cfg: TuneConfig) -> None:
    if not point.metrics:  # not simulated: string unstable in theory
        point.safe = False
        return
    m, ref = point.metrics, reference.metrics
    point.objective = m["jerk_mps3"] / ref["jerk_mps3"] + \
        m["dampening_ratio"] / ref["dampening_ratio"]
    point.safe = (m["collisions"] == 0 and m["ttc_lt_1_5s_count"] <= ref["ttc_lt_1_5s_count"]
                  and m["headway_s"] <= ref["headway_s"] * (1.0 + cfg.headway_tolerance)
                  and (not cfg.string_stable or point.hinf <= 1.0 + 1e-9))


def _grown(values: list[float], at_low: bool, at_high: bool) -> list[float]:
    values = list(values)
    if at_low:
        values.insert(0, round(values[0] / GROWTH, 4))
    if at_high:
        values.append(round(values[-1] * GROWTH, 4))
    return values


def tune_gap(h: float, cfg: TuneConfig, runner: Runner,
             known: dict[tuple[float, float], GridPoint] | None = None
             ) -> tuple[GridPoint | None, list[GridPoint], bool, GridPoint]:
    """Search one time gap: (best safe point or None, every point, interior?, textbook point).
    ``known``: points of this h already measured (by an earlier run on the same events)."""
    kp, kd = sorted(set(cfg.kp)), sorted(set(cfg.kd))
    points: dict[tuple[float, float], GridPoint] = dict(known or {})
    reference = GridPoint(h, TEXTBOOK.kp, TEXTBOOK.kd)
    for extension in range(cfg.max_extensions + 1):
        todo = [GridPoint(h, p, d) for p in kp for d in kd if (p, d) not in points]
        if (TEXTBOOK.kp, TEXTBOOK.kd) not in points and not any(
                (t.kp, t.kd) == (TEXTBOOK.kp, TEXTBOOK.kd) for t in todo):
            todo.append(reference)
        if cfg.string_stable:  # only gains that are string stable in theory are simulated
            for t in todo:
                t.hinf = cfg.robust_hinf(t.h, t.kp, t.kd)
        runner.run([t for t in todo if not cfg.string_stable or t.hinf <= 1.0 + 1e-9
                    or (t.kp, t.kd) == (TEXTBOOK.kp, TEXTBOOK.kd)])
        for point in todo:
            points[(point.kp, point.kd)] = point
        reference = points[(TEXTBOOK.kp, TEXTBOOK.kd)]
        for point in points.values():
            judge(point, reference, cfg)
        safe = [p for p in points.values() if p.safe and p.kp in kp and p.kd in kd]
        if not safe:
            return None, sorted(points.values(), key=lambda p: (p.kp, p.kd)), False, reference
        best = min(safe, key=lambda p: p.objective)
        edges = (best.kp == kp[0], best.kp == kp[-1], best.kd == kd[0], best.kd == kd[-1])
        if not any(edges):
            return best, sorted(points.values(), key=lambda p: (p.kp, p.kd)), True, reference
        if extension == cfg.max_extensions:
            break
        kp, kd = _grown(kp, edges[0], edges[1]), _grown(kd, edges[2], edges[3])
    return best, sorted(points.values(), key=lambda p: (p.kp, p.kd)), False, reference


def _point_row(p: GridPoint) -> dict:
    return {"h": p.h, "kp": p.kp, "kd": p.kd, "objective": p.objective, "safe": p.safe,
            "hinf": p.hinf, "colliding_events": p.colliding_events,
            "max_ttc15_per_event": p.max_ttc15_event, **p.metrics}


def reusable_points(path: Path, cfg: TuneConfig, n_events: int) -> list[GridPoint]:
    """The grid points of an earlier result file measured on the same events and platoon
    (``--reuse``): simulations are deterministic, so they need not run again. InputError when
    the file was made on other data."""
    try:
        payload = json.loads(Path(path).read_text())
        same = (payload["data"], payload["split"], payload["events"], payload["followers"],
                payload.get("controller", "ploeg"), payload.get("plant", "ideal"),
                payload.get("warmup_s", 0.0)) == \
            (cfg.data, cfg.split, n_events, cfg.n_followers, cfg.law, cfg.plant_key, cfg.warmup_s)
        rows = payload["grid"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise InputError(f"--reuse {path}: not a result file of `carl-sumo tune ploeg` "
                         f"({type(exc).__name__})") from None
    if not same:
        raise InputError(f"--reuse {path} was measured on other events or another platoon "
                         f"({payload['data']}, split {payload['split']}, {payload['events']} "
                         f"events, {payload['followers']} followers); run without --reuse")
    points = []
    for row in rows:
        point = GridPoint(row["h"], row["kp"], row["kd"],
                          max_ttc15_event=row["max_ttc15_per_event"],
                          colliding_events=row["colliding_events"])
        point.metrics = {k: row[k] for k in METRIC_KEYS} if METRIC_KEYS[0] in row else {}
        point.hinf = row.get("hinf", math.nan)
        points.append(point)
    return points


def tune_ploeg(cfg: TuneConfig, out: Path = TUNED_FILE, events_limit: int | None = None,
               progress: bool = False, log: Callable[[str], None] | None = None,
               reuse: Path | None = None) -> dict:
    """Tune every time gap of ``cfg`` and write the result file ``out`` (atomically); ``log``
    receives one line per time gap as it is done; ``reuse`` an earlier result file whose points
    are not simulated again. After each time gap the result so far is written to
    ``<out>.partial.json`` (removed at the end), which ``--reuse`` accepts after an interruption."""
    from carl_sumo.data import load_events

    if cfg.split in ("test", "us101", "all"):
        raise InputError(f"tuning on split {cfg.split!r} is not allowed: the test split and the "
                         "cross-site events are for scoring only; use --split train")
    events = load_events(cfg.data, cfg.split, limit=events_limit)
    if not events:
        raise InputError(f"{cfg.data} has no {cfg.split} events to tune on")
    reuse = reusable_points(reuse, cfg, len(events)) if reuse is not None else None
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(desc=f"tune {cfg.law}", unit="gains", leave=False)
    start = time.perf_counter()
    runner = Runner(cfg, len(events), events_limit, bar.update if bar is not None else None)
    entries, grid = [], []
    partial = Path(out).with_suffix(".partial.json")

    def result() -> dict:
        return {"controller": cfg.law, "plant": cfg.plant_key, "warmup_s": cfg.warmup_s,
                "string_stable": cfg.string_stable,
                "command": cfg.command, "date": date.today().isoformat(),
                "data": cfg.data, "split": cfg.split, "events": len(events),
                "followers": cfg.n_followers, "objective": OBJECTIVE,
                "constraints": {"collisions": 0,
                                "ttc_lt_1_5s_count": "at most the textbook gains' at the same h",
                                "headway_at_most_textbook_times": 1.0 + cfg.headway_tolerance},
                "grid_growth": GROWTH,
                "config": {k: v for k, v in asdict(cfg).items() if k != "impairments"},
                "wall_time_s": round(time.perf_counter() - start, 1),
                "entries": entries, "grid": grid}

    failed = True
    try:
        for h in cfg.gaps_s:
            known = {(p.kp, p.kd): p for p in (reuse or []) if p.h == h}
            best, points, interior, reference = tune_gap(h, cfg, runner, known)
            grid += [_point_row(p) for p in points]
            entry = {"h": h, "kp": best.kp if best else None, "kd": best.kd if best else None,
                     "interior": interior, "points": len(points),
                     "objective": best.objective if best else None,
                     "metrics": best.metrics if best else None,
                     "textbook": {"kp": reference.kp, "kd": reference.kd,
                                  "safe": reference.safe, "metrics": reference.metrics,
                                  "max_ttc15_per_event": reference.max_ttc15_event}}
            entries.append(entry)
            write_text_atomic(partial, json.dumps(result(), indent=1, allow_nan=True) + "\n")
            if log is not None:
                chosen = f"kp = {best.kp:g}, kd = {best.kd:g}, J = {best.objective:.3f}" if best \
                    else "no safe gains"
                log(f"h = {h:g} s: {chosen} ({len(points)} gains, interior: {interior}; "
                    f"{time.perf_counter() - start:.0f} s)")
        failed = False
    finally:
        runner.close(failed)
        if bar is not None:
            bar.close()
    return write_result(result(), out, partial)


def tune_over_gaps(cfg: TuneConfig, out: Path, events_limit: int | None,
                   header: Callable[[int], dict],
                   search: Callable[[float, "Runner"], tuple[list[dict], dict, str]],
                   log=None) -> dict:
    """The driver of a law's tuning (``tune mpf``, ``tune mpc``): every time gap of ``cfg`` in
    turn on the events, ``search(h, runner)`` -> (the gap's grid rows, its entry, a log line);
    the result (``header(events)`` with the wall time, the entries and the rows) is written to
    ``<out>.partial.json`` after each gap and to ``out`` at the end (atomically)."""
    from carl_sumo.data import load_events

    events = load_events(cfg.data, cfg.split, limit=events_limit)
    if not events:
        raise InputError(f"{cfg.data} has no {cfg.split} events to tune on")
    start = time.perf_counter()
    runner = Runner(cfg, len(events), events_limit, None)
    entries, rows = [], []
    partial = Path(out).with_suffix(".partial.json")

    def result() -> dict:
        return {**header(len(events)), "wall_time_s": round(time.perf_counter() - start, 1),
                "entries": entries, "grid": rows}

    failed = True
    try:
        for h in cfg.gaps_s:
            gap_rows, entry, line = search(h, runner)
            rows += gap_rows
            entries.append(entry)
            write_text_atomic(partial, json.dumps(result(), indent=1, allow_nan=True) + "\n")
            if log is not None:
                log(f"{line}; {time.perf_counter() - start:.0f} s)")
        failed = False
    finally:
        runner.close(failed)
    return write_result(result(), out, partial)


def write_result(payload: dict, out: Path, partial: Path) -> dict:
    """Write a finished tuning's ``payload`` to ``out`` (atomically) and drop the partial file
    that was rewritten after every gap; returns ``payload``."""
    write_text_atomic(Path(out), json.dumps(payload, indent=1, allow_nan=True) + "\n")
    partial.unlink(missing_ok=True)
    return payload


def format_result(payload: dict) -> str:
    """The chosen gains per h beside the textbook's, as a Markdown table."""
    lines = ["| h (s) | kp | kd | interior | headway (s) | jerk (m/s³) | dampening | TTC<1.5 s | "
             "J | textbook jerk | textbook dampening | textbook safe |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for e in payload["entries"]:
        t = e["textbook"]["metrics"]
        if e["kp"] is None:
            lines.append(f"| {e['h']:g} | none safe | | | | | | | | {t['jerk_mps3']:.3f} | "
                         f"{t['dampening_ratio']:.3f} | {e['textbook']['safe']} |")
            continue
        m = e["metrics"]
        lines.append(f"| {e['h']:g} | {e['kp']:g} | {e['kd']:g} | {e['interior']} | "
                     f"{m['headway_s']:.3f} | {m['jerk_mps3']:.3f} | {m['dampening_ratio']:.3f} | "
                     f"{m['ttc_lt_1_5s_count']} | {e['objective']:.3f} | {t['jerk_mps3']:.3f} | "
                     f"{t['dampening_ratio']:.3f} | {e['textbook']['safe']} |")
    return "\n".join(lines)


def grid_figure(payload: dict, path: Path) -> Path:
    """One panel per time gap: the objective J over (kp, kd) on log axes; colliding gains as
    red crosses, other unsafe gains as orange rings, the chosen gains as a star, the textbook
    gains as a square. Written through a temporary file."""
    from carl_sumo.experiments.figures import pyplot, save_png

    plt = pyplot()
    gaps = [e["h"] for e in payload["entries"]]
    fig, axes = plt.subplots(1, len(gaps), figsize=(4.2 * len(gaps), 4), squeeze=False,
                             layout="constrained")
    for ax, entry in zip(axes[0], payload["entries"]):
        grid = [g for g in payload["grid"] if g["h"] == entry["h"]]
        sc = ax.scatter([g["kp"] for g in grid], [g["kd"] for g in grid],
                        c=[g["objective"] for g in grid], cmap="viridis_r", s=120,
                        vmin=1.0, vmax=2.6)
        for g in grid:
            if "collisions" not in g:  # not simulated: string unstable in theory
                ax.plot(g["kp"], g["kd"], "+", color="grey", ms=12, mew=2)
            elif g["collisions"] > 0:
                ax.plot(g["kp"], g["kd"], "x", color="red", ms=12, mew=2)
            elif not g["safe"]:
                ax.plot(g["kp"], g["kd"], "o", mfc="none", mec="orange", ms=14, mew=2)
        ax.plot(TEXTBOOK.kp, TEXTBOOK.kd, "s", mfc="none", mec="black", ms=15, mew=1.5)
        if entry["kp"] is not None:
            ax.plot(entry["kp"], entry["kd"], "*", color="white", mec="black", ms=16)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("kp (1/s²)")
        ax.set_ylabel("kd (1/s)")
        ax.set_title(f"h = {entry['h']:g} s")
    fig.colorbar(sc, ax=axes[0].tolist(), label="J = jerk/jerk_tb + damp./damp._tb")
    fig.suptitle(f"{payload.get('controller', 'ploeg')} gains on the training events "
                 f"({payload.get('plant', 'ideal')}): red x collides, orange o unsafe (TTC<1.5 s, "
                 "headway or string stability), grey + string unstable (not run), square "
                 "textbook, star chosen", fontsize=9)
    return save_png(fig, path)


def parse_values(text: str, option: str) -> tuple[float, ...]:
    """Positive numbers separated by commas; InputError otherwise."""
    try:
        values = tuple(float(x) for x in text.split(",") if x.strip())
    except ValueError:
        values = ()
    if not values or any(not (math.isfinite(v) and v > 0) for v in values):
        raise InputError(f"{option} must be positive numbers separated by commas, got {text!r}")
    return values

