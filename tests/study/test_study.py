"""Mixed-traffic studies: chains in hand-built SUMO scenes, p = 0 = human only, a short study."""

from __future__ import annotations

import csv
import re
import shutil
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from carl_sumo.learn.agents import Agent, AgentConfig
from carl_sumo.cli import main
from carl_sumo.errors import InputError
from carl_sumo.learn.policy import save_policy
from carl_sumo.experiments.chain_controllers import ChainController
from carl_sumo.study.run import StudyConfig, run_one, _sumo_study_args
from carl_sumo.experiments.chain_formation import (cacc_observations, form_chains, merging_lanes,
                                   zipper_ahead, zipper_aheads)
from carl_sumo.sim.sumo import close_sumo, start_sumo, sumo_args
from carl_sumo.sim.traffic import DEFAULT_DEMAND, Demand, write_routes

from conftest import NET, REPO_ROOT

POLICY = REPO_ROOT / "policies" / "ca_td3_10.pt"
LOW = DEFAULT_DEMAND.scaled(0.25)


# ------------------------------------------------------------------------ chains, pure
def test_form_chains_links_consecutive_cacc_within_range():
    ids = ["a", "b", "c", "d"]
    ahead = [None, ("a", 20.0), ("human", 15.0), ("c", 300.5)]  # c behind a human; d too far
    assert form_chains(ids, ahead, 300.0) == [[0, 1], [2], [3]]
    assert form_chains(ids, ahead, 301.0) == [[0, 1], [2, 3]]


def test_form_chains_two_lanes_joining_keep_the_nearer_follower():
    ids = ["lead", "left", "right"]
    ahead = [None, ("lead", 30.0), ("lead", 12.0)]
    assert form_chains(ids, ahead, 300.0) == [[0, 2], [1]]


# --------------------------------------------------------------- chains, SUMO scenes
def _scene(vehicles: list[tuple[str, str, int, float]]):
    """Start SUMO with vehicles (id, type, lane of i80_main, position m) at 20 m/s, one step."""
    import libsumo as ls

    start_sumo(sumo_args(NET))
    ls.route.add("main", ["i80_main"])
    for vid, vtype, lane, pos in vehicles:
        ls.vehicle.add(vid, "main", vtype, depart="now", departLane=str(lane),
                       departPos=f"{pos}", departSpeed="20")
    ls.simulationStep()
    for vid, vtype, _, _ in vehicles:
        ls.vehicle.setLaneChangeMode(vid, 0)
        ls.vehicle.setSpeedMode(vid, 0)
        ls.vehicle.setSpeed(vid, 20.0)
    return ls


def _chains_now(ls, cacc: list[str], range_m: float = 300.0):
    """The chains (ids) of the CACC vehicles as SUMO has them now, and their observations."""
    speed_of = {v: ls.vehicle.getSpeed(v) for v in ls.vehicle.getIDList()}
    ahead = [ls.vehicle.getLeader(v, 400.0) for v in cacc]
    min_gap = {v: ls.vehicle.getMinGap(v) for v in cacc}
    obs, chain_ahead = cacc_observations(cacc, [speed_of[v] for v in cacc], [0.0] * len(cacc),
                                         ahead, speed_of, min_gap, 400.0)
    return [[cacc[i] for i in chain] for chain in form_chains(cacc, chain_ahead, range_m)], obs


def test_human_cut_in_splits_a_chain_and_range_limits_it():
    cacc = ["c0", "c1", "c2", "c3"]
    ls = _scene([("c0", "cacc", 2, 1000.0), ("c1", "cacc", 2, 960.0), ("c2", "cacc", 2, 920.0),
                 ("c3", "cacc", 2, 600.0), ("h", "human_krauss", 3, 945.0)])
    try:
        chains, obs = _chains_now(ls, cacc)
        # c3's bumper gap to c2 is 920 - 5 - 600 = 315 m > 300 m: a chain of its own
        assert chains == [["c0", "c1", "c2"], ["c3"]]
        assert obs[1, 2] == pytest.approx(35.0, abs=1e-6)  # bumper gap c0 -> c1 (m)
        assert obs[0, 2] == 400.0 and obs[0, 3] == 0.0  # nobody ahead of c0 within 400 m
        assert _chains_now(ls, cacc, range_m=320.0)[0] == [["c0", "c1", "c2", "c3"]]
        # the human cuts in between c1 and c2: SUMO now reports it ahead of c2
        ls.vehicle.moveTo("h", "i80_main_2", 945.0)
        ls.simulationStep()
        chains, obs = _chains_now(ls, cacc)
        assert ls.vehicle.getLeader("c2", 400.0)[0] == "h"
        assert chains == [["c0", "c1"], ["c2"], ["c3"]]
        assert obs[2, 2] == pytest.approx(945.0 - 5.0 - 920.0, abs=0.5)
    finally:
        close_sumo()


def test_zipper_merge_gives_a_virtual_vehicle_ahead():
    import libsumo as ls

    merging = merging_lanes(NET)
    assert merging["i80_merge_1"] == ("i80_merge_0",)
    start_sumo(sumo_args(NET))
    ls.route.add("main", ["i80_approach", "i80_merge", "i80_main"])
    ls.route.add("ramp", ["powell_onramp", "i80_merge", "i80_main"])
    ls.vehicle.add("ego", "main", "cacc", depart="now", departLane="0", departPos="1580",
                   departSpeed="20")
    ls.vehicle.add("foe", "ramp", "human_idm", depart="now", departLane="0", departPos="400",
                   departSpeed="20")
    for _ in range(25):  # ego to about 100 m before the merge point, foe 10 m nearer to it
        ls.simulationStep()
    try:
        assert ls.vehicle.getLaneID("ego") == "i80_merge_1"
        assert ls.vehicle.getLaneID("foe") == "i80_merge_0"
        item = zipper_ahead(ls, "ego", "i80_merge_1", merging["i80_merge_1"],
                            ls.vehicle.getLeader("ego", 300.0), 2.0, 300.0)
        ego_rest = 300.0 - ls.vehicle.getLanePosition("ego")
        foe_rest = 300.0 - ls.vehicle.getLanePosition("foe")
        assert item[0] == "foe" and foe_rest < ego_rest
        assert item[1] == pytest.approx(ego_rest - foe_rest - 5.0 - 2.0)
        # the foe, nearer to the merge point, does not yield to the ego
        assert zipper_ahead(ls, "foe", "i80_merge_0", merging["i80_merge_0"], None, 2.0,
                            300.0) is None
        # for every CACC vehicle at once, with the ego's distance to the merge point
        ahead = [ls.vehicle.getLeader("ego", 300.0)]
        assert zipper_aheads(ls, ["ego"], ahead, merging, {"ego": 2.0}, 300.0) == \
            {"ego": pytest.approx(ego_rest)}
        assert ahead == [item]
    finally:
        close_sumo()


# -------------------------------------------------------------------------- demand
def test_route_files_differ_only_in_the_cacc_set():
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        sets = {p: write_routes(Path(tmp) / f"r{p}.xml", p, 3, 120.0, LOW) for p in (0, 0.5, 1)}
        text = {p: (Path(tmp) / f"r{p}.xml").read_text() for p in sets}
    strip = lambda t: re.sub(r'type="[a-z_]+"|<!--.*?-->', "", t)  # noqa: E731
    assert strip(text[0]) == strip(text[0.5]) == strip(text[1])
    assert sets[0].n_cacc == 0 and sets[1].n_cacc == sets[1].n_vehicles > 50
    assert 0 < sets[0.5].n_cacc < sets[1].n_cacc
    assert sets[0.5].cacc_ids < sets[1].cacc_ids
    expected = 120.0 * LOW.total_vph / 3600.0
    assert abs(sets[0].n_vehicles - expected) < 4 * np.sqrt(expected)


def test_demand_rejects_bad_values():
    with pytest.raises(InputError, match="non-negative"):
        Demand(onramp_vph=-1.0)
    with pytest.raises(InputError, match="cannot be generated"):
        DEFAULT_DEMAND.scaled(2.0)


# ------------------------------------------------------------------------------ runs
def _files(run_dir: str) -> dict[str, str]:
    """SUMO's output files of a run without their header comment (date, paths)."""
    return {name: re.sub(r"<!--.*?-->", "", (Path(run_dir) / name).read_text(), flags=re.S)
            for name in ("detectors.xml", "edgedata.xml", "emissions.xml")}


def test_p0_is_exactly_the_human_only_run(tmp_path):
    import libsumo as ls

    cfg = StudyConfig(controller=str(POLICY), duration_s=30.0, warmup_s=60.0, demand=LOW,
                      seeds=(1,), detector_pos_m=100.0)
    with_policy = run_one(cfg, 0.0, 1, tmp_path / "policy")
    native = run_one(replace(cfg, controller="sumo-cacc"), 0.0, 1,
                     tmp_path / "native")
    # the same route file run by SUMO alone, nobody touching it
    bare = tmp_path / "bare"
    shutil.copytree(with_policy.run_dir, bare)
    start_sumo(_sumo_study_args(cfg, bare / "routes.rou.xml", bare / "outputs.add.xml", None, 1))
    try:
        while ls.simulation.getTime() < 90.0 - 1e-9:
            ls.simulationStep()
    finally:
        close_sumo()
    assert _files(with_policy.run_dir) == _files(bare) == _files(native.run_dir)
    timing = ("sim_speed", "sumo_share", "wall_s", "mean_chain_length", "max_chain_length")
    same = {k: v for k, v in with_policy.metrics.items() if k not in timing}
    assert same == {k: v for k, v in native.metrics.items() if k not in timing}
    assert with_policy.metrics["throughput_vph"] > 0 and with_policy.metrics["cacc_share"] == 0


def test_human_sigma_makes_humans_random_and_repeatable(tmp_path):
    cfg = StudyConfig(controller="idm-external", duration_s=30.0, warmup_s=60.0, demand=LOW,
                      seeds=(1,), detector_pos_m=100.0)
    plain = run_one(cfg, 0.0, 1, tmp_path / "plain")
    noisy = run_one(replace(cfg, human_sigma=0.5), 0.0, 1, tmp_path / "noisy")
    again = run_one(replace(cfg, human_sigma=0.5), 0.0, 1, tmp_path / "again")
    assert _files(noisy.run_dir) == _files(again.run_dir)  # the run's seed draws them
    assert _files(noisy.run_dir) != _files(plain.run_dir)


def test_chain_controller_batches_chains_like_single_platoons():
    controller = ChainController(str(POLICY))
    rng = np.random.default_rng(0)
    obs = np.column_stack([rng.uniform(10, 30, 9), rng.uniform(-1, 1, 9), rng.uniform(5, 60, 9),
                           rng.uniform(-2, 2, 9)])
    chains = [[4, 0, 7], [1], [2, 3, 5, 6, 8]]
    out = controller.adjustment(obs, chains)
    for chain in chains:
        assert np.allclose(out[chain], controller.agent.act(obs[chain]), atol=1e-5)


def test_maddpg_policy_is_refused(tmp_path, capsys):
    save_policy(Agent(AgentConfig(algo="maddpg", n_vehicles=4)), tmp_path / "m.pt", {})
    code = main(["study", "--controller", str(tmp_path / "m.pt"), "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "MADDPG" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


@pytest.mark.parametrize("argv, message", [
    (["--penetration", "0,1.5"], "--penetration"),
    (["--controller", "pid"], "unknown study controller"),
    (["--duration", "0"], "--duration"),
    (["--demand-scale", "5"], "cannot be generated"),
    (["--detector-pos", "9000"], "beyond the end"),
    (["--human-sigma", "1.5"], "--human-sigma"),
])
def test_study_bad_input_is_one_line_exit_2(tmp_path, capsys, argv, message):
    code = main(["study", *argv, "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_short_study_end_to_end(tmp_path, capsys):
    out = tmp_path / "study"
    code = main(["study", "--controller", str(POLICY), "--penetration", "1,0", "--duration", "30",
                 "--warmup", "60", "--seeds", "2", "--demand-scale", "0.25", "--detector-pos",
                 "100", "--workers", "2", "--fcd", "--out", str(out)])
    printed = capsys.readouterr().out
    assert code == 0, printed
    rows = list(csv.DictReader((out / "study.csv").open()))
    assert [float(r["penetration"]) for r in rows] == [0.0, 1.0]
    assert all(int(r["runs"]) == 2 for r in rows)
    p0, p1 = rows
    assert float(p0["cacc_share"]) == 0.0 and float(p1["cacc_share"]) == 1.0
    assert float(p1["collisions"]) == 0.0 and float(p1["mean_chain_length"]) > 1.0
    assert float(p0["throughput_vph"]) > 0 and float(p1["throughput_vph"]) > 0
    assert len(list(csv.DictReader((out / "runs.csv").open()))) == 4
    for name in ("study.md", "metrics_vs_penetration.png", "heatmap_p0.png", "heatmap_p1.png"):
        assert (out / name).stat().st_size > 0
    assert "| p | throughput (veh/h)" in (out / "study.md").read_text()
    assert (out / "runs" / "p1_seed0" / "fcd_p1_seed0.xml.gz").stat().st_size > 0
    assert not (out / "runs" / "p1_seed1" / "fcd_p1_seed1.xml.gz").exists()
    assert not [p for p in out.rglob(".*")]  # no temporary files left


def test_residual_policy_on_chains_starts_as_its_classical_base(tmp_path):
    """A fresh policy on base ploeg (a_adj = 0) gives the same accelerations on chains as
    PloegChains and keeps the same per-vehicle states."""
    from carl_sumo.control.cacc import PloegChains, parse_ploeg

    save_policy(Agent(AgentConfig(algo="ca-td3", base="ploeg:h=0.8")), tmp_path / "r.pt", {})
    controller = ChainController(str(tmp_path / "r.pt"))
    reference = PloegChains(parse_ploeg("ploeg:h=0.8"))
    rng = np.random.default_rng(0)
    ids = [f"v{i}" for i in range(9)]
    chains = [[4, 0, 7], [1], [2, 3, 5, 6, 8]]
    ahead = [("h", 20.0)] * 9
    for _ in range(3):
        obs = np.column_stack([rng.uniform(10, 30, 9), rng.uniform(-1, 1, 9),
                               rng.uniform(5, 60, 9), rng.uniform(-2, 2, 9)])
        last = {"h": float(rng.uniform(-1, 1))}
        expected = reference.acceleration(obs, chains, ids, ahead, last)
        assert np.allclose(controller.acceleration(obs, chains, ids, ahead, last), expected)
    assert controller.base.u == pytest.approx(reference.u)


def test_merge_point_bound_reaches_a_policys_base_on_chains(tmp_path):
    """ChainController.merge_behind hands each vehicle's distance to a zipper merge's point to its
    classical base: a fresh policy on a ``gn`` law brakes as that law does (PloegChains), harder
    than without it for a car beside a faster truck; a base without ``gn`` ignores it."""
    from carl_sumo.control.cacc import PloegChains, parse_ploeg

    obs = np.array([[32.2, 0.0, 30.0, 0.0], [31.1, 0.0, -4.2, 1.1]])  # truck, car beside it
    ids, chains, ahead, last = ["truck", "car"], [[0, 1]], [("x", 28.0), ("truck", -6.2)], {}
    for base, bounded in (("ploeg:h=0.6:kp=0.0445:kd=1:gn=6", True), ("ploeg:h=0.6", False)):
        save_policy(Agent(AgentConfig(algo="ca-td3", base=base)), tmp_path / "p.pt", {})
        controller = ChainController(str(tmp_path / "p.pt"))
        free = controller.acceleration(obs, chains, ids, ahead, last)
        controller.reset()
        controller.merge_behind({"car": 57.0})
        a = controller.acceleration(obs, chains, ids, ahead, last)
        reference = PloegChains(parse_ploeg(base))
        reference.merge_behind({"car": 57.0})
        assert np.allclose(a, reference.acceleration(obs, chains, ids, ahead, last))
        assert a[0] == free[0]
        assert (a[1] < free[1] - 1.0) if bounded else a[1] == free[1]


def test_every_cacc_controller_is_inserted_like_sumos_cacc():
    from carl_sumo.study.run import insertion_tau_s

    assert insertion_tau_s() == 0.6


def test_chains_over_perfect_keyed_links_act_as_without_them():
    from carl_sumo.control.channel import Impairments

    plain, linked = ChainController(str(POLICY)), ChainController(str(POLICY))
    linked.connect(Impairments(), "run")
    rng = np.random.default_rng(1)
    ids = [f"v{i}" for i in range(9)]
    chains = [[4, 0, 7], [1], [2, 3, 5, 6, 8]]
    for _ in range(3):
        obs = np.column_stack([rng.uniform(10, 30, 9), rng.uniform(-1, 1, 9),
                               rng.uniform(5, 60, 9), rng.uniform(-2, 2, 9)])
        assert np.allclose(linked.adjustment(obs, chains, ids), plain.adjustment(obs, chains),
                           atol=1e-9)


def test_impaired_study_runs_repeat_with_their_seed(tmp_path):
    from carl_sumo.control.channel import Impairments

    cfg = StudyConfig(controller=str(POLICY), duration_s=20.0, warmup_s=40.0, demand=LOW,
                      seeds=(1,), detector_pos_m=100.0)
    imp = Impairments(delay_s=0.2, loss=0.3, burst=3.0, sensor_noise=True)
    plain = run_one(cfg, 1.0, 1, tmp_path / "plain")
    first = run_one(replace(cfg, impairments=imp), 1.0, 1, tmp_path / "first")
    again = run_one(replace(cfg, impairments=imp), 1.0, 1, tmp_path / "again")
    timing = ("sim_speed", "sumo_share", "wall_s")
    assert {k: v for k, v in first.metrics.items() if k not in timing} == \
        {k: v for k, v in again.metrics.items() if k not in timing}
    assert first.metrics["jerk_mps3"] != plain.metrics["jerk_mps3"]
    assert first.metrics["collisions"] == 0


def test_sumos_own_cacc_refuses_impairments(tmp_path, capsys):
    code = main(["study", "--controller", "sumo-cacc", "--comm-loss", "0.3",
                 "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "impairments" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------------ external controllers (issue 36)
EXAMPLE = REPO_ROOT / "examples" / "my_controller.py"


def test_external_controller_runs_each_chain_as_a_platoon():
    from carl_sumo.experiments.chain_controllers import ExternalChains

    import importlib.util
    spec = importlib.util.spec_from_file_location("my_controller_ref", EXAMPLE)
    ref = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ref)
    controller = ExternalChains(f"{EXAMPLE}:constant_gap")
    rng = np.random.default_rng(1)
    obs = np.column_stack([rng.uniform(10, 30, 7), rng.uniform(-1, 1, 7), rng.uniform(5, 60, 7),
                           rng.uniform(-2, 2, 7)])
    chains = [[3, 0], [1, 2, 6], [4], [5]]
    out = controller.acceleration(obs, chains, [f"c{i}" for i in range(7)], [None] * 7, {})
    for chain in chains:
        assert np.allclose(out[chain], np.clip(ref.constant_gap(obs[chain]), -9.0, 3.0))


def test_study_with_an_external_zero_adjustment_is_the_idm_run(tmp_path):
    cfg = StudyConfig(controller="idm-external", duration_s=30.0, warmup_s=60.0, demand=LOW,
                      seeds=(0,), detector_pos_m=100.0)
    idm = run_one(cfg, 1.0, 0, tmp_path / "idm")
    ext = run_one(replace(cfg, controller=f"{EXAMPLE}:ZeroAdjust"), 1.0, 0, tmp_path / "ext")
    assert idm.metrics["cacc_share"] == 1.0 and idm.metrics["throughput_vph"] > 0
    assert _files(ext.run_dir) == _files(idm.run_dir)
    law = run_one(replace(cfg, controller=f"{EXAMPLE}:constant_gap"), 1.0, 0, tmp_path / "law")
    assert _files(law.run_dir) != _files(idm.run_dir)


def test_study_names_a_missing_external_controller(tmp_path, capsys):
    code = main(["study", "--controller", f"{EXAMPLE}:nothing_here", "--out", str(tmp_path / "o")])
    err = capsys.readouterr().err
    assert code == 2 and "no attribute 'nothing_here'" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()


def test_a_policy_on_chains_remembers_each_vehicles_commands_by_id(tmp_path):
    """--command-history on chains: the rows of a step are the CACC vehicles of that step, in
    any order; each vehicle's history is its own last commands, found by its ID, and it moves
    the policy's action."""
    import torch

    agent = Agent(AgentConfig(algo="ca-td3", base="ploeg:h=0.8", command_history=2))
    with torch.no_grad():
        for p in agent.actor.parameters():
            p.add_(0.3 * torch.randn_like(p, generator=torch.Generator().manual_seed(1)))
    save_policy(agent, tmp_path / "h.pt", {})
    controller, amnesic = (ChainController(str(tmp_path / "h.pt")) for _ in range(2))
    rng = np.random.default_rng(0)
    ids, chains, ahead = ["a", "b", "c"], [[0, 1, 2]], [("h", 20.0)] * 3
    sent: dict[str, list[float]] = {v: [] for v in ids}
    for step in range(4):
        order = [ids[(i + step) % 3] for i in range(3)]  # the rows change order every step
        obs = np.column_stack([rng.uniform(10, 30, 3), rng.uniform(-1, 1, 3),
                               rng.uniform(5, 60, 3), rng.uniform(-2, 2, 3)])
        remembered = controller.history.columns(order)
        for row, v in enumerate(order):
            assert np.allclose(remembered[row], (sent[v][::-1] + [0.0, 0.0])[:2])
        accel = controller.acceleration(obs, chains, order, ahead, {"h": 0.0})
        amnesic.history.reset()
        forgot = amnesic.acceleration(obs, chains, order, ahead, {"h": 0.0})
        if step > 0:
            assert np.abs(accel - forgot).max() > 1e-6
        for row, v in enumerate(order):
            sent[v].append(float(accel[row]))
