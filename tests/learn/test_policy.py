"""Agents and policy files: round trip, bad files, MADDPG's fixed length."""

import numpy as np
import pytest
import torch

from carl_sumo.learn.agents import Agent, AgentConfig
from carl_sumo.errors import InputError
from carl_sumo.learn.policy import load_controller, load_policy, save_policy
from carl_sumo.learn.train import ReplayBuffer


@pytest.mark.parametrize("algo", ["ca-td3", "ca-ddpg", "td3", "ddpg", "maddpg"])
def test_policy_file_round_trip(tmp_path, algo):
    torch.manual_seed(0)
    agent = Agent(AgentConfig(algo=algo, n_vehicles=3))
    path = tmp_path / "p.pt"
    save_policy(agent, path, {"algo": algo, "trained_vehicles": 3})
    payload = torch.load(path, weights_only=True)
    assert payload["metadata"]["algo"] == algo
    loaded, meta = load_policy(path)
    obs = np.random.default_rng(0).uniform(0, 20, (3, 4))
    assert np.allclose(loaded.act(obs), agent.act(obs))
    assert np.all(np.abs(loaded.act(obs)) <= 3.0)


def test_ca_policy_runs_any_length(tmp_path):
    agent = Agent(AgentConfig(algo="ca-td3", n_vehicles=10))
    save_policy(agent, tmp_path / "ca.pt", {})
    controller = load_controller(tmp_path / "ca.pt")
    for n in (1, 20, 50):
        controller.reset(n)
        assert controller.adjustment(np.ones((n, 4))).shape == (n,)


def test_maddpg_refuses_other_lengths(tmp_path):
    save_policy(Agent(AgentConfig(algo="maddpg", n_vehicles=4)), tmp_path / "m.pt", {})
    controller = load_controller(tmp_path / "m.pt")
    controller.reset(4)
    with pytest.raises(InputError, match="trained for 4 vehicles"):
        controller.reset(5)


def test_corrupt_foreign_and_mismatched_files(tmp_path):
    corrupt = tmp_path / "corrupt.pt"
    corrupt.write_bytes(b"not a torch file")
    with pytest.raises(InputError, match="corrupt"):
        load_policy(corrupt)
    foreign = tmp_path / "foreign.pt"
    torch.save({"weights": torch.zeros(3)}, foreign)
    with pytest.raises(InputError, match="not a carl-sumo policy"):
        load_policy(foreign)
    mismatched = tmp_path / "mismatched.pt"
    agent = Agent(AgentConfig(algo="td3", n_vehicles=1))
    save_policy(agent, mismatched, {})
    payload = torch.load(mismatched, weights_only=True)
    payload["agent_config"]["hidden"] = 32
    torch.save(payload, mismatched)
    with pytest.raises(InputError, match="does not match"):
        load_policy(mismatched)
    with pytest.raises(InputError, match="does not exist"):
        load_policy(tmp_path / "none.pt")


def test_update_reduces_critic_loss_on_fixed_data():
    torch.manual_seed(0)
    agent = Agent(AgentConfig(algo="ca-td3", n_vehicles=3, hidden=32, message_dim=8))
    rng = np.random.default_rng(0)
    buf = ReplayBuffer(1000, 3)
    obs = rng.uniform(0, 20, (500, 3, 4))
    buf.add(obs, rng.uniform(-3, 3, (500, 3)), -np.abs(obs[..., 3]) / 5, obs, np.zeros(500))
    first = np.mean([agent.update(buf.sample(64, rng))["critic_loss"] for _ in range(5)])
    for _ in range(200):
        agent.update(buf.sample(64, rng))
    last = np.mean([agent.update(buf.sample(64, rng))["critic_loss"] for _ in range(5)])
    assert last < first


def test_card_says_when_a_shipped_file_was_renamed(tmp_path):
    from carl_sumo.learn.policy import policy_card

    meta = {"algo": "td3", "seed": 7, "command": "carl-sumo train --algo td3 --out p/td3_1_seed7.pt"}
    save_policy(Agent(AgentConfig(algo="td3", n_vehicles=1)), tmp_path / "td3_1.pt", meta)
    save_policy(Agent(AgentConfig(algo="td3", n_vehicles=1)), tmp_path / "td3_1_seed7.pt", meta)
    assert "written as `td3_1_seed7.pt`, since renamed `td3_1.pt`" in policy_card(tmp_path / "td3_1.pt")
    assert "renamed" not in policy_card(tmp_path / "td3_1_seed7.pt")


def test_residual_policy_starts_on_its_classical_base(tmp_path):
    """A fresh agent on base ploeg outputs a_adj = 0, so its controller is the Ploeg CACC."""
    from carl_sumo.control.cacc import ploeg_controller
    from carl_sumo.control.controllers import applied_acceleration

    for algo in ("ca-td3", "td3", "maddpg"):
        agent = Agent(AgentConfig(algo=algo, n_vehicles=3, base="ploeg:h=0.8"))
        save_policy(agent, tmp_path / f"{algo}.pt", {})
        controller = load_controller(tmp_path / f"{algo}.pt")
        reference = ploeg_controller("ploeg:h=0.8")
        controller.reset(3), reference.reset(3)
        rng = np.random.default_rng(0)
        for _ in range(5):
            obs = rng.uniform([5, -1, 10, -2], [20, 1, 40, 2], (3, 4))
            assert np.all(controller.adjustment(obs) == 0.0)
            assert np.allclose(applied_acceleration(controller, obs), reference.acceleration(obs))


def test_policy_table_lists_the_seed_files_and_the_base(tmp_path):
    from carl_sumo.learn.policy import policy_table

    (tmp_path / "seeds").mkdir()
    agent = Agent(AgentConfig(algo="ca-td3", base="ploeg:h=0.8"))
    meta = {"algo": "ca-td3", "seed": 2, "steps": 100, "trained_vehicles": 10,
            "validation": {"headway_s": 1.1, "jerk_mps3": 0.2, "dampening_ratio": 0.5},
            "validation_base": {"headway_s": 1.0, "jerk_mps3": 0.3, "dampening_ratio": 0.6}}
    save_policy(agent, tmp_path / "r.pt", meta)
    for k in (10, 2):
        save_policy(agent, tmp_path / "seeds" / f"r_seed{k}.pt", {**meta, "seed": k})
        (tmp_path / "seeds" / f"r_seed{k}.csv").write_text(f"step,transitions,wall_s\n100,200,{k}\n")
    row = policy_table([tmp_path / "r.pt"]).splitlines()[-1]
    assert row.startswith("| `r.pt` | ca-td3 | ploeg:h=0.8 | 10 | 2, 10 (2) | 100 | 6 (max 10) |")
    assert "| 1.100 | 0.200 | 0.500 | 1.000 / 0.300 / 0.600 |" in row


def test_the_fingerprint_is_what_a_policy_computes_not_its_metadata(tmp_path):
    import torch

    from carl_sumo.learn.agents import Agent, AgentConfig
    from carl_sumo.learn.policy import policy_fingerprint, save_policy

    torch.manual_seed(0)
    agent = Agent(AgentConfig(algo="ca-td3", n_vehicles=3))
    save_policy(agent, tmp_path / "a.pt", {"seed": 0})
    save_policy(agent, tmp_path / "b.pt", {"seed": 1, "command": "another run"})
    shielded = Agent(AgentConfig(algo="ca-td3", n_vehicles=3, shield_ttc_s=4.0))
    shielded.actor.load_state_dict(agent.actor.state_dict())
    save_policy(shielded, tmp_path / "c.pt", {"seed": 0})
    other = Agent(AgentConfig(algo="ca-td3", n_vehicles=3))
    save_policy(other, tmp_path / "d.pt", {"seed": 0})
    older = torch.load(tmp_path / "a.pt", weights_only=False)
    del older["agent_config"]["shield_ttc_s"]  # a file written before the option existed
    torch.save(older, tmp_path / "e.pt")
    a, b, c, d, e = (policy_fingerprint(tmp_path / f"{x}.pt") for x in "abcde")
    assert a == b == e and a != c and a != d
    falls_back = Agent(AgentConfig(algo="ca-td3", n_vehicles=3, comm_fallback="base"))
    falls_back.actor.load_state_dict(agent.actor.state_dict())
    save_policy(falls_back, tmp_path / "f.pt", {"seed": 0})
    f = tmp_path / "f.pt"
    assert policy_fingerprint(f) != a  # over impaired links it drives otherwise
    assert policy_fingerprint(f, over_links=False) == policy_fingerprint(tmp_path / "a.pt", False)


def test_a_policy_file_with_nan_weights_is_refused(tmp_path):
    """Found by fault injection: a NaN weight used to load and drive (nonsense metrics)."""
    import torch

    from carl_sumo.errors import InputError
    from carl_sumo.learn.policy import load_policy

    from pathlib import Path

    shipped = Path(__file__).resolve().parents[2] / "policies" / "td3_1.pt"
    payload = torch.load(shipped, weights_only=True)
    key = next(iter(payload["actor"]))
    payload["actor"][key] = payload["actor"][key].clone().fill_(float("nan"))
    torch.save(payload, tmp_path / "nan.pt")
    with pytest.raises(InputError, match="non-finite weights"):
        load_policy(tmp_path / "nan.pt")
