"""Kept checkpoints of the product recipe with an update every step against every 3 steps (issue 19):
10 seeds each, from the learning curves in benchmarks/curves/update_every/ (recipe of
policies/recipe.sh before the safety shield; `carl-sumo train ... --update-every K --seed S`).
The kept checkpoint is re-derived from each curve by the `comfort` rule (the untrained policy,
the base, scores 0). Prints seed mean ± std and a two-sided permutation p.
Usage: python benchmarks/update_every_seeds.py"""
import csv
import glob
from pathlib import Path

import numpy as np

CURVES = Path(__file__).parent / "curves" / "update_every"
def kept(path):
    rows = list(csv.DictReader(open(path)))
    base = rows[0]  # steps before learning starts: the base alone
    best = (0.0, base)  # the untrained policy (= the base) is the first candidate, score 0
    for r in rows:
        if int(r["step"]) <= 1000: continue
        unsafe = int(r["collisions"]) > 0 or float(r["headway_s"]) > 1.05 * float(base["headway_s"])
        score = min(float(r["z_jerk"]), float(r["z_dampening"])) - (1000 if unsafe else 0)
        if score > best[0]: best = (score, r)
    later = [float(r["val_reward"]) for r in rows if int(r["step"]) > 1000]
    return float(best[1]["jerk_mps3"]), float(best[1]["dampening_ratio"]), np.mean(later), best[0] > 0
def perm(a, b, n=20000):
    rng = np.random.default_rng(0)
    a, b = np.array(a), np.array(b); obs = abs(a.mean() - b.mean()); allv = np.concatenate([a, b]); c = 0
    for _ in range(n):
        rng.shuffle(allv); c += abs(allv[:len(a)].mean() - allv[len(a):].mean()) >= obs - 1e-12
    return c / n
res = {}
for k in (1, 3):
    files = sorted(glob.glob(str(CURVES / f"ca_td3_ploeg_10_every{k}_seed*.csv")))
    res[k] = [kept(f) for f in files]
    print(f"update every {k}: {len(files)} seeds")
for i, name in enumerate(("kept jerk", "kept dampening", "val reward after 1000")):
    a = [r[i] for r in res[1]]; b = [r[i] for r in res[3]]
    print(f"{name}: every1 {np.mean(a):.4f} ± {np.std(a, ddof=1):.4f}  every3 {np.mean(b):.4f} ± {np.std(b, ddof=1):.4f}  p {perm(a, b):.3f}")
print("beat base:", sum(r[3] for r in res[1]), sum(r[3] for r in res[3]))
