"""Controllers through a manoeuvre: what ``simulate --scenario`` and ``replay --scenario`` run.

One run = one event, one :class:`carl_sumo.manoeuvres.spec.Manoeuvre` drawn for it, in a
:class:`carl_sumo.manoeuvres.simulation.ScenarioSim`. Every 0.1 s each member of the platoon observes
o = [v, a, d, Δv] of the vehicle SUMO has ahead of it (``getLeader``), whoever it is. The V2V
chains are the runs of consecutive members in the platoon lane (:func:`chains_of`): a human who
cuts in splits the chain, and the member behind him heads a chain of its own with no message
from ahead (the degraded mode: Ploeg's CACC drops its feed-forward and acts as an ACC, at the
time gap ``ha`` of a name with one, the base of a policy trained on it included; the CA module
takes its boundary message); a cut-out or a merge links the chain again; a joiner joins
it. Controllers keep their state per vehicle ID (a joiner's starts at 0; with V2V delay or loss a
new neighbour is heard from its first message that arrives,
:class:`carl_sumo.control.channel.KeyedChannel`). On the real plant each controller is told every
vehicle's powertrain limits by ID from the step the vehicle is on the road (a joiner's, of its own
powertrain, when it enters): a law named with ``aw=1``, or a policy on such a base, keeps each
vehicle's state, the message it sends, within its own class's limits. Every controller name of
``simulate`` runs:

- ``idm``, ``krauss``, ``sumo-cacc``: SUMO's own models drive the members, as in a plain run;
- ``ploeg*``, ``acc*``: :class:`carl_sumo.control.cacc.PloegChains` (a ``-tuned`` name: the
  gains tuned for the plant); ``mpc``: :class:`carl_sumo.control.mpc.MPCChains`; ``idm-external`` and policy files:
  :class:`carl_sumo.experiments.chain_controllers.ChainController` (one shared-weight policy on every chain,
  whatever its length);
- a MADDPG policy: not applicable (``n/a: fixed size``: one actor per platoon position); the
  recorded human follower: not applicable (it cannot be made to manoeuvre);
- ``module:attribute`` / ``file.py:attribute``: the whole platoon as one, reset with the new
  length whenever the number of members changes.
"""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache
from pathlib import Path
from typing import Sequence

import numpy as np

from carl_sumo.config import DT_S, SCENARIO
from carl_sumo.control.classical import classical_chains, is_classical_name
from carl_sumo.control.channel import Impairments
from carl_sumo.control.controllers import applied_acceleration
from carl_sumo.control.external import is_external_name, load_external
from carl_sumo.control.sensors import Sensors
from carl_sumo.data.events import Event
from carl_sumo.errors import InputError
from carl_sumo.experiments.simulate import (NATIVE_CONTROLLERS, cached_sim, check_impairable,
                                            fcd_run, plant_of)
from carl_sumo.manoeuvres.metrics import ScenarioTrace, manoeuvre_metrics, whole_run_metrics
from carl_sumo.manoeuvres.spec import Manoeuvre, ScenarioSpec
from carl_sumo.manoeuvres.simulation import ScenarioSim, adjacent_route
from carl_sumo.sim.sumo import LaneRoute, check_fits, lane_route, use_gui
from carl_sumo.experiments.chain_controllers import ChainController, know_vehicle


class NotApplicable(InputError):
    """A controller that cannot run a platoon whose members change (its table cell says why)."""


class WholePlatoon:
    """A controller from outside carl-sumo on every member at once, head first, reset with the
    new platoon length whenever it changes."""

    def __init__(self, controller):
        self.controller, self.name, self._n = controller, controller.name, -1
        self.controller.counting = False  # reset when the platoon changes: steps counted here
        self._step = 0

    def reset(self) -> None:
        self._n, self._step = -1, 0

    def acceleration(self, obs: np.ndarray, chains, ids, ahead, last_acc) -> np.ndarray:
        self.controller.step, self._step = self._step, self._step + 1
        if obs.shape[0] != self._n:
            self.controller.reset(obs.shape[0])
            self._n = obs.shape[0]
        return applied_acceleration(self.controller, obs)


def scenario_controller(name: str, plant: str = "ideal"):
    """(follower model, controller or None) of a controller name in a scenario run;
    NotApplicable for a MADDPG policy or the recorded follower, InputError for a bad name."""
    if name in NATIVE_CONTROLLERS:
        return NATIVE_CONTROLLERS[name], None
    if name == "human":
        raise NotApplicable("n/a: recorded follower (the recorded NGSIM follower cannot be made "
                            "to manoeuvre; choose a controller that runs in SUMO)")
    if is_classical_name(name):  # ploeg, acc, mpf, mpc
        return "external", classical_chains(name, plant)
    if is_external_name(name):
        return "external", WholePlatoon(load_external(name))
    if name == "idm-external":
        return "external", ChainController(name)
    if name.endswith(".pt"):
        from carl_sumo.learn.policy import load_policy

        agent, _ = load_policy(Path(name))
        if agent.cfg.algo == "maddpg":
            raise NotApplicable(f"n/a: fixed size ({name} is MADDPG, one actor per position of "
                                f"a platoon of exactly {agent.cfg.n_vehicles}; the platoon's size "
                                "changes in a manoeuvre)")
        return "external", ChainController(name)
    from carl_sumo.experiments.simulate import resolve_controller

    resolve_controller(name)  # raises the usual one-line error for an unknown name
    raise InputError(f"controller {name!r} cannot run a scenario")


def chains_of(ids: Sequence[str], ahead: Sequence[tuple[str, float] | None]) -> list[list[int]]:
    """V2V chains of the members ``ids`` (front first) as row indices: member i continues the
    chain of member i-1 when SUMO has i-1 directly ahead of it; anything else ahead (a human, a
    radar-only link, nothing) starts a new chain."""
    chains: list[list[int]] = []
    for i in range(len(ids)):
        item = ahead[i]
        if i > 0 and item is not None and item[0] == ids[i - 1]:
            chains[-1].append(i)
        else:
            chains.append([i])
    return chains


def heard_accelerations(sim: ScenarioSim, ids: Sequence[str], leader_acc: float
                        ) -> dict[str, float]:
    """The acceleration over the last step (m/s²) a chain head may feed forward, by the ID of
    the vehicle ahead: the NGSIM leader's (as a plain run's first follower takes it) and the
    members'; a human sends nothing, so the member behind him finds none (degraded mode)."""
    return {"leader": leader_acc, **{v: sim.accels[v] for v in ids}}


class MeasuredLeader:
    """The NGSIM leader's acceleration over the last step (m/s²) as the member behind it
    measures it under ``--sensor-noise``: the change of its measured v + Δv (0 at its first step
    behind the leader), what a plain run's first follower feeds forward (its law's and
    :class:`carl_sumo.control.controllers.AheadAcceleration`'s a_lead). Call once per step."""

    def __init__(self) -> None:
        self._last: tuple[str, float] | None = None  # (member ID, measured leader speed m/s)

    def __call__(self, ids: Sequence[str], measured: np.ndarray,
                 ahead: Sequence[tuple[str, float] | None]) -> float:
        row = next((i for i, a in enumerate(ahead) if a is not None and a[0] == "leader"), None)
        if row is None:
            self._last = None
            return 0.0
        speed = float(measured[row, 0] + measured[row, 3])
        last, self._last = self._last, (ids[row], speed)
        return 0.0 if last is None or last[0] != ids[row] else (speed - last[1]) / DT_S


class _Recorder:
    """Speed, gap and predecessor speed of every vehicle in the platoon lane, every step."""

    def __init__(self, n_samples: int):
        self.n = n_samples
        self.columns: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = {}
        self.leader = np.full(n_samples, np.nan)

    def add(self, sim: ScenarioSim) -> None:
        k = sim.k
        self.leader[k] = sim.leader_speed
        for vid in sim.order:
            if vid not in self.columns:
                self.columns[vid] = tuple(np.full(self.n, np.nan) for _ in range(3))
            speed, gap, pred_speed = self.columns[vid]
            pred, d = sim.ahead[vid]
            speed[k], gap[k] = sim.speeds[vid], d
            pred_speed[k] = sim.speeds.get(pred, np.nan) if pred is not None else np.nan

    def trace(self, sim: ScenarioSim, event: Event, collisions: int) -> ScenarioTrace:
        last = sim.k + 1
        vids = list(self.columns)
        stack = [np.column_stack([self.columns[v][j][:last] for v in vids]) if vids
                 else np.zeros((last, 0)) for j in range(3)]
        members = list(sim.ids) + (["joiner"] if sim.manoeuvre.kind == "join" else [])
        return ScenarioTrace(event.event_id, sim.manoeuvre.describe(), self.leader[:last], vids,
                             members, *stack, done_step=sim.done_step, behind=list(sim.behind),
                             collisions=collisions, scored_from=event.scored_from,
                             start_step=sim.start_step)


def tell_limits(controller, sim: ScenarioSim, known: set[str]) -> None:
    """Tell ``controller`` (:func:`carl_sumo.experiments.chain_controllers.know_vehicle`) the powertrain
    limits of the vehicles of ``sim.limits`` not in ``known`` yet (the real plant's vehicles new
    on the road), and add them to ``known``."""
    if controller is None or len(known) == len(sim.limits):
        return
    for vid, (a_max, b_max) in sim.limits.items():
        if vid not in known:
            know_vehicle(controller, vid, a_max, b_max)
            known.add(vid)


def run_scenario_event(sim: ScenarioSim, event: Event, n_followers: int, manoeuvre: Manoeuvre,
                       controller, impairments: Impairments | None = None,
                       fcd_path: Path | None = None) -> ScenarioTrace:
    """Run one event with its manoeuvre to the end or to the first collision. With
    ``--sensor-noise`` the controller sees each member's measured gap (m) and relative speed
    (m/s) (:class:`carl_sumo.control.sensors.Sensors`, the plain run's stream of the event;
    tracks keyed by vehicle ID and the ID ahead) and the leader's acceleration as measured
    (:class:`MeasuredLeader`); the trace and collisions are the true ones."""
    sensors = None
    if controller is not None:
        controller.reset()
        if impairments is not None and not impairments.perfect_channel \
                and hasattr(controller, "connect"):
            controller.connect(impairments, event.event_id)
        sensors = Sensors.of(impairments, event.event_id)
    measured_leader = MeasuredLeader()
    sim.start(event, n_followers, manoeuvre, fcd_path,
              plant=impairments.plant if impairments is not None else None,
              plant_seed=impairments.seed if impairments is not None else 0)
    known: set[str] = set()
    tell_limits(controller, sim, known)
    record = _Recorder(event.n_samples)
    record.add(sim)
    collisions, leader_acc = 0, 0.0
    while not sim.done:
        leader_before = sim.leader_speed
        if controller is not None:
            ids, obs, ahead = sim.observe()
            last_acc = heard_accelerations(sim, ids, leader_acc)
            if hasattr(controller, "arm"):  # a new vehicle ahead, no room yet (scenario_sim)
                controller.arm(sim.armed)
            if sensors is not None and ids:  # a track restarts when the vehicle ahead changes
                obs = sensors.measure(obs, vehicles=ids,
                                      predecessors=[a[0] if a else None for a in ahead])
                last_acc["leader"] = measured_leader(ids, obs, ahead)
            accel = controller.acceleration(obs, chains_of(ids, ahead), ids, ahead, last_acc) \
                if ids else np.zeros(0)
            sim.advance(dict(zip(ids, np.asarray(accel, float).tolist())))
            tell_limits(controller, sim, known)
        else:
            sim.advance()
        leader_acc = (sim.leader_speed - leader_before) / DT_S
        record.add(sim)
        gaps = [sim.ahead[v][1] for v in sim.order]
        if min(gaps, default=1.0) <= 0.0:
            collisions = sum(g <= 0.0 for g in gaps)
            break
    return record.trace(sim, event, collisions)


def scenario_sim(net_path: str | Path, follower_model: str) -> ScenarioSim:
    """This process's :class:`ScenarioSim` for a network and follower model (parsed once)."""
    return cached_sim(net_path, follower_model, ScenarioSim)


def score_trace(trace: ScenarioTrace) -> dict:
    """One event's row: the whole run's metrics, the manoeuvre, when it was complete (s) and
    its metrics."""
    done = None if trace.done_step is None else round(trace.done_step * trace.dt, 6)
    return {**whole_run_metrics(trace), "manoeuvre": trace.manoeuvre, "done_time_s": done,
            "manoeuvre_metrics": manoeuvre_metrics(trace)}


def scenario_scores(name: str, events: Sequence[Event], n_followers: int, net_path: str,
                    spec: ScenarioSpec, impairments: Impairments | None = None) -> list[dict]:
    """Per-event rows (:func:`score_trace`) of one controller, in this process."""
    follower_model, controller = scenario_controller(name, plant_of(impairments))
    sim = scenario_sim(net_path, follower_model)
    return [score_trace(run_scenario_event(sim, e, n_followers, spec.draw(e, n_followers),
                                           controller, impairments)) for e in events]


@lru_cache(maxsize=4)
def _routes(net_path: str) -> LaneRoute:
    """The platoon's lane route of a network, after checking it has a lane beside it (parsed
    once per network)."""
    adjacent_route(net_path, SCENARIO.ngsim_lane)
    return lane_route(net_path, SCENARIO.ngsim_lane)


def check_scenario(name: str, spec: ScenarioSpec, events: Sequence[Event], n_followers: int,
                   net_path: str | Path, impairments: Impairments | None = None) -> None:
    """Everything that can be wrong before any simulation: InputError (NotApplicable for a
    controller that cannot run it) for a bad controller, spec, event or network."""
    check_impairable(name, impairments)
    spec.check(n_followers)
    route = _routes(str(net_path))
    for event in events:  # a merge's second platoon needs its extra gap of road behind
        m = spec.draw(event, n_followers)
        check_fits(route, event, n_followers, replace(
            SCENARIO, start_margin_m=SCENARIO.start_margin_m + m.extra_gap_m))
    scenario_controller(name, plant_of(impairments))


def replay_scenario(name: str, event: Event, n_followers: int, fcd_path: Path,
                    net_path: str | Path, spec: ScenarioSpec, gui: bool = False,
                    impairments: Impairments | None = None) -> dict:
    """One event with its manoeuvre, written as SUMO FCD output (lane changes included); its
    row (:func:`score_trace`). ``gui``: shown in sumo-gui."""
    check_scenario(name, spec, [event], n_followers, net_path, impairments)
    follower_model, controller = scenario_controller(name, plant_of(impairments))
    manoeuvre = spec.draw(event, n_followers)
    sim = ScenarioSim(net_path, follower_model)
    use_gui(gui)
    trace = fcd_run(Path(fcd_path), gui, lambda tmp: run_scenario_event(
        sim, event, n_followers, manoeuvre, controller, impairments, fcd_path=tmp))
    return score_trace(trace)
