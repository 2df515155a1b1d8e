"""Vehicle dynamics of the followers carl-sumo drives: actuator lag, actuation dead time, limits.

Every 0.1 s step k a follower's controller commands u(k) (m/s²); the vehicle realises it as

- the command clipped to the vehicle's limits:        u(k) in [-b_max, a_max]
- reaching the powertrain after D steps of dead time:  c(k) = u(k - D)   (u = 0 before the start)
- through a first-order lag of time constant τ (Plexe's engine model ``FOLM`` in SUMO's ``CC``
  car-following model): a(k+1) = α·c(k) + (1 - α)·a(k), α = dt/(τ + dt), clipped to the limits
- and integrated as today:                             v(k+1) = max(v(k) + a(k+1)·dt, 0)

τ = 0 and D = 0 give the ideal plant (a = u). The *ideal* plant of the paper's protocol skips this
module altogether; a plant with τ = 0 and D = 0 on cars gives it bit for bit (tested).

Vehicle classes (:data:`VEHICLE_CLASSES`) draw τ and D per follower and per event from their
ranges; a fleet (``--fleet car:0.8,truck:0.2``) draws each follower's class. ``--plant real`` is
:data:`REAL_PLANT`: the default fleet and V2V delay of the real-plant protocol.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass

import numpy as np
from numba import njit

from carl_sumo.config import BOUNDS, DT_S, SCENARIO
from carl_sumo.errors import InputError


@dataclass(frozen=True)
class VehicleClass:
    """One class of vehicle (units in the names). ``vtype``: its SUMO vType when carl-sumo drives
    it (``routes/vtypes.add.xml``, same length, accel and decel)."""

    name: str
    length_m: float
    a_max_mps2: float
    b_max_mps2: float              # the largest deceleration, as a positive number
    tau_s: tuple[float, float]     # range of the powertrain lag τ (s), drawn uniformly
    dead_time_s: tuple[float, float]  # range of the actuation dead time (s), in whole steps
    vtype: str
    source: str


VEHICLE_CLASSES: dict[str, VehicleClass] = {
    "car": VehicleClass(
        "car", SCENARIO.vehicle_length_m, BOUNDS.acc_max_mps2, -BOUNDS.acc_min_mps2,
        (0.1, 0.5), (0.0, 0.1), "cacc",
        "passenger car: τ = 0.1 s identified on a Toyota Prius (Ploeg et al. 2011, 2014), 0.5 s "
        "the default engine lag of Plexe's CC model in SUMO; dead time up to one step; length "
        "and limits those of carl-sumo's CACC vehicle (5 m, 3 m/s², -9 m/s²)"),
    "truck": VehicleClass(
        "truck", 12.0, 1.0, 6.0, (0.4, 0.6), (0.1, 0.2), "cacc_truck",
        "heavy truck: a slower powertrain and brakes (τ 0.4-0.6 s, dead time 0.1-0.2 s), "
        "a rigid truck's 12 m, 1 m/s² and -6 m/s²; ranges chosen to bracket the order of "
        "magnitude that truck-platooning studies report, documented as a choice"),
}
"""The vehicle classes a fleet may hold."""


MAX_DEAD_TIME_S = 10.0
"""The longest actuation dead time a plant may have (s): its commands are held in a buffer of
that many steps per vehicle, sized before the run."""
MAX_LAG_S = 60.0
"""The longest actuator lag a plant may have (s)."""


@dataclass(frozen=True)
class Plant:
    """What the followers are: a fleet of classes with fractions, optionally every follower's τ
    (``lag_s``) and dead time (``dead_time_s``) fixed instead of drawn from its class's range."""

    fleet: tuple[tuple[str, float], ...] = (("car", 1.0),)
    lag_s: float | None = None
    dead_time_s: float | None = None

    def __post_init__(self) -> None:
        if self.lag_s is not None and not (math.isfinite(self.lag_s) and self.lag_s >= 0):
            raise InputError(f"--vehicle-lag must be 0 s or more, got {self.lag_s}")
        if self.lag_s is not None and self.lag_s > MAX_LAG_S:
            raise InputError(f"--vehicle-lag must be at most {MAX_LAG_S:g} s (a truck's is about "
                             f"0.5 s), got {self.lag_s:g}")
        if self.dead_time_s is not None:
            if math.isfinite(self.dead_time_s) and self.dead_time_s > MAX_DEAD_TIME_S:
                raise InputError(f"--actuation-delay must be at most {MAX_DEAD_TIME_S:g} s (a "
                                 f"truck's is about 0.2 s), got {self.dead_time_s:g}")
            steps = self.dead_time_s / DT_S
            if not (math.isfinite(self.dead_time_s) and self.dead_time_s >= 0) \
                    or abs(steps - round(steps)) > 1e-9:
                raise InputError(f"--actuation-delay {self.dead_time_s:g} s is not a multiple "
                                 f"of the {DT_S} s step; give 0, 0.1, 0.2, ... s")
        if not self.fleet:
            raise InputError("a fleet needs at least one vehicle class")
        for name, share in self.fleet:
            if name not in VEHICLE_CLASSES:
                raise InputError(f"unknown vehicle class {name!r} in --fleet; choose from "
                                 f"{', '.join(VEHICLE_CLASSES)}")
            if not (math.isfinite(share) and 0 < share <= 1):
                raise InputError(f"--fleet: the fraction of {name} must be in (0, 1], got "
                                 f"{share:g}")
        if abs(sum(share for _, share in self.fleet) - 1.0) > 1e-6:
            raise InputError(f"--fleet fractions sum to {sum(s for _, s in self.fleet):g}, "
                             "not 1; e.g. car:0.8,truck:0.2")
        if len({name for name, _ in self.fleet}) != len(self.fleet):
            raise InputError("--fleet names a vehicle class twice")

    @property
    def classes(self) -> list[str]:
        return [name for name, _ in self.fleet]

    def describe(self) -> str:
        """A short text of the plant, e.g. ``car:0.8,truck:0.2 tau=0.3s dead=0.1s``."""
        text = ",".join(f"{n}:{s:g}" for n, s in self.fleet)
        if self.lag_s is not None:
            text += f" tau={self.lag_s:g}s"
        if self.dead_time_s is not None:
            text += f" dead={self.dead_time_s:g}s"
        return text

    def draw(self, n: int, key: str, seed: int = 0) -> Powertrains:
        """The powertrains of ``n`` followers of one event (``key``, e.g. its ID): classes, τ and
        dead times drawn from a generator seeded by (seed, key), so every worker draws alike."""
        rng = np.random.default_rng([seed, zlib.crc32(key.encode()), 4])
        names = [n_ for n_, _ in self.fleet]
        shares = np.array([s for _, s in self.fleet])
        picked = rng.choice(len(names), size=n, p=shares / shares.sum())
        classes = [VEHICLE_CLASSES[names[i]] for i in picked]
        tau = np.array([c.tau_s[0] + (c.tau_s[1] - c.tau_s[0]) * rng.random() for c in classes])
        dead = np.array([_draw_steps(c.dead_time_s, rng) for c in classes], dtype=np.int64)
        if self.lag_s is not None:
            tau[:] = self.lag_s
        if self.dead_time_s is not None:
            dead[:] = int(round(self.dead_time_s / DT_S))
        return Powertrains([c.name for c in classes], tau, dead,
                           np.array([c.a_max_mps2 for c in classes]),
                           np.array([c.b_max_mps2 for c in classes]),
                           np.array([c.length_m for c in classes]),
                           [c.vtype for c in classes])

    def corners(self) -> list[tuple[float, int]]:
        """(τ s, dead time in steps) at both ends of every class's ranges (or the fixed values):
        the vehicles a robust check runs against."""
        return sorted({corner for name in self.classes for corner in self.class_corners(name)})

    def class_corners(self, class_name: str) -> list[tuple[float, int]]:
        """(τ s, dead time in steps) of one class at both ends of its ranges (or the fixed
        values): :meth:`corners` of that class alone."""
        c = VEHICLE_CLASSES[class_name]
        out = set()
        for tau, dead in ((c.tau_s[0], c.dead_time_s[0]), (c.tau_s[1], c.dead_time_s[1])):
            tau = self.lag_s if self.lag_s is not None else tau
            dead = self.dead_time_s if self.dead_time_s is not None else dead
            out.add((float(tau), int(round(dead / DT_S))))
        return sorted(out)

    def worst_case(self, class_name: str) -> Plant:
        """One class alone at the slow end of its ranges (largest τ and dead time), or at this
        plant's fixed values: the homogeneous platoon a string-stability check runs per class."""
        c = VEHICLE_CLASSES[class_name]
        return Plant(((class_name, 1.0),),
                     self.lag_s if self.lag_s is not None else c.tau_s[1],
                     self.dead_time_s if self.dead_time_s is not None else c.dead_time_s[1])


def _draw_steps(range_s: tuple[float, float], rng: np.random.Generator) -> int:
    lo, hi = (int(round(x / DT_S)) for x in range_s)
    return int(rng.integers(lo, hi + 1))


REAL_FLEET = (("car", 0.8), ("truck", 0.2))
"""The default fleet of the real plant: 80 % cars, 20 % heavy trucks."""

REAL_COMM_DELAY_S = 0.1
"""The V2V delay of the real plant (s): the lower end of the 0.1-0.2 s of DSRC/ITS-G5 platoons
(Ploeg et al. 2014 design for 0.15 s); ``--comm-delay 0.2`` beside ``--plant real`` takes the
upper end."""

REAL_PLANT = Plant(REAL_FLEET)
"""``--plant real``: the default fleet, each follower's τ and dead time drawn from its class."""


def parse_fleet(text: str) -> tuple[tuple[str, float], ...]:
    """``car:0.7,truck:0.3`` -> (("car", 0.7), ("truck", 0.3)); a bare ``car`` is ("car", 1.0).
    InputError naming what is wrong (checked again by :class:`Plant`)."""
    out = []
    for part in text.split(","):
        name, sep, share = part.strip().partition(":")
        if not name:
            raise InputError(f"--fleet {text!r}: write classes with fractions, e.g. "
                             "car:0.8,truck:0.2")
        try:
            value = float(share) if sep else 1.0
        except ValueError:
            raise InputError(f"--fleet {text!r}: {share!r} is not a fraction") from None
        out.append((name, value))
    return tuple(out)


class Powertrains:
    """The powertrains of one platoon's followers (head first) and their state: the realised
    acceleration a (m/s²) and the commands on their way through the dead time."""

    def __init__(self, classes: list[str], tau_s: np.ndarray, dead_steps: np.ndarray,
                 a_max_mps2: np.ndarray, b_max_mps2: np.ndarray, length_m: np.ndarray,
                 vtypes: list[str]):
        self.classes, self.tau_s, self.dead_steps = classes, tau_s, dead_steps
        self.a_max, self.b_max, self.length_m, self.vtypes = a_max_mps2, b_max_mps2, length_m, \
            vtypes
        self.alpha = DT_S / (tau_s + DT_S)
        n = len(classes)
        self._slots = int(dead_steps.max(initial=0)) + 1
        self._rows = np.arange(n)
        self.reset()

    def reset(self, acceleration: np.ndarray | None = None) -> None:
        """Start from a realised acceleration (m/s², default 0) with no command in the pipe."""
        n = len(self.classes)
        self.a = np.zeros(n) if acceleration is None else np.array(acceleration, dtype=np.float64)
        self._pipe = np.zeros((self._slots, n))
        self._k = 0

    def step(self, command: np.ndarray) -> np.ndarray:
        """Take this step's commands u(k) (m/s², shape (n,)); return a(k+1) (m/s²)."""
        _step(np.ascontiguousarray(command, dtype=np.float64), self._pipe, self._k,
              self.dead_steps, self.alpha, self.a, self.a_max, self.b_max)
        self._k += 1
        return self.a.copy()


@njit(cache=True)
def _step(command, pipe, k, dead_steps, alpha, a, a_max, b_max):
    """One step of every powertrain, in place on ``pipe`` (slots, n) and ``a`` (n,)."""
    slots = pipe.shape[0]
    for i in range(command.shape[0]):
        u = min(max(command[i], -b_max[i]), a_max[i])
        pipe[k % slots, i] = u
        c = pipe[(k - dead_steps[i]) % slots, i]
        x = alpha[i] * c + (1.0 - alpha[i]) * a[i]
        a[i] = min(max(x, -b_max[i]), a_max[i])
