"""Manoeuvres in real SUMO on the shipped default leaders and networks/i80.net.xml: cut-in,
cut-out, join and merge with SUMO's own lane changes; their metrics against hand computations;
bad scenarios refused before any simulation."""

from __future__ import annotations

import subprocess

import numpy as np
import pytest

from carl_sumo.config import DT_S
from carl_sumo.control.channel import Impairments
from carl_sumo.data import load_events
from carl_sumo.errors import InputError
from carl_sumo.manoeuvres.metrics import (ScenarioTrace, manoeuvre_metrics,
                                             settle_and_overshoot, whole_run_metrics)
from carl_sumo.manoeuvres.spec import Manoeuvre, parse_scenario
from carl_sumo.manoeuvres.simulation import ScenarioSim
from carl_sumo.sim.vehicle import Plant
from carl_sumo.manoeuvres.runs import (NotApplicable, chains_of, check_scenario,
                                       heard_accelerations, run_scenario_event,
                                       scenario_controller, score_trace)

from conftest import NET

EVENT_ID = "sumo42_f1865_l1847_fr5798"  # test split, leader at 6-10 m/s, 27 s
N = 6
PLATOON_INDEX = 4  # SUMO lane index of NGSIM lane 2 on i80_approach


@pytest.fixture(scope="module")
def event():
    (e,) = load_events("default", "test", event_ids=[EVENT_ID])
    return e


def _drive(sim: ScenarioSim, controller, watch, arm: bool = False) -> list:
    """Run the sim to its end with a scenario controller; ``watch(sim)`` after every step;
    ``arm``: tell the controller who is armed, as :func:`run_scenario_event` does."""
    import libsumo

    seen = []
    controller.reset()
    while not sim.done:
        ids, obs, ahead = sim.observe()
        if arm:
            controller.arm(sim.armed)
        accel = controller.acceleration(obs, chains_of(ids, ahead), ids, ahead,
                                        {v: sim.accels[v] for v in ids})
        sim.advance(dict(zip(ids, accel.tolist())))
        seen.append(watch(sim, libsumo))
    return seen


def test_cut_in_changes_lane_into_the_gap_and_splits_the_chain(event):
    _, controller = scenario_controller("ploeg-tuned:h=0.8")
    sim = ScenarioSim(NET, "external")
    sim.start(event, N, Manoeuvre("cut-in", 3, 6.0, 0.5))

    def watch(s, ls):
        lane = ls.vehicle.getLaneIndex("human") if "human" in s.tracked else None
        return (s.k, lane, ls.vehicle.getLeader("f3", 300)[0], list(s.order), list(s.members),
                min(s.ahead[v][1] for v in s.order))

    seen = _drive(sim, controller, watch)
    lanes = [lane for _, lane, *_ in seen if lane is not None]
    assert lanes[0] == PLATOON_INDEX - 1 and lanes[-1] == PLATOON_INDEX  # SUMO's lane change
    assert sim.done_step is not None and sim.done_step * DT_S >= 6.0
    order = sim.order
    assert order.index("human") == order.index("f2") + 1 == order.index("f3") - 1
    assert seen[-1][2] == "human"  # SUMO has the human ahead of follower 4 ...
    ids, obs, ahead = sim.observe()
    assert ahead[ids.index("f3")][0] == "human"  # ... and so does its controller
    assert "human" not in sim.members and len(sim.members) == N
    chains = [[ids[i] for i in c] for c in chains_of(ids, ahead)]
    assert chains == [["f0", "f1", "f2"], ["f3", "f4", "f5"]]  # no message reaches f3
    assert min(gap for *_, gap in seen) > 0
    assert sim.behind == ["f3", "f4", "f5"]


def test_a_human_who_leaves_again_lets_the_chain_link_again(event):
    _, controller = scenario_controller("policies/ca_td3_ploeg_10.pt")
    sim = ScenarioSim(NET, "external")
    sim.start(event, N, parse_scenario("cut-in:k=3:t=6:f=0.5:leave=4").draw(event, N))

    def watch(s, ls):
        ids, _, ahead = s.observe()
        return len(chains_of(ids, ahead)), ls.vehicle.getLeader("f3", 300)[0]

    seen = _drive(sim, controller, watch)
    assert (2, "human") in seen  # split while the human is in the lane ...
    assert seen[-1] == (1, "f2")  # ... one chain again once he is out
    assert sim.left_step - sim.done_step >= 40 and "human" not in sim.order
    import libsumo

    assert libsumo.vehicle.getLaneIndex("human") == PLATOON_INDEX - 1


def test_the_follower_behind_a_cut_in_acts_on_radar_alone(event):
    """The Ploeg CACC of the follower behind the human gets no feed-forward: its acceleration
    is the radar-only ACC law's on its own measurements, where the follower ahead of the human
    still takes its predecessor's message."""
    from dataclasses import replace

    from carl_sumo.control.cacc import PloegController

    _, controller = scenario_controller("ploeg-tuned:h=0.8")
    sim = ScenarioSim(NET, "external")
    sim.start(event, N, Manoeuvre("cut-in", 3, 6.0, 0.5))
    _drive(sim, controller, lambda s, ls: None)
    ids, obs, ahead = sim.observe()
    row = ids.index("f3")
    u_f3 = controller.u["f3"]
    heard = heard_accelerations(sim, ids, 0.0)
    assert "human" not in heard
    got = controller.acceleration(obs, chains_of(ids, ahead), ids, ahead, heard, commit=False)
    acc = PloegController(replace(controller.controller.params, feed_forward=False))
    expected = acc.step(obs[[row]], np.array([u_f3]), 0.0)
    assert got[row] == pytest.approx(expected[0], abs=1e-12)
    cacc_row = ids.index("f2")  # inside the first chain: the law with f1's message
    with_message = controller.controller.step(obs[[cacc_row - 1, cacc_row]],
                                              np.array([controller.u["f1"], controller.u["f2"]]),
                                              0.0)
    assert got[cacc_row] == pytest.approx(with_message[1], abs=1e-12)


def test_cut_out_leaves_the_lane_and_relinks_the_chain(event):
    _, controller = scenario_controller("ploeg-tuned:h=0.8")
    sim = ScenarioSim(NET, "external")
    sim.start(event, N, Manoeuvre("cut-out", 3, 6.0))

    def watch(s, ls):
        return ls.vehicle.getLaneIndex("f2"), ls.vehicle.getLeader("f3", 300)[0]

    seen = _drive(sim, controller, watch)
    assert seen[0][0] == PLATOON_INDEX and seen[-1][0] == PLATOON_INDEX - 1
    assert seen[0][1] == "f2" and seen[-1][1] == "f1"
    ids, obs, ahead = sim.observe()
    assert "f2" not in ids and ahead[ids.index("f3")][0] == "f1"
    assert chains_of(ids, ahead) == [list(range(N - 1))]  # one chain again
    assert sim.behind == ["f3", "f4", "f5"]


@pytest.mark.parametrize("lc", [0.0, 3.0])
def test_a_gradual_cut_in_is_seen_from_the_step_the_human_crosses_the_line(event, lc):
    """``lc=S``: SUMO moves the human sideways over S seconds and has him in the platoon lane
    from halfway; the follower behind sees him from the step his body crosses the lane line,
    before that, and the manoeuvre is done then. Without it the change takes one step."""
    _, controller = scenario_controller("ploeg-tuned:h=0.8")
    sim = ScenarioSim(NET, "external")
    spec = parse_scenario(f"cut-in:k=3:t=6:f=0.5:lc={lc:g}")
    assert spec.lane_change_s == lc
    sim.start(event, N, spec.draw(event, N))

    def watch(s, ls):
        if "human" not in s.tracked or "human" not in ls.vehicle.getIDList():
            return None
        lane = ls.vehicle.getLaneID("human")
        half = 0.5 * (ls.lane.getWidth(lane) - ls.vehicle.getWidth("human"))
        return (s.k, ls.vehicle.getLaneIndex("human"), ls.vehicle.getLateralLanePosition("human"),
                half, s.ahead["f3"][0], s.phase)

    seen = [w for w in _drive(sim, controller, watch) if w is not None]
    first_seen = next(w for w in seen if w[4] == "human")
    in_lane = next(w for w in seen if w[1] == PLATOON_INDEX)
    assert first_seen[5] == "done" and sim.done_step == first_seen[0]
    if lc == 0:
        assert first_seen[0] == in_lane[0] and first_seen[2] == 0.0
        return
    assert first_seen[1] == PLATOON_INDEX - 1 and first_seen[2] > first_seen[3]  # over the line
    before = [w for w in seen if w[0] < first_seen[0]]
    assert before[-1][2] <= before[-1][3] and before[-1][4] == "f2"
    start = next(w for w in seen if w[2] > 0)[0]
    assert in_lane[0] - start == pytest.approx(0.5 * lc / DT_S, abs=2)  # SUMO: halfway
    assert first_seen[0] < in_lane[0]
    lateral = [w[2] for w in seen if start <= w[0] < in_lane[0]]
    assert np.all(np.diff(lateral) > 0)  # it moves over gradually


def _signal_run(event, text: str) -> tuple[ScenarioSim, list]:
    _, controller = scenario_controller("ploeg-tuned:h=0.8")
    sim = ScenarioSim(NET, "external")
    sim.start(event, N, parse_scenario(text).draw(event, N))
    entering = sim.entering

    def watch(s, ls):
        if entering not in s.tracked:
            return None
        return (s.k, s.phase, s.ahead["f3"][0], s.ahead["f3"][1], ls.vehicle.getSignals(entering),
                ls.vehicle.getLaneIndex(entering))

    return sim, [w for w in _drive(sim, controller, watch) if w is not None]


@pytest.mark.parametrize("text", ["cut-in:k=3:t=6:f=0.5", "cut-in:k=3:t=6:f=0.5:signal=2",
                                  "join:k=3:t=6:f=0.5", "join:k=3:t=6:f=0.5:signal=2"])
def test_the_member_a_vehicle_enters_ahead_of_is_armed_until_it_has_room(event, text):
    """From the first step the human is ahead of f3 (his landing, or his first signal), or the
    joiner is in the lane ahead of it (an announced joiner: not while it signals), f3 is armed
    (the law's ``gn=B`` acts on it), in one stretch that ends the first step it is not closing in
    and (d - 2 m)/v ≥ 0.8 s; no other member is ever armed but the joiner itself (joining)."""
    _, controller = scenario_controller(ROBUST_HA + ":ttc=2")  # behind him: an ACC at 1.4 s
    sim = ScenarioSim(NET, "external")
    sim.start(event, N, parse_scenario(text).draw(event, N))
    entering = sim.entering

    def watch(s, ls):
        pred, gap = s.ahead["f3"]
        return set(s.armed), pred, gap, s.speeds["f3"], s.speeds.get(pred, np.inf), \
            entering in s.members

    seen = _drive(sim, controller, watch)
    first = next(i for i, w in enumerate(seen) if w[1] == entering)
    if entering == "joiner":  # seen from its first signal, armed from its lane change
        joined = next(i for i, w in enumerate(seen) if w[5])
        assert (joined > first + 10) == ("signal" in text)
        assert not any("f3" in w[0] for w in seen[:joined])
        first = joined
    armed = [i for i, w in enumerate(seen) if "f3" in w[0]]
    assert armed[0] == first and armed == list(range(first, armed[-1] + 1))
    assert all(w[0] - {"joiner"} == {"f3"} for w in seen[first:armed[-1] + 1])
    assert all(w[0] <= {"joiner"} for w in seen[armed[-1] + 1:])

    def has_room(w):
        return w[2] - 2.0 >= 0.8 * w[3] and w[3] <= w[4]

    assert not any(has_room(w) for w in seen[first:armed[-1] + 1])
    if entering == "human":
        assert armed[-1] + 1 < len(seen) and has_room(seen[armed[-1] + 1])
    else:  # behind a joiner the law's own 0.8 s is approached from below: armed to the end
        assert armed[-1] + 1 == len(seen) and seen[-1][1] == "joiner"


def _opening_run(event, name: str, text: str) -> tuple[ScenarioSim, list]:
    """f3's (step, gap, speed, acceleration) from the first step the entering vehicle is ahead
    of it, under the law ``name``, armed as :func:`run_scenario_event` arms it."""
    _, controller = scenario_controller(name)
    sim = ScenarioSim(NET, "external")
    sim.start(event, N, parse_scenario(text).draw(event, N))

    def watch(s, ls):
        if s.ahead["f3"][0] != s.entering:
            return None
        return s.k, s.ahead["f3"][1], s.speeds["f3"], s.accels["f3"]

    return sim, [w for w in _drive(sim, controller, watch, arm=True) if w is not None]


def test_op_drops_back_behind_a_signalling_human_at_a_bounded_braking(event):
    """``op=2``: behind a human who signals for 2 s, f3 (armed, at the front of its chain)
    opens its gap while he signals, braking at no more than 2 m/s² for it, so he lands further
    ahead of it and it comes less close than the same law without ``op`` (h = 0.6 s, ``gn=6``,
    the product's base; he takes 30 % of the gap)."""
    law = "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2:rb=1:gn=6"
    text = "cut-in:k=3:t=6:f=0.3:signal=2"
    plain, plain_seen = _opening_run(event, law, text)
    sim, seen = _opening_run(event, law + ":op=2", text)
    assert sim.done_step == plain.done_step and seen[0] == plain_seen[0]  # the same signal

    def landed(run, steps):
        return next(w[1] for w in steps if w[0] >= run.done_step)

    assert landed(sim, seen) > landed(plain, plain_seen) + 0.8  # m: measured 7.88 against 6.83
    assert min(w[1] for w in seen) > min(w[1] for w in plain_seen) + 0.3  # 7.22 against 6.83
    assert min(w[3] for w in seen) >= -2.0 - 1e-3  # m/s²: at most B while it opens


@pytest.mark.parametrize("kind", ["cut-in", "join"])
def test_a_signalled_entry_is_seen_from_the_first_signal_and_gets_room(event, kind):
    """``signal=2``: the human (his left indicator) or the joiner (its request to join) signals
    beside the gap for 2 s, keeping pace, and the follower behind takes it as its predecessor
    from then on; it moves over after that, keeping pace with the vehicle ahead of its gap. The
    follower brakes for it before it lands, so it comes less close behind it than in the same entry
    without the signal (a cut-in; behind a joiner the law at 0.8 s comes closer), and the peak
    deceleration counts from the signal."""
    plain, plain_seen = _signal_run(event, f"{kind}:k=3:t=6:f=0.5")
    sim, seen = _signal_run(event, f"{kind}:k=3:t=6:f=0.5:signal=2")
    signalling = [w for w in seen if w[1] == "signalling"]
    assert len(signalling) == round(2.0 / DT_S)
    assert all(w[2] == sim.entering and w[4] & 2 and w[5] == PLATOON_INDEX - 1
               for w in signalling)
    assert sim.start_step == signalling[0][0] - 1 == plain.done_step - 1
    assert sim.done_step == sim.start_step + round(2.0 / DT_S) + 1
    assert all(w[2] == sim.entering for w in seen if w[0] >= signalling[0][0])
    closest = min(w[3] for w in seen if w[0] >= sim.done_step)
    plain_closest = min(w[3] for w in plain_seen if w[0] >= plain.done_step)
    if kind == "cut-in":
        assert closest > plain_closest + 0.2  # m: room opened while he signalled (7.0, 6.7)
    else:  # measured: 7.7 m against 8.0: on radar alone f3 loses the joiner's feed-forward
        assert closest == pytest.approx(7.73, abs=0.05) and plain_closest > closest
    trace = ScenarioTrace("e", "cut-in", np.zeros(4), ["f3"], ["f3"],
                          np.array([[20.0], [19.0], [19.0], [19.0]]), np.full((4, 1), 10.0),
                          np.full((4, 1), 19.0), done_step=2, behind=["f3"])
    assert manoeuvre_metrics(trace)["peak_decel_mps2"] == 0.0
    trace.start_step = 0
    assert manoeuvre_metrics(trace)["peak_decel_mps2"] == pytest.approx(10.0)


def test_a_gradual_cut_out_is_seen_until_the_leaver_is_out_of_the_lane(event):
    """``cut-out:lc=3``: the follower behind keeps the leaver as its predecessor after SUMO has
    moved it to the adjacent lane, while part of it is still in the platoon lane."""
    _, controller = scenario_controller("ploeg-tuned:h=0.8")
    sim = ScenarioSim(NET, "external")
    sim.start(event, N, parse_scenario("cut-out:k=3:t=6:lc=3").draw(event, N))

    def watch(s, ls):
        return s.k, ls.vehicle.getLaneIndex("f2"), s.ahead["f3"][0], "f2" in s.members

    seen = _drive(sim, controller, watch)
    moved = next(w for w in seen if w[1] == PLATOON_INDEX - 1)
    relinked = next(w for w in seen if w[2] == "f1")
    assert not moved[3] and moved[2] == "f2"  # no longer a member, still seen
    assert relinked[0] - moved[0] >= 5
    assert seen[-1][2] == "f1" and "f2" not in sim.tracked


def test_join_grows_the_platoon_by_one(event):
    _, controller = scenario_controller("policies/ca_td3_ploeg_10.pt")
    sim = ScenarioSim(NET, "external")
    sim.start(event, N, Manoeuvre("join", 3, 6.0, 0.5))
    sizes = _drive(sim, controller, lambda s, ls: len(s.members))
    assert sizes[0] == N and sizes[-1] == N + 1
    ids, obs, ahead = sim.observe()
    assert ids.index("joiner") == 3 and ahead[3][0] == "f2" and ahead[4][0] == "joiner"
    assert chains_of(ids, ahead) == [list(range(N + 1))]  # the joiner is in the chain
    assert np.all(obs[:, 2] > 0)


def test_a_join_at_the_tail_is_measured_on_the_joiner(event):
    _, controller = scenario_controller("ploeg-tuned:h=0.8")
    trace = run_scenario_event(ScenarioSim(NET, "external"), event, N,
                               Manoeuvre("join", N, 6.0), controller)
    assert trace.behind == ["joiner"]
    m = manoeuvre_metrics(trace)
    assert m["done"] == 1 and m["min_gap_m"] > 0 and np.isfinite(m["settle_s"])


def test_merge_links_the_second_platoon_and_closes_the_gap(event):
    _, controller = scenario_controller("ploeg-tuned:h=0.8")
    sim = ScenarioSim(NET, "external")
    sim.start(event, N, Manoeuvre("merge", 3, 6.0, extra_gap_m=30.0))
    ids, obs, ahead = sim.observe()
    assert len(chains_of(ids, ahead)) == 2 and ahead[3][0] == "radar:f2"
    gap0 = sim.ahead["f3"][1]
    gaps = _drive(sim, controller, lambda s, ls: s.ahead["f3"][1])
    ids, obs, ahead = sim.observe()
    assert chains_of(ids, ahead) == [list(range(N))]
    assert gap0 > 30.0 and gaps[-1] < gap0 - 20.0


@pytest.mark.parametrize("kind", ["cut-in", "cut-out", "join", "merge"])
@pytest.mark.parametrize("name", ["idm", "ploeg-tuned:h=0.8", "policies/ca_td3_ploeg_10.pt"])
def test_every_manoeuvre_runs_and_scores_finite(event, kind, name):
    model, controller = scenario_controller(name)
    sim = ScenarioSim(NET, model)
    trace = run_scenario_event(sim, event, N, parse_scenario(kind).draw(event, N), controller)
    row = score_trace(trace)
    m = row["manoeuvre_metrics"]
    assert m["done"] == 1 and m["collisions"] == 0 and m["min_gap_m"] > 0
    for key in ("min_gap_m", "peak_decel_mps2", "peak_jerk_mps3", "settle_s", "overshoot"):
        assert np.isfinite(m[key]), key
    assert np.isfinite(row["jerk_mps3"]) and np.isfinite(row["headway_s"])


def test_real_plant_cut_in_with_the_product_policy(event):
    from carl_sumo.control.channel import Impairments
    from carl_sumo.sim.vehicle import REAL_PLANT

    imp = Impairments(delay_s=0.1, plant=REAL_PLANT)
    model, controller = scenario_controller("policies/ca_td3_real_10.pt", imp.plant_key)
    trace = run_scenario_event(ScenarioSim(NET, model), event, N,
                               Manoeuvre("cut-in", 2, 6.0, 0.5), controller, imp)
    m = manoeuvre_metrics(trace)
    assert m["done"] == 1 and m["min_gap_m"] > 0 and np.isfinite(m["peak_decel_mps2"])


# ------------------------------------------------------------------------------ anti-windup
ROBUST = "ploeg:h=0.8:kp=0.0445:kd=1"  # the robust real-plant CACC (ploeg-tuned:h=0.8 there)


def _trucks() -> Impairments:
    """The real plant with a fleet of trucks only (a_max 1 m/s², b_max 6 m/s²), 0.1 s V2V delay:
    the joiner is a truck too."""
    return Impairments(delay_s=0.1, plant=Plant((("truck", 1.0),)))


def _recorded_run(event, name: str, imp, manoeuvre: Manoeuvre):
    """Run one scenario event; (trace, sim, every step's states u of the classical law (the
    policy's base) by vehicle ID, and the IDs whose limits it knew then)."""
    model, controller = scenario_controller(name, imp.plant_key if imp is not None else "ideal")
    law = getattr(controller, "base", controller)
    steps = []
    inner = controller.acceleration

    def acceleration(*args, **kwargs):
        out = inner(*args, **kwargs)
        steps.append((dict(law.u), set(law.limits), set(sim.tracked)))
        return out

    controller.acceleration = acceleration
    sim = ScenarioSim(NET, model)
    trace = run_scenario_event(sim, event, N, manoeuvre, controller, imp)
    return trace, sim, steps


@pytest.mark.parametrize("name, binds", [(ROBUST + ":aw=1", True),
                                         ("policies/ca_td3_real_10.pt", False)])
def test_with_aw_every_truck_state_stays_within_its_limits_through_a_join(event, name, binds):
    """aw=1 on the real plant: every vehicle's state (the message it sends) stays within its own
    class's limits, a truck's 1 m/s² and -6 m/s², the joiner's from the step it is on the road
    (the same run without aw=1 passes 1 m/s²:
    test_without_aw_a_scenario_run_is_unchanged_by_the_limits)."""
    trace, sim, steps = _recorded_run(event, name, _trucks(), Manoeuvre("join", N, 6.0))
    assert sim.done_step is not None and trace.collisions == 0
    assert sim.limits == {**{f"f{i}": (1.0, 6.0) for i in range(N)}, "joiner": (1.0, 6.0)}
    states = [u for u, _, _ in steps]
    if binds:  # the classical law reaches the truck's limit in this join; the product, whose
        # start feeds forward 3 vehicles ahead, peaks at 0.91 m/s² here
        assert max(max(u.values()) for u in states) == pytest.approx(1.0, abs=1e-12)
    assert all(-6.0 <= x <= 1.0 for u in states for x in u.values())
    for _, known, on_road in steps:  # the joiner's limits are known once it is on the road
        assert ("joiner" in known) == ("joiner" in on_road)
    assert any("joiner" in u for u in states)


def test_without_aw_a_scenario_run_is_unchanged_by_the_limits(event, monkeypatch):
    """aw=0: the controller is told the limits but does not use them; the run is the one of a
    controller never told (and a truck's state passes its 1 m/s² in it)."""
    import carl_sumo.manoeuvres.runs as scenarios

    manoeuvre = Manoeuvre("join", N, 6.0)
    told, _, steps = _recorded_run(event, ROBUST, _trucks(), manoeuvre)
    assert max(max(u.values()) for u, _, _ in steps) > 1.1
    monkeypatch.setattr(scenarios, "know_vehicle", lambda *args: None)
    untold, _, _ = _recorded_run(event, ROBUST, _trucks(), manoeuvre)
    assert np.array_equal(told.speed, untold.speed, equal_nan=True)
    assert np.array_equal(told.gap, untold.gap, equal_nan=True)


def test_on_the_ideal_plant_aw_changes_nothing(event):
    manoeuvre = Manoeuvre("cut-in", 2, 6.0, 0.5)
    with_aw, sim, steps = _recorded_run(event, ROBUST + ":aw=1", None, manoeuvre)
    assert sim.limits == {} and all(not known for _, known, _ in steps)
    plain, _, _ = _recorded_run(event, ROBUST, None, manoeuvre)
    assert np.array_equal(with_aw.speed, plain.speed, equal_nan=True)


# ------------------------------------------------------------------------------ metrics
def test_settle_and_overshoot_by_hand():
    series = np.concatenate([np.linspace(0.5, 1.2, 8), np.full(40, 1.0)])
    settle, overshoot = settle_and_overshoot(series, 0.1)
    # steady state 1.0; the last sample outside ±0.1 is 1.2 - 0.1·... at index 7 (1.2) → 0.8 s
    assert settle == pytest.approx(0.8) and overshoot == pytest.approx(0.2)
    closing = np.concatenate([[2.0, 1.5, 0.85], np.full(40, 1.0)])
    assert settle_and_overshoot(closing, 0.1) == pytest.approx((0.3, 0.15))
    assert np.isnan(settle_and_overshoot(np.ones(10), 0.1)[0])


def _synthetic_trace() -> ScenarioTrace:
    """Two vehicles for 6 samples: 'a' ahead, 'b' behind it from step 2 on (t_m = 2)."""
    speed = np.array([[10, 10], [10, 10], [10, 10], [9, 10], [8, 9.5], [8, 9]], float)
    gap = np.array([[20, 8], [20, 8], [20, 6], [20, 5], [20, 4.5], [20, 4.4]], float)
    pred = np.array([[10, 10], [10, 10], [10, 10], [10, 9], [10, 8], [10, 8]], float)
    return ScenarioTrace("syn", "cut-in", np.full(6, 10.0), ["a", "b"], ["a", "b"], speed, gap,
                         pred, done_step=2, behind=["b"])


def test_manoeuvre_metrics_match_a_hand_computation():
    m = manoeuvre_metrics(_synthetic_trace())
    assert m["min_gap_m"] == pytest.approx(4.4)
    # b closes in at steps 3 (10 - 9: TTC 5/1), 4 (9.5 - 8: 4.5/1.5 = 3) and 5 (9 - 8: 4.4)
    assert m["min_ttc_s"] == pytest.approx(3.0)
    # b's a from step 2: 0, -5, -5 m/s²; jerk |Δa|/dt from step 2: 50, 0 m/s³
    assert m["peak_decel_mps2"] == pytest.approx(5.0)
    assert m["peak_jerk_mps3"] == pytest.approx(50.0)
    assert m["peak_decel_by_vehicle"] == {"b": pytest.approx(5.0)}
    assert np.isnan(m["settle_s"])  # 4 samples after t_m: too short for a steady state
    whole = whole_run_metrics(_synthetic_trace())
    assert whole["speed_mps"] == pytest.approx(speed_mean := np.mean(
        _synthetic_trace().speed)) and speed_mean > 0
    assert whole["ttc_lt_4s_count"] == 1 and whole["collisions"] == 0


def test_a_manoeuvre_that_did_not_happen_has_nan_metrics():
    trace = _synthetic_trace()
    trace.done_step = None
    m = manoeuvre_metrics(trace)
    assert m["done"] == 0 and np.isnan(m["min_gap_m"])


# ------------------------------------------------------------------------------ bad input
@pytest.mark.parametrize("text, message", [
    ("cut-in:f=0", "gap fraction"), ("cut-in:f=1", "gap fraction"), ("join:f=1.5", "gap fraction"),
    ("cut-in:wait=-1", "wait is how long"), ("join:wait=0.05", "wait is how long"),
    ("cut-out:wait=0", "not an option"),
    ("overtake", "unknown manoeuvre"), ("cut-out:f=0.5", "not an option"),
    ("cut-in:k=1.5", "whole vehicle position"), ("cut-in:t=-1", "multiple"),
    ("merge:gap=0", "positive"), ("cut-in:leave=0", "positive time"),
    ("join:leave=3", "not an option"), ("cut-in:lc=-1", "duration"),
    ("join:lc=0.05", "duration"), ("cut-out:lc=11", "duration"), ("merge:lc=3", "not an option"),
    ("cut-in:signal=-1", "signal is how long"), ("cut-in:signal=0.05", "signal is how long"),
    ("cut-out:signal=2", "not an option"), ("join:signal=11", "signal is how long")])
def test_bad_scenario_text_is_refused(text, message):
    with pytest.raises(InputError, match=message):
        parse_scenario(text)


def test_a_position_beyond_the_platoon_and_a_time_beyond_the_event_are_refused(event):
    with pytest.raises(InputError, match="beyond the platoon"):
        check_scenario("idm", parse_scenario("cut-in:k=10"), [event], 10, NET)
    with pytest.raises(InputError, match="beyond the platoon"):
        check_scenario("idm", parse_scenario("cut-out:k=0"), [event], 10, NET)
    with pytest.raises(InputError, match="does not fit event"):
        check_scenario("idm", parse_scenario("cut-in:t=26"), [event], 10, NET)
    with pytest.raises(InputError, match="at least 2 followers"):
        check_scenario("idm", parse_scenario("cut-out"), [event], 1, NET)


def test_a_network_without_a_lane_beside_the_platoon_is_refused(tmp_path, event):
    from carl_sumo.sim.network import netconvert_binary

    (tmp_path / "n.nod.xml").write_text('<nodes><node id="a" x="0" y="0"/>'
                                        '<node id="b" x="3000" y="0"/></nodes>')
    (tmp_path / "n.edg.xml").write_text('<edges><edge id="e" from="a" to="b" numLanes="2" '
                                        'speed="33"/></edges>')
    net = tmp_path / "two_lanes.net.xml"
    subprocess.run([netconvert_binary(), "-n", str(tmp_path / "n.nod.xml"), "-e",
                    str(tmp_path / "n.edg.xml"), "-o", str(net)], check=True, capture_output=True)
    # NGSIM lane 2 of a two-lane road is its right lane: nothing beside it on the right
    with pytest.raises(InputError, match="needs a lane beside it"):
        check_scenario("idm", parse_scenario("cut-in"), [event], 3, net)


def test_maddpg_and_the_recorded_follower_are_not_applicable():
    with pytest.raises(NotApplicable, match="n/a: fixed size"):
        scenario_controller("policies/maddpg_10.pt")
    with pytest.raises(NotApplicable, match="n/a"):
        scenario_controller("human")


def test_the_draw_is_seeded_per_event(event):
    a = parse_scenario("cut-in").draw(event, 10)
    assert a == parse_scenario("cut-in").draw(event, 10)
    assert 1 <= a.position <= 9 and 0.4 <= a.gap_fraction <= 0.6
    first, last = 0.2 * (event.n_samples - 1) * DT_S, 0.4 * (event.n_samples - 1) * DT_S
    assert first - 1e-9 <= a.time_s <= last + 1e-9
    draws = {parse_scenario("cut-in", seed=s).draw(event, 10) for s in range(8)}
    assert len(draws) > 1


@pytest.mark.parametrize("name", ["ploeg-tuned:h=0.8", "policies/ca_td3_ploeg_10.pt", "idm"])
def test_before_the_manoeuvre_a_scenario_run_is_the_plain_run(event, name):
    """Up to the manoeuvre the scenario layer (getLeader gaps, chains, per-vehicle states)
    drives the platoon as the plain run does (PlatoonSim, the platoon controllers)."""
    from carl_sumo.experiments.simulate import resolve_controller, run_event
    from carl_sumo.sim.sumo import PlatoonSim

    model, plain_controller = resolve_controller(name)
    plain = run_event(PlatoonSim(NET, model), event, N, plain_controller)
    _, controller = scenario_controller(name)
    trace = run_scenario_event(ScenarioSim(NET, model), event, N,
                               Manoeuvre("cut-out", 3, 6.0), controller)
    cols = [trace.column(f"f{i}") for i in range(N)]
    before = trace.done_step
    assert before is not None and before >= 60
    diff = np.abs(trace.speed[:before, cols] - plain.speed[:before]).max()
    assert diff < 1e-6, diff
    assert np.abs(trace.gap[:before, cols] - plain.gap[:before]).max() < 1e-6


# ------------------------------------------------------------------------------ degraded CACC
ROBUST_HA = ROBUST + ":aw=1:ha=1.4"  # the real plant's robust CACC, an ACC at 1.4 s unheard


def _ha_policy(tmp_path) -> str:
    """A CA-TD3 policy file on the degraded CACC (untrained: its a_adj is the shielded zero)."""
    from carl_sumo.learn.agents import Agent, AgentConfig
    from carl_sumo.learn.policy import save_policy

    path = tmp_path / "ha.pt"
    save_policy(Agent(AgentConfig(algo="ca-td3", n_vehicles=4, adj_max=1.0, base=ROBUST_HA)),
                path, {})
    return str(path)


def _law_steps(controller, watch: str, pred: str) -> list:
    """Record every committed step of the classical law (a policy's base): (obs, ids, ahead,
    adjustment, states u before, a, and how ``watch`` hears ``pred`` as (mode, message) when
    ``pred`` is directly ahead of it, else None)."""
    law = getattr(controller, "base", controller)
    steps, inner = [], law.acceleration

    def acceleration(obs, chains, ids, ahead, last_acc, adjustment=None, commit=True):
        heard = None
        row = ids.index(watch) if watch in ids else None
        if commit and row is not None and ahead[row] is not None and ahead[row][0] == pred:
            mode, held = law.links.receive(law._k, [(watch, pred)])  # what the law hears now
            heard = (int(mode[0]), float(held[0, 0]))
        before = dict(law.u)
        out = inner(obs, chains, ids, ahead, last_acc, adjustment, commit)
        if commit:
            steps.append((obs.copy(), list(ids), list(ahead),
                          np.zeros(len(ids)) if adjustment is None else np.array(adjustment),
                          before, out.copy(), heard))
        return out

    law.acceleration = acceleration
    return steps


def _law(law, vid: str, gap_s: float, feed_forward: bool):
    """A one- or two-row law of ``law``'s gains at time gap ``gap_s`` with ``vid``'s limits."""
    from dataclasses import replace

    from carl_sumo.control.cacc import PloegController

    one = PloegController(replace(law.controller.params, time_gap_s=gap_s, alone_gap_s=None,
                                  feed_forward=feed_forward))
    a_max, b_max = law.limits[vid]
    rows = 1 if not feed_forward else 2
    one.u_min, one.u_max = np.full(rows, -b_max), np.full(rows, a_max)
    return one


@pytest.mark.parametrize("which", ["law", "policy"])
def test_ha_the_follower_behind_a_cut_in_is_an_acc_at_ha_and_a_cacc_again_after(event, which,
                                                                                tmp_path):
    """Real plant, ``ha=1.4``: while the human is ahead of follower 4 (k=3) it hears no message
    and its command is the ACC law's at h = 1.4 s (not 0.8 s), from the step after the cut-in
    on; once he has left, it is in the chain again and runs the CACC at h = 0.8 s on its
    predecessor's message (at 1.4 s only at a step when no message from it has arrived yet).
    The same for a policy on that base (ChainController builds its base from the policy's)."""
    from carl_sumo.sim.vehicle import REAL_PLANT

    name = ROBUST_HA if which == "law" else _ha_policy(tmp_path)
    imp = Impairments(delay_s=0.1, plant=REAL_PLANT)
    model, controller = scenario_controller(name, imp.plant_key)
    law = getattr(controller, "base", controller)
    assert law.controller.params.alone_gap_s == 1.4 and law.controller.params.time_gap_s == 0.8
    steps = _law_steps(controller, "f3", "f2")
    sim = ScenarioSim(NET, model)
    manoeuvre = parse_scenario("cut-in:k=3:t=6:f=0.5:leave=4").draw(event, N)
    trace = run_scenario_event(sim, event, N, manoeuvre, controller, imp)
    assert trace.collisions == 0 and sim.left_step is not None
    alone = [s for s in steps if s[2][s[1].index("f3")][0] == "human"]
    assert alone and alone[0] is steps[sim.done_step]  # from the step after the cut-in on
    for obs, ids, ahead, adj, u, out, _ in alone:
        row = ids.index("f3")
        assert chains_of(ids, ahead)[1][0] == row  # f3 heads a chain of its own
        expected = _law(law, "f3", 1.4, False).step(obs[[row]], np.array([u.get("f3", 0.0)]),
                                                    0.0, adj[[row]])[0]
        assert out[row] == pytest.approx(expected, abs=1e-12)
    obs, ids, ahead, adj, u, out, _ = alone[0]
    row = ids.index("f3")
    at_h = _law(law, "f3", 0.8, False).step(obs[[row]], np.array([u.get("f3", 0.0)]), 0.0,
                                            adj[[row]])[0]
    assert abs(out[row] - at_h) > 1e-3  # not the ACC at h
    rejoined = [s for s in steps[sim.left_step:] if s[6] is not None]
    assert len(rejoined) > 20 and len(chains_of(rejoined[-1][1], rejoined[-1][2])) == 1
    modes = [s[6][0] for s in rejoined]
    assert modes[0] == 2 and set(modes[1:]) == {1}  # unheard one step, then its message
    for obs, ids, ahead, adj, u, out, (mode, held) in rejoined:
        row = ids.index("f3")
        if mode == 2:
            expected = _law(law, "f3", 1.4, False).step(obs[[row]], np.array([u["f3"]]), 0.0,
                                                        adj[[row]])[0]
        else:  # row 1 of a two-row chain hears the held message: the CACC at h = 0.8 s
            expected = _law(law, "f3", 0.8, True).step(
                obs[[row - 1, row]], np.array([u["f2"], u["f3"]]), 0.0, adj[[row - 1, row]],
                np.array([0, 1]), np.array([0.0, held]))[1]
        assert out[row] == pytest.approx(expected, abs=1e-12)


def test_ttc_reaction_stops_a_lagging_follower_running_into_a_cut_in_human():
    """Real plant, a recorded default event: the human cuts in 0.45 of the gap ahead of follower
    8 and brakes to open his own gap; behind him the degraded CACC (ACC at 1.4 s, no message)
    collides, with the reaction layer (``ttc=2``) it stops short."""
    from carl_sumo.sim.vehicle import REAL_PLANT

    event = next(e for e in load_events("default", "test")
                 if e.event_id == "sumo42_f2500_l2473_fr8486").with_warmup(60.0)
    imp = Impairments(delay_s=0.1, plant=REAL_PLANT)
    manoeuvre = parse_scenario("cut-in:k=7:t=68.2:f=0.45").draw(event, 10)
    collisions = {}
    for name in (ROBUST_HA, ROBUST_HA + ":ttc=2"):
        model, controller = scenario_controller(name, imp.plant_key)
        trace = run_scenario_event(ScenarioSim(NET, model), event, 10, manoeuvre, controller, imp)
        collisions[name] = trace.collisions
    assert collisions == {ROBUST_HA: 1, ROBUST_HA + ":ttc=2": 0}


def test_a_reaction_that_counts_the_braking_ahead_stops_short_of_a_brake_check():
    """Real plant, a recorded default event: the human cuts in ahead of follower 4 and brakes
    hard at once; the reaction that assumes he keeps his speed lets the follower touch him, the
    one that counts his braking as the radar measures it (``rb=1``) stops it short."""
    from carl_sumo.sim.vehicle import REAL_PLANT

    event = next(e for e in load_events("default", "test")
                 if e.event_id == "sumo42_f2591_l2599_fr8959").with_warmup(60.0)
    imp = Impairments(delay_s=0.1, plant=REAL_PLANT)
    manoeuvre = parse_scenario("cut-in:k=3:t=70.4:f=0.54").draw(event, 10)
    collisions = {}
    for name in (ROBUST_HA + ":ttc=2", ROBUST_HA + ":ttc=2:rb=1"):
        model, controller = scenario_controller(name, imp.plant_key)
        trace = run_scenario_event(ScenarioSim(NET, model), event, 10, manoeuvre, controller, imp)
        collisions[name] = trace.collisions
    assert collisions == {ROBUST_HA + ":ttc=2": 1, ROBUST_HA + ":ttc=2:rb=1": 0}


def test_a_joiner_without_room_reacts_although_it_hears_the_chain():
    """Real plant, a recorded default event: a second after the join the joiner is 1.4 m behind
    the vehicle ahead and closing. It hears that vehicle's message, so only its armed reaction
    layer (joining until it has room, scenario_sim.JOIN_LINK_GAP_S) keeps it from colliding."""
    from carl_sumo.sim.vehicle import REAL_PLANT

    event = next(e for e in load_events("default", "test")
                 if e.event_id == "sumo42_f2591_l2599_fr8959").with_warmup(60.0)
    imp = Impairments(delay_s=0.1, plant=REAL_PLANT)
    manoeuvre = parse_scenario("join:k=3:t=70.4:f=0.54").draw(event, 10)
    collisions = {}
    for armed in (False, True):
        model, controller = scenario_controller(ROBUST_HA + ":ttc=2", imp.plant_key)
        if not armed:
            controller.arm = lambda ids: None  # the layer for vehicles without a message only
        sim = ScenarioSim(NET, model)
        trace = run_scenario_event(sim, event, 10, manoeuvre, controller, imp)
        collisions[armed] = trace.collisions
        assert sim.done_step is not None
        if armed:  # 16 s later, at the event's end, it is still opening its gap (2.2 m)
            assert "joiner" in sim.members and sim.joining == {"joiner"}
    assert collisions == {False: 1, True: 0}


# ------------------------------------------------------------------------------ sensor noise
CUT_IN = Manoeuvre("cut-in", 3, 6.0, 0.5)  # the human cuts in ahead of follower 4 ("f3")


def _noisy_run(event, imp: Impairments | None, name: str = "ploeg-tuned:h=0.8"):
    """One cut-in run of ``name`` with impairments ``imp``: its trace."""
    model, controller = scenario_controller(name, "ideal")
    return run_scenario_event(ScenarioSim(NET, model), event, N, CUT_IN, controller, imp)


@pytest.mark.parametrize("filtered", [False, True])
def test_a_scenario_run_with_sensor_noise_is_reproducible_and_noisy(event, filtered):
    """The same noise twice (the event's stream), not the clean run; up to the manoeuvre the
    plain run with the same noise (one stream for both; the first follower's feed-forward is
    the leader's acceleration it measures, as in a plain run)."""
    from carl_sumo.experiments.simulate import resolve_controller, run_event
    from carl_sumo.sim.sumo import PlatoonSim

    imp = Impairments(sensor_noise=True, sensor_filter=filtered)
    first, second, clean = _noisy_run(event, imp), _noisy_run(event, imp), _noisy_run(event, None)
    assert first.collisions == 0 and first.done_step is not None
    np.testing.assert_array_equal(first.speed, second.speed)
    np.testing.assert_array_equal(first.gap, second.gap)
    assert str(score_trace(first)) == str(score_trace(second))  # NaN-safe
    assert np.nanmax(np.abs(first.speed - clean.speed)) > 1e-3
    model, plain_controller = resolve_controller("ploeg-tuned:h=0.8")
    plain = run_event(PlatoonSim(NET, model), event, N, plain_controller, impairments=imp)
    cols = [first.column(f"f{i}") for i in range(N)]
    before = first.done_step
    assert np.abs(first.speed[:before, cols] - plain.speed[:before]).max() < 1e-6
    assert np.abs(first.gap[:before, cols] - plain.gap[:before]).max() < 1e-6


def test_with_sensor_filter_the_follower_behind_a_cut_in_restarts_its_track(event, monkeypatch):
    """Tracks are keyed by vehicle ID and the ID ahead: at the first step f3 has the human
    ahead its estimate is its raw noisy measurement (a fresh track), filtered before and after;
    the controller sees the measurements, the trace is the true gap."""
    import carl_sumo.manoeuvres.runs as scenarios
    from carl_sumo.control.sensors import Sensors

    calls: list[tuple] = []  # (true obs, noisy obs, tracked obs, ids, predecessors)
    made: list = []

    class Recording(Sensors):
        def measure(self, obs, vehicles=None, predecessors=None):
            noisy = []
            estimate = self.tracker.estimate
            self.tracker.estimate = lambda o, v, p: noisy.append(o.copy()) or estimate(o, v, p)
            out = super().measure(obs, vehicles, predecessors)
            del self.tracker.estimate
            calls.append((obs.copy(), noisy[0], out, list(vehicles), list(predecessors)))
            made.append(self)
            return out

    monkeypatch.setattr(scenarios, "Sensors", Recording)
    trace = _noisy_run(event, Impairments(sensor_noise=True, sensor_filter=True))
    assert trace.collisions == 0 and len(calls) == trace.speed.shape[0] - 1
    rows = [ids.index("f3") for *_, ids, _ in calls]
    preds = [p[r] for (*_, p), r in zip(calls, rows)]
    k = preds.index("human")
    assert k > 10 and preds[k - 1] == "f2" and set(preds[k:]) == {"human"}
    for step in (k - 1, k, k + 1):
        _, noisy, out, _, _ = calls[step]
        r = rows[step]
        fresh = np.allclose(out[r, 2:4], [max(noisy[r, 2], 0.01), noisy[r, 3]], atol=1e-12)
        assert fresh == (step == k), step
    true_gap = np.array([c[0][r, 2] for c, r in zip(calls, rows)])
    np.testing.assert_allclose(trace.gap[:len(calls), trace.column("f3")], true_gap, atol=1e-9)
    assert np.abs(np.array([c[2][r, 2] for c, r in zip(calls, rows)]) - true_gap).max() > 0.01
    assert made[-1].tracker._tracks["f3"][0] == "human"  # keyed by vehicle ID, on the human


def test_cli_simulate_and_replay_a_cut_in_with_sensor_noise(capsys, tmp_path):
    """``--scenario`` with ``--sensor-noise --sensor-filter`` runs on simulate and replay."""
    import json

    from carl_sumo.cli import main

    out_json = tmp_path / "noisy.json"
    code = main(["simulate", "--scenario", "cut-in", "--sensor-noise", "--sensor-filter",
                 "--events", "2", "--vehicles", "4", "--controller", "ploeg-tuned:h=0.8",
                 "--workers", "1", "--json", str(out_json)])
    out, err = capsys.readouterr()
    assert code == 0, err
    rows = json.loads(out_json.read_text())["controllers"]
    assert len(rows) == 1 and len(rows[0]["events"]) == 2
    fcd = tmp_path / "noisy.xml"
    code = main(["replay", "--scenario", "cut-in:k=3:t=6", "--event", EVENT_ID, "--vehicles",
                 str(N), "--controller", "ploeg-tuned:h=0.8", "--sensor-noise", "--fcd", str(fcd)])
    out, err = capsys.readouterr()
    assert code == 0 and "done=1" in out and fcd.stat().st_size > 0, err


@pytest.mark.parametrize("kind, fraction", [("cut-in", 0.5), ("join", 0.4)])
def test_an_entering_vehicle_takes_its_share_of_the_gap_as_the_step_leaves_it(event, kind,
                                                                               fraction):
    """SUMO places a new vehicle after it has moved the others: the gap behind the entering
    vehicle right after its insertion is f·(g - L) of the gap g it was given, not a step's
    travel shorter."""
    _, controller = scenario_controller("ploeg-tuned:h=0.8")
    sim = ScenarioSim(NET, "external")
    sim.start(event, N, Manoeuvre(kind, 3, 6.0, fraction))

    def watch(s, ls):
        if s.phase != "inserted" or s.entering not in ls.vehicle.getIDList():
            return None
        lane = ls.vehicle.getLaneID(s.entering)
        front = s.adjacent.lane_starts[s.adjacent.lanes.index(lane)] + \
            ls.vehicle.getLanePosition(s.entering)
        behind, ahead = s.ids[3], s.ids[2]
        length = ls.vehicle.getLength(s.entering)
        return (front - length - s._route_x(ls, behind),
                s._route_x(ls, ahead) - ls.vehicle.getLength(ahead) - front)

    gaps = [g for g in _drive(sim, controller, watch) if g is not None]
    behind, ahead = gaps[0]
    assert behind == pytest.approx(fraction * (behind + ahead), abs=0.05)


@pytest.mark.parametrize("name, wait, phase, inserted", [
    ("ploeg:h=0.6", None, "waiting", None), ("ploeg:h=0.6", 0.0, "no room", None),
    ("ploeg:h=1.5", None, "done", 181), ("ploeg:h=1.5", 0.0, "done", 181)])
def test_with_wait_0_a_cut_in_starts_at_its_time_or_not_at_all(event, name, wait, phase,
                                                                 inserted):
    """``wait=0``: the human enters at t (step 180, in SUMO from the next) if the gap has room
    then, whatever the controller; at h = 0.6 s the gap has no room at t = 18 s, and he stays in
    his lane instead of taking the first room that comes later (none comes in this event)."""
    assert parse_scenario("cut-in:wait=0").wait_s == 0.0
    _, controller = scenario_controller(name)
    sim = ScenarioSim(NET, "external")
    sim.start(event, N, Manoeuvre("cut-in", 3, 18.0, 0.5, wait_s=wait))
    seen = [k for k in _drive(sim, controller, lambda s, ls: s.k if s.phase == "inserted"
                              else None) if k is not None]
    assert sim.phase == phase and (seen[0] if seen else None) == inserted
    assert (sim.done_step is None) == (inserted is None)
