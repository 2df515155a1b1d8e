"""Warm start by imitation: the actor first copies a classical CACC, then RL improves on it.

``carl-sumo train --imitate ploeg:h=1.1:kp=2.278:kd=10.6313`` on the paper's IDM base, or
``--imitate ploeg:h=0.8:kp=0.3:kd=1.5 --base acc:h=0.8:kp=0.3:kd=1.5`` on a radar-only ACC base
with the same gains (see "On an ACC base" below).

**Teacher.** Ploeg's law (:mod:`carl_sumo.control.cacc`) read from the platoon's observations, so that
every state can be labelled, including states the teacher itself would not reach: the
controller state u_i is the acceleration the follower applied last step (a_i, in o_i), and the
predecessor's V2V message is its applied a_{i-1}; the first follower hears nothing (its leader is
a human NGSIM vehicle), so for it the law is an ACC:

    a_T,i = clip(a_i + (dt/h)·(-a_i + kp·e_i + kd·ė_i + a_{i-1}), -9, 3)   (m/s², a_0 := 0)
    target a_adj,i = clip(a_T,i - a_IDM(o_i), ±adj_max)

with e_i = d_i - s0 - h·v_i and ė_i = Δv_i - h·a_i. On a platoon that follows the law this is
the law exactly. A communication-aware actor can represent it (a_{i-1} reaches vehicle i through
the head-to-tail messages); a per-vehicle actor (DDPG, TD3) sees o_i only and learns the mean of
the target given o_i.

**Data.** During the first ``--learning-starts`` steps the platoons drive with the teacher's
target plus the run's exploration noise (DART, Laskey et al. 2017: noise while the teacher
drives, so the data covers the states a slightly-off student reaches); the labels are the
teacher's clean targets on the stored states, recomputed from the replay buffer (so a resumed run
needs nothing else).

**On an ACC base.** The ACC is Ploeg's law without the predecessor's message, and a_adj enters
that law where the CACC feeds the message forward (:meth:`carl_sumo.control.cacc.PloegController.step`).
With the same h, kp and kd the CACC is therefore the ACC with a_adj,i = a_{i-1}, the
predecessor's acceleration (0 for the first follower, behind the human leader), and that is the
target. Only the V2V messages carry a_{i-1} to vehicle i: a communication-aware actor can copy the
teacher, an actor that hears nothing (CA-off, TD3) only its mean given o_i.
``--imitate-target command`` feeds forward the predecessor's command instead (its base's
a_base, the fifth column of o), which its actuator follows with its lag, as the CACC's own message
does; the default ``realised`` is the acceleration it achieved.

**Two ahead, on a CACC base** (``--imitate two-ahead:c=C``, 0 < C ≤ 1). The base already feeds
forward its predecessor's command; the target adds the command of the vehicle two ahead, which
leads it by that predecessor's response:

    target a_adj,i = C·(a_base,i-2 - a_base,i-1)   (m/s², 0 for the first two followers)

read from the fifth column of o (each vehicle's base command), so the CACC's feed-forward becomes
(1 - C)·u_{i-1} + C·u_{i-2}. Only the CA messages carry a_base,i-2 to vehicle i (two hops):
CA-off and TD3 see o_i only. ``benchmarks/two_ahead.py`` measures the law itself with the two
hops' V2V delays, on training events and in the frequency test.

**Fit.** At ``--learning-starts`` the actor is fitted to the targets by mean squared error
(:meth:`carl_sumo.learn.agents.Agent.imitate`); its target network is set to it; the cloned actor is
validated and kept as the first candidate, and RL (with the critics' burn-in, if given) goes on
from it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import torch

from carl_sumo.control.cacc import PloegController, is_ploeg_name, mpf_feed_forward, \
    ploeg_controller
from carl_sumo.config import BOUNDS
from carl_sumo.control.controllers import idm_acceleration
from carl_sumo.errors import InputError

TARGET_FRACTION = 0.95
"""Targets are clipped to this fraction of the actor's bound: tanh reaches ±1 only at ±∞."""


@dataclass(frozen=True)
class TwoAhead:
    """The two-ahead teacher on a CACC base (the module docstring): weight C (-) of the command
    of the vehicle two ahead in the feed-forward."""

    weight: float


TWO_AHEAD = "two-ahead"


def parse_two_ahead(name: str) -> TwoAhead | None:
    """``two-ahead:c=C`` as a :class:`TwoAhead` (None for another name); InputError for a bad C."""
    kind, _, rest = name.partition(":")
    if kind != TWO_AHEAD:
        return None
    key, _, value = rest.partition("=")
    try:
        weight = float(value) if key == "c" else math.nan
    except ValueError:
        weight = math.nan
    if not 0.0 < weight <= 1.0:
        raise InputError(f"--imitate {name}: give two-ahead:c=C with a weight C in (0, 1], "
                         "e.g. two-ahead:c=0.3")
    return TwoAhead(weight)


def teacher(name: str) -> PloegController | TwoAhead:
    """The controller a run imitates (a Ploeg name, or ``two-ahead:c=C``); InputError for
    anything else."""
    two = parse_two_ahead(name)
    if two is not None:
        return two
    if not is_ploeg_name(name):
        raise InputError(f"--imitate {name!r}: name a Ploeg CACC to imitate, e.g. "
                         "ploeg:h=1.1:kp=2.278:kd=10.6313 or ploeg-tuned:h=1")
    return ploeg_controller(name)


def check_teacher_base(name: str, base: str) -> None:
    """InputError unless ``name`` can be imitated on ``base``: any Ploeg CACC on the IDM base, or
    on an ACC base the Ploeg CACC with the ACC's own gains, and ``two-ahead`` on a CACC base
    (the module docstring)."""
    from carl_sumo.control.cacc import parse_ploeg

    if parse_two_ahead(name) is not None:
        if not is_ploeg_name(base) or not parse_ploeg(base).feed_forward:
            raise InputError(f"--imitate {name} on --base {base}: two-ahead adds to a CACC's "
                             "feed-forward; give a CACC base, e.g. --base ploeg:h=0.6:kp=0.0445:kd=1")
        return
    if base == "idm":
        return

    law, acc = parse_ploeg(name), parse_ploeg(base) if is_ploeg_name(base) else None
    if acc is None or acc.feed_forward or not law.feed_forward or \
            (law.time_gap_s, law.kp, law.kd) != (acc.time_gap_s, acc.kp, acc.kd):
        raise InputError(f"--imitate {name} on --base {base}: imitate on the IDM base, or on an "
                         "ACC base (acc:h=H:kp=KP:kd=KD) the CACC with its gains "
                         "(ploeg:h=H:kp=KP:kd=KD), whose adjustment is the predecessor's message")


IMITATE_TARGETS = ("realised", "command")
"""What the target on an ACC base feeds forward: the predecessor's realised acceleration (o's
second column) or its command (the base's a_base, o's fifth column, which its actuator then
follows with its lag)."""


def predecessor_adjustment(obs: np.ndarray, adj_max: float, target: str = "realised"
                           ) -> np.ndarray:
    """The target a_adj (m/s², shape (..., n)) on an ACC base: the predecessor's realised
    acceleration a_{i-1} or, with ``target="command"``, its command a_base,i-1 (0 for the head),
    clipped to ``TARGET_FRACTION``·``adj_max``."""
    if target not in IMITATE_TARGETS:
        raise InputError(f"imitation target {target!r}: choose {' or '.join(IMITATE_TARGETS)}")
    obs = np.asarray(obs, dtype=np.float64)
    column = 4 if target == "command" else 1
    target_a = np.zeros(obs.shape[:-1])
    target_a[..., 1:] = obs[..., :-1, column]
    bound = TARGET_FRACTION * min(adj_max, BOUNDS.adj_max_mps2)
    return np.clip(target_a, -bound, bound)


def two_ahead_adjustment(obs: np.ndarray, weight: float, adj_max: float) -> np.ndarray:
    """The two-ahead target a_adj (m/s², shape (..., n)): weight·(a_base,i-2 - a_base,i-1) from
    o's fifth column, 0 for the first two followers, clipped to ``TARGET_FRACTION``·``adj_max``:
    the feed-forward of the multi-predecessor law ``mpf:r=2:w2=C`` less its base's
    (:func:`carl_sumo.control.cacc.mpf_feed_forward`), every command heard at once."""
    target = mpf_feed_forward((1.0 - weight, weight), np.asarray(obs, dtype=np.float64)[..., 4])
    bound = TARGET_FRACTION * min(adj_max, BOUNDS.adj_max_mps2)
    return np.clip(target, -bound, bound)


def teacher_acceleration(controller: PloegController, obs: np.ndarray,
                         with_ahead: bool = False) -> np.ndarray:
    """a_T (m/s², shape (..., n)) of the law read from observations [v, a, d, Δv, ...]
    (shape (..., n, 4+), head first): u_i := a_i, the predecessor's message a_{i-1}, none for
    the head (see the module docstring), or with ``with_ahead`` the leader's acceleration a_ahead
    of the fifth column."""
    obs = np.asarray(obs, dtype=np.float64)
    flat = obs.reshape(-1, *obs.shape[-2:])
    out = np.empty(flat.shape[:2])
    for k, platoon in enumerate(flat):
        platoon = np.ascontiguousarray(platoon[:, :4])
        u = platoon[:, 1].copy()
        # the state update of vehicle i uses u_{i-1} as it was *before* this step: the kernel
        # reads its predecessor's state before overwriting it, so u = a gives a_{i-1} here; the
        # head hears the leader's acceleration when the vehicle observes it (a_ahead), else 0
        a_lead = float(flat[k, 0, 4]) if with_ahead else 0.0
        out[k] = controller.step(platoon, u, a_lead)
    return out.reshape(obs.shape[:-1])


def teacher_adjustment(controller: PloegController, obs: np.ndarray, adj_max: float,
                       with_ahead: bool = False) -> np.ndarray:
    """The target a_adj (m/s², shape (..., n)) that makes IDM + a_adj apply the teacher's a_T,
    clipped to ``TARGET_FRACTION``·``adj_max``."""
    obs = np.asarray(obs, dtype=np.float64)
    a_idm = idm_acceleration(obs[..., 0], obs[..., 2], obs[..., 3])
    bound = TARGET_FRACTION * min(adj_max, BOUNDS.adj_max_mps2)
    return np.clip(teacher_acceleration(controller, obs, with_ahead) - a_idm, -bound, bound)


def target_adjustment(controller: PloegController | TwoAhead, obs: np.ndarray, adj_max: float,
                      with_ahead: bool = False, base: str = "idm", target: str = "realised"
                      ) -> np.ndarray:
    """The teacher's target a_adj (m/s², shape (..., n)) on ``base``: IDM, an ACC (``target``:
    see :data:`IMITATE_TARGETS`) or, for :class:`TwoAhead`, a CACC."""
    if isinstance(controller, TwoAhead):
        return two_ahead_adjustment(obs, controller.weight, adj_max)
    if base != "idm":
        return predecessor_adjustment(obs, adj_max, target)
    return teacher_adjustment(controller, obs, adj_max, with_ahead)


def dataset(controller: PloegController | TwoAhead, obs: torch.Tensor, adj_max: float,
            with_ahead: bool = False, base: str = "idm", target: str = "realised"
            ) -> tuple[torch.Tensor, torch.Tensor]:
    """(observations, target a_adj) of stored platoon observations (batch, n, 4 or 5)."""
    target = target_adjustment(controller, obs.numpy(), adj_max, with_ahead, base, target)
    return obs, torch.as_tensor(target, dtype=torch.float32)
