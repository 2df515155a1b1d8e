"""Manoeuvres of a platoon: what ``--scenario cut-in|cut-out|join|merge`` asks for, and one drawn
per event.

Positions count vehicles from the front: 0 is the NGSIM leader, 1 the first follower, n the tail.

- **cut-in** ``k`` (0..n-1): a human driver (SUMO's Krauss, type ``human_krauss``; no V2V)
  enters the platoon lane from the adjacent lane between vehicle k and follower k+1; with
  ``leave`` (``cut-in:leave=5``) he changes back out that many seconds later and the chain of
  k and k+1 links again;
- **cut-out** ``k`` (1..n-1): follower k changes into the adjacent lane and leaves; k+1 then
  faces k-1 across the old gaps;
- **join** ``k`` (0..n): a CACC vehicle enters from the adjacent lane between vehicle k and
  follower k+1 (k = n: behind the tail) and joins the V2V chain (the platoon grows by one);
- **merge** ``k`` (1..n-1): followers k+1..n start as a second platoon ``extra_gap_m`` further back
  than their spacing, on radar only behind follower k (no V2V across the gap); at the manoeuvre
  time the two platoons link and the second closes the gap.

An entering vehicle of length L takes a share of the gap g between vehicle k and follower k+1:
the gap behind it is ``gap_fraction``·(g - L), the gap ahead (1 - ``gap_fraction``)·(g - L). It
starts at the first step from ``time_s`` on at which g - L is at least :data:`MIN_ROOM_M`
(drivers cut into a gap that has room), or, with ``wait=S`` (cut-in, join), only within S
seconds of ``time_s`` (``wait=0``: at ``time_s`` or not at all, so that every controller meets
the manoeuvre at the same moment of the event, at the same leader speed), beside the gap in the
adjacent lane at the mean speed of the two vehicles, and changes lanes with SUMO's own ``vehicle.changeLane``. At the tail a joiner
enters at the gap the tail keeps. A lane change is done in one 0.1 s step, or, with ``lc=S``
(cut-in, cut-out, join), gradually over S seconds (SUMO's ``--lanechange.duration``: the vehicle
moves sideways over S and SUMO counts it in its new lane from halfway, when the vehicles there
see it as their leader). With ``signal=S`` (cut-in) the human shows his turn signal for S seconds
beside the gap before he moves over, and the follower behind the gap takes him as its
predecessor from his first signal on (a cut-in prediction from the indicator, as an ACC's camera
makes it), so it can open room before he lands. A joiner with ``signal=S`` (join) does the same:
its request to join reaches the member behind the gap S seconds before it moves over (a
cooperative join, in which the platoon makes room first); until it is in the lane that member
meets it on radar alone (the degraded mode and its reaction layer, without the guards it keeps
behind a human: carl_sumo.manoeuvres.simulation), as its message joins the chain only once it is a
member.

Drawn per event (what the spec leaves open), from ``seed`` and the event's ID:
``time_s`` uniform in :data:`TIME_SHARE` of the scored part of the event (after a warm-up),
``position`` uniform over the positions between followers (cut-in 1..n-1, join 1..n, cut-out and
merge 1..n-1), ``gap_fraction`` uniform in :data:`GAP_FRACTION`, ``extra_gap_m`` uniform in
:data:`MERGE_EXTRA_GAP_M`.
"""

from __future__ import annotations

import math
import zlib
from dataclasses import dataclass, replace

import numpy as np

from carl_sumo.config import DT_S
from carl_sumo.data.events import Event
from carl_sumo.errors import InputError

KINDS = ("cut-in", "cut-out", "join", "merge")
TIME_SHARE = (0.2, 0.4)
"""The manoeuvre time, as a share of the scored duration of the event after its warm-up (-)."""
GAP_FRACTION = (0.4, 0.6)
"""The share of the free gap behind an entering vehicle (-)."""
MERGE_EXTRA_GAP_M = (20.0, 40.0)
"""How much further back the second platoon of a merge starts (m)."""
MIN_ROOM_M = 4.0
"""An entering vehicle needs g - L at least this (m): 1.6-2.4 m behind it at the drawn shares."""
MAX_LANE_CHANGE_S = 10.0
"""The longest lane change ``lc=S`` takes (s)."""
MAX_SIGNAL_S = 10.0
"""The longest turn signal ``signal=S`` before a cut-in or a join (s)."""
SETTLE_AFTER_S = 5.0
"""A manoeuvre time must leave at least this much of the event after it (s)."""


@dataclass(frozen=True)
class Manoeuvre:
    """One manoeuvre of one event (units in the names; positions as the module docstring)."""

    kind: str
    position: int
    time_s: float
    gap_fraction: float = 0.5
    extra_gap_m: float = 0.0
    leave_s: float | None = None  # cut-in: the human leaves again this long after (s)
    lane_change_s: float = 0.0    # how long a lane change takes (s; 0: one step)
    wait_s: float | None = None   # cut-in, join: the longest it waits for room after time_s
                                  # (s; None: to the end of the event)
    signal_s: float = 0.0         # cut-in, join: how long it signals before it moves over (s)

    @property
    def step(self) -> int:
        """The first step at which it may start."""
        return int(round(self.time_s / DT_S))

    def describe(self) -> str:
        text = f"{self.kind} k={self.position} t={self.time_s:.1f}s"
        if self.kind in ("cut-in", "join"):
            text += f" f={self.gap_fraction:.2f}"
        if self.kind == "merge":
            text += f" extra={self.extra_gap_m:.1f}m"
        if self.leave_s is not None:
            text += f" leave={self.leave_s:g}s"
        if self.lane_change_s > 0:
            text += f" lc={self.lane_change_s:g}s"
        if self.wait_s is not None:
            text += f" wait={self.wait_s:g}s"
        if self.signal_s > 0:
            text += f" signal={self.signal_s:g}s"
        return text

    def gives_up(self, step: int) -> bool:
        """Whether an entering vehicle that has found no room by ``step`` stops waiting."""
        return self.wait_s is not None and step >= self.step + int(round(self.wait_s / DT_S))


def position_range(kind: str, n_followers: int) -> tuple[int, int]:
    """(lowest, highest) position k a manoeuvre of ``kind`` may have in a platoon of n."""
    return {"cut-in": (0, n_followers - 1), "join": (0, n_followers),
            "cut-out": (1, n_followers - 1), "merge": (1, n_followers - 1)}[kind]


def drawn_positions(kind: str, n_followers: int) -> tuple[int, int]:
    """The positions a drawn manoeuvre takes (between followers, where the platoon has them)."""
    lo, hi = position_range(kind, n_followers)
    return (min(max(lo, 1), hi), hi)


@dataclass(frozen=True)
class ScenarioSpec:
    """What ``--scenario KIND[:k=K][:t=T][:f=F][:gap=M][:lc=S][:signal=S]`` and ``--scenario-seed`` ask
    for; the values not given are drawn per event (:meth:`draw`)."""

    kind: str
    position: int | None = None
    time_s: float | None = None
    gap_fraction: float | None = None
    extra_gap_m: float | None = None
    leave_s: float | None = None
    lane_change_s: float = 0.0
    wait_s: float | None = None
    signal_s: float = 0.0
    seed: int = 0

    def check(self, n_followers: int) -> None:
        """InputError when the spec cannot run on a platoon of ``n_followers``."""
        lo, hi = position_range(self.kind, n_followers)
        if hi < lo:
            raise InputError(f"--scenario {self.kind} needs a platoon of at least "
                             f"{lo + 1} followers, got --vehicles {n_followers}")
        if self.position is not None and not lo <= self.position <= hi:
            raise InputError(f"--scenario {self.kind}: position k={self.position} is beyond the "
                             f"platoon of {n_followers} followers; give k from {lo} to {hi}")

    def check_event(self, event: Event) -> None:
        """InputError when a fixed manoeuvre time does not fit the event."""
        if self.time_s is None:
            return
        first = event.scored_from * DT_S
        last = (event.n_samples - 1) * DT_S - SETTLE_AFTER_S
        if not first <= self.time_s <= last:
            raise InputError(f"--scenario {self.kind}: t={self.time_s:g} s does not fit event "
                             f"{event.event_id} (it must lie from {first:g} s to {last:.1f} s, "
                             f"{SETTLE_AFTER_S:g} s before its end)")

    def draw(self, event: Event, n_followers: int) -> Manoeuvre:
        """The manoeuvre of one event: the spec's values, the rest drawn from (seed, event)."""
        self.check(n_followers)
        self.check_event(event)
        rng = np.random.default_rng([self.seed, zlib.crc32(event.event_id.encode()), 35])
        lo, hi = drawn_positions(self.kind, n_followers)
        position = int(rng.integers(lo, hi + 1))
        first = event.scored_from * DT_S
        scored_s = (event.n_samples - 1) * DT_S - first
        time_s = round((first + scored_s * rng.uniform(*TIME_SHARE)) / DT_S) * DT_S
        fraction = float(rng.uniform(*GAP_FRACTION))
        extra = float(rng.uniform(*MERGE_EXTRA_GAP_M))
        return Manoeuvre(
            self.kind, self.position if self.position is not None else position,
            self.time_s if self.time_s is not None else float(time_s),
            self.gap_fraction if self.gap_fraction is not None else fraction,
            (self.extra_gap_m if self.extra_gap_m is not None else extra)
            if self.kind == "merge" else 0.0, self.leave_s, self.lane_change_s, self.wait_s,
            self.signal_s)


def _number(spec: str, key: str, text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise InputError(f"--scenario {spec!r}: {key}={text!r} is not a number") from None
    if not math.isfinite(value):
        raise InputError(f"--scenario {spec!r}: {key} must be finite, got {text}")
    return value


def parse_scenario(text: str, seed: int = 0) -> ScenarioSpec:
    """``cut-in``, ``cut-in:k=3:t=8:f=0.5``, ``merge:gap=30`` ... -> :class:`ScenarioSpec`;
    InputError naming what is wrong (a gap fraction outside (0, 1), an unknown kind or key)."""
    kind, *parts = text.strip().split(":")
    if kind not in KINDS:
        raise InputError(f"--scenario {text!r}: unknown manoeuvre {kind!r}; choose one of "
                         f"{', '.join(KINDS)}")
    if isinstance(seed, bool) or not isinstance(seed, int) or not 0 <= seed < 2 ** 32:
        raise InputError(f"--scenario-seed must be a whole number from 0 to {2 ** 32 - 1}, "
                         f"got {seed}")
    keys = [part.partition("=")[0] for part in parts]
    twice = sorted({k for k in keys if keys.count(k) > 1})
    if twice:
        raise InputError(f"--scenario {text!r}: {', '.join(twice)} is given twice; give each "
                         "option once")
    spec = ScenarioSpec(kind, seed=seed)
    allowed = {"k": "position", "t": "time_s"}
    if kind in ("cut-in", "join"):
        allowed["f"] = "gap_fraction"
        allowed["wait"] = "wait_s"
        allowed["signal"] = "signal_s"
    if kind == "cut-in":
        allowed["leave"] = "leave_s"
    if kind == "merge":
        allowed["gap"] = "extra_gap_m"
    else:
        allowed["lc"] = "lane_change_s"
    for part in parts:
        key, sep, value_text = part.partition("=")
        if not sep or key not in allowed:
            raise InputError(f"--scenario {text!r}: {part!r} is not an option of {kind}; write "
                             f"{kind}:" + ":".join(f"{k}=VALUE" for k in allowed))
        value = _number(text, key, value_text)
        if key == "k" and (value != int(value)):
            raise InputError(f"--scenario {text!r}: k is a whole vehicle position, got "
                             f"{value_text}")
        if key == "t" and (value < 0 or abs(value / DT_S - round(value / DT_S)) > 1e-6):
            raise InputError(f"--scenario {text!r}: t must be 0 s or more, a multiple of "
                             f"{DT_S} s, got {value_text}")
        if key == "f" and not 0 < value < 1:
            raise InputError(f"--scenario {text!r}: the gap fraction f must lie in (0, 1), "
                             f"got {value_text}")
        if key == "leave" and (value <= 0 or abs(value / DT_S - round(value / DT_S)) > 1e-6):
            raise InputError(f"--scenario {text!r}: leave is a positive time in s, a multiple "
                             f"of {DT_S} s, got {value_text}")
        if key == "lc" and not (0 <= value <= MAX_LANE_CHANGE_S
                                and abs(value / DT_S - round(value / DT_S)) < 1e-6):
            raise InputError(f"--scenario {text!r}: lc is the lane change's duration, 0 to "
                             f"{MAX_LANE_CHANGE_S:g} s in multiples of {DT_S} s, got {value_text}")
        if key == "signal" and not (0 <= value <= MAX_SIGNAL_S
                                    and abs(value / DT_S - round(value / DT_S)) < 1e-6):
            raise InputError(f"--scenario {text!r}: signal is how long the entering vehicle "
                             f"signals before it moves over, 0 to {MAX_SIGNAL_S:g} s in "
                             f"multiples of {DT_S} s, got {value_text}")
        if key == "wait" and (value < 0 or abs(value / DT_S - round(value / DT_S)) > 1e-6):
            raise InputError(f"--scenario {text!r}: wait is how long the entering vehicle waits "
                             f"for room, 0 s or more in multiples of {DT_S} s, got {value_text}")
        if key == "gap" and value <= 0:
            raise InputError(f"--scenario {text!r}: the merge gap must be positive (m), got "
                             f"{value_text}")
        spec = replace(spec, **{allowed[key]: int(value) if key == "k" else value})
    return spec
