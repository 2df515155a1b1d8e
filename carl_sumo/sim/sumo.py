"""The SUMO coupling: one libsumo simulation of an NGSIM-led platoon on one lane of a network.

libsumo runs one simulation per process. :class:`PlatoonSim` owns it: every ``reset`` reloads the
network (about 5 ms), inserts the leader and the followers at their initial state, and every
``step`` advances SUMO by 0.1 s.

- The leader replays a recorded trajectory exactly: after each SUMO step it is put at the recorded
  position (``moveTo``) with the recorded speed (``setPreviousSpeed``).
- ``follower_model="external"``: followers are of type ``cacc``, speedMode 0 and lane changes off;
  the acceleration a given to :meth:`PlatoonSim.step` is applied exactly by
  ``setSpeed(v + a·dt)``: v' = max(v + a·dt, 0), x' = x + v'·dt.
- ``follower_model="idm"`` / ``"krauss"`` / ``"sumo-cacc"``: followers are driven by SUMO's own
  car-following model (types ``human_idm`` / ``human_krauss`` / ``cacc_sumo``, SUMO's CACC),
  lane changes off, no external control.

Positions are route coordinates (m): distance of the front bumper from the start of the platoon's
lane route (:class:`LaneRoute`).
"""

from __future__ import annotations

import bisect
import contextlib
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numba import njit

from carl_sumo.config import DT_S, SCENARIO, ScenarioConfig
from carl_sumo.data.events import Event
from carl_sumo.errors import InputError
from carl_sumo.resources import DEFAULT_NET, VTYPES_FILE
from carl_sumo.sim.vehicle import Plant, Powertrains

FOLLOWER_TYPES = {"external": "cacc", "idm": "human_idm", "krauss": "human_krauss",
                  "sumo-cacc": "cacc_sumo"}
"""SUMO vehicle type of the followers for each follower model."""

FCD_ATTRIBUTES = ("id,type,x,y,angle,speed,acceleration,pos,lane,odometer,leaderID,leaderSpeed,"
                  "leaderGap")
"""Attributes of every vehicle in FCD output (``replay --fcd``): with ``angle``, ``x``, ``y``,
``speed`` and ``lane``, what SUMO's tools (``plot_trajectories.py``, ``sumolib.output``) read."""

_sumo_running = False  # whether this process has a libsumo simulation open
_gui = False  # whether simulations of this process run in sumo-gui through TraCI
_gui_view = None  # what sumo-gui shows (carl_sumo.sim.gui.GuiView) while _gui


def _libsumo():
    """The SUMO API of this process: libsumo, or TraCI (the same API) when the GUI is on."""
    if _gui:
        import traci

        return traci
    import libsumo  # imported lazily: worker processes and the CLI import this module cheaply

    return libsumo


def has_display() -> bool:
    """Whether a GUI window can open: on Linux/BSD a DISPLAY or WAYLAND_DISPLAY must be set."""
    import sys

    if sys.platform in ("win32", "darwin"):
        return True
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def use_gui(enabled) -> None:
    """Run the next simulations of this process in sumo-gui (through TraCI) instead of libsumo;
    ``enabled``: a bool or a :class:`carl_sumo.sim.gui.GuiView` (zoom, tracking, colours, delay,
    screenshot; True: the default view).

    Raises InputError when no display exists. Closes a simulation that is open.
    """
    global _gui, _gui_view
    from carl_sumo.sim.gui import GuiView

    if enabled and not has_display():
        raise InputError("--gui needs a display and none is set (DISPLAY is empty); run without "
                         "--gui and open the FCD file, or run on a desktop session")
    close_sumo()
    _gui = bool(enabled)
    _gui_view = (enabled if isinstance(enabled, GuiView) else GuiView()) if enabled else None


@dataclass(frozen=True)
class LaneRoute:
    """The chain of lanes a platoon drives on, and where each lane starts (route coordinate, m)."""

    net_path: Path
    edges: tuple[str, ...]
    lanes: tuple[str, ...]
    lane_starts: tuple[float, ...]
    length_m: float

    def locate(self, x: float) -> tuple[str, float]:
        """Lane ID and lane position (m) of route coordinate x (m)."""
        index = bisect.bisect_right(self.lane_starts, x) - 1
        return self.lanes[index], x - self.lane_starts[index]


def lane_route(net_path: str | Path, ngsim_lane: int = SCENARIO.ngsim_lane) -> LaneRoute:
    """Find the mainline of a network and the lane of NGSIM number ``ngsim_lane`` along it.

    The mainline starts at an edge without predecessors and always continues on the successor edge
    with the most lanes; the longest such chain wins. NGSIM lane k (1 = leftmost) is SUMO lane
    index ``numLanes - k`` on every edge, so an auxiliary lane added on the right keeps the match.
    """
    net_path = Path(net_path)
    if not net_path.is_file():
        raise InputError(f"network {net_path} does not exist; build it with "
                         "`carl-sumo net build` or give --net i80.net.xml")
    import sumolib

    try:
        net = sumolib.net.readNet(str(net_path))
    except Exception as exc:
        raise InputError(f"network {net_path} is not a valid SUMO network ({type(exc).__name__}); "
                         "rebuild it with `carl-sumo net build`") from exc
    edges = [e for e in net.getEdges() if e.getFunction() == ""]
    if not edges:
        raise InputError(f"network {net_path} has no edges; rebuild it with `carl-sumo net build`")
    best: list = []
    for start in (e for e in edges if not e.getIncoming()):
        chain, seen = [start], {start.getID()}
        while True:
            successors = [e for e in chain[-1].getOutgoing() if e.getID() not in seen]
            if not successors:
                break
            nxt = max(successors, key=lambda e: (e.getLaneNumber(), e.getLength()))
            chain.append(nxt)
            seen.add(nxt.getID())
        if sum(e.getLength() for e in chain) > sum(e.getLength() for e in best):
            best = chain
    if not best:
        raise InputError(f"network {net_path} has no road with a start (every edge has a "
                         "predecessor); give a freeway network such as i80.net.xml (the shipped one)")
    lanes, starts, x = [], [], 0.0
    for edge in best:
        index = edge.getLaneNumber() - ngsim_lane
        if index < 0:
            raise InputError(f"network {net_path}: edge {edge.getID()} has only "
                             f"{edge.getLaneNumber()} lanes, so NGSIM lane {ngsim_lane} does not "
                             "exist on it; choose a lane number the whole road has")
        lane = edge.getLane(index)
        if lanes and not any(c.getToLane().getID() == lane.getID()
                             for c in net.getLane(lanes[-1]).getOutgoing()):
            raise InputError(f"network {net_path}: lane {lanes[-1]} is not connected to "
                             f"{lane.getID()}, so a platoon cannot stay in NGSIM lane "
                             f"{ngsim_lane}; choose another lane or fix the connections")
        lanes.append(lane.getID())
        starts.append(x)
        x += lane.getLength()
    return LaneRoute(net_path, tuple(e.getID() for e in best), tuple(lanes), tuple(starts), x)


@njit(cache=True)
def _observe(speed, acc, pos, leader_front, leader_speed, lengths):
    """Observation rows [v, a, d, Δv] of a platoon, head first (see PlatoonSim.observation);
    ``lengths``: the followers' lengths (m)."""
    n = speed.shape[0]
    out = np.empty((n, 4))
    front, pred_speed = leader_front, leader_speed
    for i in range(n):
        out[i, 0] = speed[i]
        out[i, 1] = acc[i]
        out[i, 2] = front - pos[i]
        out[i, 3] = pred_speed - speed[i]
        front = pos[i] - lengths[i]
        pred_speed = speed[i]
    return out


def platoon_start_m(event: Event, n_followers: int, scenario: ScenarioConfig = SCENARIO,
                    extra_m: float = 0.0) -> float:
    """Route coordinate of the leader's front bumper at t = 0 so that the whole platoon fits (m);
    ``extra_m``: how much longer the followers are together than the scenario's vehicles."""
    return (scenario.start_margin_m + event.leader_length_m
            + n_followers * (max(event.initial_gap_m, 0.0) + scenario.vehicle_length_m)) + extra_m


def required_length_m(event: Event, n_followers: int, scenario: ScenarioConfig = SCENARIO,
                      extra_m: float = 0.0) -> float:
    """Length of lane route a platoon needs to run an event to its end (m)."""
    return (platoon_start_m(event, n_followers, scenario, extra_m) + event.leader_travel_m
            + scenario.end_margin_m)


def check_fits(route: LaneRoute, event: Event, n_followers: int,
               scenario: ScenarioConfig = SCENARIO, extra_m: float = 0.0) -> None:
    """Raise InputError when the network is too short for this event and platoon."""
    needed = required_length_m(event, n_followers, scenario, extra_m)
    if needed > route.length_m:
        raise InputError(f"network {route.net_path} is too short for event {event.event_id} with "
                         f"{n_followers} followers: it needs {needed:.0f} m of lane, the road has "
                         f"{route.length_m:.0f} m; use a longer network (i80.net.xml) or "
                         "fewer --vehicles")


def start_gaps(event: Event, n_followers: int, given: np.ndarray | None = None) -> np.ndarray:
    """Each follower's bumper gap at t = 0 (m): the event's recorded one, or ``given`` (shape
    (n,), negative ones as 0); InputError for another shape."""
    gap0 = max(event.initial_gap_m, 0.0)
    if given is None:
        return np.full(n_followers, gap0)
    gaps = np.maximum(np.asarray(given, dtype=np.float64), 0.0)
    if gaps.shape != (n_followers,):
        raise InputError(f"{gaps.size} start gaps for {n_followers} followers")
    return gaps


def sumo_args(net_path: Path, fcd_path: Path | None = None, seed: int = 0) -> list[str]:
    """Command-line options of every carl-sumo simulation."""
    args = ["-n", str(net_path), "-a", str(VTYPES_FILE), "--step-length", str(DT_S),
            "--seed", str(seed), "--no-step-log", "true", "--no-warnings", "true",
            "--insertion-checks", "none", "--collision.action", "none"]
    if fcd_path is not None:
        args += ["--fcd-output", str(fcd_path), "--fcd-output.acceleration", "true",
                 "--fcd-output.attributes", FCD_ATTRIBUTES,
                 "--fcd-output.max-leader-distance", "1000"]
    return args


@contextlib.contextmanager
def _child_stderr():
    """While the block runs, this process's stderr (file descriptor 2, which a started program
    inherits) is a temporary file; yields that file."""
    import sys
    import tempfile

    log = tempfile.TemporaryFile()
    sys.stderr.flush()
    saved = os.dup(2)
    os.dup2(log.fileno(), 2)
    try:
        yield log
    finally:
        os.dup2(saved, 2)
        os.close(saved)
        log.close()  # the started program keeps its own descriptor


def _read_log(log) -> str:
    """What a started program wrote to ``log`` so far, on one line."""
    log.seek(0)
    return " ".join(log.read().decode(errors="replace").split())[:300]


def start_sumo(args: list[str]) -> None:
    """Start this process's libsumo simulation, or reload it with new options."""
    global _sumo_running
    libsumo = _libsumo()
    gui_said = ""  # what sumo-gui itself wrote when it could not start
    try:
        if _sumo_running:
            libsumo.load(args)
        elif _gui:
            import contextlib
            import io

            import sumolib

            # a fixed port: if sumo-gui exits at once (no usable display) TraCI gives up at once
            # instead of restarting it; TraCI's "Retrying" lines are not shown, and sumo-gui's
            # own messages (e.g. "FXApp::openDisplay: unable to open display") go to a file that
            # the error below quotes, not to the terminal before carl-sumo's one line
            with contextlib.redirect_stdout(io.StringIO()), _child_stderr() as gui_log:
                try:
                    libsumo.start([sumolib.checkBinary("sumo-gui")] + _gui_view.start_args()
                                  + args, port=sumolib.miscutils.getFreeSocketPort(),
                                  numRetries=30)
                except Exception:
                    gui_said = _read_log(gui_log)
                    raise
            _sumo_running = True
        else:
            libsumo.start(["sumo"] + args)
            _sumo_running = True
    except Exception as exc:  # libsumo raises TraCIException / FatalTraCIError with SUMO's text
        close_sumo()
        what = (f"sumo-gui could not open on display {os.environ.get('DISPLAY', '')!r} (check "
                "that the display works, or run without --gui)" if _gui
                else "SUMO could not load the simulation")
        raise InputError(f"{what}: {' '.join(str(exc).split())}"
                         + (f" (sumo-gui: {gui_said})" if gui_said else "")) from exc


_OWNER: object | None = None
"""The PlatoonSim whose episode this process's libsumo simulation runs (the last one reset)."""


def close_sumo() -> None:
    """Close this process's libsumo simulation (writes and closes SUMO's output files)."""
    global _sumo_running, _OWNER
    _OWNER = None
    if _sumo_running:
        try:
            _libsumo().close()
        finally:
            _sumo_running = False


def gui_connection_lost(exc: BaseException) -> bool:
    """Whether ``exc`` says that sumo-gui went away (its window was closed) during a run."""
    return _gui and (isinstance(exc, OSError) or type(exc).__name__ == "FatalTraCIError")


def abandon_sumo() -> None:
    """Close this process's simulation after an interruption or a lost sumo-gui: a sumo-gui
    process is killed (not waited for until its window closes), a lost connection forgotten."""
    global _sumo_running, _OWNER
    _OWNER = None
    if not _gui:
        close_sumo()
        return
    _sumo_running = False
    import traci

    try:
        connection = traci.getConnection()
    except Exception:  # no connection open
        return
    process = getattr(connection, "_process", None)
    if process is not None and process.poll() is None:
        process.kill()
        process.wait()
    sock = getattr(connection, "_socket", None)
    if sock is not None:  # nothing more is sent to a killed sumo-gui
        sock.close()
        connection._socket = None
    try:
        connection.close(wait=False)
    except Exception:
        pass


def allow_speed(lanes, vtypes, speed_mps: float) -> None:
    """Let an event faster than the network run as recorded: the speed limit of each of
    ``lanes`` and the top speed of each of ``vtypes`` below ``speed_mps`` (the event's fastest
    leader speed or its followers' initial speed) are raised to it for this run (SUMO refuses to
    insert a vehicle faster than its lane allows, and the next reset reloads the network and the
    types as they are). An event within the limits runs exactly as before."""
    ls = _libsumo()
    need = speed_mps + SPEED_MARGIN_MPS
    for lane in lanes:
        if ls.lane.getMaxSpeed(lane) < speed_mps:
            ls.lane.setMaxSpeed(lane, need)
    for vtype in vtypes:
        if ls.vehicletype.getMaxSpeed(vtype) < speed_mps:
            ls.vehicletype.setMaxSpeed(vtype, need)


SPEED_MARGIN_MPS = 0.01
"""How far above an event's fastest speed a raised limit is set (m/s): the departure speeds
SUMO is given are rounded to 1e-6 m/s."""


class PlatoonSim:
    """A leader replaying an :class:`Event` and ``n`` followers on one SUMO lane (0.1 s steps).

    After :meth:`reset` and every :meth:`step`, the attributes hold the state at step ``k``:
    ``speed``, ``pos``, ``acc`` (followers, head first; m/s, m, m/s²) and ``leader_speed``,
    ``leader_pos``. ``acc`` is the acceleration of the step that led to the state.
    """

    def __init__(self, net_path: str | Path = DEFAULT_NET, follower_model: str = "external",
                 scenario: ScenarioConfig = SCENARIO):
        if follower_model not in FOLLOWER_TYPES:
            raise InputError(f"unknown follower model {follower_model!r}; choose one of "
                             f"{', '.join(FOLLOWER_TYPES)}")
        self.route = lane_route(net_path, scenario.ngsim_lane)
        self.follower_model = follower_model
        self.scenario = scenario
        self.event: Event | None = None
        self.n = 0
        self.k = 0
        self.powertrains: Powertrains | None = None
        self.lengths = np.zeros(0)

    # ----------------------------------------------------------------------------------------
    def _sumo_args(self, fcd_path: Path | None, seed: int) -> list[str]:
        """SUMO's options for a run of this simulation (:func:`sumo_args`)."""
        return sumo_args(self.route.net_path, fcd_path, seed)

    def reset(self, event: Event, n_followers: int, fcd_path: Path | None = None,
              seed: int = 0, plant: Plant | None = None, plant_seed: int = 0,
              start_gaps_m: np.ndarray | None = None) -> None:
        """Load SUMO afresh and place the leader and ``n_followers`` at the event's t = 0 state.

        Followers start at the recorded follower's initial speed, one behind the other with the
        recorded initial bumper gap, or each with its own ``start_gaps_m`` (m, shape (n,), head
        first: e.g. each at its own equilibrium). ``plant``: their vehicle dynamics (None: the
        ideal plant), drawn for this event with ``plant_seed``
        (:meth:`carl_sumo.sim.vehicle.Plant.draw`).
        """
        if n_followers < 1:
            raise InputError(f"a platoon needs at least 1 follower, got {n_followers}")
        if plant is not None and self.follower_model != "external":
            raise InputError("vehicle dynamics (--plant, --fleet, --vehicle-lag, "
                             "--actuation-delay) apply to the followers carl-sumo drives, not to "
                             "SUMO's own models or the recorded follower")
        self.powertrains = None if plant is None else plant.draw(n_followers, event.event_id,
                                                                 plant_seed)
        length = self.scenario.vehicle_length_m
        lengths = np.full(n_followers, length) if self.powertrains is None \
            else self.powertrains.length_m
        gaps = start_gaps(event, n_followers, start_gaps_m)
        longer = float(np.sum(lengths - length)) if self.powertrains is not None else 0.0
        extra = longer + float(np.sum(gaps - max(event.initial_gap_m, 0.0)))
        check_fits(self.route, event, n_followers, self.scenario, extra)
        ls = _libsumo()
        start_sumo(self._sumo_args(fcd_path, seed))
        global _OWNER
        _OWNER = self  # libsumo runs one simulation per process: this episode's, until a reset
        self.event, self.n, self.k = event, n_followers, 0
        for i in range(len(self.route.edges)):  # one route per edge a vehicle may start on
            ls.route.add(f"platoon{i}", list(self.route.edges[i:]))
        x_leader = platoon_start_m(event, n_followers, self.scenario, extra)
        if longer == 0.0 and start_gaps_m is None:
            offsets = np.arange(n_followers) * (length + gaps[0])
        else:
            offsets = np.concatenate([[0.0], np.cumsum(lengths[:-1] + gaps[1:])])
        starts = x_leader - event.leader_length_m - gaps[0] - offsets
        self.lengths = lengths
        self._leader_offset = x_leader
        self._starts = starts
        self.leader_id = "leader"
        self.ids = [f"f{i}" for i in range(n_followers)]
        v0 = event.initial_speed_mps
        ftypes = [FOLLOWER_TYPES[self.follower_model]] * n_followers \
            if self.powertrains is None else self.powertrains.vtypes
        allow_speed(self.route.lanes, ["ngsim_leader", *dict.fromkeys(ftypes)],
                    max(float(np.max(event.leader_speed_mps)), float(v0)))
        self._add("leader", "ngsim_leader", x_leader, float(event.leader_speed_mps[0]))
        for vid, x, ftype in zip(self.ids, starts, ftypes):
            self._add(vid, ftype, float(x), v0)
        ls.simulationStep()  # inserts every vehicle at its depart state, without moving it
        ls.vehicle.setLength(self.leader_id, event.leader_length_m)
        ls.vehicle.setSpeedMode(self.leader_id, 0)
        ls.vehicle.setLaneChangeMode(self.leader_id, 0)
        for vid in self.ids:
            ls.vehicle.setLaneChangeMode(vid, 0)
            if self.follower_model == "external":
                ls.vehicle.setSpeedMode(vid, 0)
        x = x_leader + event.leader_pos_m
        index = np.searchsorted(np.asarray(self.route.lane_starts), x, side="right") - 1
        self._leader_lane = [self.route.lanes[i] for i in index.tolist()]
        self._leader_lane_pos = (x - np.asarray(self.route.lane_starts)[index]).tolist()
        self._leader_speed = event.leader_speed_mps.tolist()
        self._leader_front = (x - event.leader_length_m).tolist()
        ls.vehicle.moveTo(self.leader_id, self._leader_lane[0], self._leader_lane_pos[0])
        ls.vehicle.setPreviousSpeed(self.leader_id, self._leader_speed[0])
        self.speed = np.full(n_followers, v0)
        self.pos = starts.copy()
        self.acc = np.zeros(n_followers)
        self._bind_calls()
        if _gui:  # zoom to the platoon, track a vehicle, colour them by role
            from carl_sumo.sim.gui import apply_calls

            ends = [ls.vehicle.getPosition(v) for v in (self.leader_id, self.ids[-1])]
            apply_calls(ls, _gui_view.setup_calls(self.leader_id, self.ids, self.follower_model,
                                                  *ends) + _gui_view.step_calls(0.0))

    def _add(self, vid: str, vtype: str, x: float, speed: float) -> None:
        lane, lane_pos = self.route.locate(x)
        index = self.route.lanes.index(lane)
        _libsumo().vehicle.add(vid, f"platoon{index}", vtype, depart="now",
                               departLane=lane.rsplit("_", 1)[1], departPos=f"{lane_pos:.6f}",
                               departSpeed=f"{speed:.6f}")

    def _bind_calls(self) -> None:
        ls = _libsumo()
        self._get_speed = ls.vehicle.getSpeed
        self._get_distance = ls.vehicle.getDistance
        self._set_speed = ls.vehicle.setSpeed
        self._move_to = ls.vehicle.moveTo
        self._set_previous_speed = ls.vehicle.setPreviousSpeed
        self._sim_step = ls.simulationStep

    # ----------------------------------------------------------------------------------------
    @property
    def n_steps(self) -> int:
        """Number of steps in the episode (samples of the event minus one)."""
        return self.event.n_samples - 1

    @property
    def done(self) -> bool:
        return self.k >= self.n_steps

    @property
    def leader_speed(self) -> float:
        return self._leader_speed[self.k]

    @property
    def leader_pos(self) -> float:
        return self._leader_offset + float(self.event.leader_pos_m[self.k])

    def observation(self) -> np.ndarray:
        """o_i = [v_i (m/s), a_i (m/s²), d_i (m), Δv_i = v_{i-1} - v_i (m/s)], shape (n, 4).

        d_i is the bumper-to-bumper gap to the predecessor (the leader for i = 0).
        """
        return _observe(self.speed, self.acc, self.pos, self._leader_front[self.k],
                        self._leader_speed[self.k], self.lengths)

    def step(self, accel: np.ndarray | None = None) -> None:
        """Advance SUMO by one step; ``accel`` (m/s², shape (n,)) drives external followers.
        InputError when another PlatoonSim of this process has reset SUMO since this one's
        episode started (libsumo holds one simulation per process)."""
        if _OWNER is not self:
            raise InputError("this platoon's SUMO simulation was replaced by another environment "
                             "in the same process (libsumo runs one simulation per process); run "
                             "each environment in its own process (e.g. a subprocess vector env)")
        k1 = self.k + 1
        set_speed, ids = self._set_speed, self.ids
        if self.follower_model == "external":
            if accel is None:
                raise ValueError("external followers need an acceleration every step")
            if self.powertrains is not None:  # the command through lag and dead time
                accel = self.powertrains.step(accel)
            for vid, v, a in zip(ids, self.speed.tolist(), accel.tolist()):
                v += a * DT_S
                set_speed(vid, v if v > 0.0 else 0.0)
        lead_speed = self._leader_speed[k1]
        set_speed(self.leader_id, lead_speed)
        self._sim_step()
        self._move_to(self.leader_id, self._leader_lane[k1], self._leader_lane_pos[k1])
        self._set_previous_speed(self.leader_id, lead_speed)
        get_speed, get_distance = self._get_speed, self._get_distance
        speed = np.array([get_speed(vid) for vid in ids])
        self.pos = self._starts + np.array([get_distance(vid) for vid in ids])
        self.acc = (speed - self.speed) * (1.0 / DT_S)
        self.speed = speed
        self.k = k1
        if _gui:  # a screenshot due at this time
            from carl_sumo.sim.gui import apply_calls

            apply_calls(_libsumo(), _gui_view.step_calls(k1 * DT_S))

    def leader_sumo_position(self) -> float:
        """The leader's route coordinate as SUMO has it now (m); for checking the replay."""
        ls = _libsumo()
        lane = ls.vehicle.getLaneID(self.leader_id)
        return self.route.lane_starts[self.route.lanes.index(lane)] + ls.vehicle.getLanePosition(
            self.leader_id)

    def leader_sumo_speed(self) -> float:
        return _libsumo().vehicle.getSpeed(self.leader_id)

