"""Two controllers from outside carl-sumo, for ``--controller examples/my_controller.py:NAME``.

``constant_gap``: a plain callable f(observations) -> accelerations, observations an (n, 4) array
[v m/s, a m/s², d m, Δv m/s] head first, accelerations (n,) in m/s²: a simple constant-time-gap
law (h = 1.2 s, kp = 0.2 1/s², kd = 0.7 1/s, radar only) that never drives faster than a cruise
speed of 30 m/s. A controller keeps its own cruise speed: with nothing ahead within the sensors'
range (a free road in ``carl-sumo study``) it sees d = that range and Δv = 0.

``ZeroAdjust``: a class with ``reset`` and ``adjustment``: a_adj = 0 on IDM (IDM itself).

    carl-sumo simulate --controller examples/my_controller.py:constant_gap --events 5
"""

import numpy as np


V_CRUISE = 30.0  # m/s


def constant_gap(obs: np.ndarray) -> np.ndarray:
    v, d, dv = obs[:, 0], obs[:, 2], obs[:, 3]
    return np.minimum(0.2 * (d - 2.0 - 1.2 * v) + 0.7 * dv, 0.5 * (V_CRUISE - v))


class ZeroAdjust:
    name = "zero-adjust"

    def reset(self, n_followers: int) -> None:
        self.n = n_followers

    def adjustment(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros(obs.shape[0])
