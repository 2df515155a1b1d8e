"""String stability measured in frequency: ``carl-sumo string-stability``.

For each frequency ω the leader cruises at ``base_speed_mps`` for ``settle_s`` (the platoon
settles at its own spacing), then drives v_L(t) = v0 + A·sin(ω t). After ``discard_s`` more seconds
(the transient of the start), follower i's acceleration over whole periods (at least
``min_fit_s``) is fitted by least squares with c0 + c1·sin(ω t) + c2·cos(ω t); the gain of link i is
its amplitude √(c1² + c2²) over its predecessor's (the leader's for the first link). The
accelerations are the realised ones, from SUMO's speeds. ‖Γ‖∞ is the largest gain over links and
frequencies; a platoon is string stable when it is ≤ 1.

``hinf_inner`` is the same over the links behind another follower (for a CACC: the V2V links, where
the predecessor's state u arrives by message), ``hinf_first_link`` that of the first follower, which
follows the human leader with no message: it feeds forward the leader's *measured* acceleration,
which its own lag then delays, so on a slow vehicle that link amplifies where the V2V links do not.

For the linear laws (``ploeg*``, ``acc*``) on one vehicle class with a fixed lag and dead time,
:mod:`carl_sumo.control.transfer` gives the theory to draw beside the measurement: the continuous
Γ(jω) and the exact discrete-time Γ of the law as carl-sumo runs it.
"""

from __future__ import annotations

import json
import math
import sys
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Sequence

import numpy as np

from carl_sumo.config import DT_S
from carl_sumo.control.cacc import TEXTBOOK, check_heard, is_ploeg_name, parse_ploeg
from carl_sumo.control.ploeg_names import PloegParams, tuned_gap
from carl_sumo.control.channel import Impairments, plant_impairments
from carl_sumo.control.classical import time_gap_of
from carl_sumo.control.mpc import is_mpc_name
from carl_sumo.control.transfer import gamma_continuous, gamma_discrete, links_theory, \
    smallest_stable_gap, widen_bracket, \
    log_frequencies
from carl_sumo.data.events import Event
from carl_sumo.data.synthetic import sine_event
from carl_sumo.errors import InputError
from carl_sumo.sim.sumo import DEFAULT_NET, lane_route, check_fits
from carl_sumo.sim.vehicle import VEHICLE_CLASSES, Plant

MAX_SINE_RUN_S = 100_000.0
"""The longest run of one frequency (s): a lower frequency is refused before its leader's
trajectory is built (the network's length refuses most long runs anyway)."""


@dataclass(frozen=True)
class SineTest:
    """The leader's sinusoidal speed perturbation and the measurement window (units in names)."""

    base_speed_mps: float = 20.0
    amplitude_mps: float = 0.5
    settle_s: float = 40.0
    discard_s: float = 30.0
    min_fit_s: float = 30.0

    def check(self, omegas: Sequence[float]) -> None:
        """InputError for an amplitude that stops the leader or a frequency that the run cannot
        resolve (above a tenth of the sampling frequency, or not positive)."""
        if not (math.isfinite(self.base_speed_mps) and self.base_speed_mps > 0):
            raise InputError(f"--base-speed must be a positive speed in m/s, got "
                             f"{self.base_speed_mps}")
        if not (math.isfinite(self.amplitude_mps) and 0 < self.amplitude_mps):
            raise InputError(f"--amplitude must be a positive speed in m/s, got "
                             f"{self.amplitude_mps}")
        if self.amplitude_mps >= self.base_speed_mps:
            raise InputError(f"--amplitude {self.amplitude_mps:g} m/s would stop the leader "
                             f"(base speed {self.base_speed_mps:g} m/s); give less than the base "
                             "speed")
        nyquist = math.pi / DT_S
        for w in omegas:
            if not (math.isfinite(w) and 0 < w <= nyquist / 10):
                raise InputError(f"frequency {w:g} rad/s cannot be resolved with {DT_S} s steps; "
                                 f"give frequencies in (0, {nyquist / 10:.2f}] rad/s")
            run_s = self.settle_s + self.discard_s + 4 * math.pi / w
            if run_s > MAX_SINE_RUN_S:
                lowest = 4 * math.pi / (MAX_SINE_RUN_S - self.settle_s - self.discard_s)
                raise InputError(f"frequency {w:g} rad/s needs a run of {run_s:.3g} s (two "
                                 f"periods), more than {MAX_SINE_RUN_S:g} s; give frequencies of "
                                 f"at least {lowest:.4f} rad/s")

    def fit_steps(self, omega: float) -> int:
        """Steps of the fit window: whole periods, at least two and at least ``min_fit_s``."""
        period = 2 * math.pi / omega
        periods = max(2, math.ceil(self.min_fit_s / period))
        return int(round(periods * period / DT_S))

    def event(self, omega: float, gap_m: float) -> Event:
        """The leader of one frequency; the followers start at the base speed and ``gap_m``."""
        k_settle = int(round(self.settle_s / DT_S))
        k_total = k_settle + int(round(self.discard_s / DT_S)) + self.fit_steps(omega)
        return sine_event(f"sine_w{omega:.4f}", omega, self.amplitude_mps, self.base_speed_mps,
                          k_settle, k_total, gap_m)


def _fit_amplitude(t: np.ndarray, x: np.ndarray, omega: float) -> np.ndarray:
    """Amplitude at ω of each column of ``x`` (T, m): least squares on [1, sin, cos]."""
    basis = np.column_stack([np.ones_like(t), np.sin(omega * t), np.cos(omega * t)])
    coef, *_ = np.linalg.lstsq(basis, x, rcond=None)
    return np.hypot(coef[1], coef[2])


def link_gains(leader_speed: np.ndarray, speed: np.ndarray, omega: float, test: SineTest
               ) -> np.ndarray:
    """Gain of each link (n,) at ω from one run's leader (T,) and follower (T, n) speeds."""
    acc = np.diff(np.column_stack([leader_speed, speed]), axis=0) / DT_S  # a(k), k = 1..T-1
    window = test.fit_steps(omega)
    if acc.shape[0] < window:
        raise InputError(f"the run at {omega:g} rad/s ended after {acc.shape[0]} steps (a "
                         "collision?), before its fit window")
    t = (np.arange(acc.shape[0]) + 1)[-window:] * DT_S
    amp = _fit_amplitude(t, acc[-window:], omega)
    return amp[1:] / amp[:-1]


def equilibrium_gap(controller: str, speed_mps: float) -> float:
    """Where a follower starts (m): the law's own spacing s0 + h·v for the linear laws and for a
    policy on one (its base's), else a 1.5 s gap (about IDM's)."""
    if controller.endswith(".pt"):
        from carl_sumo.learn.policy import read_policy_payload

        base = read_policy_payload(Path(controller))["agent_config"].get("base") or ""
        if is_ploeg_name(base):
            return equilibrium_gap(base, speed_mps)
    if is_mpc_name(controller):  # the MPC keeps s0 + h·v in its chain
        s0, h = time_gap_of(controller)
        return s0 + h * speed_mps
    if is_ploeg_name(controller):
        if controller.split(":")[0].endswith("-tuned"):  # its time gap, whichever plant's gains
            return TEXTBOOK.standstill_gap_m + tuned_gap(controller) * speed_mps
        p = parse_ploeg(controller)
        return p.standstill_gap_m + p.time_gap_s * speed_mps
    return 2.0 + 1.5 * speed_mps


def run_frequency(controller: str, omega: float, n: int, test: SineTest, net: str,
                  impairments: Impairments | None, decision: tuple[float, ...] = ()
                  ) -> list[float]:
    """The link gains (n,) of one frequency, run in this process; a held-gap policy with its
    first ``decision`` (gap offsets, s) in place (:mod:`carl_sumo.experiments.held_gaps`)."""
    from carl_sumo.experiments.held_gaps import HeldDecision, start_gaps_m
    from carl_sumo.experiments.simulate import cached_sim, plant_of, resolve_controller, run_event

    follower_model, ctrl = resolve_controller(controller, plant_of(impairments))
    start = None
    if decision:  # each follower at its own held gap from the start
        ctrl = HeldDecision(ctrl, decision)
        start = start_gaps_m(ctrl, decision, impairments, test.base_speed_mps)
    event = test.event(omega, equilibrium_gap(controller, test.base_speed_mps))
    traj = run_event(cached_sim(net, follower_model), event, n, ctrl, impairments=impairments,
                     start_gaps_m=start)
    if traj.collisions:
        raise InputError(f"{controller} collided at {omega:g} rad/s; string stability is "
                         "measured on a platoon that stays safe")
    return link_gains(traj.leader_speed, traj.speed, omega, test).tolist()


def check_run(controller: str, omegas: Sequence[float], n: int, test: SineTest,
              net: str = str(DEFAULT_NET)) -> None:
    """InputError before any run: bad test values, or the lowest frequency's run does not fit
    the network."""
    test.check(omegas)
    if is_ploeg_name(controller) and not controller.split(":")[0].endswith("-tuned"):
        check_heard(parse_ploeg(controller), n, controller)  # an mpf law's r within the platoon
    event = test.event(min(omegas), equilibrium_gap(controller, test.base_speed_mps))
    try:
        check_fits(lane_route(net), event, n)
    except InputError as exc:
        raise InputError(f"the run at {min(omegas):g} rad/s is too long for the network ({exc}); "
                         "raise the lowest frequency or lower --base-speed") from None


def measure(controller: str, omegas: Sequence[float], n: int, test: SineTest = SineTest(),
            impairments: Impairments | None = None, net: str = str(DEFAULT_NET),
            workers: int = 1, decision: Sequence[float] = ()) -> dict:
    """The measured curve of one controller: ``per_link`` (one list of gains per link),
    ``gain`` (the max over links per frequency) and ``hinf``; ``decision``: see
    :func:`run_frequency`."""
    from carl_sumo.scale.workers import run_parallel

    decision = tuple(float(x) for x in decision)
    items = [(controller, float(w), n, test, net, impairments, decision) for w in omegas]
    if workers > 1:
        rows = list(run_parallel(run_frequency, items, workers,
                                 describe=lambda a: f"{a[0]} at {a[1]:g} rad/s"))
    else:
        rows = [run_frequency(*item) for item in items]
    per_link = np.array(rows).T  # (n, frequencies)
    gain = per_link.max(axis=0)
    out = {"per_link": per_link.tolist(), "gain": gain.tolist(), "hinf": float(gain.max())}
    if n > 1:  # the links behind another follower: for a CACC, the V2V links
        inner = per_link[1:].max(axis=0)
        out.update({"gain_inner": inner.tolist(), "hinf_inner": float(inner.max()),
                    "hinf_first_link": float(per_link[0].max())})
    return out


def inner_gap(p: PloegParams, plant: Plant | None) -> float:
    """The time gap (s) a one-class platoon's followers that hear a message keep: h, or with
    ``ht`` and ``aw=1`` a heavy class's max(h, ht), as the law's kernel decides
    (:meth:`carl_sumo.control.ploeg_names.PloegParams.chain_gap_s`)."""
    if plant is None or len(plant.fleet) != 1:
        return p.time_gap_s
    return p.chain_gap_s(VEHICLE_CLASSES[plant.fleet[0][0]].b_max_mps2)


def analytic(controller: str, omegas: Sequence[float], plant: Plant | None,
             comm_delay_s: float, n: int = 5) -> dict | None:
    """Theory for a linear law on one class with fixed τ and dead time (None otherwise): the
    continuous and the exact discrete Γ of the first link (the leader's measured acceleration as
    feed-forward) and of the links behind it (the predecessor's V2V state, delayed); an ``mpf``
    law's ``n`` links each (:func:`carl_sumo.control.transfer.links_theory`)."""
    if not is_ploeg_name(controller):
        return None
    tau, dead = (0.0, 0) if plant is None else (plant.lag_s, plant.dead_time_s)
    if plant is not None and (len(plant.fleet) != 1 or tau is None or dead is None):
        return None
    dead_steps = int(round((dead or 0.0) / DT_S))
    delay_steps = int(round(comm_delay_s / DT_S))
    p, w, out = parse_ploeg(controller), np.asarray(omegas, dtype=float), {}
    h = inner_gap(p, plant)
    head = (p.kp if p.alone_kp is None else p.alone_kp,
            p.kd if p.alone_kd is None else p.alone_kd)  # pa, da: the head's own gains
    lead = 1.0 if p.lead_weight is None else p.lead_weight  # fa
    if p.multi:
        return links_theory(w, n, h, p.kp, p.kd, tau or 0.0, dead_steps, delay_steps,
                            p.weights, p.gap_alone_s, first_gains=head,
                            lead_weight=lead)
    for name, first in (("first_link", True), ("inner_links", False)):
        args = (p.gap_alone_s, *head, tau or 0.0) if first else (h, p.kp, p.kd, tau or 0.0)
        cont = gamma_continuous(w, *args, phi=dead_steps * DT_S,
                                theta=0.0 if first else delay_steps * DT_S,
                                cacc=p.feed_forward, first_link=first, lead_weight=lead)
        disc = gamma_discrete(w, *args, dead_steps=dead_steps, delay_steps=delay_steps,
                              cacc=p.feed_forward, first_link=first, lead_weight=lead)
        out[name] = {"continuous": np.abs(cont).tolist(), "discrete": np.abs(disc).tolist()}
    return out


def plant_cases(plant: Plant | None) -> list[tuple[str, Plant | None]]:
    """The homogeneous platoons a check runs: the ideal plant, or each class of the fleet at
    the slow end of its ranges (or at the fixed lag and dead time)."""
    if plant is None:
        return [("ideal", None)]
    return [(name, plant.worst_case(name)) for name in plant.classes]


def _tuned_name(name: str, plant_key: str) -> str:
    """The law a ``-tuned`` name runs on the plant ``plant_key`` (``mpc-tuned``: the MPC's tuned
    name; the other tuned laws: their gains as a Ploeg name); any other name as it is."""
    if not name.split(":")[0].endswith("-tuned"):
        return name
    if is_mpc_name(name):
        from carl_sumo.control.ploeg_names import tuned_law

        return tuned_law(name, plant=plant_key)
    return parse_ploeg(name, plant=plant_key).name()


def string_stability(controllers: Sequence[str], plant: Plant | None,
                     impairments: Impairments | None, n: int, omegas: Sequence[float] | None = None,
                     test: SineTest = SineTest(), net: str = str(DEFAULT_NET),
                     workers: int = 1) -> dict:
    """The whole check: every controller on every class of the plant (see :func:`plant_cases`),
    measured and, for the linear laws, in theory. A held-gap policy runs with the gaps it chose
    on events held, at the number of followers it was trained with (``decision`` in its rows,
    :mod:`carl_sumo.experiments.held_gaps`)."""
    from carl_sumo.experiments.held_gaps import held_decision

    omegas = log_frequencies() if omegas is None else np.asarray(omegas, dtype=float)
    held = {name: held_decision(name, impairments, net) for name in controllers}
    sizes = {name: n if held[name] is None else len(held[name]["offsets_s"])
             for name in controllers}
    for name in controllers:
        check_run(name, omegas, sizes[name], test, net)
    comm_delay = impairments.delay_s if impairments is not None else 0.0
    # a -tuned law runs the gains tuned for this plant (the fleet), on every class of it
    fleet_key = impairments.plant_key if impairments is not None else "ideal"
    gains = {name: _tuned_name(name, fleet_key) for name in controllers}
    runs = []
    for cls, case in plant_cases(plant):
        imp = replace(impairments or Impairments(), plant=case)
        for name in controllers:
            decision = held[name]["offsets_s"] if held[name] else ()
            entry = {"controller": name, "class": cls,
                     "plant": "ideal" if case is None else case.describe(),
                     "comm_delay_s": comm_delay,
                     **measure(gains[name], omegas, sizes[name], test,
                               imp if imp.active else None, net, workers, decision)}
            if held[name]:
                entry["decision"] = held[name]
            theory = analytic(gains[name], omegas, case, comm_delay, n)
            if theory is not None:
                entry["analytic"] = theory
            runs.append(entry)
    out = {"frequencies_rad_s": [float(w) for w in omegas], "vehicles": n,
           "base_speed_mps": test.base_speed_mps, "amplitude_mps": test.amplitude_mps,
           "runs": runs}
    worst = max(runs, key=lambda r: r["hinf"])  # the only run, or the worst one
    out.update({k: worst[k] for k in ("controller", "plant", "per_link", "gain", "hinf",
                                      "hinf_inner", "hinf_first_link") if k in worst})
    return out


def plot(result: dict, path: Path) -> None:
    """Magnitude |Γ| against ω (log), one curve per controller and class, theory dashed, the
    line |Γ| = 1 drawn."""
    from carl_sumo.experiments.figures import pyplot, save_png

    plt = pyplot()
    w = result["frequencies_rad_s"]
    fig, ax = plt.subplots(figsize=(7, 4.5))
    for run in result["runs"]:
        label = f"{run['controller']} ({run['class']})"
        line, = ax.semilogx(w, run["gain"], "o-", ms=3, label=f"{label}: ‖Γ‖∞ = {run['hinf']:.3f}")
        if "analytic" in run:
            ax.semilogx(w, run["analytic"]["inner_links"]["continuous"], "--",
                        color=line.get_color(), lw=1, label=f"{label}, theory (inner links)")
    ax.axhline(1.0, color="k", lw=0.8)
    ax.set_xlabel("ω (rad/s)")
    ax.set_ylabel("|Γ(jω)| = |a_i| / |a_{i-1}|")
    ax.set_title(f"string stability, {result['vehicles']} followers, leader "
                 f"{result['base_speed_mps']:g} ± {result['amplitude_mps']:g} m/s")
    ax.legend(fontsize=7)
    ax.grid(True, which="both", alpha=0.3)
    fig.tight_layout()
    save_png(fig, path, dpi=120)


# ------------------------------------------------------------------------- minimum time gaps
H_MIN_DELAYS_S = (0.0, 0.1, 0.2, 0.3)
H_MIN_LAGS_S = (0.1, 0.3, 0.5)
H_MIN_OMEGAS = log_frequencies(16, 0.05, 3.0)


def _hinf_measured(law: str, h: float, kp: float, kd: float, tau: float, delay_s: float,
                   n: int, net: str) -> float:
    name = f"{law}:h={h:.4f}:kp={kp:g}:kd={kd:g}"
    imp = Impairments(delay_s=delay_s, plant=Plant((("car", 1.0),), tau, 0.0))
    return measure(name, H_MIN_OMEGAS, n, SineTest(), imp, net)["hinf_inner"]


def h_min_measured(law: str, kp: float, kd: float, tau: float, delay_s: float, guess: float,
                   n: int = 3, net: str = str(DEFAULT_NET), tol: float = 0.005) -> float:
    """The smallest time gap (s) whose measured ‖Γ‖∞ (over :data:`H_MIN_OMEGAS`, the links behind
    a follower among ``n``: the V2V links of a CACC, as in the classical theory) is ≤ 1: bisection
    in [guess - 0.5, guess + 0.5], widened when needed."""
    def stable(h: float) -> bool:
        return _hinf_measured(law, h, kp, kd, tau, delay_s, n, net) <= 1.0

    lo, hi = widen_bracket(stable, max(0.05, guess - 0.5), guess + 0.5, 1.0, 0.05)
    return smallest_stable_gap(stable, lo, hi, tol)


def _h_min_cell(law: str, kp: float, kd: float, tau: float, delay_s: float, net: str) -> dict:
    from carl_sumo.control.transfer import h_min

    theory = h_min(kp, kd, tau, theta=delay_s, cacc=law == "ploeg")
    measured = h_min_measured(law, kp, kd, tau, delay_s, theory, net=net)
    return {"law": law, "lag_s": tau, "comm_delay_s": delay_s, "h_min_analytic_s": theory,
            "h_min_measured_s": measured}


def h_min_table(kp: float, kd: float, net: str = str(DEFAULT_NET), workers: int = 1) -> list[dict]:
    """h_min of ACC (radar only: one row per lag, the V2V delay does not enter) and CACC against
    lag and V2V delay: the continuous theory and the measurement in SUMO."""
    from carl_sumo.scale.workers import run_parallel

    items = [("acc", kp, kd, tau, 0.0, net) for tau in H_MIN_LAGS_S]
    items += [("ploeg", kp, kd, tau, d, net) for tau in H_MIN_LAGS_S for d in H_MIN_DELAYS_S]
    if workers > 1:
        return list(run_parallel(_h_min_cell, items, workers,
                                 describe=lambda a: f"h_min of {a[0]} at tau {a[3]}, delay {a[4]}"))
    return [_h_min_cell(*item) for item in items]


def h_min_markdown(rows: list[dict], kp: float, kd: float) -> str:
    """The h_min table: one row per lag, ACC and CACC per V2V delay, measured / analytic (s)."""
    head = ["lag τ (s)", "ACC (radar only)"] + [f"CACC, V2V delay {d:g} s" for d in H_MIN_DELAYS_S]
    lines = [f"Smallest string-stable time gap h_min (s), measured in SUMO / analytic "
             f"(continuous Γ), kp = {kp:g} 1/s², kd = {kd:g} 1/s, no dead time", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for tau in H_MIN_LAGS_S:
        cells = [f"{tau:g}"]
        for law, delays in (("acc", (0.0,)), ("ploeg", H_MIN_DELAYS_S)):
            for d in delays:
                r = next(r for r in rows if r["law"] == law and r["lag_s"] == tau
                         and r["comm_delay_s"] == d)
                cells.append(f"{r['h_min_measured_s']:.2f} / {r['h_min_analytic_s']:.2f}")
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def h_min_plot(rows: list[dict], path: Path) -> None:
    """h_min against V2V delay, one line per lag for CACC, ACC dashed (measured: markers)."""
    from carl_sumo.experiments.figures import pyplot, save_png

    fig, ax = pyplot().subplots(figsize=(6.5, 4))
    for tau in H_MIN_LAGS_S:
        cacc = sorted((r for r in rows if r["law"] == "ploeg" and r["lag_s"] == tau),
                      key=lambda r: r["comm_delay_s"])
        d = [r["comm_delay_s"] for r in cacc]
        line, = ax.plot(d, [r["h_min_analytic_s"] for r in cacc], "-", label=f"CACC, τ = {tau:g} s")
        ax.plot(d, [r["h_min_measured_s"] for r in cacc], "o", color=line.get_color())
        acc = next(r for r in rows if r["law"] == "acc" and r["lag_s"] == tau)
        ax.plot([0, max(H_MIN_DELAYS_S)], [acc["h_min_analytic_s"]] * 2, "--",
                color=line.get_color(), lw=1, label=f"ACC (radar only), τ = {tau:g} s")
        ax.plot([0], [acc["h_min_measured_s"]], "s", color=line.get_color())
    ax.set_xlabel("V2V delay θ (s)")
    ax.set_ylabel("smallest string-stable time gap h_min (s)")
    ax.set_title("lines: theory; markers: measured in SUMO")
    ax.legend(fontsize=7)
    ax.grid(alpha=0.3)
    fig.tight_layout()
    save_png(fig, path, dpi=120)


# --------------------------------------------------------------------------- the real suite
LEARNED_AMPLITUDES_MPS = (0.5, 2.0)
"""The leader's speed amplitudes a learned (nonlinear) policy is checked at (m/s)."""


def suite_table(suite, out_dir: Path, net: str, workers: int) -> str:
    """The real suite's string-stability table: ‖Γ‖∞ of every controller that runs on the plant
    (the classical laws, IDM in carl-sumo, the shipped policies at two amplitudes) on every class
    of the fleet; written to ``string_stability.md`` and ``.json``; returns its Markdown."""
    from carl_sumo.files import write_text_atomic

    omegas = log_frequencies(4, 0.1, 2.0) if suite.quick else log_frequencies(12, 0.05, 3.0)
    n = 3 if suite.quick else 5
    imp = suite.impairments
    plant = imp.plant if imp is not None else None
    names = [k for k, m in suite.models.items()
             if k.startswith(("ploeg", "acc", "mpf", "mpc", "idm-external"))]
    names += [m.files[0] for m in suite.models.values() if m.files and m.runs_on(n)]
    rows = []
    for name in names:
        amplitudes = LEARNED_AMPLITUDES_MPS if name.endswith(".pt") else (SineTest().amplitude_mps,)
        for amp in amplitudes:
            try:
                result = string_stability([name], plant, imp, n, omegas, SineTest(amplitude_mps=amp),
                                          net, workers)
                runs = result["runs"]
            except InputError as exc:  # a collision at some frequency
                runs = [{"controller": name, "class": "-", "error": str(exc)}]
            rows += [{**r, "amplitude_mps": amp} for r in runs]
    lines = [f"## String stability on the plant ({n} followers, "
             f"{len(omegas)} frequencies {omegas[0]:.2f}-{omegas[-1]:.1f} rad/s)", "",
             "‖Γ‖∞ over all links / over the links behind a follower (a CACC's V2V links); each "
             "class in a platoon of its own, at the slow end of its lag and dead-time ranges "
             "(`docs/string_stability.md`). ≤ 1: string stable.", "",
             "| controller | class | amplitude (m/s) | ‖Γ‖∞ all links | behind a follower | "
             "first link | theory (discrete) |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        label = Path(r["controller"]).name
        if "error" in r:
            lines.append(f"| {label} | - | {r['amplitude_mps']:g} | collides | | | |")
            continue
        theory = ""
        if "analytic" in r:
            links = ("first_link", "inner_links")  # an mpf law's per_link too: not here
            theory = f"{max(max(r['analytic'][k]['discrete']) for k in links):.3f}"
        lines.append(f"| {label} | {r['class']} | {r['amplitude_mps']:g} | {r['hinf']:.3f} | "
                     f"{r.get('hinf_inner', float('nan')):.3f} | "
                     f"{r.get('hinf_first_link', float('nan')):.3f} | {theory} |")
    md = "\n".join(lines) + "\n"
    write_text_atomic(out_dir / "string_stability.md", md)
    write_text_atomic(out_dir / "string_stability.json", json.dumps(
        {"frequencies_rad_s": omegas.tolist(), "vehicles": n, "rows": rows}, indent=1))
    return md


SELECTION_OMEGAS = log_frequencies(8, 0.05, 3.0)
"""The frequencies each checkpoint is checked at by ``train --gate-string-stable`` (rad/s)."""

SHIP_OMEGAS = log_frequencies(24, 0.05, 3.0)
"""The frequencies a run is checked at before it is shipped (``rank --string-stable``, a sweep's
``ship_string_stable``; rad/s): three times the gate's, so that a peak between the gate's
frequencies is not missed (a gated run amplified by 0.02 % at 0.86 rad/s, between 0.52 and 0.93)."""


def worst_hinf(policy: str, impairments: Impairments | None, n: int = 5,
               omegas: Sequence[float] = SELECTION_OMEGAS,
               amplitudes: Sequence[float] = LEARNED_AMPLITUDES_MPS,
               net: str = str(DEFAULT_NET), workers: int = 1) -> float:
    """The largest ‖Γ‖∞ of a policy file over every class of the plant of ``impairments`` (none:
    the ideal plant) and the leader amplitudes ``amplitudes`` (m/s), n followers; inf where the
    platoon collides at some frequency. ≤ 1: string stable (``carl-sumo rank --string-stable``)."""
    plant = impairments.plant if impairments is not None else None
    worst = 0.0
    for amp in amplitudes:
        try:
            result = string_stability([policy], plant, impairments, n, omegas,
                                      SineTest(amplitude_mps=amp), net, workers)
        except InputError:  # a collision at some frequency
            return math.inf
        worst = max([worst] + [run["hinf"] for run in result["runs"]])
    return worst


def string_stable_first(rows: list[dict], plant: str,
                        omegas: Sequence[float] = SHIP_OMEGAS) -> list[dict]:
    """Ranked runs (``carl-sumo rank`` rows, best first, each with its ``path``) with the first
    that is string stable on the ``plant`` ("ideal" or "real") at ``omegas`` (rad/s) moved to
    the front; every run checked until then gets its :func:`worst_hinf` (``hinf``). InputError
    when none is."""
    imp = plant_impairments(plant)
    for i, row in enumerate(rows):
        row["hinf"] = worst_hinf(row["path"], imp, omegas=omegas)
        print(f"{Path(row['path']).name}: worst ‖Γ‖∞ {row['hinf']:.4f} on the {plant} plant",
              file=sys.stderr)
        if row["hinf"] <= 1.0:
            return [row] + rows[:i] + rows[i + 1:]
    raise InputError(f"no run is string stable on the {plant} plant (worst ‖Γ‖∞: " +
                     ", ".join(f"{r['hinf']:.4f}" for r in rows) + "); ship none of them")


def keep_string_stable(out: Path, select: str, plant: str) -> dict | None:
    """``train --gate-string-stable``: of a run's validated checkpoints (its candidates, from
    :func:`carl_sumo.learn.checkpoint.candidate_dir`), write to ``out`` the best by the run's
    ``select`` rule that is string stable on ``plant`` (checked in score order until one passes,
    :func:`string_stable_first`; ties: the earlier step). Its rank row with ``hinf``; None (and
    ``out`` as training left it) when no candidate is string stable."""
    from carl_sumo.learn.checkpoint import candidate_dir
    from carl_sumo.learn.policy import read_policy_payload, save_torch_atomic
    from carl_sumo.learn.selection import rank_runs

    paths = sorted(candidate_dir(out).glob("step*.pt"))
    if not paths:
        raise InputError(f"{out} has no candidates in {candidate_dir(out)}; train it with "
                         "--gate-string-stable")
    try:
        row = string_stable_first(rank_runs(paths, select), plant, SELECTION_OMEGAS)[0]
    except InputError as exc:
        print(f"{out}: {exc}; kept the best-scoring checkpoint", file=sys.stderr)
        return None
    payload = read_policy_payload(Path(row["path"]))
    payload["metadata"]["string_stability_gate"] = {
        "plant": plant, "worst_hinf": row["hinf"], "candidate": Path(row["path"]).name,
        "candidates": len(paths)}
    save_torch_atomic(payload, out)
    print(f"{out}: kept {Path(row['path']).name}, the best-scoring string-stable checkpoint "
          f"(worst ‖Γ‖∞ {row['hinf']:.4f} on the {plant} plant)", file=sys.stderr)
    return row
