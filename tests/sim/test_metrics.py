import math

import numpy as np

from carl_sumo.sim.metrics import METRIC_KEYS, PlatoonTrajectory, aggregate, score_event


def test_hand_computed_two_followers():
    leader = np.array([10.0, 11.0, 11.0, 10.0])          # a0 = [1, 0, -1] (dt = 1)
    speed = np.array([[10.0, 10.0], [10.5, 10.0], [11.0, 10.5], [10.5, 10.5]])
    gap = np.array([[20.0, 10.0], [20.0, 10.0], [20.0, 1.0], [20.0, 10.0]])
    m = score_event(PlatoonTrajectory("e", leader, speed, gap, dt=1.0))
    assert math.isclose(m["speed_mps"], speed.mean())
    assert math.isclose(m["headway_s"], np.mean(gap / speed))
    # follower accelerations (dt = 1): f0 = [0.5, 0.5, -0.5], f1 = [0, 0.5, 0]
    jerks = [0.0, 1.0, 0.5, 0.5]
    assert math.isclose(m["jerk_mps3"], np.mean(jerks))
    # TTC: f1 closes on f0 at t=0 (v 10 vs 10: no), t=1: f1 10 vs f0 10.5 no; f0 vs leader:
    # t=2: f0 11 vs 11 no; t=3: f0 10.5 vs leader 10 -> TTC 20/0.5 = 40; f1 at t=2: 10.5 vs 11 no
    assert m["ttc_lt_4s_count"] == 0 and m["ttc_lt_1_5s_count"] == 0
    n0, n1, nl = math.sqrt(0.75), math.sqrt(0.25), math.sqrt(2.0)
    assert math.isclose(m["dampening_ratio"], (n0 / nl + n1 / nl) / 2)
    assert math.isclose(m["worst_successive_ratio"], max(n0 / nl, n1 / n0))
    assert m["collisions"] == 0


def test_ttc_counts_and_collisions():
    leader = np.full(5, 5.0)
    speed = np.array([[5.0], [8.0], [9.0], [10.0], [5.0]])
    gap = np.array([[12.0], [12.0], [5.0], [4.0], [0.0]])
    m = score_event(PlatoonTrajectory("e", leader, speed, gap, collisions=1, dt=0.1))
    # TTC = 12/3 = 4 (not < 4), 5/4 = 1.25, 4/5 = 0.8; gap 0 at equal speed is no TTC sample
    assert m["ttc_lt_4s_count"] == 2 and m["ttc_lt_1_5s_count"] == 2
    assert m["collisions"] == 1


def test_aggregate_pools_means_and_sums_counts():
    a = {"headway_s": 1.0, "jerk_mps3": 1.0, "speed_mps": 10.0, "ttc_lt_4s_count": 2,
         "ttc_lt_1_5s_count": 1, "dampening_ratio": 0.5, "worst_successive_ratio": 1.0,
         "collisions": 0, "n_headway": 10, "n_jerk": 10, "n_speed": 10}
    b = dict(a, headway_s=2.0, speed_mps=20.0, n_headway=30, n_speed=30, dampening_ratio=1.0,
             collisions=1)
    out = aggregate([a, b])
    assert list(out) == list(METRIC_KEYS)
    assert math.isclose(out["headway_s"], 1.75) and math.isclose(out["speed_mps"], 17.5)
    assert out["ttc_lt_4s_count"] == 4 and out["collisions"] == 1
    assert math.isclose(out["dampening_ratio"], 0.75)


def test_seed_comparison_welch_t_and_permutation_p():
    from carl_sumo.sim.metrics import seed_comparison

    a, b = np.array([0.64, 0.66, 0.65, 0.67, 0.63]), np.array([0.70, 0.69, 0.72, 0.68, 0.71])
    diff, t, p = seed_comparison(a, b, n_perm=4000)
    se = math.sqrt(a.var(ddof=1) / 5 + b.var(ddof=1) / 5)
    assert abs(diff - (a.mean() - b.mean())) < 1e-12 and abs(t - diff / se) < 1e-9
    # fully separated groups of 5: the exact two-sided p is 2 / C(10, 5) = 0.0079
    assert p < 0.02
    same = seed_comparison(a, a[::-1], n_perm=4000)  # the same values: no difference at all
    assert same[2] == 1.0 and abs(same[1]) < 1e-9
    assert all(math.isnan(x) for x in seed_comparison(a[:1], b))
    assert seed_comparison(a, b, n_perm=4000) == (diff, t, p)  # seeded: repeatable
