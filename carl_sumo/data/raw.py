"""Raw NGSIM trajectories: read, convert to SI units, smooth, and extract car-following events.

The raw NGSIM files (I-80, US-101) list one row per vehicle per 0.1 s frame in feet, ft/s and
ft/s². :func:`read_raw_ngsim` turns them into the *canonical trajectory frame* (metres, m/s, m/s²)

    vehicle, frame, pos_m, speed_mps, acc_mps2, length_m, lane, leader

and :func:`extract_events` cuts car-following events out of such a frame in the event table
format of :mod:`carl_sumo.data.events`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pandas as pd

from carl_sumo.data.events import DT_S, EVENT_COLUMNS, MAX_ABS_ACC_MPS2, MAX_GAP_M, \
    MAX_SPEED_MPS, MIN_EVENT_SAMPLES
from carl_sumo.errors import InputError

FT_TO_M = 0.3048
"""Metres per foot."""

RAW_COLUMNS: tuple[str, ...] = (
    "Vehicle_ID", "Frame_ID", "Local_Y", "v_Vel", "v_Acc", "v_Length", "Lane_ID", "Preceding",
)
"""Raw NGSIM columns that are read (other columns are ignored)."""

HEADER_COLUMNS: tuple[str, ...] = ("Vehicle_ID", "Frame_ID", "Local_Y")
"""Columns whose presence in the header marks a raw NGSIM file."""

TRAJ_COLUMNS: tuple[str, ...] = (
    "vehicle", "frame", "pos_m", "speed_mps", "acc_mps2", "length_m", "lane", "leader",
)
"""Columns of the canonical trajectory frame."""

SMOOTHING_WIDTH_S = 0.5
"""Width Δ of the symmetric exponential moving average on positions (s)."""

SMOOTHING_HALF_WINDOWS = 3
"""The kernel is cut at ±3Δ."""


def _first_line(exc: BaseException) -> str:
    text = str(exc)
    return text.splitlines()[0] if text else "no detail"


def read_raw_ngsim(path: str | Path) -> pd.DataFrame:
    """Read a raw NGSIM trajectory CSV (optionally .gz) into the canonical trajectory frame.

    Input units: Local_Y (front bumper) and v_Length in ft, v_Vel in ft/s, v_Acc in ft/s².
    Output: ``vehicle, frame, pos_m [m], speed_mps [m/s], acc_mps2 [m/s²], length_m [m], lane,
    leader`` (leader = Preceding id, 0 = none), sorted by vehicle and frame. Positions are smoothed
    per contiguous run of frames with :func:`smooth_positions`; speed is the central difference of
    the smoothed positions (clipped at 0) and acceleration the central difference of that speed.
    A run of a single frame keeps the converted raw speed and acceleration. Rows repeating a
    (vehicle, frame) pair are dropped (the first is kept).

    Raises InputError for a missing or unreadable file, missing columns or non-numeric/NaN values.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"raw NGSIM file {path} does not exist; give the path of a raw NGSIM "
                         "trajectory CSV (optionally .gz)")
    try:
        raw = pd.read_csv(path, low_memory=False)
    except Exception as exc:  # pandas raises many types for malformed files
        raise InputError(f"raw NGSIM file {path} is not a readable CSV table "
                         f"({type(exc).__name__}: {_first_line(exc)})") from exc
    missing = [c for c in RAW_COLUMNS if c not in raw.columns]
    if missing:
        raise InputError(f"raw NGSIM file {path} lacks the column(s) {', '.join(missing)}; a raw "
                         f"NGSIM trajectory file needs {', '.join(RAW_COLUMNS)}")
    if raw.empty:
        raise InputError(f"raw NGSIM file {path} holds no rows; give a file with trajectories")
    data = {}
    for column in RAW_COLUMNS:
        values = pd.to_numeric(raw[column], errors="coerce").to_numpy(float)
        bad = ~np.isfinite(values)
        if bad.any():
            row = int(np.flatnonzero(bad)[0])
            raise InputError(f"raw NGSIM file {path}: column {column} has a missing, infinite or "
                             f"non-numeric value ({raw[column].iloc[row]!r}) at data row "
                             f"{row + 2}; fix or drop that row")
        data[column] = values
    for column in ("Vehicle_ID", "Frame_ID", "Lane_ID", "Preceding"):
        if not np.all(data[column] == np.round(data[column])):
            raise InputError(f"raw NGSIM file {path}: column {column} must hold whole numbers "
                             "(IDs, frame numbers, lane numbers)")
    frame = pd.DataFrame({
        "vehicle": data["Vehicle_ID"].astype(np.int64),
        "frame": data["Frame_ID"].astype(np.int64),
        "pos_m": data["Local_Y"] * FT_TO_M,
        "speed_mps": data["v_Vel"] * FT_TO_M,
        "acc_mps2": data["v_Acc"] * FT_TO_M,
        "length_m": data["v_Length"] * FT_TO_M,
        "lane": data["Lane_ID"].astype(np.int64),
        "leader": data["Preceding"].astype(np.int64),
    })
    frame = (frame.sort_values(["vehicle", "frame"], kind="mergesort")
             .drop_duplicates(["vehicle", "frame"], keep="first")
             .reset_index(drop=True))
    return smooth_trajectories(frame)


def _segments(vehicle: np.ndarray, frame: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Index within and samples left in each contiguous run of frames of a vehicle.

    Rows must be sorted by vehicle and frame. Returns (run id, index in run, samples after it).
    """
    n = vehicle.shape[0]
    start = np.ones(n, dtype=bool)
    if n > 1:
        start[1:] = (vehicle[1:] != vehicle[:-1]) | (frame[1:] != frame[:-1] + 1)
    run = np.cumsum(start) - 1
    starts = np.flatnonzero(start)
    lengths = np.diff(np.append(starts, n))
    index = np.arange(n) - starts[run]
    left = lengths[run] - 1 - index
    return run, index, left


def smooth_positions(pos: np.ndarray, index: np.ndarray, left: np.ndarray,
                     width_samples: float = SMOOTHING_WIDTH_S / DT_S) -> np.ndarray:
    """Thiemann-Treiber-Kesting (2008) symmetric exponential moving average of positions (m).

    Kernel ``exp(-|i-k| / Δ)`` with Δ = ``width_samples`` (5 samples = 0.5 s), cut at ±3Δ and,
    near the ends of a run, at the distance to the nearer end (so the window stays symmetric and
    a constant-speed trajectory is kept exactly), then renormalised. ``index``/``left``: samples
    before/after each row inside its contiguous run.
    """
    reach = int(round(SMOOTHING_HALF_WINDOWS * width_samples))
    half = np.minimum(np.minimum(index, left), reach)
    total = np.zeros_like(pos, dtype=float)
    weight = np.zeros_like(pos, dtype=float)
    n = pos.shape[0]
    for offset in range(-reach, reach + 1):
        use = np.abs(offset) <= half
        if not use.any():
            continue
        rows = np.flatnonzero(use)
        w = np.exp(-abs(offset) / width_samples)
        total[rows] += w * pos[np.clip(rows + offset, 0, n - 1)]
        weight[rows] += w
    return total / weight


def _central_difference(values: np.ndarray, index: np.ndarray, left: np.ndarray,
                        dt: float = DT_S) -> np.ndarray:
    """Derivative per contiguous run: central inside, one-sided at the ends (NaN for 1 sample)."""
    n = values.shape[0]
    nxt = np.append(values[1:], np.nan) if n else values
    prv = np.insert(values[:-1], 0, np.nan) if n else values
    out = np.full(n, np.nan)
    inner = (index > 0) & (left > 0)
    out[inner] = (nxt[inner] - prv[inner]) / (2.0 * dt)
    first = (index == 0) & (left > 0)
    out[first] = (nxt[first] - values[first]) / dt
    last = (index > 0) & (left == 0)
    out[last] = (values[last] - prv[last]) / dt
    return out


def smooth_trajectories(traj: pd.DataFrame) -> pd.DataFrame:
    """Smooth ``pos_m`` and recompute ``speed_mps`` (≥ 0) and ``acc_mps2`` of a canonical frame.

    ``traj`` must be sorted by vehicle and frame; each contiguous run of frames is treated
    separately. Runs of one sample keep their given speed and acceleration.
    """
    vehicle = traj["vehicle"].to_numpy()
    frame_no = traj["frame"].to_numpy()
    _, index, left = _segments(vehicle, frame_no)
    pos = smooth_positions(traj["pos_m"].to_numpy(float), index, left)
    speed = np.clip(_central_difference(pos, index, left), 0.0, None)
    acc = _central_difference(speed, index, left)
    single = (index == 0) & (left == 0)
    speed[single] = traj["speed_mps"].to_numpy(float)[single]
    acc[single] = traj["acc_mps2"].to_numpy(float)[single]
    out = traj.copy()
    out["pos_m"] = pos
    out["speed_mps"] = speed
    out["acc_mps2"] = acc
    return out[list(TRAJ_COLUMNS)]


def _implausible(pairs: pd.DataFrame) -> np.ndarray:
    """Per follower-leader sample: a value that an event table may not hold (speed above
    MAX_SPEED_MPS, |acceleration| above MAX_ABS_ACC_MPS2 or a gap above MAX_GAP_M, see
    :mod:`carl_sumo.data.events`)."""
    speed = pairs[["speed_mps", "leader_speed_mps"]].to_numpy(float)
    acc = pairs[["acc_mps2", "leader_acc_mps2"]].to_numpy(float)
    return ((speed > MAX_SPEED_MPS).any(axis=1) | (np.abs(acc) > MAX_ABS_ACC_MPS2).any(axis=1)
            | (pairs["gap_m"].to_numpy(float) > MAX_GAP_M))


def _follower_leader_pairs(traj: pd.DataFrame) -> pd.DataFrame:
    """Every frame of a follower with its leader present in the same frame and lane and a bumper
    gap ``gap_m`` > 0 m, ordered by follower and frame."""
    cols = list(TRAJ_COLUMNS)
    follower = traj.loc[traj["leader"] != 0, cols]
    leader = traj[["vehicle", "frame", "pos_m", "speed_mps", "acc_mps2", "length_m", "lane"]]
    leader = leader.rename(columns={"vehicle": "leader", "pos_m": "leader_pos_m",
                                    "speed_mps": "leader_speed_mps", "acc_mps2": "leader_acc_mps2",
                                    "length_m": "leader_length_m", "lane": "leader_lane"})
    pairs = follower.merge(leader, on=["frame", "leader"], how="inner", validate="many_to_one")
    pairs["gap_m"] = pairs["leader_pos_m"] - pairs["leader_length_m"] - pairs["pos_m"]
    pairs = pairs[(pairs["leader_lane"] == pairs["lane"]) & (pairs["gap_m"] > 0)]
    return pairs.sort_values(["vehicle", "frame"], kind="mergesort").reset_index(drop=True)


def extract_events(traj: pd.DataFrame, source: str, site: str, period: str = "unknown",
                   id_prefix: str | None = None,
                   min_samples: int = MIN_EVENT_SAMPLES) -> pd.DataFrame:
    """Cut car-following events out of a canonical trajectory frame (see :data:`TRAJ_COLUMNS`).

    An event is a maximal run of consecutive frames in which the follower keeps the same non-zero
    leader and the same lane, the leader is present in the same frame and lane, and the bumper gap
    ``leader pos - leader length - follower pos`` is > 0 m. Runs shorter than ``min_samples``
    samples (151 = 15 s) are dropped, and so are runs with a value an event table may not hold (a
    broken record: a speed above 70 m/s, an |acceleration| above 15 m/s², a gap above 500 m). Returns an event table with exactly :data:`EVENT_COLUMNS`
    (``t_s`` = 0, 0.1, ... s; ``event_id`` = ``{id_prefix}_f{follower}_l{leader}_fr{first frame}``,
    ``id_prefix`` defaulting to ``source``), ordered by follower and first frame.
    """
    missing = [c for c in TRAJ_COLUMNS if c not in traj.columns]
    if missing:
        raise InputError(f"trajectory frame lacks the column(s) {', '.join(missing)}; it needs "
                         f"{', '.join(TRAJ_COLUMNS)}")
    if min_samples < 2:
        raise InputError(f"min_samples must be at least 2, got {min_samples}")
    prefix = source if id_prefix is None else id_prefix
    pairs = _follower_leader_pairs(traj)
    if pairs.empty:
        return pd.DataFrame({c: pd.Series(dtype=object) for c in EVENT_COLUMNS})

    veh = pairs["vehicle"].to_numpy()
    fr = pairs["frame"].to_numpy()
    lead = pairs["leader"].to_numpy()
    lane = pairs["lane"].to_numpy()
    start = np.ones(len(pairs), dtype=bool)
    start[1:] = ((veh[1:] != veh[:-1]) | (fr[1:] != fr[:-1] + 1) | (lead[1:] != lead[:-1])
                 | (lane[1:] != lane[:-1]))
    run = np.cumsum(start) - 1
    starts = np.flatnonzero(start)
    lengths = np.diff(np.append(starts, len(pairs)))
    implausible = np.zeros(len(lengths), dtype=bool)  # a run with a broken record is dropped
    np.logical_or.at(implausible, run, _implausible(pairs))
    keep = (lengths[run] >= min_samples) & ~implausible[run]
    pairs = pairs[keep].reset_index(drop=True)
    run = run[keep]
    if pairs.empty:
        return pd.DataFrame({c: pd.Series(dtype=object) for c in EVENT_COLUMNS})
    first_row = np.flatnonzero(np.r_[True, run[1:] != run[:-1]])
    counts = np.diff(np.append(first_row, len(run)))
    step = np.arange(len(run)) - np.repeat(first_row, counts)
    ids = [f"{prefix}_f{v}_l{l}_fr{f}" for v, l, f in zip(
        pairs["vehicle"].to_numpy()[first_row], pairs["leader"].to_numpy()[first_row],
        pairs["frame"].to_numpy()[first_row])]

    table = pd.DataFrame({
        "event_id": np.repeat(np.array(ids, dtype=object), counts),
        "source": source,
        "site": site,
        "period": period,
        "split_in_source": "none",
        "follower_id": pairs["vehicle"].to_numpy(),
        "leader_id": pairs["leader"].to_numpy(),
        "lane": pairs["lane"].to_numpy(),
        "frame_id": pairs["frame"].to_numpy(),
        "t_src_s": np.nan,
        "t_s": np.round(step * DT_S, 1),
        "follower_pos_m": pairs["pos_m"].to_numpy(float),
        "follower_speed_mps": pairs["speed_mps"].to_numpy(float),
        "follower_acc_mps2": pairs["acc_mps2"].to_numpy(float),
        "follower_length_m": pairs["length_m"].to_numpy(float),
        "leader_pos_m": pairs["leader_pos_m"].to_numpy(float),
        "leader_speed_mps": pairs["leader_speed_mps"].to_numpy(float),
        "leader_acc_mps2": pairs["leader_acc_mps2"].to_numpy(float),
        "leader_length_m": pairs["leader_length_m"].to_numpy(float),
        "gap_m": pairs["gap_m"].to_numpy(float),
        "rel_speed_mps": (pairs["leader_speed_mps"] - pairs["speed_mps"]).to_numpy(float),
    })
    return table[list(EVENT_COLUMNS)]


def default_site(path: str | Path) -> str:
    """Site of a raw NGSIM file from its name: ``us-101`` when it contains "101", else ``i-80``."""
    return "us-101" if "101" in Path(path).name else "i-80"


def raw_ngsim_events(path: str | Path, site: str | None = None,
                     source: str = "raw_ngsim") -> pd.DataFrame:
    """Read a raw NGSIM file and extract its car-following events (event table, SI units)."""
    traj = read_raw_ngsim(path)
    site = default_site(path) if site is None else site
    return extract_events(traj, source=source, site=site, id_prefix=source)


def is_raw_ngsim(path: str | Path) -> bool:
    """True when the CSV header (only the header is read) has Vehicle_ID, Frame_ID and Local_Y.

    A missing or unreadable file gives False.
    """
    try:
        header = pd.read_csv(Path(path), nrows=0)
    except Exception:  # noqa: BLE001 - any failure means "not a raw NGSIM file"
        return False
    return all(c in header.columns for c in HEADER_COLUMNS)
