"""What a run keeps with fewer updates per env step (issue 19), from the learning curves in
benchmarks/curves/update_every/ (validation every 500 steps on the recipes' 64 held-out events).

Recipes (`carl-sumo train ... --seed S`, recipes/):
- ``ca_td3_ploeg_10``: the product recipe before the safety shield (`--select comfort`), 10 seeds;
- ``ca_td3_10``, ``ca_ddpg_10``: the paper configuration's CA-TD3 and CA-DDPG recipes
  (`--select margin`), 5 seeds.
Schedules: ``every1`` an update every step (the recipes'), ``every3`` `--update-every 3`,
``every3scaled`` `--update-every 3 --scale-rates` (learning rates and tau three times the
recipe's; the curves were made with the equivalent `--actor-lr`, `--critic-lr`, `--tau` values).

The kept checkpoint is re-derived from each curve by the recipe's rule (the untrained policy, the
base, scores 0 for `comfort`). Prints seed mean ± std and a two-sided permutation p against
``every1``. Usage: python benchmarks/update_every_seeds.py
"""
import csv
import glob
from pathlib import Path

import numpy as np

CURVES = Path(__file__).parent / "curves" / "update_every"
RECIPES = {"ca_td3_ploeg_10": ("comfort", ("every1", "every3", "every3scaled")),
           "ca_td3_10": ("margin", ("every1", "every3scaled")),
           "ca_ddpg_10": ("margin", ("every1", "every3scaled"))}


def kept(path: str, rule: str) -> tuple[float, float, float, float, bool]:
    """Jerk, dampening, speed of the checkpoint the rule keeps; mean validation reward after
    step 1,000; whether it beats the base."""
    rows = list(csv.DictReader(open(path)))
    base = rows[0]  # steps before learning starts: the base alone
    best = (0.0, base) if rule == "comfort" else (-np.inf, None)
    for r in rows:
        if int(r["step"]) <= 1000:
            continue
        if rule == "comfort":
            unsafe = (int(r["collisions"]) > 0
                      or float(r["headway_s"]) > 1.05 * float(base["headway_s"]))
            score = min(float(r["z_jerk"]), float(r["z_dampening"]))
        else:  # margin (the curve has no TTC < 1.5 s count; the recipes' runs have none)
            unsafe = int(r["collisions"]) > 0 or not 1.0 <= float(r["headway_s"]) <= 2.5
            score = min(float(r["z_jerk"]), float(r["z_dampening"]), float(r["z_speed"]))
        score -= 1000 if unsafe else 0
        if score > best[0]:
            best = (score, r)
    later = [float(r["val_reward"]) for r in rows if int(r["step"]) > 1000]
    k = best[1]
    return (float(k["jerk_mps3"]), float(k["dampening_ratio"]), float(k["speed_mps"]),
            float(np.mean(later)), best[0] > 0)


def perm(a, b, n: int = 20000) -> float:
    rng = np.random.default_rng(0)
    a, b = np.array(a), np.array(b)
    obs = abs(a.mean() - b.mean())
    allv = np.concatenate([a, b])
    count = 0
    for _ in range(n):
        rng.shuffle(allv)
        count += abs(allv[:len(a)].mean() - allv[len(a):].mean()) >= obs - 1e-12
    return count / n


if __name__ == "__main__":
    for stem, (rule, schedules) in RECIPES.items():
        res = {}
        print(f"## {stem} (--select {rule})")
        for k in schedules:
            files = sorted(glob.glob(str(CURVES / f"{stem}_{k}_seed*.csv")))
            res[k] = [kept(f, rule) for f in files]
            print(f"{k}: {len(files)} seeds, beat the base: {sum(r[4] for r in res[k])}")
        for k in schedules[1:]:
            for i, name in enumerate(("kept jerk", "kept dampening", "kept speed",
                                      "val reward after step 1000")):
                a = [r[i] for r in res["every1"]]
                b = [r[i] for r in res[k]]
                print(f"{name}: every1 {np.mean(a):.4f} ± {np.std(a, ddof=1):.4f}  {k} "
                      f"{np.mean(b):.4f} ± {np.std(b, ddof=1):.4f}  p {perm(a, b):.3f}")
