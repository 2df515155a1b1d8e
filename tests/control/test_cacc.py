"""The classical CACC baselines: Ploeg's controller (hand-built cases, names) and SUMO's CACC."""

import json
import math

import numpy as np
import pytest

from carl_sumo.control.cacc import PloegController, PloegParams, parse_ploeg, ploeg_controller
from carl_sumo.config import DT_S
from carl_sumo.data.events import Event
from carl_sumo.data.synthetic import stop_and_go_event
from carl_sumo.errors import InputError
from carl_sumo.sim.metrics import score_event
from carl_sumo.experiments.simulate import cached_sim, resolve_controller, run_event

from conftest import NET


def _cruise(n: int, v: float, gap: float) -> Event:
    speed = np.full(n, v)
    pos = np.arange(n) * v * DT_S
    return Event("cruise", "zhu2020_testset", "i-80", pos, speed, 5.0, speed.copy(),
                 np.full(n, gap))


def test_ploeg_at_equilibrium_stays_put_in_sumo():
    # h = 1 s, s0 = 2 m: at 15 m/s the equilibrium gap is 17 m; nothing may move
    v, gap = 15.0, 2.0 + 1.0 * 15.0
    sim = cached_sim(NET, "external")
    traj = run_event(sim, _cruise(300, v, gap), 4, ploeg_controller("ploeg"))
    assert traj.collisions == 0
    assert np.abs(traj.speed - v).max() < 1e-9
    assert np.abs(traj.gap - gap).max() < 1e-6


def test_ploeg_hand_computed_step():
    c = PloegController(PloegParams(time_gap_s=0.8, kp=0.2, kd=0.7))
    c.reset(2)
    # follower 0: v 10, a 0.5, gap 12, Δv -1; follower 1 at its equilibrium, u = 0
    obs = np.array([[10.0, 0.5, 12.0, -1.0], [10.0, 0.0, 10.0, 0.0]])
    a = c.acceleration(obs)
    e0, e0_dot = 12.0 - 2.0 - 0.8 * 10.0, -1.0 - 0.8 * 0.5
    u0 = (DT_S / 0.8) * (0.2 * e0 + 0.7 * e0_dot + 0.0)  # first step: leader acceleration 0
    assert math.isclose(a[0], u0, rel_tol=1e-12) and a[1] == 0.0
    assert math.isclose(c.u[0], u0, rel_tol=1e-12)


def test_leader_acceleration_step_reaches_followers_through_messages():
    # every follower at equilibrium; the leader starts accelerating at 1 m/s² after step 0
    h, v = 1.0, 10.0
    c = PloegController(PloegParams(time_gap_s=h))
    c.reset(3)
    eq = [v, 0.0, 2.0 + h * v, 0.0]
    first = c.acceleration(np.array([eq, eq, eq]))
    assert np.all(first == 0.0)
    # next step the leader is 0.1 m/s faster (a_lead = 1 m/s²), gaps unchanged so far
    obs = np.array([[v, 0.0, 2.0 + h * v, 0.1], eq, eq])
    a1 = c.acceleration(obs)
    # follower 0 gets the leader's acceleration as feed-forward plus the Δv term
    assert math.isclose(a1[0], (DT_S / h) * (0.7 * 0.1 + 1.0), rel_tol=1e-12)
    assert a1[1] == 0.0 and a1[2] == 0.0  # messages carry the last state: one step per vehicle
    a2 = c.acceleration(np.array([[v, a1[0], 2.0 + h * v, 0.1 + (1.0 - a1[0]) * DT_S], eq, eq]))
    assert a2[1] > 0.0 and a2[2] == 0.0  # follower 1 hears follower 0's u of the last step
    assert math.isclose(a2[1], (DT_S / h) * a1[0], rel_tol=1e-12)


def test_ploeg_follows_a_braking_leader_in_sumo_without_collision():
    sim = cached_sim(NET, "external")
    _, controller = resolve_controller("ploeg:h=0.6")
    m = score_event(run_event(sim, stop_and_go_event(cycles=1, cruise_s=5.0), 5, controller))
    assert m["collisions"] == 0


def test_sumo_cacc_platoon_on_stop_and_go_has_no_collision():
    model, controller = resolve_controller("sumo-cacc")
    assert model == "sumo-cacc" and controller is None
    traj = run_event(cached_sim(NET, model), stop_and_go_event(), 10, None)
    m = score_event(traj)
    assert m["collisions"] == 0 and (traj.gap > 0).all()
    assert traj.speed.shape[0] == stop_and_go_event().n_samples  # ran to the end
    assert m["headway_s"] < 1.5  # SUMO's CACC follows closer than IDM (1.5 s time gap)


@pytest.mark.parametrize("name, params", [
    ("ploeg", PloegParams(1.0, 0.2, 0.7)),
    ("ploeg:h=0.8", PloegParams(0.8, 0.2, 0.7)),
    ("ploeg:h=0.8:kp=0.1:kd=1.5", PloegParams(0.8, 0.1, 1.5)),
    ("ploeg:kd=1:h=1.2", PloegParams(1.2, 0.2, 1.0)),
])
def test_ploeg_names(name, params):
    assert parse_ploeg(name) == params


@pytest.mark.parametrize("name, words", [
    ("ploeg:h=abc", "not a number"), ("ploeg:h=-1", "positive"), ("ploeg:x=1", "not an option"),
    ("ploeg:h", "not an option"), ("ploeg:h=1:h=2", "twice"), ("ploeg:h=nan", "positive"),
    ("ploeg-tuned", "name the time gap"), ("ploeg-tuned:kp=1", "not an option"),
])
def test_bad_ploeg_names_are_input_errors(name, words):
    with pytest.raises(InputError, match=words):
        resolve_controller(name)


def test_ploeg_tuned_reads_the_file_and_names_the_existing_gaps(tmp_path):
    path = tmp_path / "tuned.json"
    path.write_text(json.dumps({"entries": [{"h": 0.8, "kp": 0.15, "kd": 1.1},
                                            {"h": 1.0, "kp": 0.1, "kd": 0.9}]}))
    assert parse_ploeg("ploeg-tuned:h=0.8", path) == PloegParams(0.8, 0.15, 1.1)
    with pytest.raises(InputError, match=r"h = 0.8, 1 s only"):
        parse_ploeg("ploeg-tuned:h=0.6", path)
    with pytest.raises(InputError, match="tune ploeg"):
        parse_ploeg("ploeg-tuned:h=0.8", tmp_path / "missing.json")


def test_tune_on_a_tiny_grid_writes_gains_that_ploeg_tuned_reads(capsys, tmp_path,
                                                                  small_table_path):
    from carl_sumo.cli import main

    out = tmp_path / "tuned.json"
    code = main(["tune", "ploeg", "--data", str(small_table_path), "--split", "train",
                 "--vehicles", "3", "--gaps", "1.0,0.8", "--kp", "0.1,0.2", "--kd", "0.7,1.0",
                 "--max-extensions", "1", "--workers", "1", "--out", str(out)])
    printed = capsys.readouterr().out
    assert code == 0 and "| 1 |" in printed
    assert out.with_suffix(".png").read_bytes()[:4] == b"\x89PNG"
    payload = json.loads(out.read_text())
    assert payload["split"] == "train" and payload["events"] == 1 and payload["objective"]
    by_h = {e["h"]: e for e in payload["entries"]}
    assert set(by_h) == {1.0, 0.8}
    for h, entry in by_h.items():
        points = [g for g in payload["grid"] if g["h"] == h]
        assert len(points) >= 4 and any(g["kp"] == 0.2 and g["kd"] == 0.7 for g in points)
        if entry["kp"] is not None:  # the chosen point is the safe one with the least objective
            safe = [g for g in points if g["safe"]]
            assert entry["objective"] == min(g["objective"] for g in safe)
            assert parse_ploeg(f"ploeg-tuned:h={h:g}", out) == PloegParams(h, entry["kp"],
                                                                           entry["kd"])
    textbook = next(g for g in payload["grid"] if g["h"] == 1.0 and g["kp"] == 0.2
                    and g["kd"] == 0.7)
    assert math.isclose(textbook["objective"], 2.0)
    for g in payload["grid"]:  # safe: as safe as the textbook gains at the same h
        ref = next(t for t in payload["grid"]
                   if t["h"] == g["h"] and (t["kp"], t["kd"]) == (0.2, 0.7))
        assert g["safe"] == (g["collisions"] == 0 and g["ttc_lt_1_5s_count"] <= ref[
            "ttc_lt_1_5s_count"] and g["headway_s"] <= 1.05 * ref["headway_s"])
    # a second run that reuses the first one's points simulates nothing and chooses the same
    again = tmp_path / "again.json"
    assert main(["tune", "ploeg", "--data", str(small_table_path), "--split", "train",
                 "--vehicles", "3", "--gaps", "1.0,0.8", "--kp", "0.1,0.2", "--kd", "0.7,1.0",
                 "--max-extensions", "1", "--workers", "1", "--reuse", str(out),
                 "--out", str(again)]) == 0
    second = json.loads(again.read_text())
    assert second["entries"] == payload["entries"]
    assert main(["tune", "ploeg", "--data", str(small_table_path), "--split", "train",
                 "--vehicles", "2", "--reuse", str(out), "--out", str(again)]) == 2
    assert "other events or another platoon" in capsys.readouterr().err


@pytest.mark.parametrize("argv, words", [
    (["--split", "test"], "not allowed"),
    (["--kp", "0.1,x"], "--kp must be positive"),
    (["--gaps", "-1"], "--gaps must be positive"),
    (["--out", "/proc/nope/t.json"], "cannot write"),
])
def test_tune_bad_input_exits_2_before_running(capsys, tmp_path, small_table_path, argv, words):
    from carl_sumo.cli import main

    base = ["tune", "ploeg", "--data", str(small_table_path), "--out", str(tmp_path / "t.json")]
    assert main(base + argv) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1
    assert not (tmp_path / "t.json").exists()


def test_ploeg_chains_keep_state_by_vehicle_and_take_the_heads_predecessor_acceleration():
    from carl_sumo.control.cacc import PloegChains

    chains = PloegChains(PloegParams(time_gap_s=1.0))
    eq = [10.0, 0.0, 12.0, 0.0]  # at its equilibrium gap 2 + 1.0·10
    obs = np.array([eq, eq, eq])
    ahead = [("x", 12.0), ("a", 12.0), ("y", 12.0)]  # x and y are humans
    a = chains.acceleration(obs, [[0, 1], [2]], ["a", "b", "c"], ahead, {"x": 0.0, "y": 2.0})
    assert a[0] == 0.0 and a[1] == 0.0  # chain head: predecessor's acceleration 0
    assert math.isclose(a[2], DT_S * 2.0)  # head of the second chain hears 2 m/s² ahead
    # a new vehicle d, with nobody ahead, now leads c: d starts at u = 0, c hears d's state 0
    a = chains.acceleration(obs[:2], [[1, 0]], ["c", "d"], [("d", 12.0), None], {})
    assert math.isclose(a[0], 0.2 - DT_S * 0.2) and a[1] == 0.0
    assert set(chains.u) == {"c", "d"}  # vehicles that left are forgotten


def test_ploeg_cruise_cap_on_a_free_road():
    c = PloegController(PloegParams(time_gap_s=1.0))
    c.reset(1)
    for _ in range(50):  # 300 m to the vehicle ahead at the desired speed: no acceleration
        a = c.acceleration(np.array([[120 / 3.6, 0.0, 300.0, 0.0]]))
    assert abs(a[0]) < 1e-12 and abs(c.u[0]) < 1e-12


def test_cli_runs_classical_controllers_and_refuses_bad_names(capsys, tmp_path, small_table_path):
    from carl_sumo.cli import main

    code = main(["simulate", "--controller", "sumo-cacc,ploeg:h=0.8,ploeg:h=1:kp=0.1:kd=1.5",
                 "--data", str(small_table_path), "--vehicles", "3"])
    out = capsys.readouterr().out
    assert code == 0
    assert [line.split()[0] for line in out.splitlines()[2:5]] == [
        "sumo-cacc", "ploeg:h=0.8", "ploeg:h=1:kp=0.1:kd=1.5"]
    fcd = tmp_path / "p.xml"
    assert main(["replay", "--controller", "ploeg:h=0.8", "--event", "ev_test_0", "--data",
                 str(small_table_path), "--vehicles", "2", "--fcd", str(fcd)]) == 0
    assert fcd.stat().st_size > 1000
    capsys.readouterr()
    json_out = tmp_path / "x.json"
    assert main(["simulate", "--controller", "idm,ploeg:kp=zero", "--data",
                 str(small_table_path), "--json", str(json_out)]) == 2
    err = capsys.readouterr().err
    assert "kp='zero' is not a number" in err and err.count("\n") == 1
    assert not json_out.exists()


def test_aw_names_a_law_whose_states_stay_within_each_vehicles_own_limits():
    """``aw=1``: the state (the command, and the message the follower hears) of a truck that
    cannot accelerate beyond 1 m/s² stays at 1 m/s², while the car ahead of it may command 3;
    without ``aw`` the limits are ignored and the law is what it was, bit for bit."""
    from carl_sumo.control.cacc import PloegController, parse_ploeg

    params = parse_ploeg("ploeg:h=0.8:kp=0.2:kd=0.7:aw=1")
    assert params.anti_windup and params.name() == "ploeg:h=0.8:kp=0.2:kd=0.7:aw=1"
    assert not parse_ploeg("ploeg:h=0.8").anti_windup
    with pytest.raises(InputError, match="aw takes 1"):
        parse_ploeg("ploeg:h=0.8:aw=2")
    # both followers far behind: the law asks for a large acceleration
    obs = np.array([[10.0, 0.0, 80.0, 3.0], [10.0, 0.0, 80.0, 3.0]])
    plain, aware = PloegController(parse_ploeg("ploeg:h=0.8")), PloegController(params)
    for law in (plain, aware):
        law.reset(2)
        law.know_vehicles(np.array([3.0, 1.0]), np.array([9.0, 6.0]))
        for _ in range(30):
            law.step(obs, law.u, 0.0)
    assert aware.u[1] == 1.0 and aware.u[0] <= 3.0
    assert plain.u[1] > 1.5  # the plain law winds up beyond what a truck can do
    reference = PloegController(parse_ploeg("ploeg:h=0.8"))
    reference.reset(2)
    for _ in range(30):
        reference.step(obs, reference.u, 0.0)
    np.testing.assert_array_equal(reference.u, plain.u)


def test_chains_keep_each_known_vehicles_state_within_its_limits_with_aw():
    """The study's chains: with ``aw=1`` a truck's state (its message) stays within its own
    limits by vehicle ID; without ``aw`` or for an unknown vehicle nothing is clipped."""
    from carl_sumo.control.cacc import PloegChains

    obs = np.array([[10.0, 0.0, 80.0, 3.0], [10.0, 0.0, 80.0, 3.0]])
    chains, ids, ahead = [[0, 1]], ["car", "truck"], [("leader", 80.0), ("car", 80.0)]
    runs = {}
    for name in ("ploeg:h=0.8:aw=1", "ploeg:h=0.8"):
        law = PloegChains(parse_ploeg(name), name)
        law.reset()
        law.know_vehicle("truck", 1.0, 6.0)
        for _ in range(30):
            law.acceleration(obs, chains, ids, ahead, {})
        runs[name] = law.u
    assert runs["ploeg:h=0.8:aw=1"]["truck"] == 1.0
    assert runs["ploeg:h=0.8"]["truck"] > 1.5
    assert runs["ploeg:h=0.8:aw=1"]["car"] == runs["ploeg:h=0.8"]["car"]


def test_ha_degrades_a_vehicle_without_a_message_to_an_acc_at_the_longer_gap():
    """``ha=T``: the head (no message from a human leader) and a follower that hears nothing run
    the law at the time gap T; a follower that hears its predecessor keeps h. Without ``ha``
    the law is what it was."""
    params = parse_ploeg("ploeg:h=0.8:kp=0.2:kd=0.7:aw=1:ha=1.4")
    assert params.alone_gap_s == 1.4 and params.gap_alone_s == 1.4
    assert params.name() == "ploeg:h=0.8:kp=0.2:kd=0.7:aw=1:ha=1.4"
    assert parse_ploeg("acc:h=2:ha=3").gap_alone_s == 2.0  # an ACC has one gap: its own
    assert parse_ploeg("ploeg:h=0.8").gap_alone_s == 0.8
    with pytest.raises(InputError, match="ha must be a positive"):
        parse_ploeg("ploeg:h=0.8:ha=0")
    # three followers at 10 m/s, each at s0 + 1.4·v = 16 m: the head and a follower without
    # a message are at their equilibrium (u stays 0); the one with a message is 6 m long
    obs = np.array([[10.0, 0.0, 16.0, 0.0]] * 3)
    law = PloegController(params)
    law.reset(3)
    law.step(obs, law.u, 0.0, pred_mode=np.array([0, 2, 0]), pred_held=np.zeros(3))
    assert law.u[0] == 0.0 and law.u[1] == 0.0
    assert math.isclose(law.u[2], (DT_S / 0.8) * 0.2 * (16.0 - 2.0 - 8.0), rel_tol=1e-12)
    plain, reference = PloegController(parse_ploeg("ploeg:h=0.8")), \
        PloegController(PloegParams(time_gap_s=0.8))
    for law in (plain, reference):
        law.reset(3)
        law.step(obs, law.u, 0.0)
    np.testing.assert_array_equal(plain.u, reference.u)
    assert plain.u[0] > 0.0


def _law_and_plain_step(law_name: str, plain_name: str, obs: np.ndarray, mode: np.ndarray):
    """One step of a law and of the same law without its layer on ``obs`` (3 vehicles, modes
    ``mode``): (law, plain, law's a, plain's a, law's brake)."""
    plain = PloegController(parse_ploeg(plain_name))
    law = PloegController(parse_ploeg(law_name))
    for c in (plain, law):
        c.reset(3)
    a_plain = plain.step(obs, plain.u, 0.0, pred_mode=mode, pred_held=np.zeros(3))
    brake = np.full(3, np.inf)
    a = law.step(obs, law.u, 0.0, pred_mode=mode, pred_held=np.zeros(3), brake=brake)
    return law, plain, a, a_plain, brake


def test_ttc_reaction_brakes_a_vehicle_without_a_message_at_once_and_tells_its_follower():
    """``ttc=T``: below a time to collision T, a vehicle that hears no message applies at most
    -c²/(2·(d - 1 - 0.5·c)) and sends it; its state stays the law's. A follower that hears its
    predecessor, and every vehicle above T, is left to the law."""
    params = parse_ploeg("ploeg:h=0.8:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2")
    assert params.reaction_ttc_s == 2.0 and params.name().endswith(":ha=1.4:ttc=2")
    with pytest.raises(InputError, match="ttc must be a positive"):
        parse_ploeg("ploeg:h=0.8:ttc=0")
    # the head closes at 2.5 m/s with 4 m of gap (TTC (4 - 1)/2.5 = 1.2 s); followers 1 and 2
    # close as fast, 1 on its predecessor's message, 2 without one
    obs = np.array([[8.5, 0.0, 4.0, -2.5]] * 3)
    mode = np.array([0, 0, 2])
    law, plain, a, a_plain, brake = _law_and_plain_step(
        params.name(), "ploeg:h=0.8:kp=0.0445:kd=1:aw=1:ha=1.4", obs, mode)
    need = 2.5 ** 2 / (2.0 * (4.0 - 1.0 - 0.5 * 2.5))
    assert math.isclose(a[0], -need, rel_tol=1e-12) and math.isclose(a[2], -need, rel_tol=1e-12)
    assert a[1] == a_plain[1] > -need  # it hears a message: no reaction
    np.testing.assert_array_equal(law.u, plain.u)  # the states are the law's
    np.testing.assert_allclose(np.minimum(law.u, brake), [-need, a_plain[1], -need], rtol=1e-12)
    # the next step, follower 1 hears the head's braking, not its state
    a_next = law.step(obs, law.u, 0.0, pred_mode=mode, pred_held=np.zeros(3), brake=brake)
    a_plain_next = plain.step(obs, plain.u, 0.0, pred_mode=mode, pred_held=np.zeros(3))
    assert math.isclose(a_next[1] - a_plain_next[1], (DT_S / 0.8) * (-need - a_plain[0]),
                        rel_tol=1e-9)
    # no room left (d - 1 m ≤ 0.5 s·c): the most braking its vehicle can (aw: its own limit)
    law.reset(1)
    law.know_vehicles(np.array([1.0]), np.array([6.0]))
    assert law.step(np.array([[8.5, 0.0, 2.0, -2.5]]), law.u, 0.0)[0] == -6.0
    # a time to collision above T, or opening: the law alone
    for row in ([8.5, 0.0, 9.0, -2.5], [8.5, 0.0, 2.0, 0.5]):
        for c in (plain, law):
            c.reset(1)
        one = np.array([row])
        assert law.step(one, law.u, 0.0)[0] == plain.step(one, plain.u, 0.0)[0]


def test_gs_keeps_gipps_safe_speed_behind_a_vehicle_without_a_message():
    """``gs=B``: a vehicle that hears no message applies at most (v_safe - v)/0.5 s, v_safe =
    -B·0.5 + sqrt((B·0.5)² + v_ahead² + 2·B·(d - 1 m)), the speed from which it stops behind the
    vehicle ahead when both brake at B after 0.5 s of lag (Gipps 1981), and tells its follower.
    At its own time gap, or hearing a message, it is left to the law."""
    params = parse_ploeg("ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4:gs=6")
    assert params.safe_braking_mps2 == 6.0 and params.name().endswith(":ha=1.4:gs=6")
    with pytest.raises(InputError, match="gs must be a positive"):
        parse_ploeg("ploeg:h=0.6:gs=0")
    # a human cut in 2.96 m ahead at 12.17 m/s (the recorded case of docs/scenarios.md): the
    # head (no message), follower 1 (a message) and follower 2 (none) behind such a gap at 12.32
    obs = np.array([[12.32, 0.0, 2.96, -0.15]] * 3)
    mode = np.array([0, 0, 2])
    law, plain, a, a_plain, brake = _law_and_plain_step(
        params.name(), "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4", obs, mode)
    v_safe = -3.0 + math.sqrt(9.0 + 12.17 ** 2 + 2.0 * 6.0 * 1.96)
    assert math.isclose(v_safe, 10.44, abs_tol=0.01)
    expected = (v_safe - 12.32) / 0.5
    assert math.isclose(a[0], expected, rel_tol=1e-12) and math.isclose(a[2], expected,
                                                                        rel_tol=1e-12)
    assert a[1] == a_plain[1] and a_plain[0] > -1.0 > expected  # the law alone: -0.2 m/s²
    np.testing.assert_array_equal(law.u, plain.u)
    assert brake[0] == brake[2] == expected and brake[1] == np.inf
    # at the head's own gap (2 m + 1.4 s·v) and speed: far from the bound, the law alone
    steady = np.array([[12.0, 0.0, 2.0 + 1.4 * 12.0, 0.0]])
    for c in (plain, law):
        c.reset(1)
    assert law.step(steady, law.u, 0.0)[0] == plain.step(steady, plain.u, 0.0)[0]


def test_gn_keeps_the_safe_speed_only_for_an_armed_vehicle():
    """``gn=B``: the bound of ``gs=B`` for an armed vehicle at the front of its chain only (its
    new vehicle ahead is no member it hears: a human who cut in); a vehicle without a message
    that is not armed, an armed vehicle that hears its predecessor, and an armed one in a chain
    whose predecessor's first message has not arrived yet (behind a joiner, the V2V delay) are
    left to the law. gs and gn together: one line."""
    params = parse_ploeg("ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4:gn=6")
    assert params.safe_new_only and params.name().endswith(":ha=1.4:gn=6")
    with pytest.raises(InputError, match="not both"):
        parse_ploeg("ploeg:h=0.6:gs=6:gn=6")
    obs = np.array([[12.32, 0.0, 2.96, -0.15]] * 3)
    mode = np.array([0, 0, 2])
    law, plain, a, a_plain, _ = _law_and_plain_step(
        params.name(), "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4", obs, mode)
    np.testing.assert_array_equal(a, a_plain)  # nobody armed: the law alone
    _, _, a_gs, _, _ = _law_and_plain_step(
        params.name().replace(":gn=", ":gs="), "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4", obs, mode)
    for c in (law, plain):
        c.reset(3)
    armed = np.array([True, True, True])
    a = law.step(obs, law.u, 0.0, pred_mode=mode, pred_held=np.zeros(3), armed=armed)
    a_plain = plain.step(obs, plain.u, 0.0, pred_mode=mode, pred_held=np.zeros(3), armed=armed)
    assert a[0] == a_gs[0] < a_plain[0]  # the chain's front, armed: bounded
    assert a[1] == a_plain[1] > a_gs[2]  # armed with a message: the law's (gs: bounded)
    assert a[2] == a_plain[2] > a_gs[2]  # armed, its message on the way: the law's (gs: bounded)


def test_op_opens_the_gap_of_an_armed_chain_front_at_a_bounded_braking():
    """``op=B``: an armed vehicle at the front of its chain, short of 2 m + 0.8 s·v, asks for an
    opening speed of the missing gap over 3 s and brakes toward it with a 1 s time constant, at
    most B; it tells its follower. Unarmed, at its 0.8 s gap, or hearing its predecessor, it is
    left to the law; the law's state is left as it is."""
    base = "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2:rb=1:gn=6"
    params = parse_ploeg(base + ":op=2")
    assert params.opening_braking_mps2 == 2.0 and params.name() == base + ":op=2"
    with pytest.raises(InputError, match="op must be a positive"):
        parse_ploeg(base + ":op=-1")
    # a signalling human 12 m ahead of the head at 15 m/s, 0.3 m/s faster; follower 1 hears the
    # head, follower 2 (a message on its way) is as short: 2 + 0.8·15 - 12 = 2 m short
    obs = np.array([[15.0, 0.0, 12.0, 0.3]] * 3)
    mode = np.array([0, 0, 2])
    law, plain, a, a_plain, _ = _law_and_plain_step(params.name(), base, obs, mode)
    np.testing.assert_array_equal(a, a_plain)  # nobody armed: the law alone
    for c in (law, plain):
        c.reset(3)
    armed = np.array([True, True, True])
    brake = np.full(3, np.inf)
    a = law.step(obs, law.u, 0.0, pred_mode=mode, pred_held=np.zeros(3), brake=brake,
                 armed=armed)
    a_plain = plain.step(obs, plain.u, 0.0, pred_mode=mode, pred_held=np.zeros(3), armed=armed)
    expected = (0.3 - 2.0 / 3.0) / 1.0
    assert math.isclose(a[0], expected, rel_tol=1e-12) and a_plain[0] > expected
    assert brake[0] == a[0]  # its follower hears the opening
    assert a[1] == a_plain[1] and a[2] == a_plain[2]  # not a chain's front: the law's
    np.testing.assert_array_equal(law.u, plain.u)
    far = np.array([[15.0, 0.0, 8.0, -0.5]])  # 6 m short, closing at 0.5 m/s: -2.5, at most B
    close = PloegController(params)
    close.reset(1)
    assert close.step(far, close.u, 0.0, armed=np.array([True]))[0] == -2.0
    room = np.array([[15.0, 0.0, 2.0 + 0.8 * 15.0 + 0.1, 0.0]])  # at its 0.8 s: the law's
    for c in (close, plain):
        c.reset(1)
    assert close.step(room, close.u, 0.0, armed=np.array([True]))[0] == \
        plain.step(room, plain.u, 0.0, armed=np.array([True]))[0]


def test_a_law_with_gn_reaches_a_zipper_merge_point_behind_the_vehicle_ahead():
    """``merge_m`` (a zipper merge; the vehicle ahead is still on the other feeding lane): a law
    with ``gn``/``gs`` applies at most 2·(d - s0 + Δv·t)/t², t = R/v, so that it reaches the
    merge point R ahead s0 behind that vehicle, and tells its follower; without ``gn``/``gs``
    (the law at 0.8 s with its reaction layer) nothing changes. The recorded case of
    docs/study.md: a car whose bumper gap to a truck beside it is -4.2 m, 1.1 m/s slower; the law
    alone asks for less than 0.2 m/s² either way, and the car reached the merge point alongside."""
    product = "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2:rb=1:wo=5:gn=6:op=2:ht=0.8"
    law = PloegController(parse_ploeg(product))
    obs = np.array([[32.2, 0.0, 30.0, 0.0], [31.1, 0.0, -4.2, 1.1]])  # truck, car
    mode, held = np.zeros(2, dtype=np.int64), np.zeros(2)
    out = {}
    for rest in (np.inf, 57.0):  # no merge point; 57 m before it (the recorded case)
        law.reset(2)
        brake = np.full(2, np.inf)
        out[rest] = law.step(obs, law.u, 0.0, pred_mode=mode, pred_held=held, brake=brake,
                             merge_m=np.array([np.inf, rest]))
        assert brake[1] == (out[rest][1] if rest < np.inf else np.inf)  # its follower hears it
        assert out[rest][0] == out[np.inf][0]
    assert abs(out[np.inf][1]) < 0.2  # the law alone
    t = 57.0 / 31.1
    assert math.isclose(out[57.0][1], 2.0 * (-4.2 - 2.0 + 1.1 * t) / t ** 2, rel_tol=1e-12)
    assert out[57.0][1] < -2.0  # late: hard
    # the same car 8.8 m further back at the start of the 300 m merging lane: a gentle braking
    early = obs.copy()
    early[1, 2] = -13.0
    law.reset(2)
    a = law.step(early, law.u, 0.0, pred_mode=mode, pred_held=held,
                 merge_m=np.array([np.inf, 300.0]))
    t = 300.0 / 31.1
    assert math.isclose(a[1], 2.0 * (-13.0 - 2.0 + 1.1 * t) / t ** 2, rel_tol=1e-12)
    assert -0.1 < a[1] < 0.0
    law.reset(2)  # where the gap opens in time by itself (-4.2 m, 300 m ahead): the law's
    assert np.array_equal(law.step(obs, law.u, 0.0, pred_mode=mode, pred_held=held,
                                   merge_m=np.array([np.inf, 300.0])), out[np.inf])
    plain = PloegController(parse_ploeg("ploeg:h=0.8:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2:rb=1"))
    for rest in (np.inf, 57.0):
        plain.reset(2)
        out[rest] = plain.step(obs, plain.u, 0.0, pred_mode=mode, pred_held=held,
                               merge_m=np.array([np.inf, rest]))
    np.testing.assert_array_equal(out[57.0], out[np.inf])


def test_ht_gives_a_heavy_vehicle_its_own_time_gap_in_the_chain():
    """``ht=T`` (with ``aw=1``): a vehicle whose own braking is below 7 m/s² (a truck, 6) keeps
    the time gap T in its chain, a car the law's h; the head, which hears no message, keeps ha.
    Each at rest at its own gap (no error, no relative speed) applies 0."""
    base = "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4"
    params = parse_ploeg(base + ":ht=0.8")
    assert params.heavy_gap_s == 0.8 and params.name() == base + ":ht=0.8"
    # the one rule (ploeg_names.chain_gap_s) the kernel keeps inline: max(h, ht) for a known
    # heavy vehicle, h for a car, for an unknown braking, and without aw=1
    assert (params.chain_gap_s(6.0), params.chain_gap_s(9.0), params.chain_gap_s(None)) == \
        (0.8, 0.6, 0.6)
    assert parse_ploeg(base.replace("h=0.6", "h=1") + ":ht=0.8").chain_gap_s(6.0) == 1.0
    assert parse_ploeg(base.replace(":aw=1", "") + ":ht=0.8").chain_gap_s(6.0) == 0.6
    v = 15.0
    obs = np.array([[v, 0.0, 2.0 + 1.4 * v, 0.0], [v, 0.0, 2.0 + params.chain_gap_s(6.0) * v, 0.0],
                    [v, 0.0, 2.0 + params.chain_gap_s(9.0) * v, 0.0]])  # head, a truck, a car
    out = {}
    for name in (base, base + ":ht=0.8"):
        law = PloegController(parse_ploeg(name))
        law.reset(3)
        law.know_vehicles(np.array([3.0, 1.0, 3.0]), np.array([9.0, 6.0, 9.0]))
        out[name] = law.step(obs, law.u, 0.0)
    np.testing.assert_array_equal(out[base + ":ht=0.8"], [0.0, 0.0, 0.0])
    assert out[base][1] > 0.0 and out[base][0] == out[base][2] == 0.0  # at 0.6 s it closes in
    law = PloegController(params)  # limits unknown (no aw data): every vehicle at h
    law.reset(3)
    np.testing.assert_array_equal(law.step(obs, law.u, 0.0), out[base])


def test_an_armed_vehicle_reacts_although_it_hears_a_message():
    """``armed`` (a joiner without room yet): the reaction acts on a follower that hears its
    predecessor; unarmed, the same follower is left to the law; the head is unchanged."""
    law = PloegController(parse_ploeg("ploeg:h=0.8:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2"))
    obs = np.array([[8.5, 0.0, 20.0, 0.0], [8.5, 0.0, 4.0, -2.5]])
    out = {}
    for armed in (None, np.array([False, True])):
        law.reset(2)
        out[armed is None] = law.step(obs, law.u, 0.0, armed=armed)
    need = 2.5 ** 2 / (2.0 * (4.0 - 1.0 - 0.5 * 2.5))
    assert out[True][1] > -need and math.isclose(out[False][1], -need, rel_tol=1e-12)
    assert out[True][0] == out[False][0]


def test_the_reaction_adds_the_braking_of_the_vehicle_ahead_as_the_radar_measures_it():
    """``rb=1``: the reaction stops the closing in while the vehicle ahead brakes,
    -c²/(2·room) - b_ahead, b_ahead from the change of Δv over the step plus the vehicle's own
    acceleration; without it the vehicle ahead counts as keeping its speed."""
    name = "ploeg:h=0.8:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2"
    params = parse_ploeg(name + ":rb=1")
    assert params.reaction_braking_ahead and params.name() == name + ":rb=1"
    assert not parse_ploeg(name).reaction_braking_ahead
    with pytest.raises(InputError, match="rb takes 1"):
        parse_ploeg(name + ":rb=2")
    plain = PloegController(parse_ploeg(name))
    plain.reset(1)
    plain.acceleration(np.array([[8.5, 0.0, 4.0, -2.0]]))
    law = PloegController(params)
    law.reset(1)
    law.acceleration(np.array([[8.5, 0.0, 4.0, -2.0]]))  # Δv -2 m/s; no history yet: b = 0
    need = 2.5 ** 2 / (2.0 * (3.8 - 1.0 - 0.5 * 2.5))
    # a step later Δv is -2.5 and the own acceleration -1: the vehicle ahead braked at 6 m/s²
    a = law.acceleration(np.array([[8.4, -1.0, 3.8, -2.5]]))[0]
    assert math.isclose(a, -(need + 6.0), rel_tol=1e-9)
    assert math.isclose(plain.acceleration(np.array([[8.4, -1.0, 3.8, -2.5]]))[0], -need,
                        rel_tol=1e-9)
    law.reset(1)  # without the history the vehicle ahead counts as keeping its speed
    assert math.isclose(law.acceleration(np.array([[8.4, -1.0, 3.8, -2.5]]))[0], -need,
                        rel_tol=1e-9)


def test_ttc_reaction_keeps_the_platoon_of_a_close_start_apart_in_sumo():
    """A settled start from a recorded gap of 3.9 m closing at 2.5 m/s on the real plant: the
    degraded head without the reaction brakes too late; with it no follower collides."""
    from carl_sumo.control.channel import Impairments
    from carl_sumo.sim.vehicle import Plant, parse_fleet

    n, v_lead, v0, gap0, steps = 10, 6.09, 8.55, 3.93, 200
    event = Event("close_start", "synthetic", "none", v_lead * DT_S * np.arange(steps),
                  np.full(steps, v_lead), 5.0, np.full(steps, v0), np.full(steps, gap0),
                  dt=DT_S).with_warmup(10.0)
    sim = cached_sim(NET, "external")
    imp = Impairments(delay_s=0.1, plant=Plant(parse_fleet("truck:1")))  # a truck at its head
    base = "ploeg:h=0.8:kp=0.0445:kd=1:aw=1:ha=1.4"
    runs = {name: run_event(sim, event, n, ploeg_controller(name), impairments=imp)
            for name in (base, base + ":ttc=2")}
    assert runs[base].collisions > 0
    assert runs[base + ":ttc=2"].collisions == 0


def test_gn_never_acts_in_a_plain_run_where_gs_does():
    """The close start above (3.9 m, closing at 2.5 m/s, real plant): ``gs=6`` bounds the head's
    speed, ``gn=6`` (and ``op=2`` with it) arms nobody in a plain run, so it drives exactly as the
    law without it."""
    from carl_sumo.control.channel import Impairments
    from carl_sumo.sim.vehicle import REAL_PLANT

    v_lead, steps = 6.09, 200
    event = Event("close_start", "synthetic", "none", v_lead * DT_S * np.arange(steps),
                  np.full(steps, v_lead), 5.0, np.full(steps, 8.55), np.full(steps, 3.93),
                  dt=DT_S).with_warmup(10.0)
    imp = Impairments(delay_s=0.1, plant=REAL_PLANT)
    law = "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2:rb=1"
    runs = {name: run_event(cached_sim(NET, "external"), event, 5, ploeg_controller(name),
                            impairments=imp)
            for name in (law, law + ":gs=6", law + ":gn=6", law + ":gn=6:op=2")}
    np.testing.assert_array_equal(runs[law + ":gn=6"].speed, runs[law].speed)
    np.testing.assert_array_equal(runs[law + ":gn=6:op=2"].speed, runs[law].speed)
    assert np.abs(runs[law + ":gs=6"].speed - runs[law].speed).max() > 0.1


class _BiasedLaw:
    """A law with a constant learned term a_adj on every follower (m/s²)."""

    def __init__(self, name: str, bias: float):
        self.law, self.bias = ploeg_controller(name), bias

    def reset(self, n: int) -> None:
        self.law.reset(n)

    def acceleration(self, obs: np.ndarray) -> np.ndarray:
        return self.law.acceleration(obs, np.full(obs.shape[0], self.bias))


@pytest.mark.parametrize("washout, gap_change", [(None, 0.4 / 0.2), (5.0, 0.0)])
def test_washout_keeps_a_biased_learned_term_from_moving_the_steady_gap_in_sumo(washout,
                                                                                  gap_change):
    """A constant a_adj of -0.4 m/s² shifts Ploeg's steady spacing error by a_adj/kp (2 m at
    kp = 0.2); with ``wo=5`` it enters less its running mean and the gap returns to 2 + h·v."""
    v, h = 15.0, 1.0
    name = "ploeg:h=1:kp=0.2:kd=0.7" + ("" if washout is None else f":wo={washout:g}")
    assert parse_ploeg(name).washout_s == washout and parse_ploeg(name).name() == name
    traj = run_event(cached_sim(NET, "external"), _cruise(1500, v, 2.0 + h * v), 3,
                     _BiasedLaw(name, -0.4))
    assert traj.collisions == 0
    assert np.allclose(traj.gap[-1], 2.0 + h * v + gap_change, atol=0.05)


def test_washout_preview_and_chains_carry_the_running_mean():
    """The preview (commit=False) applies a_adj = 0 less the running mean and leaves the mean;
    the chains keep the mean by vehicle ID and forget a vehicle that left."""
    from carl_sumo.control.cacc import PloegChains

    law = ploeg_controller("ploeg:h=1:wo=2")
    law.reset(1)
    eq = np.array([[10.0, 0.0, 12.0, 0.0]])
    law.acceleration(eq, np.array([1.0]))  # applied 1 - 0; the mean becomes 0.05
    assert math.isclose(law.adj_mean[0], DT_S / 2.0)
    preview = law.acceleration(eq, commit=False)
    assert math.isclose(law.adj_mean[0], DT_S / 2.0)
    assert preview[0] < law.u[0]  # the law moves toward -0.05 + its other inputs (0)
    chains = PloegChains(parse_ploeg("ploeg:h=1:wo=2"))
    for _ in range(3):
        chains.acceleration(np.vstack([eq, eq]), [[0], [1]], ["a", "b"], [None, None], {},
                            np.array([1.0, 0.0]))
    assert math.isclose(chains.adj_mean["a"], 1 - (1 - DT_S / 2.0) ** 3) and \
        chains.adj_mean["b"] == 0.0
    chains.acceleration(eq, [[0]], ["b"], [None], {}, np.array([0.0]))
    assert set(chains.adj_mean) == {"b"}


def test_head_free_spares_only_each_chains_head_from_the_washout():
    """``hf=1``: the head (row 0; a chain's first vehicle) takes a_adj as it is, its mean held at
    0, while a follower's term is washed as without it; hf without wo is refused in one line."""
    from carl_sumo.control.cacc import PloegChains

    name = "ploeg:h=1:kp=0.2:kd=0.7:wo=2:hf=1"
    assert parse_ploeg(name).head_free and parse_ploeg(name).name() == name
    free, washed = ploeg_controller(name), ploeg_controller("ploeg:h=1:kp=0.2:kd=0.7:wo=2")
    free.reset(2)
    washed.reset(2)
    eq = np.array([[10.0, 0.0, 12.0, 0.0], [10.0, 0.0, 12.0, 0.0]])
    for _ in range(3):
        free.acceleration(eq, np.array([1.0, 1.0]))
        washed.acceleration(eq, np.array([1.0, 1.0]))
    assert free.adj_mean[0] == 0.0 and washed.adj_mean[0] > 0.0
    assert free.adj_mean[1] == washed.adj_mean[1] > 0.0
    assert free.u[0] > washed.u[0]  # the head's whole term reaches its law
    chains = PloegChains(parse_ploeg(name))
    chains.acceleration(eq, [[0, 1]], ["a", "b"], [None, ("a", 12.0)], {}, np.array([1.0, 1.0]))
    assert chains.adj_mean == {"a": 0.0, "b": DT_S / 2.0}
    with pytest.raises(InputError, match="give wo too"):
        parse_ploeg("ploeg:h=1:hf=1")


def test_gp_runs_the_law_at_each_vehicles_learned_gap_floored_by_its_class():
    """``gp=T``: a vehicle's time-gap offset δ (s) runs the law at its gap + δ (its gain-free
    twin at that gap gives the same command), never below its class's least gap: a car in the
    chain ``gl``, a truck ``ht``, the head ``ha``; δ follows 1 s per m/s² of the learned term
    through a low-pass of T s, and the learned term no longer enters as an acceleration."""
    base = "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4:ht=0.8"
    params = parse_ploeg(base + ":gp=10:gl=0.5")
    assert (params.gap_policy_s, params.gap_floor_s) == (10.0, 0.5)
    assert params.name() == base + ":gp=10:gl=0.5"
    v = 15.0
    obs = np.array([[v, 0.2, 30.0, 0.3], [v, -0.1, 12.0, -0.2], [v, 0.0, 11.0, 0.1],
                    [v, 0.1, 9.0, 0.0]])  # head, a truck, a car, a car
    limits = (np.array([3.0, 1.0, 3.0, 3.0]), np.array([9.0, 6.0, 9.0, 9.0]))

    def command(name, gap_off=None):
        law = PloegController(parse_ploeg(name))
        law.reset(4)
        law.know_vehicles(*limits)
        u = np.array([0.1, -0.2, 0.05, 0.0])
        return law.step(obs, u, 0.3, gap_off=gap_off)

    up = command(base + ":gp=10", np.full(4, 0.4))  # every gap 0.4 s longer
    np.testing.assert_allclose(up[0], command(base.replace("ha=1.4", "ha=1.8"))[0])
    np.testing.assert_allclose(up[1], command(base.replace("ht=0.8", "ht=1.2"))[1])
    np.testing.assert_allclose(up[2:], command(base.replace("h=0.6", "h=1"))[2:])
    down = command(base + ":gp=10:gl=0.5", np.full(4, -0.3))  # floored: head, truck, cars
    np.testing.assert_allclose(down[:2], command(base)[:2])
    np.testing.assert_allclose(down[2:], command(base.replace("h=0.6", "h=0.5"))[2:])
    np.testing.assert_allclose(command(base + ":gp=10", np.zeros(4)), command(base))
    law = PloegController(parse_ploeg(base + ":gp=10"))  # the term moves δ, not the acceleration
    law.reset(4)
    before = law.acceleration(obs, commit=False)
    law.acceleration(obs, np.full(4, 1.0))
    np.testing.assert_allclose(law.gap_off, np.full(4, 0.01))  # 1 s · 0.1 s / 10 s
    law.acceleration(obs)  # no term: δ holds
    np.testing.assert_allclose(law.gap_off, np.full(4, 0.01))
    assert np.all(np.abs(law.acceleration(obs, commit=False) - before) < 0.05)
    for bad, what in ((base + ":gp=10:wo=5", "washout"), (base + ":gl=0.5", "give gp"),
                      (base + ":gp=10:gl=0.7", "at most h")):
        with pytest.raises(InputError, match=what):
            parse_ploeg(bad)


def test_pa_da_fa_set_only_the_head_of_a_chain():
    """``pa``/``da``: the gains of a vehicle that hears no message (the chain's head, an ACC at
    ``ha``), ``fa``: the weight of the leader's measured acceleration it feeds forward. The head
    with them is the law with those gains and that feed-forward scaled; a follower that hears
    its predecessor keeps kp and kd; bad values are one line."""
    base = "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=2.3:ht=0.8"
    soft = parse_ploeg(base + ":pa=0.02:da=0.3:fa=0.5")
    assert (soft.alone_kp, soft.alone_kd, soft.lead_weight) == (0.02, 0.3, 0.5)
    assert soft.name() == "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=2.3:pa=0.02:da=0.3:fa=0.5:ht=0.8"
    obs = np.array([[15.0, 0.2, 40.0, 0.3], [15.0, -0.1, 12.0, -0.2], [15.0, 0.0, 11.0, 0.1]])

    def command(name, u_lead):
        law = PloegController(parse_ploeg(name))
        law.reset(3)
        return law.step(obs, np.array([0.1, -0.2, 0.05]), u_lead)

    head_gains = command(base.replace("kp=0.0445:kd=1", "kp=0.02:kd=0.3"), 0.25)
    got = command(base + ":pa=0.02:da=0.3:fa=0.5", 0.5)
    assert got[0] == pytest.approx(head_gains[0], abs=1e-12)  # the head: its gains, fa·a_lead
    np.testing.assert_allclose(got[1:], command(base, 0.5)[1:])  # the followers: the law's
    for bad, what in ((base + ":fa=1.5", "in \\(0, 1\\]"), ("acc:h=2:da=0.3", "no V2V"),
                      (base + ":da=-1", "positive")):
        with pytest.raises(InputError, match=what):
            parse_ploeg(bad)


def test_df_feeds_forward_the_radars_acceleration_in_place_of_a_lost_message():
    """``df=W``: a follower whose predecessor's message is lost feeds forward W times the
    acceleration ahead its radar measures (a degraded CACC, as the head does with the leader's),
    blended in as the held message fades (w·held + (1 - w)·radar) and alone once it is lost; a
    live message and the head are unchanged, and without a loss the law is the law."""
    from carl_sumo.control.cacc import lost_feed_forward

    mode = np.array([0, 0, 1, 2])
    held = np.array([0.3, -0.2, 0.25 * 0.8, 0.0])  # the channel's held is already w·held
    radar = np.array([9.0, -0.5, -0.4, -0.6])
    out = lost_feed_forward(mode, held, np.array([1.0, 1.0, 0.25, 0.0]), radar)
    np.testing.assert_allclose(out, [0.3, -0.2, 0.25 * 0.8 + 0.75 * -0.4, -0.6])
    base = "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2:rb=1"
    obs = np.array([[15.0, 0.2, 30.0, 0.3], [15.0, -0.1, 12.0, -0.2], [15.0, 0.0, 11.0, 0.1]])
    a_ahead = np.array([0.0, -0.7, -0.3])

    def command(name, mode_):
        law = PloegController(parse_ploeg(name))
        law.reset(3)
        return law.step(obs, np.array([0.1, -0.2, 0.05]), 0.3, None, np.array(mode_),
                        np.array([0.0, 0.0, 0.0]), a_ahead=a_ahead)

    lost = command(base + ":df=0.5", [0, 0, 2])
    plain = command(base, [0, 0, 2])
    np.testing.assert_allclose(lost[:2], plain[:2])
    u = 0.05 + (DT_S / 1.4) * (-0.05 + 0.0445 * (11.0 - 2.0 - 1.4 * 15.0) + (0.1 - 1.4 * 0.0)
                               + 0.5 * -0.3)  # the ACC at ha with half the radar's term
    assert lost[2] == pytest.approx(u, abs=1e-12) and lost[2] != pytest.approx(plain[2])
    np.testing.assert_allclose(command(base + ":df=1", [0, 0, 0]), command(base, [0, 0, 0]))
    for bad, what in ((base + ":df=2", "in \\(0, 1\\]"), ("ploeg:h=0.6:df=1", "rb=1"),
                      ("acc:h=2:rb=1:df=1", "no V2V")):
        with pytest.raises(InputError, match=what):
            parse_ploeg(bad)


def test_gb_keeps_the_headway_budget_within_each_class_floor():
    """``gb=1``: the learned gap offsets of a chain sum to 0 (RL moves gap between vehicles,
    never adds it), each at least its class's least gap less its own (the head ha - ha = 0, a
    truck ht - ht = 0, a car gl - h); an offset asked for by every vehicle alike is no change."""
    from carl_sumo.control.ploeg_names import budgeted_offsets

    base = "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4:ht=0.8:gp=5:gl=0.5"
    params = parse_ploeg(base + ":gb=1")
    assert params.gap_budget and params.name() == base + ":gb=1"
    own, least = params.class_gaps(np.array([9.0, 6.0, 9.0, 9.0, np.inf]))
    np.testing.assert_allclose(own, [1.4, 0.8, 0.6, 0.6, 0.6])
    np.testing.assert_allclose(least, [1.4, 0.8, 0.5, 0.5, 0.5])
    lo = least - own
    for target in ([0.9, 0.0, 0.0, 0.0, 0.0], [0.5, 0.5, 0.5, 0.5, 0.5], [0.3, -0.2, 0.4, 0.0, -1.0]):
        off = budgeted_offsets(np.array(target), lo)
        assert abs(off.sum()) < 1e-8 and np.all(off >= lo - 1e-12)
    np.testing.assert_allclose(budgeted_offsets(np.full(5, 0.5), lo), 0.0, atol=1e-8)
    # the head asks for 0.9 s: the three cars give 0.1 s each (their floor), the truck the rest
    np.testing.assert_allclose(budgeted_offsets(np.array([0.9, 0, 0, 0, 0]), lo),
                               [0.3, 0.0, -0.1, -0.1, -0.1], atol=1e-8)
    law = PloegController(params)
    law.reset(5)
    law.know_vehicles(np.full(5, 3.0), np.array([9.0, 6.0, 9.0, 9.0, 9.0]))
    obs = np.tile([15.0, 0.0, 12.0, 0.0], (5, 1))
    for _ in range(200):
        law.acceleration(obs, np.array([1.0, -1.0, -1.0, -1.0, -1.0]))
    assert abs(law.gap_off.sum()) < 1e-6 and law.gap_off[0] > 0.25
    with pytest.raises(InputError, match="give gp"):
        parse_ploeg("ploeg:h=0.6:gb=1")


def test_gh_holds_the_learned_gap_between_decisions():
    """``gh=S``: the learned gap target is chosen every S s from the first step and held in
    between (the term of the other steps is not read), in the platoon's law and the study's
    chains alike; gh without gp is refused in one line."""
    from carl_sumo.control.cacc import PloegChains

    name = "ploeg:h=0.6:kp=0.0445:kd=1:aw=1:ha=1.4:ht=0.8:gp=2:gl=0.5:gb=1:gh=0.5"
    params = parse_ploeg(name)
    assert params.gap_hold_s == 0.5 and params.gap_hold_steps() == 5 and params.name() == name
    assert parse_ploeg("ploeg:h=0.6:gp=2").gap_hold_steps() == 1
    rng = np.random.default_rng(3)
    terms = rng.uniform(-1.0, 1.0, (12, 3))
    held = terms[(np.arange(12) // 5) * 5]  # the term of each decision step, repeated
    obs = np.array([[15.0, 0.0, 30.0, 0.0], [15.0, 0.0, 11.0, 0.0], [15.0, 0.0, 11.0, 0.0]])
    laws = [PloegController(params) for _ in range(2)]
    chains = PloegChains(params)
    chains.reset()
    for law in laws:
        law.reset(3)
        law.know_vehicles(np.full(3, 3.0), np.full(3, 9.0))
    for k in range(12):
        a = laws[0].acceleration(obs, terms[k])
        np.testing.assert_array_equal(a, laws[1].acceleration(obs, held[k]))
        b = chains.acceleration(obs, [[0, 1, 2]], ["h", "c1", "c2"],
                                [None, ("h", 11.0), ("c1", 11.0)], {}, terms[k])
        np.testing.assert_allclose(b, a, atol=1e-12)
        expected = laws[0].gap_target(terms[5 * (k // 5)], np.full(3, 9.0))
        np.testing.assert_allclose(laws[0].gap_held, expected)
        assert abs(laws[0].gap_held.sum()) < 1e-9  # gb=1: the held offsets keep the budget
    with pytest.raises(InputError, match="give gp"):
        parse_ploeg("ploeg:h=0.6:gh=5")
