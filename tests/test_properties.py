"""Property-based tests: random event tables, policy bytes and CLI values give a result or an
InputError (exit status 2 from the CLI), never another exception."""

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from carl_sumo.cli import main
from carl_sumo.data import load_events
from carl_sumo.data.events import REQUIRED_COLUMNS
from carl_sumo.errors import InputError
from carl_sumo.learn.policy import load_policy

from conftest import NET

SETTINGS = settings(max_examples=40, deadline=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture])

cell = st.one_of(st.floats(allow_nan=True, allow_infinity=True, width=32),
                 st.integers(-10**6, 10**6), st.text(max_size=4), st.none())


@st.composite
def event_tables(draw):
    """A CSV text: a random subset of the required columns (sometimes all), 0-12 rows of random
    cells, or of plausible numbers with random times."""
    columns = draw(st.lists(st.sampled_from(REQUIRED_COLUMNS), unique=True, min_size=0,
                            max_size=len(REQUIRED_COLUMNS)))
    if draw(st.booleans()):
        columns = list(REQUIRED_COLUMNS)
    n = draw(st.integers(0, 12))
    plausible = draw(st.booleans())
    rows = []
    for k in range(n):
        row = []
        for c in columns:
            if plausible and c == "t_s":
                row.append(round(k * draw(st.sampled_from([0.1, 0.1, 0.2, -0.1])), 3))
            elif plausible and c.endswith(("_mps", "_m")):
                row.append(draw(st.floats(-5, 100, allow_nan=False)))
            elif plausible and c == "event_id":
                row.append(draw(st.sampled_from(["a", "b"])))
            else:
                row.append(draw(cell))
        rows.append(row)
    text = ",".join(columns) + "\n" + "\n".join(",".join("" if v is None else str(v)
                                                         for v in row) for row in rows)
    return text


@SETTINGS
@given(text=event_tables(), split=st.sampled_from(["all", "train", "test", "us101", "nope"]))
def test_random_event_tables_load_or_fail_with_input_error(tmp_path, text, split):
    path = tmp_path / "events.csv"
    path.write_text(text)
    try:
        events = load_events(path, split)
    except InputError as exc:
        assert str(exc)
        return
    for e in events:  # what loads is usable: finite, non-negative, plausible speeds, >= 3 samples
        assert len(e.leader_speed_mps) >= 3
        assert np.all(np.isfinite(e.leader_speed_mps)) and np.all(e.leader_speed_mps >= 0)
        assert np.all(e.leader_speed_mps <= 70.0)


@SETTINGS
@given(data=st.binary(max_size=512))
def test_random_policy_bytes_fail_with_input_error(tmp_path, data):
    path = tmp_path / "p.pt"
    path.write_bytes(data)
    with pytest.raises(InputError):
        load_policy(path)


@settings(max_examples=25, deadline=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(vehicles=st.one_of(st.integers(-3, 12).map(str), st.text(max_size=3)),
       events=st.one_of(st.integers(-1, 2).map(str), st.text(max_size=3)),
       controller=st.one_of(st.sampled_from(["idm", "ploeg:h=0.8", "ploeg:h=-1", "ploeg:kp=x",
                                             "ploeg-tuned:h=0.7", "sumo-cacc", "human"]),
                            st.text(max_size=6)),
       split=st.sampled_from(["test", "train", "all", "x"]))
def test_random_simulate_values_give_a_result_or_exit_2(capsys, vehicles, events, controller,
                                                        split):
    code = main(["simulate", "--net", str(NET), "--data", "default", "--split", split,
                 "--vehicles", vehicles, "--events", events, "--controller", controller])
    err = capsys.readouterr().err
    assert code in (0, 2)
    if code == 2:
        assert len(err.strip().splitlines()) == 1 and err.startswith("carl-sumo: error:")
