"""The feed-forward terms of the constant-time-gap law (:mod:`carl_sumo.control.cacc`) besides
its predecessor's message: a learned term's washout (``wo=T``, :func:`washed_adjustment`, the law's
docstring) and the multi-predecessor CACC ``mpf``'s relayed commands (:func:`mpf_relay`), run by
:class:`carl_sumo.control.cacc.PloegController` and :class:`carl_sumo.control.cacc.PloegChains`.

Multi-predecessor feed-forward (``mpf:r=R:w1=W1:...:wR=WR`` with any of Ploeg's gains and
options, e.g. ``mpf:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2:rb=1:r=2:w2=0.3``; the options are
:data:`carl_sumo.control.ploeg_names.MPF_OPTIONS`): the same law with the commands of the R
vehicles ahead in place of the predecessor's,

    u_i(k+1) = u_i(k) + (dt/h)·(-u_i(k) + kp·e_i + kd·ė_i + Σ_{j=1..R} w_j·u_{i-j}(k - j·d))

each as its message really arrives: vehicle i hears vehicle i-1's message, which carries i-1's
own state and what i-1 heard of the R - 1 vehicles ahead of it, each with the weight (0-1) with
which i-1 heard it; so the command of vehicle i-j has crossed j links, with the V2V delay d and
the losses of each (:func:`mpf_relay`). Weights not given share equally what the given ones leave
of 1 (``mpf:r=2:w2=0.3``: w1 = 0.7, the two-ahead feed-forward of ``benchmarks/two_ahead.py``).
Where the chain is broken it degrades as Ploeg's law does: a vehicle that hears no message is an
ACC (at ``ha``, with its reaction layers); the weight of a vehicle it does not hear (ahead of the
chain's head, whose vehicle ahead is a human or the recorded leader, or heard with weight h < 1
while a message fades after its timeout) moves to its predecessor's command, w_j·(h·u_{i-j} +
(1 - h)·u_{i-1}), so the second vehicle of a chain runs Ploeg's law when the weights sum to 1. With
R = 1 (and w1 = 1) it is Ploeg's law to the bit, with R = 0 the ACC. ``mpf`` runs wherever a Ploeg
name does (simulate, evaluate, scenarios, the study, string-stability, a learned policy's base).

Its transfer function, a recurrence in the vehicle index, is
:func:`carl_sumo.control.transfer.gamma_links_discrete` (docs/string_stability.md).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from carl_sumo.config import DT_S
from carl_sumo.control.channel import FALLBACK, LIVE
from carl_sumo.control.ploeg_names import PloegParams
from carl_sumo.control.transfer import heard_weights
from carl_sumo.errors import InputError


@njit(cache=True)
def _mpf_relay(sent, mode, received, heard, weights, extra, messages):
    """See :func:`mpf_relay`; fills ``extra`` (n,) and ``messages`` (n, 2r - 1)."""
    n, r = sent.shape[0], weights.shape[0]
    m = r - 1
    for i in range(n):
        messages[i, :] = 0.0
        messages[i, 0] = sent[i]
        extra[i] = 0.0
        if i == 0 or mode[i] == FALLBACK:  # it hears nobody ahead: no feed-forward, no relay
            continue
        if mode[i] == LIVE:  # this step's message of i - 1 (no delay), heard whole
            src, w_link, u_in = messages[i - 1], 1.0, sent[i - 1]
        else:  # the held message, already faded by its weight w_link
            src, w_link, u_in = received[i], heard[i], received[i, 0]
        f = weights[0] * u_in
        for j in range(2, r + 1):
            h = src[m + j - 1] / w_link if w_link > 0.0 else 0.0
            f += weights[j - 1] * (src[j - 1] + (1.0 - h) * u_in)
        extra[i] = f - u_in
        if m > 0:  # what it relays: i - 1 as heard, and i - 1's relays but the farthest
            messages[i, 1], messages[i, 1 + m] = u_in, w_link
            for j in range(1, m):
                messages[i, 1 + j], messages[i, 1 + m + j] = src[j], src[m + j]


def mpf_relay(weights: tuple[float, ...], sent: np.ndarray, mode: np.ndarray | None = None,
              received: np.ndarray | None = None, heard: np.ndarray | None = None
              ) -> tuple[np.ndarray, np.ndarray]:
    """The multi-predecessor feed-forward of one chain of n vehicles (head first) at one step
    (the module docstring): (extra (n,), messages (n, 2r - 1)). ``extra`` (m/s²) is what the law
    adds to the predecessor's command u_in (the base's feed-forward) so that it feeds forward
    Σ_j w_j·u_{i-j}: 0 for the head and for a vehicle that hears nothing. ``messages`` is what
    each vehicle sends its follower this step: [its message ``sent`` (m/s²: min(u, its
    reaction's braking)), h_1·u_1, ..., h_{r-1}·u_{r-1}, h_1, ..., h_{r-1}], the commands of the
    r - 1 vehicles ahead as it heard them, times the weight h in [0, 1] with which it heard each.
    ``mode``, ``received`` (n, 2r - 1), ``heard`` (n,): how each vehicle hears its predecessor's
    message (LIVE / HELD / FALLBACK), the held messages faded by their weight, and that weight
    (:class:`carl_sumo.control.channel.Channel`); default: every message live (no channel)."""
    n, r = sent.shape[0], len(weights)
    if mode is None:
        mode, received, heard = np.full(n, LIVE, dtype=np.int64), np.zeros((n, 2 * r - 1)), \
            np.ones(n)
    extra, messages = np.empty(n), np.empty((n, 2 * r - 1))
    _mpf_relay(np.ascontiguousarray(sent, dtype=np.float64),
               np.ascontiguousarray(mode, dtype=np.int64),
               np.ascontiguousarray(received, dtype=np.float64),
               np.ascontiguousarray(heard, dtype=np.float64),
               np.asarray(weights, dtype=np.float64), extra, messages)
    return extra, messages


def mpf_feed_forward(weights: tuple[float, ...], commands: np.ndarray) -> np.ndarray:
    """:func:`mpf_relay`'s ``extra`` (m/s², shape (..., n)) when every message arrives at once:
    Σ_j c_{i,j}·u_{i-j} - u_{i-1} from the commands ``commands`` (m/s², shape (..., n), head
    first), with the weights c_{i,j} follower i uses (those of vehicles ahead of the head on its
    predecessor's: :func:`carl_sumo.control.transfer.heard_weights`); 0 for the head. The teacher
    ``two-ahead:c=C`` of ``train --imitate`` is this with weights (1 - C, C)."""
    commands = np.asarray(commands, dtype=np.float64)
    extra = np.zeros(commands.shape)
    for i in range(1, commands.shape[-1]):
        c = heard_weights(weights, i)
        extra[..., i] = sum(w * commands[..., i - j] for j, w in enumerate(c, 1)) \
            - commands[..., i - 1]
    return extra


def check_heard(params: PloegParams, n_followers: int, name: str | None = None) -> None:
    """InputError (one line) when a law hears more vehicles ahead than a platoon of
    ``n_followers`` has: its last follower hears n - 1 members (the leader sends nothing)."""
    if params.heard > max(n_followers - 1, 1):
        raise InputError(f"controller {name or params.name()!r}: r = {params.heard} vehicles "
                         f"heard, but in a platoon of {n_followers} followers the last one has "
                         f"{max(n_followers - 1, 0)} ahead that send; give r ≤ "
                         f"{max(n_followers - 1, 1)} or more --vehicles")


def message_size(params: PloegParams) -> int:
    """Numbers in one V2V message of the law: its state, and for an ``mpf`` law the r - 1
    relayed commands and their weights (:func:`mpf_relay`)."""
    return 2 * params.heard - 1 if params.multi else 1


def with_relays(params: PloegParams, sent: np.ndarray, adjustment: np.ndarray | None,
                mode: np.ndarray | None = None, received: np.ndarray | None = None,
                heard: np.ndarray | None = None) -> tuple[np.ndarray | None, np.ndarray]:
    """(the law's feed-forward term, the messages (n, :func:`message_size`)) of one chain at one
    step: for an ``mpf`` law ``adjustment`` (m/s², None: 0) plus :func:`mpf_relay`'s extra, and
    each vehicle's ``sent`` with its relays; for Ploeg's law ``adjustment`` and ``sent`` as they
    are."""
    if not params.multi:
        return adjustment, np.asarray(sent, dtype=np.float64)[:, None]
    extra, messages = mpf_relay(params.weights, sent, mode, received, heard)
    return (extra if adjustment is None else adjustment + extra), messages


def washed_adjustment(adjustment: np.ndarray | None, mean: np.ndarray, washout_s: float,
                      free: np.ndarray | list[int] | None = None
                      ) -> tuple[np.ndarray, np.ndarray]:
    """(a_adj - m, m updated with a_adj) for the washout ``wo=T`` (module docstring): the learned
    term (m/s², shape (n,); None: 0) less its running mean ``mean`` (m/s²), and the new mean.
    The rows ``free`` (the heads of ``hf=1``) take the term as it is, their mean held at 0."""
    adj = np.zeros_like(mean) if adjustment is None else \
        np.asarray(adjustment, dtype=np.float64)
    out, new_mean = adj - mean, mean + (DT_S / washout_s) * (adj - mean)
    if free is not None and len(free):
        out[free], new_mean[free] = adj[free], 0.0
    return out, new_mean
