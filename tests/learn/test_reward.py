import math

import numpy as np

from carl_sumo.config import REWARD
from carl_sumo.learn.reward import headway_reward, platoon_reward


def lognormal(h, mu=0.4226, sigma=0.4366):
    return math.exp(-(math.log(h) - mu) ** 2 / (2 * sigma ** 2)) / (h * sigma * math.sqrt(2 * math.pi))


def test_headway_term_is_the_lognormal_pdf():
    for h in (0.5, 1.26, 2.0, 4.0):
        assert math.isclose(headway_reward(h), lognormal(h), rel_tol=1e-12)


def test_reward_hand_computed():
    # follower 0: v=10, a=1 after a=0 (jerk 10 m/s³), gap 15, closing at 5 m/s -> TTC 3 s
    # follower 1: v=10, gap 20, opening: no safety term, no jerk
    obs = np.array([[10.0, 1.0, 15.0, -5.0], [10.0, 0.0, 20.0, 1.0]])
    r, collided = platoon_reward(obs, np.zeros(2))
    assert math.isclose(r[0], lognormal(1.5) + math.log(3.0 / 4.0) - (10.0 / 60.0) ** 2)
    assert math.isclose(r[1], lognormal(2.0))
    assert not collided.any()


def test_collision_penalty():
    obs = np.array([[10.0, 0.0, -0.1, -5.0]])
    r, collided = platoon_reward(obs, np.zeros(1))
    assert collided[0] and r[0] < REWARD.collision_penalty + 1.0


def test_optional_control_effort_term():
    from dataclasses import replace

    obs = np.array([[10.0, 2.0, 20.0, 0.0], [10.0, -1.0, 20.0, 0.0]])
    plain, _ = platoon_reward(obs, obs[:, 1].copy())  # no jerk: only the headway term
    with_effort, _ = platoon_reward(obs, obs[:, 1].copy(), replace(REWARD, w_accel=0.5))
    assert np.allclose(plain - with_effort, [0.5 * 4.0, 0.5 * 1.0])


def test_optional_spacing_term_penalises_the_time_gap_error():
    from dataclasses import replace

    cfg = replace(REWARD, w_spacing=2.0, spacing_gap_s=0.7)
    # v = 10 m/s: the reference is 2 + 0.7·10 = 9 m; 9 m, 12 m (0.3 s long), 7 m (0.2 s short),
    # 60 m (error capped at 1 s²); v = 0.5 m/s: the error is divided by 1 m/s, not 0.5
    obs = np.array([[10.0, 0.0, 9.0, 0.0], [10.0, 0.0, 12.0, 0.0], [10.0, 0.0, 7.0, 0.0],
                    [10.0, 0.0, 60.0, 0.0], [0.5, 0.0, 3.35, 0.0]])
    plain, _ = platoon_reward(obs, obs[:, 1].copy())
    spaced, _ = platoon_reward(obs, obs[:, 1].copy(), cfg)
    assert np.allclose(plain - spaced, [0.0, 2.0 * 0.09, 2.0 * 0.04, 2.0, 2.0 * 1.0])


def test_the_head_may_have_its_own_spacing_gap():
    from dataclasses import replace

    cfg = replace(REWARD, w_spacing=1.0, spacing_gap_s=0.7, spacing_head_gap_s=1.4)
    # both at 2 + 1.4·10 = 16 m: the head is at its reference, the second 0.7 s long
    obs = np.array([[10.0, 0.0, 16.0, 0.0], [10.0, 0.0, 16.0, 0.0]])
    plain, _ = platoon_reward(obs, obs[:, 1].copy())
    spaced, _ = platoon_reward(obs, obs[:, 1].copy(), cfg)
    assert np.allclose(plain - spaced, [0.0, 0.49])


def test_the_spacing_budget_prices_the_platoons_mean_gap_error():
    """``spacing_budget``: one follower 0.3 s long and one 0.3 s short cost nothing together;
    every follower pays the square of the mean error (here 0.1 s: all three 0.1 s long)."""
    from dataclasses import replace

    cfg = replace(REWARD, w_spacing=1.0, spacing_gap_s=0.7, spacing_budget=True)
    v = 10.0  # the reference 2 + 0.7·10 = 9 m
    balanced = np.array([[v, 0.0, 12.0, 0.0], [v, 0.0, 6.0, 0.0], [v, 0.0, 9.0, 0.0]])
    plain, _ = platoon_reward(balanced, balanced[:, 1].copy())
    spaced, _ = platoon_reward(balanced, balanced[:, 1].copy(), cfg)
    assert np.allclose(plain - spaced, 0.0)
    long = balanced + np.array([0.0, 0.0, 1.0, 0.0])
    plain, _ = platoon_reward(long, long[:, 1].copy())
    spaced, _ = platoon_reward(long, long[:, 1].copy(), cfg)
    assert np.allclose(plain - spaced, 0.01)
    own, _ = platoon_reward(long, long[:, 1].copy(), replace(cfg, spacing_budget=False))
    assert np.allclose(plain - own, [0.16, 0.04, 0.01])


def test_a_heavy_vehicle_may_have_its_own_spacing_gap():
    from dataclasses import replace

    cfg = replace(REWARD, w_spacing=1.0, spacing_gap_s=0.6, spacing_head_gap_s=1.4,
                  spacing_heavy_gap_s=0.8)
    # all at 2 + 0.8·10 = 10 m: the heavy follower (b_max 6 m/s²) is at its reference, the car
    # 0.2 s long; a heavy head keeps the head's gap (0.6 s short)
    obs = np.array([[10.0, 0.0, 10.0, 0.0], [10.0, 0.0, 10.0, 0.0], [10.0, 0.0, 10.0, 0.0]])
    b_max = np.array([6.0, 6.0, 9.0])
    plain, _ = platoon_reward(obs, obs[:, 1].copy())
    spaced, _ = platoon_reward(obs, obs[:, 1].copy(), cfg, b_max)
    assert np.allclose(plain - spaced, [0.36, 0.0, 0.04])
    # without the vehicles' braking, nobody is heavy
    unknown, _ = platoon_reward(obs, obs[:, 1].copy(), cfg)
    assert np.allclose(plain - unknown, [0.36, 0.04, 0.04])


def test_optional_critical_ttc_term_counts_the_metrics_samples():
    from dataclasses import replace

    cfg = replace(REWARD, w_critical=3.0)
    # closing at 10 m/s: TTC 1.4 s (below 1.5: penalised), 1.5 s and 2 s (not); opening: not;
    # a collision (d ≤ 0) has its own penalty and no critical term
    obs = np.array([[20.0, 0.0, 14.0, -10.0], [20.0, 0.0, 15.0, -10.0], [20.0, 0.0, 20.0, -10.0],
                    [20.0, 0.0, 5.0, 1.0], [20.0, 0.0, -0.1, -10.0]])
    plain, _ = platoon_reward(obs, obs[:, 1].copy())
    critical, _ = platoon_reward(obs, obs[:, 1].copy(), cfg)
    assert np.allclose(plain - critical, [3.0, 0.0, 0.0, 0.0, 0.0])


def test_optional_amplification_term_prices_a_follower_harder_than_its_predecessor():
    from dataclasses import replace

    cfg = replace(REWARD, w_amplify=2.0)
    # a: head -1.5 (no term: its predecessor is the human leader), then 1.0 (weaker than -1.5:
    # none), -2.0 (harder than 1.0: 2·(4 - 1) = 6), -2.0 (as hard: none), 0.5 (none)
    a = np.array([-1.5, 1.0, -2.0, -2.0, 0.5])
    obs = np.column_stack([np.full(5, 20.0), a, np.full(5, 30.0), np.zeros(5)])
    plain, _ = platoon_reward(obs, a.copy())
    amplify, _ = platoon_reward(obs, a.copy(), cfg)
    assert np.allclose(plain - amplify, [0.0, 0.0, 6.0, 0.0, 0.0])
