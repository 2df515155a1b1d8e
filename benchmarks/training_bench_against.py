"""The training bench of this checkout's ``carl_sumo/experiments/bench.py`` run against whichever
``carl_sumo`` package Python imports, so an older commit is measured by the same harness:

    git worktree add /tmp/before <commit>
    PYTHONPATH=/tmp/before python benchmarks/training_bench_against.py 10,20 500   # older code
    python benchmarks/training_bench_against.py 10,20 500                          # this code
    python benchmarks/training_bench_against.py 10 500 3        # this code, an update every 3 steps

Arguments: platoon sizes (comma-separated), vector steps per phase, and vector steps per update
(default 1). The older package needs
``Agent``, ``AgentConfig``, ``ColoredNoise``, ``train.ReplayBuffer`` and ``vec_env.VecPlatoon``
with today's signatures (true since the first training bench).
"""

import importlib.util
import sys
from pathlib import Path

if __name__ == "__main__":  # the SUMO workers are spawned: they re-import this file
    import carl_sumo

    harness = Path(__file__).resolve().parents[1] / "carl_sumo" / "experiments" / "bench.py"
    spec = importlib.util.spec_from_file_location("bench_harness", harness)
    bench = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(bench)
    sizes = tuple(int(s) for s in (sys.argv[1] if len(sys.argv) > 1 else "10,20").split(","))
    steps = int(sys.argv[2]) if len(sys.argv) > 2 else 500
    every = int(sys.argv[3]) if len(sys.argv) > 3 else 1
    print(f"package: {Path(carl_sumo.__file__).parent}")
    print(bench.format_training_bench(bench.run_training_bench("ca-td3", sizes, 2, steps,
                                                               update_every=every)))
