"""What a training run reports: progress lines without a terminal, the learning-curve figure,
TensorBoard scalars (validation, reward, losses, Q) with ``--tensorboard``, and one line with
exit 2 when no TensorBoard library is installed."""

from __future__ import annotations

import io
import struct
import sys
from pathlib import Path

import pytest

from carl_sumo.cli import main
from carl_sumo.learn.curve import LOG_COLUMNS
from carl_sumo.learn.report import ProgressLines, plot_curve

from conftest import NET


def test_progress_lines_every_n_seconds_with_eta_rate_and_validation():
    now = [0.0]
    out = io.StringIO()
    bar = ProgressLines("td3", total=1000, initial=0, every_s=10.0, file=out,
                        clock=lambda: now[0])
    for _ in range(100):  # 100 steps in 25 s: lines at 10 s and 20 s
        now[0] += 0.25
        bar.update()
    bar.set_postfix(val="1.234", jerk="0.100")
    now[0] += 0.25
    bar.update()
    bar.close()
    lines = out.getvalue().splitlines()
    assert len(lines) == 3  # two on the clock, one at the end
    assert lines[0] == "td3: step 40/1000 (4 %), 4.0 steps/s, ETA 4m00s"
    assert lines[-1].endswith("last validation: val=1.234, jerk=0.100")
    assert "step 101/1000" in lines[-1]


def test_learning_curve_figure(tmp_path):
    row = {name: "1.0" for name in LOG_COLUMNS}
    rows = [[{**row, "step": str(s), "jerk_mps3": str(1.0 / s)}[c] for c in LOG_COLUMNS]
            for s in (100, 200, 300)]
    rows[1][LOG_COLUMNS.index("headway_s")] = ""  # an older curve's empty value
    png = plot_curve(rows, tmp_path / "run.png", "td3: run.pt")
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in tmp_path.iterdir()] == ["run.png"]


def _scalars(logdir: Path) -> dict[str, list[float]]:
    """tag -> values of the scalar summaries in a TensorBoard log folder (its TFRecord files)."""
    from tensorboardX.proto import event_pb2

    tags: dict[str, list[float]] = {}
    for path in logdir.glob("events.out.tfevents.*"):
        data = path.read_bytes()
        pos = 0
        while pos < len(data):
            (length,) = struct.unpack("<Q", data[pos:pos + 8])
            event = event_pb2.Event.FromString(data[pos + 12:pos + 12 + length])
            pos += 12 + length + 4
            for value in event.summary.value:
                tags.setdefault(value.tag, []).append(value.simple_value)
    return tags


def _train_argv(tmp_path: Path, *extra: str) -> list[str]:
    return ["train", "--algo", "td3", "--vehicles", "2", "--steps", "400", "--envs", "1",
            "--learning-starts", "100", "--eval-every", "200", "--checkpoint-every", "400",
            "--eval-events", "1", "--net", str(NET), "--out", str(tmp_path / "run.pt"), *extra]


def test_train_logs_to_tensorboard_plots_its_curve_and_reports_in_lines(tmp_path, capsys):
    pytest.importorskip("tensorboardX")
    code = main(_train_argv(tmp_path, "--tensorboard", str(tmp_path / "tb"),
                            "--progress-every", "0.01"))
    captured = capsys.readouterr()
    assert code == 0, captured.err
    tags = _scalars(tmp_path / "tb")
    for tag in ("validation/val_reward", "validation/jerk_mps3", "validation/collisions",
                "train/reward"):
        assert len(tags[tag]) == 2, tag  # at steps 200 and 400
    for tag in ("train/critic_loss", "train/actor_loss", "train/q_mean"):
        assert tags[tag], tag
    lines = [ln for ln in captured.err.splitlines() if ln.startswith("td3: step")]
    assert lines and "steps/s" in lines[-1] and "ETA" in lines[-1]
    assert lines[-1].startswith("td3: step 400/400") and "last validation: " in lines[-1]
    assert "\r" not in captured.err  # no progress bar without a terminal
    assert (tmp_path / "run.png").read_bytes()[:4] == b"\x89PNG"
    assert (tmp_path / "run.csv").is_file()


def test_tensorboard_without_the_library_is_one_line_exit_2(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "tensorboardX", None)  # import fails as if not installed
    monkeypatch.setitem(sys.modules, "torch.utils.tensorboard", None)
    code = main(_train_argv(tmp_path, "--tensorboard", str(tmp_path / "tb")))
    err = capsys.readouterr().err
    assert code == 2 and "pip install" in err and len(err.strip().splitlines()) == 1
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("value", ["0", "-1", "nan"])
def test_progress_every_must_be_positive(tmp_path, capsys, value):
    code = main(_train_argv(tmp_path, "--progress-every", value))
    err = capsys.readouterr().err
    assert code == 2 and "--progress-every" in err and len(err.strip().splitlines()) == 1
