"""Sensor noise and the predecessor tracker (carl_sumo.control.sensors)."""

import numpy as np
import pytest

from carl_sumo.control.channel import Impairments
from carl_sumo.config import DT_S
from carl_sumo.control.sensors import (GAP_NOISE_M, REL_SPEED_NOISE_MPS, PredecessorTracker, Sensors,
                               steady_state_gain)


def _relative_motion(steps: int, a_pred, a_own) -> np.ndarray:
    """True observations [v, a, d, Δv] of one follower, as SUMO moves them (the position advances
    with the new speed), for predecessor and own accelerations over each step."""
    v_pred, v, d = 15.0, 15.0, 20.0
    rows = [[v, 0.0, d, v_pred - v]]
    for k in range(1, steps):
        v_pred += a_pred[k] * DT_S
        v += a_own[k] * DT_S
        d += (v_pred - v) * DT_S
        rows.append([v, a_own[k], d, v_pred - v])
    return np.array(rows)


def test_without_noise_and_a_steady_predecessor_the_estimates_are_the_measurements():
    steps = 100
    own = np.where(np.arange(steps) < 50, 0.5, -1.0)  # the follower's own acceleration is known
    true = _relative_motion(steps, np.zeros(steps), own)
    tracker = PredecessorTracker()
    for row in true:
        est = tracker.estimate(row[None, :])
        np.testing.assert_allclose(est[0], row, atol=1e-9)


def test_the_tracker_filters_the_noise_and_finds_the_predecessors_acceleration():
    rng = np.random.default_rng(0)
    steps = 600
    a_pred = 1.5 * np.sin(np.arange(steps) * DT_S * 2 * np.pi / 20.0)  # a 20 s oscillation
    true = _relative_motion(steps, a_pred, np.zeros(steps))
    tracker = PredecessorTracker()
    measured = true.copy()
    measured[:, 2] += rng.normal(0, GAP_NOISE_M, steps)
    measured[:, 3] += rng.normal(0, REL_SPEED_NOISE_MPS, steps)
    est = np.array([tracker.estimate(row[None, :])[0] for row in measured])
    settled = slice(100, None)
    err_d = np.sqrt(np.mean((est[settled, 2] - true[settled, 2]) ** 2))
    err_v = np.sqrt(np.mean((est[settled, 3] - true[settled, 3]) ** 2))
    assert err_d < 0.5 * GAP_NOISE_M and err_v < 0.7 * REL_SPEED_NOISE_MPS
    a_est = np.array(tracker._tracks[0][1][2])
    assert abs(a_est - a_pred[-1]) < 0.5
    # the leader acceleration a Ploeg head derives from the change of the estimated relative
    # speed is far less noisy than from the raw one (σ √2 / dt = 1.4 m/s² there)
    diff_raw = np.diff(measured[settled, 3]) / DT_S
    diff_est = np.diff(est[settled, 3]) / DT_S
    assert np.std(diff_est - np.diff(true[settled, 3]) / DT_S) < 0.5 * np.std(
        diff_raw - np.diff(true[settled, 3]) / DT_S)


def test_the_gain_is_finite_and_trusts_the_measurements_more_for_a_livelier_predecessor():
    k = steady_state_gain(2.0)
    assert k.shape == (3, 2) and np.all(np.isfinite(k))
    assert 0 < k[0, 0] < 1 and 0 < k[1, 1] < 1
    # a larger expected jerk trusts the measurements more
    assert steady_state_gain(8.0)[1, 1] > k[1, 1] > steady_state_gain(0.5)[1, 1]


def test_a_track_restarts_when_the_predecessor_changes_or_is_gone():
    tracker = PredecessorTracker()
    obs = np.array([[10.0, 0.0, 30.0, 1.0], [10.0, 0.0, 25.0, -1.0]])
    tracker.estimate(obs, ["a", "b"], ["x", "a"])
    moved = obs + [0.0, 0.0, 0.5, 0.2]
    est = tracker.estimate(moved, ["a", "b"], ["x", "new"])
    assert est[1, 2] == moved[1, 2] and est[1, 3] == moved[1, 3]  # a new track: the measurement
    assert est[0, 2] != moved[0, 2]  # the kept track filters
    est = tracker.estimate(moved, ["a", "b"], [None, "new"])
    assert est[0, 2] == moved[0, 2] and "a" not in tracker._tracks


def test_sensors_exist_only_with_noise_and_filter_when_asked():
    assert Sensors.of(None, "e") is None
    assert Sensors.of(Impairments(loss=0.3), "e") is None
    raw = Sensors.of(Impairments(sensor_noise=True, seed=3), "e")
    filtered = Sensors.of(Impairments(sensor_noise=True, sensor_filter=True, seed=3), "e")
    assert raw.tracker is None and filtered.tracker is not None
    true = _relative_motion(300, np.zeros(300), np.zeros(300))
    seen_raw = np.array([raw.measure(row[None, :])[0] for row in true])
    seen_filtered = np.array([filtered.measure(row[None, :])[0] for row in true])
    np.testing.assert_array_equal(seen_raw[:, :2], true[:, :2])
    np.testing.assert_array_equal(seen_filtered[:, :2], true[:, :2])
    assert np.std(seen_filtered[50:, 3] - true[50:, 3]) < 0.8 * np.std(seen_raw[50:, 3] - true[50:, 3])


@pytest.mark.parametrize("extra", [[], ["--comm-loss", "0.3"]])
def test_a_filter_without_noise_is_refused(tmp_path, capsys, extra):
    from carl_sumo.cli import main

    code = main(["simulate", "--controller", "ploeg", "--sensor-filter", *extra])
    err = capsys.readouterr().err
    assert code == 2 and "--sensor-noise" in err and len(err.strip().splitlines()) == 1
