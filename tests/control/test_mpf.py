"""The multi-predecessor CACC ``mpf``: its names, its relayed feed-forward, that it is Ploeg's
law (r = 1) and the ACC (r = 0) to the bit and degrades to Ploeg's law where its chain is broken,
on chains as on a platoon, and its bad input (one line, exit 2, before any simulation). Its
frequency test is in tests/experiments/test_string_stability.py."""

from __future__ import annotations

import numpy as np
import pytest

from carl_sumo.cli import main
from carl_sumo.control.cacc import (PloegChains, mpf_feed_forward, mpf_relay, parse_ploeg,
                                    ploeg_controller)
from carl_sumo.control.channel import FALLBACK, HELD, LIVE, Impairments, plant_impairments
from carl_sumo.errors import InputError
from carl_sumo.experiments.simulate import cached_sim, resolve_controller, run_event

from conftest import NET, braking_event

LAYERS = "h=0.8:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2:rb=1"


@pytest.mark.parametrize("name,weights,canonical", [
    ("mpf", (0.5, 0.5), "mpf:h=1:kp=0.2:kd=0.7:r=2:w1=0.5:w2=0.5"),
    ("mpf:r=2:w2=0.3", (0.7, 0.3), "mpf:h=1:kp=0.2:kd=0.7:r=2:w1=0.7:w2=0.3"),
    ("mpf:r=3:w2=0.2:h=0.6", (0.4, 0.2, 0.4), "mpf:h=0.6:kp=0.2:kd=0.7:r=3:w1=0.4:w2=0.2:w3=0.4"),
    ("mpf:r=2:w1=1:w2=0.5", (1.0, 0.5), "mpf:h=1:kp=0.2:kd=0.7:r=2:w1=1:w2=0.5"),
    ("mpf:r=2:w1=0:w2=1", (0.0, 1.0), "mpf:h=1:kp=0.2:kd=0.7:r=2:w1=0:w2=1"),
    ("mpf:r=1", (1.0,), "ploeg:h=1:kp=0.2:kd=0.7"),
    ("mpf:r=0:h=3", (1.0,), "acc:h=3:kp=0.2:kd=0.7"),
    (f"mpf:{LAYERS}:r=2:w2=0.3:ht=1", (0.7, 0.3),
     "mpf:h=0.8:kp=0.0445:kd=1:r=2:w1=0.7:w2=0.3:aw=1:ha=1.4:ttc=2:rb=1:ht=1"),
])
def test_mpf_names(name, weights, canonical):
    p = parse_ploeg(name)
    assert p.weights == weights and p.name() == canonical
    assert p.heard == (0 if name.startswith("mpf:r=0") else len(weights))
    assert parse_ploeg(canonical) == p  # the canonical name runs the same law


@pytest.mark.parametrize("name,words", [
    ("mpf:r=2:w2=-0.1", "w2=-0.1 must be a number of at least 0, finite"),
    ("mpf:r=2:w1=nan", "w1=nan must be a number"),
    ("mpf:r=2:w1=inf", "w1=inf must be a number"),
    ("mpf:r=2:w3=0.1", "w3 is the weight of vehicle 3 ahead, but the law hears r = 2"),
    ("mpf:r=0:w1=1", "hears no vehicle ahead"),
    ("mpf:r=1.5", "r=1.5 must be a whole number from 0 to 9"),
    ("mpf:r=-1", "r=-1 must be a whole number"),
    ("mpf:r=3:w1=0.9:w2=0.5", "sum to 1.4 > 1, so w3"),
    ("mpf:r=2:x=1", "'x=1' is not an option; write mpf:r=R:wJ=W:h=VALUE"),
    ("mpf:r=2:r=3", "given twice"),
    ("mpf:r=2:kp=0", "kp must be a positive number"),
])
def test_bad_mpf_names_are_one_line_input_errors(name, words):
    with pytest.raises(InputError, match=None) as info:
        parse_ploeg(name)
    assert words in str(info.value) and "\n" not in str(info.value)


def test_the_relay_feeds_forward_the_weighted_commands_and_degrades_where_the_chain_breaks():
    """Five vehicles with states 1, 2, 3, 4, 5 m/s², r = 3, w = (0.5, 0.3, 0.2). Every message
    live: vehicle i feeds forward Σ_j w_j·u_{i-j}, the weight of vehicles ahead of the head on its
    predecessor's. Vehicle 2 hearing nothing (a lost message past its timeout, a human ahead):
    it is an ACC (no feed-forward) and relays nothing, so vehicle 3 runs Ploeg's law (all weight
    on u_2) and vehicle 4 hears u_3 and u_2 only. A held message fading at w = 0.5 fades whole,
    as Ploeg's predecessor input does."""
    w = (0.5, 0.3, 0.2)
    sent = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    extra, messages = mpf_relay(w, sent)
    feed = extra + np.concatenate([[0.0], sent[:-1]])  # the law's u_in + extra
    assert extra[0] == 0.0
    np.testing.assert_allclose(feed[1:], [1.0, 0.7 * 2 + 0.3 * 1, 0.5 * 3 + 0.3 * 2 + 0.2 * 1,
                                          0.5 * 4 + 0.3 * 3 + 0.2 * 2], rtol=1e-15)
    np.testing.assert_allclose(extra, mpf_feed_forward(w, sent), rtol=0, atol=1e-15)
    assert messages.shape == (5, 5)
    np.testing.assert_array_equal(messages[3], [4.0, 3.0, 2.0, 1.0, 1.0])  # u_3, relays u_2, u_1

    mode = np.array([LIVE, LIVE, FALLBACK, LIVE, LIVE])
    extra, _ = mpf_relay(w, sent, mode, np.zeros((5, 5)), np.ones(5))
    assert extra[2] == 0.0 and extra[3] == 0.0
    assert extra[4] == pytest.approx(0.7 * 4 + 0.3 * 3 - 4)

    _, live = mpf_relay(w, sent)
    mode = np.array([LIVE, LIVE, LIVE, HELD, LIVE])
    received = np.zeros((5, 5))
    received[3] = 0.5 * live[2]  # the held message of vehicle 2, faded to w = 0.5
    extra, messages = mpf_relay(w, sent, mode, received, np.array([1, 1, 1, 0.5, 1]))
    assert extra[3] + received[3, 0] == pytest.approx(0.5 * (0.5 * 3 + 0.3 * 2 + 0.2 * 1))
    np.testing.assert_allclose(messages[3], [4.0, 1.5, 1.0, 0.5, 0.5])


@pytest.mark.parametrize("impairments", [
    None, Impairments(delay_s=0.2, loss=0.3, burst=3.0), plant_impairments("real")])
def test_one_vehicle_heard_is_ploeg_none_the_acc_and_a_short_chain_ploeg_in_sumo(impairments):
    """In SUMO, on a perfect and an impaired channel and on the real plant with Ploeg's layers:
    ``mpf:r=1`` is Ploeg's law and ``mpf:r=0`` the ACC, bit for bit. With ``mpf:r=2`` the head
    and the second follower drive as under Ploeg's law, bit for bit: the second hears only the
    head, whose vehicle ahead (the recorded leader) sends nothing. The third does not."""
    event = braking_event(300)

    def speeds(name: str, n: int) -> np.ndarray:
        model, ctrl = resolve_controller(name)
        return run_event(cached_sim(str(NET), model), event, n, ctrl,
                         impairments=impairments).speed

    ploeg = speeds(f"ploeg:{LAYERS}", 3)
    assert np.array_equal(speeds(f"mpf:{LAYERS}:r=1", 3), ploeg)
    assert np.array_equal(speeds(f"mpf:{LAYERS}:r=0", 3), speeds(f"acc:{LAYERS}", 3))
    mpf = speeds(f"mpf:{LAYERS}:r=2:w2=0.3", 3)
    assert np.array_equal(mpf[:, :2], ploeg[:, :2]) and not np.array_equal(mpf, ploeg)


def test_chains_run_the_law_as_a_platoon_does():
    """One chain of PloegChains over delayed vehicle-keyed links gives the platoon controller's
    accelerations over its channel, step by step: the same relays, the same delays."""
    from carl_sumo.config import DT_S

    name = f"mpf:{LAYERS}:r=3:w1=0.5:w2=0.3:w3=0.2"
    imp = Impairments(delay_s=0.1)
    platoon, chains = ploeg_controller(name), PloegChains(parse_ploeg(name), name)
    platoon.reset(5)
    platoon.connect(imp, "e")
    chains.connect(imp, "e")
    ids = [f"v{i}" for i in range(5)]
    ahead = [("L", 20.0)] + [(ids[i - 1], 20.0) for i in range(1, 5)]
    rng = np.random.default_rng(1)
    leader_before = None
    for k in range(60):
        obs = np.column_stack([15 + rng.normal(0, 1, 5), rng.normal(0, 0.5, 5),
                               20 + rng.normal(0, 2, 5), rng.normal(0, 0.5, 5)])
        leader = obs[0, 0] + obs[0, 3]
        a_lead = 0.0 if leader_before is None else (leader - leader_before) / DT_S
        leader_before = leader
        a = platoon.acceleration(obs)
        b = chains.acceleration(obs, [list(range(5))], ids, ahead, {"L": a_lead})
        assert np.allclose(a, b, rtol=0, atol=1e-12), k


def test_the_commands_run_mpf_by_name_and_refuse_bad_input_before_any_run(
        capsys, tmp_path, small_table_path):
    code = main(["simulate", "--controller", "ploeg:h=0.8,mpf:h=0.8:r=2:w2=0.3", "--data",
                 str(small_table_path), "--vehicles", "3", "--workers", "1"])
    out = capsys.readouterr().out
    assert code == 0
    assert [line.split()[0] for line in out.splitlines()[2:4]] == [
        "ploeg:h=0.8", "mpf:h=0.8:r=2:w2=0.3"]
    for argv, words in (
            (["simulate", "--controller", "mpf:r=3", "--data", str(small_table_path),
              "--vehicles", "3"], "r = 3 vehicles heard, but in a platoon of 3 followers"),
            (["simulate", "--controller", "mpf:r=2:w2=-1", "--data", str(small_table_path)],
             "w2=-1 must be a number of at least 0"),
            (["string-stability", "--controller", "mpf:r=3", "--vehicles", "3", "--net",
              str(NET), "--json", str(tmp_path / "s.json")], "give r ≤ 2 or more --vehicles"),
            (["string-stability", "--controller", "mpf:r=2:w9=1", "--net", str(NET)],
             "w9 is the weight of vehicle 9 ahead")):
        assert main(argv) == 2
        err = capsys.readouterr().err
        assert words in err and err.count("\n") == 1, err
    assert not (tmp_path / "s.json").exists()


def test_a_cut_in_scenario_runs_mpf_on_its_chains(capsys, tmp_path):
    """A human cuts into the platoon: the chains behind it run the law from its new head."""
    import json

    out_json = tmp_path / "cut.json"
    code = main(["simulate", "--scenario", "cut-in", "--events", "1", "--vehicles", "5",
                 "--controller", f"mpf:{LAYERS}:r=2:w2=0.3", "--workers", "1",
                 "--plant", "real", "--json", str(out_json)])
    out, err = capsys.readouterr()
    assert code == 0, err
    rows = json.loads(out_json.read_text())["controllers"]
    assert rows[0]["metrics"]["collisions"] == 0
