"""The project's own default leader set, recorded from a congested SUMO run of human drivers.

:func:`make_default_set` simulates noisy human drivers (``routes/default_leaders.rou.xml``) on the
I-80-like network (``networks/i80.net.xml``) with libsumo. On-ramp traffic weaving across all lanes
after the Powell Street merge is a bottleneck for the heavy mainline demand, so a queue with
stop-and-go waves holds on ``i80_approach`` from about 400 s of simulated time on. Every
vehicle on that edge is recorded each 0.1 s (like an NGSIM camera), the records form a canonical
trajectory frame (see :mod:`carl_sumo.data.raw`) and car-following events are cut out of it with
:func:`carl_sumo.data.raw.extract_events`. About 30% of the events get the source
``carl_sumo_default_test`` (the test split), the rest ``carl_sumo_default_train``.

Generate the shipped file with ``python -m carl_sumo.data.default_set``.
"""

from __future__ import annotations

import argparse
import gzip
import sys
import time
from pathlib import Path

import numpy as np
import pandas as pd

from carl_sumo.data.events import DT_S, EVENT_COLUMNS, MIN_EVENT_SAMPLES
from carl_sumo.data.raw import TRAJ_COLUMNS, extract_events
from carl_sumo.errors import InputError
from carl_sumo.files import atomic_write
from carl_sumo.resources import DEFAULT_NET, ROUTES

DEFAULT_ROUTES = ROUTES / "default_leaders.rou.xml"
DEFAULT_EVENTS = Path(__file__).resolve().parent / "default_events.csv.gz"
"""The shipped default event table."""

TRAIN_SOURCE = "carl_sumo_default_train"
TEST_SOURCE = "carl_sumo_default_test"
SITE = "i80-sumo"
RECORD_EDGE = "i80_approach"
"""Edge observed by the virtual camera (6 lanes, 1600 m)."""

NGSIM_LANES_6 = 6
"""NGSIM lane k (1 = leftmost) is SUMO lane index 6 - k on the 6-lane edges."""

WARMUP_S = 300.0
"""Simulated time before recording starts, when ``duration_s`` allows it (s)."""

CONTEXT_RANGE_M = 100.0
"""Lateral range of the context subscription around :data:`RECORD_EDGE` (m)."""

MAX_EVENT_S = 27.0
"""Recorded events longer than this are cut to their first ``MAX_EVENT_S`` seconds (s); keeps the
shipped file under 1.5 MB (the median NGSIM event lasts about 31 s)."""

CONGESTED_MAX_MPS = 15.0
"""Events are chosen among those with a mean follower speed up to this (m/s), if enough."""

FOLLOWING_MAX_GAP_M = 100.0
"""... and whose gap stays below this (m; the largest gap in the NGSIM I-80 events is 99 m)."""


def _close_running() -> None:
    """Close a libsumo simulation that is already running in this process."""
    import libsumo

    try:
        loaded = libsumo.simulation.isLoaded()
    except Exception:  # noqa: BLE001 - an unusable old session is treated as loaded
        loaded = True
    if loaded:
        try:
            libsumo.close()
        except Exception:  # noqa: BLE001
            pass


def record_trajectories(net: Path, routes: Path, seed: int, duration_s: float,
                        warmup_s: float) -> pd.DataFrame:
    """Run SUMO (libsumo) and record every vehicle on :data:`RECORD_EDGE` each 0.1 s.

    Returns the canonical trajectory frame (``vehicle, frame, pos_m [m], speed_mps [m/s],
    acc_mps2 [m/s²], length_m [m], lane (NGSIM number), leader``); ``frame`` counts 0.1 s steps
    from the start of the simulation, vehicle ids are numbered 1, 2, ... in order of departure,
    and the leader is the next recorded vehicle ahead in the same lane in the same frame (0 = none).
    """
    import libsumo
    from libsumo import constants as tc

    _close_running()
    args = ["sumo", "-n", str(net), "-r", str(routes), "--step-length", f"{DT_S}",
            "--seed", str(int(seed)), "--no-step-log", "--no-warnings", "--begin", "0",
            "--end", f"{duration_s}", "--time-to-teleport", "-1", "--collision.action", "warn"]
    libsumo.start(args)
    variables = (tc.VAR_LANE_ID, tc.VAR_LANEPOSITION, tc.VAR_SPEED, tc.VAR_ACCELERATION)
    lane_prefix = RECORD_EDGE + "_"
    cut = len(lane_prefix)
    numbers: dict[str, int] = {}
    lengths: list[float] = [0.0]
    chunks: list[np.ndarray] = []
    n_steps = int(round(duration_s / DT_S))
    first_frame = int(round(warmup_s / DT_S))
    try:
        # Context subscription around the edge (its range is lateral, so it is generous and the
        # vehicles are then filtered by lane id).
        libsumo.edge.subscribeContext(RECORD_EDGE, tc.CMD_GET_VEHICLE_VARIABLE, CONTEXT_RANGE_M,
                                      variables)
        for step in range(1, n_steps + 1):
            libsumo.simulationStep()
            for vid in libsumo.simulation.getDepartedIDList():
                numbers[vid] = len(numbers) + 1
                lengths.append(libsumo.vehicle.getLength(vid))
            if step < first_frame:
                continue
            results = libsumo.edge.getContextSubscriptionResults(RECORD_EDGE)
            if not results:
                continue
            rows = [(numbers[vid], step, int(res[tc.VAR_LANE_ID][cut:]), res[tc.VAR_LANEPOSITION],
                     res[tc.VAR_SPEED], res[tc.VAR_ACCELERATION])
                    for vid, res in results.items() if res[tc.VAR_LANE_ID].startswith(lane_prefix)]
            if rows:
                chunks.append(np.array(rows, dtype=float))
    finally:
        libsumo.close()
    data = np.concatenate(chunks) if chunks else np.zeros((0, 6))
    length_by_number = np.asarray(lengths, dtype=float)
    traj = pd.DataFrame({
        "vehicle": data[:, 0].astype(np.int64),
        "frame": data[:, 1].astype(np.int64),
        "pos_m": data[:, 3],
        "speed_mps": data[:, 4],
        "acc_mps2": data[:, 5],
        "lane": NGSIM_LANES_6 - data[:, 2].astype(np.int64),
    })
    traj["length_m"] = length_by_number[traj["vehicle"].to_numpy()]
    traj["leader"] = _leaders_ahead(traj)
    return traj.sort_values(["vehicle", "frame"], kind="mergesort").reset_index(drop=True)[
        list(TRAJ_COLUMNS)]


def _leaders_ahead(traj: pd.DataFrame) -> np.ndarray:
    """Id of the next vehicle ahead in the same frame and lane (0 = none), aligned with ``traj``."""
    order = np.lexsort((traj["pos_m"].to_numpy(), traj["lane"].to_numpy(),
                        traj["frame"].to_numpy()))
    frame = traj["frame"].to_numpy()[order]
    lane = traj["lane"].to_numpy()[order]
    vehicle = traj["vehicle"].to_numpy()[order]
    ahead = np.zeros(len(order), dtype=np.int64)
    if len(order) > 1:
        same = (frame[1:] == frame[:-1]) & (lane[1:] == lane[:-1])
        ahead[:-1] = np.where(same, vehicle[1:], 0)
    leader = np.zeros(len(order), dtype=np.int64)
    leader[order] = ahead
    return leader


def _truncate(events: pd.DataFrame, max_samples: int) -> pd.DataFrame:
    """Keep the first ``max_samples`` rows of each event."""
    index = events.groupby("event_id", sort=False).cumcount()
    return events[index < max_samples]


def select_events(events: pd.DataFrame, max_events: int,
                  max_mean_speed_mps: float = CONGESTED_MAX_MPS,
                  max_gap_m: float = FOLLOWING_MAX_GAP_M) -> list[str]:
    """Deterministic choice of at most ``max_events`` event ids with variety.

    Candidates are the congested car-following events (mean follower speed at most
    ``max_mean_speed_mps`` in m/s, gap always at most ``max_gap_m`` in m), or all events when there
    are fewer than ``max_events`` of those; one event per follower (its longest) where that still
    leaves enough. The choice is evenly spaced in mean follower speed, so
    stop-and-go, slow and faster events (and so all lanes) are represented. Returned in order of
    mean speed.
    """
    summary = events.groupby("event_id", sort=True).agg(
        follower=("follower_id", "first"), n=("t_s", "size"),
        speed=("follower_speed_mps", "mean"), gap=("gap_m", "max")).reset_index()
    congested = summary[(summary["speed"] <= max_mean_speed_mps) & (summary["gap"] <= max_gap_m)]
    pool = congested if len(congested) >= max_events else summary
    by_follower = (pool.sort_values(["follower", "n", "event_id"], ascending=[True, False, True])
                   .drop_duplicates("follower"))
    if len(by_follower) >= max_events:
        pool = by_follower
    pool = pool.sort_values(["speed", "event_id"]).reset_index(drop=True)
    if len(pool) <= max_events:
        return pool["event_id"].tolist()
    # Targets evenly spaced in speed (not in rank): the set covers the whole speed range evenly
    # even where the pool is dense at some speeds. Each target takes the nearest unused event.
    speeds = pool["speed"].to_numpy()
    free = np.ones(len(pool), dtype=bool)
    chosen: list[int] = []
    for target in np.linspace(speeds[0], speeds[-1], max_events):
        distance = np.where(free, np.abs(speeds - target), np.inf)
        pick = int(np.argmin(distance))
        free[pick] = False
        chosen.append(pick)
    return pool["event_id"].to_numpy()[np.sort(chosen)].tolist()


def write_table_atomic(table: pd.DataFrame, out: Path) -> None:
    """Write ``table`` as gzip CSV (``%.4f``) whole or not at all (:mod:`carl_sumo.files`).

    The gzip header carries no file name and no time stamp, so equal tables give equal bytes.
    """
    out = Path(out)
    data = table.to_csv(index=False, float_format="%.4f", lineterminator="\n").encode("utf-8")
    with atomic_write(out, "wb") as raw_file:
        with gzip.GzipFile(filename="", mode="wb", fileobj=raw_file, compresslevel=9,
                           mtime=0) as gz:
            gz.write(data)


def make_default_set(net: Path, out: Path, seed: int = 42, duration_s: float = 1200.0,
                     max_events: int = 160, *, routes: Path | None = None,
                     warmup_s: float | None = None,
                     max_event_s: float = MAX_EVENT_S) -> pd.DataFrame:
    """Simulate congested human traffic, extract car-following events and write them to ``out``.

    ``duration_s``: simulated time (s), of which the first ``warmup_s`` (default: 300 s, at most a
    quarter of ``duration_s``) is not recorded. Events are cut to their first ``max_event_s``
    seconds; at most ``max_events`` are kept (see :func:`select_events`). Every third of them,
    in order of mean speed, gets source ``carl_sumo_default_test``, the others
    ``carl_sumo_default_train``; site ``i80-sumo``, period ``sumo-seed{seed}``. The table is
    written atomically to ``out`` (gzip CSV) and returned. A run is reproducible for a seed.

    Raises InputError for missing network/route files or when the run yields no event.
    """
    net = Path(net)
    routes = DEFAULT_ROUTES if routes is None else Path(routes)
    for name, path in (("network", net), ("route", routes)):
        if not path.is_file():
            raise InputError(f"SUMO {name} file {path} does not exist; give an existing file")
    if duration_s <= 0 or max_events < 1:
        raise InputError("duration_s must be > 0 s and max_events >= 1")
    warmup = min(WARMUP_S, duration_s / 4.0) if warmup_s is None else float(warmup_s)
    traj = record_trajectories(net, routes, seed, duration_s, warmup)
    period = f"sumo-seed{seed}"
    events = extract_events(traj, source=TRAIN_SOURCE, site=SITE, period=period,
                            id_prefix=f"sumo{seed}", min_samples=MIN_EVENT_SAMPLES)
    if events.empty:
        raise InputError(f"the SUMO run ({duration_s:g} s, seed {seed}) gave no car-following "
                         f"event of at least {MIN_EVENT_SAMPLES} samples; simulate longer")
    max_samples = max(MIN_EVENT_SAMPLES, int(round(max_event_s / DT_S)) + 1)
    events = _truncate(events, max_samples)
    chosen = select_events(events, max_events)
    test_ids = set(chosen[1::3])
    rank = {event_id: i for i, event_id in enumerate(chosen)}
    events = events[events["event_id"].isin(rank)].copy()
    events["source"] = np.where(events["event_id"].isin(test_ids), TEST_SOURCE, TRAIN_SOURCE)
    events["_rank"] = events["event_id"].map(rank)
    events = (events.sort_values(["_rank", "t_s"], kind="mergesort")
              .drop(columns="_rank").reset_index(drop=True))[list(EVENT_COLUMNS)]
    write_table_atomic(events, Path(out))
    return events


def summarize(events: pd.DataFrame) -> str:
    """A few lines on an event table: events per source, durations, speeds (m/s), gaps (m)."""
    g = events.groupby("event_id", sort=False)
    mean_speed = g["follower_speed_mps"].mean()
    duration = (g.size() - 1) * DT_S
    sources = g["source"].first().value_counts().to_dict()
    q = mean_speed.quantile([0.1, 0.5, 0.9]).to_numpy()
    return "\n".join([
        f"events: {g.ngroups} ({', '.join(f'{k}: {v}' for k, v in sorted(sources.items()))}), "
        f"rows: {len(events)}",
        f"duration (s): min {duration.min():.1f}, median {duration.median():.1f}, "
        f"max {duration.max():.1f}",
        f"event-mean follower speed (m/s): min {mean_speed.min():.2f}, p10 {q[0]:.2f}, "
        f"median {q[1]:.2f}, p90 {q[2]:.2f}, max {mean_speed.max():.2f}",
        f"speed range (m/s): {events['follower_speed_mps'].min():.2f} - "
        f"{events['follower_speed_mps'].max():.2f}; events with a stop (< 0.5 m/s): "
        f"{int((g['follower_speed_mps'].min() < 0.5).sum())}",
        f"gap (m): min {events['gap_m'].min():.2f}, median {events['gap_m'].median():.2f}, "
        f"max {events['gap_m'].max():.2f}",
        f"lanes: {dict(sorted(g['lane'].first().value_counts().to_dict().items()))}",
    ])


def main(argv: list[str] | None = None) -> int:
    """Command line: generate the default event table and print a summary."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--net", type=Path, default=DEFAULT_NET)
    parser.add_argument("--routes", type=Path, default=DEFAULT_ROUTES)
    parser.add_argument("--out", type=Path, default=DEFAULT_EVENTS)
    parser.add_argument("--seed", type=int, default=42)
    parser.add_argument("--duration", type=float, default=1200.0, help="simulated time (s)")
    parser.add_argument("--max-events", type=int, default=160)
    args = parser.parse_args(argv)
    start = time.perf_counter()
    try:
        events = make_default_set(args.net, args.out, seed=args.seed, duration_s=args.duration,
                                  max_events=args.max_events, routes=args.routes)
    except InputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    elapsed = time.perf_counter() - start
    print(f"wrote {args.out} ({args.out.stat().st_size / 1e6:.2f} MB) in {elapsed:.0f} s")
    print(summarize(events))
    return 0


if __name__ == "__main__":
    sys.exit(main())
