"""Imperfect V2V communication and sensing: message delay, loss (with bursts) and sensor noise.

**Channel.** Every V2V quantity travels on a link from one follower to a neighbour: the CA
module's forward messages (follower i+1 → i) and backward messages (i-1 → i), and the Ploeg
controller's predecessor input u_{i-1} (i-1 → i). Each link, every 0.1 s step k:

- the message sent at step k is lost with the link's loss process (below), else it arrives at
  step k + d, d = ``delay_s`` / 0.1 s (a whole number of steps: another delay is refused);
- the receiver holds the last message that arrived and knows its age, k - (the step it was sent);
  with d = 0 a message that is not lost is used in the step it is sent (today's behaviour);
- past ``timeout_s`` the receiver falls back (the CA module takes its learned boundary message,
  as the last vehicle of a chain does; the Ploeg controller drops the feed-forward and acts as an
  ACC on its own sensors); so does a receiver that has heard nothing yet. The fallback is not a
  jump: over ``fade_s`` after the timeout the held message fades linearly into the fallback
  message f (the boundary message; 0 for the Ploeg feed-forward). With age a, timeout T and fade
  F in steps, the receiver uses w·held + (1 - w)·f with

      w = clip((T + F + 1 - a) / (F + 1), 0, 1),

  so w = 1 up to the timeout and w = 0 (the fallback alone) from age T + F + 1 on; F = 0 is a
  hard switch at the timeout. Why: switching from a held message to the boundary message in one
  step is a step in a_adj. On 300 training events at the suite's bursty point (30 % loss in
  bursts of 3 steps, 0.2 s delay) the shipped CA-TD3's jerk was 0.204 m/s³ with the hard
  switch, 0.193 with a 0.5 s fade and 0.191 with 1 s (0.187 on a perfect channel, IDM 0.196),
  with the same headway and dampening.

**Degraded mode** (a policy trained with ``--comm-fallback base``): a CA vehicle that hears
none of its neighbours also drops its learned adjustment and drives on its base model alone, as
Ploeg's CACC drops to ACC. Its a_adj is scaled by the larger weight w of its links (1 for a live
message, :attr:`Channel.heard`), so it fades out with its messages after the timeout and is back
in full with the first message that arrives; with every message lost the platoon is its base.
The CA module still computes with the boundary messages, so its neighbours' inputs are unchanged.

**Loss.** ``burst`` = 1: every message is lost independently with probability P = ``loss``. With
``burst`` = L > 1 a two-state Gilbert-Elliott channel per link: in the bad state every message is
lost, in the good state none; bad → good with probability 1/L per step (bursts of mean length L
steps) and good → bad with probability P / (L·(1 - P)), so that the long-run loss rate is P. The
first state is drawn from that long-run distribution. P = 1 loses everything.

**Sensors** (``sensor_noise``, ``sensor_filter``): noise on the gap and the relative speed a
follower measures itself, and the tracker that filters it: :mod:`carl_sumo.control.sensors`.

All draws come from ``seed`` and the event's ID, so the same seed gives the same losses and noise
on an event whichever worker runs it.

**Randomised training** (``train --comm-randomize``, :func:`random_impairments`): every training
episode draws its own impairments: with probability :data:`PERFECT_SHARE` a perfect channel and
clean sensors; otherwise a delay of 0, 0.1, ..., 0.5 s (uniform), a loss probability uniform on
[0, 1], bursts (L uniform on [1, 5] steps) in half of the episodes, the default 1 s timeout and
1 s fade, and sensor noise in half of the episodes (none with ``train --no-sensor-randomize``).
The policy acts on what it receives (:class:`PlatoonLinks`), and its replay buffer keeps how each
message arrived, so the actor learns on those inputs.
"""

from __future__ import annotations

import math
import zlib
from collections import deque
from dataclasses import dataclass

import numpy as np

from carl_sumo.config import DT_S
from carl_sumo.errors import InputError
from carl_sumo.options import option
from carl_sumo.sim.vehicle import REAL_COMM_DELAY_S, REAL_PLANT, Plant, parse_fleet

LIVE, HELD, FALLBACK = 0, 1, 2
"""How a receiver gets its message this step: the one sent this step, the last one held, none."""


@dataclass(frozen=True)
class Impairments:
    """What ``--comm-delay``, ``--comm-loss``, ``--comm-burst``, ``--comm-timeout``,
    ``--comm-fade``, ``--sensor-noise`` and ``--sensor-filter`` ask for (units in the names; those
    options are these fields, :func:`carl_sumo.options.option`); the defaults are a perfect
    channel and perfect sensors. ``plant``: the vehicle dynamics of the
    followers (``--plant``, ``--fleet``, ``--vehicle-lag``, ``--actuation-delay``,
    :mod:`carl_sumo.sim.vehicle`); None is the ideal plant."""

    delay_s: float = 0.0  # (--comm-delay: none means 0, or 0.1 s with --plant real)
    loss: float = option(0.0, "probability that a V2V message is lost", "plant", low=0.0,
                         high=1.0, metavar="P", flag="comm-loss")
    burst: float = option(1.0, "mean length of a loss burst (Gilbert-Elliott; 1: independent)",
                          "plant", unit="steps", low=1.0, high=10_000, metavar="L",
                          flag="comm-burst")
    timeout_s: float = option(1.0, "a receiver falls back (CA: the boundary message; Ploeg: ACC) "
                              "when its last message is older than this", "plant", unit="s",
                              low=0.0, high=3_600, open_low=True, metavar="S",
                              flag="comm-timeout")
    fade_s: float = option(1.0, "past the timeout the held message fades linearly into the "
                           "fallback over this time (0: a hard switch)", "plant", unit="s",
                           low=0.0, high=3_600, metavar="S", flag="comm-fade")
    sensor_noise: bool = option(False, "Gaussian noise on the measured gap (0.1 m) and relative "
                                "speed (0.1 m/s)", "plant")
    sensor_filter: bool = option(False, "noisy measurements (--sensor-noise, or train's "
                                 "--comm-randomize) are filtered: every follower tracks its "
                                 "measured gap and relative speed with a Kalman filter "
                                 "(sensors.py, docs/robustness.md)", "plant")
    seed: int = option(0, "seed of the losses, the noise and the fleet's draws", "plant", low=0,
                       high=2**31 - 1, flag="impairment-seed")
    plant: Plant | None = None

    def __post_init__(self) -> None:
        if not (math.isfinite(self.delay_s) and self.delay_s >= 0):
            raise InputError(f"--comm-delay must be 0 s or more, got {self.delay_s}")
        if abs(self.delay_s / DT_S - round(self.delay_s / DT_S)) > 1e-9:
            raise InputError(f"--comm-delay {self.delay_s:g} s is not a multiple of the "
                             f"{DT_S} s step; give 0, 0.1, 0.2, ... s")
        if not (math.isfinite(self.loss) and 0 <= self.loss <= 1):
            raise InputError(f"--comm-loss is a probability from 0 to 1, got {self.loss}")
        if not (math.isfinite(self.burst) and self.burst >= 1):
            raise InputError(f"--comm-burst is a mean burst length of 1 step or more, "
                             f"got {self.burst}")
        if not (math.isfinite(self.timeout_s) and self.timeout_s >= DT_S - 1e-12):
            raise InputError(f"--comm-timeout must be at least one step ({DT_S} s), "
                             f"got {self.timeout_s}")
        if not (math.isfinite(self.fade_s) and self.fade_s >= 0):
            raise InputError(f"--comm-fade must be 0 s or more, got {self.fade_s}")
        if self.seed < 0:
            raise InputError(f"--impairment-seed must be 0 or more, got {self.seed}")

    @property
    def delay_steps(self) -> int:
        return int(round(self.delay_s / DT_S))

    @property
    def timeout_steps(self) -> int:
        """The oldest usable message, in steps (a message exactly this old is still used)."""
        return int(math.floor(self.timeout_s / DT_S + 1e-9))

    @property
    def fade_steps(self) -> int:
        """Steps over which a held message fades into the fallback after the timeout."""
        return int(math.floor(self.fade_s / DT_S + 1e-9))

    def held_weight(self, age_steps: np.ndarray) -> np.ndarray:
        """w of held messages of these ages (steps): 1 up to the timeout, then falling linearly
        to 0 over the fade (see the module docstring)."""
        t, f = self.timeout_steps, self.fade_steps
        w = (t + f + 1 - np.asarray(age_steps, dtype=np.float64)) / (f + 1)
        return np.maximum(np.minimum(w, 1.0), 0.0)  # np.clip costs more on a few links

    @classmethod
    def from_options(cls, options) -> Impairments | None:
        """The impairments of an object with the option names as attributes (``comm_delay``,
        ``comm_loss``, ``comm_burst``, ``comm_timeout``, ``comm_fade``, ``sensor_noise``,
        ``sensor_filter``, ``impairment_seed``: parsed CLI options or a training config); None
        when all is perfect. InputError for a bad value."""
        plant = plant_from(options)
        delay = options.comm_delay
        if getattr(options, "plant", None) == "real" and delay is None:
            delay = REAL_COMM_DELAY_S
        imp = cls(delay_s=delay or 0.0, loss=options.comm_loss, burst=options.comm_burst,
                  timeout_s=options.comm_timeout, fade_s=options.comm_fade,
                  sensor_noise=options.sensor_noise, sensor_filter=options.sensor_filter,
                  seed=options.impairment_seed, plant=plant)
        return imp if imp.active else None

    @property
    def perfect_channel(self) -> bool:
        return self.delay_s == 0 and self.loss == 0

    @property
    def active(self) -> bool:
        return not self.perfect_channel or self.sensor_noise or self.plant is not None

    @property
    def plant_key(self) -> str:
        """The plant as tuned gains are stored for it: ``ideal``, or the fleet and its fixed
        values with the V2V delay (e.g. ``car:0.8,truck:0.2 v2v=0.1s``)."""
        return plant_key(self.plant, self.delay_s)


    def rng(self, event_id: str, stream: int) -> np.random.Generator:
        """The generator of one event and one stream (0: sensors, 1, 2, ...: links)."""
        return np.random.default_rng([self.seed, zlib.crc32(event_id.encode()), stream])


def plant_impairments(plant: str) -> Impairments | None:
    """``--plant real``'s impairments (the default fleet, 0.1 s V2V delay), None for ideal."""
    return Impairments(delay_s=REAL_COMM_DELAY_S, plant=REAL_PLANT) if plant == "real" else None


def plant_key(plant: Plant | None, delay_s: float) -> str:
    """See :attr:`Impairments.plant_key`."""
    return "ideal" if plant is None else f"{plant.describe()} v2v={delay_s:g}s"


def plant_from(options) -> Plant | None:
    """The vehicle dynamics of parsed options (``plant``: ``ideal``/``real``, ``fleet``,
    ``vehicle_lag``, ``actuation_delay``; any may be absent) or None for the ideal plant.
    ``--plant real`` is the default fleet (:data:`carl_sumo.sim.vehicle.REAL_PLANT`); the
    options beside it replace its parts; ``--vehicle-lag`` or ``--actuation-delay`` alone is a
    fleet of cars with those values."""
    kind = getattr(options, "plant", None) or "ideal"
    if kind not in ("ideal", "real"):
        raise InputError(f"--plant {kind!r}: choose ideal or real")
    fleet_text = getattr(options, "fleet", None)
    lag, dead = getattr(options, "vehicle_lag", None), getattr(options, "actuation_delay", None)
    if kind == "ideal" and fleet_text is None and lag is None and dead is None:
        return None
    fleet = parse_fleet(fleet_text) if fleet_text is not None else \
        (REAL_PLANT.fleet if kind == "real" else (("car", 1.0),))
    if kind == "ideal" and fleet_text is None:  # a lag or dead time alone: cars with it
        lag, dead = lag if lag is not None else 0.0, dead if dead is not None else 0.0
    return Plant(fleet, lag, dead)



BURSTY_CHANNEL = Impairments(delay_s=0.2, loss=0.3, burst=3.0)
"""The robustness suite's bursty point: 30 % loss in bursts of 3 steps, 0.2 s delay."""


def _faded(held: np.ndarray, weight: np.ndarray, fallback: np.ndarray | None) -> np.ndarray:
    """w·held + (1 - w)·fallback per row (fallback None: zeros); ``held`` itself when nothing
    fades (most steps)."""
    if weight.min(initial=1.0) >= 1.0:
        return held
    out = held * weight[:, None]
    if fallback is not None:
        out += (1.0 - weight)[:, None] * np.asarray(fallback, dtype=np.float64)
    return out


def to_bad_probability(loss: float, burst: float) -> float:
    """Gilbert-Elliott good → bad probability per step that gives the long-run loss rate
    ``loss`` with bursts of mean length ``burst`` steps (bad → good: 1/burst)."""
    return loss / (burst * (1.0 - loss)) if loss < 1 else 1.0


class LossProcess:
    """Which of ``n`` links lose their message at each step (see the module docstring)."""

    def __init__(self, n: int, loss: float, burst: float, rng: np.random.Generator):
        self.n, self.loss, self.burst, self.rng = n, loss, burst, rng
        self.bad = rng.random(n) < loss if burst > 1 else np.zeros(n, dtype=bool)
        self.to_good = 1.0 / burst
        self.to_bad = to_bad_probability(loss, burst)

    def draw(self) -> np.ndarray:
        """Lost flags (n,) of the messages sent this step."""
        if self.loss <= 0:
            return np.zeros(self.n, dtype=bool)
        if self.loss >= 1:
            return np.ones(self.n, dtype=bool)
        u = self.rng.random(self.n)
        if self.burst <= 1:
            return u < self.loss
        self.bad = np.where(self.bad, u >= self.to_good, u < self.to_bad)
        return self.bad.copy()


class Channel:
    """``n`` links of one direction, each carrying a message of ``dim`` numbers to receiver j.

    Every step: :meth:`receive` (how each receiver gets its message, and the held values), then
    the sender computes, then :meth:`send` with the messages sent this step. A step's
    :meth:`receive` may be asked again (a preview): it draws once per step.
    """

    def __init__(self, n: int, dim: int, impairments: Impairments, rng: np.random.Generator):
        self.cfg, self.n, self.dim = impairments, n, dim
        self.losses = LossProcess(n, impairments.loss, impairments.burst, rng)
        self.held = np.zeros((n, dim))
        self.sent_at = np.full(n, -10 ** 9)  # step the held message was sent (none yet)
        self.in_flight: deque[tuple[int, np.ndarray, np.ndarray]] = deque()
        self.k = -1
        self._lost = np.zeros(n, dtype=bool)
        self._mode = np.full(n, FALLBACK)
        self._weight = np.zeros(n)
        self.heard = np.zeros(n)  # per receiver this step: 1 live, else the held message's weight w

    def receive(self, k: int, fallback: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
        """(mode (n,) of LIVE/HELD/FALLBACK, held messages (n, dim), fading into ``fallback``
        (dim,) past the timeout (None: zeros)) of step k."""
        if k != self.k:
            self.k = k
            self._lost = self.losses.draw()
            d = self.cfg.delay_steps
            while self.in_flight and self.in_flight[0][0] <= k - d:
                sent, messages, lost = self.in_flight.popleft()
                arrived = ~lost
                self.held[arrived] = messages[arrived]
                self.sent_at[arrived] = sent
            self._weight = self.cfg.held_weight(k - self.sent_at)
            mode = np.where(self._weight > 0, HELD, FALLBACK)
            if d == 0:
                mode = np.where(self._lost, mode, LIVE)
            self._mode = mode
            self.heard = np.where(mode == LIVE, 1.0, self._weight)
        return self._mode, _faded(self.held, self._weight, fallback)

    def send(self, k: int, messages: np.ndarray) -> None:
        """The messages (n, dim) sent at step k (after :meth:`receive` of step k)."""
        if self.cfg.delay_steps == 0:
            arrived = ~self._lost
            self.held[arrived] = messages[arrived]
            self.sent_at[arrived] = k
        else:
            self.in_flight.append((k, np.array(messages, dtype=np.float64), self._lost.copy()))


class KeyedChannel:
    """Links whose ends change: the study's CACC chains form and break in traffic. One link per
    receiving vehicle (by ID), carrying whichever vehicle is its neighbour now; a held message
    counts only while it comes from the current neighbour (a new neighbour is not heard until
    its first message arrives). Losses as :class:`LossProcess`, with the burst state of a link
    advanced at the steps its vehicle receives. Every step: :meth:`receive` for the (receiver,
    sender) pairs, then :meth:`send` with their messages."""

    def __init__(self, dim: int, impairments: Impairments, rng: np.random.Generator):
        self.cfg, self.dim, self.rng = impairments, dim, rng
        self.held: dict[str, tuple[str, np.ndarray, int]] = {}  # receiver: (sender, message, sent)
        self.bad: dict[str, bool] = {}
        self.in_flight: deque[tuple[int, str, str, np.ndarray]] = deque()
        self.k = -1
        self._lost: dict[str, bool] = {}
        self._to_bad = to_bad_probability(impairments.loss, impairments.burst)
        self._last_full = impairments.timeout_steps  # the oldest message used whole (steps)
        self._fade = impairments.fade_steps
        self.heard = np.zeros(0)  # per pair of the last receive, as Channel.heard

    def _draw(self, receiver: str) -> bool:
        loss, burst = self.cfg.loss, self.cfg.burst
        if loss <= 0 or loss >= 1:
            return loss >= 1
        u = self.rng.random()
        if burst <= 1:
            return bool(u < loss)
        if receiver not in self.bad:  # first use: the long-run distribution
            self.bad[receiver] = bool(u < loss)
            return self.bad[receiver]
        bad = u >= 1.0 / burst if self.bad[receiver] else u < self._to_bad
        self.bad[receiver] = bool(bad)
        return self.bad[receiver]

    def receive(self, k: int, pairs: list[tuple[str, str]], fallback: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
        """(modes (m,) of LIVE/HELD/FALLBACK, held messages (m, dim), fading into ``fallback``
        past the timeout as :class:`Channel`'s) at step k of the m (receiver, sender) pairs;
        asked again in the same step it draws nothing new."""
        if k != self.k:
            self.k, self._lost = k, {}
            d = self.cfg.delay_steps
            while self.in_flight and self.in_flight[0][0] <= k - d:
                sent, receiver, sender, message = self.in_flight.popleft()
                self.held[receiver] = (sender, message, sent)
        modes, held = np.full(len(pairs), FALLBACK), np.zeros((len(pairs), self.dim))
        weight = np.zeros(len(pairs))
        for j, (receiver, sender) in enumerate(pairs):
            if receiver not in self._lost:
                self._lost[receiver] = self._draw(receiver)
            got = self.held.get(receiver)
            if got is not None and got[0] == sender:  # the held_weight of one link, in Python
                w = (self._last_full + self._fade + 1 - (k - got[2])) / (self._fade + 1)
                if w > 0:
                    modes[j], held[j], weight[j] = HELD, got[1], min(w, 1.0)
            if self.cfg.delay_steps == 0 and not self._lost[receiver]:
                modes[j] = LIVE
        self.heard = np.where(modes == LIVE, 1.0, weight)
        return modes, _faded(held, weight, fallback)

    def send(self, k: int, pairs: list[tuple[str, str]], messages: np.ndarray) -> None:
        """The messages (m, dim) of step k (after :meth:`receive` of step k with these pairs)."""
        for (receiver, sender), message in zip(pairs, messages):
            if self._lost.get(receiver, False):
                continue
            if self.cfg.delay_steps == 0:
                self.held[receiver] = (sender, np.array(message, dtype=np.float64), k)
            else:
                self.in_flight.append((k, receiver, sender, np.array(message, dtype=np.float64)))


PERFECT_SHARE = 0.25
"""Share of randomised training episodes with a perfect channel and clean sensors."""

MAX_RANDOM_DELAY_STEPS = 5
"""Randomised training delays: 0 to this many 0.1 s steps (0.5 s, the suite's largest)."""


def random_impairments(rng: np.random.Generator, sensor_noise_share: float = 0.5,
                       sensor_filter: bool = False) -> Impairments:
    """One training episode's impairments, drawn as the module docstring says (sensor noise in
    ``sensor_noise_share`` of the impaired episodes, filtered by the followers' trackers when
    ``sensor_filter``; the channel draws do not depend on either)."""
    seed = int(rng.integers(2 ** 31))
    if rng.random() < PERFECT_SHARE:
        return Impairments(seed=seed)
    delay_s = round(int(rng.integers(MAX_RANDOM_DELAY_STEPS + 1)) * DT_S, 10)
    loss = float(rng.random())
    burst = float(rng.uniform(1.0, 5.0)) if rng.random() < 0.5 else 1.0
    return Impairments(delay_s=delay_s, loss=loss, burst=burst,
                       sensor_noise=bool(rng.random() < sensor_noise_share),
                       sensor_filter=sensor_filter, seed=seed)


def heard_weights(forward: np.ndarray, backward: np.ndarray) -> np.ndarray:
    """(n,) per follower of a chain of n: the larger weight of its links, given the n - 1
    forward links (i hears i+1, i = 0..n-2) and the n - 1 backward links (i hears i-1,
    i = 1..n-1); a chain end has one link, a chain of one none (1: nothing to lose)."""
    out = np.ones(len(forward) + 1)
    if len(forward):
        out[:-1] = forward
        out[-1] = backward[-1]
        out[1:-1] = np.maximum(out[1:-1], backward[:-1])
    return out


class PlatoonLinks:
    """The CA messages of one platoon of ``n`` followers over impaired links: forward (i+1 → i,
    link stream 2 of the event) and backward (i-1 → i, stream 3). Per step: :meth:`receive`, the
    actor computes, :meth:`send` with the messages it computed."""

    def __init__(self, n: int, dim: int, impairments: Impairments, event_id: str):
        self.n = n
        self.forward = Channel(n, dim, impairments, impairments.rng(event_id, 2))
        self.backward = Channel(n, dim, impairments, impairments.rng(event_id, 3))
        self.k = 0

    def receive(self, forward_fallback: np.ndarray | None = None,
                backward_fallback: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(forward modes (n,), forward held (n, dim), backward modes, backward held) of this
        step (LIVE/HELD/FALLBACK; a preview until :meth:`send`); held messages past the timeout
        fade into the fallbacks (the actor's boundary messages; None: zeros)."""
        f_mode, f_held = self.forward.receive(self.k, forward_fallback)
        b_mode, b_held = self.backward.receive(self.k, backward_fallback)
        return f_mode, f_held, b_mode, b_held

    def heard(self) -> np.ndarray:
        """How much each follower hears its neighbours this step (n,), in [0, 1]: the larger
        weight of its links (1 live or held within the timeout, fading to 0 over the fade; a chain
        end has one link, a platoon of one has none and hears fully). After :meth:`receive`."""
        return heard_weights(self.forward.heard[:self.n - 1], self.backward.heard[1:])

    def send(self, forward_messages: np.ndarray, backward_messages: np.ndarray) -> None:
        """Every follower's forward and backward message (n, dim) of this step; the step ends."""
        zero = np.zeros((1, forward_messages.shape[1]))
        self.forward.send(self.k, np.vstack([forward_messages[1:], zero]))  # to i from i+1
        self.backward.send(self.k, np.vstack([zero, backward_messages[:self.n - 1]]))
        self.k += 1
