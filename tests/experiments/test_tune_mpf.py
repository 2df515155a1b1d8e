"""``carl-sumo tune mpf``: the multi-predecessor law's robust ‖Γ‖∞ (each class a homogeneous
platoon at its own gap, from the exact discrete recurrence), the tuning of its weights on the
training events, ``mpf-tuned`` reading the result, the shipped tuned weights running, and bad
input (one line, exit 2, before any simulation)."""

from __future__ import annotations

import json
import math
from dataclasses import replace

import numpy as np
import pytest

from carl_sumo.cli import main
from carl_sumo.control.channel import plant_impairments
from carl_sumo.control.ploeg_names import PRESETS, parse_ploeg, tuned_file_for, without_washout
from carl_sumo.control.transfer import (ROBUST_OMEGAS, gamma_discrete, gamma_links_discrete,
                                        robust_hinf)
from carl_sumo.errors import InputError
from carl_sumo.experiments.tune import TuneConfig
from carl_sumo.experiments.tune_mpf import class_hinf

BASE = parse_ploeg(without_washout("product-base"))
CARS, TRUCKS = [(0.1, 0), (0.5, 1)], [(0.4, 1), (0.6, 2)]
REAL = plant_impairments("real")


def _links(h, weights, corners, n=10):
    return max(float(np.abs(gamma_links_discrete(ROBUST_OMEGAS, n, h, BASE.kp, BASE.kd, tau,
                                                 dead, 1, weights))[1:].max())
               for tau, dead in corners)


def test_mpf_robust_hinf_is_the_largest_discrete_link_gain_of_each_homogeneous_platoon():
    for weights in [(0.7, 0.3), (0.6, 0.3, 0.1), (0.5, 0.5)]:
        for h, corners in [(0.6, CARS), (0.8, TRUCKS)]:
            assert robust_hinf(h, BASE.kp, BASE.kd, corners, 1, weights=weights) == \
                _links(h, weights, corners)
    # r = 1 through the recurrence is Ploeg's single link (what robust_hinf took before)
    for tau, dead in TRUCKS:
        one = np.abs(gamma_discrete(ROBUST_OMEGAS, 0.8, BASE.kp, BASE.kd, tau, dead, 1))
        links = np.abs(gamma_links_discrete(ROBUST_OMEGAS, 10, 0.8, BASE.kp, BASE.kd, tau, dead,
                                            1, (1.0,)))
        assert np.allclose(links[1:], one, atol=1e-12)
    # the two-ahead weights are string stable on both classes, equal weights are not on trucks
    assert robust_hinf(0.8, BASE.kp, BASE.kd, TRUCKS, 1, weights=(0.7, 0.3)) <= 1.0
    assert robust_hinf(0.8, BASE.kp, BASE.kd, TRUCKS, 1, weights=(0.5, 0.5)) > 1.1
    with pytest.raises(ValueError):
        robust_hinf(0.8, BASE.kp, BASE.kd, TRUCKS, 1, mixed=True, weights=(0.7, 0.3))


def test_the_check_of_the_fleet_takes_each_class_at_its_own_gap():
    cfg = TuneConfig(impairments=REAL, n_followers=10, string_stable=True)
    law = replace(BASE, weights=(0.5, 0.5))
    cars, trucks = _links(0.6, (0.5, 0.5), CARS), _links(0.8, (0.5, 0.5), TRUCKS)
    assert class_hinf(law, cfg) == max(cars, trucks)
    # without ht every class runs at h
    assert class_hinf(replace(law, heavy_gap_s=None), cfg) == \
        max(cars, _links(0.6, (0.5, 0.5), TRUCKS))


def test_tune_mpf_on_a_tiny_grid_writes_weights_that_mpf_tuned_runs(capsys, tmp_path,
                                                                    small_table_path):
    out = tmp_path / "mpf.json"
    code = main(["tune", "mpf", "--data", str(small_table_path), "--split", "train",
                 "--vehicles", "5", "--heard", "2", "--w2", "0.3,0.5", "--max-extensions", "0",
                 "--workers", "1", "--plant", "real", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    payload = json.loads(out.read_text())
    assert payload["controller"] == "mpf" and payload["split"] == "train"
    assert payload["plant"] == REAL.plant_key and payload["events"] == 1
    rows = {tuple(g["weights"]): g for g in payload["grid"]}
    assert set(rows) == {(1.0,), (0.7, 0.3), (0.5, 0.5)}
    assert math.isclose(rows[(1.0,)]["objective"], 2.0)  # the base is the reference
    # equal weights amplify on the fourth link of 5 trucks: not run (3 followers would be stable)
    assert rows[(0.5, 0.5)]["hinf"] > 1 and "jerk_mps3" not in rows[(0.5, 0.5)]
    assert rows[(0.7, 0.3)]["hinf"] <= 1 and "jerk_mps3" in rows[(0.7, 0.3)]
    entry = payload["entries"][0]
    assert entry["h"] == 0.6 and entry["base_h"] == 0.6
    assert entry["objective"] == min(g["objective"] for g in rows.values() if g["safe"])
    assert entry["name"] == rows[tuple(entry["weights"])]["name"]
    law = parse_ploeg("mpf-tuned", out, REAL.plant_key)
    assert law == parse_ploeg(entry["name"]) == parse_ploeg("mpf-tuned:h=0.6", out,
                                                            REAL.plant_key)
    assert law.kp == BASE.kp and law.heavy_gap_s == 0.8 and law.washout_s is None
    with pytest.raises(InputError, match="tuned for h = 0.6 s on this plant"):
        parse_ploeg("mpf-tuned:h=0.8", out, REAL.plant_key)
    with pytest.raises(InputError, match="no mpf weights tuned for the plant 'ideal'"):
        parse_ploeg("mpf-tuned", out, "ideal")
    with pytest.raises(InputError, match="'x=1' is not an option"):
        parse_ploeg("mpf-tuned:x=1", out, REAL.plant_key)


@pytest.mark.parametrize("argv, words", [
    (["--split", "test"], "not allowed"),
    (["--w2", "-0.1"], "--w2 must be positive"),
    (["--w3", "nan"], "--w3 must be positive"),
    (["--heard", "3", "--vehicles", "3"], "--heard 3: in a platoon of 3 followers"),
    (["--heard", "4"], "r = 2 or 3"),
    (["--heard", "2.5"], "--heard must be whole numbers"),
    (["--w2", "0.95", "--w3", "0.1", "--heard", "3"], "leave no weights"),
    (["--base", "acc:h=2"], "the base of mpf must be Ploeg's CACC"),
    (["--base", "ploeg:h=-1"], "h must be a positive number"),
    (["--kp", "0.1"], "--kp: not an option of `carl-sumo tune mpf`"),
])
def test_tune_mpf_bad_input_exits_2_before_running(capsys, tmp_path, small_table_path, argv,
                                                   words):
    out = tmp_path / "t.json"
    assert main(["tune", "mpf", "--data", str(small_table_path), "--out", str(out)] + argv) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1
    assert not out.exists()


def test_the_shipped_mpf_tuned_runs_on_the_real_plant(capsys, small_table_path):
    shipped = json.loads(tuned_file_for("mpf", REAL.plant_key).read_text())
    assert shipped["split"] == "train" and shipped["entries"][0]["name"]
    assert main(["simulate", "--data", str(small_table_path), "--split", "test", "--events", "1",
                 "--vehicles", "4", "--plant", "real", "--controller", "mpf-tuned",
                 "--workers", "1"]) == 0
    printed = capsys.readouterr().out
    assert "mpf-tuned" in printed
    assert PRESETS["product-base"].startswith("ploeg:h=0.6")


def test_the_tables_list_mpf_tuned_beside_the_product_and_its_base():
    from carl_sumo.experiments.chain_controllers import resolve_study_controller
    from carl_sumo.experiments.suite import PRODUCT_MPF, PRODUCT_STEM, plan_suite
    from carl_sumo.manoeuvres.tables import PLANT_CONTROLLERS, PRODUCT_BASE

    from conftest import NET

    suite = plan_suite("real", quick=True, events=1, net=NET, warmup_s=0.0,
                       plant=REAL.plant_key)
    table1 = suite.tables[0]
    assert PRODUCT_MPF == "mpf-tuned:h=0.6"
    for key in (PRODUCT_MPF, PRESETS["product-base"], PRODUCT_STEM):
        assert key in table1.models
    assert (PRODUCT_STEM, PRODUCT_MPF) in table1.paired
    assert PRODUCT_MPF not in plan_suite(quick=True, events=1, net=NET).tables[0].models
    real = PLANT_CONTROLLERS["real"]
    assert real.index(PRODUCT_BASE) + 1 == real.index(PRODUCT_MPF)  # the product's start after its base
    assert real.index("mpc-tuned:h=0.6") > real.index(PRODUCT_MPF)  # the MPC at the same gap
    _, chains = resolve_study_controller("mpf-tuned", REAL.plant_key)  # the study's plant
    assert chains.controller.params == parse_ploeg("mpf-tuned", None, REAL.plant_key)
    with pytest.raises(InputError, match="no mpf weights tuned for the plant 'ideal'"):
        resolve_study_controller("mpf-tuned")
