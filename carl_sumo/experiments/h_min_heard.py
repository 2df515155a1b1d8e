"""The shortest string-stable time gap against the number of vehicles heard, r = 0 (the ACC),
1 (Ploeg's CACC), 2 and 3 (the multi-predecessor ``mpf``, :mod:`carl_sumo.control.feed_forward`):
``carl-sumo string-stability --controller ploeg:kp=KP:kd=KD --h-min-heard DIR``.

For each lag τ (:data:`LAGS_S`, no dead time) and V2V delay (:data:`DELAYS_S`), h_min is the
smallest time gap at which every link that hears all r vehicles (followers i ≥ max(r, 1), counted
from 0, among :func:`followers`: the links of a long platoon) has |Γ_i| ≤ 1. The links before
them hear fewer (the second follower hears only the head, whose vehicle ahead sends nothing) and
so are Ploeg's links; over every link behind a follower h_min is Ploeg's for every r.

- analytic: the exact discrete Γ_i of the recurrence
  (:func:`carl_sumo.control.transfer.gamma_links_discrete`), scanned upwards in h from 0.05 s in
  0.01 s steps and refined by bisection to 1 ms, on :data:`DENSE_OMEGAS` (0.001-3 rad/s, the band
  the measurement resolves) and on the measured frequencies
  (:data:`carl_sumo.experiments.string_stability.H_MIN_OMEGAS`); the scan goes on to
  :data:`H_HIGH_S` and reports where string stability ends again (``h_max``), as it does for
  r ≥ 2: a longer gap slows the law's filter until the relayed commands arrive out of phase;
- measured: the largest gain of those links in SUMO on the measured frequencies, bisected to 5 ms between gaps
  0.05 s either side of the analytic value (widened while the bracket does not hold);
- Darbha, Konduri and Pagilla (2018): 2τ/(1 + r), for their law (spacing feedback on each of the
  r vehicles heard, their gains, continuous time).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from carl_sumo.control.channel import Impairments
from carl_sumo.control.transfer import gamma_links_discrete, smallest_stable_gap, widen_bracket
from carl_sumo.experiments.string_stability import H_MIN_OMEGAS, SineTest, measure
from carl_sumo.resources import DEFAULT_NET
from carl_sumo.sim.vehicle import Plant

LAGS_S = (0.1, 0.3, 0.5, 0.6)
DELAYS_S = (0.0, 0.1, 0.2)
WEIGHTS = {0: (), 1: (1.0,), 2: (0.7, 0.3), 3: (0.6, 0.3, 0.1)}
"""The weights w_1..w_r of each r: r = 2 is the two-ahead feed-forward at C = 0.3."""


def followers(r: int) -> int:
    """The platoon of each r: r + 3 followers, at least 3, so that three links hear all r (and
    the ACC's longest run, at 0.05 rad/s and h ≈ 3.1 s, fits the network)."""
    return max(3, r + 3)


DENSE_OMEGAS = np.geomspace(1e-3, 3.0, 600)
H_LOW_S, H_HIGH_S, H_STEP_S = 0.05, 4.0, 0.01


def law_name(r: int, h: float, kp: float, kd: float) -> str:
    """The controller name of r vehicles heard at time gap h (s)."""
    gains = f"h={h:.4f}:kp={kp:g}:kd={kd:g}"
    if r <= 1:
        return f"{'acc' if r == 0 else 'ploeg'}:{gains}"
    return f"mpf:{gains}:r={r}:" + ":".join(f"w{j}={w:g}" for j, w in enumerate(WEIGHTS[r], 1))


def _stable(h: float, r: int, kp: float, kd: float, tau: float, delay_steps: int,
            omegas: np.ndarray) -> bool:
    links = gamma_links_discrete(omegas, followers(r), h, kp, kd, tau, 0, delay_steps, WEIGHTS[r])
    return float(np.abs(links[max(r, 1):]).max()) <= 1.0 + 1e-9


def h_range_analytic(r: int, kp: float, kd: float, tau: float, delay_s: float,
                     omegas: np.ndarray = DENSE_OMEGAS) -> tuple[float, float]:
    """(h_min, h_max) (s) of the discrete theory: the smallest string-stable gap, and the
    smallest larger gap that is not (inf: none up to :data:`H_HIGH_S`); (inf, inf) when none is
    stable."""
    d = int(round(delay_s / 0.1))
    grid = np.round(np.arange(H_LOW_S, H_HIGH_S + 1e-9, H_STEP_S), 6)
    ok = [_stable(h, r, kp, kd, tau, d, omegas) for h in grid]
    if not any(ok):
        return float("inf"), float("inf")
    k = ok.index(True)

    def refine(lo: float, hi: float, stable_high: bool) -> float:
        return smallest_stable_gap(
            lambda h: _stable(h, r, kp, kd, tau, d, omegas) == stable_high, lo, hi, 1e-3)

    h_min = grid[0] if k == 0 else refine(grid[k - 1], grid[k], True)
    if all(ok[k:]):
        return float(h_min), float("inf")
    j = k + ok[k:].index(False)
    return float(h_min), float(refine(grid[j - 1], grid[j], False))


def h_min_measured(r: int, kp: float, kd: float, tau: float, delay_s: float, guess: float,
                   net: str = str(DEFAULT_NET), tol: float = 0.005) -> float:
    """The smallest time gap (s) whose links that hear all r vehicles have a measured gain ≤ 1
    in SUMO at every measured frequency (the module docstring)."""
    imp = Impairments(delay_s=delay_s, plant=Plant((("car", 1.0),), tau, 0.0))

    def stable(h: float) -> bool:
        name = law_name(r, h, kp, kd)
        per_link = measure(name, H_MIN_OMEGAS, followers(r), SineTest(), imp, net)["per_link"]
        return float(np.max(per_link[max(r, 1):])) <= 1.0

    lo, hi = widen_bracket(stable, max(H_LOW_S, guess - 0.05), guess + 0.05, 0.1, H_LOW_S)
    return smallest_stable_gap(stable, lo, hi, tol)


def cell(r: int, kp: float, kd: float, tau: float, delay_s: float, net: str) -> dict:
    """One row: r, lag, delay, the analytic range on both frequency sets, measured, Darbha's."""
    h_min, h_max = h_range_analytic(r, kp, kd, tau, delay_s)
    on_measured, _ = h_range_analytic(r, kp, kd, tau, delay_s, H_MIN_OMEGAS)
    measured = h_min_measured(r, kp, kd, tau, delay_s, on_measured, net) \
        if np.isfinite(on_measured) else float("inf")
    return {"heard": r, "weights": list(WEIGHTS[r]), "lag_s": tau, "comm_delay_s": delay_s,
            "h_min_analytic_s": h_min, "h_max_analytic_s": h_max,
            "h_min_analytic_measured_omegas_s": on_measured, "h_min_measured_s": measured,
            "h_min_darbha_s": 2 * tau / (1 + r)}


def table(kp: float, kd: float, net: str = str(DEFAULT_NET), workers: int = 1) -> list[dict]:
    """Every row: the ACC once per lag (its links hear no message), r = 1-3 per lag and delay."""
    from carl_sumo.scale.workers import run_parallel

    items = [(0, kp, kd, tau, 0.0, net) for tau in LAGS_S]
    items += [(r, kp, kd, tau, d, net) for r in (1, 2, 3) for tau in LAGS_S for d in DELAYS_S]
    if workers > 1:
        return list(run_parallel(cell, items, workers,
                                 describe=lambda a: f"h_min r={a[0]}, tau {a[3]}, delay {a[4]}"))
    return [cell(*item) for item in items]


def markdown(rows: list[dict], kp: float, kd: float) -> str:
    """One row per lag and delay: per r, measured / analytic (h_max where stability ends) and
    Darbha's 2τ/(1 + r) at delay 0."""
    def fmt(x: float) -> str:
        return f"{x:.2f}" if np.isfinite(x) else "none"

    head = ["lag τ (s)", "V2V delay (s)"] + [f"r = {r}" for r in WEIGHTS]
    lines = [f"h_min (s) against the vehicles heard r, measured in SUMO / analytic (exact "
             f"discrete, 0.001-3 rad/s), r + 3 followers (ACC: 3), kp = {kp:g} 1/s², kd = {kd:g} 1/s,"
             f" no dead time; the links that hear all r vehicles; weights {', '.join(f'r = {r}: {w}' for r, w in WEIGHTS.items() if r > 1)}"
             "; [h_max: stability ends again]; (Darbha et al.: 2τ/(1 + r))", "",
             "| " + " | ".join(head) + " |", "|" + "---|" * len(head)]
    for tau in LAGS_S:
        for d in DELAYS_S:
            cells = [f"{tau:g}", f"{d:g}"]
            for r in WEIGHTS:
                row = next(x for x in rows if x["heard"] == r and x["lag_s"] == tau
                           and x["comm_delay_s"] == (0.0 if r == 0 else d))
                text = f"{fmt(row['h_min_measured_s'])} / {fmt(row['h_min_analytic_s'])}"
                if np.isfinite(row["h_max_analytic_s"]):
                    text += f" [{fmt(row['h_max_analytic_s'])}]"
                if d == 0:
                    text += f" ({row['h_min_darbha_s']:.2f})"
                cells.append(text)
            lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def write(rows: list[dict], kp: float, kd: float, out: Path) -> str:
    """``h_min_heard.md``, ``.json`` and ``.csv`` in ``out``; returns the Markdown."""
    from carl_sumo.files import write_text_atomic

    out.mkdir(parents=True, exist_ok=True)
    md = markdown(rows, kp, kd)
    write_text_atomic(out / "h_min_heard.md", md)
    write_text_atomic(out / "h_min_heard.json", json.dumps(rows, indent=1))
    keys = [k for k in rows[0] if k != "weights"]
    write_text_atomic(out / "h_min_heard.csv", "\n".join([",".join(keys)] + [
        ",".join(str(r[k]) for k in keys) for r in rows]) + "\n")
    return md
