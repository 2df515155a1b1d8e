"""--trust-string-stable (issue 55): each validated checkpoint's ‖Γ‖∞ acts on the actor. An
amplifying actor goes back to its anchor (weights, target, optimiser moments) and α halves; a
string-stable best becomes the anchor; an amplifying checkpoint is never kept. The real check
(SUMO sine runs) is exercised by the command-line test; here a given check function stands for
its outcome so that each branch is reached on purpose."""

import math

import pandas as pd
import pytest
import torch

from carl_sumo.cli import main
from carl_sumo.experiments.bench import cruise_event
from carl_sumo.learn.agents import Agent, AgentConfig
from carl_sumo.learn.policy import load_policy, policy_card
from carl_sumo.learn.train import TrainConfig, train
from carl_sumo.learn.trust import StableTrust

from conftest import NET


def _agent():
    torch.manual_seed(0)
    return Agent(AgentConfig(algo="ca-td3", n_vehicles=3, base="ploeg:h=0.8", hidden=16,
                             message_dim=4, actor_lr=1e-2))


def _moved(agent):
    with torch.no_grad():
        for p in agent.actor.parameters():
            p.add_(0.1)
        for p in agent.actor_target.parameters():
            p.add_(0.1)


def _same(a, b):
    return all(torch.equal(x, y) for x, y in zip(a.state_dict().values(),
                                                  b.state_dict().values()))


def test_an_amplifying_actor_goes_back_to_its_anchor_and_alpha_halves(tmp_path):
    agent = _agent()
    agent.anchor(2.5)
    start = {k: v.clone() for k, v in agent.actor.state_dict().items()}
    _moved(agent)
    agent.actor_opt.state[next(agent.actor.parameters())]["exp_avg"] = torch.ones(1)
    trust = StableTrust(lambda path: 1.02)
    hinf, kappa, there = trust.judge(agent, tmp_path / "x.pt", 500, best_score=True)
    assert (hinf, kappa) == (1.02, 0.0) and math.isnan(there)
    assert all(torch.equal(v, start[k]) for k, v in agent.actor.state_dict().items())
    assert _same(agent.actor, agent.actor_target) and not agent.actor_opt.state
    assert agent.bc_alpha == 1.25 and trust.state() == [1]


def test_a_string_stable_best_becomes_the_anchor_and_a_stable_other_one_does_not(tmp_path):
    agent = _agent()
    agent.anchor(2.5)
    _moved(agent)
    trust = StableTrust(lambda path: 0.999)
    trust.judge(agent, tmp_path / "x.pt", 500, best_score=False)
    assert not _same(agent.actor, agent.start_actor) and trust.accepted == []
    trust.judge(agent, tmp_path / "x.pt", 1000, best_score=True)
    assert _same(agent.actor, agent.start_actor) and trust.accepted == [1000]
    assert agent.bc_alpha == 2.5
    assert trust.judge(agent, tmp_path / "x.pt", 1500, best_score=True) == (0.999, 1.0, 0.999)
    restored = StableTrust(lambda path: 0.0)
    restored.restore(trust.state())
    assert restored.state() == [0, 1000, 1500]


def test_backtracking_keeps_the_first_string_stable_point_on_the_way_to_the_anchor(tmp_path):
    agent = _agent()
    agent.anchor(2.5)
    start = {k: v.clone() for k, v in agent.actor.state_dict().items()}
    _moved(agent)  # every weight 0.1 from its anchor
    agent.actor_opt.state[next(agent.actor.parameters())]["exp_avg"] = torch.ones(1)
    outcomes, written = iter([1.02, 1.01, 0.998]), []

    def rewrite():
        written.append({k: v.clone() for k, v in agent.actor.state_dict().items()})
        return tmp_path / "x.pt"

    trust = StableTrust(lambda path: next(outcomes), backtrack=3)
    assert trust.judge(agent, tmp_path / "x.pt", 500, True, rewrite) == (1.02, 0.25, 0.998)
    assert len(written) == 2  # κ = 1/2 amplified, κ = 1/4 did not
    for k, v in agent.actor.state_dict().items():
        assert torch.allclose(v, start[k] + 0.025) and torch.equal(v, written[1][k])
    assert _same(agent.actor, agent.actor_target) and not agent.actor_opt.state
    assert agent.bc_alpha == 2.5 and trust.state() == [0]  # shortened, not refused
    assert not _same(agent.actor, agent.start_actor)  # the caller validates it, then accepts
    trust.accept(agent, 500)
    assert _same(agent.actor, agent.start_actor) and trust.accepted == [500]


def test_backtracking_that_finds_no_stable_point_goes_back_to_the_anchor(tmp_path):
    agent = _agent()
    agent.anchor(2.5)
    start = {k: v.clone() for k, v in agent.actor.state_dict().items()}
    _moved(agent)
    checks = []
    trust = StableTrust(lambda path: checks.append(path) or 1.5, backtrack=2)
    hinf, kappa, there = trust.judge(agent, tmp_path / "x.pt", 500, True,
                                     lambda: tmp_path / "y.pt")
    assert (hinf, kappa) == (1.5, 0.0) and math.isnan(there) and len(checks) == 3
    assert all(torch.equal(v, start[k]) for k, v in agent.actor.state_dict().items())
    assert agent.bc_alpha == 1.25 and trust.state() == [1]


def _cfg(tmp_path, **kw):
    options = dict(algo="ca-td3", n_vehicles=3, steps=400, seed=0, num_envs=2,
                   base="ploeg:h=0.8", learning_starts=100, bc_alpha=2.5, eval_every=100,
                   eval_events=1, checkpoint_every=400, net=str(NET), out=str(tmp_path / "t.pt"),
                   gate_string_stable="real", trust_string_stable=True)
    return TrainConfig(**{**options, **kw}).check()


def test_a_run_never_keeps_an_amplifying_checkpoint_and_records_its_checks(tmp_path):
    seen = []

    def check(path):  # every trained checkpoint amplifies
        seen.append(path.name)
        return 1.5

    cfg = _cfg(tmp_path)
    result = train(cfg, [cruise_event(150, 12.0, 20.0)], progress=False, log=lambda line: None,
                   stability_check=check)
    first = result["training"]["first_actor_update_step"]
    checked = [s for s in (200, 300, 400) if s > first]
    assert seen == [f"step{s:06d}.pt" for s in checked]
    record = result["training"]["trust_string_stable"]
    assert record["rejected"] == len(checked) and record["accepted_steps"] == []
    assert record["final_bc_alpha"] == 2.5 * 0.5 ** len(checked)
    _, meta = load_policy(tmp_path / "t.pt")
    assert meta["step"] < min(checked)  # kept from before the actor moved
    curve = pd.read_csv(tmp_path / "t.csv")
    assert curve["worst_hinf"].notna().sum() == len(checked)
    card = policy_card(tmp_path / "t.pt")
    assert f"{len(checked)} checkpoints sent back to their anchor" in card
    assert "anchors accepted at steps none" in card


def test_a_backtracking_run_keeps_and_records_the_string_stable_points(tmp_path):
    calls = []

    def check(path):  # every actor as trained amplifies; half its step does not
        calls.append(path.name)
        return 1.5 if len(calls) % 2 else 0.999

    cfg = _cfg(tmp_path, trust_backtrack=2)
    result = train(cfg, [cruise_event(150, 12.0, 20.0)], progress=False, log=lambda line: None,
                   stability_check=check)
    first = result["training"]["first_actor_update_step"]
    checked = [s for s in (200, 300, 400) if s > first]
    assert calls == [name for s in checked for name in (f"step{s:06d}.pt", "backtrack.pt")]
    record = result["training"]["trust_string_stable"]
    assert record["rejected"] == 0 and record["shortened_steps"] == checked
    assert "moved back to a string-stable point" in policy_card(tmp_path / "t.pt")
    folder = tmp_path / "t.candidates"
    assert sorted(p.name for p in folder.glob("amplifying_*.pt")) == \
        [f"amplifying_step{s:06d}.pt" for s in checked]
    assert not (folder / "backtrack.pt").exists()
    for s in checked:  # the candidate is the point kept, the record the actor as trained
        _, meta = load_policy(folder / f"step{s:06d}.pt")
        assert meta["string_stability_gate"]["kappa"] == meta["validation"]["kappa"] == 0.5
        _, raw = load_policy(folder / f"amplifying_step{s:06d}.pt")
        assert raw["step"] == s and "kappa" not in raw["validation"]
    curve = pd.read_csv(tmp_path / "t.csv").set_index("step")
    assert (curve.loc[checked, "kappa"] == 0.5).all()
    assert (curve.loc[checked, "worst_hinf"] == 0.999).all()
    assert curve.loc[checked, "raw_score"].notna().all()
    _, meta = load_policy(tmp_path / "t.pt")
    if meta["step"] in checked:  # a backtracked point can be kept: it is string stable
        assert meta["string_stability_gate"]["kappa"] == 0.5


def test_a_resumed_run_keeps_its_anchor_alpha_and_record(tmp_path):
    cfg = _cfg(tmp_path, checkpoint_every=300)
    train(_cfg(tmp_path, checkpoint_every=300, steps=300), [cruise_event(150, 12.0, 20.0)],
          progress=False, log=lambda line: None, stability_check=lambda path: 1.5)
    result = train(cfg, [cruise_event(150, 12.0, 20.0)], resume=tmp_path / "t.ckpt",
                   progress=False, log=lambda line: None, stability_check=lambda path: 1.5)
    record = result["training"]["trust_string_stable"]
    assert record["final_bc_alpha"] == 2.5 * 0.5 ** record["rejected"]


@pytest.mark.parametrize("options", ["--trust-string-stable --bc-alpha 2.5",
                                     "--trust-string-stable --gate-string-stable real",
                                     "--trust-backtrack 2 --bc-alpha 2.5 --gate-string-stable "
                                     "real"])
def test_the_trust_region_needs_the_gate_and_an_anchor(tmp_path, capsys, options):
    argv = ["train", "--steps", "10", *options.split(), "--out", str(tmp_path / "p.pt")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--trust-string-stable" in err[0]
    assert not (tmp_path / "p.pt").exists()


def test_train_without_a_check_refuses_the_trust_region(tmp_path):
    from carl_sumo.errors import InputError

    with pytest.raises(InputError, match="string-stability check"):
        train(_cfg(tmp_path), [cruise_event(150, 12.0, 20.0)], progress=False)
