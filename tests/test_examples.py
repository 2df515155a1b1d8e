"""The examples under examples/ run as a new user runs them, in a tiny configuration: an SB3 model
and an RLlib checkpoint trained by their scripts, each scored by `carl-sumo simulate` through the
controller protocol (skipped where the library is not installed)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from carl_sumo.cli import main
from carl_sumo.control.external import load_external

from conftest import REPO_ROOT

EXAMPLES = REPO_ROOT / "examples"
OBS = np.array([[20.0, 0.1, 30.0, -0.5], [18.0, -0.4, 25.0, 1.0], [15.0, 0.0, 40.0, 0.0]])


def _run_script(script: str, *args: str, cwd: Path) -> str:
    """Run an example script in a fresh process (each libsumo lives in its own) and return its
    standard output; fails the test with the script's error output."""
    done = subprocess.run([sys.executable, str(EXAMPLES / script), *args], cwd=cwd,
                          capture_output=True, text=True, timeout=180,
                          env={**os.environ, "PYTHONPATH": str(REPO_ROOT)})
    assert done.returncode == 0, done.stderr[-3000:]
    return done.stdout


def _score(name: str, out: Path, capsys) -> dict:
    """`carl-sumo simulate` of the controller and idm-external on 2 events; their metrics."""
    code = main(["simulate", "--controller", f"{name},idm-external", "--events", "2",
                 "--vehicles", "4", "--workers", "1", "--json", str(out)])
    printed = capsys.readouterr()
    assert code == 0, printed.err
    return json.loads(out.read_text())["controllers"]


def test_sb3_example_trains_and_scores_through_simulate(tmp_path, monkeypatch, capsys):
    pytest.importorskip("stable_baselines3")
    model = tmp_path / "sb3.zip"
    printed = _run_script("sb3_platoon.py", "--steps", "300", "--out", str(model), cwd=tmp_path)
    assert model.is_file() and "wrote" in printed
    monkeypatch.setenv("CARL_SUMO_SB3_MODEL", str(model))
    name = f"{EXAMPLES / 'sb3_platoon.py'}:Controller"
    controller = load_external(name)
    controller.reset(3)
    adj = controller.adjustment(OBS)
    one_by_one = [controller.model.predict(row.astype(np.float32), deterministic=True)[0][0]
                  for row in OBS]
    assert adj.shape == (3,) and np.allclose(adj, one_by_one, atol=1e-6)
    assert np.all(np.abs(adj) <= controller.model.action_space.high[0] + 1e-9)
    results = _score(name, tmp_path / "sb3.json", capsys)
    assert len(results[name]["events"]) == 2
    assert results[name]["metrics"] != results["idm-external"]["metrics"]


def test_sb3_controller_without_a_model_is_one_line_exit_2(tmp_path, monkeypatch, capsys):
    pytest.importorskip("stable_baselines3")
    monkeypatch.setenv("CARL_SUMO_SB3_MODEL", str(tmp_path / "missing.zip"))
    code = main(["simulate", "--controller", f"{EXAMPLES / 'sb3_platoon.py'}:Controller",
                 "--events", "1"])
    err = capsys.readouterr().err
    assert code == 2 and "no SB3 model" in err and len(err.strip().splitlines()) == 1


def test_rllib_example_trains_ppo_and_scores_the_checkpoint(tmp_path, monkeypatch, capsys):
    pytest.importorskip("ray.rllib")
    checkpoint = tmp_path / "ckpt"
    printed = _run_script("rllib_platoon.py", "--iterations", "1", "--batch", "400", "--out",
                          str(checkpoint), cwd=tmp_path)
    assert "iteration 1/1" in printed
    monkeypatch.setenv("CARL_SUMO_RLLIB_CHECKPOINT", str(checkpoint))
    name = f"{EXAMPLES / 'rllib_platoon.py'}:Controller"
    controller = load_external(name)
    controller.reset(3)
    adj = controller.adjustment(OBS)
    single = np.array([controller.adjustment(row[None])[0] for row in OBS])
    assert adj.shape == (3,) and np.allclose(adj, single, atol=1e-6)
    assert np.all((controller.low <= adj) & (adj <= controller.high))
    results = _score(name, tmp_path / "rllib.json", capsys)
    assert len(results[name]["events"]) == 2
    assert results[name]["metrics"] != results["idm-external"]["metrics"]
