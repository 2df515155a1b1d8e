"""Shared fixtures: small hand-made events and the optional shared NGSIM data."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from carl_sumo.data.events import EVENT_COLUMNS, Event

REPO_ROOT = Path(__file__).resolve().parents[1]
NGSIM_DIR = REPO_ROOT.parent / "shared" / "data" / "ngsim"
NET = REPO_ROOT / "carl_sumo" / "networks" / "i80.net.xml"


def braking_event(n: int = 200, event_id: str = "brake", v0: float = 12.0, gap: float = 20.0,
                  source: str = "zhu2020_testset") -> Event:
    """A leader at v0 that brakes at -2 m/s² to 4 m/s after 3 s and recovers at 1 m/s²."""
    acc = np.zeros(n - 1)
    acc[30:30 + int((v0 - 4.0) / 2.0 / 0.1)] = -2.0
    acc[100:100 + int((v0 - 4.0) / 1.0 / 0.1)] = 1.0
    speed = v0 + np.concatenate([[0.0], np.cumsum(acc) * 0.1])
    pos = np.concatenate([[0.0], np.cumsum(speed[1:]) * 0.1])
    return Event(event_id, source, "i-80", pos, speed, 5.0, np.full(n, v0), np.full(n, gap))


def event_table(events: list[Event]) -> pd.DataFrame:
    """The event-table rows of events (Zhu style: no positions)."""
    frames = []
    for e in events:
        n = e.n_samples
        frame = pd.DataFrame({c: [np.nan] * n for c in EVENT_COLUMNS})
        frame["event_id"] = e.event_id
        frame["source"] = e.source
        frame["site"] = e.site
        frame["t_s"] = np.arange(n) * 0.1
        frame["leader_speed_mps"] = e.leader_speed_mps
        frame["follower_speed_mps"] = e.follower_speed_mps
        frame["gap_m"] = e.gap_m
        frame["rel_speed_mps"] = e.leader_speed_mps - e.follower_speed_mps
        frames.append(frame)
    return pd.concat(frames, ignore_index=True)


@pytest.fixture
def small_events() -> list[Event]:
    return [braking_event(event_id="ev_test_0"), braking_event(event_id="ev_test_1", v0=10.0),
            braking_event(event_id="ev_train_0", source="zhu2020_pool_transfollower")]


@pytest.fixture
def small_table_path(tmp_path: Path, small_events: list[Event]) -> Path:
    path = tmp_path / "events.csv"
    event_table(small_events).to_csv(path, index=False)
    return path


@pytest.fixture
def ngsim_dir() -> Path:
    if not (NGSIM_DIR / "ngsim_cf_events.csv.gz").is_file():
        pytest.skip("shared NGSIM data not present (../shared/data/ngsim)")
    return NGSIM_DIR
