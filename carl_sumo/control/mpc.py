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
``rb=1``: counting the braking ahead) and the cruise cap a ≤ k_cc·(v0 - v). In Ploeg's law the
reaction layer guards only a vehicle that hears no message (the feed-forward passes a braking
on); the MPC's quadratic cost has no notion of a collision (it trades a spacing error against
its command), so with ``ra=1`` the layer guards every vehicle. Not kept: the washout and learned
term (``wo``: the MPC is no policy's base), Gipps' safe speed for every vehicle without a plan
(``gs``) and the gap opening (``op``). With ``gn=B`` (0: off) the chains (the study, the
scenarios) keep Ploeg's ``gn`` layers on the MPC's command: Gipps' safe speed for braking B
towards a vehicle that entered ahead (an armed vehicle at the front of its chain) and the bound
to reach a zipper merge's point behind the vehicle ahead (:mod:`carl_sumo.control.layers`).

**Opening a short gap** (``go=R``, m/s; 0: off). A vehicle far inside its spacing (a cramped
start, a cut-in) has a large negative spacing error e, and the quadratic cost removes it as fast
as the weights allow: each follower brakes to open its own gap while its predecessor does the
same, so the braking grows down the chain (measured on the training event
``zhu2020pool_val_0086``, every follower 1.27 m behind at 9.6 m/s: -0.6 m/s² at the head, -6
m/s² at the tail, where a truck's limit is reached and it collides). With ``go`` the cost's
error at predicted step j is e_j + o_j, o_j = max(-e_0 - b - R·j·dt, 0), for an error e_0 < -b
measured now (b the band below): the plan is asked to remove the shortfall at R m/s, re-planned every step (a reference
governor: it changes the QP's q only, :meth:`CondensedQP.opening_term`). The first
:data:`OPENING_DEADBAND_M` of a shortfall are left to the weights, so the governor does not act
while a platoon tracks its gaps: without that band it acted in the sine test and raised ‖Γ‖∞
(wq=0.4:ha=2: 1.0246 against 1.0003 without ``go``; with the band, 1.0003).

**Closing a long gap** (``gc=R``, m/s; 0: off). The same governor the other way round: a gap
longer than s0 + h·v by e_0 > b is closed at most R m/s faster than the spacing policy asks (the
cost's error is e_j - max(e_0 - b - R·j·dt, 0)), as a CACC's gap-closing mode. Without it a chain
far behind a slow vehicle removes its +50 m errors at full acceleration up to the road's speed,
and with a 3 s horizon it sees the queue too late (measured on the default event
``sumo42_f2321_l2303_fr7763``: a car hits a truck ahead at 32 m/s; docs/baselines.md).

Names: ``mpc`` (:data:`DEFAULTS`: ``mpc:h=0.6:N=30:wq=0.1:wv=1:wu=2:wj=0.2:ha=1.4:ht=0.8:ttc=2:
rb=1:ra=1``), or ``mpc`` with any of the options of :data:`MPC_OPTIONS`, e.g. ``mpc:h=0.8:N=40``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numpy as np
import osqp
from scipy import sparse

from carl_sumo.config import BOUNDS, DT_S, IDM
from carl_sumo.control.cacc import CRUISE_GAIN_PER_S, REACTION_LAG_S, REACTION_MARGIN_M
from carl_sumo.control.channel import FALLBACK, LIVE, Channel, Impairments, KeyedChannel
from carl_sumo.control.layers import layer_params, merge_point, safe_speed
from carl_sumo.control.ploeg_names import OptionSpec, chain_gap_s, tuned_law
from carl_sumo.errors import InputError
from carl_sumo.sim.vehicle import VEHICLE_CLASSES

STANDSTILL_GAP_M = 2.0
"""s0 of the spacing error (m), as Ploeg's law."""

OPENING_DEADBAND_M = 2.0
"""``go`` and ``gc``: the part of a short gap's shortfall (of a long gap's excess) the MPC removes
as its weights say (m); only the rest is opened (closed) at the bounded speed, so a platoon tracking its gaps (and the sine test of
string stability) is not affected."""

MAX_HORIZON = 100
"""The longest horizon N (steps, 10 s): the QP has up to N variables per vehicle and step."""

MAX_CLASS_DEAD_STEPS = max(int(round(c.dead_time_s[1] / DT_S)) for c in VEHICLE_CLASSES.values())
"""The longest dead time a model of a class has (steps; a truck's 0.2 s): N must exceed it."""


@dataclass(frozen=True)
class MPCParams:
    """The parameters of the distributed MPC (:data:`MPC_OPTIONS`; units in the names)."""

    time_gap_s: float = 0.6           # h
    horizon: int = 30                 # N (steps)
    w_spacing: float = 0.1            # wq (1/m²)
    w_speed: float = 1.0              # wv (s²/m²)
    w_command: float = 2.0            # wu (s⁴/m²)
    w_rate: float = 0.2               # wj (s⁶/m²)
    alone_gap_s: float | None = None  # ha (None: h)
    heavy_gap_s: float | None = None  # ht (None: h)
    reaction_ttc_s: float | None = None  # ttc (None: no reaction layer)
    reaction_braking_ahead: bool = False  # rb
    reaction_all: bool = False        # ra: the reaction layer on every vehicle (False: only one
                                      # that hears no plan, as Ploeg's law)
    opening_speed: float = 0.0        # go (m/s): a gap short of s0 + h·v opens at most this fast
                                      # (0: off)
    safe_braking: float = 0.0         # gn (m/s²): Gipps' safe speed towards a new vehicle ahead
                                      # and the zipper merge's bound, as Ploeg's ``gn`` (0: off)
    closing_speed: float = 0.0        # gc (m/s): a gap longer than s0 + h·v closes at most this
                                      # fast (0: off)

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
            (":rb=1" if self.reaction_braking_ahead else "") + \
            (":ra=1" if self.reaction_all else "") + \
            (f":go={self.opening_speed:g}" if self.opening_speed > 0.0 else "") + \
            (f":gn={self.safe_braking:g}" if self.safe_braking > 0.0 else "") + \
            (f":gc={self.closing_speed:g}" if self.closing_speed > 0.0 else "")


_FIELD = {"h": "time_gap_s", "N": "horizon", "wq": "w_spacing", "wv": "w_speed",
          "wu": "w_command", "wj": "w_rate", "ha": "alone_gap_s", "ht": "heavy_gap_s",
          "ttc": "reaction_ttc_s", "rb": "reaction_braking_ahead", "ra": "reaction_all",
          "go": "opening_speed", "gn": "safe_braking", "gc": "closing_speed"}
assert set(_FIELD.values()) == {f.name for f in fields(MPCParams)}

DEFAULTS = MPCParams(alone_gap_s=1.4, heavy_gap_s=0.8, reaction_ttc_s=2.0,
                     reaction_braking_ahead=True, reaction_all=True)
"""``mpc`` alone: the product's time gaps (cars 0.6 s, trucks 0.8 s, 1.4 s as an ACC), the
reaction layer of the product's base (``ttc=2:rb=1``) on every vehicle (``ra=1``), a 3 s horizon
and the weights chosen on 40 training events (docs/baselines.md); options given replace these."""

_W = (1e-6, 1e6)  # the range of a weight: positive and finite (0 would make P singular)


def _default(key: str) -> str:
    """The default of an option as :data:`DEFAULTS` has it."""
    value = getattr(DEFAULTS, _FIELD[key])
    return str(int(value)) if isinstance(value, bool) else f"{value:g}"


MPC_OPTIONS = (
    OptionSpec("h", float, "s", _default("h"), 0.05, 10.0, "the time gap in a chain"),
    OptionSpec("N", int, "steps of 0.1 s", _default("N"), 1, MAX_HORIZON,
               "the prediction horizon, longer than the dead time of every class (0.2 s)"),
    OptionSpec("wq", float, "1/m²", _default("wq"), *_W,
               "the weight of the squared spacing error e"),
    OptionSpec("wv", float, "s²/m²", _default("wv"), *_W,
               "the weight of the squared relative speed"),
    OptionSpec("wu", float, "s⁴/m²", _default("wu"), *_W, "the weight of the squared command"),
    OptionSpec("wj", float, "s⁶/m²", _default("wj"), *_W,
               "the weight of the squared command rate"),
    OptionSpec("ha", float, "s", _default("ha"), 0.05, 10.0,
               "the time gap of a vehicle that hears no plan (an ACC)"),
    OptionSpec("ht", float, "s", _default("ht"), 0.05, 10.0,
               "the time gap of a heavy vehicle (braking below 7 m/s²) in its chain"),
    OptionSpec("ttc", float, "s", _default("ttc"), 0.1, 60.0,
               "below this time to collision the reaction layer brakes (Ploeg's layer)"),
    OptionSpec("rb", int, "-", _default("rb"), 0, 1, "1: the reaction counts the braking ahead"),
    OptionSpec("ra", int, "-", _default("ra"), 0, 1,
               "1: the reaction layer guards every vehicle, 0: only one that hears no plan"),
    OptionSpec("go", float, "m/s", _default("go"), 0.0, 10.0,
               "a gap short of s0 + h·v is opened at most this fast (the spacing error's "
               "reference governor; 0: off)"),
    OptionSpec("gn", float, "m/s²", _default("gn"), 0.0, 20.0,
               "Gipps' safe speed for this braking towards a vehicle that entered ahead and, in "
               "traffic, the bound to reach a zipper merge's point behind the vehicle ahead "
               "(the layers of Ploeg's gn; 0: off)"),
    OptionSpec("gc", float, "m/s", _default("gc"), 0.0, 10.0,
               "a gap longer than s0 + h·v is closed at most this fast (the spacing error's "
               "reference governor, as a CACC's gap-closing mode; 0: off)"),
)
"""The options of an ``mpc`` name: key, type, unit, default (that of ``mpc``, :data:`DEFAULTS`),
range (inclusive) and meaning."""


def is_mpc_name(name: str) -> bool:
    """Whether ``name`` names the distributed MPC (``mpc``, or ``mpc-tuned``: the weights that
    ``carl-sumo tune mpc`` chose for a plant)."""
    return name.split(":")[0] in ("mpc", "mpc-tuned")


def parse_mpc(name: str, plant: str = "ideal") -> MPCParams:
    """The parameters of an ``mpc`` name (:data:`DEFAULTS` with the options given replaced), or of
    ``mpc-tuned[:h=H]`` (the law tuned for ``plant``, :func:`carl_sumo.control.ploeg_names.
    tuned_law`); InputError, one line, for an unknown option, a value out of its range, an option
    given twice, a horizon not longer than a truck's dead time, or no law tuned."""
    if not is_mpc_name(name):
        raise InputError(f"{name!r} is not an mpc controller name")
    if name.split(":")[0] == "mpc-tuned":
        return parse_mpc(tuned_law(name, plant=plant))
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
        given[_FIELD[key]] = bool(value) if key in ("rb", "ra") else value
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

    def opening_term(self, error_m: float, speed_mps: float, w_spacing: float,
                     closing_mps: float = 0.0) -> np.ndarray:
        """The change of q that opens a short gap at most ``speed_mps`` (``go``): with the
        spacing error now ``error_m`` < -b (b = :data:`OPENING_DEADBAND_M`), the cost's error at
        predicted step j is e_j + o_j, o_j = max(-error_m - b - speed_mps·j·dt, 0), so the plan
        is asked to remove the shortfall beyond b at that speed rather than at once (the cost's
        o_j·e_j term, halved as OSQP's q is: wq·Sᵀo with S the spacing map's command columns);
        zeros when the gap is short by b or less (or ``speed_mps`` is 0). With ``closing_mps`` >
        0 (``gc``) a gap too long by more than b is closed the same way: o_j = -max(error_m - b
        - closing_mps·j·dt, 0)."""
        steps = np.arange(1, self.n + 1) * DT_S
        excess = abs(error_m) - OPENING_DEADBAND_M
        rate = speed_mps if error_m < 0.0 else closing_mps
        if excess <= 0.0 or rate <= 0.0:
            return np.zeros(self.m)
        offset = np.maximum(excess - rate * steps, 0.0) * (1.0 if error_m < 0.0 else -1.0)
        return w_spacing * self.spacing[:, self.nz:].T @ offset

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
    ``update`` and ``solve`` check their arguments and build a namespace of the results per call
    (under cProfile, 4,485 calls took 1.15 s, 0.41 s of it in the compiled solve); where an OSQP
    version has no compiled solver object it goes through the wrapper."""

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


class MPCLaw:
    """The step of the MPC on a set of vehicles, shared by a platoon (:class:`MPCController`)
    and the chains in traffic (:class:`MPCChains`): each vehicle's QP (its OSQP problem kept by
    its key and model), the data of the step, the solve and the layers."""

    def __init__(self, params: MPCParams):
        self.params = params
        self.solvers: dict[tuple, QPSolver] = {}  # (vehicle key, QP): its problem
        self.timed = False  # True: every OSQP solve time is appended to solve_s (s)
        self.solve_s: list[float] = []

    def forget(self, keys: set) -> None:
        """Drop the problems of the vehicles not in ``keys`` (they left the road)."""
        self.solvers = {k: s for k, s in self.solvers.items() if k[0] in keys}

    def step(self, keys: list, obs: np.ndarray, state: dict, messages: np.ndarray,
             a_hold: np.ndarray, react: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(the commands applied (n,), the plans [1, k, a(k+1..k+N)] (n, N + 2)) of n vehicles
        at step k from their observations [v, a, d, Δv] (n, 4+); ``state``: their ``model``
        (list of (τ, D)), ``low``, ``high`` (m/s², (n,)), ``pipe`` (n, P) and ``u_prev`` (n,);
        ``messages`` (n, N + 2): the plan each hears (weight 0: none, it is an ACC at ha);
        ``a_hold`` (n,): the measured acceleration of the vehicle ahead; ``react`` (n,): whose
        reaction layer acts (``ttc``)."""
        n, p = obs.shape[0], self.params
        z = np.empty((n, 5 + MAX_CLASS_DEAD_STEPS + p.horizon))
        z[:, 0], z[:, 1], z[:, 2], z[:, 3] = 1.0, obs[:, 1], obs[:, 0], obs[:, 2]
        z[:, 4], z[:, 5:5 + MAX_CLASS_DEAD_STEPS] = state["u_prev"], state["pipe"]
        z[:, 5 + MAX_CLASS_DEAD_STEPS:] = predecessor_speeds(obs[:, 0] + obs[:, 3], a_hold,
                                                             messages, k)
        out, plans = np.empty(n), np.zeros((n, p.horizon + 2))
        for i in range(n):
            alone = messages[i, 0] <= 0.0
            out[i], plans[i, 2:] = self._solve(keys[i], obs[i], z[i], state["model"][i],
                                               (state["low"][i], state["high"][i]), alone,
                                               bool(react[i]), a_hold[i])
        plans[:, 0], plans[:, 1] = 1.0, k
        return out, plans

    def _time_gap(self, alone: bool, low: float) -> float:
        p = self.params
        if alone:
            return p.gap_alone_s
        return chain_gap_s(p.time_gap_s, p.heavy_gap_s, -low)

    def _solve(self, key, o: np.ndarray, z: np.ndarray, model: tuple[float, int],
               limits: tuple[float, float], alone: bool, react: bool, a_ahead: float
               ) -> tuple[float, np.ndarray]:
        """(the command applied, the predicted accelerations a(k+1..k+N)) of one vehicle with
        the step's data ``z`` (:class:`CondensedQP`)."""
        p = self.params
        low, high = limits
        h = self._time_gap(alone, low)
        qp = condensed_qp(*model, h, p)
        v, gap, dv = float(o[0]), float(o[2]), float(o[3])
        high = max(min(high, CRUISE_GAIN_PER_S * (IDM.desired_speed_mps - v)), low)
        solver = self.solvers.get((key, qp))
        if solver is None:
            solver = self.solvers[(key, qp)] = qp.solver(low, high)
        q = qp.linear @ z
        if p.opening_speed > 0.0 or p.closing_speed > 0.0:
            q = q + qp.opening_term(gap - STANDSTILL_GAP_M - h * v, p.opening_speed, p.w_spacing,
                                    p.closing_speed)
        u, seconds = solver.solve(q, low, high)
        if self.timed:
            self.solve_s.append(seconds)
        a = min(max(float(u[0]), BOUNDS.acc_min_mps2, low), BOUNDS.acc_max_mps2, high)
        if react and p.reaction_ttc_s is not None:
            limit = reaction_limit(gap, -dv, a_ahead if p.reaction_braking_ahead else 0.0,
                                   p.reaction_ttc_s)
            a = max(min(a, limit), BOUNDS.acc_min_mps2, low)
        u = u.copy()
        u[0] = a
        return a, qp.acc_z @ z + qp.acc_u @ u


def _fresh_state(n: int, horizon: int) -> dict:
    """The state of n vehicles new to the MPC: the ideal model and limits, no command sent, no
    plan (its rows are sent as [0, ...]: no plan yet)."""
    return {"model": [(0.0, 0)] * n, "low": np.full(n, BOUNDS.acc_min_mps2),
            "high": np.full(n, BOUNDS.acc_max_mps2),
            "pipe": np.zeros((n, MAX_CLASS_DEAD_STEPS)), "u_prev": np.zeros(n),
            "plan": np.zeros((n, horizon + 2))}


class MPCController:
    """The distributed MPC of a platoon (module docstring): a full acceleration per follower."""

    def __init__(self, params: MPCParams = DEFAULTS, name: str | None = None):
        self.params, self.name, self.bounds = params, name or params.name(), BOUNDS
        self.law = MPCLaw(params)
        self.reset(0)

    @property
    def model(self) -> list[tuple[float, int]]:
        """Each follower's model (τ s, dead time in steps)."""
        return self.state["model"]

    @property
    def timed(self) -> bool:
        return self.law.timed

    @timed.setter
    def timed(self, value: bool) -> None:
        self.law.timed = value

    @property
    def solve_s(self) -> list[float]:
        """Every OSQP solve time since ``timed`` was set (s)."""
        return self.law.solve_s

    @solve_s.setter
    def solve_s(self, value: list[float]) -> None:
        self.law.solve_s = value

    def reset(self, n_followers: int) -> None:
        """A new platoon of ``n_followers``: ideal models, no plan, no channel."""
        self.state = _fresh_state(n_followers, self.params.horizon)
        self._dv: np.ndarray | None = None
        self.channel: Channel | None = None
        self._k = 0

    def know_vehicles(self, a_max_mps2: np.ndarray, b_max_mps2: np.ndarray) -> None:
        """Each follower's limits (m/s², positive), which bound its commands, and its class's
        model (:func:`class_model`). Call after :meth:`reset`."""
        self.state["high"] = np.asarray(a_max_mps2, dtype=np.float64).copy()
        self.state["low"] = -np.asarray(b_max_mps2, dtype=np.float64)
        self.state["model"] = [class_model(a, b) for a, b in zip(a_max_mps2, b_max_mps2)]

    def connect(self, impairments: Impairments, event_id: str) -> None:
        """Carry the plans over impaired links (one per follower, link stream 1 of the event,
        :class:`carl_sumo.control.channel.Channel`). Call after :meth:`reset`."""
        self.channel = Channel(len(self.state["u_prev"]), self.params.horizon + 2, impairments,
                               impairments.rng(event_id, 1))

    def _heard(self, n: int) -> np.ndarray:
        """The message (n, N + 2) each follower has of its predecessor's plan this step (the
        head and a follower that falls back: none), having sent the plans of the last step."""
        plans = self.state["plan"]
        sent = np.vstack([np.zeros((1, plans.shape[1])), plans[:-1]])
        if self.channel is not None:
            mode, held = self.channel.receive(self._k)
            self.channel.send(self._k, sent)
            sent = np.where((mode == LIVE)[:, None], sent, held)
            sent[mode == FALLBACK] = 0.0
        sent[0] = 0.0  # the head hears no plan: the recorded leader sends none
        return sent

    def _reacting(self, messages: np.ndarray) -> np.ndarray:
        """Whose reaction layer acts: every vehicle's with ``ra=1``, else those without a plan."""
        alone = messages[:, 0] <= 0.0
        return np.ones_like(alone) if self.params.reaction_all else alone

    def acceleration(self, obs: np.ndarray) -> np.ndarray:
        """a (m/s², shape (n,)) from the observations [v, a, d, Δv] (shape (n, 4+), head first);
        every follower's plan of this step is kept, to be sent at the next."""
        n = obs.shape[0]
        a_ahead = np.zeros(n) if self._dv is None else obs[:, 1] + (obs[:, 3] - self._dv) / DT_S
        self._dv = np.array(obs[:, 3], dtype=np.float64)
        messages = self._heard(n)
        out, self.state["plan"] = self.law.step(list(range(n)), obs, self.state, messages,
                                                a_ahead, self._reacting(messages), self._k)
        self.state["pipe"] = np.column_stack([self.state["pipe"][:, 1:], out])
        self.state["u_prev"] = out
        self._k += 1
        return out


class MPCChains:
    """The distributed MPC on chains of CACC vehicles that form and break in traffic (the study,
    the scenarios; :class:`carl_sumo.control.cacc.PloegChains`' interface). Each vehicle's
    state (its model and limits, the commands in its dead time, its last plan) is kept by its
    ID; inside a chain each vehicle hears its predecessor's plan of the last step (over
    vehicle-keyed impaired links when connected); a chain's head hears none and plans as an ACC
    at ``ha`` with the vehicle ahead holding its acceleration of the last step. ``arm``: those
    vehicles' reaction layer acts although they hear a plan; with ``gn`` the safe-speed and
    merge-point layers of :class:`carl_sumo.control.cacc.PloegChains` bound the commands."""

    FORGET_EVERY = 100
    """Steps between two clean-ups of the OSQP problems of vehicles that left."""

    def __init__(self, params: MPCParams = DEFAULTS, name: str | None = None):
        self.params, self.name = params, name or params.name()
        self.law = MPCLaw(params)
        # gn: Ploeg's safe-speed and merge-point layers only (the MPC has its own reaction)
        self._gn_layers = layer_params(0.0, REACTION_MARGIN_M, REACTION_LAG_S,
                                       params.safe_braking, True, 0.0, STANDSTILL_GAP_M,
                                       BOUNDS.acc_min_mps2)
        self.reset()

    def reset(self) -> None:
        """Forget every vehicle, limit and link: a new run starts."""
        self.vehicles: dict[str, dict] = {}  # ID: model, low, high, pipe, u_prev, plan
        self.limits: dict[str, tuple[float, float]] = {}  # ID: (a_max, b_max) (m/s²)
        self.links: KeyedChannel | None = None
        self.armed: set[str] = set()
        self.merge_m: dict[str, float] = {}
        self._k = 0

    def arm(self, vehicle_ids: set[str]) -> None:
        """Arm these vehicles' reaction layer (``ttc=T``) although they hear a plan."""
        self.armed = set(vehicle_ids)

    def merge_behind(self, merge_m: dict[str, float]) -> None:
        """ID: distance to a zipper merge's point (m) of the vehicles whose vehicle ahead is
        still on the other feeding lane; with ``gn`` the MPC's command is bounded to reach that
        point behind it (:func:`carl_sumo.control.layers.merge_point`), else unused."""
        self.merge_m = dict(merge_m)

    def know_vehicle(self, vehicle_id: str, a_max_mps2: float, b_max_mps2: float) -> None:
        """What one vehicle's powertrain can do (m/s², positive): its limits and model."""
        self.limits[vehicle_id] = (a_max_mps2, b_max_mps2)

    def connect(self, impairments: Impairments, run_id: str) -> None:
        """Carry the plans over impaired vehicle-keyed links (stream 1 of ``run_id``)."""
        self.links = KeyedChannel(self.params.horizon + 2, impairments,
                                  impairments.rng(run_id, 1))
        self._k = 0

    def _state(self, row_ids: list[str]) -> dict:
        """The state of these vehicles (a vehicle new to the MPC: fresh, with its limits)."""
        state = _fresh_state(len(row_ids), self.params.horizon)
        state["model"] = list(state["model"])
        for j, vid in enumerate(row_ids):
            if vid in self.vehicles:
                for key in state:
                    state[key][j] = self.vehicles[vid][key]
            elif vid in self.limits:
                a_max, b_max = self.limits[vid]
                state["model"][j] = class_model(a_max, b_max)
                state["low"][j], state["high"][j] = -b_max, a_max
        return state

    def _messages(self, chains: list[list[int]], ids: list[str], plans: np.ndarray,
                  commit: bool) -> np.ndarray:
        """The plan each chain row hears (rows in chain order; heads: none), sending the plans
        of the last step over the links when connected."""
        index, at = {}, 0
        for chain in chains:
            for j, i in enumerate(chain):
                index[i] = at + j
            at += len(chain)
        pairs = [(ids[c[j]], ids[c[j - 1]]) for c in chains for j in range(1, len(c))]
        rows = [index[c[j]] for c in chains for j in range(1, len(c))]
        senders = plans[[index[c[j - 1]] for c in chains for j in range(1, len(c))]]
        messages = np.zeros_like(plans)
        if self.links is None or not pairs:
            messages[rows] = senders
            return messages
        mode, held = self.links.receive(self._k, pairs)
        if commit:
            self.links.send(self._k, pairs, senders)
        heard = np.where((mode == LIVE)[:, None], senders, held)
        heard[mode == FALLBACK] = 0.0
        messages[rows] = heard
        return messages

    def acceleration(self, obs: np.ndarray, chains: list[list[int]], ids: list[str],
                     ahead: list[tuple[str, float] | None], last_acc: dict[str, float],
                     adjustment: np.ndarray | None = None, commit: bool = True) -> np.ndarray:
        """a (m/s², shape (m,)) of the CACC vehicles ``ids`` with observations ``obs`` (m, 4+);
        ``chains`` index rows head first, ``ahead`` is each row's (vehicle ahead, gap) or None
        and ``last_acc`` every vehicle's acceleration over the last step (m/s²).
        ``adjustment``: none (the MPC is no learned policy's base); ``commit=False``: a preview
        that leaves the states as they are."""
        if adjustment is not None:
            raise InputError("the MPC takes no learned adjustment (it is no policy's base)")
        rows = [i for chain in chains for i in chain]
        out = np.zeros(obs.shape[0])
        if not rows:
            return out
        row_ids = [ids[i] for i in rows]
        state = self._state(row_ids)
        messages = self._messages(chains, ids, state["plan"], commit)
        a_hold = np.array([last_acc.get(ahead[i][0], 0.0) if ahead[i] is not None else 0.0
                           for i in rows])
        react = (messages[:, 0] <= 0.0) | np.array([v in self.armed for v in row_ids]) | \
            self.params.reaction_all
        out[rows], plans = self.law.step(row_ids, np.ascontiguousarray(obs[rows]), state,
                                         messages, a_hold, react, self._k)
        if self.params.safe_braking > 0.0:
            self._guard(obs, out, chains, ids, state, rows)
        if commit:
            pipe = np.column_stack([state["pipe"][:, 1:], out[rows]])
            self.vehicles = {vid: {"model": state["model"][j], "low": state["low"][j],
                                   "high": state["high"][j], "pipe": pipe[j],
                                   "u_prev": out[rows[j]], "plan": plans[j]}
                             for j, vid in enumerate(row_ids)}
            self._k += 1
            if self._k % self.FORGET_EVERY == 0:
                self.law.forget(set(row_ids))
        return out

    def _guard(self, obs: np.ndarray, out: np.ndarray, chains: list[list[int]], ids: list[str],
               state: dict, rows: list[int]) -> None:
        """``gn``: Ploeg's safe-speed layer (an armed vehicle at the front of its chain) and
        merge-point layer on each chain's commands ``out`` (in place), within each vehicle's
        braking (:mod:`carl_sumo.control.layers`)."""
        low, layers = dict(zip(rows, state["low"])), self._gn_layers
        for chain in chains:
            chain_obs = np.ascontiguousarray(obs[chain, :4])
            a = out[chain].copy()
            brake = np.full(len(chain), np.inf)
            armed = np.array([ids[i] in self.armed for i in chain], dtype=np.bool_)
            merge = np.array([self.merge_m.get(ids[i], np.inf) for i in chain])
            u_min = np.array([low[i] for i in chain], dtype=np.float64)
            safe_speed(chain_obs, a, brake, np.zeros(len(chain), dtype=np.int64), armed, u_min,
                       layers)
            merge_point(chain_obs, a, brake, merge, u_min, layers)
            out[chain] = a


def mpc_controller(name: str, plant: str = "ideal") -> MPCController:
    """An :class:`MPCController` from an ``mpc`` name (``mpc-tuned``: tuned for ``plant``)."""
    return MPCController(parse_mpc(name, plant), name=name)


def mpc_chains(name: str, plant: str = "ideal") -> MPCChains:
    """An :class:`MPCChains` from an ``mpc`` name (``mpc-tuned``: tuned for ``plant``)."""
    return MPCChains(parse_mpc(name, plant), name=name)
