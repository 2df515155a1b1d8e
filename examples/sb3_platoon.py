"""Train a platoon controller with Stable-Baselines3 and score it with carl-sumo.

Needs ``pip install stable-baselines3`` (or ``pip install -e ".[sb3]"``). Train TD3 on the
single-agent Gymnasium environment ``carl_sumo/Platoon-v0`` (one follower behind a recorded leader;
the action is the acceleration adjustment a_adj in m/s², added to IDM), for a few thousand steps:

    python examples/sb3_platoon.py --steps 5000 --out runs/sb3_platoon.zip

then score the saved model on a 10-vehicle platoon like any other controller. ``Controller`` runs
the model on every follower (shared weights; each follower sees its own [v, a, d, Δv]); the model
file comes from ``CARL_SUMO_SB3_MODEL`` (default ``runs/sb3_platoon.zip``):

    carl-sumo simulate --controller examples/sb3_platoon.py:Controller,idm-external --events 5
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

DEFAULT_MODEL = "runs/sb3_platoon.zip"


def train(steps: int, out: Path, seed: int = 0, n_followers: int = 1,
          data: str = "default") -> Path:
    """Train TD3 for ``steps`` environment steps (0.1 s each) and save it to ``out`` (.zip)."""
    import gymnasium
    import torch
    from stable_baselines3 import TD3
    from stable_baselines3.common.noise import NormalActionNoise

    import carl_sumo  # noqa: F401  (registers carl_sumo/Platoon-v0)

    torch.set_num_threads(1)  # a 64x64 MLP: more threads only contend with SUMO and each other
    env = gymnasium.make("carl_sumo/Platoon-v0", n_followers=n_followers, data=data,
                         split="train")
    n = env.action_space.shape[0]
    model = TD3("MlpPolicy", env, learning_starts=min(1000, steps // 2), seed=seed, verbose=0,
                action_noise=NormalActionNoise(np.zeros(n), 0.3 * np.ones(n)),
                policy_kwargs={"net_arch": [64, 64]})
    model.learn(total_timesteps=steps)
    out.parent.mkdir(parents=True, exist_ok=True)
    model.save(out)  # SB3 appends .zip when the name has no suffix
    env.close()
    return out if out.suffix == ".zip" else out.with_name(out.name + ".zip")


class Controller:
    """An SB3 model as a carl-sumo controller: ``adjustment(obs)`` (m/s², shape (n,)) from the
    model's deterministic action for each follower's [v, a, d, Δv], added to IDM by carl-sumo."""

    def __init__(self, path: str | None = None):
        from stable_baselines3 import TD3

        from carl_sumo.errors import InputError

        path = Path(path or os.environ.get("CARL_SUMO_SB3_MODEL", DEFAULT_MODEL))
        if not path.is_file():
            raise InputError(f"no SB3 model {path}: train one with `python examples/"
                             f"sb3_platoon.py --out {path}` or set CARL_SUMO_SB3_MODEL")
        self.model = TD3.load(path, device="cpu")
        self.name = f"sb3:{path.stem}"
        self.width = self.model.observation_space.shape[0]

    def reset(self, n_followers: int) -> None:
        self.n = n_followers

    def adjustment(self, obs: np.ndarray) -> np.ndarray:
        rows = np.asarray(obs[:, :self.width], dtype=np.float32)  # one model input per follower
        action, _ = self.model.predict(rows, deterministic=True)
        return np.asarray(action, dtype=np.float64).reshape(obs.shape[0])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=5000, help="environment steps (0.1 s each)")
    parser.add_argument("--out", type=Path, default=Path(DEFAULT_MODEL), help="model file (.zip)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--data", default="default", help="leader data (default: shipped set)")
    args = parser.parse_args()
    path = train(args.steps, args.out, args.seed, data=args.data)
    print(f"wrote {path}; score it with\n  CARL_SUMO_SB3_MODEL={path} carl-sumo simulate "
          f"--controller examples/sb3_platoon.py:Controller,idm-external --events 5")


if __name__ == "__main__":
    main()
