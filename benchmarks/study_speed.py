"""Simulated seconds per wall second of a mixed-traffic study run at p = 0 (SUMO alone) and p = 1.

One run each, seed 0, back to back in this process (300 s warm-up + 100 s measured, full
demand), and their ratio. Usage:
    python benchmarks/study_speed.py [--controller policies/ca_td3_ploeg_10.pt] [--duration 100]
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from carl_sumo.study.run import StudyConfig, run_one


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--controller", default="policies/ca_td3_ploeg_10.pt")
    parser.add_argument("--duration", type=float, default=100.0, help="measured seconds")
    args = parser.parse_args()
    cfg = StudyConfig(controller=args.controller, duration_s=args.duration)
    speeds = {}
    with tempfile.TemporaryDirectory() as tmp:
        for p in (0.0, 1.0):
            result = run_one(cfg, p, 0, Path(tmp))
            row = result.metrics
            speeds[p] = row["sim_speed"]
            print(f"p = {p:g}: {row['sim_speed']:.2f} sim s / wall s, "
                  f"{100 * row['sumo_share']:.1f}% inside SUMO's step, "
                  f"{row['mean_vehicles']:.0f} vehicles on average")
    print(f"p = 1 runs at {speeds[1.0] / speeds[0.0]:.2f} times the speed of p = 0")


if __name__ == "__main__":
    main()
