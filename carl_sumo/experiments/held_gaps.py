"""The gaps a held-gap policy chooses, for its string-stability test.

A policy on a base that learns each vehicle's time gap and holds it (``gp=T`` with ``gh=S``,
docs/models.md) decides once, at the first step of an event, from what its platoon looks like
then. The sine test starts every follower alike at the base's spacing behind a cruising leader, a
platoon unlike any event's, and under the headway budget (``gb=1``) a common choice is removed:
run as it is, the test measures the start law, not the gaps the policy keeps on events.

So the test of such a policy (:func:`carl_sumo.experiments.string_stability.string_stability`)
runs the policy itself with its first decision replaced by the gaps it chose on events: at each
position the smallest offset it chose at the first step of its own validation events (the
metadata's ``validation_events`` of its ``data``; the project's default leader set where those
cannot be read), every follower at that offset from the start, held for the whole run (the next
decision is S s on, after the longest sine run). Each position at its shortest chosen gap is the
hardest case for every link below the law's upper string-stable gap (the gain of a link falls
as its gap grows up to there; docs/string_stability.md, "h_min against the number of vehicles
heard"); the head, which hears no message, is an ACC, whose gain also falls with its gap.
"""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache
from pathlib import Path
from typing import Sequence

import numpy as np

from carl_sumo.control.channel import Impairments
from carl_sumo.data.events import Event
from carl_sumo.errors import InputError

DECISION_SAMPLES = 3
"""Samples of an event run to see a policy's first decision (it is made at the first step)."""


class HeldDecision:
    """A held-gap policy's controller whose first decision is ``offsets`` (s, head first),
    held for the run (:meth:`carl_sumo.control.cacc.PloegController.hold_decision`)."""

    def __init__(self, controller, offsets: Sequence[float]):
        self.controller, self.offsets = controller, np.asarray(offsets, dtype=np.float64)

    def __getattr__(self, name):
        return getattr(self.controller, name)

    def reset(self, n: int) -> None:
        self.controller.reset(n)
        self.controller.base.hold_decision(self.offsets)


def start_gaps_m(controller, offsets: Sequence[float], impairments: Impairments | None,
                 speed_mps: float) -> np.ndarray:
    """Each follower's equilibrium gap (m) at ``speed_mps`` under the held ``offsets`` (s):
    s0 + h_i·v with h_i its class's own gap plus its offset, at least its class's least gap (as
    the law keeps it), for a one-class plant (a string-stability run's); each starts there, so
    that the run measures the held gaps' response, not the way to them (a head 0.9 s behind its
    gap needs minutes at ``mpf-tuned``'s gains to settle)."""
    from carl_sumo.sim.vehicle import VEHICLE_CLASSES

    params, n = controller.base.params, len(offsets)
    plant = impairments.plant if impairments is not None else None
    b_max = np.inf if plant is None or len(plant.fleet) != 1 else \
        VEHICLE_CLASSES[plant.fleet[0][0]].b_max_mps2
    own, least = params.class_gaps(np.full(n, b_max))
    h = np.maximum(own + np.asarray(offsets, dtype=np.float64), least)
    return params.standstill_gap_m + h * speed_mps


def is_held_gap_policy(name: str) -> bool:
    """Whether ``name`` is a policy file whose base holds a learned gap (``gp`` with ``gh``)."""
    if not str(name).endswith(".pt"):
        return False
    from carl_sumo.control.cacc import parse_ploeg, is_ploeg_name
    from carl_sumo.learn.policy import read_policy_payload

    base = read_policy_payload(Path(name))["agent_config"].get("base") or ""
    if not is_ploeg_name(base):
        return False
    p = parse_ploeg(base)
    return p.gap_policy_s is not None and p.gap_hold_s is not None


def decision_events(policy: str) -> tuple[list[Event], str]:
    """The events whose first decisions a policy's test uses, and where they come from: its
    validation events (from the metadata) when its data can be read, else the default set's."""
    from carl_sumo.data import load_events
    from carl_sumo.learn.policy import read_policy_payload

    meta = read_policy_payload(Path(policy))["metadata"]
    ids, data = meta.get("validation_events") or [], meta.get("data")
    if ids and data:
        try:
            return load_events(data, "train", event_ids=list(ids)), \
                f"its {len(ids)} validation events of {data}"
        except (InputError, OSError):
            pass
    events = load_events("default", "test")
    return events, f"the {len(events)} events of the default leader set (its data: unread)"


def first_steps(event: Event) -> Event:
    """The first :data:`DECISION_SAMPLES` samples of ``event``, all scored: enough to see a
    held-gap policy's first decision."""
    k = min(DECISION_SAMPLES, event.n_samples)
    return replace(event, leader_pos_m=event.leader_pos_m[:k],
                   leader_speed_mps=event.leader_speed_mps[:k],
                   follower_speed_mps=event.follower_speed_mps[:k], gap_m=event.gap_m[:k],
                   scored_from=0)


def first_decisions(policy: str, events: Sequence[Event], n: int,
                    impairments: Impairments | None, net: str) -> tuple[np.ndarray, np.ndarray]:
    """The gap offsets (s, shape (events, n), head first, after the budget) a held-gap policy
    chooses at the first step of each event, n followers, on the plant of ``impairments``, and
    each follower's largest braking there (m/s², same shape; inf on the ideal plant), which sets
    its class's gaps (:meth:`carl_sumo.control.ploeg_names.PloegParams.class_gaps`)."""
    from carl_sumo.experiments.simulate import cached_sim, plant_of, resolve_controller, run_event

    follower_model, ctrl = resolve_controller(policy, plant_of(impairments))
    sim, offsets, braking = cached_sim(net, follower_model), [], []
    for e in events:
        run_event(sim, first_steps(e), n, ctrl, impairments=impairments)
        offsets.append(ctrl.base.gap_held.copy())
        braking.append(np.full(n, np.inf) if sim.powertrains is None else
                       np.array(sim.powertrains.b_max, dtype=np.float64))
    return np.array(offsets), np.array(braking)


def held_decision(policy: str, impairments: Impairments | None, net: str
                  ) -> dict | None:
    """For a held-gap policy (None for anything else): the decision its string-stability test
    holds, ``offsets_s`` (the smallest chosen at each position), with ``events``, ``source`` and
    the chosen offsets' ``mean_s``; n = the followers it was trained with. Kept per file version,
    plant and network for this process (a check runs it once per amplitude)."""
    if not is_held_gap_policy(policy):
        return None
    return dict(_held_decision(str(policy), Path(policy).stat().st_mtime_ns, impairments, net))


@lru_cache(maxsize=32)
def _held_decision(policy: str, _version: int, impairments: Impairments | None, net: str
                   ) -> tuple:
    from carl_sumo.learn.policy import read_policy_payload

    n = int(read_policy_payload(Path(policy))["agent_config"]["n_vehicles"])
    events, source = decision_events(policy)
    chosen, _ = first_decisions(policy, events, n, impairments, net)
    return (("offsets_s", chosen.min(axis=0).tolist()), ("mean_s", chosen.mean(axis=0).tolist()),
            ("events", len(events)), ("source", source))
