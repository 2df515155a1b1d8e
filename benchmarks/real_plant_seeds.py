"""The judged numbers of a real-plant recipe (docs/results.md, "The real-plant product"): every
seed of the product ``ca_td3_real_10`` and of its communication ablation
``ca_td3_real_nocomm_10`` (or of the stems given) on the NGSIM test split, 10 followers,
``--plant real --warmup 60`` (the default fleet and V2V delay, settled start); ‖Γ‖∞ of the CA
seeds per class at 0.5 and 2 m/s (5 followers, 8 frequencies 0.05-3 rad/s); CA against CA-off
paired by seed (t-test).

Writes ``docs/results_real/learned_test_<CA_STEM>.json`` (CA, with ‖Γ‖∞) and
``learned_test_<CA_OFF_STEM>.json`` and prints the comparison. About 15 minutes on 2 free cores.

Usage: python benchmarks/real_plant_seeds.py [DATA] [CA_STEM CA_OFF_STEM [TD3_STEM] [--no-hinf]
[--reuse]]

``--reuse``: a model whose JSON is already written (with a row for each of its seed files) is
read from it, not run again (e.g. to add TD3 when its seeds finish later).

With TD3_STEM (plain TD3 on the same recipe, e.g. ``td3_real_10``) also
``learned_test_<TD3_STEM>.json`` and CA against it, paired by seed. The earlier recipes' files
(``learned_test.json``, ``learned_test_nocomm.json`` and the other stems) were written by this
script from seed files that git history keeps.
"""
import glob
import json
import sys
from pathlib import Path

import numpy as np
from scipy import stats

from carl_sumo.control.channel import Impairments
from carl_sumo.control.transfer import log_frequencies
from carl_sumo.data import load_events
from carl_sumo.errors import InputError
from carl_sumo.experiments.simulate import simulate
from carl_sumo.experiments.string_stability import SineTest, string_stability
from carl_sumo.files import write_text_atomic
from carl_sumo.sim.vehicle import REAL_COMM_DELAY_S, REAL_PLANT

OUT = Path("docs/results_real")
KEYS = ("headway_s", "jerk_mps3", "dampening_ratio", "speed_mps", "ttc_lt_1_5s_count",
        "collisions")
REAL = Impairments(delay_s=REAL_COMM_DELAY_S, plant=REAL_PLANT)


def test_split(model: str, events, saved: Path | None = None) -> dict:
    """Every seed file of ``model`` on the events: {path: metrics}; read from ``saved`` (a JSON
    this script wrote) when given and it has every seed."""
    paths = sorted(glob.glob(f"policies/seeds/{model}_seed[0-9]*.pt"))
    if saved is not None and saved.is_file():
        rows = json.loads(saved.read_text())
        if set(rows) == set(paths):
            return rows
    rows = {}
    for path in paths:
        metrics = simulate(path, events, 10, workers=2, impairments=REAL)["metrics"]
        rows[path] = {k: metrics[k] for k in KEYS}
        print(path, rows[path], flush=True)
    return rows


def add_hinf(rows: dict) -> None:
    """‖Γ‖∞ per class (all links and the V2V links) at 0.5 and 2 m/s, into each row."""
    omegas = log_frequencies(8, 0.05, 3.0)
    for path, row in rows.items():
        for amp in (0.5, 2.0):
            try:
                result = string_stability([path], REAL_PLANT, REAL, 5, omegas,
                                          SineTest(amplitude_mps=amp), workers=2)
            except InputError as exc:  # a collision at some frequency
                row[f"hinf_error_{amp:g}"] = str(exc)
                continue
            for run in result["runs"]:
                row[f"hinf_{run['class']}_{amp:g}"] = run["hinf"]
                row[f"hinf_inner_{run['class']}_{amp:g}"] = run["hinf_inner"]


def main() -> None:
    args = [a for a in sys.argv[1:] if a not in ("--no-hinf", "--reuse")]
    reuse = "--reuse" in sys.argv
    data = args[0] if args else "../shared/data/ngsim/ngsim_cf_events.csv.gz"
    ca_stem, off_stem = args[1:3] if len(args) >= 3 else ("ca_td3_real_10",
                                                          "ca_td3_real_nocomm_10")
    events = [e.with_warmup(60.0) for e in load_events(data, "test")]
    OUT.mkdir(parents=True, exist_ok=True)
    ca_out = OUT / f"learned_test_{ca_stem}.json"
    ca = test_split(ca_stem, events, ca_out if reuse else None)
    if "--no-hinf" not in sys.argv and not any(k.startswith("hinf") for r in ca.values()
                                               for k in r):
        add_hinf(ca)
    write_text_atomic(ca_out, json.dumps(ca, indent=1))
    off_out = OUT / f"learned_test_{off_stem}.json"
    off = test_split(off_stem, events, off_out if reuse else None)
    write_text_atomic(off_out, json.dumps(off, indent=1))
    compare(ca, off, ca_stem, off_stem)
    if len(args) >= 4:
        td3_out = OUT / f"learned_test_{args[3]}.json"
        td3 = test_split(args[3], events, td3_out if reuse else None)
        write_text_atomic(td3_out, json.dumps(td3, indent=1))
        compare(ca, td3, ca_stem, args[3])


def compare(ca: dict, other: dict, ca_stem: str, other_stem: str) -> None:
    """Print CA against the other model per metric: seed means ± std, paired t-test by seed."""
    print(f"{ca_stem} against {other_stem}:")
    pairs = [(ca[p], other[p.replace(ca_stem, other_stem)]) for p in ca
             if p.replace(ca_stem, other_stem) in other]
    for key in KEYS:
        a = np.array([x[key] for x, _ in pairs], float)
        b = np.array([y[key] for _, y in pairs], float)
        p = stats.ttest_rel(a, b).pvalue
        print(f"{key}: CA {a.mean():.4f} ± {a.std(ddof=1):.4f}, other {b.mean():.4f} ± "
              f"{b.std(ddof=1):.4f}, {(a.mean() / b.mean() - 1) * 100:+.1f} %, paired p = {p:.3f}")


if __name__ == "__main__":
    main()
