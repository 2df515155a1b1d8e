import math

import numpy as np

from carl_sumo.config import BOUNDS, IDM
from carl_sumo.controllers import ZeroAdjustment, idm_acceleration, total_acceleration


def test_idm_hand_computed():
    # v = 10, d = 20, Δv = -2 (closing): s* = 2 + 10*1.5 + 10*2/(2*sqrt(6)) = 21.0825
    s_star = 2.0 + 15.0 + 20.0 / (2.0 * math.sqrt(6.0))
    expected = 3.0 * (1.0 - (10.0 / (120 / 3.6)) ** 4 - (s_star / 20.0) ** 2)
    assert math.isclose(float(idm_acceleration(10.0, 20.0, -2.0)), expected, rel_tol=1e-12)
    # free road at v0: no acceleration
    assert abs(float(idm_acceleration(IDM.desired_speed_mps, 1e9, 0.0))) < 1e-9
    # standstill at the jam distance s0: a = -a_max·(s0/s0)² + a_max = 0
    assert abs(float(idm_acceleration(0.0, IDM.min_gap_m, 0.0))) < 1e-12


def test_total_acceleration_clips_adjustment_and_total():
    obs = np.array([[10.0, 0.0, 30.0, 0.0], [10.0, 0.0, 0.5, -5.0], [0.0, 0.0, 100.0, 0.0]])
    a = total_acceleration(obs, np.array([10.0, 0.0, 10.0]))
    base = idm_acceleration(obs[:, 0], obs[:, 2], obs[:, 3])
    assert math.isclose(a[0], min(base[0] + BOUNDS.adj_max_mps2, BOUNDS.acc_max_mps2))
    assert a[1] == BOUNDS.acc_min_mps2  # hard braking is bounded below
    assert a[2] == BOUNDS.acc_max_mps2


def test_zero_adjustment_is_plain_idm():
    c = ZeroAdjustment()
    c.reset(3)
    obs = np.array([[10.0, 0.0, 30.0, 1.0]] * 3)
    assert np.array_equal(total_acceleration(obs, c.adjustment(obs)),
                          np.clip(idm_acceleration(obs[:, 0], obs[:, 2], obs[:, 3]), -9, 3))
