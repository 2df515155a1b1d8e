"""A platoon whose members change during a run: the SUMO side of a manoeuvre
(:mod:`carl_sumo.manoeuvres.spec`).

:class:`ScenarioSim` is a :class:`carl_sumo.sim.sumo.PlatoonSim` whose followers are no longer a
fixed column: every vehicle carl-sumo tracks (the followers, a human who cuts in, a joiner) has
its predecessor and bumper gap from SUMO's ``vehicle.getLeader`` (plus the follower's minGap),
in whichever lane SUMO has it, so a follower sees a vehicle that cut in ahead of it. Vehicles
enter and leave the platoon lane by SUMO's own ``vehicle.changeLane`` (laneChangeMode 0: the
request is carried out as asked), so FCD output and sumo-gui show the lane changes.

The **members** are the CACC followers in the platoon lane, front first: carl-sumo drives them
(``follower_model="external"``) or SUMO does (a native model). A member leaves when its cut-out
lane change is done (SUMO then drives it in the adjacent lane) and a joiner becomes one when its
lane change into the platoon lane is done. It hears the chain's messages from then on, and it is
``joining`` (its reaction layer armed, if its law has one: carl_sumo.control.cacc) until it is
no longer closing in on the vehicle ahead and its spacing (d - 2 m)/v has reached
:data:`JOIN_LINK_GAP_S`: it entered at a share of a gap kept for one vehicle. The member behind a
vehicle that enters is armed the same way until it has that room: behind a human who cuts in from
the first step it has him ahead (his landing, or his first signal), behind a joiner from the step
the joiner is in the lane. A joiner that announces itself (``join:signal=S``) keeps pace beside
its gap and brakes only as its chain does, so until it is in the lane the member meets it on radar
with its law and reaction layer alone, without a human's guards (carl_sumo.control.cacc's ``gn=B``
and ``op=B``; docs/scenarios.md). A human who cuts in is never a member: it is driven by SUMO's
Krauss model (``human_krauss``) from the step it is in the platoon lane, and it sends no V2V.
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np

from carl_sumo.config import DT_S, SCENARIO, ScenarioConfig
from carl_sumo.data.events import Event
from carl_sumo.errors import InputError
from carl_sumo.manoeuvres.spec import MIN_ROOM_M, Manoeuvre
from carl_sumo.sim.sumo import DEFAULT_NET, FOLLOWER_TYPES, LaneRoute, PlatoonSim, _libsumo, \
    allow_speed, lane_route
from carl_sumo.sim.vehicle import Plant

SENSOR_RANGE_M = 300.0
"""How far a follower sees the vehicle ahead (m): beyond it d = this and Δv = 0."""
HUMAN_TYPE = "human_krauss"
"""SUMO vType of the human who cuts in: SUMO's Krauss (its passenger defaults, no driver
imperfection), which brakes at most at its 4.5 m/s² to open the gap it cut into; SUMO's IDM with
the paper's T = 1.5 s brakes at its emergency 9 m/s² behind a 12 m gap at 17 m/s."""
LANE_CHANGE_S = 5.0
"""How long a ``changeLane`` request holds (s), beyond a gradual lane change's duration."""
ENTERING_ID = {"cut-in": "human", "join": "joiner"}
SIGNAL_TOWARD_PLATOON = 2
"""SUMO's VEH_SIGNAL_BLINKER_LEFT: the platoon lane is left of the adjacent lane."""
JOIN_LINK_GAP_S = 0.8
"""A joiner is joining until its spacing (d - 2 m)/v reaches this (s; the product's time gap)
and it is not closing in (the module docstring)."""
JOIN_STANDSTILL_M = 2.0
"""The standstill gap of that spacing (m; Ploeg's s0, carl_sumo.control.cacc)."""


def adjacent_route(net_path: str | Path, ngsim_lane: int) -> LaneRoute:
    """The lane beside the platoon's (NGSIM lane ``ngsim_lane`` + 1, its right neighbour) along
    the whole road; InputError when the network has none."""
    try:
        return lane_route(net_path, ngsim_lane + 1)
    except InputError as exc:
        raise InputError(f"--scenario does not fit network {net_path}: the platoon's lane (NGSIM "
                         f"lane {ngsim_lane}) needs a lane beside it on its right along the whole "
                         f"road for vehicles to enter and leave ({exc})") from None


class ScenarioSim(PlatoonSim):
    """A leader, ``n`` followers and one :class:`Manoeuvre` (see the module docstring).

    After :meth:`start` and every :meth:`advance`: ``members`` (CACC followers in the platoon
    lane, front first), ``order`` (every tracked vehicle in the platoon lane, front first),
    ``ahead[vid]`` = (predecessor ID or None, bumper gap m), ``speeds`` / ``accels`` (m/s, m/s²),
    ``done_step`` (the step the manoeuvre was complete, None before), ``start_step`` (with
    ``signal=S``: the entering vehicle's first signal step, when the member behind first sees
    it; None without), ``joining`` (a joiner
    that has no room yet, module docstring), ``new_ahead`` (a member a human or a joiner just
    entered ahead of, until it has room: :attr:`armed`), ``behind`` (the vehicles
    behind the manoeuvre, from then on) and, on the real plant, ``limits[vid]`` = (a_max, b_max)
    (m/s², positive) of every CACC vehicle carl-sumo drives that exists so far: the followers from
    the start, a joiner from the step it is on the road, each with its own powertrain's class
    limits (empty on the ideal plant).
    """

    def __init__(self, net_path: str | Path = DEFAULT_NET, follower_model: str = "external",
                 scenario: ScenarioConfig = SCENARIO):
        super().__init__(net_path, follower_model, scenario)
        self.adjacent = adjacent_route(net_path, scenario.ngsim_lane)
        self.base_scenario = scenario
        self._shifted: set[str] = set()
        self._extra_m = 0.0

    # ----------------------------------------------------------------------------------------
    def start(self, event: Event, n_followers: int, manoeuvre: Manoeuvre,
              fcd_path: Path | None = None, seed: int = 0, plant: Plant | None = None,
              plant_seed: int = 0) -> None:
        """Load SUMO and place the platoon as :meth:`PlatoonSim.reset` does (a merge's second
        platoon ``extra_gap_m`` further back); the manoeuvre starts at its step."""
        extra = manoeuvre.extra_gap_m
        self.manoeuvre = manoeuvre
        self.scenario = replace(self.base_scenario,
                                start_margin_m=self.base_scenario.start_margin_m + extra)
        self._shifted = {f"f{i}" for i in range(manoeuvre.position, n_followers)} \
            if manoeuvre.kind == "merge" else set()  # the second platoon, inserted further back
        self._extra_m = extra
        try:
            self.reset(event, n_followers, fcd_path, seed, plant, plant_seed)
        finally:
            self.scenario = self.base_scenario
            self._shifted = set()
        ls = _libsumo()
        self.members = list(self.ids)
        self.tracked = list(self.ids)
        self.speeds = dict(zip(self.ids, self.speed.tolist()))
        self.speeds["leader"] = self.leader_speed
        self.accels = {vid: 0.0 for vid in self.ids}
        self.entering: str | None = ENTERING_ID.get(manoeuvre.kind)
        self.phase = "waiting"
        self.done_step: int | None = None
        self.start_step: int | None = None  # signal=S: the human's first signal step
        self.left_step: int | None = None  # cut-in with leave: the step the human was out
        self.behind: list[str] = []
        self.radar_only: set[str] = set()
        self.joining: set[str] = set()
        self.new_ahead: set[str] = set()  # members behind a vehicle that just entered, until room
        self._met_entering: set[str] = set()  # members that have had it ahead (armed once)
        self._gone: set[str] = set()  # vehicles that left the lane, tracked while in it
        self.offset: dict[str, float] = {}
        self._enter_speed = 0.0
        self._joiner_plant = None if plant is None else plant.draw(1, event.event_id + "/joiner",
                                                                   plant_seed)
        self.limits: dict[str, tuple[float, float]] = {} if self.powertrains is None else {
            vid: (float(a), float(b)) for vid, a, b in
            zip(self.ids, self.powertrains.a_max, self.powertrains.b_max)}
        self.crossing: list[str] = []  # tracked vehicles seen in the lane from beside it
        self._body_crossing: list[str] = []  # those whose body crosses the line (_crossing)
        if manoeuvre.kind == "merge":
            head = self.ids[manoeuvre.position]
            self.radar_only.add(head)
            self.offset[head] = extra
            if self.follower_model != "external":  # SUMO's models keep the offset as minGap
                ls.vehicle.setMinGap(head, ls.vehicle.getMinGap(head) + extra)
        self._sense(ls)

    def _sumo_args(self, fcd_path: Path | None, seed: int) -> list[str]:
        """A plain run's options, and gradual lane changes when the manoeuvre has ``lc=S``."""
        args = super()._sumo_args(fcd_path, seed)
        if self.manoeuvre.lane_change_s > 0:
            args += ["--lanechange.duration", f"{self.manoeuvre.lane_change_s:g}"]
        return args

    @property
    def _hold_s(self) -> float:
        """How long this run's ``changeLane`` requests hold (s)."""
        return LANE_CHANGE_S + self.manoeuvre.lane_change_s

    def _add(self, vid: str, vtype: str, x: float, speed: float) -> None:
        """Insert as PlatoonSim does; a merge's second platoon ``extra_gap_m`` further back."""
        super()._add(vid, vtype, x - self._extra_m if vid in self._shifted else x, speed)

    # ----------------------------------------------------------------------------------------
    def _route_x(self, ls, vid: str) -> float:
        """Route coordinate of a vehicle's front bumper, in the platoon lane or beside it (m)."""
        lane = ls.vehicle.getLaneID(vid)
        route = self.route if lane in self.route.lanes else self.adjacent
        return route.lane_starts[route.lanes.index(lane)] + ls.vehicle.getLanePosition(vid)

    def _crossing(self, ls) -> list[str]:
        """Tracked vehicles in the adjacent lane whose body reaches over the line into the
        platoon lane: halfway through a gradual lane change in or out (``lc=S``), SUMO has them
        in the adjacent lane, but a radar behind them in the platoon lane sees them."""
        if self.manoeuvre.lane_change_s <= 0:
            return []
        out = []
        for vid in self.tracked:
            lane = ls.vehicle.getLaneID(vid)
            if lane in self.adjacent.lanes and ls.vehicle.getLateralLanePosition(vid) > \
                    0.5 * (ls.lane.getWidth(lane) - ls.vehicle.getWidth(vid)):
                out.append(vid)  # the platoon lane is the adjacent lane's left neighbour
        return out

    def _announced(self) -> list[str]:
        """The entering vehicle that signals (``signal=S``: a human's indicator before a cut-in,
        a joiner's request over V2V before a join), from its first signal until it is in the
        lane: the member behind the gap takes it as its predecessor."""
        if self.manoeuvre.signal_s > 0 and self.phase in ("signalling", "changing") \
                and self.entering in self.tracked and self.entering not in self._body_crossing:
            return [self.entering]
        return []

    def _sense(self, ls) -> None:
        """The platoon-lane order and every tracked vehicle's predecessor and gap, from SUMO;
        a vehicle crossing into or out of the lane (:attr:`crossing`) counts in it."""
        lanes = set(self.route.lanes)
        crossing = self.crossing
        in_lane = [v for v in self.tracked if ls.vehicle.getLaneID(v) in lanes] + crossing
        x = {v: self._route_x(ls, v) for v in in_lane}
        self.order = sorted(in_lane, key=lambda v: -x[v])
        self.ahead: dict[str, tuple[str | None, float]] = {}
        for vid in self.order:
            item = None if vid in crossing else ls.vehicle.getLeader(vid, SENSOR_RANGE_M)
            if item is None or item[0] == "":
                self.ahead[vid] = (None, SENSOR_RANGE_M)
            else:
                self.ahead[vid] = (item[0], item[1] + ls.vehicle.getMinGap(vid))
        if crossing:  # SUMO's getLeader does not see them: bumper gaps along the route
            self._see_crossing(ls, x)
        member_set = set(self.members)
        self.members = [v for v in self.order if v in member_set]
        self._settle()

    def _see_crossing(self, ls, x: dict[str, float]) -> None:
        """Each vehicle's predecessor when a crossing vehicle is closer than SUMO's leader, and a
        crossing vehicle's own (``x``: route coordinates of the vehicles in the lane, m)."""
        x = {**x, self.leader_id: self._route_x(ls, self.leader_id)}
        rear = {v: x[v] - ls.vehicle.getLength(v) for v in x}
        for vid in self.order:
            for other in x:
                gap = rear[other] - x[vid]  # bumper gap (m)
                if x[other] > x[vid] and gap < self.ahead[vid][1] \
                        and (vid in self.crossing or other in self.crossing):
                    self.ahead[vid] = (other, gap)

    @property
    def armed(self) -> set[str]:
        """The members whose vehicle ahead is new and who have no room yet: the joiner that is
        joining and the member a human cut in or a joiner joined ahead of (the law's ``armed``,
        :mod:`carl_sumo.control.cacc`)."""
        return self.joining | self.new_ahead

    def _settle(self) -> None:
        """A member gets a vehicle that enters ahead of it (a human who cuts in, from the step he
        is ahead: his landing or his first signal; a joiner, from the step it is in the lane and
        in the chain): it is new to that vehicle until it has room. The joiner stops joining, and
        such a member being new, once it has room (:data:`JOIN_LINK_GAP_S`) or, for the member,
        once the entering vehicle is no longer ahead of it."""
        entering = self.entering  # None for a cut-out or a merge
        joiner_outside_chain = entering == "joiner" and entering not in self.members
        for vid in self.members:
            if entering is not None and vid != entering and self.ahead[vid][0] == entering \
                    and vid not in self._met_entering and not joiner_outside_chain:
                self._met_entering.add(vid)
                self.new_ahead.add(vid)
        for vid in list(self.armed):
            if vid not in self.ahead:
                continue
            pred, gap = self.ahead[vid]
            v = self.speeds.get(vid, 0.0)
            closing = pred is not None and v > self.speeds.get(pred, v)
            if (not closing and gap - JOIN_STANDSTILL_M >= JOIN_LINK_GAP_S * v) or \
                    (vid in self.new_ahead and pred != entering):
                self.joining.discard(vid)
                self.new_ahead.discard(vid)

    def observe(self) -> tuple[list[str], np.ndarray, list[tuple[str, float] | None]]:
        """(member IDs front first, observations [v, a, d, Δv] (m, 4), what each sees ahead as
        (ID, gap); a radar-only link, the second platoon of a merge before it links, is named
        ``radar:ID`` so that no V2V input is found for it)."""
        ids = list(self.members)
        obs = np.empty((len(ids), 4))
        seen: list[tuple[str, float] | None] = []
        for row, vid in enumerate(ids):
            pred, gap = self.ahead[vid]
            v = self.speeds[vid]
            gap -= self.offset.get(vid, 0.0)
            obs[row] = (v, self.accels[vid], gap,
                        (self.speeds.get(pred, v) - v) if pred is not None else 0.0)
            if pred is None:
                seen.append(None)
            else:
                seen.append((f"radar:{pred}" if vid in self.radar_only else pred, gap))
        return ids, obs, seen

    # ----------------------------------------------------------------------------------------
    def advance(self, accel: dict[str, float] | None = None) -> None:
        """One 0.1 s step: the manoeuvre's actions, then ``accel`` (m/s² by member ID) applied as
        :meth:`PlatoonSim.step` applies it (through the powertrains on the real plant)."""
        ls = _libsumo()
        self._act(ls)
        set_speed = ls.vehicle.setSpeed
        if self.follower_model == "external":
            if accel is None:
                raise ValueError("external followers need an acceleration every step")
            for vid, a in self._realised(accel).items():
                v = self.speeds[vid] + a * DT_S
                set_speed(vid, v if v > 0.0 else 0.0)
        if self.entering in self.tracked and self.phase in ("inserted", "signalling",
                                                             "changing"):
            set_speed(self.entering, self._pace())  # keeps pace beside the gap
        k1 = self.k + 1
        set_speed(self.leader_id, self._leader_speed[k1])
        ls.simulationStep()
        ls.vehicle.moveTo(self.leader_id, self._leader_lane[k1], self._leader_lane_pos[k1])
        ls.vehicle.setPreviousSpeed(self.leader_id, self._leader_speed[k1])
        if self.phase == "inserted" and self.entering not in self.tracked:
            self.tracked.append(self.entering)
            self.speeds[self.entering] = self._enter_speed
            if self._joiner_plant is not None and self.entering == "joiner":
                self.limits["joiner"] = (float(self._joiner_plant.a_max[0]),
                                         float(self._joiner_plant.b_max[0]))
        for vid in self.tracked:
            v = ls.vehicle.getSpeed(vid)
            self.accels[vid] = (v - self.speeds[vid]) / DT_S
            self.speeds[vid] = v
        self.speeds["leader"] = self._leader_speed[k1]
        self.k = k1
        self._body_crossing = self._crossing(ls)
        self.crossing = self._body_crossing + self._announced()
        self._complete(ls)
        self._untrack_gone()
        self._sense(ls)

    def _pace(self) -> float:
        """The entering vehicle's speed beside its gap (m/s): the speed it entered with for a
        one-step lane change; over a signal or a gradual change (``signal=S``, ``lc=S``) that of
        the vehicle ahead of its gap, as a driver moving in behind it keeps pace with it (a
        constant speed would run into a vehicle ahead that brakes)."""
        m = self.manoeuvre
        if m.signal_s <= 0 and m.lane_change_s <= 0:
            return self._enter_speed
        ahead = "leader" if m.position == 0 else self.ids[m.position - 1]
        return self.speeds.get(ahead, self._enter_speed)

    def _realised(self, accel: dict[str, float]) -> dict[str, float]:
        """The accelerations the members realise this step (m/s²): the commands themselves on
        the ideal plant, through each vehicle's lag and dead time on the real one."""
        if self.powertrains is None:
            return accel
        command = np.array([accel.get(vid, 0.0) for vid in self.ids])
        realised = self.powertrains.step(command)
        out = {vid: float(a) for vid, a in zip(self.ids, realised) if vid in accel}
        if self._joiner_plant is not None and self.entering == "joiner":
            a = self._joiner_plant.step(np.array([accel.get("joiner", 0.0)]))[0]
            if "joiner" in accel:
                out["joiner"] = float(a)
        return out

    # ----------------------------------------------------------------------------------------
    def _act(self, ls) -> None:
        """What the manoeuvre does before this step's SUMO step."""
        m = self.manoeuvre
        if self.phase == "inserted" and m.signal_s > 0 and self.start_step is None:
            ls.vehicle.setLaneChangeMode(self.entering, 0)
            ls.vehicle.setSpeedMode(self.entering, 0)  # it keeps pace beside its gap
            self.start_step, self.phase = self.k, "signalling"
        if self.phase == "signalling":
            if self.k < self.start_step + int(round(m.signal_s / DT_S)):
                ls.vehicle.setSignals(self.entering, SIGNAL_TOWARD_PLATOON)  # SUMO clears it
            else:
                ls.vehicle.setSignals(self.entering, -1)  # SUMO shows the lane change's own
                self.phase = "inserted"
        if self.phase == "inserted":
            ls.vehicle.setLaneChangeMode(self.entering, 0)
            if m.lane_change_s > 0:  # it keeps pace with its gap while it moves over
                ls.vehicle.setSpeedMode(self.entering, 0)
            ls.vehicle.changeLane(self.entering, ls.vehicle.getLaneIndex(self.entering) + 1,
                                  self._hold_s)
            self.phase = "changing"
        if self.phase == "done" and m.leave_s is not None and m.kind == "cut-in" \
                and self.k >= self.done_step + int(round(m.leave_s / DT_S)):
            ls.vehicle.changeLane(self.entering, ls.vehicle.getLaneIndex(self.entering) - 1,
                                  self._hold_s)  # the human leaves again
            self.phase = "leaving"
        if self.phase != "waiting" or self.k < m.step:
            return
        if m.kind == "cut-out":
            leaver = self.ids[m.position - 1]
            ls.vehicle.setLaneChangeMode(leaver, 0)
            ls.vehicle.changeLane(leaver, ls.vehicle.getLaneIndex(leaver) - 1, self._hold_s)
            self.phase = "changing"
        elif m.kind == "merge":
            head = self.ids[m.position]
            self.radar_only.discard(head)
            extra = self.offset.pop(head)
            if self.follower_model != "external":
                ls.vehicle.setMinGap(head, ls.vehicle.getMinGap(head) - extra)
            self.done_step, self.phase = self.k, "done"
            self.behind = [v for v in self.order[self.order.index(head):]]
        else:
            self._insert(ls)

    def _insert(self, ls) -> None:
        """Insert the entering vehicle beside its gap, when the gap has room. SUMO puts a new
        vehicle at its depart position after it has moved the others in the step, so the gap is
        measured where the step will leave its two vehicles (each at its speed for dt)."""
        m = self.manoeuvre
        original = self.ids
        if m.position == self.n:  # join behind the tail, at the gap the tail keeps
            tail = original[-1]
            if tail not in self.order:
                return
            gap = self.ahead[tail][1]
            speed = self.speeds[tail]
            front = self._route_x(ls, tail) + speed * DT_S - self.lengths[-1] - gap
        else:
            behind = original[m.position]
            if behind not in self.order:
                return
            pred, gap = self.ahead[behind]
            v_behind = self.speeds[behind]
            v_pred = self.speeds.get(pred, v_behind)
            length = self._entering_length()
            room = gap + (v_pred - v_behind) * DT_S - length
            if room < MIN_ROOM_M:
                if m.gives_up(self.k):
                    self.phase = "no room"  # it stays in its own lane: no manoeuvre
                return
            front = self._route_x(ls, behind) + v_behind * DT_S + m.gap_fraction * room + length
            speed = 0.5 * (v_behind + v_pred)
        lane, lane_pos = self.adjacent.locate(front)
        route_index = self.adjacent.lanes.index(lane)
        allow_speed(self.adjacent.lanes, [self._entering_type()], speed)  # a fast event's speed
        ls.vehicle.add(self.entering, f"platoon{route_index}", self._entering_type(),
                       depart="now", departLane=lane.rsplit("_", 1)[1],
                       departPos=f"{lane_pos:.6f}", departSpeed=f"{speed:.6f}")
        self._enter_speed = speed
        self.phase = "inserted"

    def _entering_type(self) -> str:
        if self.manoeuvre.kind == "cut-in":
            return HUMAN_TYPE
        if self._joiner_plant is not None:
            return self._joiner_plant.vtypes[0]
        return FOLLOWER_TYPES[self.follower_model]

    def _entering_length(self) -> float:
        if self.manoeuvre.kind == "join" and self._joiner_plant is not None:
            return float(self._joiner_plant.length_m[0])
        return self.scenario.vehicle_length_m

    def _untrack_gone(self) -> None:
        """Stop tracking a vehicle that has left the platoon lane once no part of it is in the
        lane (at once without ``lc=S``)."""
        if self.phase == "left":
            self._gone.add(self.entering)
        for vid in [v for v in self._gone if v in self.tracked and v not in self.crossing]:
            self.tracked.remove(vid)

    def _complete(self, ls) -> None:
        """Whether this step's lane change finished the manoeuvre; hand vehicles over."""
        lanes = set(self.route.lanes)
        if self.phase == "leaving" and ls.vehicle.getLaneID(self.entering) not in lanes:
            self.left_step, self.phase = self.k, "left"
        if self.phase != "changing":
            return
        m = self.manoeuvre
        if m.kind == "cut-out":
            leaver = self.ids[m.position - 1]
            if ls.vehicle.getLaneID(leaver) in lanes:
                return
            self.members.remove(leaver)
            self._gone.add(leaver)  # tracked until it is out of the lane (_untrack_gone)
            if self.follower_model == "external":  # SUMO drives it from now on
                ls.vehicle.setSpeedMode(leaver, 31)
                ls.vehicle.setSpeed(leaver, -1)
            self.behind = [v for v in self.order[self.order.index(leaver) + 1:]]
        else:  # in the lane from the step its body crosses the line (lc=S: before SUMO has it)
            if ls.vehicle.getLaneID(self.entering) not in lanes \
                    and self.entering not in self._body_crossing:
                return
            ls.vehicle.setLaneChangeMode(self.entering, 0)
            if m.kind == "join" and self.follower_model == "external":
                ls.vehicle.setSpeedMode(self.entering, 0)
                self.accels[self.entering] = 0.0
            else:
                ls.vehicle.setSpeedMode(self.entering, 31)  # SUMO's own model drives it
                ls.vehicle.setSpeed(self.entering, -1)
            if m.kind == "join":
                self.members.append(self.entering)  # _sense puts it in its place
                self.joining.add(self.entering)  # until it has room (_settle)
            x = self._route_x(ls, self.entering)
            self.behind = [v for v in self.order if self._route_x(ls, v) < x]
            if m.kind == "join" and not self.behind:  # at the tail: the joiner's own gap
                self.behind = [self.entering]
        self.done_step, self.phase = self.k, "done"
