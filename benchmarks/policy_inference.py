"""Time one platoon step of a policy: torch ``Agent.act`` against the numba ``CompiledActor``.

    python benchmarks/policy_inference.py [--vehicles 10] [--calls 2000]

Random-weight actors of CA-TD3 and TD3 (the weights do not change the cost); prints µs per call
for each path, the ratio, and the largest |difference| in a_adj (m/s²).
"""

from __future__ import annotations

import argparse
import time
from typing import Callable

import numpy as np
import torch

from carl_sumo.learn.agents import Agent, AgentConfig
from carl_sumo.learn.inference import CompiledActor


def us_per_call(act: Callable[[np.ndarray], np.ndarray], observations: list[np.ndarray]) -> float:
    """Mean wall time of one call (µs), best of 3 passes over ``observations``."""
    best = float("inf")
    for _ in range(3):
        start = time.perf_counter()
        for obs in observations:
            act(obs)
        best = min(best, (time.perf_counter() - start) / len(observations))
    return best * 1e6


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--vehicles", type=int, default=10)
    parser.add_argument("--calls", type=int, default=2000)
    args = parser.parse_args()
    torch.set_num_threads(1)
    rng = np.random.default_rng(0)
    n = args.vehicles
    observations = [np.column_stack([rng.uniform(0, 30, n), rng.uniform(-3, 3, n),
                                     rng.uniform(2, 80, n), rng.uniform(-5, 5, n)])
                    for _ in range(args.calls)]
    print(f"{n} vehicles, {args.calls} calls, torch {torch.__version__} "
          f"({torch.get_num_threads()} thread)")
    print(f"{'algo':8s} {'Agent.act µs':>13s} {'compiled µs':>12s} {'ratio':>7s} {'max |diff|':>11s}")
    for algo in ("ca-td3", "td3"):
        torch.manual_seed(0)
        agent = Agent(AgentConfig(algo=algo, n_vehicles=n))
        agent.eval()
        compiled = CompiledActor(agent)
        compiled(observations[0])  # compile (or load numba's cache) outside the timing
        diff = max(float(np.abs(compiled(o) - agent.act(o)).max()) for o in observations[:200])
        t_torch = us_per_call(agent.act, observations)
        t_compiled = us_per_call(compiled, observations)
        print(f"{algo:8s} {t_torch:13.1f} {t_compiled:12.1f} {t_torch / t_compiled:7.1f} "
              f"{diff:11.1e}")


if __name__ == "__main__":
    main()
