"""``carl-sumo tune mpc``: the weights of the distributed MPC (``mpc``,
:mod:`carl_sumo.control.mpc`) tuned for a plant on the training events, one weight set for the
whole fleet, at the product's time gaps, against a fixed reference law (default
``product-base`` without its washout ``wo``: Ploeg's CACC with the gains tuned for the real
fleet, cars at 0.6 s and trucks at 0.8 s, with its layers).

For each time gap h (default: the reference's), the grid holds every combination of the spacing
weight ``wq``, the relative-speed weight ``wv``, the command weight ``wu``, the command-rate
weight ``wj``, the time gap of a vehicle that hears no plan ``ha`` (the MPC's ACC mode) and the
speed ``go`` at which a short gap is opened (default 0.5 m/s only); the
horizon N, the heavy vehicles' gap and the reaction layer are :data:`carl_sumo.control.mpc.
DEFAULTS`'s (the reference's ``ht`` when it has one). As :mod:`carl_sumo.experiments.tune_mpf`
does for the feed-forward weights, a point is **safe** when, on every training event, it has no
collision, no more TTC < 1.5 s samples than the reference, a mean headway at most
``headway_tolerance`` above the reference's and, with a plant, ‖Γ‖∞ ≤ 1 on every class. The MPC
has no analytic transfer function, so ‖Γ‖∞ is **measured in SUMO** before a point runs on the
events (:func:`carl_sumo.experiments.string_stability.worst_hinf`: every class of the fleet at
the slow end of its ranges, leader amplitudes 0.5 and 2 m/s, the gate's 8 frequencies 0.05-3
rad/s); a point that amplifies is not simulated on the events. Among safe points the chosen one
minimises

    J = jerk / jerk_reference + dampening / dampening_reference      (J = 2 at the reference).

When the best safe point lies on an edge of an axis with more than one value, that axis grows
one step beyond the edge (a weight multiplied or divided by :data:`GROWTH`, ``ha`` by
:data:`HA_STEP_S`) and the search runs again, up to ``max_extensions`` times (``interior`` in the
result says whether it stopped inside its grid). With no safe point there is no direction to
grow: the result says so (``name`` null) and ``mpc-tuned`` refuses to run.

The result (``policies/mpc_tuned_<plant>.json``, beside the other tuned laws) holds per h the
chosen law's name (``mpc-tuned:h=H`` runs it), its metrics, ‖Γ‖∞ and the reference's, and every
grid point with its measured ‖Γ‖∞.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import asdict, dataclass, field, replace
from datetime import date
from pathlib import Path

from carl_sumo.control.cacc import parse_ploeg
from carl_sumo.control.mpc import DEFAULTS, MPCParams
from carl_sumo.control.ploeg_names import without_washout
from carl_sumo.errors import InputError
from carl_sumo.experiments.tune import Runner, TuneConfig, judge, tune_over_gaps
from carl_sumo.experiments.tune_mpf import class_hinf

DEFAULT_REFERENCE = "product-base"
"""The law whose metrics the objective and the safety constraints are relative to."""
WQ = (0.4, 0.8)
"""Starting grid of wq, the weight of the squared spacing error (1/m²)."""
WV = (1.0, 2.0)
"""Starting grid of wv, the weight of the squared relative speed (s²/m²)."""
WU = (2.0,)
"""Starting grid of wu, the weight of the squared command (s⁴/m²)."""
WJ = (0.2,)
"""Starting grid of wj, the weight of the squared command rate (s⁶/m²)."""
HA = (1.4, 2.0)
"""Starting grid of ha, the time gap of a vehicle that hears no plan (s)."""
GO = (0.5,)
"""Starting grid of go, the speed at which a short gap is opened (m/s; 0: off). Without it no
weight set of the first grids was collision-free: a cramped start (the training event
``zhu2020pool_val_0086``) made every one brake harder down the chain until a truck collided
(:mod:`carl_sumo.control.mpc`, "Opening a short gap")."""
GROWTH = 1.5
"""A weight's axis grows by this factor beyond its edge."""
HA_STEP_S = 0.3
"""The ``ha`` axis grows by this step beyond its edge (s); never below h."""
AXES = ("wq", "wv", "wu", "wj", "ha", "go")


def _grid_help() -> dict[str, str]:
    from carl_sumo.control.mpc import MPC_OPTIONS

    specs = {s.key: s for s in MPC_OPTIONS}
    defaults = {"wq": WQ, "wv": WV, "wu": WU, "wj": WJ, "ha": HA, "go": GO}
    return {a: f"starting grid of {a}, {specs[a].doc} ({specs[a].unit}), commas (default "
               f"{','.join(f'{v:g}' for v in defaults[a])})" for a in AXES}


GRID_HELP = _grid_help()
"""The help of each axis's option of ``carl-sumo tune mpc`` (from the MPC's option specs)."""
OBJECTIVE = ("J = jerk/jerk_reference + dampening/dampening_reference at the same h, on the "
             "training events; lower is better")


@dataclass(frozen=True)
class MpcGrid:
    """What ``carl-sumo tune mpc`` searches besides :class:`TuneConfig` (its gaps, events,
    plant, constraints): the reference law and the starting values of each axis."""

    reference: str = DEFAULT_REFERENCE
    wq: tuple[float, ...] = WQ
    wv: tuple[float, ...] = WV
    wu: tuple[float, ...] = WU
    wj: tuple[float, ...] = WJ
    ha: tuple[float, ...] = HA
    go: tuple[float, ...] = GO
    omegas: tuple[float, ...] = ()   # frequencies of the ‖Γ‖∞ measurement (rad/s; (): the gate's)

    def reference_law(self, h: float | None = None) -> str:
        """The reference's name (no washout) at the time gap h (None: its own); InputError when
        it is not a constant-time-gap law."""
        from carl_sumo.control.cacc import is_ploeg_name

        name = without_washout(self.reference)
        if not is_ploeg_name(name) or name.split(":")[0].endswith("-tuned"):
            raise InputError(f"--base {self.reference!r}: the reference of `tune mpc` must be a "
                             "constant-time-gap law with its gains (ploeg:h=H:kp=KP:kd=KD:..., "
                             "or a preset such as product-base)")
        p = parse_ploeg(name)
        return (p if h is None else replace(p, time_gap_s=h)).name()

    def check(self) -> None:
        """InputError (one line) for a weight ≤ 0 or not finite, or an ``ha`` outside its
        option's range."""
        from carl_sumo.control.mpc import MPC_OPTIONS

        specs = {s.key: s for s in MPC_OPTIONS}
        for axis in AXES:
            for value in getattr(self, axis):
                if not (math.isfinite(value) and specs[axis].low <= value <= specs[axis].high):
                    raise InputError(f"--{axis} {value:g}: {specs[axis].doc} must be in "
                                     f"[{specs[axis].low:g}, {specs[axis].high:g}] "
                                     f"{specs[axis].unit}")

    def base_params(self, h: float) -> MPCParams:
        """The MPC's fixed part at h: :data:`DEFAULTS` with the reference's heavy gap."""
        heavy = parse_ploeg(self.reference_law()).heavy_gap_s
        return replace(DEFAULTS, time_gap_s=h,
                       heavy_gap_s=heavy if heavy is not None else DEFAULTS.heavy_gap_s)


@dataclass
class MpcPoint:
    h: float
    values: tuple[float, ...]       # (wq, wv, wu, wj, ha, go); () for the reference
    name: str = ""
    metrics: dict[str, float] = field(default_factory=dict)
    max_ttc15_event: int = 0
    colliding_events: int = 0
    objective: float = math.nan
    safe: bool = False
    hinf: float = math.nan            # measured worst ‖Γ‖∞ over the classes, with string_stable


def law(base: MPCParams, values: tuple[float, ...]) -> MPCParams:
    """The MPC of one grid point (wq, wv, wu, wj, ha, go) on ``base``."""
    wq, wv, wu, wj, ha, go = values
    return replace(base, w_spacing=wq, w_speed=wv, w_command=wu, w_rate=wj, alone_gap_s=ha,
                   opening_speed=go)


def measured_hinf(name: str, cfg: TuneConfig, omegas: tuple[float, ...] = ()) -> float:
    """The worst ‖Γ‖∞ of a law over the classes of ``cfg``'s plant at ``omegas`` (rad/s; (): the
    gate's 8), measured in SUMO (inf where the platoon collides at a frequency)."""
    from carl_sumo.experiments.string_stability import SELECTION_OMEGAS, worst_hinf

    return worst_hinf(name, cfg.impairments, omegas=omegas or SELECTION_OMEGAS, net=cfg.net,
                      workers=cfg.workers)


def _grow(values: list[float], axis: str, low: bool, high: bool, h: float) -> list[float]:
    """One step more at the low or high edge of an axis with more than one value."""
    values = sorted(set(values))
    if len(values) < 2:
        return values
    if axis == "ha":
        if low and values[0] - HA_STEP_S >= h:
            values.insert(0, round(values[0] - HA_STEP_S, 4))
        if high:
            values.append(round(values[-1] + HA_STEP_S, 4))
        return values
    if low:
        values.insert(0, round(values[0] / GROWTH, 6))
    if high:
        values.append(round(values[-1] * GROWTH, 6))
    return values


def tune_gap_weights(h: float, cfg: TuneConfig, grid: MpcGrid, runner: Runner, log=None
                     ) -> tuple[MpcPoint | None, list[MpcPoint], bool, MpcPoint]:
    """Search one time gap: (best safe point or None, every point, interior?, the reference)."""
    base = grid.base_params(h)
    axes = {a: sorted(set(getattr(grid, a))) for a in AXES}
    reference = MpcPoint(h, (), grid.reference_law(h))
    if cfg.string_stable:  # a constant-time-gap law: from its exact discrete transfer function
        reference.hinf = class_hinf(parse_ploeg(reference.name), cfg)
    runner.run([reference], lambda p: p.name)
    points: dict[tuple[float, ...], MpcPoint] = {}
    best, interior = None, False
    for extension in range(cfg.max_extensions + 1):
        current = set(itertools.product(*(axes[a] for a in AXES)))
        todo = [MpcPoint(h, v, law(base, v).name()) for v in sorted(current) if v not in points]
        for t in todo:
            t.hinf = measured_hinf(t.name, cfg, grid.omegas) if cfg.string_stable else math.nan
            if log is not None:
                log(f"  {t.name}: worst ‖Γ‖∞ {t.hinf:.5f}")
        runner.run([t for t in todo if not cfg.string_stable or t.hinf <= 1.0 + 1e-9],
                   lambda p: p.name)
        points.update({t.values: t for t in todo})
        judge(reference, reference, cfg)
        for point in points.values():
            judge(point, reference, cfg)
        safe = [p for p in points.values() if p.safe and p.values in current]
        if not safe:
            return None, _sorted(points), False, reference
        best = min(safe, key=lambda p: p.objective)
        grown = {a: _grow(axes[a], a, best.values[i] == axes[a][0],
                          best.values[i] == axes[a][-1], h) for i, a in enumerate(AXES)}
        interior = grown == axes
        if interior or extension == cfg.max_extensions:
            break
        axes = grown
    return best, _sorted(points), interior, reference


def _sorted(points: dict[tuple[float, ...], MpcPoint]) -> list[MpcPoint]:
    return sorted(points.values(), key=lambda p: p.values)


def _row(p: MpcPoint) -> dict:
    return {"h": p.h, **dict(zip(AXES, p.values)), "name": p.name, "objective": p.objective,
            "safe": p.safe, "hinf": p.hinf, "colliding_events": p.colliding_events,
            "max_ttc15_per_event": p.max_ttc15_event, **p.metrics}


def _entry(h: float, best: MpcPoint | None, points: list, interior: bool, reference: MpcPoint,
           base_h: float) -> dict:
    """The result of one time gap: the chosen law (``mpc-tuned:h=H`` reads ``name``)."""
    return {"h": h, "base_h": base_h, "name": best.name if best else None,
            **{a: (best.values[i] if best else None) for i, a in enumerate(AXES)},
            "interior": interior, "points": len(points),
            "string_stable_points": sum(1 for p in points if p.hinf <= 1.0 + 1e-9),
            "objective": best.objective if best else None, "hinf": best.hinf if best else None,
            "metrics": best.metrics if best else None,
            "base": {"name": reference.name, "safe": reference.safe, "hinf": reference.hinf,
                     "metrics": reference.metrics,
                     "max_ttc15_per_event": reference.max_ttc15_event}}


def tune_mpc(cfg: TuneConfig, grid: MpcGrid, out: Path, events_limit: int | None = None,
             log=None) -> dict:
    """Tune the weights at every time gap of ``cfg`` and write the result file ``out``
    (atomically; after each gap the result so far to ``<out>.partial.json``, removed at the
    end); ``log`` receives a line per point's ‖Γ‖∞ and per gap."""
    if cfg.split in ("test", "us101", "all"):
        raise InputError(f"tuning on split {cfg.split!r} is not allowed: the test split and the "
                         "cross-site events are for scoring only; use --split train")
    grid.check()
    base_h = parse_ploeg(grid.reference_law()).time_gap_s
    for h in cfg.gaps_s:
        grid.base_params(h)  # a bad gap or horizon fails before any run

    def header(events: int) -> dict:
        return {"controller": "mpc", "plant": cfg.plant_key, "warmup_s": cfg.warmup_s,
                "string_stable": cfg.string_stable, "reference": grid.reference,
                "command": cfg.command, "date": date.today().isoformat(), "data": cfg.data,
                "split": cfg.split, "events": events, "followers": cfg.n_followers,
                "objective": OBJECTIVE,
                "constraints": {"collisions": 0, "ttc_lt_1_5s_count": "at most the reference's",
                                "headway_at_most_reference_times": 1.0 + cfg.headway_tolerance,
                                "hinf_every_class_at_most": 1.0 if cfg.string_stable else None,
                                "hinf": "measured in SUMO: every class at the slow end of its "
                                        "ranges, 0.5 and 2 m/s, 8 frequencies 0.05-3 rad/s"},
                "config": {**{k: v for k, v in asdict(cfg).items()
                              if k not in ("impairments", "kp", "kd", "law")}, **asdict(grid)}}

    def search(h: float, runner: Runner) -> tuple[list[dict], dict, str]:
        best, points, interior, reference = tune_gap_weights(h, cfg, grid, runner, log)
        entry = _entry(h, best, points, interior, reference, base_h)
        chosen = f"{best.name}, J = {best.objective:.3f}" if best else "no safe weights"
        return [_row(p) for p in points], entry, \
            (f"h = {h:g} s: {chosen} ({len(points)} weight sets, "
             f"{entry['string_stable_points']} string stable, interior: {interior}")

    return tune_over_gaps(cfg, out, events_limit, header, search, log)


def format_result(payload: dict) -> str:
    """The chosen law per h beside the reference, as a Markdown table."""
    lines = ["| h (s) | law | interior | string-stable points | headway (s) | jerk (m/s³) | "
             "dampening | TTC<1.5 s | ‖Γ‖∞ | J | reference jerk | reference dampening |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for e in payload["entries"]:
        b = e["base"]["metrics"]
        stable = f"{e['string_stable_points']} of {e['points']}"
        if e["name"] is None:
            lines.append(f"| {e['h']:g} | no safe weights | | {stable} | | | | | | | "
                         f"{b.get('jerk_mps3', math.nan):.3f} | "
                         f"{b.get('dampening_ratio', math.nan):.3f} |")
            continue
        m = e["metrics"]
        lines.append(f"| {e['h']:g} | `{e['name']}` | {e['interior']} | {stable} | "
                     f"{m['headway_s']:.3f} | {m['jerk_mps3']:.3f} | {m['dampening_ratio']:.3f} | "
                     f"{m['ttc_lt_1_5s_count']} | {e['hinf']:.5f} | {e['objective']:.3f} | "
                     f"{b['jerk_mps3']:.3f} | {b['dampening_ratio']:.3f} |")
    return "\n".join(lines)
