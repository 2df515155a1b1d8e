"""The string-stability test of a policy that holds a learned gap (``gp`` with ``gh``): it sees
the gaps the policy chooses on events, not the start law (docs/string_stability.md, "Policies
that choose their gaps")."""

from __future__ import annotations

import numpy as np
import pytest

from carl_sumo.control.channel import Impairments, plant_impairments
from carl_sumo.data import load_events
from carl_sumo.experiments.held_gaps import (HeldDecision, first_decisions, first_steps,
                                             is_held_gap_policy, start_gaps_m)
from carl_sumo.experiments.simulate import cached_sim, resolve_controller, run_event
from carl_sumo.experiments.string_stability import SineTest, equilibrium_gap, link_gains
from carl_sumo.resources import PRODUCT as PRODUCT_FILE, policies_dir
from carl_sumo.sim.vehicle import Plant

from conftest import NET, REPO_ROOT

LAW = "mpf:h=0.6:kp=0.0445:kd=1:r=3:w1=0.5:w2=0.4:w3=0.1:aw=1:ha=1.4:ttc=2:rb=1"
PRODUCT = policies_dir() / PRODUCT_FILE


def test_followers_start_each_at_its_own_gap():
    event = load_events("default", "test")[0]
    sim = cached_sim(NET, "external")
    gaps = np.array([30.0, 12.0, 12.5, 40.0])
    sim.reset(event, 4, start_gaps_m=gaps)
    assert np.allclose(sim.observation()[:, 2], gaps, atol=1e-6)
    with pytest.raises(Exception, match="3 start gaps for 4 followers"):
        sim.reset(event, 4, start_gaps_m=gaps[:3])


def test_a_held_decision_runs_the_law_at_the_chosen_gaps(tmp_path):
    """An untrained policy on a held-gap base, its decision replaced by chosen offsets, gives the
    link gains of the plain law at those gaps (head 1.4 + 0.3 s, cars 0.6 - 0.1 s), from the same
    start; and it is recognised as a held-gap policy, its base alone or a plain law not."""
    from carl_sumo.learn.agents import Agent, AgentConfig
    from carl_sumo.learn.policy import save_policy

    policy = tmp_path / "held.pt"
    save_policy(Agent(AgentConfig(algo="ca-td3", n_vehicles=4, adj_max=1.0,
                                  base=LAW + ":gp=2:gl=0.5:gb=1:gh=1000")), policy, {})
    assert is_held_gap_policy(str(policy))
    assert not is_held_gap_policy(LAW) and not is_held_gap_policy(str(policies_dir() / "seeds" /
                                                                      "nonexistent.txt"))
    imp = Impairments(delay_s=0.1, plant=Plant((("car", 1.0),), 0.5, 0.2))
    decision = [0.3, -0.1, -0.1, -0.1]
    test, omega = SineTest(), 0.3
    event = test.event(omega, equilibrium_gap(LAW, test.base_speed_mps))
    _, held = resolve_controller(str(policy), imp.plant_key)
    held = HeldDecision(held, decision)
    start = start_gaps_m(held, decision, imp, test.base_speed_mps)
    assert np.allclose(start, 2.0 + np.array([1.7, 0.5, 0.5, 0.5]) * test.base_speed_mps)
    gains = []
    for name, ctrl in ((str(policy), held),
                       (LAW, resolve_controller(LAW.replace("h=0.6", "h=0.5")
                                                .replace("ha=1.4", "ha=1.7"), imp.plant_key)[1])):
        traj = run_event(cached_sim(NET, "external"), event, 4, ctrl, impairments=imp,
                         start_gaps_m=start)
        gains.append(link_gains(traj.leader_speed, traj.speed, omega, test))
        assert np.allclose(traj.gap[-1] - 2.0, np.array([1.7, 0.5, 0.5, 0.5]) * traj.speed[-1],
                           atol=0.3), name  # each at its held gap at the end
    assert np.allclose(gains[0], gains[1], atol=1e-6)


def test_the_command_tests_a_held_gap_policy_at_the_gaps_of_its_validation_events(tmp_path,
                                                                                 capsys):
    """`string-stability` on a held-gap policy: its decision found on the validation events its
    metadata names (here two of the default set), held, at the followers it was trained with;
    printed and in the JSON."""
    import json

    from carl_sumo.cli import main
    from carl_sumo.learn.agents import Agent, AgentConfig
    from carl_sumo.learn.policy import save_policy

    policy = tmp_path / "held.pt"
    ids = [e.event_id for e in load_events("default", "train")[:2]]
    save_policy(Agent(AgentConfig(algo="ca-td3", n_vehicles=4, adj_max=1.0,
                                  base=LAW + ":gp=2:gl=0.5:gb=1:gh=1000")), policy,
                {"validation_events": ids, "data": "default"})
    out = tmp_path / "ss.json"
    main(["string-stability", "--controller", str(policy), "--frequencies", "1",
          "--min-frequency", "1", "--max-frequency", "1", "--json", str(out), "--workers", "1"])
    assert "chosen gap offsets held, 4 followers (the smallest of 2 events" in \
        capsys.readouterr().out
    run = json.loads(out.read_text())["runs"][0]
    assert len(run["per_link"]) == 4 and run["decision"]["events"] == 2
    assert run["decision"]["source"].startswith("its 2 validation events")


def test_the_product_decides_a_role_within_its_budget():
    """The shipped product's first decision on real-plant events: offsets that keep the headway
    budget (sum 0, each at least its floor: cars -0.1 s, trucks and the head 0), the head's gap
    up and the followers' down."""
    imp = plant_impairments("real")
    events = load_events("default", "test")[:3]
    chosen, braking = first_decisions(str(PRODUCT), events, 10, imp, str(NET))
    assert chosen.shape == (3, 10) and braking.shape == (3, 10)
    assert np.allclose(chosen.sum(axis=1), 0.0, atol=1e-9)
    assert (chosen >= -0.1 - 1e-9).all()
    assert (chosen[:, 0] > 0.02).all() and (chosen[:, 1:] <= 0.0).all()


def test_the_budget_corner_rule_holds_every_car_at_its_floor_and_the_head_at_the_rest():
    """benchmarks/budget_corner.py, the product's design without learning: at its one decision
    every car at the 0.5 s floor (offset -0.1 s), trucks at their own gap, the head given all the
    room that frees (the budget kept)."""
    from carl_sumo.control.external import load_external

    corner = load_external(f"{REPO_ROOT / 'benchmarks' / 'budget_corner.py'}:BudgetCorner")
    imp = plant_impairments("real")
    sim = cached_sim(NET, "external")
    for e in load_events("default", "test")[:2]:
        run_event(sim, first_steps(e), 10, corner, impairments=imp)
        law = corner.inner.law
        own, least = law.params.class_gaps(sim.powertrains.b_max)
        assert np.allclose(law.gap_held[1:], (least - own)[1:])
        assert law.gap_held[0] == pytest.approx((own - least)[1:].sum())
