"""The V2V channel and the sensors (carl_sumo.control.channel), and controllers driven over them."""

import numpy as np
import pytest

from carl_sumo.control.channel import FALLBACK, HELD, LIVE, Channel, Impairments, LossProcess
from carl_sumo.errors import InputError

from conftest import NET, braking_event


def _stream(imp: Impairments, steps: int, n: int = 3):
    """(mode, held) at every step of a channel whose sender sends its step number + link/10."""
    ch = Channel(n, 1, imp, imp.rng("e", 1))
    out = []
    for k in range(steps):
        mode, held = ch.receive(k)
        out.append((mode.copy(), held[:, 0].copy()))
        ch.send(k, (k + np.arange(n) / 10)[:, None])
    return out


def test_the_delay_line_returns_exactly_the_message_of_s_seconds_ago():
    out = _stream(Impairments(delay_s=0.3), 12)
    for k, (mode, held) in enumerate(out):
        if k < 3:
            assert np.all(mode == FALLBACK)  # nothing has arrived yet
        else:
            assert np.all(mode == HELD)
            np.testing.assert_allclose(held, k - 3 + np.arange(3) / 10)
    assert all(np.all(m == LIVE) for m, _ in _stream(Impairments(loss=0.0), 5))


def test_losses_are_reproducible_and_have_the_requested_rate_and_burst_length():
    imp = Impairments(loss=0.3, seed=4)
    a = LossProcess(10, 0.3, 1.0, imp.rng("ev", 1))
    b = LossProcess(10, 0.3, 1.0, Impairments(loss=0.3, seed=4).rng("ev", 1))
    draws = np.array([a.draw() for _ in range(10_000)])
    assert np.array_equal(draws, np.array([b.draw() for _ in range(10_000)]))
    assert abs(draws.mean() - 0.3) < 0.02 * 0.3 + 0.005  # 10^5 draws
    other = LossProcess(10, 0.3, 1.0, Impairments(loss=0.3, seed=5).rng("ev", 1))
    assert not np.array_equal(draws[:100], np.array([other.draw() for _ in range(100)]))
    burst = LossProcess(10, 0.3, 5.0, np.random.default_rng(0))
    lost = np.array([burst.draw() for _ in range(20_000)])
    assert abs(lost.mean() - 0.3) < 0.02
    lengths = []
    for link in lost.T:
        edges = np.diff(np.concatenate([[0], link.astype(int), [0]]))
        lengths += list(np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1))
    assert np.mean(lengths) == pytest.approx(5.0, rel=0.05)
    assert LossProcess(3, 1.0, 2.0, np.random.default_rng(0)).draw().all()


def test_a_receiver_past_its_timeout_falls_back_and_a_lost_message_is_held():
    imp = Impairments(loss=1.0, timeout_s=0.3, fade_s=0.0)  # a hard switch
    ch = Channel(2, 1, imp, imp.rng("e", 1))
    ch.held[:] = 7.0
    ch.sent_at[:] = 0
    for k, expected in [(1, HELD), (2, HELD), (3, HELD), (4, FALLBACK)]:
        mode, held = ch.receive(k)
        assert np.all(mode == expected)
        assert np.all(held == (7.0 if expected == HELD else 0.0))
        ch.send(k, np.full((2, 1), float(k)))


def test_past_the_timeout_a_held_message_fades_linearly_into_the_fallback():
    imp = Impairments(loss=1.0, timeout_s=0.3, fade_s=0.3)
    ch = Channel(2, 1, imp, imp.rng("e", 1))
    ch.held[:] = 7.0
    ch.sent_at[:] = 0
    fallback = np.array([-1.0])
    got = []
    for k in range(1, 9):
        mode, held = ch.receive(k, fallback)
        got.append((int(mode[0]), float(held[0, 0])))
        ch.send(k, np.full((2, 1), float(k)))  # all lost
    w = [1, 1, 1, 0.75, 0.5, 0.25, 0, 0]  # ages 1..8, T = F = 3 steps
    assert [m for m, _ in got] == [HELD] * 6 + [FALLBACK] * 2
    assert [v for _, v in got] == pytest.approx([7.0 * x - (1 - x) for x in w])
    assert imp.held_weight(np.arange(8)).tolist() == [1, 1, 1, 1, 0.75, 0.5, 0.25, 0]


@pytest.mark.parametrize("kwargs, message", [
    ({"delay_s": -0.1}, "--comm-delay must be"), ({"delay_s": 0.25}, "not a multiple"),
    ({"loss": 1.5}, "--comm-loss is a probability"), ({"loss": -0.1}, "--comm-loss"),
    ({"burst": 0.5}, "--comm-burst"), ({"timeout_s": 0.05}, "at least one step"),
    ({"fade_s": -0.1}, "--comm-fade must be")])
def test_bad_values_are_refused(kwargs, message):
    with pytest.raises(InputError, match=message):
        Impairments(**kwargs)


def test_bad_values_give_one_line_and_exit_2(capsys):
    from carl_sumo.cli import main

    assert main(["simulate", "--controller", "ploeg", "--comm-loss", "2"]) == 2
    assert main(["simulate", "--controller", "idm", "--comm-loss", "0.2"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 2 and "--comm-loss is a probability" in err and "native" in err


def _trajectory(controller, impairments=None, connect_perfect=False):
    from carl_sumo.experiments.simulate import cached_sim, run_event

    sim = cached_sim(NET, "external")
    event = braking_event(v0=14.0)
    if connect_perfect:  # the channel code path with a perfect channel
        imp = Impairments()
        orig = controller.reset

        def reset(n):
            orig(n)
            controller.connect(imp, event.event_id)
        controller.reset = reset
    return run_event(sim, event, 4, controller, impairments=impairments)


def _policy(tmp_path):
    import torch

    from carl_sumo.learn.agents import Agent, AgentConfig
    from carl_sumo.learn.policy import load_controller, save_policy

    torch.manual_seed(0)
    save_policy(Agent(AgentConfig(algo="ca-td3", n_vehicles=4, adj_max=1.0)), tmp_path / "p.pt", {})
    return lambda: load_controller(tmp_path / "p.pt")


def test_a_perfect_channel_gives_todays_results_for_ploeg_and_ca(tmp_path):
    from carl_sumo.control.cacc import ploeg_controller

    for make in (lambda: ploeg_controller("ploeg:h=0.8"), _policy(tmp_path)):
        today = _trajectory(make())
        over = _trajectory(make(), connect_perfect=True)
        np.testing.assert_array_equal(today.speed, over.speed)


def test_impairments_change_the_run_and_the_same_seed_repeats_it(tmp_path):
    from carl_sumo.control.cacc import ploeg_controller

    imp = Impairments(delay_s=0.2, loss=0.3, burst=3.0, sensor_noise=True, seed=1)
    for make in (lambda: ploeg_controller("ploeg:h=0.8"), _policy(tmp_path)):
        clean = _trajectory(make())
        a, b = _trajectory(make(), imp), _trajectory(make(), imp)
        np.testing.assert_array_equal(a.speed, b.speed)
        assert not np.array_equal(a.speed, clean.speed)
        c = _trajectory(make(), Impairments(delay_s=0.2, loss=0.3, burst=3.0, seed=1))
        assert not np.array_equal(c.speed, clean.speed)  # the channel alone changes it


def test_every_message_lost_makes_ploeg_an_acc():
    """With every message lost the predecessor feed-forward is gone: the followers behind the
    head act as with u_{i-1} = 0."""
    from carl_sumo.control.cacc import ploeg_controller

    obs = np.array([[10.0, 0.5, 12.0, 0.0], [10.0, 0.5, 12.0, 0.0]])
    lost = ploeg_controller("ploeg:h=1")
    lost.reset(2)
    lost.u[:] = 0.5
    lost.connect(Impairments(loss=1.0), "e")
    plain = ploeg_controller("ploeg:h=1")
    plain.reset(2)
    plain.u[:] = 0.5
    a_lost, a_plain = lost.acceleration(obs), plain.acceleration(obs)
    assert a_lost[0] == a_plain[0]  # the head hears its leader through its own sensors
    assert a_plain[1] - a_lost[1] == pytest.approx(0.1 / 1.0 * 0.5)  # dt/h · u_pred


def test_the_robustness_suite_writes_its_table_and_figures(tmp_path, capsys):
    import csv

    from carl_sumo.cli import main
    from conftest import REPO_ROOT

    out = tmp_path / "rob"
    assert main(["evaluate", "--suite", "robustness", "--quick", "--out", str(out), "--net",
                 str(NET), "--policies", str(REPO_ROOT / "policies")]) == 0
    rows = list(csv.DictReader(open(out / "robustness.csv")))
    settings = {r["setting"] for r in rows}
    assert settings == {"perfect", "loss 0.3", "delay 0.2 s", "sensor noise"}
    assert len(rows) == 4 * 6 - 2  # IDM sends no messages: not rerun on the channel settings
    by_seeds = {r["controller"]: int(r["seeds"]) for r in rows}
    assert by_seeds[str(REPO_ROOT / "policies" / "ca_td3_10_robust.pt")] == 2  # seed means
    assert by_seeds["ploeg"] == 1
    seed_runs = list(csv.DictReader(open(out / "robustness_seeds.csv")))
    assert len(seed_runs) == 4 * 2 * 2 and all("_seed" in r["policy"] for r in seed_runs)
    assert (out / "robustness_vs_loss.png").stat().st_size > 0
    assert "| loss 0.3 | `" in (out / "robustness.md").read_text()
    ploeg = {r["setting"]: r for r in rows if r["controller"] == "ploeg"}
    assert ploeg["delay 0.2 s"]["jerk_mps3"] != ploeg["perfect"]["jerk_mps3"]


def test_keyed_links_follow_the_neighbour_and_hear_a_new_one_only_after_its_message():
    from carl_sumo.control.channel import KeyedChannel

    imp = Impairments(delay_s=0.2)
    ch = KeyedChannel(1, imp, imp.rng("run", 1))
    got = []
    for k in range(8):
        sender = "a" if k < 4 else "b"  # the vehicle ahead of "r" changes at step 4
        mode, held = ch.receive(k, [("r", sender)])
        got.append((int(mode[0]), float(held[0, 0])))
        ch.send(k, [("r", sender)], np.array([[k + (0.5 if sender == "b" else 0.0)]]))
    # 0.2 s late: step k hears the message of step k - 2 from the same sender, else nothing
    assert got[:2] == [(FALLBACK, 0.0), (FALLBACK, 0.0)]
    assert got[2:4] == [(HELD, 0.0), (HELD, 1.0)]
    assert [m for m, _ in got[4:6]] == [FALLBACK, FALLBACK]  # "a"'s messages are not "b"'s
    assert got[6:] == [(HELD, 4.5), (HELD, 5.5)]


def test_keyed_links_lose_at_the_requested_rate_and_repeat_with_the_seed():
    from carl_sumo.control.channel import KeyedChannel

    imp = Impairments(loss=0.3, burst=3.0, seed=4)
    modes = []
    for _ in range(2):
        ch = KeyedChannel(1, imp, imp.rng("run", 2))
        out = []
        for k in range(20000):
            mode, _ = ch.receive(k, [("r1", "s1"), ("r2", "s2")])
            ch.send(k, [("r1", "s1"), ("r2", "s2")], np.zeros((2, 1)))
            out.append(mode.copy())
        modes.append(np.array(out))
    assert np.array_equal(*modes)
    lost = modes[0] != LIVE
    assert abs(lost.mean() - 0.3) < 0.02
    runs = np.diff(np.flatnonzero(np.diff(np.concatenate([[0], lost[:, 0], [0]]))))[::2]
    assert abs(runs.mean() - 3.0) < 0.3  # bursts of the requested mean length


def test_a_follower_hears_its_freshest_link_and_a_chain_end_its_only_one():
    from carl_sumo.control.channel import PlatoonLinks, heard_weights

    f, b = np.array([1.0, 0.5, 0.2]), np.array([0.0, 0.6, 0.3])  # receivers 0-2 and 1-3
    assert heard_weights(f, b).tolist() == [1.0, 0.5, 0.6, 0.3]  # 0: f only, 3: b only
    assert heard_weights(np.zeros(0), np.zeros(0)).tolist() == [1.0]  # no link to lose
    imp = Impairments(loss=1.0, timeout_s=0.3, fade_s=0.3)
    links = PlatoonLinks(3, 2, imp, "e")
    for ch in (links.forward, links.backward):
        ch.sent_at[:] = 0  # every link last heard at step 0, then nothing arrives
    got = []
    for _ in range(8):
        links.receive()
        got.append(links.heard().tolist())
        links.send(np.zeros((3, 2)), np.zeros((3, 2)))
    w = [1, 1, 1, 1, 0.75, 0.5, 0.25, 0]  # the held messages' weights at ages 0..7 (T = F = 3)
    assert got == [[x] * 3 for x in w]
    live = PlatoonLinks(3, 2, Impairments(loss=0.0, delay_s=0.0, seed=3), "e")
    live.receive()
    assert live.heard().tolist() == [1.0, 1.0, 1.0]  # heard live from the first step on


def test_with_every_message_lost_a_base_fallback_policy_drives_as_its_base(tmp_path):
    """--comm-fallback base: hearing nobody, the learned adjustment is gone (IDM alone, as
    idm-external); with the boundary fallback the same actor still adjusts."""
    import torch

    from carl_sumo.learn.agents import Agent, AgentConfig
    from carl_sumo.control.controllers import ZeroAdjustment
    from carl_sumo.learn.policy import load_controller, save_policy

    lost = Impairments(loss=1.0)
    base = _trajectory(ZeroAdjustment(), lost)
    runs = {}
    for fallback in ("base", "boundary"):
        torch.manual_seed(0)
        path = tmp_path / f"{fallback}.pt"
        save_policy(Agent(AgentConfig(algo="ca-td3", n_vehicles=4, adj_max=1.0,
                                      comm_fallback=fallback)), path, {})
        runs[fallback] = _trajectory(load_controller(path), lost)
    np.testing.assert_array_equal(runs["base"].speed, base.speed)
    assert not np.array_equal(runs["boundary"].speed, base.speed)
    perfect = [_trajectory(load_controller(tmp_path / f"{f}.pt")) for f in ("base", "boundary")]
    np.testing.assert_array_equal(perfect[0].speed, perfect[1].speed)  # only when unheard


def test_comm_fallback_is_for_ca_models():
    from carl_sumo.learn.agents import AgentConfig
    from carl_sumo.cli import main

    with pytest.raises(InputError, match="unknown --comm-fallback"):
        AgentConfig(algo="ca-td3", comm_fallback="acc")
    with pytest.raises(InputError, match="for CA models"):
        AgentConfig(algo="td3", comm_fallback="base")
    assert main(["train", "--algo", "td3", "--comm-fallback", "base", "--steps", "10"]) == 2


def test_in_the_study_a_base_fallback_vehicle_that_hears_nobody_has_no_adjustment():
    import torch

    from carl_sumo.learn.agents import Agent, AgentConfig
    from carl_sumo.control.channel import KeyedChannel
    from carl_sumo.learn.inference import CompiledActor

    obs = np.array([[10.0, 0.2, 15.0, 0.5], [9.0, -0.1, 12.0, -0.3], [11.0, 0.0, 20.0, 0.1]])
    ids = ["a", "b", "c"]
    for fallback, loss in (("base", 1.0), ("boundary", 1.0), ("base", 0.0)):
        torch.manual_seed(0)
        actor = CompiledActor(Agent(AgentConfig(algo="ca-td3", n_vehicles=3, adj_max=1.0,
                                                comm_fallback=fallback)))
        imp = Impairments(loss=loss, seed=2)
        channels = [KeyedChannel(actor.message_dim, imp, imp.rng("s", j)) for j in (2, 3)]
        action = actor.act_keyed(obs, ids, *channels, 0)
        if fallback == "base" and loss == 1.0:
            assert action.tolist() == [0.0, 0.0, 0.0]
        else:
            assert np.all(np.abs(action) > 0)
