"""The SUMO coupling: exact leader replay, exact application of accelerations, native models."""

import numpy as np
import pytest

from carl_sumo.config import DT_S
from carl_sumo.control.controllers import ZeroAdjustment
from carl_sumo.data.synthetic import stop_and_go_event
from carl_sumo.errors import InputError
from carl_sumo.experiments.simulate import run_event
from carl_sumo.sim.sumo import PlatoonSim, lane_route

from conftest import NET, braking_event


def test_leader_replays_recording_within_1cm():
    import libsumo

    event = stop_and_go_event()
    sim = PlatoonSim(NET, "idm")
    sim.reset(event, 3)
    worst_pos, worst_speed, lanes = 0.0, 0.0, set()
    while not sim.done:
        sim.step()
        recorded = sim._leader_offset + event.leader_pos_m[sim.k]
        worst_pos = max(worst_pos, abs(sim.leader_sumo_position() - recorded))
        worst_speed = max(worst_speed, abs(sim.leader_sumo_speed() - event.leader_speed_mps[sim.k]))
        lanes.add(libsumo.vehicle.getLaneID("leader"))
    assert worst_pos < 0.01 and worst_speed < 1e-9
    assert len(lanes) == 3  # the leader crossed the merge onto the main edge


def test_external_acceleration_applied_exactly_and_lane_kept():
    import libsumo

    sim = PlatoonSim(NET, "external")
    sim.reset(braking_event(), 3)
    rng = np.random.default_rng(0)
    lane0 = [libsumo.vehicle.getLaneIndex(v) for v in sim.ids]
    for _ in range(150):
        v, x = sim.speed.copy(), sim.pos.copy()
        accel = rng.uniform(-4.0, 3.0, size=3)
        sim.step(accel)
        v_next = np.maximum(v + accel * DT_S, 0.0)
        assert np.allclose(sim.speed, v_next, atol=1e-9)
        assert np.allclose(sim.pos, x + v_next * DT_S, atol=1e-6)
    # hard braking to standstill: speed stays at 0, never negative
    for _ in range(40):
        sim.step(np.full(3, -9.0))
    assert np.all(sim.speed == 0.0)
    lanes = [libsumo.vehicle.getLaneID(v) for v in sim.ids]
    assert all(lane.endswith("_4") or lane.endswith("_5") for lane in lanes)
    assert lane0 == [4, 4, 4]


def test_idm_external_matches_native_idm():
    event = braking_event(n=300)
    native = run_event(PlatoonSim(NET, "idm"), event, 5, None)
    external = run_event(PlatoonSim(NET, "external"), event, 5, ZeroAdjustment())
    assert np.abs(native.speed - external.speed).max() < 1e-4
    assert np.abs(native.gap - external.gap).max() < 1e-3


def test_followers_start_at_recorded_speed_and_gap():
    event = braking_event(v0=11.0, gap=17.0)
    sim = PlatoonSim(NET, "krauss")
    sim.reset(event, 4)
    obs = sim.observation()
    assert np.allclose(obs[:, 0], 11.0) and np.allclose(obs[:, 2], 17.0)


def test_krauss_native_runs_without_collision():
    traj = run_event(PlatoonSim(NET, "krauss"), braking_event(), 4, None)
    assert traj.collisions == 0 and traj.speed.shape == (200, 4)


def test_too_short_network_is_refused():
    sim = PlatoonSim(NET, "external")
    long_event = braking_event(n=200)
    object.__setattr__(long_event, "leader_pos_m", long_event.leader_pos_m * 100.0)
    with pytest.raises(InputError, match="too short"):
        sim.reset(long_event, 10)


def test_lane_that_does_not_exist_is_refused():
    with pytest.raises(InputError, match="NGSIM lane 7"):
        lane_route(NET, ngsim_lane=7)


def test_vehicle_types_carry_the_paper_idm_and_explicit_randomness():
    import xml.etree.ElementTree as ET

    from carl_sumo.config import IDM
    from carl_sumo.sim.sumo import VTYPES_FILE

    types = {t.get("id"): t for t in ET.parse(VTYPES_FILE).getroot().iter("vType")}
    assert {"human_krauss", "human_idm", "cacc", "ngsim_leader"} <= set(types)
    idm = types["human_idm"]
    assert idm.get("carFollowModel") == "IDM"
    assert float(idm.get("accel")) == IDM.accel_mps2 and float(idm.get("decel")) == IDM.decel_mps2
    assert float(idm.get("minGap")) == IDM.min_gap_m and float(idm.get("tau")) == IDM.time_headway_s
    assert float(idm.get("delta")) == IDM.delta
    assert abs(float(idm.get("maxSpeed")) - IDM.desired_speed_mps) < 1e-3
    assert types["human_krauss"].get("carFollowModel") == "Krauss"
    for t in types.values():
        assert t.get("sigma") == "0" and t.get("speedDev") == "0"


def test_parallel_workers_give_the_same_metrics():
    from carl_sumo.experiments.simulate import simulate

    events = [braking_event(n=60, event_id=f"e{i}", v0=8.0 + i * 0.1) for i in range(40)]
    one = simulate("idm-external", events, 2, NET, workers=1)
    two = simulate("idm-external", events, 2, NET, workers=2)
    assert one["events"] == two["events"] and one["metrics"] == two["metrics"]


def test_a_warmup_extends_the_leader_backwards_and_is_not_scored():
    from carl_sumo.experiments.simulate import cached_sim, human_trajectory

    event = braking_event(v0=12.0, gap=30.0)
    warm = event.with_warmup(60.0)
    k = 600
    assert warm.scored_from == k and warm.n_samples == event.n_samples + k
    assert np.all(warm.leader_speed_mps[:k + 1] == 12.0)
    np.testing.assert_allclose(np.diff(warm.leader_pos_m), warm.leader_speed_mps[1:] * DT_S)
    np.testing.assert_allclose(warm.leader_pos_m[k:] - warm.leader_pos_m[k], event.leader_pos_m)
    assert event.with_warmup(0.0) is event
    np.testing.assert_array_equal(human_trajectory(warm).speed, human_trajectory(event).speed)
    sim = cached_sim(NET, "idm")
    cold, settled = run_event(sim, event, 4, None), run_event(sim, warm, 4, None)
    assert settled.speed.shape == cold.speed.shape  # the recorded part only
    np.testing.assert_array_equal(settled.leader_speed, event.leader_speed_mps)
    # a 30 m gap at 12 m/s is far below IDM's spacing: without a warm-up the followers brake
    # to open it in the first seconds, with one they start the event settled
    cold_change = np.abs(np.diff(cold.speed[:20], axis=0)).max()
    assert cold_change > 0.05
    assert np.abs(np.diff(settled.speed[:20], axis=0)).max() < 0.05 * cold_change


def test_a_bad_warmup_gets_one_line_and_exit_2(capsys):
    from carl_sumo.cli import main

    assert main(["simulate", "--warmup", "-1"]) == 2
    assert main(["simulate", "--warmup", "0.25"]) == 2
    assert main(["evaluate", "--suite", "robustness", "--warmup", "10", "--quick"]) == 2
    assert main(["train", "--warmup", "0.05", "--steps", "10"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 4 and err.count("multiple of the 0.1 s step") == 2


def test_two_live_platoons_in_one_process_fail_with_one_clear_line():
    """libsumo holds one simulation per process: stepping one environment after another has
    reset SUMO used to corrupt both silently; now it is an InputError (reset again to reuse)."""
    from carl_sumo.data import load_events
    from carl_sumo.errors import InputError
    from carl_sumo.learn.env import PlatoonEnv

    events = load_events("default", "test")[:1]
    a, b = PlatoonEnv(events, 3, NET), PlatoonEnv(events, 3, NET)
    a.reset_array(event=events[0])
    b.reset_array(event=events[0])
    b.step_array(np.zeros(3))
    with pytest.raises(InputError, match="one simulation per process"):
        a.step_array(np.zeros(3))
    a.reset_array(event=events[0])  # a reset takes the simulation back
    a.step_array(np.zeros(3))
