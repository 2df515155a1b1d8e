import numpy as np
import pandas as pd
import pytest

from carl_sumo.data import load_events, load_table
from carl_sumo.data.events import events_from_table, select_split
from carl_sumo.data.synthetic import stop_and_go_event
from carl_sumo.errors import InputError


def test_table_round_trip_and_positions_integrate_speed(small_table_path, small_events):
    events = load_events(small_table_path, "all")
    assert [e.event_id for e in events] == [e.event_id for e in small_events]
    e, ref = events[0], small_events[0]
    assert np.allclose(e.leader_speed_mps, ref.leader_speed_mps)
    assert np.allclose(np.diff(e.leader_pos_m), e.leader_speed_mps[1:] * 0.1)
    assert e.initial_gap_m == 20.0 and e.initial_speed_mps == 12.0


def test_splits(small_table_path):
    assert [e.event_id for e in load_events(small_table_path, "test")] == ["ev_test_0", "ev_test_1"]
    assert [e.event_id for e in load_events(small_table_path, "train")] == ["ev_train_0"]
    with pytest.raises(InputError, match="no events"):
        load_events(small_table_path, "us101")
    with pytest.raises(InputError, match="unknown split"):
        load_events(small_table_path, "validation")
    assert len(load_events(small_table_path, "test", limit=1)) == 1


def test_positions_used_when_given(small_table_path):
    table = pd.read_csv(small_table_path)
    table["leader_pos_m"] = 100.0 + table["t_s"] * 3.0
    (e,) = events_from_table(table[table.event_id == "ev_test_0"])
    assert np.allclose(e.leader_pos_m, table[table.event_id == "ev_test_0"].t_s * 3.0)


@pytest.mark.parametrize("mutate, message", [
    (lambda t: t.drop(columns=["gap_m"]), "lacks the column"),
    (lambda t: t.assign(leader_speed_mps=t.leader_speed_mps.where(t.index != 5)), "NaN"),
    (lambda t: t.assign(gap_m="x"), "non-numeric"),
    (lambda t: t.assign(t_s=t.t_s * 2), "not sampled every"),
])
def test_bad_tables(tmp_path, small_table_path, mutate, message):
    bad = tmp_path / "bad.csv"
    mutate(pd.read_csv(small_table_path)).to_csv(bad, index=False)
    with pytest.raises(InputError, match=message):
        load_events(bad, "all")


def _one_event(small_table_path, tmp_path, rows=None, **columns):
    """A table of the first event of the small table, cut to ``rows`` and with columns replaced."""
    table = pd.read_csv(small_table_path)
    table = table[table.event_id == "ev_test_0"].iloc[:rows].assign(**columns)
    path = tmp_path / "one.csv"
    table.to_csv(path, index=False)
    return path


@pytest.mark.parametrize("rows", [1, 2, 50])
def test_an_event_shorter_than_5_s_is_refused_with_exit_2(capsys, tmp_path, small_table_path,
                                                          rows):
    from carl_sumo.cli import main

    path = _one_event(small_table_path, tmp_path, rows)
    with pytest.raises(InputError, match=f"ev_test_0 lasts .* s \\({rows} samples\\); an event "
                                         "needs at least 5 s"):
        load_events(path, "all")
    assert main(["simulate", "--data", str(path), "--split", "all", "--vehicles", "2"]) == 2
    out, err = capsys.readouterr()
    assert out == "" and err.count("\n") == 1 and "at least 5 s" in err
    (event,) = load_events(_one_event(small_table_path, tmp_path, 51), "all")  # 5.0 s is enough
    assert event.n_samples == 51


@pytest.mark.parametrize("column", ["leader_speed_mps", "follower_speed_mps"])
def test_an_implausible_speed_is_named_as_such(capsys, tmp_path, small_table_path, column):
    from carl_sumo.cli import main

    path = _one_event(small_table_path, tmp_path)
    table = pd.read_csv(path)
    table.loc[7, column] = 1e6
    table.to_csv(path, index=False)
    with pytest.raises(InputError, match=f"ev_test_0 has an implausible speed in column {column}: "
                                         "1e\\+06 m/s at t_s = 0.7 s"):
        load_events(path, "all")
    assert main(["simulate", "--data", str(path), "--split", "all", "--vehicles", "2"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "implausible speed" in err and "too short" not in err
    table.loc[7, column] = 70.0  # the bound itself is plausible
    table.to_csv(path, index=False)
    assert load_events(path, "all")[0].n_samples == len(table)


@pytest.mark.parametrize("column, value, quantity", [
    ("leader_acc_mps2", -15.5, "acceleration"), ("follower_acc_mps2", 40.0, "acceleration"),
    ("gap_m", 600.0, "gap"), ("gap_m", -1.0, "gap"), ("leader_speed_mps", -2.0, "speed")])
def test_implausible_accelerations_gaps_and_speeds_are_named_with_their_row(
        tmp_path, small_table_path, column, value, quantity):
    path = _one_event(small_table_path, tmp_path)
    table = pd.read_csv(path)
    if column not in table:
        table[column] = 0.0
    table.loc[12, column] = value
    table.to_csv(path, index=False)
    with pytest.raises(InputError, match=f"ev_test_0 has an implausible {quantity} in column "
                                         f"{column}: {value:g} .* at t_s = 1.2 s \\(row 12, "
                                         "sample 12 of the event\\)"):
        load_events(path, "all")
    table.loc[12, column] = {"gap_m": 500.0, "leader_speed_mps": 0.0}.get(column, 15.0)
    table.to_csv(path, index=False)  # the bounds themselves are plausible
    assert load_events(path, "all")[0].n_samples == len(table)


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        load_table(tmp_path / "nope.csv")
    garbage = tmp_path / "garbage.csv.gz"
    garbage.write_bytes(b"\x1f\x8b not really gzip")
    with pytest.raises(InputError, match="not a readable CSV"):
        load_table(garbage)


def test_unknown_event(small_table_path):
    with pytest.raises(InputError, match="unknown event"):
        load_events(small_table_path, "all", event_ids=["nope"])


def test_stop_and_go_brakes_repeatedly_to_near_standstill():
    e = stop_and_go_event()
    v = e.leader_speed_mps
    assert v.max() == pytest.approx(25.0) and v.min() <= 1.0
    stops = np.sum((v[1:] <= 1.0) & (v[:-1] > 1.0))
    assert stops == 3
    assert np.diff(v).min() / 0.1 == pytest.approx(-5.0)
    assert load_events("stop-and-go")[0].event_id == "stop_and_go"


def test_default_set_ships_train_and_test():
    test, train = load_events("default", "test"), load_events("default", "train")
    assert len(test) >= 10 and len(train) >= 20
    assert {e.source for e in test} == {"carl_sumo_default_test"}


def test_shared_ngsim_protocol_splits(ngsim_dir):
    table = load_table(ngsim_dir / "ngsim_cf_events.csv.gz")
    test = select_split(table, "test")
    assert test.event_id.nunique() == 403 and set(test.source) == {"zhu2020_testset"}
    train = select_split(table, "train")
    assert set(train.site) == {"i-80"} and train.event_id.nunique() == 1176 - 403
    assert select_split(table, "us101").event_id.nunique() == 165


@pytest.mark.parametrize("column,row", [("leader_speed_mps", 40), ("follower_speed_mps", 0),
                                        ("gap_m", 10), ("leader_pos_m", 20)])
def test_an_infinite_value_is_refused_with_one_line(tmp_path, capsys, column, row):
    """Found by fault injection: an infinite leader speed mid-event used to run and score."""
    from carl_sumo.data import DEFAULT_EVENTS

    table = pd.read_csv(DEFAULT_EVENTS)
    first = table[table["event_id"] == table["event_id"].iloc[0]].copy()
    first.iloc[row, first.columns.get_loc(column)] = np.inf
    path = tmp_path / "inf.csv"
    first.to_csv(path, index=False)
    with pytest.raises(InputError, match="infinite|implausible"):
        load_events(str(path), "all")
