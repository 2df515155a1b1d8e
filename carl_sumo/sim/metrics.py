"""The paper's platoon metrics, computed the same way for simulated and recorded followers.

Definitions (all over the followers' 0.1 s samples of one event; ``docs/metrics.md`` has more):

- acceleration a_k = (v_{k+1} - v_k)/dt and jerk j_k = (a_{k+1} - a_k)/dt, from speed, for every
  vehicle including the leader (so recorded and simulated vehicles are treated alike);
- ``headway_s``: mean time headway d/v over samples with v > 0.5 m/s (s);
- ``jerk_mps3``: mean |j| (m/s³); ``speed_mps``: mean v (m/s);
- ``ttc_lt_4s_count`` / ``ttc_lt_1_5s_count``: number of samples with 0 < TTC < 4 s / < 1.5 s,
  TTC = d / (v - v_pred) when closing in (v > v_pred);
- ``dampening_ratio``: mean over followers i of ‖a_i‖₂ / ‖a_0‖₂, a_0 = leader;
- ``worst_successive_ratio``: max over followers of ‖a_i‖₂ / ‖a_{i-1}‖₂ (string stable if ≤ 1);
- ``collisions``: number of followers whose bumper gap reached ≤ 0 (the episode ends there).

Over several events (:func:`aggregate`): the means are pooled over all samples, the ratios are
averaged over events, the counts and collisions are summed.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from carl_sumo.config import DT_S, HEADWAY_MIN_SPEED_MPS

METRIC_KEYS: tuple[str, ...] = (
    "headway_s", "jerk_mps3", "speed_mps", "ttc_lt_4s_count", "ttc_lt_1_5s_count",
    "dampening_ratio", "worst_successive_ratio", "collisions",
)
COUNT_KEYS = ("ttc_lt_4s_count", "ttc_lt_1_5s_count", "collisions")
RATIO_KEYS = ("dampening_ratio", "worst_successive_ratio")
BETTER = {"jerk_mps3": -1.0, "speed_mps": 1.0, "dampening_ratio": -1.0}
"""The criteria the CA-RL quality bar compares with IDM, and the sign of a better difference:
less jerk, a higher mean speed, a lower dampening ratio."""
POOLED_WEIGHTS = {"headway_s": "n_headway", "jerk_mps3": "n_jerk", "speed_mps": "n_speed"}
"""The pooled means and the per-event sample count that weights each event in them."""


@dataclass
class PlatoonTrajectory:
    """What one event produced: leader and follower series sampled every ``dt`` seconds.

    ``speed`` and ``gap`` have shape (T, n), followers head first; ``gap`` is the bumper-to-bumper
    gap to the predecessor (m).
    """

    event_id: str
    leader_speed: np.ndarray
    speed: np.ndarray
    gap: np.ndarray
    collisions: int = 0
    dt: float = DT_S

    def scored(self, first: int) -> PlatoonTrajectory:
        """The samples from ``first`` on (an event's warm-up cut off,
        :meth:`carl_sumo.data.events.Event.with_warmup`); a run that ended earlier (a collision
        in the warm-up) keeps its last sample and its collisions."""
        if first <= 0:
            return self
        k = min(first, len(self.leader_speed) - 1)
        return PlatoonTrajectory(self.event_id, self.leader_speed[k:], self.speed[k:],
                                 self.gap[k:], self.collisions, self.dt)


def _norm(x: np.ndarray) -> np.ndarray:
    return np.sqrt(np.sum(x * x, axis=0))


def metric_samples(traj: PlatoonTrajectory) -> dict[str, np.ndarray]:
    """The samples the pooled means average: time headway (s, samples with v > 0.5 m/s), speed
    (m/s) and |jerk| (m/s³) of every follower, flattened (what the ECDF figures show)."""
    v = traj.speed
    moving = v > HEADWAY_MIN_SPEED_MPS
    acc = np.diff(v, axis=0) / traj.dt
    return {"headway_s": traj.gap[moving] / v[moving], "speed_mps": v.ravel(),
            "jerk_mps3": np.abs(np.diff(acc, axis=0)).ravel() / traj.dt}


def acceleration_norms(traj: PlatoonTrajectory) -> np.ndarray:
    """‖a_i‖₂ over the event's samples for the leader (index 0) and each follower (m/s²·√samples).

    ``acceleration_norms(t)[1:] / acceleration_norms(t)[0]`` is the per-vehicle profile whose
    mean is the dampening ratio.
    """
    leader_acc = np.diff(traj.leader_speed) / traj.dt
    acc = np.diff(traj.speed, axis=0) / traj.dt
    return np.concatenate([[np.sqrt(np.sum(leader_acc ** 2))], _norm(acc)])


def score_event(traj: PlatoonTrajectory) -> dict[str, float]:
    """Metrics of one event (see the module docstring), plus the sample counts for pooling."""
    v = traj.speed
    pred = np.concatenate([traj.leader_speed[:, None], v[:, :-1]], axis=1)
    d = traj.gap
    samples = metric_samples(traj)
    headway, jerk = samples["headway_s"], samples["jerk_mps3"]
    closing = v - pred
    with np.errstate(divide="ignore", invalid="ignore"):
        ttc = np.where(closing > 0, d / closing, np.inf)
    valid_ttc = ttc > 0
    chain = acceleration_norms(traj)
    norms = chain[1:]
    with np.errstate(divide="ignore", invalid="ignore"):
        successive = chain[1:] / chain[:-1]
    successive = np.where(np.isfinite(successive), successive, np.nan)
    return {
        "event_id": traj.event_id,
        "headway_s": float(headway.mean()) if headway.size else float("nan"),
        "jerk_mps3": float(jerk.mean()) if jerk.size else float("nan"),
        "speed_mps": float(v.mean()),
        "ttc_lt_4s_count": int(np.sum(valid_ttc & (ttc < 4.0))),
        "ttc_lt_1_5s_count": int(np.sum(valid_ttc & (ttc < 1.5))),
        "dampening_ratio": float(np.mean(norms / chain[0])) if chain[0] > 0 else float("nan"),
        "worst_successive_ratio": float(np.nanmax(successive)) if np.isfinite(successive).any()
        else float("nan"),
        "collisions": int(traj.collisions),
        "n_headway": int(headway.size),
        "n_jerk": int(jerk.size),
        "n_speed": int(v.size),
    }


def aggregate(per_event: list[dict[str, float]]) -> dict[str, float]:
    """Metrics over several events: pooled means, event-mean ratios, summed counts."""
    out: dict[str, float] = {}
    for key, weight_key in POOLED_WEIGHTS.items():
        values = np.array([e[key] for e in per_event], float)
        weights = np.array([e[weight_key] for e in per_event], float)
        ok = np.isfinite(values) & (weights > 0)
        out[key] = float(np.sum(values[ok] * weights[ok]) / np.sum(weights[ok])) if ok.any() \
            else float("nan")
    for key in COUNT_KEYS:
        out[key] = int(sum(e[key] for e in per_event))
    for key in RATIO_KEYS:
        values = np.array([e[key] for e in per_event], float)
        out[key] = float(np.nanmean(values)) if np.isfinite(values).any() else float("nan")
    return {key: out[key] for key in METRIC_KEYS}


def event_weights(per_event: list[dict[str, float]], key: str) -> np.ndarray:
    """How much each event counts in the aggregate of a mean metric: its sample count for a
    pooled mean (headway, jerk, speed), 1 for an event-mean ratio."""
    if key in POOLED_WEIGHTS:
        return np.array([e[POOLED_WEIGHTS[key]] for e in per_event], float)
    return np.ones(len(per_event))


def _resample_counts(n: int, n_boot: int, seed: int) -> np.ndarray:
    """How often each of n events is drawn in each of n_boot resamples, shape (n_boot, n)."""
    rng = np.random.default_rng(seed)
    return rng.multinomial(n, np.full(n, 1.0 / n), size=n_boot).astype(float)


def _resampled(per_event: list[dict[str, float]], key: str, counts: np.ndarray) -> np.ndarray:
    """``key`` aggregated as :func:`aggregate` does, once per resample (row of ``counts``)."""
    values = np.array([e[key] for e in per_event], float)
    if key in COUNT_KEYS:
        return counts @ values
    weights = event_weights(per_event, key)
    ok = np.isfinite(values) & (weights > 0)
    w = np.where(ok, weights, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        return (counts @ np.where(ok, values * w, 0.0)) / (counts @ w)


def _interval(stats: np.ndarray, level: float) -> tuple[float, float]:
    if not np.isfinite(stats).any():
        return float("nan"), float("nan")
    tail = 100.0 * (1.0 - level) / 2.0
    lo, hi = np.nanpercentile(stats, [tail, 100.0 - tail])
    return float(lo), float(hi)


def bootstrap_ci(per_event: list[dict[str, float]], n_boot: int = 2000, level: float = 0.95,
                 seed: int = 0) -> dict[str, tuple[float, float]]:
    """Percentile bootstrap interval of every :func:`aggregate` metric, resampling events.

    Each of ``n_boot`` resamples draws len(per_event) events with replacement and aggregates them
    exactly as :func:`aggregate` does (pooled means, event-mean ratios, summed counts). With fewer
    than 2 events there is no interval: (nan, nan).
    """
    n = len(per_event)
    if n < 2:
        return {key: (float("nan"), float("nan")) for key in METRIC_KEYS}
    counts = _resample_counts(n, n_boot, seed)
    return {key: _interval(_resampled(per_event, key, counts), level) for key in METRIC_KEYS}


def paired_difference(a: list[dict[str, float]], b: list[dict[str, float]],
                      keys: tuple[str, ...] = METRIC_KEYS, n_boot: int = 2000,
                      level: float = 0.95, seed: int = 0) -> dict[str, tuple[float, float, float]]:
    """aggregate(a) - aggregate(b) for two models run on the same events, with a paired
    percentile bootstrap interval: each resample draws the same events for both, so what the
    events have in common cancels (much narrower than comparing the two models' own intervals).

    Returns key -> (difference, lo, hi); (nan, nan) intervals with fewer than 2 events.
    ValueError when the two lists do not hold the same events.
    """
    by_id = {e["event_id"]: e for e in b}
    if len(a) != len(b) or set(by_id) != {e["event_id"] for e in a}:
        raise ValueError("paired_difference needs the same events for both models")
    b = [by_id[e["event_id"]] for e in a]
    agg_a, agg_b = aggregate(a), aggregate(b)
    counts = _resample_counts(len(a), n_boot, seed) if len(a) >= 2 else None
    out = {}
    for key in keys:
        diff = float(agg_a[key] - agg_b[key])
        if counts is None:
            out[key] = (diff, float("nan"), float("nan"))
            continue
        out[key] = (diff, *_interval(_resampled(a, key, counts) - _resampled(b, key, counts),
                                     level))
    return out


def seed_comparison(a: np.ndarray, b: np.ndarray, n_perm: int = 10000, seed: int = 0
                    ) -> tuple[float, float, float]:
    """Compare two models by their per-seed values of one metric (one value per training seed).

    Returns (mean(a) - mean(b), Welch's t, two-sided permutation p-value of the difference of
    means: the seed labels are shuffled ``n_perm`` times, p = (1 + #{|Δ*| ≥ |Δ|}) / (1 + n_perm)).
    This is the across-seeds question (is one algorithm better than the other, whichever seed is
    drawn?), which the paired bootstrap over events of two single files cannot answer. NaNs with
    fewer than 2 values on either side.
    """
    a, b = np.asarray(a, float), np.asarray(b, float)
    if len(a) < 2 or len(b) < 2:
        return float("nan"), float("nan"), float("nan")
    diff = float(a.mean() - b.mean())
    se = float(np.sqrt(a.var(ddof=1) / len(a) + b.var(ddof=1) / len(b)))
    t = diff / se if se > 0 else float("nan")
    pooled = np.concatenate([a, b])
    rng = np.random.default_rng(seed)
    perms = np.argsort(rng.random((n_perm, len(pooled))), axis=1)
    shuffled = pooled[perms]
    diffs = shuffled[:, :len(a)].mean(axis=1) - shuffled[:, len(a):].mean(axis=1)
    p = (1 + int(np.sum(np.abs(diffs) >= abs(diff) - 1e-12))) / (1 + n_perm)
    return diff, float(t), float(p)
