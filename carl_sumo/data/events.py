"""Car-following events: the leader trajectory a platoon follows, and the recorded human follower.

The on-disk format is the long event table of ``../shared/data/ngsim/ngsim_cf_events.csv.gz``
(one row per event per 0.1 s, SI units). Every loader in :mod:`carl_sumo.data` produces that table,
and :func:`events_from_table` turns it into :class:`Event` objects.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pandas as pd

from carl_sumo.config import DT_S  # the sampling period of every event and the SUMO step (s)
from carl_sumo.errors import InputError

DEFAULT_VEHICLE_LENGTH_M = 5.0
"""Vehicle length used where an event does not give one (m)."""

MIN_EVENT_SAMPLES = 151
"""Shortest event that the extractors of raw trajectories keep: 151 samples = 15.0 s."""

MIN_EVENT_S = 5.0
"""Shortest event that a table may hold (s): 51 samples. A platoon needs a few seconds to show a
dampening ratio or a headway at all (the real NGSIM events are 15 s or longer); a shorter event is
refused with its name, not scored."""

MIN_SCORED_SAMPLES = int(round(MIN_EVENT_S / DT_S)) + 1
""":data:`MIN_EVENT_S` in samples (51)."""

MAX_SPEED_MPS = 70.0
"""Highest plausible speed of a leader or follower (m/s, 252 km/h); a higher one is refused as
implausible (wrong units, a broken record) before anything is simulated."""

MAX_ABS_ACC_MPS2 = 15.0
"""Largest plausible recorded acceleration of a leader or follower (m/s², about 1.5 g): the
``leader_acc_mps2`` / ``follower_acc_mps2`` columns, where a table has them (the real NGSIM
records stay within ±4.9). Accelerations derived from the speeds are not checked: the US-101
speed records move in steps of up to 7.4 m/s between 0.1 s samples (recorded as ±3.4 m/s²), which
is how NGSIM quantised them, not a broken record."""

MAX_GAP_M = 500.0
"""Largest plausible bumper gap of a car-following event (m); a gap must also be positive (the
real NGSIM events: 0.05-99 m). Beyond it a follower follows nothing."""

EVENT_COLUMNS: tuple[str, ...] = (
    "event_id", "source", "site", "period", "split_in_source", "follower_id", "leader_id", "lane",
    "frame_id", "t_src_s", "t_s", "follower_pos_m", "follower_speed_mps", "follower_acc_mps2",
    "follower_length_m", "leader_pos_m", "leader_speed_mps", "leader_acc_mps2", "leader_length_m",
    "gap_m", "rel_speed_mps",
)
"""Columns of the event table, in file order."""

REQUIRED_COLUMNS: tuple[str, ...] = (
    "event_id", "source", "site", "t_s", "follower_speed_mps", "leader_speed_mps", "gap_m",
)
"""Columns a table must have; the others are optional."""

NUMERIC_REQUIRED: tuple[str, ...] = ("t_s", "follower_speed_mps", "leader_speed_mps", "gap_m")

TEST_SOURCES: frozenset[str] = frozenset({"zhu2020_testset", "carl_sumo_default_test"})
"""Sources of the ``test`` split (the paper's protocol: Zhu et al. 2020's 403-event test set)."""

SPLITS: tuple[str, ...] = ("test", "train", "us101", "all")
"""``test`` = TEST_SOURCES; ``us101`` = site us-101; ``train`` = every other event; ``all``."""


@dataclass(frozen=True)
class Event:
    """One leader-follower car-following event sampled every ``dt`` seconds.

    Positions are front-bumper positions along the road (m), shifted so the leader starts at 0.
    """

    event_id: str
    source: str
    site: str
    leader_pos_m: np.ndarray
    leader_speed_mps: np.ndarray
    leader_length_m: float
    follower_speed_mps: np.ndarray
    gap_m: np.ndarray
    lane: int | None = None
    dt: float = DT_S
    scored_from: int = 0  # first sample the metrics score; the ones before are a warm-up

    @property
    def n_samples(self) -> int:
        return int(self.leader_speed_mps.shape[0])

    @property
    def duration_s(self) -> float:
        return (self.n_samples - 1) * self.dt

    @property
    def initial_gap_m(self) -> float:
        return float(self.gap_m[0])

    @property
    def initial_speed_mps(self) -> float:
        return float(self.follower_speed_mps[0])

    def with_warmup(self, seconds: float) -> Event:
        """This event after ``seconds`` (a multiple of ``dt``) of warm-up: the leader first drives
        at its initial speed (its recorded trajectory extended backwards), so the platoon, which
        starts with the recorded follower's speed and gap, settles at its own controller's
        spacing; the metrics then score only the recorded part (from :attr:`scored_from` on). The
        recorded follower is held at its initial state over the warm-up."""
        check_warmup(seconds)
        k = int(round(seconds / self.dt))
        if k == 0:
            return self
        v0, steps = float(self.leader_speed_mps[0]), np.arange(k, 0, -1)
        pos = np.concatenate([self.leader_pos_m[0] - v0 * self.dt * steps, self.leader_pos_m])
        return replace(self, leader_pos_m=pos - pos[0],
                       leader_speed_mps=np.concatenate([np.full(k, v0), self.leader_speed_mps]),
                       follower_speed_mps=np.concatenate(
                           [np.full(k, self.follower_speed_mps[0]), self.follower_speed_mps]),
                       gap_m=np.concatenate([np.full(k, self.gap_m[0]), self.gap_m]),
                       scored_from=self.scored_from + k)

    @property
    def leader_travel_m(self) -> float:
        """Distance the leader covers over the event (m)."""
        return float(self.leader_pos_m.max() - self.leader_pos_m[0])


MAX_WARMUP_S = 3600.0
"""The longest warm-up before an event (s): an hour, 36,000 steps (a platoon settles in a minute
or two); a longer one is refused before anything is allocated."""


def check_warmup(seconds: float, option: str = "--warmup") -> float:
    """``seconds`` of warm-up, or InputError (one line) when it is negative, not finite or longer
    than :data:`MAX_WARMUP_S`."""
    if not (math.isfinite(seconds) and 0 <= seconds <= MAX_WARMUP_S):
        raise InputError(f"{option} must be from 0 to {MAX_WARMUP_S:g} s (a platoon settles in a "
                         f"minute or two), got {seconds:g}")
    return float(seconds)


def check_whole_steps(seconds: float, option: str = "--warmup") -> float:
    """``seconds``, or InputError (one line) when it is not a whole number of simulation steps."""
    if abs(seconds / DT_S - round(seconds / DT_S)) > 1e-6:
        raise InputError(f"{option} {seconds} is not a multiple of the {DT_S} s step; give e.g. "
                         f"{round(seconds / DT_S) * DT_S:g}")
    return seconds


def read_event_table(path: str | Path) -> pd.DataFrame:
    """Read and validate an event table (CSV, optionally gzip-compressed).

    Raises InputError for a missing file, unreadable content, missing columns or NaN values.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"data file {path} does not exist; give the path of an event table "
                         "(e.g. ../shared/data/ngsim/ngsim_cf_events.csv.gz) or --data default")
    try:
        table = pd.read_csv(path, low_memory=False)
    except Exception as exc:  # pandas raises many types for malformed files
        raise InputError(f"data file {path} is not a readable CSV table ({type(exc).__name__}: "
                         f"{str(exc).splitlines()[0] if str(exc) else 'no detail'})") from exc
    validate_event_table(table, str(path))
    return table


def validate_event_table(table: pd.DataFrame, name: str) -> None:
    """Check columns, NaN and numeric types of an event table; raise InputError if wrong."""
    missing = [c for c in REQUIRED_COLUMNS if c not in table.columns]
    if missing:
        raise InputError(f"{name} lacks the column(s) {', '.join(missing)}; an event table needs "
                         f"{', '.join(REQUIRED_COLUMNS)} (see the data format in the README)")
    if table.empty:
        raise InputError(f"{name} holds no rows; give a table with at least one event")
    for column in NUMERIC_REQUIRED:
        values = pd.to_numeric(table[column], errors="coerce")
        bad = values.isna() | np.isinf(values.to_numpy(float))
        if bad.any():
            row = int(np.flatnonzero(bad.to_numpy())[0])
            raise InputError(f"{name}: column {column} has a missing, infinite or non-numeric "
                             f"value (NaN, inf) in "
                             f"event {table['event_id'].iloc[row]} at data row {row + 2}; "
                             "fix or drop that event")
        table[column] = values.astype(float)
    for column in ("leader_pos_m", "leader_length_m"):
        if column in table.columns:
            table[column] = pd.to_numeric(table[column], errors="coerce")


def select_split(table: pd.DataFrame, split: str) -> pd.DataFrame:
    """Rows of the events of one split (see :data:`SPLITS`)."""
    if split not in SPLITS:
        raise InputError(f"unknown split {split!r}; choose one of {', '.join(SPLITS)}")
    if split == "all":
        return table
    is_test = table["source"].isin(TEST_SOURCES)
    is_us101 = table["site"].astype(str).str.lower().isin({"us-101", "us101"})
    mask = {"test": is_test, "us101": is_us101, "train": ~is_test & ~is_us101}[split]
    return table[mask]


PLAUSIBLE: tuple[tuple[str, str, float, float, str], ...] = (
    ("leader_speed_mps", "speed", 0.0, MAX_SPEED_MPS, "m/s"),
    ("follower_speed_mps", "speed", 0.0, MAX_SPEED_MPS, "m/s"),
    ("leader_acc_mps2", "acceleration", -MAX_ABS_ACC_MPS2, MAX_ABS_ACC_MPS2, "m/s²"),
    ("follower_acc_mps2", "acceleration", -MAX_ABS_ACC_MPS2, MAX_ABS_ACC_MPS2, "m/s²"),
    ("gap_m", "gap", 0.0, MAX_GAP_M, "m"),
)
"""(column, quantity, lowest, highest, unit) of the plausibility checks; a missing optional column
or a NaN in one is not checked (speeds and gaps are required and never NaN)."""


def _check_plausible(rows: pd.DataFrame, event_id, name: str) -> None:
    """InputError naming the event, the column, the row (its t_s and sample) and the value of
    the first value outside :data:`PLAUSIBLE`'s range (a gap must be above 0)."""
    for column, quantity, low, high, unit in PLAUSIBLE:
        if column not in rows.columns:
            continue
        values = rows[column].to_numpy(float)
        outside = (values > high) | ((values <= low) if column == "gap_m" else (values < low))
        bad = np.flatnonzero(outside & ~np.isnan(values))  # an infinite value is outside too
        if bad.size:
            k = int(bad[0])
            bound = f"above 0 and at most {high:g}" if column == "gap_m" else \
                f"from {low:g} to {high:g}"
            raise InputError(f"{name}: event {event_id} has an implausible {quantity} in column "
                             f"{column}: {values[k]:g} {unit} at t_s = {rows['t_s'].iloc[k]:g} s "
                             f"(row {rows.index[k]}, sample {k} of the event); a {quantity} must be "
                             f"{bound} {unit}: check the units or drop that event")


def events_from_table(table: pd.DataFrame, name: str = "event table") -> list[Event]:
    """Build :class:`Event` objects from a validated table, in file order of their first row.

    Leader positions come from ``leader_pos_m`` when an event has them all, otherwise they are the
    integral of the leader speed with SUMO's update rule ``x[k+1] = x[k] + v[k+1] * dt``.
    """
    events: list[Event] = []
    has_pos = "leader_pos_m" in table.columns
    has_len = "leader_length_m" in table.columns
    has_lane = "lane" in table.columns
    for event_id, rows in table.groupby("event_id", sort=False):
        t = rows["t_s"].to_numpy(float)
        if len(t) < MIN_SCORED_SAMPLES:
            raise InputError(f"{name}: event {event_id} lasts {(len(t) - 1) * DT_S:.1f} s "
                             f"({len(t)} samples); an event needs at least {MIN_EVENT_S:g} s "
                             f"({MIN_SCORED_SAMPLES} samples {DT_S} s apart): drop that event or "
                             "give a longer one")
        steps = np.diff(t)
        if not np.allclose(steps, DT_S, atol=1e-3):
            raise InputError(f"{name}: event {event_id} is not sampled every {DT_S} s in column "
                             "t_s (rows must be contiguous and ordered by time)")
        leader_speed = rows["leader_speed_mps"].to_numpy(float)
        _check_plausible(rows, event_id, name)
        pos = rows["leader_pos_m"].to_numpy(float) if has_pos else None
        if pos is not None and np.isinf(pos).any():
            raise InputError(f"{name}: event {event_id} has an infinite leader_pos_m; fix or "
                             "drop that event")
        if pos is None or np.isnan(pos).any():
            pos = np.concatenate([[0.0], np.cumsum(leader_speed[1:]) * DT_S])
        else:
            pos = pos - pos[0]
        length = float(rows["leader_length_m"].iloc[0]) if has_len else float("nan")
        if not np.isfinite(length) or length <= 0:
            length = DEFAULT_VEHICLE_LENGTH_M
        lane_value = pd.to_numeric(rows["lane"].iloc[0], errors="coerce") if has_lane else np.nan
        events.append(Event(
            event_id=str(event_id),
            source=str(rows["source"].iloc[0]),
            site=str(rows["site"].iloc[0]),
            leader_pos_m=pos,
            leader_speed_mps=leader_speed,
            leader_length_m=length,
            follower_speed_mps=rows["follower_speed_mps"].to_numpy(float),
            gap_m=rows["gap_m"].to_numpy(float),
            lane=None if pd.isna(lane_value) else int(lane_value),
        ))
    return events


def read_event_ids(path: str | Path) -> list[str]:
    """Event IDs listed in a text file, one per line (blank lines and ``#`` comments skipped);
    InputError for a file that cannot be read or lists none."""
    try:
        lines = Path(path).read_text().splitlines()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read the event ID list {path}: {exc}; give a text file with "
                         "one event ID per line") from None
    ids = [line.split("#", 1)[0].strip() for line in lines]
    ids = [i for i in ids if i]
    if not ids:
        raise InputError(f"the event ID list {path} names no event; give one event ID per line")
    return ids
