"""What a follower measures itself: sensor noise, and the tracker that filters it.

**Noise** (``--sensor-noise``): the gap and the relative speed a follower measures get Gaussian
noise with standard deviations :data:`GAP_NOISE_M` and :data:`REL_SPEED_NOISE_MPS`, drawn anew
every step; its own speed and acceleration are exact. The metrics stay on the true state.

**Tracker** (``--sensor-filter``). Real ACC and CACC vehicles do not act on raw radar samples: a
tracker filters them. With ``--sensor-filter`` every follower runs a Kalman filter on what it
measures (gap d, m; relative speed Δv = v_pred - v, m/s), knowing its own acceleration a (m/s²),
and acts on the estimates instead of the samples.

State x = [d, Δv, a_pred] (m, m/s, m/s²), step dt = 0.1 s, from step k-1 to k (the vehicle's own
acceleration over that step, a_k, is known; SUMO advances positions with the new speed):

    Δv_k = Δv_{k-1} + dt·(a_pred - a_k)
    d_k  = d_{k-1} + dt·Δv_k = d_{k-1} + dt·Δv_{k-1} + dt²·(a_pred - a_k)
    a_pred,k = a_pred,k-1 + w,   w: the predecessor's unknown jerk over the step

The jerk is white noise of σ = :data:`TRACKER_JERK_MPS3` (the discrete white-noise-jerk model:
Q = σ² g gᵀ with g = [dt³/6, dt²/2, dt]). The measurements z = [d, Δv] have the noise above
(R = diag(σ_d², σ_Δv²)). The gain is the filter's steady-state Kalman gain K (3×2, from iterating
the Riccati equation, once per σ): every step

    x⁻ = F x + B a_k,     x = x⁻ + K (z - H x⁻),

and a track starts at its first measurement, x = [z_d, z_Δv, 0]. A track belongs to a vehicle
and its predecessor: when the predecessor changes (in the mixed-traffic study) or there is none
within sensing range, the track starts again.
"""

from __future__ import annotations

from collections.abc import Hashable, Sequence
from functools import lru_cache
from typing import TYPE_CHECKING

import numpy as np

from carl_sumo.config import DT_S

if TYPE_CHECKING:
    from carl_sumo.control.channel import Impairments

GAP_NOISE_M = 0.1
"""σ of the measured bumper gap (m): the order of the range accuracy of automotive long-range
radars (about ±0.1 m)."""

REL_SPEED_NOISE_MPS = 0.1
"""σ of the measured relative speed (m/s): the order of their range-rate accuracy (about ±0.1 m/s)."""

TRACKER_JERK_MPS3 = 2.0
"""σ of the predecessor's jerk in the tracker's model (m/s³): how fast it expects the predecessor's
acceleration to change. Chosen on NGSIM training events (docs/robustness.md)."""


@lru_cache(maxsize=8)
def steady_state_gain(jerk_mps3: float = TRACKER_JERK_MPS3, dt: float = DT_S,
                      gap_noise_m: float = GAP_NOISE_M,
                      rel_speed_noise_mps: float = REL_SPEED_NOISE_MPS) -> np.ndarray:
    """The steady-state Kalman gain K (3×2, read-only: cached) of the model in the module
    docstring."""
    f = np.array([[1.0, dt, dt * dt], [0.0, 1.0, dt], [0.0, 0.0, 1.0]])
    g = np.array([dt ** 3 / 6.0, dt * dt / 2.0, dt])
    q = jerk_mps3 ** 2 * np.outer(g, g)
    h = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    r = np.diag([gap_noise_m ** 2, rel_speed_noise_mps ** 2])
    p = np.diag([gap_noise_m ** 2, rel_speed_noise_mps ** 2, 1.0])
    gain = np.zeros((3, 2))
    for _ in range(10_000):
        p_prior = f @ p @ f.T + q
        gain_new = p_prior @ h.T @ np.linalg.inv(h @ p_prior @ h.T + r)
        p = (np.eye(3) - gain_new @ h) @ p_prior
        if np.abs(gain_new - gain).max() < 1e-12:
            break
        gain = gain_new
    gain_new.flags.writeable = False
    return gain_new


class PredecessorTracker:
    """The trackers of a set of vehicles, each on its current predecessor (module docstring)."""

    def __init__(self, jerk_mps3: float | None = None):
        self.gain = steady_state_gain(TRACKER_JERK_MPS3 if jerk_mps3 is None else jerk_mps3)
        self._tracks: dict[Hashable, tuple[Hashable, np.ndarray]] = {}

    def estimate(self, obs: np.ndarray, vehicles: Sequence[Hashable] | None = None,
                 predecessors: Sequence[Hashable | None] | None = None) -> np.ndarray:
        """Observations [v, a, d, Δv, ...] (n, 4+) with the measured d and Δv replaced by the
        tracker's estimates. ``vehicles``: a key per row (default: the row numbers, a fixed
        platoon); ``predecessors``: each row's predecessor (None: none in range, no track;
        default: a fixed predecessor per row)."""
        n = len(obs)
        keys = range(n) if vehicles is None else vehicles
        preds = [0] * n if predecessors is None else predecessors
        prior = np.zeros((n, 3))  # fresh rows: replaced by their measurement below
        fresh = np.zeros(n, dtype=bool)
        tracks = self._tracks
        for row, (key, pred) in enumerate(zip(keys, preds)):
            track = tracks.get(key)
            if pred is None or track is None or track[0] != pred:
                fresh[row] = True
            else:
                prior[row] = track[1]
        z_d, z_v, a_own = obs[:, 2], obs[:, 3], obs[:, 1]
        dt = DT_S
        # x⁻ = F x + B a_k
        rel_acc = prior[:, 2] - a_own
        d_prior = prior[:, 0] + dt * prior[:, 1] + dt * dt * rel_acc
        v_prior = prior[:, 1] + dt * rel_acc
        innov_d, innov_v = z_d - d_prior, z_v - v_prior
        k = self.gain
        est = np.column_stack([d_prior + k[0, 0] * innov_d + k[0, 1] * innov_v,
                               v_prior + k[1, 0] * innov_d + k[1, 1] * innov_v,
                               prior[:, 2] + k[2, 0] * innov_d + k[2, 1] * innov_v])
        est[fresh] = np.column_stack([z_d[fresh], z_v[fresh], np.zeros(int(fresh.sum()))])
        self._tracks = {key: (pred, est[row]) for row, (key, pred) in enumerate(zip(keys, preds))
                        if pred is not None}
        out = np.array(obs, dtype=np.float64)
        out[:, 2] = np.maximum(est[:, 0], 0.01)
        out[:, 3] = est[:, 1]
        return out


class Sensors:
    """What the followers of one run measure: noisy gap and relative speed, filtered by a
    :class:`PredecessorTracker` when ``filtered`` (see the module docstring)."""

    def __init__(self, rng: np.random.Generator, filtered: bool = False):
        self.rng = rng
        self.tracker = PredecessorTracker() if filtered else None

    @classmethod
    def of(cls, impairments: Impairments | None, key: str) -> Sensors | None:
        """The sensors of a run (``key``: its event ID or name; draws from stream 0 of
        ``impairments``), or None when its sensors are perfect."""
        if impairments is None or not impairments.sensor_noise:
            return None
        return cls(impairments.rng(key, 0), impairments.sensor_filter)

    def measure(self, obs: np.ndarray, vehicles: Sequence[Hashable] | None = None,
                predecessors: Sequence[Hashable | None] | None = None) -> np.ndarray:
        """Observations [v, a, d, Δv, ...] with noise on d (kept ≥ 0.01 m) and Δv, the tracker's
        estimates when filtered (``vehicles``, ``predecessors``: see
        :meth:`PredecessorTracker.estimate`)."""
        out = np.array(obs, dtype=np.float64)
        out[:, 2] = np.maximum(out[:, 2] + self.rng.normal(0.0, GAP_NOISE_M, len(out)), 0.01)
        out[:, 3] += self.rng.normal(0.0, REL_SPEED_NOISE_MPS, len(out))
        if self.tracker is not None:
            return self.tracker.estimate(out, vehicles, predecessors)
        return out
