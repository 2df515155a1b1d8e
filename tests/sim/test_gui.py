"""replay --gui: sumo-gui's options and TraCI calls (no display needed), their vehicle calls on a
real libsumo simulation, the options' bad input, and a real sumo-gui under Xvfb (skipped where
``xvfb-run`` is absent)."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from carl_sumo.cli import main
from carl_sumo.errors import InputError
from carl_sumo.sim.gui import COLOURS, VIEW, GuiView, apply_calls, parse_screenshot
from carl_sumo.sim.sumo import PlatoonSim, close_sumo

from conftest import NET, REPO_ROOT, braking_event


def test_start_args_delay_quit_and_window():
    assert GuiView().start_args() == ["--start", "--delay", "100"]
    view = GuiView(delay_ms=20, quit_on_end=True, screenshot=Path("a.png"))
    assert view.start_args() == ["--start", "--delay", "20", "--quit-on-end", "true",
                                 "--window-size", "1280,720"]


def test_setup_colours_by_role_fits_the_platoon_and_tracks_the_head_follower():
    calls = GuiView().setup_calls("leader", ["f0", "f1", "f2"], "external", (200.0, 0.0),
                                  (40.0, 0.0))
    colours = {args[0]: args[1] for dom, meth, args in calls if meth == "setColor"}
    assert colours == {"leader": COLOURS["leader"], "f0": COLOURS["tracked"],
                       "f1": COLOURS["cacc"], "f2": COLOURS["cacc"]}
    (boundary,) = [args for _, meth, args in calls if meth == "setBoundary"]
    assert boundary == (VIEW, -40.0, -16.0, 280.0, 16.0)  # 160 m of platoon, 80 m either side
    assert GuiView.boundary((0.0, 0.0), (-10.0, 0.0)) == (-85.0, -8.0, 75.0, 8.0)  # 80 m at least
    assert GuiView.boundary((30.0, 40.0), (0.0, 0.0)) == (-45.0, -60.0, 75.0, 100.0)
    assert calls[-1] == ("gui", "trackVehicle", (VIEW, "f0"))
    human = GuiView(track="leader", zoom=800).setup_calls("leader", ["f0", "f1"], "krauss",
                                                          (0.0, 0.0), (-1.0, 0.0))
    assert ("vehicle", "setColor", ("f0", COLOURS["human"])) in human
    assert ("gui", "setZoom", (VIEW, 800)) in human and calls[-1][2][1] == "f0"
    assert human[-1] == ("gui", "trackVehicle", (VIEW, "leader"))
    assert not [c for c in human if c[1] == "setBoundary"]


def test_screenshot_is_requested_once_the_step_before_its_time():
    view = GuiView(screenshot=Path("s.png"), screenshot_s=5.0)
    view.setup_calls("leader", ["f0"], "external", (0.0, 0.0), (-10.0, 0.0))
    asked = [round(k * 0.1, 1) for k in range(100) if view.step_calls(k * 0.1)]
    assert asked == [4.9]
    assert GuiView().step_calls(3.0) == []


@pytest.mark.parametrize("text, expected", [("a.png", (Path("a.png"), 0.0)),
                                            ("out/b.png@12.5", (Path("out/b.png"), 12.5))])
def test_parse_screenshot(text, expected):
    assert parse_screenshot(text) == expected


@pytest.mark.parametrize("text", ["a.png@x", "a.png@-1", "a.txt", "@3", "a.png@nan"])
def test_parse_screenshot_refuses(text):
    with pytest.raises(InputError, match="--screenshot"):
        parse_screenshot(text)


def test_vehicle_calls_colour_a_real_simulation():
    import libsumo

    sim = PlatoonSim(NET, "external")
    try:
        sim.reset(braking_event(), 3)
        calls = GuiView().setup_calls(sim.leader_id, sim.ids, "external", (0.0, 0.0), (1.0, 0.0))
        apply_calls(libsumo, [c for c in calls if c[0] == "vehicle"])
        assert libsumo.vehicle.getColor("leader") == COLOURS["leader"]
        assert libsumo.vehicle.getColor("f0") == COLOURS["tracked"]
        assert libsumo.vehicle.getColor("f2") == COLOURS["cacc"]
    finally:
        close_sumo()


@pytest.mark.parametrize("argv, message", [
    (["--track", "f1"], "add --gui"),
    (["--screenshot", "s.png"], "add --gui"),
    (["--gui", "--track", "f7"], "no such vehicle"),
    (["--gui", "--delay", "-5"], "--delay"),
    (["--gui", "--zoom", "0"], "--zoom"),
    (["--gui", "--screenshot", "s.txt"], "name a .png"),
    (["--gui", "--screenshot", "s.png@500"], "after the end of event"),
])
def test_gui_options_bad_input_is_one_line_exit_2(tmp_path, capsys, argv, message):
    code = main(["replay", "--event", "stop_and_go", "--data", "stop-and-go", "--vehicles", "3",
                 "--fcd", str(tmp_path / "out.xml"), *[a.replace("s.", f"{tmp_path}/s.")
                                                       for a in argv]])
    err = capsys.readouterr().err
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert list(tmp_path.iterdir()) == []


def _pixels(png: Path, colour: tuple[int, int, int, int]) -> np.ndarray:
    """Columns (0..1 of the width) of the pixels of ``colour`` (RGB within 30) in an image."""
    import matplotlib.image

    image = matplotlib.image.imread(png)[..., :3] * 255.0
    near = np.all(np.abs(image - np.array(colour[:3])) < 30, axis=-1)
    return np.nonzero(near)[1] / image.shape[1]


@pytest.mark.skipif(shutil.which("xvfb-run") is None, reason="xvfb-run is not installed")
@pytest.mark.parametrize("track, centred", [(None, "tracked"), ("leader", "leader")])
def test_sumo_gui_under_xvfb_tracks_colours_and_screenshots(tmp_path, track, centred):
    shot, fcd = tmp_path / "view.png", tmp_path / "out.xml"
    cmd = ["xvfb-run", "-a", "-s", "-screen 0 1280x1024x24", sys.executable, "-m", "carl_sumo",
           "replay", "--gui", "--quit-on-end", "--delay", "0", "--screenshot", f"{shot}@8",
           "--controller", "idm-external", "--event", "stop_and_go", "--data", "stop-and-go",
           "--vehicles", "4", "--fcd", str(fcd)] + (["--track", track] if track else [])
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120, cwd=REPO_ROOT,
                          env={k: v for k, v in os.environ.items() if k != "DISPLAY"})
    assert done.returncode == 0, done.stderr[-2000:]
    assert f"view saved to {shot}" in done.stdout and fcd.stat().st_size > 0
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []
    for role in ("leader", "cacc") + (() if track else ("tracked",)):
        assert _pixels(shot, COLOURS[role]).size > 0, role
    columns = _pixels(shot, COLOURS[centred])
    assert abs(np.median(columns) - 0.5) < 0.05  # the view follows that vehicle
