"""Training inside SUMO: a tiny run improves its reward; a killed run resumes from its checkpoint."""

import os
import signal
import subprocess
import sys
import time

import pandas as pd
import torch

from carl_sumo.agents import Agent, AgentConfig
from carl_sumo.bench import cruise_event
from carl_sumo.env import PlatoonEnv
from carl_sumo.policy import load_policy
from carl_sumo.train import (TrainConfig, export_policy, seed_everything, selection_score,
                             train, validate)

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


def test_selection_prefers_safe_smooth_policies():
    base = {"val_reward": 0.5, "collisions": 0, "ttc_lt_1_5s_count": 0, "headway_s": 1.5,
            "dampening_ratio": 0.9, "jerk_mps3": 0.3}
    smoother = dict(base, dampening_ratio=0.7)
    unsafe = dict(base, dampening_ratio=0.1, collisions=1)
    too_close = dict(base, dampening_ratio=0.1, headway_s=0.8)
    assert selection_score(smoother) > selection_score(base) > selection_score(unsafe)
    assert selection_score(base) > selection_score(too_close)
    assert selection_score(dict(base, val_reward=0.6), "reward") > selection_score(base, "reward")


def test_killed_run_resumes_from_checkpoint(tmp_path):
    data = tmp_path / "events.csv"
    event_table([cruise_event(150, 12.0, 20.0)]).to_csv(data, index=False)
    out = tmp_path / "p.pt"
    cmd = [sys.executable, "-m", "carl_sumo.cli", "train", "--algo", "ca-ddpg", "--vehicles", "2",
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
