"""Synthetic leaders: the stop-and-go leader of the paper's Table 3 scenario, and random
hard-braking leaders for training.

The leader cruises near 25 m/s, brakes hard (-5 m/s²) to near standstill (1 m/s), waits, recovers
at +1.5 m/s², and does so ``cycles`` times. The followers start at 25 m/s with a 40 m gap (close to
the IDM equilibrium gap s0 + v·T = 39.5 m at that speed).
"""

from __future__ import annotations

import math

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
    return _event(STOP_AND_GO_ID, "carl_sumo_synthetic", accel, cruise_mps, low_mps, gap_m)


def _event(event_id: str, source: str, accel: list[float], cruise_mps: float, low_mps: float,
           gap_m: float) -> Event:
    speed = np.clip(cruise_mps + np.concatenate([[0.0], np.cumsum(accel)]) * DT_S, low_mps,
                    cruise_mps)
    pos = np.concatenate([[0.0], np.cumsum(speed[1:]) * DT_S])
    return Event(event_id, source, "synthetic", pos, speed, 5.0,
                 np.full_like(speed, cruise_mps), np.full_like(speed, gap_m))


SINE_SOURCE = "carl_sumo_sine"
"""The ``source`` of a sinusoidal leader (:func:`sine_event`)."""


def sine_event(event_id: str, omega: float, amplitude_mps: float, base_speed_mps: float,
               lead_in_steps: int, total_steps: int, gap_m: float) -> Event:
    """A leader at ``base_speed_mps`` for ``lead_in_steps`` steps, then v = v0 + A·sin(ω·t) (ω in
    rad/s, A in m/s) up to step ``total_steps``: the excitation of the string-stability test
    (:class:`carl_sumo.experiments.string_stability.SineTest`); the followers start at v0 and
    ``gap_m`` (positions by SUMO's update rule)."""
    t = np.arange(total_steps + 1) * DT_S
    started = np.maximum(t - lead_in_steps * DT_S, 0.0)
    speed = base_speed_mps + amplitude_mps * np.sin(omega * started)
    pos = np.concatenate([[0.0], np.cumsum(speed[1:]) * DT_S])
    return Event(event_id, SINE_SOURCE, "synthetic", pos, speed, 5.0,
                 np.full_like(speed, base_speed_mps), np.full_like(speed, gap_m))


SINE_TRAINING_OMEGAS = (0.1, 3.0)
"""The frequency range of :func:`sine_events` (rad/s): that of the string-stability gate, whose
lowest frequency (0.05 rad/s) would need a 250 s leader for its two periods."""


def sine_events(n: int, seed: int = 0) -> list[Event]:
    """``n`` sinusoidal leaders for training, so that an agent meets the excitation it is judged
    by for string stability: ω log-spaced over :data:`SINE_TRAINING_OMEGAS` (rad/s, shuffled with
    ``seed``), base speed 10-25 m/s, speed amplitude 0.5-2 m/s (the gate's 0.5 and 2 m/s) capped
    at an acceleration amplitude of 2 m/s², 20 s of cruise, then three periods of sine and at
    least 60 s; the followers start at a gap of 1.5 s."""
    rng = np.random.default_rng(seed)
    low, high = SINE_TRAINING_OMEGAS
    omegas = np.geomspace(low, high, n) if n > 1 else np.array([math.sqrt(low * high)])
    events = []
    for k, omega in enumerate(rng.permutation(omegas)):
        speed = rng.uniform(10.0, 25.0)
        amplitude = min(rng.uniform(0.5, 2.0), 2.0 / omega)
        lead_in = int(round(20.0 / DT_S))
        sine = int(round(max(60.0, 3 * 2 * math.pi / omega) / DT_S))
        events.append(sine_event(f"sine_{seed}_{k:03d}", float(omega), amplitude, speed, lead_in,
                                 lead_in + sine, 1.5 * speed))
    return events


BRAKING_SOURCE = "carl_sumo_braking"
"""The ``source`` of :func:`braking_events`."""


def braking_events(n: int, seed: int = 0) -> list[Event]:
    """``n`` hard-braking leaders for training, drawn with ``seed``: cruise at 15-30 m/s for
    5-15 s, brake at -3 to -6 m/s² down to 0.5-8 m/s, wait 1-6 s, recover at 1-2.5 m/s², cruise
    10 s; the followers start at the cruise speed with a gap of 1.5 s. Freeway speeds and hard
    braking, which the NGSIM I-80 events (about 8 m/s) lack; none is the Table 3 leader (three
    brakings from 25 m/s at -5 m/s² to 1 m/s)."""
    rng = np.random.default_rng(seed)
    events = []
    for k in range(n):
        cruise, low = rng.uniform(15.0, 30.0), rng.uniform(0.5, 8.0)
        brake, recover = rng.uniform(-6.0, -3.0), rng.uniform(1.0, 2.5)
        accel: list[float] = []
        for seconds, value in ((rng.uniform(5.0, 15.0), 0.0), ((cruise - low) / -brake, brake),
                               (rng.uniform(1.0, 6.0), 0.0), ((cruise - low) / recover, recover),
                               (10.0, 0.0)):
            accel.extend([value] * int(round(seconds / DT_S)))
        events.append(_event(f"braking_{seed}_{k:03d}", BRAKING_SOURCE, accel, cruise, low,
                             1.5 * cruise))
    return events
