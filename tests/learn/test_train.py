"""Training inside SUMO: a tiny run improves its reward; a killed run resumes from its checkpoint."""

import dataclasses
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
import pandas as pd
import torch

from carl_sumo.experiments.bench import cruise_event
from carl_sumo.learn.env import PlatoonEnv
from carl_sumo.errors import InputError
from carl_sumo.learn.policy import load_policy
from carl_sumo.learn.agents import Agent, AgentConfig, idm_acceleration_torch
from carl_sumo.control.controllers import idm_acceleration
from carl_sumo.learn.policy import save_policy
from carl_sumo.learn.selection import improvement_z, rank_runs, selection_score, validate
from carl_sumo.learn.train import TrainConfig, export_policy, held_out_split, seed_everything, train

from conftest import NET, REPO_ROOT, event_table


def test_tiny_training_run_improves_reward(tmp_path):
    events = [cruise_event(200, 15.0, 30.0)]
    cfg = TrainConfig(algo="td3", n_vehicles=1, steps=800, seed=0, num_envs=2,
                      learning_starts=200, eval_every=800, eval_events=1, checkpoint_every=800,
                      net=str(NET), out=str(tmp_path / "td3.pt"))
    result = train(cfg, events, progress=False)
    seed_everything(0)
    untrained = validate(Agent(AgentConfig(algo="td3", n_vehicles=1)), PlatoonEnv(events, 1, NET),
                         events)
    assert result["validation"]["val_reward"] > untrained["val_reward"] + 0.02
    agent, meta = load_policy(tmp_path / "td3.pt")
    assert meta["algo"] == "td3" and meta["trained_vehicles"] == 1
    assert (tmp_path / "td3.csv").read_text().startswith("step,transitions")
    meta = export_policy(tmp_path / "td3.ckpt", tmp_path / "final.pt")
    assert meta["exported_from"] == "td3.ckpt at step 800"
    assert load_policy(tmp_path / "final.pt")[0].cfg.algo == "td3"


def test_runs_of_several_seeds_share_one_validation_set_with_val_seed():
    events = [dataclasses.replace(cruise_event(50), event_id=f"e{i}") for i in range(40)]

    def held(**kw):
        return [e.event_id for e in held_out_split(events, TrainConfig(eval_events=8, **kw))[1]]

    assert held(seed=1) != held(seed=2)  # by default the training seed picks them
    assert held(seed=1, val_seed=0) == held(seed=2, val_seed=0) == held(seed=0)
    train_ids = {e.event_id for e in held_out_split(events, TrainConfig(seed=1, val_seed=0))[0]}
    assert len(held(seed=0)) == 8 and not train_ids & set(held(seed=0))
    events = [dataclasses.replace(e, source="zhu" if i % 4 == 0 else "other")
              for i, e in enumerate(events)]
    from_zhu = held(seed=0, val_source="zhu")
    assert len(from_zhu) == 5 and all(int(i[1:]) % 4 == 0 for i in from_zhu)  # half of 10
    with pytest.raises(InputError, match="--val-source 'nope'.*choose one of other, zhu"):
        held(val_source="nope")


def test_named_hardest_events_are_held_out_and_validated_too(tmp_path):
    events = [dataclasses.replace(cruise_event(50), event_id=f"e{i}") for i in range(40)]
    ids = tmp_path / "hard.txt"
    ids.write_text("# the hardest\ne3  # 1, 2, 3\n\ne7\n")
    random_train, random_val = held_out_split(events, TrainConfig(eval_events=8, seed=0))
    train_ev, val_ev = held_out_split(events, TrainConfig(eval_events=8, seed=0,
                                                          val_events=str(ids)))
    named = {"e3", "e7"}
    assert {e.event_id for e in val_ev} == {e.event_id for e in random_val} | named
    assert not named & {e.event_id for e in train_ev}
    assert len(train_ev) + len(val_ev) == 40
    ids.write_text("e3\nnope\n")
    with pytest.raises(InputError, match="--val-events: 1 event ID.*'nope'"):
        held_out_split(events, TrainConfig(val_events=str(ids)))
    ids.write_text("# nothing\n")
    with pytest.raises(InputError, match="names no event"):
        held_out_split(events, TrainConfig(val_events=str(ids)))
    with pytest.raises(InputError, match="cannot read the event ID list"):
        held_out_split(events, TrainConfig(val_events=str(tmp_path / "missing.txt")))


def test_excluded_events_are_neither_trained_nor_validated_on(tmp_path):
    events = [dataclasses.replace(cruise_event(50), event_id=f"e{i}") for i in range(40)]
    _, random_val = held_out_split(events, TrainConfig(eval_events=8, seed=0))
    gone = {random_val[0].event_id, "e39"}  # one the random draw validates on, one it trains on
    ids = tmp_path / "overlap.txt"
    ids.write_text("\n".join(sorted(gone)) + "\n")
    train_ev, val_ev = held_out_split(events, TrainConfig(eval_events=8, seed=0,
                                                          exclude_events=str(ids)))
    kept = [e.event_id for e in [*train_ev, *val_ev]]
    assert not gone & set(kept) and len(kept) == 38
    assert [e.event_id for e in val_ev] == [e.event_id for e in random_val[1:]]  # the same draw
    ids.write_text("nope\n")
    with pytest.raises(InputError, match="--exclude-events: 1 event ID.*'nope'"):
        held_out_split(events, TrainConfig(exclude_events=str(ids)))


def test_oversampled_events_are_drawn_k_times_as_often_and_never_validation_events(tmp_path):
    events = [dataclasses.replace(cruise_event(50), event_id=f"e{i}") for i in range(40)]
    val_ids = {e.event_id for e in held_out_split(events, TrainConfig(eval_events=8, seed=0))[1]}
    hard = sorted({f"e{i}" for i in range(40)} - val_ids)[:2]
    ids = tmp_path / "hard.txt"
    ids.write_text("\n".join(hard) + "\n")
    train_ev, val_ev = held_out_split(events, TrainConfig(eval_events=8, seed=0,
                                                          oversample=str(ids), oversample_times=5))
    counts = {i: sum(e.event_id == i for e in train_ev) for i in {e.event_id for e in train_ev}}
    assert {i: counts[i] for i in hard} == dict.fromkeys(hard, 5)
    assert set(counts.values()) == {1, 5} and len(train_ev) == 32 + 2 * 4
    assert {e.event_id for e in val_ev} == val_ids  # validation is unchanged
    ids.write_text(sorted(val_ids)[0] + "\n")
    with pytest.raises(InputError, match="--oversample: .* is held out for validation"):
        held_out_split(events, TrainConfig(eval_events=8, seed=0, oversample=str(ids)))
    ids.write_text("nope\n")
    with pytest.raises(InputError, match="--oversample: 1 event ID.*'nope'"):
        held_out_split(events, TrainConfig(eval_events=8, seed=0, oversample=str(ids)))


def test_selection_prefers_safe_smooth_policies():
    base = {"val_reward": 0.5, "collisions": 0, "ttc_lt_1_5s_count": 0, "headway_s": 1.5,
            "dampening_ratio": 0.9, "jerk_mps3": 0.3}
    smoother = dict(base, dampening_ratio=0.7)
    unsafe = dict(base, dampening_ratio=0.1, collisions=1)
    too_close = dict(base, dampening_ratio=0.1, headway_s=0.8)
    assert selection_score(smoother, "metrics") > selection_score(base, "metrics") > \
        selection_score(unsafe, "metrics")
    assert selection_score(base, "metrics") > selection_score(too_close, "metrics")
    assert selection_score(dict(base, val_reward=0.6), "reward") > selection_score(base, "reward")
    # reward: safety first, measured against the base's TTC < 1.5 s samples; no headway bound
    assert selection_score(base, "reward") > selection_score(dict(unsafe, val_reward=0.9), "reward")
    assert selection_score(dict(too_close, val_reward=0.6), "reward") > \
        selection_score(base, "reward")
    risky = dict(base, val_reward=0.9, ttc_lt_1_5s_count=3)
    assert selection_score(risky, "reward") < selection_score(base, "reward")
    assert selection_score(risky, "reward", dict(base, ttc_lt_1_5s_count=3)) > \
        selection_score(base, "reward", dict(base, ttc_lt_1_5s_count=3))
    # a base that collides once on the validation events: one collision is no worse than it
    hard = dict(base, collisions=1)
    assert selection_score(dict(hard, val_reward=0.9), "reward", hard) > \
        selection_score(hard, "reward", hard) > selection_score(dict(hard, collisions=2,
                                                                      val_reward=0.9), "reward", hard)
    idm = dict(base, speed_mps=8.0, dampening_ratio=0.8, jerk_mps3=0.2)
    fast = dict(base, speed_mps=9.0)
    slow = dict(fast, speed_mps=7.5)
    assert selection_score(fast, "metrics", idm) > selection_score(slow, "metrics", idm)
    # relative to IDM: 10 % less jerk outweighs 5 % more dampening
    assert selection_score(dict(fast, jerk_mps3=0.18, dampening_ratio=0.84), "metrics", idm) > \
        selection_score(fast | {"jerk_mps3": 0.2, "dampening_ratio": 0.8}, "metrics", idm)


def _event(jerk, damp, speed, n=100):
    return {"jerk_mps3": jerk, "dampening_ratio": damp, "speed_mps": speed,
            "n_jerk": n, "n_speed": n}


def test_margin_selection_keeps_the_checkpoint_that_beats_idm_on_its_weakest_criterion():
    rng = np.random.default_rng(0)
    idm = [_event(0.2 + 0.05 * rng.random(), 0.7 + 0.1 * rng.random(), 8 + rng.random())
           for _ in range(30)]
    noise = rng.normal(0.0, 0.01, size=(30, 3))

    def run(djerk, ddamp, dspeed):
        return [_event(e["jerk_mps3"] + djerk + a, e["dampening_ratio"] + ddamp + b,
                       e["speed_mps"] + dspeed + c) for e, (a, b, c) in zip(idm, noise)]

    z = improvement_z(run(-0.02, -0.02, 0.02), idm)
    assert all(v > 5 for v in z.values())  # paired: per-event noise 0.01 against a 0.02 gain
    z_slow = improvement_z(run(-0.05, -0.05, -0.01), idm)
    assert z_slow["z_jerk"] > 10 and z_slow["z_speed"] < -2  # slower than IDM: negative z
    # an undefined dampening ratio (a leader that never accelerates) leaves that event out
    nan_event = run(-0.02, -0.02, 0.02)
    nan_event[0]["dampening_ratio"] = float("nan")
    assert np.isfinite(improvement_z(nan_event, idm)["z_dampening"])
    safe = {"collisions": 0, "ttc_lt_1_5s_count": 0, "headway_s": 1.8}
    balanced, lopsided = safe | z, safe | z_slow
    assert selection_score(balanced, "margin") == min(z.values())
    assert selection_score(balanced, "margin") > selection_score(lopsided, "margin")
    assert selection_score(lopsided, "margin") > selection_score(balanced | {"collisions": 1},
                                                                 "margin")


def _run_file(path, seed, z, algo="ca-td3", n=4, **safety):
    val = {"collisions": 0.0, "ttc_lt_1_5s_count": 0.0, "headway_s": 1.8, **safety,
           "z_jerk": z[0], "z_dampening": z[1], "z_speed": z[2]}
    save_policy(Agent(AgentConfig(algo=algo, n_vehicles=n)), path,
                {"algo": algo, "trained_vehicles": n, "seed": seed, "validation": val})
    return path


def test_rank_runs_orders_seeds_by_their_stored_validation_score(tmp_path):
    files = [_run_file(tmp_path / "s5.pt", 5, (4.0, 1.0, 3.0)),     # weakest z 1.0
             _run_file(tmp_path / "s6.pt", 6, (2.0, 2.5, 2.0)),     # weakest z 2.0
             _run_file(tmp_path / "s7.pt", 7, (9.0, 9.0, 9.0), collisions=1.0),  # unsafe
             _run_file(tmp_path / "s8.pt", 8, (2.0, 2.0, 3.0))]     # ties seed 6
    rows = rank_runs(files)
    assert [r["seed"] for r in rows] == [6, 8, 5, 7]  # tie to the lower seed; unsafe last
    assert rows[0]["score"] == 2.0 and rows[-1]["unsafe"]
    other = _run_file(tmp_path / "td3.pt", 0, (1.0, 1.0, 1.0), algo="td3", n=1)
    with pytest.raises(InputError, match="one model at a time"):
        rank_runs([files[0], other])
    save_policy(Agent(AgentConfig(algo="ca-td3", n_vehicles=4)), tmp_path / "old.pt",
                {"seed": 1, "validation": {"collisions": 0.0}})
    with pytest.raises(InputError, match="no validation z_jerk"):
        rank_runs([tmp_path / "old.pt"])


def test_idm_torch_matches_controllers():
    rng = np.random.default_rng(0)
    obs = rng.uniform([0, -1, 1, -3], [30, 1, 80, 3], (64, 4))
    expected = idm_acceleration(obs[:, 0], obs[:, 2], obs[:, 3])
    assert np.allclose(idm_acceleration_torch(torch.as_tensor(obs)).numpy(), expected, atol=1e-9)


def test_smoothness_terms_lower_the_policy_jerk():
    """With only the smoothness terms in the actor loss, the actor learns to cancel IDM's change."""
    torch.manual_seed(0)
    rng = np.random.default_rng(1)
    obs = rng.uniform([5, 0, 10, -1], [15, 0, 40, 1], (64, 3, 4))
    next_obs = obs + rng.normal(0, [0.1, 0.0, 0.5, 0.2], obs.shape)
    batch = {"obs": torch.tensor(obs, dtype=torch.float32),
             "next_obs": torch.tensor(next_obs, dtype=torch.float32),
             "action": torch.zeros(64, 3), "reward": torch.zeros(64, 3), "done": torch.zeros(64),
             "mask": torch.ones(64, 3, dtype=torch.bool)}
    # critic_lr 0: Q stays as initialised, so the smoothness terms drive the actor
    agent = Agent(AgentConfig(algo="ddpg", smooth_jerk=1.0, actor_lr=1e-3, critic_lr=0.0))

    def policy_jerk() -> float:
        with torch.no_grad():
            return float(agent._smoothness(batch["obs"], batch["next_obs"],
                                           agent._act(agent.actor, batch["obs"], None),
                                           batch["mask"]).mean())

    before = policy_jerk()
    for _ in range(100):
        agent.update(batch)
    assert policy_jerk() < 0.7 * before


def test_the_adjustment_penalty_pulls_the_learned_term_towards_its_base():
    """--adj-l2: with the critic frozen, a heavy W·a_adj² in the actor loss shrinks a_adj."""
    torch.manual_seed(0)
    rng = np.random.default_rng(1)
    obs = torch.tensor(rng.uniform([5, 0, 10, -1], [15, 0, 40, 1], (64, 3, 4)), dtype=torch.float32)
    batch = {"obs": obs, "next_obs": obs, "action": torch.zeros(64, 3), "reward": torch.zeros(64, 3),
             "done": torch.zeros(64), "mask": torch.ones(64, 3, dtype=torch.bool)}

    def mean_adjustment(agent: Agent) -> float:
        with torch.no_grad():
            return float(agent._act(agent.actor, obs, None).abs().mean())

    sizes = {}
    for weight in (0.0, 100.0):
        torch.manual_seed(0)
        agent = Agent(AgentConfig(algo="ca-td3", n_vehicles=3, adj_l2=weight, actor_lr=1e-3,
                                  critic_lr=0.0))
        for _ in range(60):
            agent.update(batch)
        sizes[weight] = mean_adjustment(agent)
    assert sizes[100.0] < 0.5 * sizes[0.0]
    assert TrainConfig(adj_l2=2.0).agent_config().adj_l2 == 2.0


def test_killed_run_resumes_from_checkpoint(tmp_path):
    data = tmp_path / "events.csv"
    event_table([cruise_event(150, 12.0, 20.0)]).to_csv(data, index=False)
    out = tmp_path / "p.pt"
    cmd = [sys.executable, "-m", "carl_sumo", "train", "--algo", "ca-ddpg", "--vehicles", "2",
           "--data", str(data), "--split", "all", "--net", str(NET), "--out", str(out),
           "--learning-starts", "20", "--eval-every", "100", "--checkpoint-every", "100",
           "--envs", "1"]
    proc = subprocess.Popen(cmd + ["--steps", "100000"], cwd=REPO_ROOT,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            start_new_session=True)
    ckpt = out.with_suffix(".ckpt")
    deadline = time.time() + 120
    while not ckpt.exists() and time.time() < deadline:
        time.sleep(0.2)
    time.sleep(0.5)
    os.killpg(proc.pid, signal.SIGKILL)
    proc.wait()
    assert ckpt.exists() and out.exists()
    step = torch.load(ckpt, weights_only=True)["step"]
    assert step >= 100
    done = subprocess.run(cmd + ["--steps", str(step + 100), "--resume", str(ckpt)],
                          cwd=REPO_ROOT, capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    log = pd.read_csv(out.with_suffix(".csv"))
    assert log["step"].iloc[-1] == step + 100
    assert torch.load(ckpt, weights_only=True)["step"] == step + 100
    load_policy(out)
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_resuming_an_older_learning_curve_upgrades_its_header(tmp_path):
    from carl_sumo.learn.train import LOG_COLUMNS, _upgrade_log

    log = tmp_path / "p.csv"
    old = LOG_COLUMNS[:10]  # before the z columns
    log.write_text(",".join(old) + "\n" + ",".join(["500"] + ["1"] * 9) + "\n")
    _upgrade_log(log)
    with open(log, "a") as f:  # what the resumed run appends
        f.write(",".join(["1000"] + ["2"] * (len(LOG_COLUMNS) - 1)) + "\n")
    curve = pd.read_csv(log)
    assert list(curve.columns) == LOG_COLUMNS and list(curve["step"]) == [500, 1000]
    assert curve["z_speed"].isna().iloc[0] and curve["z_speed"].iloc[1] == 2
    before = log.read_text()
    _upgrade_log(log)  # a current log is left as it is
    assert log.read_text() == before


def test_residual_smoothness_reads_the_applied_acceleration_back():
    """On a classical base a(o) = a'_o' + g·(a_adj - stored a_adj): with another action it is the
    acceleration the simulation would have applied, and its jerk is the one the reward sees."""
    from carl_sumo.experiments.bench import cruise_event

    env = PlatoonEnv([cruise_event(80, 12.0, 20.0)], 3, NET, base="ploeg:h=0.8")
    obs = env.reset_array(seed=0)
    env.step_array(np.zeros(3))
    obs = env._obs.copy()
    stored, other = np.array([0.3, -0.2, 0.1]), np.array([-0.1, 0.4, 0.0])
    state = env._base.u.copy(), env._base._leader_speed
    _, _, _, _, applied = env.step_array(other)  # what the other action applies
    env._base.u, env._base._leader_speed = state
    env.sim.reset(env.event, 3)  # replay the same two steps, then take the stored action
    env._base.reset(3)
    env._obs = env._observe()
    env.step_array(np.zeros(3))
    assert np.allclose(env._obs, obs)
    next_obs, _, _, _, _ = env.step_array(stored)
    agent = Agent(AgentConfig(algo="td3", base="ploeg:h=0.8", smooth_jerk=1.0, smooth_accel=0.5))
    t = lambda x: torch.as_tensor(x[None])
    penalty = agent._residual_smoothness(t(obs), t(next_obs), t(stored), t(other))[0].numpy()
    jerk = (applied - obs[:, 1]) / 0.1
    assert np.allclose(penalty, 1.0 * jerk ** 2 + 0.5 * applied ** 2, rtol=1e-9)


def test_training_on_a_classical_base_records_it(tmp_path):
    events = [cruise_event(200, 15.0, 30.0)]
    cfg = TrainConfig(algo="ca-td3", n_vehicles=2, steps=300, seed=0, num_envs=2,
                      learning_starts=100, eval_every=300, eval_events=1, checkpoint_every=300,
                      net=str(NET), base="ploeg:h=0.8", smooth_jerk=0.05, select="comfort",
                      out=str(tmp_path / "r.pt"))
    result = train(cfg, events, progress=False)
    agent, meta = load_policy(tmp_path / "r.pt")
    assert agent.cfg.base == meta["base"] == "ploeg:h=0.8"
    assert meta["validation_base"]["headway_s"] == pytest.approx(
        result["validation_base"]["headway_s"])
    assert rank_runs([tmp_path / "r.pt"], "comfort")[0]["path"] == str(tmp_path / "r.pt")


def test_validation_in_two_processes_scores_as_in_one(tmp_path):
    """--val-workers 2: a helper process validates every other event; the base's validation
    (recorded in the run) is that of one process on the same held-out events."""
    import dataclasses

    from carl_sumo.learn.selection import BaseOnly, validate_events
    from carl_sumo.sim.metrics import aggregate

    events = [dataclasses.replace(cruise_event(150, 15.0, 30.0 + 2 * i), event_id=f"c{i}")
              for i in range(4)]
    cfg = TrainConfig(algo="ca-td3", n_vehicles=2, steps=200, seed=0, num_envs=1,
                      learning_starts=100, eval_every=200, eval_events=3, checkpoint_every=200,
                      net=str(NET), base="ploeg:h=0.8", val_workers=2, out=str(tmp_path / "r.pt"))
    result = train(cfg, events, progress=False)
    _, val = held_out_split(events, cfg)
    reward, per_event = validate_events(BaseOnly(), PlatoonEnv(val, 2, NET, base="ploeg:h=0.8"),
                                        val)
    np.testing.assert_equal(result["validation_base"],  # NaN (no dampening ratio) equals NaN
                            {"val_reward": reward, **aggregate(per_event)})


def test_comfort_selection_refuses_a_longer_headway_than_the_base():
    base = {"headway_s": 1.30}
    val = {"collisions": 0, "ttc_lt_1_5s_count": 0, "z_jerk": 3.0, "z_dampening": 2.0}
    assert selection_score({**val, "headway_s": 1.33}, "comfort", base) == 2.0
    assert selection_score({**val, "headway_s": 1.40}, "comfort", base) < -900


def test_critic_burn_in_leaves_the_actor_as_it_is():
    torch.manual_seed(0)
    agent = Agent(AgentConfig(algo="ca-td3", n_vehicles=3, base="ploeg:h=0.8"))
    batch = {"obs": torch.rand(16, 3, 5) * 10, "next_obs": torch.rand(16, 3, 5) * 10,
             "action": torch.rand(16, 3) - 0.5, "reward": torch.rand(16, 3),
             "done": torch.zeros(16), "mask": torch.ones(16, 3, dtype=torch.bool)}
    actor = [p.detach().clone() for p in agent.actor.parameters()]
    critic = [p.detach().clone() for p in agent.critic1.parameters()]
    for _ in range(4):
        agent.update(batch, train_actor=False)
    assert all(torch.equal(a, p) for a, p in zip(actor, agent.actor.parameters()))
    assert not all(torch.equal(c, p) for c, p in zip(critic, agent.critic1.parameters()))
    for _ in range(2):
        agent.update(batch)
    assert not all(torch.equal(a, p) for a, p in zip(actor, agent.actor.parameters()))


def test_braking_events_join_training_and_a_quarter_validates():
    from carl_sumo.data.synthetic import BRAKING_SOURCE, braking_events
    from carl_sumo.sim.sumo import lane_route, check_fits

    events = [dataclasses.replace(cruise_event(50), event_id=f"e{i}") for i in range(40)]
    train_set, val = held_out_split(events, TrainConfig(eval_events=8, val_seed=0,
                                                        braking_events=8))
    braking_val = [e for e in val if e.source == BRAKING_SOURCE]
    braking_train = [e for e in train_set if e.source == BRAKING_SOURCE]
    assert len(val) == 8 + 2 and len(braking_val) == 2 and len(braking_train) == 6
    assert not {e.event_id for e in braking_val} & {e.event_id for e in braking_train}
    again = braking_events(8, 0)
    assert [e.event_id for e in again] == [e.event_id for e in braking_val + braking_train]
    assert np.array_equal(again[0].leader_speed_mps, braking_val[0].leader_speed_mps)
    route = lane_route(NET)
    for e in again:
        v = e.leader_speed_mps
        assert 15.0 <= v[0] <= 30.0 and v.min() <= 8.0 and np.diff(v).min() / 0.1 >= -6.0 - 1e-9
        check_fits(route, e, 10)


def test_update_every_k_steps_with_a_larger_batch(tmp_path):
    from carl_sumo.learn.policy import load_torch

    events = [cruise_event(200, 15.0, 30.0)]
    cfg = TrainConfig(algo="td3", n_vehicles=1, steps=240, seed=0, num_envs=2, learning_starts=40,
                      eval_every=240, eval_events=1, checkpoint_every=240, update_every=4,
                      batch_size=64, tau=0.02, net=str(NET), out=str(tmp_path / "t.pt"))
    train(cfg, events, progress=False)
    state = load_torch(tmp_path / "t.ckpt", "checkpoint")
    assert state["updates"] == 200 // 4
    kept = load_policy(tmp_path / "t.pt")[0].cfg
    assert (kept.batch_size, kept.tau) == (64, 0.02)


def test_decayed_learning_rates_fall_linearly_to_zero_at_the_last_step(tmp_path):
    from carl_sumo.learn.policy import load_torch

    events = [cruise_event(200, 15.0, 30.0)]
    cfg = TrainConfig(algo="td3", n_vehicles=1, steps=120, seed=0, num_envs=2, learning_starts=40,
                      eval_every=120, eval_events=1, checkpoint_every=120, lr_decay=True,
                      actor_lr=1e-3, critic_lr=2e-3, net=str(NET), out=str(tmp_path / "t.pt"))
    train(cfg, events, progress=False)
    state = load_torch(tmp_path / "t.ckpt", "checkpoint")
    # the last update (step 119) ran at 1 - 79/80 of the rates
    assert state["actor_opt"]["param_groups"][0]["lr"] == pytest.approx(1e-3 / 80)
    assert state["critic_opt"]["param_groups"][0]["lr"] == pytest.approx(2e-3 / 80)


def test_scaled_rates_move_the_networks_as_far_per_env_step():
    """--scale-rates: an update every K steps gets K times the learning rates and tau."""
    plain = TrainConfig(actor_lr=1e-4, critic_lr=3e-4, update_every=3).agent_config()
    scaled = TrainConfig(actor_lr=1e-4, critic_lr=3e-4, update_every=3, scale_rates=True).agent_config()
    assert (plain.actor_lr, plain.critic_lr, plain.tau) == (1e-4, 3e-4, AgentConfig.tau)
    assert scaled.actor_lr == pytest.approx(3e-4) and scaled.critic_lr == pytest.approx(9e-4)
    assert scaled.tau == pytest.approx(3 * AgentConfig.tau)


def test_a_warm_start_keeps_its_actor_until_a_trained_checkpoint_validates_better(tmp_path):
    """--init: the run starts from the policy's actor, which is validated and written as the
    first candidate; with no update before the end it is the file the run keeps."""
    torch.manual_seed(3)
    start = Agent(AgentConfig(algo="ca-td3", n_vehicles=3))
    save_policy(start, tmp_path / "start.pt", {})
    cfg = TrainConfig(algo="ca-td3", n_vehicles=3, steps=40, learning_starts=1000, eval_every=40,
                      eval_events=1, checkpoint_every=40, net=str(NET), init=str(tmp_path / "start.pt"),
                      out=str(tmp_path / "warm.pt"))
    lines = []
    train(cfg, [cruise_event(100), cruise_event(100, 10.0, 14.0)], progress=False,
          log=lines.append)
    kept, meta = load_policy(tmp_path / "warm.pt")
    for name, tensor in start.actor.state_dict().items():
        assert torch.equal(kept.actor.state_dict()[name], tensor)
    assert meta["init"] == str(tmp_path / "start.pt")
    assert any(line.startswith("validation of --init") for line in lines)


def test_a_warm_start_from_another_configuration_is_refused(tmp_path, capsys):
    from carl_sumo.cli import main

    save_policy(Agent(AgentConfig(algo="ca-td3", n_vehicles=3)), tmp_path / "start.pt", {})
    cfg = TrainConfig(algo="ca-td3", n_vehicles=3, base="ploeg:h=0.8", net=str(NET),
                      init=str(tmp_path / "start.pt"), out=str(tmp_path / "x.pt"))
    with pytest.raises(InputError, match="--init"):
        train(cfg, [cruise_event(100)], progress=False)
    assert not (tmp_path / "x.pt").exists()
    code = main(["train", "--init", str(tmp_path / "start.pt"), "--resume", str(tmp_path / "c"),
                 "--out", str(tmp_path / "y.pt")])
    err = capsys.readouterr().err
    assert code == 2 and "--init" in err and len(err.strip().splitlines()) == 1


def test_training_with_a_warmup_settles_every_event_and_validates_the_recorded_part():
    from conftest import braking_event
    from carl_sumo.learn.selection import BaseOnly, validate_events
    from carl_sumo.experiments.simulate import cached_sim, run_event

    events = [dataclasses.replace(braking_event(v0=12.0, gap=30.0), event_id=f"e{i}")
              for i in range(12)]
    train_set, val = held_out_split(events, TrainConfig(eval_events=4, val_seed=0, warmup=20.0))
    assert {e.scored_from for e in train_set + val} == {200}
    env = PlatoonEnv(val[:1], 3, NET)
    _, (settled,) = validate_events(BaseOnly(), env, val[:1])
    # the same numbers as simulate --warmup 20 on that event with idm-external
    from carl_sumo.control.controllers import ZeroAdjustment
    from carl_sumo.sim.metrics import score_event

    expected = score_event(run_event(cached_sim(NET, "external"), val[0], 3, ZeroAdjustment()))
    assert settled["jerk_mps3"] == pytest.approx(expected["jerk_mps3"], rel=1e-9)
    assert settled["n_speed"] == expected["n_speed"] == events[0].n_samples * 3


def test_sine_leaders_join_training_span_the_gate_band_and_fit_the_road():
    """--sine-events: the string-stability test's excitation, a quarter in validation, the
    frequencies log-spaced over 0.1-3 rad/s, the leader's acceleration within ±2 m/s², each
    leader fitting the network with 10 followers after a 60 s warm-up."""
    from carl_sumo.data.synthetic import SINE_SOURCE, sine_events
    from carl_sumo.sim.sumo import lane_route, check_fits

    events = [dataclasses.replace(cruise_event(50), event_id=f"e{i}") for i in range(40)]
    train_set, val = held_out_split(events, TrainConfig(eval_events=8, val_seed=0,
                                                        sine_events=8))
    assert [e.source for e in val].count(SINE_SOURCE) == 2
    drawn = [e.source for e in train_set].count(SINE_SOURCE)  # a quarter of the draws (default)
    assert len({e.event_id for e in train_set if e.source == SINE_SOURCE}) == 6
    assert drawn == 6 * 2 and abs(drawn / len(train_set) - 0.25) < 0.05
    with pytest.raises(InputError, match="--sine-events"):
        TrainConfig(sine_share=0.5).check()
    route, peaks = lane_route(NET), []
    for e in sine_events(8, 0):
        v = e.leader_speed_mps
        assert np.all(v[:200] == v[0]) and 10.0 <= v[0] <= 25.0
        a = np.diff(v) / 0.1
        assert np.abs(a).max() <= 2.0 + 1e-9 and np.abs(a).max() > 0.04
        spectrum = np.abs(np.fft.rfft(v[200:] - v[0], n=1 << 16))
        peaks.append(2 * np.pi * np.argmax(spectrum) / ((1 << 16) * 0.1))
        check_fits(route, e.with_warmup(60.0), 10)
    assert np.allclose(sorted(peaks), np.geomspace(0.1, 3.0, 8), rtol=0.1)
