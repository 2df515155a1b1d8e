"""Where the vehicles that were not counted stayed: per run, the vehicles SUMO inserted at the six
mainline entries and the on-ramp during the measured interval, and the mean speed and waiting
time on the approach (SUMO's edgeData of each run folder).

``python docs/study/capacity_real/entries.py results/capacity_real/s0`` writes entries.csv here
(one row per run folder under that path)."""

from __future__ import annotations

import csv
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

HERE = Path(__file__).resolve().parent


def main(root: Path) -> None:
    rows = []
    for edgedata in sorted(root.glob("**/runs/p*_seed*/edgedata.xml")):
        run = edgedata.parent
        p, seed = run.name[1:].split("_seed")
        edges = {e.get("id"): e for e in ET.parse(edgedata).getroot().iter("edge")}
        folder = run.parent.parent.relative_to(root).parts[0]
        rows.append({"folder": folder, "p": float(p), "seed": int(seed),
                     "inserted_mainline": int(float(edges["i80_approach"].get("departed"))),
                     "inserted_onramp": int(float(edges["powell_onramp"].get("departed"))),
                     "approach_speed_mps": float(edges["i80_approach"].get("speed")),
                     "approach_waiting_s": float(edges["i80_approach"].get("waitingTime")),
                     "main_speed_mps": float(edges["i80_main"].get("speed"))})
    rows.sort(key=lambda r: (r["folder"], r["p"], r["seed"]))
    with (HERE / "entries.csv").open("w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    for r in rows:
        print(r)


if __name__ == "__main__":
    main(Path(sys.argv[1]))
