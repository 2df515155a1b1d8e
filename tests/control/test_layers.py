"""The safety layers are parts of their own over the Ploeg law: each bounds the law's output on
its own, off at 0, and the kernel is the law followed by them."""

from __future__ import annotations

import numpy as np

from carl_sumo.control.cacc import _numbers, _ploeg_law, _ploeg_step, parse_ploeg
from carl_sumo.control.layers import apply_layers, layer_params, reaction, safe_speed
from carl_sumo.config import BOUNDS

PRODUCT = "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2:rb=1:gn=6:op=2:ht=0.8"


def _chain(n=4, seed=0):
    rng = np.random.default_rng(seed)
    obs = np.column_stack([rng.uniform(5, 30, n), rng.uniform(-3, 2, n), rng.uniform(1, 40, n),
                           rng.uniform(-6, 2, n)])
    return obs, np.zeros(n, dtype=np.int64), np.zeros(n), np.full(n, -9.0), np.full(n, 3.0)


def test_the_kernel_is_the_law_then_its_layers_bit_for_bit():
    law, layers = _numbers(parse_ploeg(PRODUCT), BOUNDS)
    for seed in range(20):
        obs, mode, held, u_min, u_max = _chain(seed=seed)
        armed, a_ahead = np.arange(4) % 2 == 0, np.full(4, -1.0)
        merge = np.array([np.inf, 80.0, np.inf, 5.0])
        u1, u2 = np.full(4, 0.3), np.full(4, 0.3)
        b1, b2 = np.full(4, -0.5), np.full(4, -0.5)
        gap_off = np.array([0.0, 0.3, -0.2, 0.1])  # gp: each vehicle's learned gap offset (s)
        whole = _ploeg_step(obs, u1, b1, 0.2, np.zeros(4), law, layers, mode, held, u_min,
                            u_max, armed, a_ahead, merge, gap_off)
        parts = _ploeg_law(obs, u2, b2, 0.2, np.zeros(4), law, mode, held, u_min, u_max,
                           gap_off)
        apply_layers(obs, parts, b2, mode, armed, a_ahead, merge, u_min, layers)
        assert whole.tobytes() == parts.tobytes() and u1.tobytes() == u2.tobytes()
        assert b1.tobytes() == b2.tobytes()


def test_a_layer_off_leaves_the_law_and_one_on_only_brakes():
    off = layer_params(0.0, 1.0, 0.5, 0.0, False, 0.0, 2.0, -9.0)
    on = layer_params(2.0, 1.0, 0.5, 6.0, False, 0.0, 2.0, -9.0)
    obs = np.array([[20.0, 0.0, 8.0, -5.0], [20.0, 0.0, 30.0, 0.0]])
    mode, armed, u_min = np.array([0, 0]), np.zeros(2, dtype=np.bool_), np.full(2, -9.0)
    for layers in (off, on):
        out, brake = np.array([0.5, 0.5]), np.zeros(2)
        apply_layers(obs, out, brake, mode, armed, np.zeros(2), np.full(2, np.inf), u_min, layers)
        if layers is off:
            assert out.tolist() == [0.5, 0.5] and np.isinf(brake).all()
        else:  # the head closes in at 5 m/s 8 m behind: it brakes; the second is left alone
            assert out[0] < -1.0 and brake[0] == out[0] and out[1] == 0.5 and np.isinf(brake[1])
    out, brake = np.array([0.5, 0.5]), np.zeros(2)
    reaction(obs, out, brake, mode, armed, np.zeros(2), u_min, on)  # one layer on its own
    ttc_only = out.copy()
    safe_speed(obs, out, brake, mode, armed, u_min, on)
    assert out[0] <= ttc_only[0] and out[1] == 0.5
