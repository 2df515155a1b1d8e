"""Running controllers on events and scoring them: what ``carl-sumo simulate`` and ``replay`` do.

Controllers by name:

- ``idm`` / ``krauss``: SUMO's native car-following models drive the followers;
- ``idm-external``: IDM computed in Python and applied through libsumo (a_adj = 0);
- ``sumo-cacc``: SUMO's native CACC model (Milanés & Shladover) drives the followers;
- ``ploeg``, ``ploeg:h=0.8:kp=0.1:kd=1.5``, ``ploeg-tuned:h=0.8``: the classical CACC of
  :mod:`carl_sumo.control.cacc`, applied through libsumo; ``acc``, ``acc:h=3``, ``acc-tuned:h=H``:
  the same law fed by radar only; ``mpf:r=2:w2=0.3`` (and Ploeg's gains and options): the law
  with the commands of the r vehicles ahead in its feed-forward, relayed over V2V;
- ``mpc``, ``mpc:h=0.6:N=30:wq=0.1:...``: the distributed MPC of :mod:`carl_sumo.control.mpc`
  (every follower solves a QP each step with its predecessor's plan received over V2V);
- ``human``: the recorded NGSIM follower of each event (one follower), scored the same way;
- a path to a policy file (``.pt``): a learned a_adj on top of IDM (:mod:`carl_sumo.learn.policy`);
- ``module:attribute`` or ``file.py:attribute``: a controller from outside carl-sumo
  (:mod:`carl_sumo.control.external`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Iterator, Sequence, TypeVar

import numpy as np

from carl_sumo.control.classical import classical_controller, is_classical_name
from carl_sumo.control.channel import Impairments
from carl_sumo.control.external import is_external_name, load_external
from carl_sumo.control.controllers import AccelerationController, Controller, ZeroAdjustment, \
    applied_acceleration
from carl_sumo.data.events import Event
from carl_sumo.errors import InputError
from carl_sumo.control.sensors import Sensors
from carl_sumo.files import atomic_path, check_xml
from carl_sumo.progress import track
from carl_sumo.sim.metrics import PlatoonTrajectory, aggregate, score_event
from carl_sumo.sim.sumo import (DEFAULT_NET, PlatoonSim, abandon_sumo, close_sumo,
                               gui_connection_lost, use_gui)
from carl_sumo.scale.workers import run_parallel

NATIVE_CONTROLLERS = {"idm": "idm", "krauss": "krauss", "sumo-cacc": "sumo-cacc"}
BUILTIN_CONTROLLERS = ("idm", "krauss", "sumo-cacc", "idm-external", "ploeg[:h=H:kp=KP:kd=KD]",
                       "ploeg-tuned:h=H", "acc[:h=H:kp=KP:kd=KD]", "acc-tuned:h=H",
                       "mpf[:r=R:wJ=W:h=H:kp=KP:kd=KD]", "mpf-tuned[:h=H]",
                       "mpc[:h=H:N=N:wq=WQ:wv=WV:wu=WU:wj=WJ]", "mpc-tuned[:h=H]", "human")


def resolve_controller(name: str, plant: str = "ideal"
                       ) -> tuple[str, Controller | AccelerationController | None]:
    """(follower model, controller) of a controller name or policy path; InputError if unknown.
    ``plant``: the plant a ``-tuned`` law's gains are read for (:attr:`Impairments.plant_key`)."""
    if name in NATIVE_CONTROLLERS:
        return NATIVE_CONTROLLERS[name], None
    if name == "idm-external":
        return "external", ZeroAdjustment()
    if is_classical_name(name):  # ploeg, acc, mpf, mpc (carl_sumo.control.classical)
        return "external", classical_controller(name, plant=plant)
    if name == "human":
        return "human", None
    if is_external_name(name):  # module:attribute or file.py:attribute
        return "external", load_external(name)
    if name.endswith(".pt") or Path(name).suffix == ".pt":
        try:
            from carl_sumo.learn.policy import load_controller
        except ImportError:
            raise InputError(f"controller {name}: learned policies are not available in this "
                             "version; use idm, krauss, idm-external or human") from None
        return "external", load_controller(Path(name))
    raise InputError(f"unknown controller {name!r}; choose one of "
                     f"{', '.join(BUILTIN_CONTROLLERS)} or the path of a policy file (.pt)")


def human_trajectory(event: Event) -> PlatoonTrajectory:
    """The recorded follower of an event as a one-vehicle platoon."""
    return PlatoonTrajectory(event.event_id, event.leader_speed_mps,
                             event.follower_speed_mps[:, None], event.gap_m[:, None],
                             collisions=int(np.any(event.gap_m <= 0)),
                             dt=event.dt).scored(event.scored_from)


def run_event(sim: PlatoonSim, event: Event, n_followers: int,
              controller: Controller | AccelerationController | None,
              fcd_path: Path | None = None,
              impairments: Impairments | None = None,
              start_gaps_m: np.ndarray | None = None) -> PlatoonTrajectory:
    """Run one event in SUMO to its end or to the first collision; the trajectory (from the
    event's ``scored_from`` on: a warm-up is run but not returned). With
    ``impairments`` (:mod:`carl_sumo.control.channel`) the controller's V2V messages cross impaired links
    and it sees noisy own measurements; the trajectory is the true one. ``start_gaps_m``: each
    follower's own start gap (m; :meth:`PlatoonSim.reset`)."""
    if controller is not None:
        controller.reset(n_followers)
    sensors = None
    if impairments is not None and controller is not None:
        if not impairments.perfect_channel and hasattr(controller, "connect"):
            controller.connect(impairments, event.event_id)
        sensors = Sensors.of(impairments, event.event_id)
    plant = impairments.plant if impairments is not None else None
    sim.reset(event, n_followers, fcd_path, plant=plant,
              plant_seed=impairments.seed if impairments is not None else 0,
              start_gaps_m=start_gaps_m)
    if controller is not None and sim.powertrains is not None and \
            hasattr(controller, "know_vehicles"):
        controller.know_vehicles(sim.powertrains.a_max, sim.powertrains.b_max)
    obs = sim.observation()
    leader, speeds, gaps = [sim.leader_speed], [obs[:, 0]], [obs[:, 2]]
    collisions = 0
    while not sim.done:
        if controller is not None:
            seen = obs if sensors is None else sensors.measure(obs)
            sim.step(applied_acceleration(controller, seen))
        else:
            sim.step()
        obs = sim.observation()
        leader.append(sim.leader_speed)
        speeds.append(obs[:, 0])
        gaps.append(obs[:, 2])
        if (obs[:, 2] <= 0.0).any():
            collisions = int((obs[:, 2] <= 0.0).sum())
            break
    return PlatoonTrajectory(event.event_id, np.array(leader), np.array(speeds), np.array(gaps),
                             collisions).scored(event.scored_from)


_SIMS: dict[tuple[type, str, str], PlatoonSim] = {}


def cached_sim(net_path: str | Path, follower_model: str,
               kind: type[PlatoonSim] = PlatoonSim) -> PlatoonSim:
    """This process's ``kind`` of simulation (a :class:`PlatoonSim` or a subclass) for a network
    and follower model (parsed once)."""
    key = (kind, str(net_path), follower_model)
    if key not in _SIMS:
        _SIMS[key] = kind(net_path, follower_model)
    return _SIMS[key]


def event_trajectories(controller_name: str, events: Sequence[Event], n_followers: int,
                       net_path: str | Path = DEFAULT_NET, progress: bool = False,
                       impairments: Impairments | None = None
                       ) -> Iterator[tuple[Event, PlatoonTrajectory]]:
    """(event, trajectory) of one controller on each event, in this process, in order."""
    check_impairable(controller_name, impairments)
    follower_model, controller = resolve_controller(controller_name, plant_of(impairments))
    iterator = track(events, len(events), controller_name, "event", progress)
    if follower_model == "human":
        for e in iterator:
            yield e, human_trajectory(e)
        return
    sim = cached_sim(net_path, follower_model)
    for e in iterator:
        yield e, run_event(sim, e, n_followers, controller, impairments=impairments)


def impairable(controller_name: str) -> bool:
    """Whether a controller runs in carl-sumo and so can have impairments (not SUMO's native
    models, whose V2V and sensing are inside SUMO, nor the recorded human follower)."""
    if is_classical_name(controller_name) or is_external_name(controller_name):
        return True
    return resolve_controller(controller_name)[0] == "external"


def check_impairable(controller_name: str, impairments: Impairments | None) -> None:
    """InputError for impairments on a controller that cannot have them: SUMO's native models
    (their V2V and sensing are inside SUMO) and the recorded human follower."""
    if impairments is None or not impairments.active:
        return
    if not impairable(controller_name):
        raise InputError(f"{controller_name}: impairments (--comm-*, --sensor-noise) and vehicle "
                         "dynamics (--plant, --fleet, --vehicle-lag, --actuation-delay) apply to "
                         "controllers that run in carl-sumo (idm-external, ploeg, acc, a policy "
                         "file), not to SUMO's native models or the recorded follower")


def plant_of(impairments: Impairments | None) -> str:
    """The plant key a ``-tuned`` law reads its gains for: ``ideal`` without impairments."""
    return impairments.plant_key if impairments is not None else "ideal"


def score_events(controller_name: str, events: Sequence[Event], n_followers: int,
                  net_path: str, progress: bool = False,
                  impairments: Impairments | None = None) -> list[dict]:
    """Per-event metrics of one controller, in this process."""
    return [score_event(traj) for _, traj in
            event_trajectories(controller_name, events, n_followers, net_path, progress,
                               impairments)]


def simulate(controller_name: str, events: Sequence[Event], n_followers: int,
             net_path: str | Path = DEFAULT_NET, progress: bool = False, workers: int = 1,
             impairments: Impairments | None = None) -> dict:
    """Metrics of one controller over events: ``{"metrics": {...}, "events": [...]}``.

    With ``workers`` > 1 the events are split over that many spawned processes (one libsumo each),
    at least 20 events per worker. ``impairments``: V2V delay and loss, sensor noise
    (:mod:`carl_sumo.control.channel`; the same draws on an event whichever worker runs it).
    """
    check_impairable(controller_name, impairments)
    follower_model, _ = resolve_controller(controller_name, plant_of(impairments))
    workers = max(1, min(workers, len(events) // 20))  # a spawned worker costs seconds to start
    if workers == 1 or follower_model == "human":
        per_event = score_events(controller_name, events, n_followers, str(net_path), progress,
                                  impairments)
    else:
        per_event = simulate_jobs([(controller_name, impairments)], events, n_followers,
                                  net_path, workers, chunks=workers)[0]["events"]
    return {"controller": controller_name, "followers": 1 if follower_model == "human"
            else n_followers, "metrics": aggregate(per_event), "events": per_event}


def simulate_jobs(jobs: Sequence[tuple[str, Impairments | None]], events: Sequence[Event],
                  n_followers: int, net_path: str | Path, workers: int, chunks: int,
                  progress: bool = False) -> list[dict]:
    """``{"metrics", "events"}`` of every (controller, impairments) job on ``events``, all in
    one pool of ``workers`` processes: each job's events split in ``chunks`` tasks, its
    per-event metrics back in the order of ``events``."""
    chunks = max(1, min(chunks, len(events)))
    parts = [list(events[i::chunks]) for i in range(chunks)]
    items = [(name, part, n_followers, str(net_path), False, imp)
             for name, imp in jobs for part in parts]
    results = run_parallel(score_events, items, workers,
                           describe=lambda a: f"{a[0]} on {len(a[1])} events from "
                                              f"{a[1][0].event_id} ({a[5]})")
    results = list(track(results, len(items), "runs", "task", progress))
    order = {e.event_id: i for i, e in enumerate(events)}
    out = []
    for j in range(len(jobs)):
        per_event = sorted((m for part in results[j * chunks:(j + 1) * chunks] for m in part),
                           key=lambda m: order[m["event_id"]])
        out.append({"metrics": aggregate(per_event), "events": per_event})
    return out


def replay(controller_name: str, event: Event, n_followers: int, fcd_path: Path,
           net_path: str | Path = DEFAULT_NET, gui: bool = False,
           impairments: Impairments | None = None) -> dict:
    """Run one event and write SUMO's FCD output (with acceleration and leader fields).

    With ``gui`` the same run is shown in sumo-gui (through TraCI; InputError without a display).
    """
    follower_model, controller = resolve_controller(controller_name, plant_of(impairments))
    if follower_model == "human":
        raise InputError("the recorded human follower is not simulated, so it has no FCD output; "
                         "choose idm, krauss, sumo-cacc, idm-external, ploeg or a policy file")
    check_impairable(controller_name, impairments)
    if controller is not None:
        controller.reset(n_followers)  # a MADDPG policy refuses another length before SUMO starts
    fcd_path = Path(fcd_path)
    sim = PlatoonSim(net_path, follower_model)
    use_gui(gui)
    traj = fcd_run(fcd_path, gui, lambda tmp: run_event(sim, event, n_followers, controller,
                                                        fcd_path=tmp, impairments=impairments))
    return score_event(traj)


T = TypeVar("T")


def fcd_run(fcd_path: Path, gui: bool, run: Callable[[Path], T]) -> T:
    """``run(tmp)``: a simulation of this process (sumo-gui with ``gui``) that writes SUMO's FCD
    output to ``tmp``, a temporary file that moves to ``fcd_path`` once SUMO has closed it and
    it parses whole (else OutputError: a full disk). An error, an interrupt or a closed sumo-gui
    window removes it and takes sumo-gui down (a closed window: one InputError line)."""
    with atomic_path(fcd_path, verify=lambda tmp: check_xml(tmp, f"SUMO's FCD output {fcd_path}")
                     ) as tmp:
        try:
            result = run(tmp)
            close_sumo()  # SUMO finishes the FCD file when the simulation closes (sumo-gui:
            # when its window is closed)
        except BaseException as exc:  # an error, an interrupt, a closed sumo-gui window
            lost = gui_connection_lost(exc)
            abandon_sumo()  # a sumo-gui goes down with the run
            if lost:
                raise InputError("sumo-gui was closed before the event ended; nothing was "
                                 f"written to {fcd_path}: run it again and let the event end "
                                 "(or run without --gui)") from None
            raise
        finally:
            if gui:
                use_gui(False)
    return result
