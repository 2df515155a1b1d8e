"""Resume (issue 37): a run stopped at a checkpoint and resumed ends exactly as the uninterrupted
run with the same seed (the same actor, bit for bit, and the same learning curve), its curve has
every step once even after a kill left rows past the checkpoint, and a checkpoint already at
``--steps`` resumed into a new ``--out`` writes the policy."""

from __future__ import annotations

from pathlib import Path

import pandas as pd
import pytest
import torch

from carl_sumo.cli import main

from conftest import NET, braking_event, event_table


@pytest.fixture(scope="module")
def events(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("events") / "events.csv"
    event_table([braking_event(150, "brake_a"), braking_event(120, "brake_b", v0=10.0)]
                ).to_csv(path, index=False)
    return path


def argv(events: Path, out: Path, steps: int, *extra: str) -> list[str]:
    """A CA-TD3 run of 2 followers in 2 environments: episodes of 12-15 s end and restart
    during the run, updates from step 20, a validation every 15 steps, a checkpoint every 45."""
    return ["train", "--algo", "ca-td3", "--vehicles", "2", "--data", str(events), "--split",
            "all", "--net", str(NET), "--learning-starts", "20", "--eval-every", "15",
            "--checkpoint-every", "45", "--envs", "2", "--seed", "5", "--hidden", "16",
            "--steps", str(steps), "--out", str(out), *extra]


def actor(path: Path) -> dict[str, torch.Tensor]:
    return torch.load(path, weights_only=True)["actor"]


def curve(path: Path) -> pd.DataFrame:
    return pd.read_csv(path).drop(columns=["wall_s"])


@pytest.fixture(scope="module")
def uninterrupted(events, tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("whole") / "p.pt"
    assert main(argv(events, out, 135)) == 0
    return out


def test_a_stopped_run_resumed_ends_exactly_as_the_uninterrupted_run(events, uninterrupted,
                                                                     tmp_path):
    out = tmp_path / "p.pt"
    assert main(argv(events, out, 90)) == 0  # stopped at its checkpoint at step 90
    # a run killed after a validation past its checkpoint has left that row behind
    rows = out.with_suffix(".csv").read_text().splitlines()
    out.with_suffix(".csv").write_text("\n".join(rows + [rows[-1].replace("90,", "105,", 1)])
                                       + "\n")
    assert main(argv(events, out, 135, "--resume", str(out.with_suffix(".ckpt")))) == 0
    resumed, whole = curve(out.with_suffix(".csv")), curve(uninterrupted.with_suffix(".csv"))
    assert list(resumed["step"]) == list(range(15, 136, 15))  # every step once
    pd.testing.assert_frame_equal(resumed, whole)
    mine, theirs = actor(out), actor(uninterrupted)
    assert mine.keys() == theirs.keys()
    for key in mine:
        assert torch.equal(mine[key], theirs[key]), key
    last = torch.load(out.with_suffix(".ckpt"), weights_only=True)
    for key, value in torch.load(uninterrupted.with_suffix(".ckpt"),
                                 weights_only=True)["agent"].items():
        assert torch.equal(last["agent"][key], value), key


def test_a_finished_checkpoint_resumed_into_a_new_out_writes_the_policy(events, uninterrupted,
                                                                        tmp_path, capsys):
    new = tmp_path / "copy.pt"
    assert main(argv(events, new, 135, "--resume",
                     str(uninterrupted.with_suffix(".ckpt")))) == 0
    out = capsys.readouterr().out
    assert "nothing to train" in out and f"wrote {new}" in out
    assert new.read_bytes() == uninterrupted.read_bytes()
