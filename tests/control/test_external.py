"""Controllers from outside carl-sumo (``module:attribute``, ``file.py:attribute``) run in every
table like the built-in ones, in worker processes too; bad names are one line and exit 2."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from carl_sumo.cli import main
from carl_sumo.control.external import is_external_name

from conftest import NET

EXAMPLE = str(Path(__file__).resolve().parents[2] / "examples" / "my_controller.py")


def test_names():
    assert is_external_name("examples/my_controller.py:constant_gap")
    assert is_external_name("mypkg.controllers:MyCACC")
    for name in ("ploeg:h=0.8", "acc:h=3:kp=0.2", "idm", "policies/ca_td3_10.pt"):
        assert not is_external_name(name)


def test_an_external_adjustment_of_zero_is_idm_and_a_callable_runs(tmp_path, capsys):
    out = tmp_path / "r.json"
    assert main(["simulate", "--net", str(NET), "--events", "3", "--vehicles", "3",
                 "--controller", f"{EXAMPLE}:ZeroAdjust,idm-external,{EXAMPLE}:constant_gap",
                 "--json", str(out)]) == 0
    zero, idm, gap = json.loads(out.read_text())["controllers"].values()
    assert zero["metrics"] == idm["metrics"]
    assert gap["metrics"]["collisions"] == 0 and gap["metrics"] != idm["metrics"]


@pytest.mark.parametrize("name,message", [
    ("nowhere/x.py:f", "no file"), (f"{EXAMPLE}:missing", "no attribute"),
    ("no_such_module_xyz:f", "does not import")])
def test_bad_external_names_are_one_line_and_exit_2(capsys, name, message):
    assert main(["simulate", "--net", str(NET), "--events", "1", "--controller", name]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and "\n" not in err
