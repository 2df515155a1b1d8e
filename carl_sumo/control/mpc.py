"""Distributed model predictive CACC (``mpc``): every follower solves a QP every step.

Each follower i, every 0.1 s step k, plans its commands u(k), ..., u(k + N - 1 - D) (m/s²) over
a horizon of N steps with its own vehicle's model, the plant of :mod:`carl_sumo.sim.vehicle`:

    c(k) = u(k - D)                                  (D steps of actuation dead time)
    a(k+1) = α·c(k) + (1 - α)·a(k),  α = dt/(τ + dt) (first-order powertrain lag τ)
    v(k+1) = v(k) + a(k+1)·dt,  x(k+1) = x(k) + v(k+1)·dt   (SUMO's update)

and minimises, over the predicted steps j = 1..N,

    Σ_j wq·e_j² + wv·(v_p,j - v_j)²  +  Σ_i wu·u_i² + wj·((u_i - u_{i-1})/dt)²

with the constant-time-gap spacing error e_j = d_j - s0 - h·v_j (d the bumper gap, s0 = 2 m) and
the predecessor's predicted speed v_p,j, subject to u_i in the vehicle's own limits
[-b_max, a_max] (a car's [-9, 3] m/s², a truck's [-6, 1]). The commands already on their way
through the dead time are known to the vehicle (it sent them) and enter as data.

**The model** is the vehicle's class (known from its limits, :meth:`MPCController.know_vehicles`):
τ at the middle of the class's range and D at the top of its dead-time range
(:func:`class_model`: a car 0.3 s and 1 step, a truck 0.5 s and 2 steps), not the τ drawn for the
event, so on the real plant the MPC meets a model error of up to ±0.2 s of lag as a real vehicle
does. On the ideal plant (no powertrain) τ = 0 and D = 0, the limits -9 and 3 m/s².

**The predecessor's plan.** Every vehicle sends, every step, the accelerations it predicted at
its last step, a(k_s + 1), ..., a(k_s + N), stamped with that step k_s (one message late: the
vehicles solve at the same time, so a follower has its predecessor's plan of the last step), over
the platoon's impaired V2V links (:mod:`carl_sumo.control.channel`, delay and losses; a held
message is shifted by its age and its last value held past its end). The follower predicts the
predecessor's speed from the speed its radar measures now, v + Δv, and the plan (not below 0), and
its gap from the gap measured now. A vehicle that hears no plan (the platoon's head behind the
recorded human leader, a message lost past the timeout) plans with the vehicle ahead holding the
acceleration its radar measures (a + the change of Δv over the step), as an ACC at the time gap
``ha`` (Ploeg's degraded mode); while a held plan fades after the timeout (``--comm-fade``) the
prediction blends the two by the message's weight.

**QP.** Condensed: the states are affine in the m = N - D commands that act within the horizon,
so the QP has m variables, a fixed Hessian P (it does not depend on the plan, which enters the
gap and speed linearly) and box constraints (A = I); :mod:`osqp` is set up once per vehicle and
model, and every step only q and the bounds l, u are updated and the solver warm-starts from its
last solution. q = Q·z is one matrix product with the step's data z (own a, v, gap, last command,
the commands in the dead time, the predecessor's predicted speeds).

**Layers kept from Ploeg's law** (:mod:`carl_sumo.control.cacc`): the vehicle's own limits (as
``aw=1``, always on), the degraded ACC gap ``ha``, the heavy vehicles' gap ``ht`` (a vehicle whose
braking is below 7 m/s² keeps max(h, ht) in its chain), the reaction layer ``ttc=T`` (with
``rb=1``: counting the braking ahead) for a vehicle that hears no plan, and the cruise cap
a ≤ k_cc·(v0 - v). Not kept: the washout and learned term (``wo``), Gipps' safe speed (``gs``,
``gn``), the gap opening (``op``) and the merge-point layer; the MPC does not run in the mixed
traffic chains (study, scenarios) nor as a learned policy's base.

Names: ``mpc`` (:data:`DEFAULTS`), ``mpc:h=0.6:N=30:wq=0.1:wv=1:wu=0.5:wj=0.05:ha=1.4:ttc=2:rb=1``
with the options of :data:`MPC_OPTIONS`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
import osqp
from scipy import sparse

from carl_sumo.config import BOUNDS, DT_S, IDM
from carl_sumo.control.cacc import CRUISE_GAIN_PER_S, HEAVY_BRAKING_MPS2, REACTION_LAG_S, \
    REACTION_MARGIN_M
from carl_sumo.control.channel import FALLBACK, LIVE, Channel, Impairments
from carl_sumo.control.ploeg_names import OptionSpec
from carl_sumo.errors import InputError
from carl_sumo.sim.vehicle import VEHICLE_CLASSES

STANDSTILL_GAP_M = 2.0
"""s0 of the spacing error (m), as Ploeg's law."""

MAX_HORIZON = 100
"""The longest horizon N (steps, 10 s): the QP has up to N variables per vehicle and step."""

MAX_CLASS_DEAD_STEPS = max(int(round(c.dead_time_s[1] / DT_S)) for c in VEHICLE_CLASSES.values())
"""The longest dead time a model of a class has (steps; a truck's 0.2 s): N must exceed it."""

_W = (1e-6, 1e6)  # the range of a weight: positive and finite (0 would make P singular)
MPC_OPTIONS = (
    OptionSpec("h", float, "s", "0.6", 0.05, 10.0, "the time gap in a chain"),
    OptionSpec("N", int, "steps of 0.1 s", "30", 1, MAX_HORIZON,
               "the prediction horizon, longer than the dead time of every class (0.2 s)"),
    OptionSpec("wq", float, "1/m²", "0.1", *_W, "the weight of the squared spacing error e"),
    OptionSpec("wv", float, "s²/m²", "1", *_W, "the weight of the squared relative speed"),
    OptionSpec("wu", float, "s⁴/m²", "0.5", *_W, "the weight of the squared command"),
    OptionSpec("wj", float, "s⁶/m²", "0.05", *_W, "the weight of the squared command rate"),
    OptionSpec("ha", float, "s", "h", 0.05, 10.0,
               "the time gap of a vehicle that hears no plan (an ACC)"),
    OptionSpec("ht", float, "s", "h", 0.05, 10.0,
               "the time gap of a heavy vehicle (braking below 7 m/s²) in its chain"),
    OptionSpec("ttc", float, "s", "off", 0.1, 60.0,
               "below this time to collision a vehicle that hears no plan brakes (Ploeg's layer)"),
    OptionSpec("rb", int, "-", "0", 0, 1, "1: the reaction counts the braking ahead"),
)
"""The options of an ``mpc`` name: key, type, unit, default, range (inclusive) and meaning."""


@dataclass(frozen=True)
class MPCParams:
    """The parameters of the distributed MPC (:data:`MPC_OPTIONS`; units in the names)."""

    time_gap_s: float = 0.6           # h
    horizon: int = 30                 # N (steps)
    w_spacing: float = 0.1            # wq (1/m²)
    w_speed: float = 1.0              # wv (s²/m²)
    w_command: float = 0.5            # wu (s⁴/m²)
    w_rate: float = 0.05              # wj (s⁶/m²)
    alone_gap_s: float | None = None  # ha (None: h)
    heavy_gap_s: float | None = None  # ht (None: h)
    reaction_ttc_s: float | None = None  # ttc (None: no reaction layer)
    reaction_braking_ahead: bool = False  # rb

    def __post_init__(self) -> None:
        if self.horizon <= MAX_CLASS_DEAD_STEPS:
            raise InputError(f"the horizon N = {self.horizon} steps "
                             f"({self.horizon * DT_S:g} s) is not longer than the dead time of a "
                             f"truck ({MAX_CLASS_DEAD_STEPS * DT_S:g} s); give N > "
                             f"{MAX_CLASS_DEAD_STEPS}")

    @property
    def gap_alone_s(self) -> float:
        return self.time_gap_s if self.alone_gap_s is None else self.alone_gap_s

    @property
    def weights(self) -> tuple[float, float, float, float]:
        return self.w_spacing, self.w_speed, self.w_command, self.w_rate

    def name(self) -> str:
        """The controller name of these parameters (parses back to them)."""
        return (f"mpc:h={self.time_gap_s:g}:N={self.horizon}:wq={self.w_spacing:g}"
                f":wv={self.w_speed:g}:wu={self.w_command:g}:wj={self.w_rate:g}") + \
            (f":ha={self.alone_gap_s:g}" if self.alone_gap_s is not None else "") + \
            (f":ht={self.heavy_gap_s:g}" if self.heavy_gap_s is not None else "") + \
            (f":ttc={self.reaction_ttc_s:g}" if self.reaction_ttc_s is not None else "") + \
            (":rb=1" if self.reaction_braking_ahead else "")


_FIELD = {"h": "time_gap_s", "N": "horizon", "wq": "w_spacing", "wv": "w_speed",
          "wu": "w_command", "wj": "w_rate", "ha": "alone_gap_s", "ht": "heavy_gap_s",
          "ttc": "reaction_ttc_s", "rb": "reaction_braking_ahead"}
assert set(_FIELD.values()) == {f.name for f in fields(MPCParams)}

DEFAULTS = MPCParams(alone_gap_s=1.4, heavy_gap_s=0.8, reaction_ttc_s=2.0,
                     reaction_braking_ahead=True)
"""``mpc`` alone: the product's time gaps (cars 0.6 s, trucks 0.8 s, 1.4 s as an ACC) and the
reaction layer of the product's base (``ttc=2:rb=1``); options given replace these."""


def is_mpc_name(name: str) -> bool:
    """Whether ``name`` names the distributed MPC."""
    return name.split(":")[0] == "mpc"


def parse_mpc(name: str) -> MPCParams:
    """The parameters of an ``mpc`` name (:data:`DEFAULTS` with the options given replaced);
    InputError, one line, for an unknown option, a value out of its range, an option given twice
    or a horizon not longer than a truck's dead time."""
    if not is_mpc_name(name):
        raise InputError(f"{name!r} is not an mpc controller name")
    specs = {s.key: s for s in MPC_OPTIONS}
    given: dict[str, object] = {}
    for part in name.split(":")[1:]:
        key, sep, text = part.partition("=")
        if not sep or key not in specs:
            raise InputError(f"controller {name!r}: {part!r} is not an option; write mpc:" +
                             ":".join(f"{k}=VALUE" for k in specs))
        if _FIELD[key] in given:
            raise InputError(f"controller {name!r}: {key} is given twice")
        value = specs[key].value(name, text)
        given[_FIELD[key]] = bool(value) if key == "rb" else value
    values = {f.name: getattr(DEFAULTS, f.name) for f in fields(MPCParams)}
    values.update(given)
    try:
        return MPCParams(**values)
    except InputError as exc:
        raise InputError(f"controller {name!r}: {exc}") from None


def class_model(a_max_mps2: float, b_max_mps2: float) -> tuple[float, int]:
    """(τ s, dead time in steps) of the model of a vehicle with these limits: its class's
    (:data:`carl_sumo.sim.vehicle.VEHICLE_CLASSES`, matched by its limits) τ range's middle and
    dead-time range's top; the ideal vehicle (0, 0) when no class has these limits."""
    for c in VEHICLE_CLASSES.values():
        if math.isclose(c.a_max_mps2, a_max_mps2) and math.isclose(c.b_max_mps2, b_max_mps2):
            return 0.5 * (c.tau_s[0] + c.tau_s[1]), int(round(c.dead_time_s[1] / DT_S))
    return 0.0, 0


# ------------------------------------------------------------------------------ the QP
class CondensedQP:
    """The condensed QP of one model (τ, D), time gap h and weights over N steps (module
    docstring): the cost is wᵀKw in w = [z; U], z = [1, a0, v0, d0, u_prev, the last
    P = :data:`MAX_CLASS_DEAD_STEPS` commands u(k-P..k-1) (the model uses the last D of them, the
    commands in its dead time), the predecessor's speeds v_p,1..v_p,N], U the m = N - D
    commands u(k..k+m-1). z has the same layout for every model, so a platoon's z are one array."""

    def __init__(self, tau_s: float, dead_steps: int, time_gap_s: float, horizon: int,
                 weights: tuple[float, float, float, float]):
        n, d = horizon, dead_steps
        if n <= d:
            raise InputError(f"the MPC's horizon N = {n} steps is not longer than the dead time "
                             f"of {d} steps")
        self.n, self.d, self.m, self.nz = n, d, n - d, 5 + MAX_CLASS_DEAD_STEPS + n
        if d > MAX_CLASS_DEAD_STEPS:
            raise InputError(f"the MPC models at most {MAX_CLASS_DEAD_STEPS} steps of dead time")
        maps = self._maps(DT_S / (tau_s + DT_S), time_gap_s)
        acc, spacing, rel, command, rate = maps
        k = sum(w * mat.T @ mat for w, mat in zip(weights, (spacing, rel, command, rate)))
        self.hessian = k[self.nz:, self.nz:]
        self.linear = k[self.nz:, :self.nz]  # q = linear @ z
        self.acc_z, self.acc_u = acc[:, :self.nz], acc[:, self.nz:]
        self.spacing, self.relative = spacing, rel

    def _maps(self, alpha: float, h: float) -> tuple[np.ndarray, ...]:
        """The affine maps of w = [z; U] to the predicted a (N), e (N), v_p - v (N), U (m) and
        the command rate (U_i - U_{i-1})/dt (m)."""
        n, d, m, nz = self.n, self.d, self.m, self.nz
        first = 5 + MAX_CLASS_DEAD_STEPS  # the predecessor's speeds
        beta = 1.0 - alpha
        j = np.arange(n)
        steps = j[:, None] - j[None, :]
        lag = np.where(steps >= 0, alpha * beta ** np.maximum(steps, 0), 0.0)
        acc = np.zeros((n, nz + m))
        acc[:, 1] = beta ** (j + 1)            # a0 decays
        acc[:, first - d:first] = lag[:, :d]   # the commands in the dead time
        acc[:, nz:] = lag[:, d:]               # the commands planned now
        cum = np.tril(np.ones((n, n))) * DT_S  # Σ_{l ≤ j} · dt
        speed = cum @ acc
        speed[:, 2] += 1.0                     # v0
        gap = -cum @ speed
        gap[:, 3] += 1.0                       # d0
        gap[:, first:nz] += cum                # the predecessor's displacement
        spacing = gap - h * speed
        spacing[:, 0] -= STANDSTILL_GAP_M
        rel = -speed
        rel[:, first:nz] += np.eye(n)
        command = np.zeros((m, nz + m))
        command[:, nz:] = np.eye(m)
        rate = command.copy()
        rate[1:, nz:-1] -= np.eye(m - 1)
        rate[0, 4] = -1.0                      # u_prev
        return acc, spacing, rel, command, rate / DT_S

    def solver(self, low: float, high: float) -> QPSolver:
        """An OSQP problem of this QP with U in [low, high], set up once (q = 0 until updated),
        warm-starting from its last solution."""
        return QPSolver(self, low, high)

    def cost(self, z: np.ndarray, u: np.ndarray) -> float:
        """The cost ½Uᵀ P U + qᵀU + const of the QP (in OSQP's form, P = K_uu, q = K_uz·z)."""
        return float(0.5 * u @ self.hessian @ u + (self.linear @ z) @ u)


OSQP_SETTINGS = {"verbose": False, "warm_starting": True, "polishing": False, "eps_abs": 1e-5,
                 "eps_rel": 1e-5, "check_termination": 5, "max_iter": 4000, "adaptive_rho": True}
"""OSQP's settings for the MPC's QPs: tolerances 1e-5 (m/s² on commands of order 1), the
termination checked every 5 iterations (warm-started, most steps converge in a few)."""


class QPSolver:
    """One OSQP problem of a :class:`CondensedQP` (P and A = I fixed, set up once); per step
    :meth:`solve` updates q, and l and u only when they changed, and warm-starts from the last
    solution. It calls the compiled solver of :class:`osqp.OSQP` directly: the Python wrapper's
    ``update`` and ``solve`` (argument checks and a namespace of the results per call) cost 3
    times the solve itself on these small problems."""

    def __init__(self, qp: CondensedQP, low: float, high: float):
        self.problem = osqp.OSQP()
        self.problem.setup(sparse.triu(sparse.csc_matrix(qp.hessian), format="csc"),
                           np.zeros(qp.m), sparse.identity(qp.m, format="csc"),
                           np.full(qp.m, low), np.full(qp.m, high), **OSQP_SETTINGS)
        self.m, self.bounds = qp.m, (low, high)
        self.core = getattr(self.problem, "_solver", None)  # None: the wrapper's API

    def solve(self, q: np.ndarray, low: float, high: float) -> tuple[np.ndarray, float]:
        """(U, solve time s) of the QP with linear term q and U in [low, high]; U is 0 when
        OSQP returns no finite solution (it does not on these strictly convex problems)."""
        bounds = None
        if (low, high) != self.bounds:
            self.bounds = (low, high)
            bounds = (np.full(self.m, low), np.full(self.m, high))
        low_v, high_v = bounds if bounds else (None, None)
        if self.core is None:
            self.problem.update(q=q, l=low_v, u=high_v)
            result = self.problem.solve(raise_error=False)
            x, seconds = result.x, result.info.solve_time
        else:
            self.core.update_data_vec(q=q, l=low_v, u=high_v)
            self.core.solve()
            x, seconds = self.core.solution.x, self.core.info.solve_time
        return (x if np.isfinite(x).all() else np.zeros(self.m)), seconds


_QPS: dict[tuple, CondensedQP] = {}


def condensed_qp(tau_s: float, dead_steps: int, time_gap_s: float, params: MPCParams
                 ) -> CondensedQP:
    """The QP of one model and time gap (built once per process)."""
    key = (tau_s, dead_steps, time_gap_s, params.horizon, params.weights)
    if key not in _QPS:
        _QPS[key] = CondensedQP(tau_s, dead_steps, time_gap_s, params.horizon, params.weights)
    return _QPS[key]


def predecessor_speeds(v_ahead: np.ndarray, a_hold: np.ndarray, messages: np.ndarray, k: int
                       ) -> np.ndarray:
    """The predecessor's speeds v_p,1..v_p,N (m/s, not below 0; shape (n, N)) of n vehicles, from
    its speed now ``v_ahead`` (n,) and its accelerations a(k+1..k+N): the plan of each message
    [w, w·k_s, w·a(k_s+1..k_s+N)] (n, N + 2; made at step k_s < k, shifted by its age and its
    last value held past its end) with weight w, the measured ``a_hold`` (n,) held with the
    rest (w = 0: no plan)."""
    horizon = messages.shape[1] - 2
    w = messages[:, 0]
    heard = w > 0.0
    safe_w = np.where(heard, w, 1.0)
    age = np.where(heard, np.rint(k - messages[:, 1] / safe_w), 1).astype(np.int64)
    idx = np.minimum(np.maximum(age, 1)[:, None] + np.arange(horizon), horizon - 1)
    plan = np.take_along_axis(messages[:, 2:], idx, axis=1) / safe_w[:, None]
    a = w[:, None] * plan + (1.0 - w)[:, None] * a_hold[:, None]
    return np.maximum(v_ahead[:, None] + DT_S * np.cumsum(a, axis=1), 0.0)


def reaction_limit(gap_m: float, closing_mps: float, a_ahead: float, ttc_s: float) -> float:
    """The most a vehicle closing in may apply under Ploeg's reaction layer (m/s²;
    :mod:`carl_sumo.control.cacc`): -c²/(2·(d - 1 m - 0.5 s·c)) - max(-a_ahead, 0) when the time
    to collision is below ``ttc_s``, -inf with no room left, +inf when it does not act."""
    if closing_mps <= 0.0 or gap_m - REACTION_MARGIN_M >= ttc_s * closing_mps:
        return math.inf
    room = gap_m - REACTION_MARGIN_M - REACTION_LAG_S * closing_mps
    if room <= 0.0:
        return -math.inf
    return -(closing_mps * closing_mps / (2.0 * room) + max(-a_ahead, 0.0))


class MPCController:
    """The distributed MPC of a platoon (module docstring): a full acceleration per follower."""

    def __init__(self, params: MPCParams = DEFAULTS, name: str | None = None):
        self.params, self.name, self.bounds = params, name or params.name(), BOUNDS
        self._solvers: dict[tuple, QPSolver] = {}  # (follower, model, QP): its problem
        self.timed = False  # True: every OSQP solve time is appended to solve_s (s)
        self.solve_s: list[float] = []
        self.reset(0)

    def reset(self, n_followers: int) -> None:
        """A new platoon of ``n_followers``: ideal models, no plan, no channel."""
        n, horizon = n_followers, self.params.horizon
        self.model = [(0.0, 0)] * n
        self.low = np.full(n, BOUNDS.acc_min_mps2)
        self.high = np.full(n, BOUNDS.acc_max_mps2)
        self.pipe = np.zeros((n, MAX_CLASS_DEAD_STEPS))  # u(k-P..k-1) of each follower
        self.u_prev = np.zeros(n)
        self.plans = np.zeros((n, horizon + 2))  # [1, k_s, a(k_s+1..k_s+N)] (0 row: none yet)
        self._dv: np.ndarray | None = None
        self.channel: Channel | None = None
        self._k = 0

    def know_vehicles(self, a_max_mps2: np.ndarray, b_max_mps2: np.ndarray) -> None:
        """Each follower's limits (m/s², positive), which bound its commands, and its class's
        model (:func:`class_model`). Call after :meth:`reset`."""
        self.high = np.asarray(a_max_mps2, dtype=np.float64).copy()
        self.low = -np.asarray(b_max_mps2, dtype=np.float64)
        self.model = [class_model(a, b) for a, b in zip(self.high, -self.low)]

    def connect(self, impairments: Impairments, event_id: str) -> None:
        """Carry the plans over impaired links (one per follower, link stream 1 of the event,
        :class:`carl_sumo.control.channel.Channel`). Call after :meth:`reset`."""
        self.channel = Channel(len(self.u_prev), self.params.horizon + 2, impairments,
                               impairments.rng(event_id, 1))

    def _heard(self, n: int) -> tuple[np.ndarray, np.ndarray]:
        """(mode (n,), message (n, N + 2)) each follower has of its predecessor's plan this
        step, and sends the plans of the last step."""
        sent = np.vstack([np.zeros((1, self.plans.shape[1])), self.plans[:-1]])
        if self.channel is None:
            mode = np.full(n, LIVE)
            mode[0] = FALLBACK
            return mode, sent
        mode, held = self.channel.receive(self._k)
        held = np.where((mode == LIVE)[:, None], sent, held)
        self.channel.send(self._k, sent)
        return mode, held

    def acceleration(self, obs: np.ndarray) -> np.ndarray:
        """a (m/s², shape (n,)) from the observations [v, a, d, Δv] (shape (n, 4+), head first);
        every follower's plan of this step is kept, to be sent at the next."""
        n, p = obs.shape[0], self.params
        a_ahead = np.zeros(n) if self._dv is None else obs[:, 1] + (obs[:, 3] - self._dv) / DT_S
        self._dv = np.array(obs[:, 3], dtype=np.float64)
        mode, heard = self._heard(n)
        heard[mode == FALLBACK] = 0.0
        heard[0] = 0.0  # the head hears no plan: the recorded leader sends none
        alone = heard[:, 0] <= 0.0
        z = np.empty((n, 5 + MAX_CLASS_DEAD_STEPS + p.horizon))
        z[:, 0], z[:, 1], z[:, 2], z[:, 3], z[:, 4] = 1.0, obs[:, 1], obs[:, 0], obs[:, 2], self.u_prev
        z[:, 5:5 + MAX_CLASS_DEAD_STEPS] = self.pipe
        z[:, 5 + MAX_CLASS_DEAD_STEPS:] = predecessor_speeds(obs[:, 0] + obs[:, 3], a_ahead,
                                                             heard, self._k)
        out, plans = np.empty(n), np.zeros_like(self.plans)
        for i in range(n):
            out[i], plans[i, 2:] = self._solve(i, obs[i], z[i], a_ahead[i], bool(alone[i]))
        self.pipe = np.column_stack([self.pipe[:, 1:], out])
        self.u_prev = out
        plans[:, 0], plans[:, 1] = 1.0, self._k
        self.plans = plans
        self._k += 1
        return out

    def _time_gap(self, i: int, alone: bool) -> float:
        p = self.params
        if alone:
            return p.gap_alone_s
        if p.heavy_gap_s is not None and -self.low[i] < HEAVY_BRAKING_MPS2:
            return max(p.time_gap_s, p.heavy_gap_s)
        return p.time_gap_s

    def _solve(self, i: int, o: np.ndarray, z: np.ndarray, a_ahead: float, alone: bool
               ) -> tuple[float, np.ndarray]:
        """(the command applied, the predicted accelerations a(k+1..k+N)) of follower i with
        the step's data ``z`` (:class:`CondensedQP`)."""
        p = self.params
        tau, dead = self.model[i]
        qp = condensed_qp(tau, dead, self._time_gap(i, alone), p)
        v, gap, dv = float(o[0]), float(o[2]), float(o[3])
        low, high = self.low[i], self.high[i]
        high = max(min(high, CRUISE_GAIN_PER_S * (IDM.desired_speed_mps - v)), low)
        key = (i, qp)
        solver = self._solvers.get(key)
        if solver is None:
            solver = self._solvers[key] = qp.solver(low, high)
        u, seconds = solver.solve(qp.linear @ z, low, high)
        if self.timed:
            self.solve_s.append(seconds)
        a = min(max(float(u[0]), BOUNDS.acc_min_mps2, low), BOUNDS.acc_max_mps2, high)
        if alone and p.reaction_ttc_s is not None:
            limit = reaction_limit(gap, -dv, a_ahead if p.reaction_braking_ahead else 0.0,
                                   p.reaction_ttc_s)
            a = max(min(a, limit), BOUNDS.acc_min_mps2, low)
        u = u.copy()
        u[0] = a
        return a, qp.acc_z @ z + qp.acc_u @ u


def mpc_controller(name: str) -> MPCController:
    """An :class:`MPCController` from an ``mpc`` name."""
    return MPCController(parse_mpc(name), name=name)
