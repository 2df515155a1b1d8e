"""What sumo-gui shows in ``replay --gui``: its command-line options and the TraCI calls that zoom
to the platoon, track one vehicle, colour the vehicles by role and take a screenshot.

Everything here is data (:meth:`GuiView.start_args`, :meth:`GuiView.setup_calls`,
:meth:`GuiView.step_calls`: lists of ``(domain, method, args)``), so it is tested without a
display; :func:`apply_calls` makes the calls on a running sumo-gui.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from carl_sumo.errors import InputError

VIEW = "View #0"
"""sumo-gui's first (and only) view."""

DT_S = 0.1  # the simulation step (s), as carl_sumo.sim.sumo has it

COLOURS: dict[str, tuple[int, int, int, int]] = {
    "leader": (220, 30, 30, 255),      # the recorded NGSIM leader: red
    "tracked": (0, 200, 255, 255),     # the vehicle the view follows: cyan
    "cacc": (40, 90, 230, 255),        # CACC followers (carl-sumo's or SUMO's CACC): blue
    "human": (240, 190, 0, 255),       # human-driver models (IDM, Krauss): amber
}
"""Vehicle colours (RGBA) by role."""

HUMAN_MODELS = ("idm", "krauss")
"""Follower models of ``PlatoonSim`` that are human drivers, not CACC."""


def parse_screenshot(text: str) -> tuple[Path, float]:
    """``PNG`` or ``PNG@TIME``: the file and the simulated time (s, default 0: the start) at which
    sumo-gui saves the view; InputError naming what is wrong."""
    path, sep, time = text.rpartition("@") if "@" in text else (text, "", "")
    try:
        time_s = float(time) if sep else 0.0
    except ValueError:
        time_s = math.nan
    if not path or not math.isfinite(time_s) or time_s < 0:
        raise InputError(f"--screenshot takes PNG or PNG@TIME (TIME in seconds >= 0), got {text!r}")
    if Path(path).suffix.lower() not in (".png", ".jpg", ".svg", ".pdf", ".eps"):
        raise InputError(f"--screenshot {path}: name a .png file (sumo-gui picks the format from "
                         "the suffix)")
    return Path(path), time_s


@dataclass
class GuiView:
    """How sumo-gui shows a replay: ``delay_ms`` between steps (100 ms = real time at 0.1 s
    steps), the vehicle to ``track`` (None: the head follower ``f0``), ``zoom`` in percent
    (None: the view fits the platoon with as much road again around it), ``quit_on_end``
    (close without the end-of-simulation dialog), ``screenshot`` file saved at simulated time
    ``screenshot_s`` (in a window of ``window`` pixels, so that screenshots are alike)."""

    delay_ms: float = 100.0
    track: str | None = None
    zoom: float | None = None
    quit_on_end: bool = False
    screenshot: Path | None = None
    screenshot_s: float = 0.0
    schema: str = "real world"
    window: tuple[int, int] = (1280, 720)
    _shot_taken: bool = field(default=False, repr=False)

    def start_args(self) -> list[str]:
        """sumo-gui's options before carl-sumo's simulation options."""
        args = ["--start", "--delay", f"{self.delay_ms:g}"]
        if self.quit_on_end:
            args += ["--quit-on-end", "true"]
        if self.screenshot is not None:
            args += ["--window-size", f"{self.window[0]},{self.window[1]}"]
        return args

    def tracked(self, followers: Sequence[str]) -> str:
        """The vehicle the view follows: ``track`` or the head follower."""
        return self.track if self.track is not None else followers[0]

    @staticmethod
    def boundary(front_xy: tuple[float, float], back_xy: tuple[float, float],
                 min_span_m: float = 80.0) -> tuple[float, float, float, float]:
        """(xmin, ymin, xmax, ymax) of the view (m): centred on the platoon, twice its extent
        (from the leader at ``front_xy`` to the last follower at ``back_xy``) along x and y,
        at least ``min_span_m`` along the longer; sumo-gui fits the box into its window."""
        (x0, y0), (x1, y1) = front_xy, back_xy
        dx, dy = abs(x1 - x0), abs(y1 - y0)
        scale = max(min_span_m / max(dx, dy, 1e-9), 1.0)
        half_x, half_y = dx * scale, dy * scale  # twice the extent: a half-width of the extent
        half_x, half_y = max(half_x, 0.1 * half_y), max(half_y, 0.1 * half_x)  # never flat
        cx, cy = (x0 + x1) / 2.0, (y0 + y1) / 2.0
        return (cx - half_x, cy - half_y, cx + half_x, cy + half_y)

    def setup_calls(self, leader: str, followers: Sequence[str], follower_model: str,
                    front_xy: tuple[float, float], back_xy: tuple[float, float]
                    ) -> list[tuple[str, str, tuple[Any, ...]]]:
        """The TraCI calls after the vehicles are inserted: colours by role, the schema, the
        view on the platoon (``front_xy``: the leader's position, ``back_xy``: the last
        follower's, m) and the tracked vehicle."""
        role = "human" if follower_model in HUMAN_MODELS else "cacc"
        track = self.tracked(followers)
        calls = [("vehicle", "setColor", (leader, COLOURS["leader"]))]
        calls += [("vehicle", "setColor", (vid, COLOURS["tracked" if vid == track else role]))
                  for vid in followers]
        calls.append(("gui", "setSchema", (VIEW, self.schema)))
        calls.append(("gui", "setZoom", (VIEW, self.zoom)) if self.zoom is not None
                     else ("gui", "setBoundary", (VIEW, *self.boundary(front_xy, back_xy))))
        calls.append(("gui", "trackVehicle", (VIEW, track)))
        self._shot_taken = False
        return calls

    def step_calls(self, time_s: float) -> list[tuple[str, str, tuple[Any, ...]]]:
        """The TraCI calls after the step that reached simulated time ``time_s`` (s): the
        screenshot once that time is within a step (sumo-gui saves it at the next step)."""
        if self.screenshot is None or self._shot_taken or time_s + DT_S < self.screenshot_s - 1e-9:
            return []
        self._shot_taken = True
        return [("gui", "screenshot", (VIEW, str(self.screenshot)))]


def check_track(view: GuiView, n_followers: int) -> None:
    """InputError unless the tracked vehicle is ``leader`` or one of ``f0`` .. ``f{n-1}``."""
    names = ["leader"] + [f"f{i}" for i in range(n_followers)]
    if view.track is not None and view.track not in names:
        raise InputError(f"--track {view.track}: no such vehicle; choose leader or f0 .. "
                         f"f{n_followers - 1} (f0 is the head follower)")


def apply_calls(traci_module, calls: Sequence[tuple[str, str, tuple[Any, ...]]]) -> None:
    """Make the calls on the running simulation (``traci``)."""
    for domain, method, args in calls:
        getattr(getattr(traci_module, domain), method)(*args)
