"""Does a trained CA policy use its messages? Each seed of a CA model on the NGSIM test split
(10 followers, ``--plant real --warmup 60``) with its CA messages cut at test time (the policy
file's ``comm_off`` set: every message lost, as the CA-off ablation trains), against the same
seed with its messages, read from ``docs/results_real/learned_test_<STEM>.json``
(benchmarks/real_plant_seeds.py). The base's own V2V link is not cut.

Writes ``docs/results_real/messages_cut_<STEM>.json`` and prints the change per seed.

Usage: python benchmarks/ca_messages_cut.py DATA STEM [SEED ...]
"""
import json
import sys
import tempfile
from pathlib import Path

import torch

from carl_sumo.control.channel import Impairments
from carl_sumo.data import load_events
from carl_sumo.experiments.simulate import simulate
from carl_sumo.files import write_text_atomic
from carl_sumo.learn.policy import read_policy_payload
from carl_sumo.sim.vehicle import REAL_COMM_DELAY_S, REAL_PLANT

OUT = Path("docs/results_real")
KEYS = ("headway_s", "jerk_mps3", "dampening_ratio", "ttc_lt_1_5s_count", "collisions")


def main(data: str, stem: str, seeds: list[int]) -> None:
    events = [e.with_warmup(60.0) for e in load_events(data, "test")]
    real = Impairments(delay_s=REAL_COMM_DELAY_S, plant=REAL_PLANT)
    intact = json.loads((OUT / f"learned_test_{stem}.json").read_text())
    rows = {}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in seeds:
            path = f"policies/seeds/{stem}_seed{seed}.pt"
            payload = read_policy_payload(Path(path))
            payload["agent_config"] = {**payload["agent_config"], "comm_off": True}
            cut_path = Path(tmp) / f"{stem}_seed{seed}_cut.pt"
            torch.save(payload, cut_path)
            metrics = simulate(str(cut_path), events, 10, workers=2, impairments=real)["metrics"]
            rows[path] = {"with_messages": {k: intact[path][k] for k in KEYS},
                          "messages_cut": {k: metrics[k] for k in KEYS}}
            print(path, {k: f"{intact[path][k]:.4f} -> {metrics[k]:.4f}" for k in KEYS},
                  flush=True)
    write_text_atomic(OUT / f"messages_cut_{stem}.json", json.dumps(
        {"command": f"python benchmarks/ca_messages_cut.py DATA {stem} "
                    + " ".join(map(str, seeds)), "seeds": rows}, indent=1))


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2], [int(s) for s in sys.argv[3:]] or [0, 1, 2, 3, 4])
