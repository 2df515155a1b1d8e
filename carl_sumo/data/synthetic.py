"""A synthetic stop-and-go leader like the paper's Table 3 scenario.

The leader cruises near 25 m/s, brakes hard (-5 m/s²) to near standstill (1 m/s), waits, recovers
at +1.5 m/s², and does so ``cycles`` times. The followers start at 25 m/s with a 40 m gap (close to
the IDM equilibrium gap s0 + v·T = 39.5 m at that speed).
"""

from __future__ import annotations

import numpy as np

from carl_sumo.config import DT_S
from carl_sumo.data.events import Event

STOP_AND_GO_ID = "stop_and_go"


def stop_and_go_event(cycles: int = 3, cruise_mps: float = 25.0, low_mps: float = 1.0,
                      brake_mps2: float = -5.0, recover_mps2: float = 1.5, cruise_s: float = 20.0,
                      wait_s: float = 4.0, gap_m: float = 40.0) -> Event:
    """The stop-and-go event (positions by SUMO's update rule x[k+1] = x[k] + v[k+1]·dt)."""
    accel: list[float] = []

    def hold(seconds: float, value: float) -> None:
        accel.extend([value] * int(round(seconds / DT_S)))

    for _ in range(cycles):
        hold(cruise_s, 0.0)
        hold((cruise_mps - low_mps) / -brake_mps2, brake_mps2)
        hold(wait_s, 0.0)
        hold((cruise_mps - low_mps) / recover_mps2, recover_mps2)
    hold(cruise_s, 0.0)
    speed = np.clip(cruise_mps + np.concatenate([[0.0], np.cumsum(accel)]) * DT_S, low_mps,
                    cruise_mps)
    pos = np.concatenate([[0.0], np.cumsum(speed[1:]) * DT_S])
    return Event(STOP_AND_GO_ID, "carl_sumo_synthetic", "synthetic", pos, speed, 5.0,
                 np.full_like(speed, cruise_mps), np.full_like(speed, gap_m))
