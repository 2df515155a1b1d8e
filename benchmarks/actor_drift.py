"""How a product-recipe actor changes when training runs on past its kept checkpoint (issue 21):
on 2,000 platoon states from the run's own replay buffer, the mean and largest |a_adj| (m/s²) and
its sensitivity to each observation, the mean |Δa_adj| per unit change of v (m/s), a (m/s²),
d (m), Δv (m/s) and a_base (m/s²), for the kept policy and for the last checkpoint's actor.

Make the runs first (`docs/training.md`, "What limits the product's gain"): for seed S,
    see recipes/
    carl-sumo train --algo ca-td3 --vehicles 10 --steps 24000 \\
        ${COMMON/--eval-every 500/--eval-every 1500} $PRODUCT --update-every 3 --scale-rates \\
        --seed S --out runs/long_seedS.pt
    carl-sumo export runs/long_seedS.ckpt --out runs/long_seedS_last.pt
then: python benchmarks/actor_drift.py runs/long_seed{0,1,2,3,4}.pt
"""
import sys

import numpy as np

from carl_sumo.learn.policy import load_policy, load_torch
from carl_sumo.learn.replay_buffer import ReplayBuffer

COLUMNS = (("v", 0.1), ("a", 0.1), ("d", 0.5), ("dv", 0.1), ("a_base", 0.1))  # name, step


def profile(agent, obs: np.ndarray) -> list[float]:
    """Mean and largest |a_adj|, then its mean sensitivity to each observation column."""
    a = agent.act(obs)
    row = [float(np.abs(a).mean()), float(np.abs(a).max())]
    for column, (_, step) in enumerate(COLUMNS):
        moved = obs.copy()
        moved[..., column] += step
        row.append(float(np.abs(agent.act(moved) - a).mean() / step))
    return row


if __name__ == "__main__":
    header = "run    actor  mean|a_adj|  max|a_adj|  " + "  ".join(f"d/d{n:<6}" for n, _ in COLUMNS)
    print(header)
    for path in sys.argv[1:]:
        buffer = ReplayBuffer.from_state(load_torch(path[:-3] + ".ckpt", "checkpoint")["buffer"])
        rows = np.random.default_rng(0).integers(0, buffer.size, 2000)
        obs = buffer.obs[rows].numpy().astype(np.float64)
        for label, policy in (("kept", path), ("last", path[:-3] + "_last.pt")):
            values = profile(load_policy(policy)[0], obs)
            print(f"{path.split('/')[-1]:<18} {label:<5} " + "  ".join(f"{v:9.3f}" for v in values))
