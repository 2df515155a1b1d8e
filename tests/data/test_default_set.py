"""Tests of the shipped default leader set (carl_sumo/data/default_events.csv.gz)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from carl_sumo.data.default_set import (
    DEFAULT_EVENTS, TEST_SOURCE, TRAIN_SOURCE, select_events, write_table_atomic,
)
from carl_sumo.data.events import (
    EVENT_COLUMNS, MIN_EVENT_SAMPLES, TEST_SOURCES, events_from_table, read_event_table,
    select_split,
)


@pytest.fixture(scope="module")
def shipped() -> pd.DataFrame:
    return read_event_table(DEFAULT_EVENTS)


def test_shipped_file_loads_with_both_splits(shipped: pd.DataFrame) -> None:
    assert DEFAULT_EVENTS.stat().st_size < 1_600_000
    assert list(shipped.columns) == list(EVENT_COLUMNS)
    sources = set(shipped["source"])
    assert sources == {TRAIN_SOURCE, TEST_SOURCE}
    assert TEST_SOURCE in TEST_SOURCES
    per_event = shipped.groupby("event_id")["source"].first()
    assert 0.2 < (per_event == TEST_SOURCE).mean() < 0.4
    assert select_split(shipped, "test")["source"].eq(TEST_SOURCE).all()
    assert select_split(shipped, "train")["source"].eq(TRAIN_SOURCE).all()
    assert (shipped["site"] == "i80-sumo").all()


def test_shipped_events_are_congested_car_following(shipped: pd.DataFrame) -> None:
    events = events_from_table(shipped, "default set")
    assert 100 <= len(events) <= 160
    assert min(e.n_samples for e in events) >= MIN_EVENT_SAMPLES
    assert (shipped["gap_m"] > 0).all()
    mean_speed = np.array([e.follower_speed_mps.mean() for e in events])
    assert 4.0 < np.median(mean_speed) < 11.0
    assert mean_speed.min() < 3.0  # stop-and-go
    np.testing.assert_allclose(
        shipped["gap_m"], shipped["leader_pos_m"] - shipped["leader_length_m"]
        - shipped["follower_pos_m"], atol=2e-3)


def test_select_events_is_deterministic_and_varied() -> None:
    rows = []
    for i in range(40):
        for k in range(MIN_EVENT_SAMPLES):
            rows.append({"event_id": f"e{i:02d}", "follower_id": i, "t_s": k * 0.1,
                         "follower_speed_mps": 0.3 * i, "gap_m": 10.0})
    table = pd.DataFrame(rows)
    first = select_events(table, 10)
    assert first == select_events(table.sample(frac=1.0, random_state=1), 10)
    assert len(first) == 10 and first[0] == "e00"
    speeds = [0.3 * int(e[1:]) for e in first]
    assert max(speeds) > 10.0 and speeds == sorted(speeds)


def test_write_table_atomic_is_reproducible(tmp_path: Path) -> None:
    table = pd.DataFrame({"a": [1.0, 2.123456], "b": ["x", "y"]})
    out = tmp_path / "sub" / "t.csv.gz"
    write_table_atomic(table, out)
    first = out.read_bytes()
    write_table_atomic(table, out)
    assert out.read_bytes() == first
    assert pd.read_csv(out)["a"].tolist() == [1.0, 2.1235]
    assert [p.name for p in out.parent.iterdir()] == ["t.csv.gz"]


def test_short_generation_run(tmp_path: Path) -> None:
    """A 30 s SUMO run (under a second) gives a valid, reproducible table with both splits."""
    libsumo = pytest.importorskip("libsumo")
    from carl_sumo.data.default_set import DEFAULT_NET, DEFAULT_ROUTES, make_default_set

    # A simulation already running in this process is closed first.
    libsumo.start(["sumo", "-n", str(DEFAULT_NET), "-r", str(DEFAULT_ROUTES), "--no-step-log",
                   "--no-warnings"])
    out = tmp_path / "short.csv.gz"
    table = make_default_set(DEFAULT_NET, out, seed=7, duration_s=30.0, max_events=6)
    assert not libsumo.simulation.isLoaded()
    first = out.read_bytes()
    assert make_default_set(DEFAULT_NET, out, seed=7, duration_s=30.0, max_events=6).equals(table)
    assert out.read_bytes() == first
    loaded = read_event_table(out)
    assert loaded["event_id"].nunique() == 6
    assert set(loaded["source"]) == {TRAIN_SOURCE, TEST_SOURCE}
    assert (loaded["period"] == "sumo-seed7").all() and (loaded["gap_m"] > 0).all()
    assert set(loaded["lane"]) <= set(range(1, 7))
