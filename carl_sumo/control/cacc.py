"""Classical CACC: Ploeg et al. (2011)'s controller, its names, and its tuned gains.

Ploeg, Scheepers, van Nunen, van de Wouw & Nijmeijer (2011), *Design and experimental evaluation
of cooperative adaptive cruise control*, IEEE ITSC. Each follower i keeps a controller state u_i
(m/s², the desired acceleration it also sends to its follower over V2V) and, every step k of
dt = 0.1 s, from its own sensors and its predecessor's message:

- spacing error      e_i  = d_i - s0 - h·v_i                (m; d_i bumper gap, v_i speed)
- its rate           ė_i  = (v_{i-1} - v_i) - h·a_i          (m/s; a_i: last step's acceleration)
- controller state   u_i(k+1) = u_i(k) + (dt/h)·(-u_i(k) + kp·e_i + kd·ė_i + u_{i-1}(k))
- applied            a_i  = clip(u_i(k+1), -9, 3)           (m/s², the CACC vehicle's bounds)

Cruise control caps it, as CACC systems switch to CC when the road ahead is free (this matters
only in the mixed-traffic study, where a vehicle may have no predecessor within sensing range;
NGSIM I-80 leaders stay below 25 m/s, where the cap is above 3 m/s² and never binds):
u_i(k+1) ≤ k_cc·(v0 - v_i) with v0 = 120 km/h (the IDM desired speed) and k_cc = 0.4 1/s (the
magnitude of SUMO's CACC speed-control gain); the capped value is the state (no wind-up).

u_{i-1}(k) is the predecessor's last state, as its V2V message carries it; the first follower
receives the leader's acceleration over the last step instead (0 at the first step). u starts at 0.
h is the time gap (s), s0 = 2 m the standstill gap, kp (1/s²) and kd (1/s) the feedback gains.
The textbook gains are kp = 0.2, kd = 0.7 (Ploeg et al. 2011).

Degraded CACC (``ha=T`` in a name, e.g. ``ploeg:h=0.8:kp=0.0445:kd=1:ha=1.4``): a vehicle that
hears no V2V message (the first follower behind a human leader, a follower behind a cut-in
human) runs the same law as an ACC at the longer time gap T (h → T in e_i, ė_i and the filter),
as a radar-only link needs a longer gap to stay string stable (docs/string_stability.md).

The safety layers below are parts of their own (:mod:`carl_sumo.control.layers`): the kernel runs
the law on a chain (:func:`_ploeg_law`), then each layer in turn bounds its output; the scenario
inputs (armed vehicles, distances to a merge point) reach only the layers.

Reaction layer (``ttc=T`` in a name, e.g. ``ploeg:h=0.8:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2``): a
vehicle that hears no V2V message reacts at once when it closes in on the vehicle ahead, which the
law at T, filtered with time constant T, does too slowly on a lagging powertrain. When the time to
collision (d_i - 1 m)/c_i with closing speed c_i = v_i - v_{i-1} > 0 drops below T, it applies at
most -c_i²/(2·(d_i - 1 m - 0.5 s·c_i)), the deceleration that stops the closing in 1 m short
after 0.5 s of lag if the vehicle ahead keeps its speed, or the most braking when no room is left.
With ``rb=1`` it also brakes as hard as the vehicle ahead does, b_{i-1}, which the radar measures
as a_i plus the change of Δv_i over the step (-c_i²/(2·...) - b_{i-1}). That braking is what it
applies and what its follower hears as its message; its state u is left to the law, so it resumes
from its own state when the threat has passed (written into u, the filter would keep the braking
at dt/T per step). A follower that hears its predecessor has the braking in its message and does
not react.

Safe speed (``gs=B`` in a name): a vehicle that hears no V2V message also keeps at most Gipps'
safe speed v_safe for the vehicle ahead, the speed from which it stops behind it when both brake
at B m/s² after its 0.5 s of lag, applying at most (v_safe - v)/0.5 s. ``gn=B`` does the same
only for an armed vehicle at the front of its V2V chain: one whose vehicle ahead is new and is no
member it hears (a human who just cut in or signals to) until it has room
(carl_sumo.manoeuvres.simulation), never for a platoon's head. Behind a joiner the member is left to
its law and its reaction layer: while an announced joiner signals beside its gap (it is not armed
then) and once the joiner is in its chain, also in the steps before the joiner's first message
arrives (the V2V delay).

Merge point (with ``gs`` or ``gn``): at a zipper merge in traffic (carl_sumo.study.run) a vehicle
whose vehicle ahead is still on the other feeding lane, nearer to the merge point, hears it, and
its law runs on the gap it will have behind it. Beside it that gap is short, often negative, and
while the other vehicle draws away the law's robust gains answer it with almost nothing (kd·ė
against kp·e): it can reach the merge point alongside. So it also keeps at most the constant
acceleration with which it reaches the merge point, R metres ahead, s0 behind that vehicle:
2·(d - s0 + Δv·t)/t², t = R/v (:meth:`PloegChains.merge_behind`), and tells its follower. Far
from the merge point that is a gentle braking; it binds only when the gap would not open in time.

Opening (``op=B`` in a name): the same armed vehicle at the front of its chain opens its gap to
the 0.8 s at which it stops being armed, instead of leaving the gap to its law (whose robust
kp = 0.0445 1/s² answers a 10 m spacing error with -0.4 m/s²). Short of s_open = s0 + 0.8 s·v
by m = s_open - d_i > 0, it asks for the vehicle ahead to draw away at m/3 s and applies at most
(Δv_i - m/3 s)/1 s, never below -B; its follower hears it as a reaction's braking. Behind a
human who signals (``cut-in:signal=S``) it so makes room before he is in the lane.

The head's own law (``pa=KP``, ``da=KD``, ``fa=W`` in a name of a CACC): a vehicle that hears no
message (a chain's head behind a human, an ACC at ``ha``) runs the law with the gains kp = KP and
kd = KD instead of the chain's, and the head feeds forward W·a_0 (0 < W ≤ 1) of the leader's
measured acceleration instead of all of it. With a long ``ha``, a small KD and W below 1 the head
follows the leader's speed through its spacing terms alone, lets its gap breathe and passes on
less of the leader's motion (docs/baselines.md, "A soft head"); the followers' law is unchanged.
Theory: the first link's Γ with those gains and W·a_0 (:mod:`carl_sumo.control.transfer`).

A degraded CACC (``df=W`` in a name, with ``rb=1``): a follower whose predecessor's message is
lost (past the channel's timeout) feeds forward W times the acceleration ahead its radar
measures (a + the change of Δv over the step) instead of nothing, as the head does with the
leader's; while the held message fades (weight w) the feed-forward is w·held + (1 - w)·W·a_ahead.
It keeps its fallback gap ``ha``. (Ploeg et al. 2015, "Graceful degradation of CACC".)

Heavy vehicles (``ht=T`` in a name, with ``aw=1``): a vehicle whose own largest braking is below
7 m/s² (a truck) keeps the time gap T instead of h in its chain (in e_i, ė_i and the filter); a
car keeps h, a vehicle without a message ha.

As the base of a learned controller (``carl-sumo train --base ploeg-tuned:h=1``), a learned term
a_adj,i (m/s²) enters the law as one more feed-forward input beside the predecessor's:
u_i(k+1) = u_i(k) + (dt/h)·(-u_i(k) + kp·e_i + kd·ė_i + u_{i-1}(k) + a_adj,i). So it passes
through the controller's own first-order filter (time constant h), is part of the state u_i the
follower hears, and shifts the steady state by a_adj,i; an adjustment added after the law instead
is undone by it (measured: a low-pass adjustment added after the law raises jerk). Because
kp is small on the real plant (0.0445 1/s²), a bias of -0.07 m/s² in a_adj opens the gap by
1.6 m. With ``wo=T`` in the base's name (washout, e.g. ``ploeg:h=0.6:kp=0.0445:kd=1:wo=5``) the
term enters the law less its own running mean m_i (m_i(k+1) = m_i(k) + (dt/T)·(a_adj,i - m_i(k)),
T in s): a_adj,i - m_i(k) has no steady part, so the base alone holds the time gap and the learned
term only shapes transients (its effect on a constant input decays with time constant T).
With ``hf=1`` too (``...:wo=5:hf=1``) the head of a chain (no CACC vehicle ahead: the platoon's
first follower behind a human) takes its term as it is: the learned term may move the head's gap
(an ACC at ``ha`` with slack to spare) while every follower's stays the base's.

A learned spacing policy (``gp=T``, e.g. ``...:ht=0.8:gp=5:gl=0.5``): the learned term a_adj,i is
not an acceleration but follower i's time-gap command. Its offset δ_i (s) follows
GAP_PER_ADJ_S·a_adj,i (1 s per m/s²) through a low-pass of time constant T:
δ_i(k+1) = δ_i(k) + (dt/T)·(1 s/(m/s²)·a_adj,i - δ_i(k)), held where no term is given, and the
law runs at h_i + δ_i in e_i, ė_i and the filter (h_i its own gap: h, ht or ha), never below the
least gap of its class: ``gl`` (s, at most h; default h) for a car in the chain, ht for a heavy
vehicle, ha for a vehicle without a message. With a_adj = 0 it is the law itself. Not with ``wo``.
With ``gb=1`` (a headway budget) the offsets a chain asks for are shifted by one common amount so
that they sum to 0, each at or above its floor (:func:`ploeg_names.budgeted_offsets`; the floors
from the vehicles' braking known with ``aw=1``): RL moves gap between vehicles, never adds it.
With ``gh=S`` the target is chosen only every S s from a run's first step and held in between
(the term given at the other steps is not read): the learned gap is a decision of its own time
scale, and a trainer steps the environment S s per decision (a semi-MDP, ``PlatoonEnv.hold_steps``).

Names (accepted wherever a controller name is): ``ploeg`` (h = 1.0 s, textbook gains),
``ploeg:h=0.8``, ``ploeg:h=0.8:kp=0.1:kd=1.5``, and ``ploeg-tuned:h=0.8`` (the gains
``carl-sumo tune ploeg`` chose for that h, read from :data:`TUNED_FILE`).

``acc``, ``acc:h=3:kp=0.2:kd=0.7`` and ``acc-tuned:h=H`` are the same constant-time-gap law fed
by radar only: no V2V feed-forward (u_{i-1} = 0 for every follower, the first one included), the
adaptive cruise control that CACC is compared with (Ploeg et al. 2014).

``mpf:r=2:w2=0.3``: the commands of r vehicles ahead (:mod:`carl_sumo.control.feed_forward`).
"""

from __future__ import annotations

import math
from functools import lru_cache
from pathlib import Path

import numpy as np
from numba import njit

from carl_sumo.control.channel import Channel, Impairments, KeyedChannel
from carl_sumo.control.layers import (  # noqa: F401 (the layers' constants are read from here too)
    MERGE_MIN_SPEED_MPS, OPEN_GAP_S, OPEN_SPEED_TIME_S, OPEN_TIME_S, REACTION_LAG_S,
    REACTION_MARGIN_M, apply_layers, layer_params, without_message)
from carl_sumo.control.feed_forward import (  # noqa: F401 (mpf_*: read from here too)
    check_heard, message_size, mpf_feed_forward, mpf_relay, washed_adjustment, with_relays)
from carl_sumo.control.ploeg_names import (  # noqa: F401 (the names are read from here too)
    CLASSICAL_KINDS, GAP_PER_ADJ_S, HEAVY_BRAKING_MPS2, TEXTBOOK, TUNED_FILE, PloegParams,
    budgeted_offsets, gap_offset_step, is_ploeg_name, parse_ploeg, read_tuned, read_tuned_entries,
    tuned_file_for)
from carl_sumo.config import BOUNDS, DT_S, IDM, ControlBounds
from carl_sumo.errors import InputError

CRUISE_GAIN_PER_S = 0.4
"""k_cc: cruise-control gain of the speed cap a ≤ k_cc·(v0 - v) (1/s)."""


LAW = np.dtype([
    ("h", np.float64),        # time gap (s)
    ("h_alone", np.float64),  # time gap of a vehicle without a message, ha (s)
    ("h_heavy", np.float64),  # time gap of a heavy vehicle, ht (s; 0: h)
    ("h_floor", np.float64),  # the least time gap of a car in a chain under ``gp`` (s): gl, or h
    ("kp", np.float64),       # 1/s²
    ("kd", np.float64),       # 1/s
    ("kp_alone", np.float64),  # kp of a vehicle without a message, pa (1/s²; kp when not given)
    ("kd_alone", np.float64),  # kd of a vehicle without a message, da (1/s; kd when not given)
    ("lead_weight", np.float64),  # fa: the weight of the leader's measured acceleration in the
                                  # head's law (-; 1 when not given)
    ("s0", np.float64),       # standstill gap (m)
    ("dt", np.float64),       # step (s)
    ("acc_min", np.float64),  # the vehicle's bounds (m/s²)
    ("acc_max", np.float64),
    ("v0", np.float64),       # cruise-control speed (m/s)
    ("k_cc", np.float64),     # cruise-control gain (1/s)
])
"""The Ploeg law's numbers (the module docstring): the kernel's ``law``, an array of one record
(:func:`_numbers`)."""


@njit(cache=True)
def _ploeg_law(obs, u, brake, u_lead, adj, numbers, pred_mode, pred_held, u_min, u_max,
               gap_off):
    """The law alone, every follower (head first): updates ``u`` in place, returns a (m/s²).
    ``adj`` (m/s², shape (n,)) is the learned feed-forward term (zeros for the plain law).
    ``pred_mode`` / ``pred_held`` (shape (n,)): how follower i > 0 hears its predecessor's
    message (carl_sumo.control.channel: 0 this step's, 1 the held value, 2 none: no feed-forward);
    the message is the predecessor's last min(u, brake) (``brake``: its last layers' braking,
    m/s², inf: none). ``u_min`` / ``u_max`` (m/s², shape (n,)): each vehicle's own limits, which
    its state does not pass (anti-windup; ±inf: none), so the message it sends is a command it
    can follow. ``law.h_alone``: the time gap of the head and of a follower that hears no
    message; ``law.h_heavy`` that of a heavy vehicle (its braking below 7 m/s²). ``gap_off``
    (s, shape (n,)): each vehicle's time-gap offset under ``gp`` (zeros: none), added to its gap
    and floored at its class's least gap (a car in a chain ``law.h_floor``, a heavy vehicle its
    heavy gap, a vehicle without a message ``law.h_alone``)."""
    law = numbers[0]
    n = obs.shape[0]
    out = np.empty(n)
    u_pred = law.lead_weight * u_lead  # fa: the head's feed-forward of the leader's acceleration
    for i in range(n):
        alone = without_message(i, pred_mode)  # no message from ahead: ACC at h_alone
        hi = law.h_alone if alone else law.h
        kp, kd = (law.kp_alone, law.kd_alone) if alone else (law.kp, law.kd)
        if not alone and -u_min[i] < HEAVY_BRAKING_MPS2:  # ht (ploeg_names.chain_gap_s, inline)
            hi = max(law.h, law.h_heavy)
        if gap_off[i] != 0.0:  # gp: the learned gap, never below the class's least gap
            floor = hi if (alone or hi > law.h) else law.h_floor
            hi = max(hi + gap_off[i], floor)
        e = obs[i, 2] - law.s0 - hi * obs[i, 0]
        e_dot = obs[i, 3] - hi * obs[i, 1]
        u_in = u_pred
        if i > 0 and pred_mode[i] == 1:
            u_in = pred_held[i]
        elif i > 0 and pred_mode[i] == 2:  # no message: its fallback (0, or df's radar term)
            u_in = pred_held[i]
        sent_old = min(u[i], brake[i])  # its message of step k: u, or its layers' braking
        u_old = u[i]
        u[i] = min(u_old + (law.dt / hi) * (-u_old + kp * e + kd * e_dot + u_in + adj[i]),
                   law.k_cc * (law.v0 - obs[i, 0]))
        u[i] = min(max(u[i], u_min[i]), u_max[i])
        u_pred = sent_old
        out[i] = min(max(u[i], law.acc_min), law.acc_max)
    return out


@njit(cache=True)
def _ploeg_step(obs, u, brake, u_lead, adj, law, layers, pred_mode, pred_held, u_min, u_max,
                armed, a_ahead, merge_m, gap_off):
    """One step of a chain: the law (:func:`_ploeg_law`), then its safety layers
    (:func:`carl_sumo.control.layers.apply_layers`: ``armed``, ``a_ahead`` and ``merge_m`` are
    theirs), which bound a and write the braking they applied into ``brake``. Returns a (m/s²)."""
    out = _ploeg_law(obs, u, brake, u_lead, adj, law, pred_mode, pred_held, u_min, u_max,
                     gap_off)
    apply_layers(obs, out, brake, pred_mode, armed, a_ahead, merge_m, u_min, layers)
    return out


def _numbers(p: PloegParams, b: ControlBounds) -> tuple[np.ndarray, np.ndarray]:
    """The kernel's ``law`` (:data:`LAW`) and ``layers`` (:data:`carl_sumo.control.layers.LAYERS`)
    of a law, read-only."""
    law = np.array([(p.time_gap_s, p.gap_alone_s, p.heavy_gap_s or 0.0,
                     p.time_gap_s if p.gap_floor_s is None else p.gap_floor_s, p.kp, p.kd,
                     p.kp if p.alone_kp is None else p.alone_kp,
                     p.kd if p.alone_kd is None else p.alone_kd,
                     1.0 if p.lead_weight is None else p.lead_weight,
                     p.standstill_gap_m, DT_S, b.acc_min_mps2, b.acc_max_mps2,
                     IDM.desired_speed_mps, CRUISE_GAIN_PER_S)], dtype=LAW)
    law.flags.writeable = False
    layers = layer_params(p.reaction_ttc_s or 0.0, REACTION_MARGIN_M, REACTION_LAG_S,
                          p.safe_braking_mps2 or 0.0, p.safe_new_only,
                          p.opening_braking_mps2 or 0.0, p.standstill_gap_m, b.acc_min_mps2)
    return law, layers


def lost_feed_forward(mode: np.ndarray, held: np.ndarray, weight: np.ndarray | None,
                      radar: np.ndarray) -> np.ndarray:
    """``df``: each follower's feed-forward in place of its predecessor's message (m/s²): the
    message while it is live, w·held + (1 - w)·radar while it fades (``held`` is already
    w·held), ``radar`` (df times the acceleration ahead as the radar measures it) once it is
    lost; the head (row 0) keeps what it had."""
    w = np.ones(len(mode)) if weight is None else np.asarray(weight, dtype=np.float64)
    out = np.where(mode == 1, held + (1.0 - w) * radar, np.where(mode == 2, radar, held))
    out[:1] = held[:1]
    return np.ascontiguousarray(out, dtype=np.float64)


@lru_cache(maxsize=64)
def _no_limits(n: int) -> tuple[np.ndarray, np.ndarray]:
    """(-inf, +inf) limits of ``n`` vehicles, read-only (shared by every call)."""
    low, high = np.full(n, -np.inf), np.full(n, np.inf)
    low.flags.writeable = high.flags.writeable = False
    return low, high


@lru_cache(maxsize=64)
def _no_offsets(n: int) -> np.ndarray:
    """No learned time-gap offset for ``n`` vehicles (s), read-only (shared)."""
    zero = np.zeros(n)
    zero.flags.writeable = False
    return zero


@lru_cache(maxsize=64)
def _no_reaction_inputs(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """No vehicle of ``n`` armed, no braking ahead measured and no merge point, read-only
    (shared)."""
    armed, a_ahead = np.zeros(n, dtype=np.bool_), np.zeros(n)
    armed.flags.writeable = a_ahead.flags.writeable = False
    merge_m = np.full(n, np.inf)
    merge_m.flags.writeable = False
    return armed, a_ahead, merge_m


class PloegController:
    """The Ploeg CACC of a platoon: a full acceleration per follower, not an adjustment of IDM."""

    def __init__(self, params: PloegParams = TEXTBOOK, name: str | None = None,
                 bounds: ControlBounds = BOUNDS):
        if not (params.time_gap_s > 0 and math.isfinite(params.time_gap_s)):
            raise InputError(f"the Ploeg time gap h must be a positive number of seconds, "
                             f"got {params.time_gap_s}")
        self.params = params
        self.hold_steps = params.gap_hold_steps(DT_S)  # steps per learned-gap decision (gh)
        self.name = name or params.name()
        self.bounds = bounds
        self.u = np.zeros(0)
        self.brake = np.zeros(0)  # each follower's last reaction braking (m/s²; inf: none)
        self.u_min, self.u_max = np.zeros(0), np.zeros(0)
        self._leader_speed: float | None = None
        self._dv: np.ndarray | None = None  # each follower's Δv of the last step (m/s)
        self.channel: Channel | None = None
        self._k = 0
        self.adj_mean = np.zeros(0)  # each follower's running mean of a_adj (m/s², ``wo=T``)
        self.gap_off = np.zeros(0)  # each follower's learned time-gap offset (s, ``gp=T``)
        self.gap_held = np.zeros(0)  # each follower's held gap target (s, ``gh=S``)
        self._steps = 0  # committed steps since reset (``gh``'s decision steps: every S s)
        self._numbers: tuple = (None, None)  # (params, bounds, law, layers) of the kernel
        self._gap_floors: dict = {}  # gb=1: a chain's gap floors less its own gaps, by braking

    def reset(self, n_followers: int) -> None:
        check_heard(self.params, n_followers, self.name)
        self.u, self.brake = np.zeros(n_followers), np.full(n_followers, np.inf)
        self.adj_mean, self.gap_off = np.zeros(n_followers), np.zeros(n_followers)
        self.gap_held, self._steps = np.zeros(n_followers), 0
        self.u_min, self.u_max = np.full(n_followers, -np.inf), np.full(n_followers, np.inf)
        self._leader_speed, self._dv = None, None
        self.channel, self._k = None, 0

    def know_vehicles(self, a_max_mps2: np.ndarray, b_max_mps2: np.ndarray) -> None:
        """Every follower knows what its own vehicle can do (its class's largest acceleration
        and deceleration, m/s², positive): its state stays within them, so the command it sends
        its follower is one it can follow (without it a truck that cannot accelerate at 2 m/s²
        tells the car behind it to; docs/vehicles.md). Only a law named with ``aw=1`` uses them.
        Call after :meth:`reset`."""
        if self.params.anti_windup:
            self.u_min = -np.asarray(b_max_mps2, dtype=np.float64)
            self.u_max = np.asarray(a_max_mps2, dtype=np.float64).copy()

    def connect(self, impairments: Impairments, event_id: str) -> None:
        """Carry this episode's predecessor messages over an impaired channel (one link per
        follower, :mod:`carl_sumo.control.channel`, link stream 1 of the event). Call after
        :meth:`reset`."""
        self.channel = Channel(len(self.u), message_size(self.params), impairments,
                               impairments.rng(event_id, 1))
        self._k = 0

    def acceleration(self, obs: np.ndarray, adjustment: np.ndarray | None = None,
                     commit: bool = True) -> np.ndarray:
        """a (m/s², shape (n,)) from the observations [v, a, d, Δv] (shape (n, 4+), head first),
        with a learned feed-forward ``adjustment`` (m/s², shape (n,)) in the law when given.
        ``commit=False``: what the law would apply, the state left as it is (a preview)."""
        leader_speed = float(obs[0, 0] + obs[0, 3])
        a_lead = 0.0 if self._leader_speed is None else (leader_speed - self._leader_speed) / DT_S
        mode = held = received = heard = None
        if self.channel is not None:
            mode, received = self.channel.receive(self._k)
            held, heard = received[:, 0], self.channel.heard
        a_ahead = None if self._dv is None else obs[:, 1] + (obs[:, 3] - self._dv) / DT_S
        if self.params.washout_s is not None:
            adjustment, adj_mean = washed_adjustment(adjustment, self.adj_mean,
                                                     self.params.washout_s,
                                                     [0] if self.params.head_free else None)
        gap_off, gap_held = self.gap_off, self.gap_held
        if self.params.gap_policy_s is not None:  # the learned term is a gap, not an acceleration
            if adjustment is not None:
                if self._steps % self.hold_steps == 0:  # gh: a decision step
                    gap_held = self.gap_target(adjustment, -self.u_min)
                gap_off = gap_offset_step(self.gap_off, gap_held, self.params.gap_policy_s, DT_S)
            adjustment = None
        adjustment, sent = with_relays(self.params, np.minimum(self.u, self.brake), adjustment,
                                       mode, received, None if mode is None else self.channel.heard)
        if not commit:
            return self.step(obs, self.u.copy(), a_lead, adjustment, mode, held,
                             self.brake.copy(), a_ahead=a_ahead, gap_off=gap_off,
                             pred_weight=heard)
        if self.params.washout_s is not None:
            self.adj_mean = adj_mean
        self.gap_off, self.gap_held, self._steps = gap_off, gap_held, self._steps + 1
        self._leader_speed = leader_speed
        if self.params.reaction_braking_ahead:  # the radar's Δv, for the next step's a_ahead
            self._dv = np.array(obs[:, 3], dtype=np.float64)
        if self.channel is not None:  # follower j hears j - 1's message of step k: its state,
            messages = np.vstack([np.zeros((1, sent.shape[1])), sent[:-1]])  # or its braking
        out = self.step(obs, self.u, a_lead, adjustment, mode, held, self.brake, a_ahead=a_ahead,
                        gap_off=gap_off, pred_weight=heard)
        if self.channel is not None:
            self.channel.send(self._k, messages)
            self._k += 1
        return out

    def hold_decision(self, offsets: np.ndarray) -> None:
        """``gh``: start as if the decision of the first step had been ``offsets`` (s, one per
        follower, head first, after the budget): every gap offset in place and held, the next
        decision S s on (the string-stability test of a policy's chosen gaps,
        :mod:`carl_sumo.experiments.held_gaps`). Call after :meth:`reset`."""
        offsets = np.asarray(offsets, dtype=np.float64)
        if offsets.shape != self.gap_off.shape:
            raise InputError(f"{offsets.size} gap offsets for a platoon of {self.gap_off.size}")
        self.gap_off, self.gap_held, self._steps = offsets.copy(), offsets.copy(), 1

    def gap_target(self, adjustment: np.ndarray, b_max_mps2: np.ndarray) -> np.ndarray:
        """``gp``: the gap offsets (s) a chain's learned term asks for, head first (with ``gb=1``
        within the headway budget, :func:`budgeted_offsets`, at the floors of the vehicles whose
        largest braking is ``b_max_mps2``, m/s², inf: not known)."""
        target = GAP_PER_ADJ_S * np.asarray(adjustment, dtype=np.float64)
        if not self.params.gap_budget:
            return target
        key = (self.params, np.asarray(b_max_mps2, dtype=np.float64).tobytes())
        floors = self._gap_floors.get(key)
        if floors is None:  # a chain's (own, least) gaps change only with its vehicles
            own, least = self.params.class_gaps(b_max_mps2)
            floors = self._gap_floors[key] = least - own
        return budgeted_offsets(target, floors)

    def step(self, obs: np.ndarray, u: np.ndarray, u_lead: float,
             adjustment: np.ndarray | None = None, pred_mode: np.ndarray | None = None,
             pred_held: np.ndarray | None = None, brake: np.ndarray | None = None,
             armed: np.ndarray | None = None, a_ahead: np.ndarray | None = None,
             merge_m: np.ndarray | None = None, gap_off: np.ndarray | None = None,
             pred_weight: np.ndarray | None = None) -> np.ndarray:
        """One step of the law on a chain (head first): updates the states ``u`` in place; the
        head hears ``u_lead`` (m/s²); ``adjustment``: the learned feed-forward term (m/s²);
        ``pred_mode`` / ``pred_held``: how each follower hears its predecessor (default: this
        step's message); ``brake``: each vehicle's reaction braking of the last step (m/s², inf:
        none; its message is min(u, brake)), updated in place (default: none); ``armed``: the
        vehicles whose reaction layer acts although they hear a message (default: none);
        ``a_ahead``: the acceleration of each vehicle's vehicle ahead as its radar measures it
        (m/s², for the reaction and ``df``; default: 0); ``merge_m``: each vehicle's distance to
        a zipper merge's point while its vehicle ahead is still on the other feeding lane (m;
        inf: none, the default); ``pred_weight``: the weight w of each held message as it fades
        (:attr:`carl_sumo.control.channel.Channel.heard`; default 1), with ``df`` the rest
        (1 - w) of the feed-forward is the radar's term.
        Returns a (m/s²)."""
        p, b = self.params, self.bounds
        n = obs.shape[0]
        adj = np.zeros(n) if adjustment is None else \
            np.ascontiguousarray(adjustment, dtype=np.float64)
        if not p.feed_forward:  # ACC: radar only, no feed-forward for any follower
            u_lead, pred_mode, pred_held = 0.0, np.full(n, 2, dtype=np.int64), np.zeros(n)
        elif pred_mode is None:
            pred_mode, pred_held = np.zeros(n, dtype=np.int64), np.zeros(n)
        brake = np.full(n, np.inf) if brake is None else brake
        armed, a_ahead, merge_m = self._reaction_inputs(n, armed, a_ahead, merge_m)
        if p.lost_weight is not None and p.feed_forward:
            pred_held = lost_feed_forward(pred_mode, pred_held, pred_weight,
                                          p.lost_weight * a_ahead)
        if self._numbers[0] is not p or self._numbers[1] is not b:  # made once per law
            self._numbers = (p, b, *_numbers(p, b))
        law, layers = self._numbers[2:]
        return _ploeg_step(obs, u, brake, u_lead, adj, law, layers,
                           np.ascontiguousarray(pred_mode, dtype=np.int64),
                           np.ascontiguousarray(pred_held, dtype=np.float64), *self._limits(n),
                           armed, a_ahead, merge_m,
                           _no_offsets(n) if gap_off is None or gap_off.shape[0] != n else
                           np.ascontiguousarray(gap_off, dtype=np.float64))

    @staticmethod
    def _reaction_inputs(n: int, armed: np.ndarray | None, a_ahead: np.ndarray | None,
                         merge_m: np.ndarray | None
                         ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The kernel's ``armed``, ``a_ahead`` and ``merge_m`` (none armed, 0 and no merge
        point where not given)."""
        no_armed, zero, no_merge = _no_reaction_inputs(n)
        return (no_armed if armed is None else np.ascontiguousarray(armed, dtype=np.bool_),
                zero if a_ahead is None else np.ascontiguousarray(a_ahead, dtype=np.float64),
                no_merge if merge_m is None else np.ascontiguousarray(merge_m, dtype=np.float64))

    def _limits(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(u_min, u_max) of a chain of ``n`` (m/s²): the known vehicles' limits, else none
        (made once per length: this runs every step)."""
        if self.u_min.shape[0] == n:
            return self.u_min, self.u_max
        return _no_limits(n)


def ploeg_controller(name: str, tuned_file: Path | None = None, plant: str = "ideal"
                     ) -> PloegController:
    """A :class:`PloegController` from a name such as ``ploeg:h=0.8``, ``ploeg-tuned:h=1`` or
    ``acc:h=3`` (a ``-tuned`` name: the gains tuned for ``plant``)."""
    return PloegController(parse_ploeg(name, tuned_file, plant), name=name)


class PloegChains:
    """The Ploeg CACC on chains of CACC vehicles that form and break in traffic (the study).

    The state u of each vehicle is kept by vehicle ID (a vehicle new to the CACC starts at 0).
    Inside a chain each vehicle hears its predecessor's state of the last step; a chain's head
    has no CACC predecessor and takes, like a platoon's first follower, the acceleration of the
    vehicle ahead over the last step (0 with no vehicle ahead).
    """

    def __init__(self, params: PloegParams = TEXTBOOK, name: str | None = None,
                 bounds: ControlBounds = BOUNDS):
        self.controller = PloegController(params, name, bounds)
        self.name = self.controller.name
        self.u: dict[str, float] = {}
        self.brake: dict[str, float] = {}  # ID: its last reaction braking (m/s²; none: inf)
        self.limits: dict[str, tuple[float, float]] = {}  # ID: (a_max, b_max) (m/s²)
        self.links: KeyedChannel | None = None
        self.armed: set[str] = set()  # IDs whose reaction acts although they hear a message
        self.merge_m: dict[str, float] = {}  # ID: its distance to a zipper merge's point (m)
        self._dv: dict[str, tuple[str | None, float]] = {}
        self._k = 0
        self.adj_mean: dict[str, float] = {}  # ID: its running mean of a_adj (m/s², ``wo=T``)
        self.gap_off: dict[str, float] = {}  # ID: its learned time-gap offset (s, ``gp=T``)
        self.gap_held: dict[str, float] = {}  # ID: its held gap target (s, ``gh=S``)
        self._steps = 0  # committed steps since reset (``gh``: a choice every S s)

    def reset(self) -> None:
        """Forget every state, limit and link: a new run starts (every vehicle's u at 0)."""
        self.u, self.brake, self.limits, self.links, self._k = {}, {}, {}, None, 0
        self.adj_mean, self.gap_off, self.gap_held, self._steps = {}, {}, {}, 0
        self.armed, self.merge_m, self._dv = set(), {}, {}

    def arm(self, vehicle_ids: set[str]) -> None:
        """Arm these vehicles' reaction layer (``ttc=T``) although they hear a message."""
        self.armed = set(vehicle_ids)

    def merge_behind(self, merge_m: dict[str, float]) -> None:
        """ID: distance to a zipper merge's point (m) of the vehicles whose vehicle ahead is still
        on the other feeding lane; a law with ``gs``/``gn`` reaches that point behind it (the
        module docstring)."""
        self.merge_m = dict(merge_m)

    def know_vehicle(self, vehicle_id: str, a_max_mps2: float, b_max_mps2: float) -> None:
        """What one vehicle's powertrain can do (:meth:`PloegController.know_vehicles`; only a
        law named with ``aw=1`` uses it)."""
        self.limits[vehicle_id] = (a_max_mps2, b_max_mps2)

    def _set_limits(self, chain_ids: list[str]) -> None:
        """The chain's limits into the law (none for a vehicle whose limits are unknown)."""
        if not self.controller.params.anti_windup:
            return
        a_b = [self.limits.get(v, (np.inf, np.inf)) for v in chain_ids]
        self.controller.u_max = np.array([a for a, _ in a_b])
        self.controller.u_min = -np.array([b for _, b in a_b])

    def connect(self, impairments: Impairments, run_id: str) -> None:
        """Carry the predecessor states over impaired vehicle-keyed links
        (:class:`carl_sumo.control.channel.KeyedChannel`, stream 1 of ``run_id``)."""
        self.links = KeyedChannel(message_size(self.controller.params), impairments,
                                  impairments.rng(run_id, 1))
        self._k = 0

    def _radar_ahead(self, obs: np.ndarray, chain: list[int], ids: list[str],
                     ahead: list[tuple[str, float] | None], dv_new: dict) -> np.ndarray | None:
        """The acceleration of each chain row's vehicle ahead as its radar measures it (m/s²:
        a + the change of Δv since the last step with the same vehicle ahead, else 0), for a
        law with ``rb=1`` (else None); each row's (ID ahead, Δv) into ``dv_new``."""
        if not self.controller.params.reaction_braking_ahead:
            return None
        a_ahead = np.zeros(len(chain))
        for j, i in enumerate(chain):
            pred = ahead[i][0] if ahead[i] is not None else None
            prev = self._dv.get(ids[i])
            if prev is not None and prev[0] == pred:
                a_ahead[j] = obs[i, 1] + (obs[i, 3] - prev[1]) / DT_S
            dv_new[ids[i]] = (pred, float(obs[i, 3]))
        return a_ahead

    def acceleration(self, obs: np.ndarray, chains: list[list[int]], ids: list[str],
                     ahead: list[tuple[str, float] | None],
                     last_acc: dict[str, float], adjustment: np.ndarray | None = None,
                     commit: bool = True) -> np.ndarray:
        """a (m/s², shape (m,)) of the CACC vehicles ``ids`` with observations ``obs`` (m, 4);
        ``chains`` index rows head first, ``ahead`` is each row's (vehicle ahead, gap) or None
        and ``last_acc`` every vehicle's acceleration over the last step (m/s²). ``adjustment``
        (m/s², shape (m,)): a learned feed-forward term in the law; ``commit=False``: a preview
        that leaves the states as they are."""
        out = np.empty(obs.shape[0])
        washout_s = self.controller.params.washout_s
        if washout_s is not None:
            mean = np.array([self.adj_mean.get(v, 0.0) for v in ids])
            heads = [chain[0] for chain in chains] if self.controller.params.head_free else None
            adjustment, mean = washed_adjustment(adjustment, mean, washout_s, heads)
            if commit:
                self.adj_mean = dict(zip(ids, mean.tolist()))
        gap_off = np.array([self.gap_off.get(v, 0.0) for v in ids])
        gap_policy_s = self.controller.params.gap_policy_s
        if gap_policy_s is not None:  # the learned term is each vehicle's gap (``gp=T``)
            if adjustment is not None:
                target = np.array([self.gap_held.get(v, 0.0) for v in ids])
                if self._steps % self.controller.hold_steps == 0:
                    for chain in chains:  # each chain's budget (gb=1) over its own vehicles
                        b_max = [self.limits.get(ids[i], (np.inf, np.inf))[1] for i in chain]
                        target[chain] = self.controller.gap_target(
                            np.asarray(adjustment)[chain], np.array(b_max))
                gap_off = gap_offset_step(gap_off, target, gap_policy_s, DT_S)
                if commit:
                    self.gap_off = dict(zip(ids, gap_off.tolist()))
                    self.gap_held = dict(zip(ids, target.tolist()))
            adjustment = None
        u_new: dict[str, float] = {}
        brake_new: dict[str, float] = {}
        dv_new: dict[str, tuple[str | None, float]] = {}
        for chain in chains:
            head = ahead[chain[0]]
            a_pred = last_acc.get(head[0], 0.0) if head is not None else 0.0
            u = np.array([self.u.get(ids[i], 0.0) for i in chain])
            brake = np.array([self.brake.get(ids[i], np.inf) for i in chain])
            adj = None if adjustment is None else adjustment[chain]
            mode = held = received = heard = None
            if self.links is not None:  # follower j > 0 hears j - 1 over its link
                pairs = [(ids[chain[j]], ids[chain[j - 1]]) for j in range(1, len(chain))]
                mode = np.zeros(len(chain), dtype=np.int64)
                received = np.zeros((len(chain), message_size(self.controller.params)))
                got_mode, received[1:] = self.links.receive(self._k, pairs)
                mode[1:], held, heard = got_mode, received[:, 0], np.r_[1.0, self.links.heard]
            adj, sent = with_relays(self.controller.params, np.minimum(u, brake), adj, mode,
                                    received, heard)  # sent: its state, or its reaction's braking
            if self.links is not None and commit:
                self.links.send(self._k, pairs, sent[:-1])
            self._set_limits([ids[i] for i in chain])
            armed = [ids[i] in self.armed for i in chain] if self.armed else None
            merge_m = [self.merge_m.get(ids[i], np.inf) for i in chain] if self.merge_m else None
            a_ahead = self._radar_ahead(obs, chain, ids, ahead, dv_new)
            out[chain] = self.controller.step(np.ascontiguousarray(obs[chain]), u, a_pred, adj,
                                              mode, held, brake, armed, a_ahead, merge_m,
                                              gap_off[chain], heard)
            u_new.update(zip((ids[i] for i in chain), u.tolist()))
            brake_new.update(zip((ids[i] for i in chain), brake.tolist()))
        if commit:
            self.u, self.brake, self._dv = u_new, brake_new, dv_new
            self._k, self._steps = self._k + 1, self._steps + 1
        return out
