"""Leader data: NGSIM event tables, raw NGSIM trajectories, the shipped default set, stop-and-go.

:func:`load_events` is the one entry point: ``data`` is ``default`` (the set shipped in
``carl_sumo/data/default_events.csv.gz``), ``stop-and-go`` (synthetic), or the path of an event
table (``ngsim_cf_events.csv.gz`` format) or of a raw NGSIM trajectory CSV. The lists of event
IDs that recipes name (``event_lists/*.txt``, read by :func:`carl_sumo.data.events.read_event_ids`)
ship beside the default set (:data:`carl_sumo.resources.EVENT_LISTS`).
"""

from __future__ import annotations

from pathlib import Path

from carl_sumo.data.events import SPLITS, Event, events_from_table, read_event_table, select_split
from carl_sumo.data.synthetic import STOP_AND_GO_ID, stop_and_go_event
from carl_sumo.errors import InputError

DEFAULT_EVENTS = Path(__file__).with_name("default_events.csv.gz")

__all__ = ["Event", "SPLITS", "DEFAULT_EVENTS", "load_events", "load_table"]


def load_table(data: str | Path):
    """The event table of ``data`` (``default`` or a path), validated."""
    if str(data) == "default":
        return read_event_table(DEFAULT_EVENTS)
    path = Path(data)
    from carl_sumo.data import raw

    if path.is_file() and raw.is_raw_ngsim(path):
        return raw.raw_ngsim_events(path)
    return read_event_table(path)


def load_events(data: str | Path = "default", split: str = "test", limit: int | None = None,
                event_ids: list[str] | None = None) -> list[Event]:
    """Events of one split of ``data``: the first ``limit`` ones, or those named in ``event_ids``."""
    if split not in SPLITS:
        raise InputError(f"unknown split {split!r}; choose one of {', '.join(SPLITS)}")
    if str(data) == "stop-and-go":
        events = [stop_and_go_event()]
    else:
        table = select_split(load_table(data), split)
        if event_ids is not None:
            wanted = set(event_ids)
            table = table[table["event_id"].isin(wanted)]
            missing = wanted - set(table["event_id"].unique())
            if missing:
                raise InputError(f"unknown event(s) {', '.join(sorted(missing))} in split {split} "
                                 f"of {data}; list them with `carl-sumo data list --data {data} "
                                 f"--split {split}`")
        elif limit is not None:
            keep = table["event_id"].drop_duplicates().iloc[:limit]
            table = table[table["event_id"].isin(set(keep))]
        events = events_from_table(table, str(data))
    if event_ids is not None and str(data) == "stop-and-go":
        unknown = set(event_ids) - {STOP_AND_GO_ID}
        if unknown:
            raise InputError(f"unknown event(s) {', '.join(sorted(unknown))}; the stop-and-go "
                             f"scenario has one event, {STOP_AND_GO_ID}")
    if not events:
        raise InputError(f"split {split} of {data} holds no events; choose another --split "
                         f"({', '.join(SPLITS)})")
    return events[:limit] if limit is not None else events
