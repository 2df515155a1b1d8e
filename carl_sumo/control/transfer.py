"""String stability in frequency, in theory: the transfer function Γ(jω) of one platoon link
(follower i's acceleration over its predecessor's) for the linear constant-time-gap laws of
:mod:`carl_sumo.control.cacc` on a vehicle with lag and dead time (:mod:`carl_sumo.sim.vehicle`).

Continuous (Ploeg et al. 2011, 2014): with the vehicle G(s) = e^{-φs} / (s²(τs + 1)) from command
to position, the controller K(s) = kp + kd·s, the spacing policy H(s) = 1 + h·s and the V2V
feed-forward D(s) = e^{-θs} (CACC) or 0 (ACC, radar only):

    Γ(s) = (G·K + D) / (H·(1 + G·K))

Discrete (:func:`gamma_discrete`): the same links as carl-sumo runs them every dt = 0.1 s, exactly:
the controller's Euler step u(k+1) = u(k) + (dt/h)(-u + kp·e + kd·ė + u_pred), the command u(k+1)
through D steps of dead time and the lag a(k+1) = α·c(k) + (1 - α)·a(k), and SUMO's integration
v(k+1) = v(k) + a(k+1)·dt, x(k+1) = x(k) + v(k+1)·dt. A link is string stable when
‖Γ‖∞ = max_ω |Γ(jω)| ≤ 1; :func:`h_min` is the smallest such time gap.

Multi-predecessor feed-forward (``mpf``, :func:`gamma_links_discrete`,
:func:`gamma_links_continuous`): follower i feeds forward Σ_j c_{i,j}·u_{i-j} delayed by j hops,
so the platoon is a recurrence in the vehicle index. With X_i the acceleration of follower i over
the leader's (X_{-1} = 1), P the plant a = P·u and the law's own terms as above, for i ≥ 1

    (ctrl/P + (dt/h)·own)·X_i = (dt/h)·(f·X_{i-1} + Σ_{j=1..min(r, i)} c_{i,j}·z^{-j·d}·X_{i-j}/P)

with c_{i,1} = w_1 + Σ_{j>i} w_j (a vehicle hears no one ahead of the chain's head: that weight
moves to its predecessor) and c_{i,j} = w_j otherwise; the head (i = 0) is the first link as
above. Link i's gain is Γ_i = X_i/X_{i-1}: it depends on i, through the r links before it. With
r = 1 it is Γ above for every i ≥ 1.
"""

from __future__ import annotations

import numpy as np

from carl_sumo.config import DT_S


def gamma_continuous(omega: np.ndarray, h: float, kp: float, kd: float, tau: float,
                     phi: float = 0.0, theta: float = 0.0, cacc: bool = True,
                     first_link: bool = False, lead_weight: float = 1.0) -> np.ndarray:
    """Γ(jω) (complex, shape of ``omega`` in rad/s) of the continuous law: time gap ``h`` (s),
    gains ``kp`` (1/s²), ``kd`` (1/s), lag ``tau`` (s), dead time ``phi`` (s), V2V delay ``theta``
    (s), with (``cacc``) or without the feed-forward. ``first_link``: the feed-forward is the
    leader's realised acceleration, not its command, so D(s) is the follower's own e^{-φs}/(τs+1)
    (the head of a carl-sumo platoon measures the leader's acceleration), weighted by
    ``lead_weight`` (``fa``)."""
    s = 1j * np.asarray(omega, dtype=float)
    lag = np.exp(-phi * s) / (tau * s + 1.0)
    g = lag / s ** 2
    gk = g * (kp + kd * s)
    d = (lead_weight * lag if first_link else np.exp(-theta * s)) if cacc else 0.0
    return (gk + d) / ((1.0 + h * s) * (1.0 + gk))


def gamma_discrete(omega: np.ndarray, h: float, kp: float, kd: float, tau: float,
                   dead_steps: int = 0, delay_steps: int = 0, cacc: bool = True,
                   pred_tau: float | None = None, pred_dead_steps: int | None = None,
                   first_link: bool = False, dt: float = DT_S,
                   lead_weight: float = 1.0) -> np.ndarray:
    """Γ(e^{jωdt}) of a link as carl-sumo runs it (see the module docstring): the follower's lag
    ``tau`` (s) and dead time ``dead_steps``, its predecessor's (default: the same; they set how
    the predecessor's message u relates to its acceleration), the V2V delay ``delay_steps``.
    ``first_link``: the predecessor is the leader, whose measured acceleration over the last step
    is the head's feed-forward (not a V2V message), weighted by ``lead_weight`` (``fa``)."""
    z = np.exp(1j * np.asarray(omega, dtype=float) * dt)
    integ = dt * z / (z - 1.0)                    # v from a, x from v (SUMO's Euler update)
    f = kp * integ ** 2 + kd * integ              # kp·e + kd·ė on the predecessor's a
    own = f + h * (kp * integ + kd)               # ... and on the follower's own a
    plant = _plant(z, tau, dead_steps, dt)        # a = P·u
    ctrl = z - 1.0 + dt / h                       # (z - 1 + dt/h)·U = (dt/h)·(...)
    if not cacc:
        feed = 0.0
    elif first_link:
        feed = lead_weight                        # the leader's measured acceleration
    else:
        pred = _plant(z, tau if pred_tau is None else pred_tau,
                      dead_steps if pred_dead_steps is None else pred_dead_steps, dt)
        feed = z ** (-delay_steps) / pred         # u_pred = a_pred / P_pred, delayed
    return (dt / h) * (f + feed) / (ctrl / plant + (dt / h) * own)


def heard_weights(weights: tuple[float, ...], i: int) -> list[float]:
    """c_{i,1..min(r,i)}: the weights follower i (i ≥ 1, counted from its chain's head) uses of
    the ``weights`` w_1..w_r, those of the vehicles ahead of the chain's head added to its
    predecessor's (the module docstring; :func:`carl_sumo.control.cacc.mpf_relay`)."""
    c = list(weights[:i])
    c[0] += sum(weights[i:])
    return c


def gamma_links_discrete(omega: np.ndarray, n: int, h: float, kp: float, kd: float, tau: float,
                         dead_steps: int = 0, delay_steps: int = 0,
                         weights: tuple[float, ...] = (1.0,), h_first: float | None = None,
                         dt: float = DT_S, first_gains: tuple[float, float] | None = None,
                         lead_weight: float = 1.0) -> np.ndarray:
    """Γ_i(e^{jωdt}) (complex, shape (n, len(omega))) of the n links of a homogeneous platoon
    that feeds forward the commands of the r = len(weights) vehicles ahead with weights w_j, the
    j-th delayed by j·``delay_steps`` (the module docstring); ``weights`` () is the ACC. The
    head's link is :func:`gamma_discrete`'s first link at ``h_first`` (default h) with the gains
    ``first_gains`` (kp, kd; default the others') and the leader's acceleration weighted by
    ``lead_weight``."""
    z = np.exp(1j * np.asarray(omega, dtype=float) * dt)
    integ = dt * z / (z - 1.0)
    plant = _plant(z, tau, dead_steps, dt)

    def law(gap: float, p: float, d: float) -> tuple[np.ndarray, np.ndarray]:
        f = p * integ ** 2 + d * integ
        return f, (z - 1.0 + dt / gap) / plant + (dt / gap) * (f + gap * (p * integ + d))

    gap0 = h if h_first is None else h_first
    f0, den0 = law(gap0, *(first_gains or (kp, kd)))
    x = [(dt / gap0) * (f0 + (lead_weight if weights else 0.0)) / den0]  # X_0 over the leader
    f, inner = law(h, kp, kd)
    for i in range(1, n):
        feed = sum(c * z ** (-j * delay_steps) * x[i - j] / plant
                   for j, c in enumerate(heard_weights(weights, i) if weights else [], 1))
        x.append((dt / h) * (f * x[i - 1] + feed) / inner)
    x = np.array(x)
    return x / np.vstack([np.ones_like(x[:1]), x[:-1]])


def gamma_links_continuous(omega: np.ndarray, n: int, h: float, kp: float, kd: float,
                           tau: float, phi: float = 0.0, theta: float = 0.0,
                           weights: tuple[float, ...] = (1.0,), h_first: float | None = None,
                           first_gains: tuple[float, float] | None = None,
                           lead_weight: float = 1.0) -> np.ndarray:
    """The continuous counterpart of :func:`gamma_links_discrete`: H·(1 + G·K)·X_i =
    G·K·X_{i-1} + Σ_j c_{i,j}·e^{-jθs}·X_{i-j}, the head's link :func:`gamma_continuous`'s
    first link (at ``h_first``, default h, with the gains ``first_gains``, default kp, kd)."""
    s = 1j * np.asarray(omega, dtype=float)
    lag = np.exp(-phi * s) / (tau * s + 1.0)
    gk = lag / s ** 2 * (kp + kd * s)
    gap0 = h if h_first is None else h_first
    p0, d0 = first_gains or (kp, kd)
    gk0 = lag / s ** 2 * (p0 + d0 * s)
    x = [(gk0 + (lead_weight * lag if weights else 0.0)) / ((1.0 + gap0 * s) * (1.0 + gk0))]
    for i in range(1, n):
        feed = sum(c * np.exp(-j * theta * s) * x[i - j]
                   for j, c in enumerate(heard_weights(weights, i) if weights else [], 1))
        x.append((gk * x[i - 1] + feed) / ((1.0 + h * s) * (1.0 + gk)))
    x = np.array(x)
    return x / np.vstack([np.ones_like(x[:1]), x[:-1]])


def links_theory(omega: np.ndarray, n: int, h: float, kp: float, kd: float, tau: float,
                 dead_steps: int, delay_steps: int, weights: tuple[float, ...],
                 h_first: float | None = None, dt: float = DT_S,
                 first_gains: tuple[float, float] | None = None, lead_weight: float = 1.0
                 ) -> dict:
    """|Γ_i| of a multi-predecessor platoon of ``n`` followers, discrete and continuous (lists,
    for JSON): ``per_link`` (n lists each), ``first_link`` and ``inner_links`` (the largest over
    the links behind a follower; a platoon of one: its link). ``first_gains``: the head's
    (kp, kd) where they differ (``pa``, ``da``), ``lead_weight`` its ``fa``."""
    disc = np.abs(gamma_links_discrete(omega, n, h, kp, kd, tau, dead_steps, delay_steps, weights,
                                       h_first, dt, first_gains, lead_weight))
    cont = np.abs(gamma_links_continuous(omega, n, h, kp, kd, tau, dead_steps * dt,
                                         delay_steps * dt, weights, h_first, first_gains,
                                         lead_weight))
    inner = slice(1, None) if n > 1 else slice(0, 1)
    return {"per_link": {"continuous": cont.tolist(), "discrete": disc.tolist()},
            "first_link": {"continuous": cont[0].tolist(), "discrete": disc[0].tolist()},
            "inner_links": {"continuous": cont[inner].max(axis=0).tolist(),
                            "discrete": disc[inner].max(axis=0).tolist()}}


def _plant(z: np.ndarray, tau: float, dead_steps: int, dt: float) -> np.ndarray:
    """a(z)/u(z): the command u(k+1) of step k, D steps of dead time, the first-order lag."""
    alpha = dt / (tau + dt)
    return alpha * z ** (1 - dead_steps) / (z - 1.0 + alpha)


def log_frequencies(n: int = 24, low: float = 0.05, high: float = 3.0) -> np.ndarray:
    """``n`` log-spaced frequencies from ``low`` to ``high`` (rad/s)."""
    return np.geomspace(low, high, n)


def hinf(omega: np.ndarray, gamma: np.ndarray) -> float:
    """max_ω |Γ(jω)| over the given frequencies."""
    return float(np.max(np.abs(gamma)))


def h_min(kp: float, kd: float, tau: float, phi: float = 0.0, theta: float = 0.0,
          cacc: bool = True, h_high: float = 20.0, tol: float = 1e-3,
          omega: np.ndarray | None = None) -> float:
    """The smallest time gap (s) with ‖Γ‖∞ ≤ 1 for the continuous law (bisection; the peak
    falls as h grows); ``inf`` when even ``h_high`` is not string stable."""
    w = np.geomspace(1e-3, 30.0, 3000) if omega is None else omega

    def stable(h: float) -> bool:
        return hinf(w, gamma_continuous(w, h, kp, kd, tau, phi, theta, cacc)) <= 1.0 + 1e-9

    return smallest_stable_gap(stable, 0.0, h_high, tol) if stable(h_high) else float("inf")


def widen_bracket(stable, lo: float, hi: float, step: float, floor: float) -> tuple[float, float]:
    """A bracket (lo, hi) of the smallest string-stable gap around a guessed one: ``hi`` raised
    by ``step`` until ``stable(hi)``, ``lo`` lowered by ``step`` (not below ``floor``) while
    ``stable(lo)``."""
    while not stable(hi):
        lo, hi = hi, hi + step
    while lo > floor and stable(lo):
        hi, lo = lo, max(floor, lo - step)
    return lo, hi


def smallest_stable_gap(stable, lo: float, hi: float, tol: float) -> float:
    """Bisection for the smallest time gap (s) in (lo, hi] with ``stable(h)`` true, given that it
    holds at ``hi`` and not at ``lo``, to within ``tol``; every h_min of carl-sumo uses it."""
    while hi - lo > tol:
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if stable(mid) else (mid, hi)
    return hi


def h_min_links(kp: float, kd: float, tau: float, delay_steps: int = 0,
                weights: tuple[float, ...] = (1.0,), n: int = 5, h_high: float = 20.0,
                tol: float = 1e-3, omega: np.ndarray | None = None) -> float:
    """The smallest time gap (s) at which the exact discrete Γ_i of every link behind a follower
    among ``n`` (:func:`gamma_links_discrete`, the links a CACC's messages reach) has
    |Γ_i| ≤ 1 at every frequency of ``omega`` (default: 2000 from 1e-3 rad/s to Nyquist);
    bisection, ``inf`` when even ``h_high`` is not string stable."""
    w = np.geomspace(1e-3, np.pi / DT_S, 2000) if omega is None else omega

    def stable(h: float) -> bool:
        links = gamma_links_discrete(w, n, h, kp, kd, tau, 0, delay_steps, weights)
        return float(np.abs(links[1:]).max()) <= 1.0 + 1e-9

    return smallest_stable_gap(stable, 0.0, h_high, tol) if stable(h_high) else float("inf")


ROBUST_OMEGAS = np.geomspace(0.01, 10.0, 400)
"""Frequencies (rad/s) of the robust check: the peak of a constant-time-gap link lies in them."""
ROBUST_LINKS = 10
"""Followers of the homogeneous platoon in which the robust check of a multi-predecessor law
takes each link's gain (the platoon length of the tables and of ``carl-sumo tune``)."""


def robust_hinf(h: float, kp: float, kd: float, corners: list[tuple[float, int]],
                delay_steps: int, cacc: bool = True, omegas: np.ndarray = ROBUST_OMEGAS,
                mixed: bool = False, first_link: bool = False,
                weights: tuple[float, ...] = (1.0,), n_links: int = ROBUST_LINKS) -> float:
    """The largest ‖Γ‖∞ of the discrete law over platoons of each vehicle (τ s, dead steps) in
    ``corners``, behind one like itself (a V2V link of a CACC); ``mixed``: also behind every
    other corner (a heterogeneous link); ``first_link``: also behind the leader.

    A multi-predecessor law (``weights`` w_1..w_r other than (1,), with ``cacc``): the gain of
    each link depends on the r links before it (:func:`gamma_links_discrete`), so each corner is
    a homogeneous platoon of ``n_links`` followers and the largest |Γ_i| over its links behind a
    follower (i ≥ 1, those the relayed messages reach) counts; ``first_link`` adds the head's
    link, and ``mixed`` is not defined for it (InputError is the caller's: ValueError here)."""
    if cacc and tuple(weights) != (1.0,):
        if mixed:
            raise ValueError("robust_hinf: a mixed platoon of a multi-predecessor law is not "
                             "a single link; give corners as homogeneous platoons")
        worst = 0.0
        for tau, dead in corners:
            links = np.abs(gamma_links_discrete(omegas, max(n_links, 2), h, kp, kd, tau, dead,
                                                delay_steps, tuple(weights)))
            worst = max(worst, float((links if first_link else links[1:]).max()))
        return worst
    worst = 0.0
    for tau, dead in corners:
        if first_link:
            worst = max(worst, hinf(omegas, gamma_discrete(
                omegas, h, kp, kd, tau, dead, delay_steps, cacc, first_link=True)))
        for pred_tau, pred_dead in (corners if mixed else [(tau, dead)]):
            worst = max(worst, hinf(omegas, gamma_discrete(
                omegas, h, kp, kd, tau, dead, delay_steps, cacc, pred_tau, pred_dead)))
    return worst
