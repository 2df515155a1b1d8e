"""The distributed MPC ``mpc``: its condensed QP against an independent simulation of the plant
and independent solvers (numpy's linear solve, SciPy's bounded minimiser), its names and bad
input (one line, exit 2, before any simulation), and short SUMO runs of a platoon."""

from __future__ import annotations

import json
import numpy as np
import pytest
from scipy.optimize import minimize

from carl_sumo.cli import main
from carl_sumo.config import DT_S
from carl_sumo.control.channel import Impairments, plant_impairments
from carl_sumo.control.classical import classical_controller
from carl_sumo.control.mpc import (DEFAULTS, MAX_CLASS_DEAD_STEPS, OPENING_DEADBAND_M, MPCParams,
                                   STANDSTILL_GAP_M,
                                   CondensedQP, class_model, mpc_controller, parse_mpc,
                                   predecessor_speeds)
from carl_sumo.errors import InputError
from carl_sumo.experiments.simulate import cached_sim, run_event

from conftest import NET, braking_event

WEIGHTS = (0.1, 1.0, 0.5, 0.05)


def _data(rng: np.random.Generator, n: int) -> np.ndarray:
    """A step's data z: [1, a0, v0, d0, u_prev, u(k-P..k-1), v_p,1..v_p,N]."""
    return np.concatenate(([1.0, rng.normal(0, 0.5), 15 + rng.normal(0, 2), 12 + rng.normal(0, 3),
                            rng.normal(0, 0.5)], rng.normal(0, 0.5, MAX_CLASS_DEAD_STEPS),
                           15 + np.cumsum(rng.normal(0, 0.1, n))))


def _simulated(z: np.ndarray, u: np.ndarray, tau: float, dead: int, h: float, n: int):
    """(a, e, v_p - v) over the horizon by a loop over the plant's equations
    (carl_sumo.sim.vehicle): independent of the QP's matrices."""
    a0, v, d, pipe, vp = z[1], z[2], z[3], list(z[5:5 + MAX_CLASS_DEAD_STEPS]), z[-n:]
    commands = pipe[len(pipe) - dead:] + list(u) if dead else list(u)
    alpha, a, xp, x = DT_S / (tau + DT_S), a0, 0.0, 0.0
    out = []
    for j in range(n):
        a = alpha * commands[j] + (1 - alpha) * a
        v += a * DT_S
        x += v * DT_S
        xp += vp[j] * DT_S
        gap = d + xp - x
        out.append((a, gap - STANDSTILL_GAP_M - h * v, vp[j] - v))
    return np.array(out).T


@pytest.mark.parametrize("tau,dead", [(0.0, 0), (0.3, 1), (0.5, 2)])
def test_the_condensed_predictions_are_the_plant_simulated_step_by_step(tau, dead):
    rng, n = np.random.default_rng(1), 30
    qp = CondensedQP(tau, dead, 0.6, n, WEIGHTS)
    for _ in range(3):
        z, u = _data(rng, n), rng.normal(0, 1, n - dead)
        w = np.concatenate([z, u])
        a, e, r = _simulated(z, u, tau, dead, 0.6, n)
        assert np.allclose(qp.acc_z @ z + qp.acc_u @ u, a, atol=1e-10)
        assert np.allclose(qp.spacing @ w, e, atol=1e-9)
        assert np.allclose(qp.relative @ w, r, atol=1e-10)
        cost = WEIGHTS[0] * e @ e + WEIGHTS[1] * r @ r + WEIGHTS[2] * u @ u + \
            WEIGHTS[3] * np.sum(np.diff(np.r_[z[4], u]) ** 2) / DT_S ** 2
        u_star = np.linalg.solve(qp.hessian, -qp.linear @ z)
        # the QP's cost differs from the simulated one by a constant in u
        a_star, e_star, r_star = _simulated(z, u_star, tau, dead, 0.6, n)
        cost_star = WEIGHTS[0] * e_star @ e_star + WEIGHTS[1] * r_star @ r_star + \
            WEIGHTS[2] * u_star @ u_star + \
            WEIGHTS[3] * np.sum(np.diff(np.r_[z[4], u_star]) ** 2) / DT_S ** 2
        assert np.isclose(cost - cost_star, 2 * (qp.cost(z, u) - qp.cost(z, u_star)),
                          rtol=1e-8, atol=1e-8)
        assert cost_star <= cost


def test_osqp_without_active_bounds_is_the_linear_solve():
    rng, n = np.random.default_rng(2), 30
    qp = CondensedQP(0.3, 1, 0.6, n, WEIGHTS)
    solver = qp.solver(-100.0, 100.0)
    for _ in range(5):  # warm-started from the last solution each time
        z = _data(rng, n)
        u, seconds = solver.solve(qp.linear @ z, -100.0, 100.0)
        exact = np.linalg.solve(qp.hessian, -qp.linear @ z)
        assert np.abs(exact).max() < 100 and seconds > 0
        assert np.allclose(u, exact, atol=2e-4), np.abs(u - exact).max()
    wrapped = qp.solver(-100.0, 100.0)
    wrapped.core = None  # through OSQP's Python wrapper: the same solution
    assert np.allclose(wrapped.solve(qp.linear @ z, -1.0, 1.0)[0],
                       solver.solve(qp.linear @ z, -1.0, 1.0)[0], atol=1e-6)


def test_a_binding_bound_gives_the_bounded_minimiser():
    rng, n = np.random.default_rng(3), 30
    qp = CondensedQP(0.5, 2, 0.8, n, WEIGHTS)
    z = _data(rng, n)
    z[3] = 60.0  # far behind: it wants to accelerate harder than a truck's 1 m/s²
    q = qp.linear @ z
    free = np.linalg.solve(qp.hessian, -q)
    assert free[0] > 1.0
    u, _ = qp.solver(-6.0, 1.0).solve(q, -6.0, 1.0)
    reference = minimize(lambda x: 0.5 * x @ qp.hessian @ x + q @ x, np.zeros(qp.m),
                         jac=lambda x: qp.hessian @ x + q, bounds=[(-6.0, 1.0)] * qp.m,
                         method="L-BFGS-B", options={"ftol": 1e-15, "gtol": 1e-12})
    assert np.isclose(u[0], 1.0, atol=1e-4)  # the bound binds
    assert np.allclose(u, reference.x, atol=1e-3)
    assert u.max() <= 1.0 + 1e-4 and u.min() >= -6.0 - 1e-4


def test_the_predecessors_plan_is_shifted_by_its_age_and_blended_when_it_fades():
    n, k = 5, 10
    plan = np.arange(1.0, n + 1)  # a(k_s+1..k_s+5) made at k_s = 8: age 2
    full = np.r_[1.0, 8.0, plan]
    v = predecessor_speeds(np.array([10.0, 10.0, 10.0]), np.array([-1.0, -1.0, -1.0]),
                           np.vstack([full, 0.5 * full, np.zeros(n + 2)]), k)
    shifted = np.array([3, 4, 5, 5, 5.0])  # a(k+1..k+5): plan[2:], its last value held
    assert np.allclose(v[0], 10 + DT_S * np.cumsum(shifted))
    assert np.allclose(v[1], 10 + DT_S * np.cumsum(0.5 * shifted - 0.5))
    assert np.allclose(v[2], 10 - DT_S * np.arange(1, n + 1))  # no plan: its acceleration held
    stop = predecessor_speeds(np.array([0.2]), np.array([-3.0]), np.zeros((1, n + 2)), k)
    assert stop.min() == 0.0  # not below a standstill


def test_mpc_names_parse_and_round_trip():
    assert parse_mpc("mpc") == DEFAULTS
    p = parse_mpc("mpc:h=0.8:N=40:wq=0.2:wv=2:wu=1:wj=0.1:ha=1.6:ttc=3")
    assert (p.time_gap_s, p.horizon, p.weights) == (0.8, 40, (0.2, 2.0, 1.0, 0.1))
    assert (p.alone_gap_s, p.heavy_gap_s, p.reaction_ttc_s, p.reaction_braking_ahead) == \
        (1.6, 0.8, 3.0, True)  # the options not given keep the defaults
    assert parse_mpc(p.name()) == p and parse_mpc(DEFAULTS.name()) == DEFAULTS
    assert parse_mpc("mpc:rb=0").reaction_braking_ahead is False
    assert parse_mpc("mpc:ra=0").reaction_all is False and DEFAULTS.reaction_all
    assert class_model(3.0, 9.0) == (0.3, 1) and class_model(1.0, 6.0) == (0.5, 2)
    assert isinstance(classical_controller("mpc:h=1"), type(mpc_controller("mpc")))


@pytest.mark.parametrize("name,words", [
    ("mpc:wq=0", "wq=0 must be a number from 1e-06"),
    ("mpc:wv=-1", "wv=-1 must be a number"),
    ("mpc:wu=nan", "wu=nan must be a number"),
    ("mpc:wj=inf", "wj=inf must be a number"),
    ("mpc:N=2", "the horizon N = 2 steps (0.2 s) is not longer than the dead time"),
    ("mpc:N=3.5", "N=3.5 must be a whole number"),
    ("mpc:h=0", "h=0 must be a number from 0.05"),
    ("mpc:kp=1", "'kp=1' is not an option; write mpc:h=VALUE"),
    ("mpc:h=1:h=2", "h is given twice"),
    ("mpc:rb=2", "rb=2 must be a whole number from 0 to 1"),
])
def test_bad_mpc_names_are_one_line_input_errors(name, words):
    with pytest.raises(InputError) as info:
        parse_mpc(name)
    assert words in str(info.value) and "\n" not in str(info.value)
    assert str(info.value).startswith(f"controller {name!r}")


def test_a_horizon_not_longer_than_the_dead_time_is_refused_in_the_dataclass():
    with pytest.raises(InputError, match="not longer than the dead time"):
        MPCParams(horizon=MAX_CLASS_DEAD_STEPS)


def test_the_mpc_drives_a_real_plant_platoon_through_a_braking_without_collision():
    event = braking_event(120)  # 12 s: the leader brakes at -2 m/s² from 12 to 4 m/s
    law = mpc_controller("mpc")
    traj = run_event(cached_sim(NET, "external"), event, 3, law, impairments=plant_impairments("real"))
    assert traj.collisions == 0 and traj.gap.min() > 3.0
    assert law.model != [(0.0, 0)] * 3  # it knows its classes' models on the real plant
    speeds = traj.speed[:, 1:]  # behind the head, the plans: no follower amplifies the braking
    assert speeds.min() > traj.speed[:, 0].min() - 0.5
    lost = mpc_controller("mpc")  # every plan lost: each follower is an ACC at ha = 1.4 s
    traj_lost = run_event(cached_sim(NET, "external"), event, 3, lost,
                          impairments=Impairments(delay_s=0.1, loss=1.0,
                                                  plant=plant_impairments("real").plant))
    assert traj_lost.collisions == 0
    assert traj_lost.gap[-1, 1:].mean() > traj.gap[-1, 1:].mean() + 2.0


def test_the_commands_run_mpc_by_name_and_refuse_bad_input_before_any_run(
        capsys, tmp_path, small_table_path):
    code = main(["simulate", "--controller", "mpc:N=20", "--data", str(small_table_path),
                 "--vehicles", "3", "--workers", "1", "--plant", "real", "--events", "1"])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert out.splitlines()[2].split()[0] == "mpc:N=20"
    for argv, words in (
            (["simulate", "--controller", "mpc:wq=0", "--data", str(small_table_path)],
             "wq=0 must be a number from 1e-06"),
            (["simulate", "--controller", "mpc:N=1", "--data", str(small_table_path)],
             "not longer than the dead time"),
            (["simulate", "--controller", "mpc:x=1", "--data", str(small_table_path)],
             "'x=1' is not an option"),
            (["string-stability", "--controller", "mpc:wv=-1", "--net", str(NET), "--json",
              str(tmp_path / "s.json")], "wv=-1 must be a number")):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert words in err and err.count("\n") == 1, err
    assert not (tmp_path / "s.json").exists()
    # the tuned MPC by name in string-stability runs the weights tuned for the plant
    code = main(["string-stability", "--controller", "mpc-tuned:h=0.6", "--plant", "real",
                 "--frequencies", "1", "--vehicles", "2", "--net", str(NET), "--json",
                 str(tmp_path / "s.json")])
    assert code == 0, capsys.readouterr().err
    runs = json.loads((tmp_path / "s.json").read_text())["runs"]
    assert {r["class"] for r in runs} == {"car", "truck"} and all(r["hinf"] < 1.1 for r in runs)


def test_on_one_chain_the_chains_controller_is_the_platoons():
    from carl_sumo.control.mpc import mpc_chains

    name, n = "mpc:N=20", 4
    platoon, chains = mpc_controller(name), mpc_chains(name)
    platoon.reset(n)
    chains.reset()
    a_max, b_max = np.array([3.0, 1.0, 3.0, 3.0]), np.array([9.0, 6.0, 9.0, 9.0])
    platoon.know_vehicles(a_max, b_max)
    ids = [f"c{i}" for i in range(n)]
    for vid, a, b in zip(ids, a_max, b_max):
        chains.know_vehicle(vid, a, b)
    ahead = [("L", 10.0)] + [(ids[i - 1], 10.0) for i in range(1, n)]
    rng, dv_before = np.random.default_rng(5), None
    for k in range(30):
        obs = np.column_stack([15 + rng.normal(0, 1, n), rng.normal(0, 0.5, n),
                               12 + rng.normal(0, 2, n), rng.normal(0, 0.5, n)])
        a_lead = 0.0 if dv_before is None else obs[0, 1] + (obs[0, 3] - dv_before) / DT_S
        dv_before = obs[0, 3]
        a = platoon.acceleration(obs)
        b = chains.acceleration(obs, [list(range(n))], ids, ahead, {"L": a_lead})
        assert np.allclose(a, b, rtol=0, atol=1e-9), k
    assert chains.vehicles["c1"]["model"] == (0.5, 2)  # the truck's model


def test_a_cut_in_scenario_runs_mpc_on_its_chains(capsys, tmp_path):
    import json

    out_json = tmp_path / "cut.json"
    code = main(["simulate", "--scenario", "cut-in", "--events", "1", "--vehicles", "5",
                 "--controller", "mpc", "--workers", "1", "--plant", "real", "--json",
                 str(out_json)])
    out, err = capsys.readouterr()
    assert code == 0, err
    rows = json.loads(out_json.read_text())["controllers"]
    assert rows[0]["metrics"]["collisions"] == 0


def test_the_reaction_layer_on_every_vehicle_keeps_a_cramped_start_collision_free():
    """Followers start 0.88 m apart at 3.2 m/s behind a leader at 5 m/s (an NGSIM start; this
    event ID draws trucks at positions 5, 6 and 8): the QP alone trades the spacing error against
    its command and the trucks' follower closes in (ra=0 collides), the reaction layer on every
    vehicle (ra=1, the default) brakes it in time."""
    from carl_sumo.data.events import Event

    n = 60
    speed = np.full(n, 5.05)
    pos = np.concatenate([[0.0], np.cumsum(speed[1:]) * DT_S])
    event = Event("emd_0400_f2337_l2322_fr6892", "zhu2020_testset", "i-80", pos, speed, 5.0,
                  np.full(n, 3.22), np.full(n, 0.88))
    runs = {ra: run_event(cached_sim(NET, "external"), event, 10, mpc_controller(f"mpc:ra={ra}"),
                          impairments=plant_impairments("real")) for ra in (0, 1)}
    assert runs[0].collisions > 0
    assert runs[1].collisions == 0 and runs[1].gap.min() > 0.3


def _assert_governed_cost(rng, qp, z, q, offset, tau, dead, h, n):
    """q is the QP of the cost with the spacing error e_j + offset_j: the objective's differences
    between two random plans are half the cost's, computed from the simulated plant."""
    def governed(u):
        _, e, r = _simulated(z, u, tau, dead, h, n)
        return WEIGHTS[0] * np.sum((e + offset) ** 2) + WEIGHTS[1] * r @ r + \
            WEIGHTS[2] * u @ u + WEIGHTS[3] * np.sum(np.diff(np.r_[z[4], u]) ** 2) / DT_S ** 2

    u1, u2 = rng.normal(0, 1, qp.m), rng.normal(0, 1, qp.m)
    objective = [0.5 * u @ qp.hessian @ u + q @ u for u in (u1, u2)]
    assert np.isclose(governed(u1) - governed(u2), 2 * (objective[0] - objective[1]), rtol=1e-8)


def test_the_opening_term_is_the_governed_spacing_errors_cost():
    """``go``: q + opening_term is the QP of the cost with the error e_j + o_j, o_j =
    max(-e_0 - deadband - R·j·dt, 0) (checked against the cost computed from the simulated
    plant), and nothing changes within the deadband."""
    rng, n, tau, dead, h, speed = np.random.default_rng(4), 30, 0.3, 1, 0.6, 0.5
    qp = CondensedQP(tau, dead, h, n, WEIGHTS)
    z = _data(rng, n)
    e0 = -6.0
    offset = np.maximum(-e0 - OPENING_DEADBAND_M - speed * np.arange(1, n + 1) * DT_S, 0.0)
    q = qp.linear @ z + qp.opening_term(e0, speed, WEIGHTS[0])

    _assert_governed_cost(rng, qp, z, q, offset, tau, dead, h, n)
    assert not qp.opening_term(0.5, speed, WEIGHTS[0]).any()
    assert not qp.opening_term(-0.99 * OPENING_DEADBAND_M, speed, WEIGHTS[0]).any()
    free, governed_plan = (np.linalg.solve(qp.hessian, -qq)
                           for qq in (qp.linear @ z, q))
    assert governed_plan[0] > free[0]  # it brakes less to open the gap
    assert parse_mpc("mpc:go=0.5").opening_speed == 0.5
    assert parse_mpc(parse_mpc("mpc:go=0.5").name()) == parse_mpc("mpc:go=0.5")
    with pytest.raises(InputError, match="go=-1 must be a number from 0"):
        parse_mpc("mpc:go=-1")


def test_the_closing_term_is_the_governed_spacing_errors_cost():
    """``gc``: q + opening_term(..., closing) is the QP of the cost with the error e_j + o_j,
    o_j = -max(e_0 - deadband - R·j·dt, 0) for a gap too long by e_0 (checked against the cost
    computed from the simulated plant); nothing within the deadband, nothing with gc off."""
    rng, n, tau, dead, h, rate = np.random.default_rng(5), 30, 0.5, 2, 0.8, 1.5
    qp = CondensedQP(tau, dead, h, n, WEIGHTS)
    z = _data(rng, n)
    e0 = 25.0
    offset = -np.maximum(e0 - OPENING_DEADBAND_M - rate * np.arange(1, n + 1) * DT_S, 0.0)
    q = qp.linear @ z + qp.opening_term(e0, 0.0, WEIGHTS[0], rate)

    _assert_governed_cost(rng, qp, z, q, offset, tau, dead, h, n)
    assert not qp.opening_term(0.99 * OPENING_DEADBAND_M, 0.0, WEIGHTS[0], rate).any()
    assert not qp.opening_term(e0, 0.5, WEIGHTS[0]).any()  # go alone leaves a long gap be
    free, governed_plan = (np.linalg.solve(qp.hessian, -qq) for qq in (qp.linear @ z, q))
    assert governed_plan[0] < free[0]  # it speeds up less to close the gap
    assert parse_mpc("mpc:gc=2").closing_speed == 2.0
    assert parse_mpc(parse_mpc("mpc:go=0.5:gc=2").name()) == parse_mpc("mpc:go=0.5:gc=2")
    with pytest.raises(InputError, match="gc=11 must be a number from 0"):
        parse_mpc("mpc:gc=11")


def test_closing_a_long_gap_slowly_keeps_the_tuned_mpc_out_of_the_queue():
    """The shipped default event sumo42_f2321_l2303_fr7763 (a follower at 15 m/s, 72 m behind a
    leader at 2.2 m/s), real plant, 60 s settled start: the tuned MPC closes every long gap as its
    weights say, its cars reach the road's 33 m/s and the tail meets the queue too fast to stop;
    closing at 1 m/s beyond the deadband (gc=1) does not collide."""
    from carl_sumo.control.ploeg_names import tuned_law
    from carl_sumo.data import load_events

    event = next(e for e in load_events("default", "test")
                 if e.event_id == "sumo42_f2321_l2303_fr7763").with_warmup(60.0)
    tuned = tuned_law("mpc-tuned:h=0.6", plant=plant_impairments("real").plant_key)
    runs = {name: run_event(cached_sim(NET, "external"), event, 10, mpc_controller(name, "real"),
                            impairments=plant_impairments("real"))
            for name in (tuned, tuned + ":gc=1")}
    assert runs[tuned].collisions > 0
    assert runs[tuned + ":gc=1"].collisions == 0


def test_opening_a_short_gap_slowly_keeps_the_cramped_chain_collision_free():
    """The start of the training event zhu2020pool_val_0086 (every follower 1.27 m behind at 9.6
    m/s, the leader at 11.8 m/s; its ID draws the fleet): the MPC's braking to open every gap at
    once grows down the chain and the tail collides; opening them at 0.5 m/s (go=0.5) does not."""
    from carl_sumo.data.events import Event

    n = 80
    speed = np.full(n, 11.77)
    pos = np.concatenate([[0.0], np.cumsum(speed[1:]) * DT_S])
    event = Event("zhu2020pool_val_0086", "zhu2020_pool_transfollower", "i-80", pos, speed, 5.0,
                  np.full(n, 9.59), np.full(n, 1.27))
    runs = {name: run_event(cached_sim(NET, "external"), event, 10, mpc_controller(name),
                            impairments=plant_impairments("real"))
            for name in ("mpc", "mpc:go=0.5")}
    assert runs["mpc"].collisions > 0
    assert runs["mpc:go=0.5"].collisions == 0 and runs["mpc:go=0.5"].gap.min() > 0.5


def test_gn_bounds_the_mpc_at_a_merge_point_and_behind_a_new_vehicle_as_ploegs_layers():
    """``gn=6`` on the MPC's chains: a car beside a faster truck, 57 m from the zipper merge's
    point, brakes at most as Ploeg's merge-point layer allows (much harder than without it), the
    truck ahead is untouched, and an armed front vehicle keeps Gipps' safe speed; without
    ``gn`` (or without a merge) the commands are the MPC's own. The name parses back."""
    from carl_sumo.control.layers import layer_params, merge_point
    from carl_sumo.control.mpc import MPCChains, parse_mpc

    name = "mpc:h=0.6:N=30:wq=0.8:wv=0.666667:wu=2:wj=0.2:ha=2:ht=0.8:ttc=2:rb=1:ra=1:go=0.5"
    assert parse_mpc(name + ":gn=6").name() == name + ":gn=6" and parse_mpc(name).safe_braking == 0
    obs = np.array([[32.2, 0.0, 30.0, 0.0], [31.1, 0.0, -4.2, 1.1]])  # truck, car beside it
    ids, chains, ahead, last = ["truck", "car"], [[0, 1]], [("x", 28.0), ("truck", -6.2)], {}
    plain, guarded = MPCChains(parse_mpc(name)), MPCChains(parse_mpc(name + ":gn=6"))
    for law in (plain, guarded):
        law.merge_behind({"car": 57.0})
    a_plain = plain.acceleration(obs, chains, ids, ahead, last)
    a = guarded.acceleration(obs, chains, ids, ahead, last)
    assert a[0] == a_plain[0]
    bound = a_plain[1:].copy()
    merge_point(obs[1:], bound, np.full(1, np.inf), np.array([57.0]), np.full(1, -9.0),
                layer_params(0.0, 1.0, 0.5, 6.0, True, 0.0, 2.0, -9.0))
    assert a[1] == pytest.approx(bound[0]) and a[1] < a_plain[1] - 1.0
    close = np.array([[30.0, 0.0, 6.0, -3.0]])  # a new vehicle 6 m ahead, 3 m/s slower
    free, armed = MPCChains(parse_mpc(name + ":gn=6")), MPCChains(parse_mpc(name + ":gn=6"))
    armed.arm({"v"})
    assert armed.acceleration(close, [[0]], ["v"], [("h", 6.0)], {})[0] < \
        free.acceleration(close, [[0]], ["v"], [("h", 6.0)], {})[0] - 0.5
