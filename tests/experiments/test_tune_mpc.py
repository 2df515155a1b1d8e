"""``carl-sumo tune mpc``: the MPC's weights tuned on the training events with ‖Γ‖∞ measured in
SUMO before a point runs, ``mpc-tuned`` reading the result in every command, and bad input (one
line, exit 2, before any simulation)."""

from __future__ import annotations

import json
import math

import pytest

from carl_sumo.cli import main
from carl_sumo.control.channel import plant_impairments
from carl_sumo.control.classical import classical_controller, time_gap_of
from carl_sumo.control.mpc import parse_mpc
from carl_sumo.errors import InputError
from carl_sumo.experiments.tune import TuneConfig
from carl_sumo.experiments.tune_mpc import MpcGrid, tune_mpc

REAL = plant_impairments("real")


def test_tune_mpc_runs_only_string_stable_weights_and_mpc_tuned_runs_the_choice(
        tmp_path, small_table_path):
    from conftest import NET

    out = tmp_path / "mpc.json"
    cfg = TuneConfig(gaps_s=(0.6,), n_followers=4, max_extensions=0, data=str(small_table_path),
                     split="train", net=str(NET), workers=1, law="mpc", impairments=REAL,
                     string_stable=True, command="test")
    # at 0.86 rad/s the MPC as an ACC at 1.4 s amplifies on the first link (docs/baselines.md:
    # 1.023 on cars at 24 frequencies); at 2 s it does not
    grid = MpcGrid(wq=(0.1,), wv=(1.0,), wu=(2.0,), wj=(0.2,), ha=(1.4, 2.0), omegas=(0.86,))
    payload = tune_mpc(cfg, grid, out, log=None)
    assert json.loads(out.read_text()) == json.loads(json.dumps(payload))
    assert payload["controller"] == "mpc" and payload["plant"] == REAL.plant_key
    rows = {g["ha"]: g for g in payload["grid"]}
    assert rows[1.4]["hinf"] > 1.0 and "jerk_mps3" not in rows[1.4] and not rows[1.4]["safe"]
    assert rows[2.0]["hinf"] <= 1.0 and "jerk_mps3" in rows[2.0]
    entry = payload["entries"][0]
    assert entry["base"]["name"].startswith("ploeg:h=0.6") and entry["base"]["metrics"]
    assert entry["base"]["hinf"] <= 1.0 and entry["base"]["safe"]  # the product's base
    assert entry["string_stable_points"] == 1 and entry["points"] == 2
    if entry["name"] is not None:  # the one stable point is chosen when it is safe
        assert entry["name"] == rows[2.0]["name"] and entry["ha"] == 2.0
        assert math.isclose(entry["objective"], rows[2.0]["objective"])
        assert not entry["interior"]  # ha's high edge could grow; one-value axes cannot
        params = parse_mpc(entry["name"])
        assert params.alone_gap_s == 2.0 and params.heavy_gap_s == 0.8
    else:
        assert not rows[2.0]["safe"]


def test_mpc_tuned_reads_the_shipped_weights_of_its_plant(tmp_path, monkeypatch):
    from carl_sumo.control import ploeg_names

    folder = tmp_path / "policies"
    folder.mkdir()
    ploeg = ploeg_names.TUNED_FILE
    monkeypatch.setattr(ploeg_names, "TUNED_FILE", folder / ploeg.name)
    (folder / ploeg.name).write_text(ploeg.read_text())
    name = "mpc:h=0.6:N=30:wq=0.2:wv=1:wu=2:wj=0.2:ha=2:ht=0.8:ttc=2:rb=1:ra=1"
    (folder / "mpc_tuned_x.json").write_text(json.dumps({
        "controller": "mpc", "plant": REAL.plant_key,
        "entries": [{"h": 0.6, "base_h": 0.6, "name": name},
                    {"h": 0.5, "base_h": 0.6, "name": None}]}))
    law = classical_controller("mpc-tuned", REAL.plant_key)
    assert law.params == parse_mpc(name) and law.name == "mpc-tuned"
    assert classical_controller("mpc-tuned:h=0.6", REAL.plant_key).params == parse_mpc(name)
    assert time_gap_of("mpc-tuned") == (2.0, 0.6)
    with pytest.raises(InputError, match="no safe weights for h = 0.5 s"):
        classical_controller("mpc-tuned:h=0.5", REAL.plant_key)
    with pytest.raises(InputError, match="no mpc weights tuned for the plant 'ideal'"):
        classical_controller("mpc-tuned")
    with pytest.raises(InputError, match="tuned for h = 0.5, 0.6 s on this plant"):
        classical_controller("mpc-tuned:h=0.8", REAL.plant_key)


@pytest.mark.parametrize("argv, words", [
    (["--split", "test"], "not allowed"),
    (["--wq", "-0.1"], "--wq must be positive"),
    (["--wv", "nan"], "--wv must be positive"),
    (["--ha", "0.01"], "--ha 0.01: the time gap of a vehicle that hears no plan"),
    (["--wu", "1e9"], "--wu 1e+09"),
    (["--base", "acc-tuned:h=2"], "must be a constant-time-gap law with its gains"),
    (["--w2", "0.1"], "--w2: not an option of `carl-sumo tune mpc`"),
    (["--kp", "0.1"], "--kp: not an option of `carl-sumo tune mpc`"),
])
def test_tune_mpc_bad_input_exits_2_before_running(capsys, tmp_path, small_table_path, argv,
                                                   words):
    out = tmp_path / "t.json"
    assert main(["tune", "mpc", "--data", str(small_table_path), "--plant", "real", "--out",
                 str(out)] + argv) == 2
    err = capsys.readouterr().err
    assert words in err and err.count("\n") == 1
    assert not out.exists()


def test_the_other_laws_refuse_the_mpc_axes(capsys, small_table_path):
    for law in ("mpf", "ploeg"):
        assert main(["tune", law, "--data", str(small_table_path), "--wq", "0.1"]) == 2
        assert "--wq: not an option of `carl-sumo tune " + law in capsys.readouterr().err
