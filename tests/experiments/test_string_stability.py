"""String stability in frequency: the gains measured in SUMO against theory at three plants (the
exact discrete-time Γ of the law within 1 % everywhere; the continuous Γ(jω) within 3 % for
ω ≤ 0.6 rad/s and within 0.03 of |Γ| up to 1 rad/s, where the 0.1 s step starts to show: 2-6 %
there, docs/string_stability.md), the classical numbers of Ploeg et al. (2014), and bad inputs."""

from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np
import pytest

from carl_sumo.cli import main
from carl_sumo.control.channel import Impairments
from carl_sumo.control.transfer import (gamma_continuous, gamma_discrete, gamma_links_continuous,
                                       gamma_links_discrete, h_min)
from carl_sumo.experiments.string_stability import SineTest, analytic, measure
from carl_sumo.sim.vehicle import Plant

from conftest import NET

OMEGAS = np.array([0.1, 0.3, 0.6, 1.0, 2.0, 3.0])


@pytest.mark.parametrize("controller,tau,dead,delay", [
    ("ploeg:h=0.8", 0.1, 0.0, 0.1),
    ("ploeg:h=0.6:kp=0.3:kd=0.9", 0.3, 0.1, 0.2),
    ("acc:h=1.5", 0.5, 0.0, 0.0),
])
def test_measured_gains_match_theory(controller, tau, dead, delay):
    plant = Plant((("car", 1.0),), tau, dead)
    imp = Impairments(delay_s=delay, plant=plant)
    measured = np.array(measure(controller, OMEGAS, 3, SineTest(), imp, str(NET))["per_link"])
    theory = analytic(controller, OMEGAS, plant, delay)
    low, up_to_1 = OMEGAS <= 0.6, OMEGAS <= 1.0
    for link in range(3):
        key = "first_link" if link == 0 else "inner_links"
        disc, cont = np.array(theory[key]["discrete"]), np.array(theory[key]["continuous"])
        assert np.max(np.abs(measured[link] / disc - 1)) < 0.01
        assert np.max(np.abs(measured[link] / cont - 1)[low]) < 0.03
        assert np.max(np.abs(measured[link] - cont)[up_to_1]) < 0.03


@pytest.mark.parametrize("controller,vehicle,tau,dead,delay,n", [
    ("mpf:h=0.8:r=2:w2=0.3", "car", 0.1, 0.0, 0.1, 4),
    ("mpf:h=0.6:kp=0.3:kd=0.9:r=3:w1=0.5:w2=0.3:w3=0.2", "car", 0.3, 0.1, 0.2, 5),
    ("mpf:h=0.8:kp=0.0445:kd=1:aw=1:ttc=2:rb=1:r=3:w1=0.6:w3=0.1", "truck", 0.5, 0.2, 0.1, 5),
])
def test_multi_predecessor_gains_match_the_recurrence_within_1e_5(controller, vehicle, tau, dead,
                                                                  delay, n):
    """The exact discrete Γ_i of the multi-predecessor law, link by link from the recurrence in
    the vehicle index (each relayed command j hops late), is what SUMO measures, within 1e-5 of
    |Γ| on every link and frequency (measured: at most 2e-6); the layers (anti-windup, the
    reaction layer) do not act in the linear regime. The truck's soft kp = 0.0445 1/s² settles
    slowly: its start's transient is left 60 s to decay (at the default 30 s, 7e-6 of it remains;
    with ``ha=1.4`` the head starts 0.6 s off its gap, 2e-3 then, 1.2e-5 after 150 s, as Ploeg's)."""
    plant = Plant(((vehicle, 1.0),), tau, dead)
    imp = Impairments(delay_s=delay, plant=plant)
    test = SineTest(discard_s=60.0 if vehicle == "truck" else 30.0)
    measured = np.array(measure(controller, OMEGAS, n, test, imp, str(NET))["per_link"])
    theory = analytic(controller, OMEGAS, plant, delay, n)
    disc = np.array(theory["per_link"]["discrete"])
    assert disc.shape == measured.shape == (n, len(OMEGAS))
    assert np.max(np.abs(measured - disc)) < 1e-5
    assert np.allclose(theory["inner_links"]["discrete"], disc[1:].max(axis=0))
    assert np.max(np.abs(measured - np.array(theory["per_link"]["continuous"]))[:, :3]) < 0.03
    assert len({tuple(np.round(link, 6)) for link in disc[1:]}) == n - 1  # a gain per link


@pytest.mark.parametrize("controller,n", [
    ("ploeg:h=0.8:ha=1.2:pa=0.1:da=0.4:fa=0.5", 3),
    ("mpf:h=0.6:kp=0.3:kd=0.9:ha=1.2:pa=0.1:da=0.4:fa=0.5:r=3:w1=0.5:w2=0.3:w3=0.2", 4),
])
def test_a_soft_head_matches_the_exact_discrete_gamma_within_1e_5(controller, n):
    """The head's own gains (``pa``, ``da``) and the weight of the leader's acceleration it feeds
    forward (``fa``) in the first link's exact discrete Γ are what SUMO measures, the links behind
    it unchanged (measured: 3e-10 after 90 s of settling; the head starts at h, not ha)."""
    plant = Plant((("car", 1.0),), 0.3, 0.1)
    imp = Impairments(delay_s=0.1, plant=plant)
    measured = np.array(measure(controller, OMEGAS, n, SineTest(discard_s=90.0), imp,
                                str(NET))["per_link"])
    theory = analytic(controller, OMEGAS, plant, 0.1, n)
    if "per_link" in theory:
        disc = np.array(theory["per_link"]["discrete"])
    else:
        disc = np.array([theory["first_link"]["discrete"]] + [theory["inner_links"]["discrete"]]
                        * (n - 1))
    assert np.max(np.abs(measured - disc)) < 1e-5
    plain = analytic(controller.replace(":pa=0.1:da=0.4:fa=0.5", ""), OMEGAS, plant, 0.1, n)
    first = plain.get("per_link", {"discrete": [plain["first_link"]["discrete"]]})["discrete"][0]
    assert np.max(np.abs(np.array(first) - disc[0])) > 0.01  # the head's options change it


def test_the_recurrence_with_one_vehicle_heard_is_ploegs_link_and_with_none_the_accs():
    w = np.geomspace(0.01, 3.0, 40)
    links = gamma_links_discrete(w, 4, 0.8, 0.2, 0.7, 0.3, 1, 2, (1.0,), h_first=1.4)
    assert np.allclose(links[0], gamma_discrete(w, 1.4, 0.2, 0.7, 0.3, 1, 2, first_link=True),
                       rtol=1e-12)
    for link in links[1:]:
        assert np.allclose(link, gamma_discrete(w, 0.8, 0.2, 0.7, 0.3, 1, 2), rtol=1e-12)
    acc = gamma_links_discrete(w, 3, 1.5, 0.2, 0.7, 0.5, 0, 0, ())
    assert np.allclose(acc, gamma_discrete(w, 1.5, 0.2, 0.7, 0.5, cacc=False), rtol=1e-12)
    cont = gamma_links_continuous(w, 3, 0.8, 0.2, 0.7, 0.3, 0.1, 0.2, (1.0,))
    assert np.allclose(cont[1:], gamma_continuous(w, 0.8, 0.2, 0.7, 0.3, 0.1, 0.2), rtol=1e-12)


def test_a_policy_on_a_ploeg_base_starts_where_its_base_does_and_measures_the_same(tmp_path):
    """An untrained policy (a_adj = 0) on a Ploeg base is its base: from the base's own
    equilibrium gap it gives the same link gains, to the last bit."""
    from carl_sumo.learn.agents import Agent, AgentConfig
    from carl_sumo.learn.policy import save_policy

    base = "ploeg:h=0.8:kp=0.0445:kd=1:aw=1:ha=1.4:ttc=2"
    policy = tmp_path / "zero.pt"
    save_policy(Agent(AgentConfig(algo="ca-td3", n_vehicles=3, adj_max=1.0, base=base)),
                policy, {})
    imp = Impairments(delay_s=0.1, plant=Plant((("truck", 1.0),), 0.5, 0.2))
    omegas = np.array([0.3])
    gains = [measure(c, omegas, 3, SineTest(), imp, str(NET))["per_link"]
             for c in (base, str(policy))]
    assert gains[0] == gains[1]


def test_theory_gives_the_classical_minimum_time_gaps():
    """Ploeg et al. (2014): τ = 0.1 s, kp = 0.2, kd = 0.7: ACC string stable only from
    h ≈ 3.2 s, CACC from 0.55 / 0.68 / 0.78 s at V2V delays of 0.1 / 0.15 / 0.2 s."""
    assert h_min(0.2, 0.7, 0.1, cacc=False) == pytest.approx(3.16, abs=0.02)
    for delay, expected in ((0.1, 0.55), (0.15, 0.68), (0.2, 0.78)):
        assert h_min(0.2, 0.7, 0.1, theta=delay) == pytest.approx(expected, abs=0.01)


def test_discrete_theory_tends_to_continuous_at_low_frequency():
    w = np.array([0.01, 0.03])
    for cacc in (True, False):
        c = gamma_continuous(w, 0.8, 0.2, 0.7, 0.3, theta=0.2, cacc=cacc)
        d = gamma_discrete(w, 0.8, 0.2, 0.7, 0.3, delay_steps=2, cacc=cacc)
        assert np.allclose(np.abs(c), np.abs(d), rtol=2e-3)


def test_the_command_writes_json_and_a_plot(tmp_path, capsys):
    out, png = tmp_path / "ss.json", tmp_path / "ss.png"
    assert main(["string-stability", "--controller", "acc:h=1", "--vehicles", "2",
                 "--frequencies", "3", "--min-frequency", "0.5", "--vehicle-lag", "0.2",
                 "--net", str(NET), "--json", str(out), "--plot", str(png),
                 "--workers", "1"]) == 0
    result = json.loads(out.read_text())
    assert len(result["frequencies_rad_s"]) == 3 and len(result["per_link"]) == 2
    assert result["hinf"] == max(result["gain"]) and result["hinf"] > 1.0  # ACC at h = 1
    assert png.stat().st_size > 1000
    assert "unstable" in capsys.readouterr().out


@pytest.mark.parametrize("options,message", [
    (["--amplitude", "25"], "would stop the leader"),
    (["--max-frequency", "10"], "cannot be resolved"),
    (["--min-frequency", "0.001"], "too long for the network"),
    (["--controller", "idm"], "vehicle dynamics"),
])
def test_bad_string_stability_input_is_one_line_and_exit_2(capsys, options, message):
    args = ["string-stability", "--net", str(NET), "--vehicle-lag", "0.1"]
    if "--controller" not in options:
        args += ["--controller", "ploeg"]
    assert main(args + options) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("carl-sumo: error:") and message in err and "\n" not in err


def test_the_gate_keeps_the_best_scoring_string_stable_checkpoint(tmp_path, capsys):
    """``train --gate-string-stable``: a real run keeps its base and every validated actor as
    candidates. A candidate that validated best but always accelerates (a_adj = +5 m/s², 25 m
    of spacing error at kp = 0.2) runs into its predecessor in the frequency test, so the gate passes it over and writes the next
    one in score order, string stable, to the run's file."""
    import torch

    from carl_sumo.errors import InputError
    from carl_sumo.experiments.bench import cruise_event
    from carl_sumo.experiments.string_stability import keep_string_stable
    from carl_sumo.learn.policy import read_policy_payload, save_torch_atomic
    from carl_sumo.learn.selection import rank_runs
    from carl_sumo.learn.train import TrainConfig, candidate_dir, train

    out = tmp_path / "p.pt"
    cfg = TrainConfig(algo="td3", n_vehicles=2, steps=80, seed=0, num_envs=2,
                      learning_starts=20, eval_every=40, eval_events=1, checkpoint_every=80,
                      base="ploeg:h=0.8:kp=0.2:kd=0.7", adj_max=5.0, select="reward",
                      gate_string_stable="ideal", net=str(NET), out=str(out))
    train(cfg, [cruise_event(120, 15.0, 30.0)], progress=False)
    names = sorted(p.name for p in candidate_dir(out).iterdir())
    assert names == ["step000000.pt", "step000040.pt", "step000080.pt"]
    greedy = read_policy_payload(candidate_dir(out) / "step000080.pt")
    last = [k for k in greedy["actor"] if k.endswith("bias")][-1]
    greedy["actor"][last] = torch.full_like(greedy["actor"][last], 50.0)
    greedy["actor"][last.replace("bias", "weight")].zero_()
    greedy["metadata"]["validation"]["val_reward"] = 1e3  # validated best
    save_torch_atomic(greedy, candidate_dir(out) / "step000120.pt")
    kept = keep_string_stable(out, "reward", "ideal")
    err = capsys.readouterr().err
    assert "step000120.pt: worst ‖Γ‖∞ inf" in err
    ranked = [r["path"] for r in rank_runs(sorted(candidate_dir(out).glob("*.pt")), "reward")]
    assert ranked[0].endswith("step000120.pt") and kept["path"] == ranked[1]
    payload = read_policy_payload(out)
    gate = payload["metadata"]["string_stability_gate"]
    assert gate["candidate"] == os.path.basename(ranked[1]) and 0 < gate["worst_hinf"] <= 1
    assert gate["candidates"] == 4
    chosen = read_policy_payload(Path(ranked[1]))["actor"]
    assert all(torch.equal(payload["actor"][k], chosen[k]) for k in chosen)
    with pytest.raises(InputError, match="no candidates"):
        keep_string_stable(tmp_path / "other.pt", "reward", "ideal")


def test_shipping_checks_between_the_gates_frequencies():
    """``REAL_TWO`` seed 2 passed the per-checkpoint gate's 8 frequencies, but trucks at 0.5 m/s
    amplify at 0.863 rad/s, a shipping frequency between the gate's 0.517 and 0.928 rad/s: the
    finer grid of ``rank --string-stable`` sees it, the gate's neighbours do not."""
    from dataclasses import replace

    from carl_sumo.control.channel import plant_impairments
    from carl_sumo.experiments.string_stability import SELECTION_OMEGAS, SHIP_OMEGAS

    policy = str(Path(__file__).resolve().parents[2] / "policies/seeds/ca_td3_real_two_10_seed2.pt")
    between = [w for w in SHIP_OMEGAS if 0.86 < w < 0.87]
    neighbours = [w for w in SELECTION_OMEGAS if 0.5 < w < 1.0]
    assert len(between) == 1 and len(neighbours) == 2
    real = plant_impairments("real")
    trucks = replace(real, plant=real.plant.worst_case("truck"))
    gains = measure(policy, [*neighbours, between[0]], 5, SineTest(amplitude_mps=0.5), trucks,
                    str(NET))["gain"]
    assert max(gains[:2]) <= 1.0 < gains[2]


def test_the_theory_of_a_heavy_class_uses_its_ht_gap_as_the_law_does():
    """With ``ht`` and ``aw=1`` a truck (braking below 7 m/s²) that hears a message keeps
    max(h, ht): the analytic links of a truck-only platoon are those of the law at ht, a car's
    those at h; without aw the kernel cannot tell the class and keeps h."""
    from carl_sumo.sim.vehicle import Plant

    truck = Plant(fleet=(("truck", 1.0),), lag_s=0.6, dead_time_s=0.2)
    car = Plant(fleet=(("car", 1.0),), lag_s=0.5, dead_time_s=0.2)
    w = np.array([0.05, 0.2, 1.0])
    law = "mpf:h=0.5:kp=0.0445:kd=1:r=3:w1=0.5:w2=0.4:w3=0.1:aw=1:ha=2.3:ht=0.8"
    at_ht = law.replace("h=0.5", "h=0.8").replace(":ht=0.8", "")
    assert analytic(law, w, truck, 0.1) == analytic(at_ht, w, truck, 0.1)
    assert analytic(law, w, car, 0.1) == analytic(law.replace(":ht=0.8", ""), w, car, 0.1)
    no_aw = law.replace(":aw=1", "")
    assert analytic(no_aw, w, truck, 0.1) == analytic(no_aw.replace(":ht=0.8", ""), w, truck, 0.1)
