"""The suite's figures stay readable (time series wrap into a grid with one legend, the frontier's
labels do not overlap and an outlier does not squash its axis), its tables say which data they ran
on, and `evaluate --controller` adds a controller of the user's own to every table."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from carl_sumo.experiments.figures import (CURVES, _frontier_panel, declutter, outliers, pyplot,
                                           timeseries_canvas)
from carl_sumo.experiments.suite import data_titles


@pytest.mark.parametrize("values, expected", [
    ([0.176, 0.134, 0.104, 0.083, 0.061, 0.127, 1.062, 0.099], {6}),  # SUMO's CACC on jerk
    ([3.92, 3.08, 2.47, 2.02, 1.58, 4.22, 5.40, 2.33], set()),        # a wide spread: none
    ([1.0, 2.0, 3.0, 100.0, 200.0], {3, 4}),
    ([-50.0, 1.0, 2.0, 3.0, 2.5], {0}),
    ([1.0, 9.0, 30.0], set()),                                       # too few to tell
])
def test_outliers(values, expected):
    assert outliers(values) == expected


def _series(n_followers: int = 4, steps: int = 50) -> dict[str, np.ndarray]:
    t = np.arange(steps) * 0.1
    speed = np.tile(np.linspace(10, 12, steps)[:, None], (1, n_followers + 1))
    return {"t": t, "pos": np.cumsum(speed, axis=0) * 0.1, "speed": speed,
            "acc": np.diff(speed, axis=0) / 0.1}


def test_timeseries_wrap_into_a_grid_with_one_legend():
    plt = pyplot()
    fig = timeseries_canvas({f"model {i}": _series() for i in range(6)}, "six models")
    try:
        visible = [ax for ax in fig.axes if ax.get_visible()]
        assert len(visible) == 18 and len(fig.axes) == 6 * 4  # 2 block rows of 4, 2 blocks empty
        assert len(fig.legends) == 1 and not [ax for ax in fig.axes if ax.get_legend()]
        assert [t.get_text() for t in fig.legends[0].get_texts()] == ["leader", "follower 1",
                                                                      "follower 4"]
        width, height = fig.get_size_inches()
        assert width <= 4 * 3.6 + 1e-9 and height > width * 0.9  # a grid, not one long row
        speeds = [ax for ax in visible if ax.get_ylabel() == "speed (m/s)"]
        assert len({ax.get_ylim() for ax in fig.axes[4:8]}) == 1 and speeds
    finally:
        plt.close(fig)


def _frontier_points() -> list[dict]:
    points = []
    for curve, rows in ((CURVES["ploeg:"], [(0.6, 2.0, 0.176), (0.8, 2.235, 0.134),
                                            (1.0, 2.46, 0.104), (1.2, 2.68, 0.083)]),
                        (CURVES["ploeg-tuned:"], [(0.6, 2.345, 0.127), (0.8, 2.277, 0.117),
                                                  (1.0, 2.465, 0.108), (1.2, 2.675, 0.087)])):
        points += [{"label": f"x h={h:g} s", "curve": curve, "headway_s": x, "jerk_mps3": y}
                   for h, x, y in rows]
    points += [{"label": "CACC (SUMO)", "curve": None, "headway_s": 2.2, "jerk_mps3": 1.062},
               {"label": "IDM (SUMO)", "curve": None, "headway_s": 2.67, "jerk_mps3": 0.085}]
    return points


def test_frontier_labels_do_not_overlap_and_an_outlier_sits_on_the_edge():
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.5, 5.2))
    try:
        texts = _frontier_panel(ax, _frontier_points(), "jerk_mps3")
        fig.canvas.draw()
        renderer = fig.canvas.get_renderer()
        before = [t.get_window_extent(renderer) for t in texts]
        assert any(a.overlaps(b) for a, b in itertools.combinations(before, 2))  # as drawn
        declutter(ax, texts)
        boxes = [t.get_window_extent(renderer) for t in texts]
        assert not any(a.overlaps(b) for a, b in itertools.combinations(boxes, 2))
        low, high = ax.get_ylim()
        assert high < 0.2 and low > 0.05  # fitted to the others, not squashed by 1.06
        assert any(t.get_text() == "CACC (SUMO): 1.06 ↑" for t in texts)
    finally:
        plt.close(fig)


def test_a_point_far_along_the_headway_axis_sits_on_its_right_edge():
    plt = pyplot()
    fig, ax = plt.subplots()
    try:
        points = _frontier_points() + [{"label": "slow ACC", "curve": None, "headway_s": 9.0,
                                        "jerk_mps3": 0.05}]
        texts = _frontier_panel(ax, points, "jerk_mps3")
        assert ax.get_xlim()[1] < 3.0
        assert any(t.get_text() == "slow ACC: 9.00 s, 0.05 →" for t in texts)
    finally:
        plt.close(fig)


def test_the_frontier_draws_more_single_points_than_it_has_markers():
    """The real suite has about 20 models that are points, not curves (its frontier figure
    failed with a KeyError on the 14th before the markers were cycled)."""
    plt = pyplot()
    fig, ax = plt.subplots()
    try:
        points = _frontier_points() + [{"label": f"law {k}", "curve": None,
                                        "headway_s": 1.0 + 0.05 * k, "jerk_mps3": 0.1 + 0.002 * k}
                                       for k in range(20)]
        _frontier_panel(ax, points, "jerk_mps3")
        labels = ax.get_legend_handles_labels()[1]
        assert {f"law {k}" for k in range(20)} <= set(labels)
    finally:
        plt.close(fig)


def test_tables_say_which_data_they_ran_on():
    assert data_titles("../shared/data/ngsim/ngsim_cf_events.csv.gz", None, False) == (
        "NGSIM test split", "US-101 (no model was trained on it)")
    test, cross = data_titles("default", 2, True)
    assert test == "test split of the shipped default set (not NGSIM), first 2 events (--quick)"
    assert cross.startswith("train split of the shipped default set standing in")
    assert data_titles("mine.csv", 5, False)[0] == "test split of mine.csv, first 5 events"


EXAMPLE = "examples/my_controller.py"


def test_evaluate_controller_adds_a_row_to_every_table():
    from conftest import NET, REPO_ROOT
    from carl_sumo.experiments.suite import plan_suite

    name = f"{REPO_ROOT / EXAMPLE}:constant_gap"
    suite = plan_suite("paper", quick=True, events=1, net=NET, extra=(name,))
    assert all(spec.models[-1] == name for spec in suite.tables)
    assert suite.models[name].name == "constant_gap (my_controller.py)"
    assert suite.models[name].controllers == (name,)


@pytest.mark.parametrize("argv, message", [
    (["--controller", "idm"], "give module:attribute"),
    (["--controller", f"{EXAMPLE}:nothing"], "no attribute 'nothing'"),
    (["--suite", "robustness", "--controller", f"{EXAMPLE}:constant_gap"],
     "--suite paper or real"),
])
def test_evaluate_controller_bad_input_is_one_line_exit_2(tmp_path, capsys, monkeypatch, argv,
                                                          message):
    from conftest import REPO_ROOT
    from carl_sumo.cli import main

    monkeypatch.chdir(REPO_ROOT)
    code = main(["evaluate", "--quick", "--out", str(tmp_path / "out"), *argv])
    err = capsys.readouterr().err
    assert code == 2 and message in err and len(err.strip().splitlines()) == 1, err
    assert not (tmp_path / "out").exists()
