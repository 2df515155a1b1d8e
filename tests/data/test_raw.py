"""Tests of carl_sumo.data.raw (raw NGSIM reading, smoothing, event extraction)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from carl_sumo.data.events import (
    EVENT_COLUMNS, MIN_EVENT_SAMPLES, events_from_table, validate_event_table,
)
from carl_sumo.data.raw import (
    FT_TO_M, TRAJ_COLUMNS, extract_events, is_raw_ngsim, raw_ngsim_events, read_raw_ngsim,
)
from carl_sumo.errors import InputError

REPO_ROOT = Path(__file__).resolve().parents[2]
US101_SAMPLE = REPO_ROOT.parent / "shared" / "data" / "ngsim" / \
    "us101_raw_sample_0750am_first65535rows.csv.gz"

N_FRAMES = 201  # 20 s at 0.1 s
FIRST_FRAME = 100
LEADER_SPEED_FT = 40.0  # ft/s
FOLLOWER_SPEED_FT = 38.0  # ft/s
LEADER_LENGTH_FT = 15.0
FOLLOWER_LENGTH_FT = 14.0


def _raw_rows(vehicle: int, frames: np.ndarray, y0_ft: float, v_ft: float, length_ft: float,
              lane: np.ndarray | int, preceding: np.ndarray | int) -> pd.DataFrame:
    """Raw NGSIM rows of one vehicle driving at constant speed (ft, ft/s)."""
    t = (frames - frames[0]) * 0.1
    return pd.DataFrame({
        "Vehicle_ID": vehicle, "Frame_ID": frames, "Total_Frames": len(frames),
        "Global_Time": 1113433135300 + frames * 100, "Local_X": 30.0,
        "Local_Y": y0_ft + v_ft * t, "v_Length": length_ft, "v_Width": 6.0, "v_Class": 2,
        "v_Vel": v_ft, "v_Acc": 0.0, "Lane_ID": lane, "Preceding": preceding, "Following": 0,
        "Space_Headway": 0.0, "Time_Headway": 0.0,
    })


def _write(frame: pd.DataFrame, path: Path) -> Path:
    frame.to_csv(path, index=False)
    return path


def _pair(follower_lane: np.ndarray | int = 3, follower_leader: np.ndarray | int = 1,
          n: int = N_FRAMES) -> pd.DataFrame:
    """Vehicle 1 (leader) and vehicle 2 (follower, 100 ft behind) in lane 3 for ``n`` frames."""
    frames = np.arange(FIRST_FRAME, FIRST_FRAME + n)
    leader = _raw_rows(1, frames, 500.0, LEADER_SPEED_FT, LEADER_LENGTH_FT, 3, 0)
    follower = _raw_rows(2, frames, 400.0, FOLLOWER_SPEED_FT, FOLLOWER_LENGTH_FT,
                         follower_lane, follower_leader)
    # Interleave rows by frame as in the NGSIM files.
    return pd.concat([leader, follower]).sort_values(["Frame_ID", "Vehicle_ID"])


def _n_events(table: pd.DataFrame) -> int:
    return table["event_id"].nunique() if len(table) else 0


def test_units_and_constant_speed_kept_exact(tmp_path: Path) -> None:
    path = _write(_pair(), tmp_path / "i80_raw.csv")
    traj = read_raw_ngsim(path)
    assert list(traj.columns) == list(TRAJ_COLUMNS)
    assert len(traj) == 2 * N_FRAMES
    assert traj[["vehicle", "frame"]].equals(
        traj[["vehicle", "frame"]].sort_values(["vehicle", "frame"]))
    lead = traj[traj["vehicle"] == 1]
    foll = traj[traj["vehicle"] == 2]
    t = (lead["frame"].to_numpy() - FIRST_FRAME) * 0.1
    # Smoothing keeps a constant-speed (linear) trajectory exactly, ends included.
    np.testing.assert_allclose(lead["pos_m"], (500.0 + LEADER_SPEED_FT * t) * FT_TO_M, atol=1e-9)
    np.testing.assert_allclose(lead["speed_mps"], LEADER_SPEED_FT * FT_TO_M, atol=1e-9)
    np.testing.assert_allclose(foll["speed_mps"], FOLLOWER_SPEED_FT * FT_TO_M, atol=1e-9)
    np.testing.assert_allclose(traj["acc_mps2"], 0.0, atol=1e-7)
    assert lead["length_m"].iloc[0] == pytest.approx(LEADER_LENGTH_FT * FT_TO_M)
    assert set(foll["leader"]) == {1} and set(lead["leader"]) == {0}
    assert set(traj["lane"]) == {3}


def test_smoothing_damps_noise_and_handles_frame_gaps(tmp_path: Path) -> None:
    frames = np.r_[np.arange(0, 100), np.arange(150, 250)]  # a 5 s hole in the trajectory
    rows = _raw_rows(7, frames, 0.0, 50.0, 15.0, 2, 0)
    rows["Local_Y"] = 50.0 * frames * 0.1  # true position follows the frame number
    rng = np.random.default_rng(0)
    rows["Local_Y"] += rng.normal(0.0, 0.5, len(rows))
    traj = read_raw_ngsim(_write(rows, tmp_path / "noisy.csv"))
    speed = traj["speed_mps"].to_numpy()
    # No speed spike across the hole: each contiguous run is differentiated on its own.
    assert np.all(np.abs(speed - 50.0 * FT_TO_M) < 2.0)
    raw_speed = np.diff(rows["Local_Y"].to_numpy()[:100]) / 0.1 * FT_TO_M
    assert np.std(speed[:100]) < 0.25 * np.std(raw_speed)


def test_event_extraction(tmp_path: Path) -> None:
    table = raw_ngsim_events(_write(_pair(), tmp_path / "pair.csv"))
    assert list(table.columns) == list(EVENT_COLUMNS)
    assert _n_events(table) == 1 and len(table) == N_FRAMES
    assert table["event_id"].iloc[0] == f"raw_ngsim_f2_l1_fr{FIRST_FRAME}"
    assert table["site"].iloc[0] == "i-80" and table["source"].iloc[0] == "raw_ngsim"
    assert (table["split_in_source"] == "none").all()
    np.testing.assert_allclose(table["t_s"], np.arange(N_FRAMES) * 0.1, atol=1e-9)
    gap0 = (500.0 - LEADER_LENGTH_FT - 400.0) * FT_TO_M
    gap_end = gap0 + (LEADER_SPEED_FT - FOLLOWER_SPEED_FT) * FT_TO_M * 20.0
    assert table["gap_m"].iloc[0] == pytest.approx(gap0)
    assert table["gap_m"].iloc[-1] == pytest.approx(gap_end)
    np.testing.assert_allclose(table["rel_speed_mps"],
                               (LEADER_SPEED_FT - FOLLOWER_SPEED_FT) * FT_TO_M, atol=1e-9)
    np.testing.assert_allclose(
        table["gap_m"], table["leader_pos_m"] - table["leader_length_m"] - table["follower_pos_m"])
    validate_event_table(table, "extracted")
    events = events_from_table(table)
    assert len(events) == 1 and events[0].n_samples == N_FRAMES and events[0].lane == 3


def test_site_from_file_name(tmp_path: Path) -> None:
    table = raw_ngsim_events(_write(_pair(), tmp_path / "us101_part.csv"))
    assert table["site"].iloc[0] == "us-101"
    table = raw_ngsim_events(_write(_pair(), tmp_path / "x.csv"), site="elsewhere", source="s")
    assert table["site"].iloc[0] == "elsewhere" and table["event_id"].iloc[0].startswith("s_f2")


def test_leader_change_splits_event(tmp_path: Path) -> None:
    n = 2 * MIN_EVENT_SAMPLES + 20
    frames = np.arange(FIRST_FRAME, FIRST_FRAME + n)
    half = MIN_EVENT_SAMPLES + 10
    preceding = np.where(np.arange(n) < half, 1, 3)
    rows = pd.concat([
        _raw_rows(1, frames, 500.0, 40.0, 15.0, 3, 0),
        _raw_rows(3, frames, 450.0, 40.0, 15.0, 3, 1),  # cuts in between at the same speed
        _raw_rows(2, frames, 400.0, 40.0, 14.0, 3, preceding),
    ])
    table = raw_ngsim_events(_write(rows, tmp_path / "cutin.csv"))
    follower2 = table[table["follower_id"] == 2]
    assert sorted(follower2.groupby("event_id").size().tolist()) == [n - half, half]
    assert set(follower2["leader_id"]) == {1, 3}
    # Vehicle 3 follows vehicle 1 the whole time.
    assert table[table["follower_id"] == 3].groupby("event_id").size().tolist() == [n]


def test_lane_change_splits_event(tmp_path: Path) -> None:
    n = 2 * MIN_EVENT_SAMPLES + 20
    lanes = np.where(np.arange(n) < MIN_EVENT_SAMPLES + 5, 3, 4)
    table = raw_ngsim_events(_write(_pair(follower_lane=lanes, n=n), tmp_path / "lc.csv"))
    # After the lane change the leader is in another lane, so only the first part is an event.
    assert table.groupby("event_id").size().tolist() == [MIN_EVENT_SAMPLES + 5]
    assert set(table["lane"]) == {3}


def test_short_run_dropped_and_min_samples(tmp_path: Path) -> None:
    path = _write(_pair(n=MIN_EVENT_SAMPLES - 1), tmp_path / "short.csv")
    table = raw_ngsim_events(path)
    assert _n_events(table) == 0 and list(table.columns) == list(EVENT_COLUMNS)
    traj = read_raw_ngsim(path)
    short = extract_events(traj, "src", "i-80", min_samples=50, id_prefix="p")
    assert _n_events(short) == 1 and short["event_id"].iloc[0] == f"p_f2_l1_fr{FIRST_FRAME}"


def test_frame_gap_and_nonpositive_gap_split(tmp_path: Path) -> None:
    rows = _pair(n=400)
    drop = (rows["Vehicle_ID"] == 2) & (rows["Frame_ID"] == FIRST_FRAME + 200)
    table = raw_ngsim_events(_write(rows[~drop], tmp_path / "hole.csv"))
    assert sorted(table.groupby("event_id").size().tolist()) == [199, 200]
    overlap = _pair()
    overlap.loc[overlap["Vehicle_ID"] == 1, "Local_Y"] -= 100.0  # leader's rear behind follower
    assert _n_events(raw_ngsim_events(_write(overlap, tmp_path / "overlap.csv"))) == 0


def test_bad_input(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="does not exist"):
        read_raw_ngsim(tmp_path / "missing.csv")
    rows = _pair()
    with pytest.raises(InputError, match="v_Vel"):
        read_raw_ngsim(_write(rows.drop(columns="v_Vel"), tmp_path / "nocol.csv"))
    nan = rows.copy()
    nan["Local_Y"] = nan["Local_Y"].astype(float)
    nan.iloc[5, nan.columns.get_loc("Local_Y")] = np.nan
    with pytest.raises(InputError, match="Local_Y.*row 7"):
        read_raw_ngsim(_write(nan, tmp_path / "nan.csv"))
    text = rows.astype({"Lane_ID": object})
    text.iloc[3, text.columns.get_loc("Lane_ID")] = "left"
    with pytest.raises(InputError, match="Lane_ID"):
        read_raw_ngsim(_write(text, tmp_path / "text.csv"))
    binary = tmp_path / "binary.csv.gz"
    binary.write_bytes(b"\x1f\x8b\x08\x00 not really gzip")
    with pytest.raises(InputError, match="not a readable CSV"):
        read_raw_ngsim(binary)
    with pytest.raises(InputError, match="lacks"):
        extract_events(pd.DataFrame({"vehicle": [1]}), "s", "i-80")
    for error in (InputError,):
        try:
            read_raw_ngsim(tmp_path / "missing.csv")
        except error as exc:
            assert "\n" not in str(exc)


def test_is_raw_ngsim(tmp_path: Path) -> None:
    raw = _write(_pair(), tmp_path / "raw.csv")
    assert is_raw_ngsim(raw)
    other = tmp_path / "events.csv"
    other.write_text("event_id,source,site,t_s\nx,y,z,0.0\n")
    assert not is_raw_ngsim(other)
    assert not is_raw_ngsim(tmp_path / "missing.csv")


def test_us101_raw_sample() -> None:
    if not US101_SAMPLE.is_file():
        pytest.skip(f"shared NGSIM sample not present at {US101_SAMPLE}")
    assert is_raw_ngsim(US101_SAMPLE)
    table = raw_ngsim_events(US101_SAMPLE)
    assert list(table.columns) == list(EVENT_COLUMNS)
    assert (table["site"] == "us-101").all()
    sizes = table.groupby("event_id").size()
    assert len(sizes) > 100 and sizes.min() >= MIN_EVENT_SAMPLES
    mean_speed = table.groupby("event_id")["follower_speed_mps"].mean()
    assert 8.0 < mean_speed.median() < 20.0  # about 13.6 m/s in the morning peak
    assert table["follower_speed_mps"].between(0.0, 40.0).all()
    assert (table["gap_m"] > 0).all()
    # Smoothed accelerations are far less noisy than the raw ±3.4 m/s² values.
    assert table["follower_acc_mps2"].abs().quantile(0.99) < 3.0
    events = events_from_table(table)
    assert len(events) == len(sizes)
