"""What a spacing policy's critic (a base with ``gp=T``, docs/models.md) says about trading gap:
on rows of a training checkpoint's replay buffer, the change of the first critic's Q (summed
over the platoon and per vehicle) when every vehicle's action is changed from 0 to the trade
"head +k·0.9, every follower -k·0.1" (m/s², i.e. s of gap asked for: the direction of the
gap-traded law) for k = 0.05, 0.15, 0.3 and 1, and to the current actor's action. A positive
slope near k = 0 is what the actor's gradient needs to move towards the trade.

Usage: python benchmarks/gap_trade_critic.py RUN.ckpt [RUN.ckpt ...] [--rows N]
(RUN.ckpt: the checkpoint ``carl-sumo train --out RUN.pt`` keeps beside its output)
"""
import argparse

import torch

from carl_sumo.learn.agents import Agent, normalise
from carl_sumo.learn.checkpoint import read_checkpoint
from carl_sumo.learn.replay_buffer import ReplayBuffer
from carl_sumo.learn.train_config import TrainConfig


def probe(path: str, rows: int) -> None:
    state = read_checkpoint(path)
    agent = Agent(TrainConfig(**state["train_config"]).agent_config())
    agent.load_state_dict(state["agent"])
    buffer = ReplayBuffer.from_state(state["buffer"])
    batch = buffer.rows(torch.arange(0, buffer.size, max(1, buffer.size // rows)))
    x, mask = normalise(batch["obs"]), batch["mask"]
    with torch.no_grad():
        actor = agent._act_normalised(agent.actor, x, mask)
        trade = torch.full_like(actor, -0.1)
        trade[:, 0] = 0.9
        q0 = agent._q([agent.critic1], x, torch.zeros_like(actor), mask)[0]
        print(f"{path}: step {state['step']}, {x.shape[0]} rows, Q(0) mean {q0.mean():.3f}, "
              f"reward per vehicle-step {batch['reward'].mean():.4f}; the actor's |a| "
              f"{actor.abs().mean():.3f} (head {actor[:, 0].mean():+.3f}, followers "
              f"{actor[:, 1:].mean():+.3f})")
        for name, action in [(f"trade x{k:g}", k * trade) for k in (0.05, 0.15, 0.3, 1.0)] + \
                [("the actor", actor)]:
            dq = agent._q([agent.critic1], x, action, mask)[0] - q0
            print(f"  {name}: dQ platoon mean {dq.mean():+.5f} (rows above 0: "
                  f"{(dq.mean(1) > 0).float().mean():.2f}), head {dq[:, 0].mean():+.5f}, "
                  f"followers {dq[:, 1:].mean():+.5f}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("checkpoints", nargs="+")
    parser.add_argument("--rows", type=int, default=4000, help="buffer rows, evenly spaced")
    args = parser.parse_args()
    for ckpt in args.checkpoints:
        probe(ckpt, args.rows)
