"""Learning curves of several recipes overlaid: each seed's validation score relative to its
start (the score of the policy RL starts from, the curve's first row), and the worst ‖Γ‖∞ of
each validated checkpoint (``--trust-string-stable``), against the platoon transitions seen (a
recipe with 8 environments sees 4 times as many per step as one with 2).

Usage: python benchmarks/overlay_curves.py OUT.png STEM [STEM ...]
(each STEM's curves: ``policies/seeds/STEM_seed*.csv``). A row that ``--trust-backtrack`` moved
to a string-stable point also shows the amplifying actor's score before it (``raw_score``, a
cross joined to the point kept).
"""
import glob
import sys

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import pandas as pd  # noqa: E402


def main() -> None:
    out, stems = sys.argv[1], sys.argv[2:]
    fig, (ax, bx) = plt.subplots(2, 1, figsize=(8, 7), sharex=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for colour, stem in zip(colours, stems):
        paths = sorted(glob.glob(f"policies/seeds/{stem}_seed[0-9].csv"))
        for i, path in enumerate(paths):
            curve = pd.read_csv(path)
            start = curve["score"].iloc[0]
            gain = (curve["score"] - start) / abs(start) * 100
            label = f"{stem} ({len(paths)} seeds)" if i == 0 else None
            ax.plot(curve["transitions"], gain, color=colour, alpha=0.7, label=label)
            if "raw_score" in curve and curve["raw_score"].notna().any():
                moved = curve[curve["raw_score"].notna()]
                raw = (moved["raw_score"] - start) / abs(start) * 100
                ax.plot(moved["transitions"], raw, "x", color=colour, alpha=0.7)
                ax.vlines(moved["transitions"], raw, gain[moved.index], color=colour, lw=0.6,
                          alpha=0.5)
            if "worst_hinf" in curve:
                bx.plot(curve["transitions"], curve["worst_hinf"], ".-", color=colour, alpha=0.6)
    ax.axhline(0, color="k", lw=0.8)
    ax.axhline(5, color="k", lw=0.8, ls=":")
    ax.set_ylabel("validation score against the start (%)")
    ax.legend(fontsize=8)
    bx.axhline(1, color="k", lw=0.8)
    bx.set_ylabel("worst ‖Γ‖∞ of the checkpoint")
    bx.set_xlabel("platoon transitions seen")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
