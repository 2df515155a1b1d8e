"""Train a platoon controller with RLlib PPO on the PettingZoo environment and score it with carl-sumo.

Needs the Ray extra (``pip install -e ".[ray]"``). Every follower of a 3-vehicle platoon is an
agent of :class:`carl_sumo.learn.env.PlatoonEnv` (observation [v, a, d, Δv], action the
acceleration adjustment a_adj in m/s², added to IDM); all share one policy. Train briefly and save
a checkpoint:

    python examples/rllib_platoon.py --iterations 5 --out runs/rllib_platoon

then score the checkpoint's shared module on a 10-vehicle platoon like any other controller.
``Controller`` reads the checkpoint from ``CARL_SUMO_RLLIB_CHECKPOINT`` (default
``runs/rllib_platoon``) and applies the mean of the policy's action distribution:

    carl-sumo simulate --controller examples/rllib_platoon.py:Controller,idm-external --events 5

The environment runs in the driver process (``num_env_runners=0``): libsumo runs one simulation
per process, so more environment runners each need a process of their own.
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

DEFAULT_CHECKPOINT = "runs/rllib_platoon"
MODULE = "shared"


def _make_env(config: dict):
    from ray.rllib.env.wrappers.pettingzoo_env import ParallelPettingZooEnv

    from carl_sumo.data import load_events
    from carl_sumo.learn.env import PlatoonEnv

    events = load_events(config.get("data", "default"), "train")
    return ParallelPettingZooEnv(PlatoonEnv(events, int(config.get("n_followers", 3))))


def train(iterations: int, out: Path, seed: int = 0, n_followers: int = 3,
          batch: int = 2000, data: str = "default") -> Path:
    """Run ``iterations`` PPO iterations of ``batch`` environment steps (0.1 s each) and save the
    algorithm's checkpoint to the folder ``out``."""
    import ray
    import torch
    from ray.rllib.algorithms.ppo import PPOConfig
    from ray.tune.registry import register_env

    torch.set_num_threads(1)  # small networks: more threads only contend with SUMO
    register_env("carl_sumo_platoon", _make_env)
    config = (PPOConfig()
              .environment("carl_sumo_platoon",
                           env_config={"n_followers": n_followers, "data": data})
              .env_runners(num_env_runners=0, rollout_fragment_length=min(batch, 200))
              .multi_agent(policies={MODULE}, policy_mapping_fn=lambda agent, *a, **k: MODULE)
              .training(train_batch_size=batch, minibatch_size=min(batch, 256), num_epochs=4,
                        lr=3e-4)
              .debugging(seed=seed))
    ray.init(num_cpus=1, include_dashboard=False, ignore_reinit_error=True,
             log_to_driver=False)
    try:
        algo = config.build_algo()
        for i in range(iterations):
            result = algo.train()
            ret = result.get("env_runners", {}).get("episode_return_mean", float("nan"))
            print(f"iteration {i + 1}/{iterations}: mean episode return {ret:.1f}")
        out = Path(out).resolve()
        algo.save(str(out))
        algo.stop()
    finally:
        ray.shutdown()
    return out


class Controller:
    """The shared RLlib module of a checkpoint as a carl-sumo controller: ``adjustment(obs)``
    (m/s², shape (n,)) is the mean action for each follower's [v, a, d, Δv], mapped from RLlib's
    normalised [-1, 1] to the action space's bounds, added to IDM by carl-sumo."""

    def __init__(self, path: str | None = None):
        from carl_sumo.errors import InputError

        root = Path(path or os.environ.get("CARL_SUMO_RLLIB_CHECKPOINT", DEFAULT_CHECKPOINT))
        module_dir = root / "learner_group" / "learner" / "rl_module" / MODULE
        if not module_dir.is_dir():
            raise InputError(f"no RLlib checkpoint with module {MODULE!r} at {root}: train one "
                             f"with `python examples/rllib_platoon.py --out {root}` or set "
                             "CARL_SUMO_RLLIB_CHECKPOINT")
        import torch
        from ray.rllib.core.rl_module.rl_module import RLModule

        self.torch = torch
        self.module = RLModule.from_checkpoint(module_dir.resolve())
        space = self.module.action_space
        self.low, self.high = float(space.low[0]), float(space.high[0])
        self.width = self.module.observation_space.shape[0]
        self.name = f"rllib:{root.name}"

    def reset(self, n_followers: int) -> None:
        self.n = n_followers

    def adjustment(self, obs: np.ndarray) -> np.ndarray:
        rows = self.torch.as_tensor(np.asarray(obs[:, :self.width], dtype=np.float32))
        with self.torch.no_grad():
            out = self.module.forward_inference({"obs": rows})
        mean = out["action_dist_inputs"].numpy()[:, 0]  # [mean, log_std] of a Gaussian
        unit = np.clip(mean.astype(np.float64), -1.0, 1.0)
        return self.low + (unit + 1.0) * 0.5 * (self.high - self.low)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--iterations", type=int, default=5, help="PPO iterations")
    parser.add_argument("--batch", type=int, default=2000,
                        help="environment steps (0.1 s each) per iteration")
    parser.add_argument("--out", type=Path, default=Path(DEFAULT_CHECKPOINT),
                        help="checkpoint folder")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--data", default="default", help="leader data (default: shipped set)")
    args = parser.parse_args()
    path = train(args.iterations, args.out, args.seed, batch=args.batch, data=args.data)
    print(f"wrote {path}; score it with\n  CARL_SUMO_RLLIB_CHECKPOINT={path} carl-sumo simulate "
          f"--controller examples/rllib_platoon.py:Controller,idm-external --events 5")


if __name__ == "__main__":
    main()
