"""``--scenario`` on ``simulate`` and ``replay`` end to end in real SUMO (shipped default leaders,
networks/i80.net.xml), and its one-line exit-2 errors before any simulation."""

import json
import xml.etree.ElementTree as ET

import pytest

from carl_sumo.cli import main

from conftest import REPO_ROOT

MADDPG = str(REPO_ROOT / "policies" / "maddpg_10.pt")
EVENT_ID = "sumo42_f1865_l1847_fr5798"


def run(capsys, *argv):
    code = main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


@pytest.mark.parametrize("argv, message", [
    (["simulate", "--scenario", "cut-in:f=1.5"], "gap fraction f must lie in (0, 1)"),
    (["simulate", "--scenario", "cut-in:f=0"], "gap fraction f must lie in (0, 1)"),
    (["simulate", "--scenario", "cut-in:k=12", "--vehicles", "10"], "beyond the platoon"),
    (["simulate", "--scenario", "cut-out:k=10", "--vehicles", "10"], "beyond the platoon"),
    (["simulate", "--scenario", "lane-drop"], "unknown manoeuvre"),
    (["simulate", "--scenario", "cut-in:k=1:k=2"], "k is given twice"),
    (["simulate", "--scenario", "cut-in", "--scenario-seed", "-1"],
     "--scenario-seed must be a whole number from 0"),
    (["simulate", "--scenario", "cut-in:t=30"], "does not fit event"),
    (["simulate", "--scenario", "cut-in", "--controller", MADDPG],
     "n/a: fixed size"),
    (["simulate", "--scenario", "cut-in", "--controller", "idm", "--sensor-noise"],
     "idm: impairments (--comm-*, --sensor-noise)"),
    (["replay", "--scenario", "join:k=11", "--event", EVENT_ID, "--fcd", "x.xml"],
     "beyond the platoon"),
    (["replay", "--scenario", "cut-in", "--event", EVENT_ID, "--fcd", "x.xml", "--gui",
      "--screenshot", "v.png"], "--screenshot is for replays without --scenario"),
])
def test_bad_scenarios_end_with_one_line_and_exit_2(capsys, tmp_path, monkeypatch, argv, message):
    monkeypatch.chdir(tmp_path)
    code, out, err = run(capsys, *argv, "--events", "3") if argv[0] == "simulate" else \
        run(capsys, *argv)
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1
    assert not list(tmp_path.iterdir())  # nothing written, nothing run


def test_simulate_scenario_prints_a_row_per_controller_and_writes_json(capsys, tmp_path):
    out_json = tmp_path / "cut.json"
    code, out, _ = run(capsys, "simulate", "--scenario", "cut-out", "--events", "2",
                       "--vehicles", "4", "--controller", "idm,policies/maddpg_10.pt",
                       "--workers", "1", "--json", str(out_json))
    assert code == 0
    lines = out.splitlines()
    assert "min gap (m)" in lines[0] and "settle (s)" in lines[0]
    assert lines[2].split()[:2] == ["idm", "2"] and "n/a: fixed size" in lines[3]
    payload = json.loads(out_json.read_text())
    idm, maddpg = payload["controllers"]
    assert maddpg == {"controller": "policies/maddpg_10.pt", "not_applicable": "n/a: fixed size"}
    assert idm["manoeuvre"]["done"] == 2 and len(idm["events"]) == 2
    assert idm["events"][0]["manoeuvre"].startswith("cut-out k=")


def _fcd(path):
    """{vehicle: [(time, lane, leaderID), ...]} of an FCD file."""
    out = {}
    for step in ET.parse(path).getroot():
        for v in step:
            out.setdefault(v.get("id"), []).append((float(step.get("time")), v.get("lane"),
                                                    v.get("leaderID")))
    return out


def test_replay_cut_in_writes_the_lane_change_to_fcd(capsys, tmp_path):
    fcd = tmp_path / "cut_in.xml"
    code, out, _ = run(capsys, "replay", "--scenario", "cut-in:k=3:t=6", "--event", EVENT_ID,
                       "--vehicles", "6", "--controller", "ploeg-tuned:h=0.8", "--fcd", str(fcd))
    assert code == 0 and "done=1" in out and "collisions=0" in out
    rows = _fcd(fcd)
    lanes = [lane for _, lane, _ in rows["human"]]
    assert lanes[0] == "i80_approach_3" and lanes[-1].endswith("_4")
    assert rows["f3"][0][2] == "f2" and rows["f3"][-1][2] == "human"
    assert rows["human"][-1][2] == "f2"


def test_replay_cut_out_on_the_real_plant(capsys, tmp_path):
    fcd = tmp_path / "cut_out.xml"
    code, out, _ = run(capsys, "replay", "--scenario", "cut-out:k=2:t=6", "--event", EVENT_ID,
                       "--vehicles", "5", "--controller", "policies/ca_td3_real_10.pt",
                       "--plant", "real", "--fcd", str(fcd))
    assert code == 0 and "done=1" in out
    rows = _fcd(fcd)
    assert rows["f1"][0][1].endswith("_4") and rows["f1"][-1][1].endswith("_3")
    assert rows["f2"][0][2] == "f1" and rows["f2"][-1][2] == "f0"


def test_evaluate_scenarios_writes_a_table_per_manoeuvre_and_plant(capsys, tmp_path):
    code, out, _ = run(capsys, "evaluate", "--suite", "scenarios", "--scenario", "cut-out",
                       "--quick", "--events", "2", "--workers", "1",
                       "--out", str(tmp_path / "s"))
    assert code == 0
    text = (tmp_path / "s" / "scenarios.md").read_text()
    assert "## cut-out ideal plant" in text and "## cut-out real plant" in text
    assert text.count("n/a: fixed size") == 2  # MADDPG in both tables
    payload = json.loads((tmp_path / "s" / "scenarios.json").read_text())
    assert set(payload["tables"]) == {"cut-out ideal", "cut-out real"}
    # a cut-out needs no room, so it happened for all: its example replay and figure
    assert (tmp_path / "s" / "cut-out.png").stat().st_size > 0
    assert "i80_approach_3" in (tmp_path / "s" / "fcd" / "cut-out.xml").read_text()


def test_scenario_on_another_suite_is_refused(capsys, tmp_path):
    code, _, err = run(capsys, "evaluate", "--suite", "paper", "--scenario", "cut-in",
                       "--out", str(tmp_path / "p"))
    assert code == 2 and "--suite scenarios" in err
