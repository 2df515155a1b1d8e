"""Issue 35's judged bar, event by event: a controller against its reference through one manoeuvre.

The bar: the product has 0 collisions and no TTC < 1.5 s wherever the reference (its tuned
classical CACC) has none, and its peak deceleration and settle time are no worse. The scenario
tables give means over events; this compares the two runs on each event both did the manoeuvre
in (:func:`manoeuvre_criterion`):

- ``collisions_where_reference_none``: events in which the controller collides and the reference
  does not (their IDs: ``collision_events_where_reference_none``; the converse count:
  ``reference_collisions_where_none``);
- ``ttc_where_reference_none``: events with a TTC below 1.5 s after the manoeuvre for the
  controller and none for the reference (their IDs: ``ttc_events_where_reference_none``; and the
  converse count);
- per metric of :data:`PAIRED_MANOEUVRE_KEYS`, the mean per-event difference controller minus
  reference with a 95 % percentile-bootstrap interval over events (settle time over the events
  that settle for both), and how many events it is worse on.
"""

from __future__ import annotations

import math

import numpy as np

PAIRED_MANOEUVRE_KEYS = ("peak_decel_mps2", "settle_s")
"""Manoeuvre metrics compared event by event (lower is better for both)."""
TTC_CRITICAL_S = 1.5


def _by_event(result: dict) -> dict[str, dict]:
    """event ID -> manoeuvre metrics of the events in which the manoeuvre was done."""
    return {e["event_id"]: e["manoeuvre_metrics"] for e in result["events"]
            if e["manoeuvre_metrics"]["done"]}


def _critical(m: dict) -> bool:
    ttc = m.get("min_ttc_s", math.nan)
    return ttc == ttc and ttc < TTC_CRITICAL_S


def _bootstrap_mean(diff: np.ndarray, n_boot: int, seed: int) -> tuple[float, float]:
    """95 % percentile-bootstrap interval of the mean of ``diff``; (nan, nan) below 2 values."""
    if diff.size < 2:
        return math.nan, math.nan
    rng = np.random.default_rng(seed)
    means = diff[rng.integers(0, diff.size, size=(n_boot, diff.size))].mean(axis=1)
    lo, hi = np.percentile(means, [2.5, 97.5])
    return float(lo), float(hi)


def manoeuvre_criterion(result: dict, reference: dict, n_boot: int = 2000,
                        seed: int = 0) -> dict:
    """``result`` against ``reference`` (each as :func:`carl_sumo.manoeuvres.tables.result_of`
    returns it, with its per-event rows) on the events both did the manoeuvre in; see the
    module docstring for the keys."""
    mine, ref = _by_event(result), _by_event(reference)
    common = sorted(set(mine) & set(ref))
    out: dict = {"controller": result["controller"], "reference": reference["controller"],
                 "paired_events": len(common)}
    worse = [e for e in common if mine[e]["collisions"] > 0 and ref[e]["collisions"] == 0]
    out["collisions_where_reference_none"] = len(worse)
    out["collision_events_where_reference_none"] = worse
    out["reference_collisions_where_none"] = sum(
        ref[e]["collisions"] > 0 and mine[e]["collisions"] == 0 for e in common)
    close = [e for e in common if _critical(mine[e]) and not _critical(ref[e])]
    out["ttc_where_reference_none"] = len(close)
    out["ttc_events_where_reference_none"] = close
    out["reference_ttc_where_none"] = sum(
        _critical(ref[e]) and not _critical(mine[e]) for e in common)
    for key in PAIRED_MANOEUVRE_KEYS:
        pairs = np.array([(mine[e][key], ref[e][key]) for e in common], float).reshape(-1, 2)
        pairs = pairs[np.isfinite(pairs).all(axis=1)]
        diff = pairs[:, 0] - pairs[:, 1]
        lo, hi = _bootstrap_mean(diff, n_boot, seed)
        out[key] = {"events": int(diff.size),
                    "difference": float(diff.mean()) if diff.size else math.nan,
                    "lo": lo, "hi": hi, "worse_events": int(np.sum(diff > 0)),
                    "better_events": int(np.sum(diff < 0))}
    return out


def criterion_lines(c: dict) -> list[str]:
    """Markdown bullet lines of one :func:`manoeuvre_criterion` result."""
    lines = [f"- event by event ({c['paired_events']} paired): collisions where the reference has "
             f"none {c['collisions_where_reference_none']} (the converse "
             f"{c['reference_collisions_where_none']}); TTC < 1.5 s where the reference has none "
             f"{c['ttc_where_reference_none']} (the converse {c['reference_ttc_where_none']})"]
    if c["collision_events_where_reference_none"]:
        lines.append("- its collisions where the reference has none: " +
                     ", ".join(f"`{e}`" for e in c["collision_events_where_reference_none"]))
    if c.get("ttc_events_where_reference_none"):
        lines.append("- its TTC < 1.5 s events where the reference has none: " +
                     ", ".join(f"`{e}`" for e in c["ttc_events_where_reference_none"]))
    for key in PAIRED_MANOEUVRE_KEYS:
        d = c[key]
        lines.append(f"- {key}, controller minus reference over {d['events']} events: "
                     f"{d['difference']:+.3f} [{d['lo']:+.3f}, {d['hi']:+.3f}] (95 % bootstrap), "
                     f"worse on {d['worse_events']}, better on {d['better_events']}")
    return lines
