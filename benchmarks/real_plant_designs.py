"""Every real-plant design tried (issues 34 and 55) in one table, from the test-split files that
``benchmarks/real_plant_seeds.py`` wrote (``docs/results_real/learned_test*.json``; no simulation
here): per design the CA seeds' mean ± std (NGSIM test split, 10 followers, ``--plant real
--warmup 60``), the worst ‖Γ‖∞ over its seeds (every class, 0.5 and 2 m/s), CA against its
CA-off ablation paired by seed (relative difference of the means, paired t-test p), and the
commit whose tree holds its recipe, seed files and policy (the shipped product's: this one).
The former product's files are ``learned_test_*_mpf160k_*.json``; their rows keep the names its
seed files had at its commit (``ca_td3_real_10_seed*``).

Usage: python benchmarks/real_plant_designs.py   (prints a markdown table)
"""
import json
import math
from pathlib import Path

import numpy as np
from scipy import stats

OUT = Path("docs/results_real")
DESIGNS = (  # (label, CA file stem, CA-off file stem or None, commit holding its files)
    ("`REAL`: the robust CACC h = 0.8 s", "learned_test", "learned_test_nocomm", "4ac338e"),
    ("`REAL_AW`: + anti-windup `aw=1`", "learned_test_ca_td3_real_aw_10",
     "learned_test_ca_td3_real_aw_nocomm_10", "4ac338e"),
    ("`REAL_SPACING`: + a spacing term at 0.7 s", "learned_test_ca_td3_real_spacing_10", None, "4ac338e"),
    ("`REAL_SPACING_HA`: + the degraded head `ha=1.4`", "learned_test_ca_td3_real_ha_10",
     "learned_test_ca_td3_real_ha_nocomm_10", "4ac338e"),
    ("`REAL_REACT`: + the reaction layer `ttc=2`, validated on every source",
     "learned_test_ca_td3_real_react_10", "learned_test_ca_td3_real_react_nocomm_10", "4ac338e"),
    ("`REAL_CRIT`: + a critical-TTC reward term", "learned_test_ca_td3_real_crit_10",
     "learned_test_ca_td3_real_crit_nocomm_10", "4ac338e"),
    ("`REAL_RB`: + braking ahead in the reaction `rb=1`", "learned_test_ca_td3_real_rb_10", None, "4ac338e"),
    ("`REAL_GAP`: base at h = 0.7 s, + validation on the 32 hardest training events",
     "learned_test_ca_td3_real_gap_10", "learned_test_ca_td3_real_gap_nocomm_10", "4ac338e"),
    ("`REAL_GAP06`: base at h = 0.6 s", "learned_test_ca_td3_real_gap06_10",
     "learned_test_ca_td3_real_gap06_nocomm_10", "4ac338e"),
    ("`REAL_HARD`: + washout `wo=5`, the 64 hardest training events 4x in training",
     "learned_test_ca_td3_real_hard_10", "learned_test_ca_td3_real_hard_nocomm_10", "4ac338e"),
    ("`REAL_RCPO`: + close calls as a Lagrangian constraint (`--lagrange-lr 1`)",
     "learned_test_ca_td3_real_rcpo_10", "learned_test_ca_td3_real_rcpo_nocomm_10", "4ac338e"),
    ("`REAL_SETTLED`: + trained and validated from the 60 s settled start",
     "learned_test_ca_td3_real_settled_10", "learned_test_ca_td3_real_settled_nocomm_10", "4ac338e"),
    ("`REAL_GATED`: + each run keeps its best string-stable checkpoint (`--gate-string-stable`)",
     "learned_test_ca_td3_real_gated_10", "learned_test_ca_td3_real_gated_nocomm_10", "4ac338e"),
    ("`REAL_AMP`: `REAL_SETTLED` + an amplification term in the reward (`--w-amplify 1`)",
     "learned_test_ca_td3_real_amp_10", "learned_test_ca_td3_real_amp_nocomm_10", "4ac338e"),
    ("`REAL_HP`: `REAL_SETTLED` with the washout at 1 s (`wo=1`)",
     "learned_test_ca_td3_real_hp_10", "learned_test_ca_td3_real_hp_nocomm_10", "4ac338e"),
    ("`REAL_TWO`: `REAL_GATED`, CA first copies the two-ahead feed-forward (`--imitate two-ahead:c=0.3`)",
     "learned_test_ca_td3_real_two_10", "learned_test_ca_td3_real_two_nocomm_10", "4ac338e"),
    ("`REAL_TRUCK`: `REAL_TWO` with `gn=6`, `op=2` and trucks at 0.8 s `ht=0.8` (the former "
     "product: its kept checkpoints are the copy made before any RL update)",
     "learned_test_ca_td3_real_truck_10", "learned_test_ca_td3_real_truck_nocomm_10", "ecbde40"),
    ("`REAL_ACC_SPACING`: radar-only ACC base, CA copies the CACC",
     "learned_test_ca_td3_real_accsp_10", "learned_test_ca_td3_real_accsp_nocomm_10", "4ac338e"),
    ("`REAL_ACC_CMD`: the same, copying the predecessor's command",
     "learned_test_ca_td3_real_acccmd_10", "learned_test_ca_td3_real_acccmd_nocomm_10", "4ac338e"),
    ("`REAL_BASE`: RL from `product-base` itself, no imitation, critic calibrated first, "
     "TD3+BC anchored at the last string-stable checkpoint (`--trust-string-stable`), 16,000 "
     "transitions", "learned_test_ca_td3_real_base_10", "learned_test_ca_td3_real_base_nocomm_10",
     "ecbde40"),
    ("`REAL_MPF`: the same regime on `mpf-tuned`, 16,000 transitions",
     "learned_test_ca_td3_real_mpf_10", None, "a9f8386"),
    ("`REAL_MPF_160K`: `REAL_MPF` with 160,000 transitions (the former product)",
     "learned_test_ca_td3_real_mpf160k_10", "learned_test_ca_td3_real_mpf160k_nocomm_10",
     "b619a00"),
    ("`REAL_BACKTRACK`: the former product's recipe with `--trust-backtrack 3` (an amplifying "
     "checkpoint keeps the first string-stable point on the way back to its anchor)",
     "learned_test_ca_td3_real_bt_10", None, "d6cf41a"),
    ("`REAL_HEAD_FREE`: the former product's recipe with the head freed from the washout (`hf=1`: "
     "the first follower takes its learned term as it is)",
     "learned_test_ca_td3_real_hf_10", None, "10f3ba6"),
    ("`REAL_GAP_TRADED`: the same (`hf=1`) started from the gap-traded law (cars 0.5 s, head "
     "2.3 s, the reward's spacing term at the same gaps)",
     "learned_test_ca_td3_real_gt_10", None, "c05c2fe"),
    ("`REAL_GAP_BANDIT`: each vehicle's gap on `mpf-tuned` within its headway budget, chosen "
     "once per episode against the base on the same event (`gp=2:gl=0.5:gb=1:gh=1000`, "
     "`--paired-base`), the critics blind to the budget's common mode (the product, "
     "`ca_td3_real_10`)", "learned_test_ca_td3_real_10", "learned_test_ca_td3_real_nocomm_10",
     "this"),
)


def seeds(stem: str) -> list[dict]:
    """Per-seed rows of one file, in seed order (empty when the file is absent)."""
    path = OUT / f"{stem}.json"
    return [] if not path.exists() else [v for _, v in sorted(json.loads(path.read_text()).items())]


def mean_std(rows: list[dict], key: str, form: str) -> str:
    x = np.array([r[key] for r in rows], float)
    return f"{x.mean():{form}} ± {x.std(ddof=1):{form}}" if x.size > 1 else f"{x.mean():{form}}"


def worst_hinf(rows: list[dict]) -> str:
    """The largest ‖Γ‖∞ over seeds, classes and amplitudes (a test that collided is noted)."""
    values = [v for r in rows for k, v in r.items() if k.startswith("hinf_") and "inner" not in k]
    numbers = [v for v in values if isinstance(v, (int, float))]
    text = f"{max(numbers):.4f}" if numbers else ""
    return text + (" (a test collides)" if len(numbers) < len(values) else "")


def paired(ca: list[dict], off: list[dict], key: str) -> str:
    """CA relative to CA-off (%) and the paired t-test p, over the seeds both have."""
    a = np.array([r[key] for r in ca], float)
    b = np.array([r[key] for r in off], float)
    if not off or a.size != b.size:
        return "n/a"
    p = stats.ttest_rel(a, b).pvalue
    p_text = "n/a" if not math.isfinite(p) else f"{p:.2f}" if p >= 0.01 else "< 0.01"
    return f"{100 * (a.mean() / b.mean() - 1):+.1f} % (p {p_text})"


def main() -> None:
    print("| recipe | headway (s) | jerk (m/s³) | dampening | TTC < 1.5 s | collisions | worst ‖Γ‖∞ "
          "| CA vs CA-off: jerk | dampening | files in git |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for label, ca_stem, off_stem, commit in DESIGNS:
        ca = seeds(ca_stem)
        if not ca:
            continue
        off = seeds(off_stem) if off_stem else []
        cells = [mean_std(ca, "headway_s", ".3f"), mean_std(ca, "jerk_mps3", ".3f"),
                 mean_std(ca, "dampening_ratio", ".3f"), mean_std(ca, "ttc_lt_1_5s_count", ".1f"),
                 mean_std(ca, "collisions", ".1f"), worst_hinf(ca),
                 paired(ca, off, "jerk_mps3"), paired(ca, off, "dampening_ratio"),
                 "main" if commit == "this" else f"`{commit}`"]
        print(f"| {label} | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
