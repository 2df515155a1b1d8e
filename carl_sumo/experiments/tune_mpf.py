"""``carl-sumo tune mpf``: the feed-forward weights of the multi-predecessor CACC (``mpf``,
:mod:`carl_sumo.control.feed_forward`) tuned for a plant on the training events, one weight set
for the whole fleet, on top of a fixed base law (default ``product-base`` without its washout
``wo``, which acts only on a learned term: Ploeg's CACC with the gains tuned for the real fleet,
cars at 0.6 s and trucks at 0.8 s, with its layers).

For each time gap h (default: the base's), the grid holds the weights of r = 2 vehicles heard,
(1 - w2, w2), and of r = 3, (1 - w2 - w3, w2, w3), for every w2 and w3 of the grid with
w1 = 1 - w2 - w3 > 0; the base itself (r = 1, Ploeg's law) is the reference. As
:mod:`carl_sumo.experiments.tune` does for the gains, each point runs on every training event
through the same SUMO loop as ``simulate``; a point is **safe** when, on those events, it has no
collision, no more TTC < 1.5 s samples than the base, a mean headway at most
``headway_tolerance`` above the base's and, with a plant, ‖Γ‖∞ ≤ 1 on every class (weights that
are not are not simulated). Among safe points (the base among them) the chosen one minimises

    J = jerk / jerk_base + dampening / dampening_base      (J = 2 at the base).

‖Γ‖∞ on every class: the multi-predecessor platoon is a recurrence in the vehicle index, so the
gain of a link depends on the r links before it; each class of the fleet, at both ends of its
lag and dead-time ranges, is a homogeneous platoon of ``n_followers`` vehicles at its own time
gap (a heavy class at the base's ``ht``), and the largest exact discrete |Γ_i| over its links
behind a follower (:func:`carl_sumo.control.transfer.robust_hinf` with the weights, from
:func:`carl_sumo.control.transfer.gamma_links_discrete`) must be at most 1, as the robust check
of Ploeg's gains takes each class in a platoon of its own class.

When the best safe point lies on an edge of the grid that can still move (w2 or w3 halved at
the low edge, one grid step more at the high edge, w1 staying positive; the base winning counts
as the low edge of w2), the grid is extended and searched again, up to ``max_extensions`` times
(``interior`` in the result says whether the search stopped inside its grid).

The result (``policies/mpf_tuned_<plant>.json``, beside the tuned Ploeg gains) holds per h the
chosen law's name (``mpf-tuned:h=H`` runs it), its metrics and the base's, and every grid point.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, replace
from datetime import date
from pathlib import Path

from carl_sumo.control.cacc import PloegParams, parse_ploeg
from carl_sumo.control.ploeg_names import MAX_HEARD, without_washout
from carl_sumo.control.transfer import robust_hinf
from carl_sumo.errors import InputError
from carl_sumo.experiments.tune import Runner, TuneConfig, judge, tune_over_gaps
from carl_sumo.sim.vehicle import VEHICLE_CLASSES

DEFAULT_BASE = "product-base"
"""The base law whose feed-forward weights are tuned (its washout ``wo`` left out)."""
HEARD = (2, 3)
"""Vehicles heard r of the grid."""
W2 = (0.1, 0.2, 0.3, 0.4, 0.5)
"""Starting grid of w2, the weight of the command two ahead (-)."""
W3 = (0.1, 0.2)
"""Starting grid of w3, the weight of the command three ahead (r = 3; -)."""
MIN_WEIGHT = 0.025
"""The low edge of a weight's grid is not halved below this (-)."""
OBJECTIVE = ("J = jerk/jerk_base + dampening/dampening_base at the same h, on the training "
             "events; lower is better")


@dataclass(frozen=True)
class MpfGrid:
    """What ``carl-sumo tune mpf`` searches besides :class:`TuneConfig` (its gaps, events,
    plant, constraints)."""

    base: str = DEFAULT_BASE
    heard: tuple[int, ...] = HEARD
    w2: tuple[float, ...] = W2
    w3: tuple[float, ...] = W3

    def base_params(self, h: float | None = None) -> PloegParams:
        """The base law (no washout) at the time gap h (None: its own); InputError when the base
        is not a CACC (Ploeg) name."""
        name = without_washout(self.base)
        if name.split(":")[0] != "ploeg":
            raise InputError(f"--base {self.base!r}: the base of mpf must be Ploeg's CACC with "
                             "its gains (ploeg:h=H:kp=KP:kd=KD:..., or a preset such as "
                             "product-base)")
        p = parse_ploeg(name)
        return p if h is None else replace(p, time_gap_s=h)

    def check(self, n_followers: int) -> None:
        """InputError (one line) for r outside 2..MAX_HEARD or above the platoon, or weights
        that leave nothing of 1 to w1."""
        for r in self.heard:
            if not (2 <= r <= min(MAX_HEARD, 3)):
                raise InputError(f"--heard {r}: the grid holds r = 2 or 3 vehicles heard")
            if r > max(n_followers - 1, 1):
                raise InputError(f"--heard {r}: in a platoon of {n_followers} followers the last "
                                 f"one has {max(n_followers - 1, 0)} ahead that send; give r ≤ "
                                 f"{max(n_followers - 1, 1)} or more --vehicles")
        if not candidates(self.heard, self.w2, self.w3):
            raise InputError("--w2/--w3 leave no weights with w1 = 1 - w2 - w3 > 0")


def candidates(heard: tuple[int, ...], w2s: tuple[float, ...] | list[float],
               w3s: tuple[float, ...] | list[float]) -> list[tuple[float, ...]]:
    """The weight sets (w1, ..., wr) of the grid: w1 = what w2 (and w3) leave of 1, above 0."""
    out = []
    for r in sorted(set(heard)):
        for w2 in sorted(set(w2s)):
            for w3 in (sorted(set(w3s)) if r == 3 else [0.0]):
                w1 = round(1.0 - w2 - w3, 6)
                if w1 > 0:
                    out.append((w1, w2, w3) if r == 3 else (w1, w2))
    return out


@dataclass
class MpfPoint:
    h: float
    weights: tuple[float, ...]
    metrics: dict[str, float] = field(default_factory=dict)
    max_ttc15_event: int = 0
    colliding_events: int = 0
    objective: float = math.nan
    safe: bool = False
    hinf: float = math.nan            # robust ‖Γ‖∞ over the classes, with string_stable


def law(base: PloegParams, weights: tuple[float, ...]) -> PloegParams:
    """The base with the feed-forward weights (``(1,)``: the base itself)."""
    return replace(base, weights=tuple(weights))


def class_hinf(params: PloegParams, cfg: TuneConfig) -> float:
    """The largest ‖Γ‖∞ of the law over the classes of the plant, each at both ends of its
    ranges in a homogeneous platoon of ``cfg.n_followers`` at its own time gap (a heavy class at
    ``ht``); the ideal plant: vehicles without lag."""
    imp = cfg.impairments
    plant = imp.plant if imp is not None else None
    delay = imp.delay_steps if imp is not None else 0
    classes = plant.classes if plant is not None else [None]
    worst = 0.0
    for name in classes:
        corners = plant.class_corners(name) if name is not None else [(0.0, 0)]
        h = params.chain_gap_s(VEHICLE_CLASSES[name].b_max_mps2 if name is not None else None)
        worst = max(worst, robust_hinf(h, params.kp, params.kd, corners, delay,
                                       weights=params.weights, n_links=cfg.n_followers))
    return worst


def _grow(values: list[float], low: bool, high: bool, room: float) -> list[float]:
    """One step more at the low (halved) or high (one grid step up, below ``room``) edge."""
    values = sorted(set(values))
    step = values[-1] - values[-2] if len(values) > 1 else 0.1
    if low and values[0] / 2 >= MIN_WEIGHT:
        values.insert(0, round(values[0] / 2, 4))
    if high and values[-1] + step < room:
        values.append(round(values[-1] + step, 4))
    return values


def _edges(best: MpfPoint, w2s: list[float], w3s: list[float]) -> tuple[bool, ...]:
    """(w2 low, w2 high, w3 low, w3 high): the edges of the grid the best point lies on."""
    w = best.weights
    if len(w) == 1:  # the base: no feed-forward beats it, so try less of it
        return True, False, False, False
    w2, w3 = w[1], w[2] if len(w) > 2 else None
    return (w2 == w2s[0], w2 == w2s[-1], w3 is not None and w3 == w3s[0],
            w3 is not None and w3 == w3s[-1])


def tune_gap_weights(h: float, cfg: TuneConfig, grid: MpfGrid, runner: Runner
                     ) -> tuple[MpfPoint | None, list[MpfPoint], bool, MpfPoint]:
    """Search one time gap: (best safe point or None, every point, interior?, the base's)."""
    base = grid.base_params(h)
    w2s, w3s = sorted(set(grid.w2)), sorted(set(grid.w3))
    points: dict[tuple[float, ...], MpfPoint] = {}
    best, interior = None, False
    for extension in range(cfg.max_extensions + 1):
        todo = [MpfPoint(h, w) for w in [(1.0,)] + candidates(grid.heard, w2s, w3s)
                if w not in points]
        for t in todo:
            t.hinf = class_hinf(law(base, t.weights), cfg) if cfg.string_stable else math.nan
        runner.run([t for t in todo if not cfg.string_stable or t.hinf <= 1.0 + 1e-9
                    or t.weights == (1.0,)], lambda p: law(base, p.weights).name())
        points.update({t.weights: t for t in todo})
        reference = points[(1.0,)]
        for point in points.values():
            judge(point, reference, cfg)
        current = set(candidates(grid.heard, w2s, w3s)) | {(1.0,)}
        safe = [p for p in points.values() if p.safe and p.weights in current]
        if not safe:
            return None, _sorted(points), False, reference
        best = min(safe, key=lambda p: p.objective)
        edges = _edges(best, w2s, w3s)
        room = 1.0 - (best.weights[2] if len(best.weights) > 2 else 0.0)
        grown2 = _grow(w2s, edges[0], edges[1], room)
        grown3 = _grow(w3s, edges[2], edges[3], 1.0 - best.weights[1]) \
            if len(best.weights) > 2 else w3s
        interior = grown2 == w2s and grown3 == w3s
        if interior or extension == cfg.max_extensions:
            break
        w2s, w3s = grown2, grown3
    return best, _sorted(points), interior, points[(1.0,)]


def _sorted(points: dict[tuple[float, ...], MpfPoint]) -> list[MpfPoint]:
    return sorted(points.values(), key=lambda p: (len(p.weights), p.weights[1:]))


def _row(p: MpfPoint, base: PloegParams) -> dict:
    return {"h": p.h, "r": len(p.weights), "weights": list(p.weights),
            "name": law(base, p.weights).name(), "objective": p.objective, "safe": p.safe,
            "hinf": p.hinf, "colliding_events": p.colliding_events,
            "max_ttc15_per_event": p.max_ttc15_event, **p.metrics}


def _entry(h: float, best: MpfPoint | None, points: list, interior: bool, reference: MpfPoint,
           base: PloegParams, base_h: float) -> dict:
    """The result of one time gap: the chosen law (``mpf-tuned:h=H`` reads ``name``)."""
    chosen = law(base, best.weights) if best is not None else None
    return {"h": h, "base_h": base_h,
            "kp": base.kp if best else None, "kd": base.kd if best else None,
            "r": len(best.weights) if best else None,
            "weights": list(best.weights) if best else None,
            "name": chosen.name() if chosen else None, "interior": interior,
            "points": len(points), "objective": best.objective if best else None,
            "hinf": best.hinf if best else None, "metrics": best.metrics if best else None,
            "base": {"name": base.name(), "safe": reference.safe, "hinf": reference.hinf,
                     "metrics": reference.metrics,
                     "max_ttc15_per_event": reference.max_ttc15_event}}


def tune_mpf(cfg: TuneConfig, grid: MpfGrid, out: Path, events_limit: int | None = None,
             log=None) -> dict:
    """Tune the weights at every time gap of ``cfg`` and write the result file ``out``
    (atomically; after each gap the result so far to ``<out>.partial.json``, removed at the
    end); ``log`` receives one line per gap."""
    if cfg.split in ("test", "us101", "all"):
        raise InputError(f"tuning on split {cfg.split!r} is not allowed: the test split and the "
                         "cross-site events are for scoring only; use --split train")
    grid.check(cfg.n_followers)
    base_h = grid.base_params().time_gap_s

    def header(events: int) -> dict:
        return {"controller": "mpf", "plant": cfg.plant_key, "warmup_s": cfg.warmup_s,
                "string_stable": cfg.string_stable, "base": grid.base,
                "command": cfg.command, "date": date.today().isoformat(), "data": cfg.data,
                "split": cfg.split, "events": events, "followers": cfg.n_followers,
                "objective": OBJECTIVE,
                "constraints": {"collisions": 0, "ttc_lt_1_5s_count": "at most the base's",
                                "headway_at_most_base_times": 1.0 + cfg.headway_tolerance,
                                "hinf_every_class_at_most": 1.0 if cfg.string_stable else None},
                "config": {**{k: v for k, v in asdict(cfg).items()
                              if k not in ("impairments", "kp", "kd", "law")}, **asdict(grid)}}

    def search(h: float, runner: Runner) -> tuple[list[dict], dict, str]:
        best, points, interior, reference = tune_gap_weights(h, cfg, grid, runner)
        base = grid.base_params(h)
        entry = _entry(h, best, points, interior, reference, base, base_h)
        chosen = f"{entry['name']}, J = {best.objective:.3f}" if best else "no safe weights"
        return [_row(p, base) for p in points], entry, \
            f"h = {h:g} s: {chosen} ({len(points)} weight sets, interior: {interior}"

    return tune_over_gaps(cfg, out, events_limit, header, search, log)


def format_result(payload: dict) -> str:
    """The chosen weights per h beside the base's, as a Markdown table."""
    lines = ["| h (s) | law | interior | headway (s) | jerk (m/s³) | dampening | TTC<1.5 s | "
             "‖Γ‖∞ | J | base jerk | base dampening |", "|---|---|---|---|---|---|---|---|---|---|---|"]
    for e in payload["entries"]:
        b = e["base"]["metrics"]
        if e["name"] is None:
            lines.append(f"| {e['h']:g} | no safe weights | | | | | | | | "
                         f"{b.get('jerk_mps3', math.nan):.3f} | "
                         f"{b.get('dampening_ratio', math.nan):.3f} |")
            continue
        m = e["metrics"]
        lines.append(f"| {e['h']:g} | `{e['name']}` | {e['interior']} | {m['headway_s']:.3f} | "
                     f"{m['jerk_mps3']:.3f} | {m['dampening_ratio']:.3f} | "
                     f"{m['ttc_lt_1_5s_count']} | {e['hinf']:.5f} | {e['objective']:.3f} | "
                     f"{b['jerk_mps3']:.3f} | {b['dampening_ratio']:.3f} |")
    return "\n".join(lines)
