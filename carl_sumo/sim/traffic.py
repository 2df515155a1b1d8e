"""Mixed human/CACC demand on the I-80-like network: route files, detectors and SUMO outputs.

Demand is given in vehicles/hour per entry: one entry per mainline lane of ``i80_approach`` (SUMO
index 0 = rightmost) and one for the Powell Street on-ramp ``powell_onramp``. Every vehicle is
written explicitly into the route file (``<vehicle>``), sorted by departure, so that runs at
different penetration rates p with the same seed share everything except the CACC set:

- arrivals per entry: shifted exponential headways ``h = h_min + Exp(3600/q - h_min)`` (s), q the
  entry's demand (veh/h), from their own random stream;
- human model per vehicle: Krauss with probability ``krauss_share`` else IDM, own stream;
- CACC per vehicle: ``u < p`` with ``u ~ U(0, 1)`` from a third stream, so the CACC set at p is a
  subset of the CACC set at any larger p, and p = 0 is exactly the human-only route file.

Vehicles are inserted by SUMO with its insertion checks on (``departSpeed="max"``: the highest speed
that is safe behind the vehicle ahead), so insertion never creates a collision; a vehicle that
cannot enter yet waits at its entry (SUMO's insertion backlog).

Human types are ``human_krauss`` and ``human_idm`` of ``routes/vtypes.add.xml`` (sigma = 0: no
randomness in the drivers themselves; the randomness of a run is its arrivals and its type draws,
all from ``seed``), with SUMO's default lane-change model LC2013 on.

Default demand (:data:`DEFAULT_DEMAND`): 2,000 veh/h on each of the six mainline lanes and
500 veh/h on the on-ramp. The NGSIM I-80 data set (Emeryville, CA, FHWA, 2005) shows mainline flows
of roughly 1,900-2,100 veh/h/lane in its 4:00-4:15 pm period and several hundred veh/h from the
Powell Street on-ramp; the defaults sit in the middle of that range.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from carl_sumo.errors import InputError
from carl_sumo.files import write_text_atomic

MAINLINE_EDGE = "i80_approach"
ONRAMP_EDGE = "powell_onramp"
MAIN_EDGE = "i80_main"
MAINLINE_ROUTE = ("i80_approach", "i80_merge", "i80_main")
ONRAMP_ROUTE = ("powell_onramp", "i80_merge", "i80_main")

HUMAN_TYPES = ("human_krauss", "human_idm")
CACC_TYPES = {"external": "cacc", "sumo": "cacc_sumo"}
"""CACC vehicle type: ``external`` = controlled by carl-sumo, ``sumo`` = SUMO's CACC model."""


@dataclass(frozen=True)
class Demand:
    """Traffic demand of a study run (veh/h per entry) and the human driver mix."""

    mainline_vph: tuple[float, ...] = (2000.0,) * 6  # per lane of i80_approach, index 0 = right
    onramp_vph: float = 500.0                        # Powell Street on-ramp (veh/h)
    krauss_share: float = 0.5                        # share of humans with Krauss, rest IDM (-)
    min_headway_s: float = 1.0                       # h_min of the arrival headways per entry (s)

    def __post_init__(self) -> None:
        rates = (*self.mainline_vph, self.onramp_vph)
        if any(not np.isfinite(q) or q < 0 for q in rates):
            raise InputError(f"demand must be finite and non-negative veh/h, got {rates}")
        if any(q > 0 and 3600.0 / q <= self.min_headway_s for q in rates):
            raise InputError(f"a demand above {3600.0 / self.min_headway_s:.0f} veh/h per entry "
                             "cannot be generated (mean headway below the minimum headway "
                             f"{self.min_headway_s} s); lower the demand")
        if not 0.0 <= self.krauss_share <= 1.0:
            raise InputError(f"krauss share must be in [0, 1], got {self.krauss_share}")

    @property
    def total_vph(self) -> float:
        return float(sum(self.mainline_vph) + self.onramp_vph)

    def scaled(self, factor: float) -> "Demand":
        """The same demand multiplied by ``factor`` (for small test runs)."""
        return Demand(tuple(q * factor for q in self.mainline_vph), self.onramp_vph * factor,
                      self.krauss_share, self.min_headway_s)


DEFAULT_DEMAND = Demand()


@dataclass
class RouteSet:
    """What :func:`write_routes` wrote: vehicle counts by kind, and the CACC vehicle ids."""

    path: Path
    n_vehicles: int
    cacc_ids: set[str] = field(default_factory=set)

    @property
    def n_cacc(self) -> int:
        return len(self.cacc_ids)


def _arrivals(rng: np.random.Generator, vph: float, min_headway_s: float,
              horizon_s: float) -> np.ndarray:
    """Departure times (s) in [0, horizon_s) of one entry: shifted exponential headways."""
    if vph <= 0:
        return np.zeros(0)
    mean_extra = 3600.0 / vph - min_headway_s
    n = int(horizon_s * vph / 3600.0 * 1.5) + 20
    times = np.cumsum(min_headway_s + rng.exponential(mean_extra, n)) - min_headway_s
    while times[-1] < horizon_s:  # never in practice; keeps the function exact for any horizon
        more = times[-1] + np.cumsum(min_headway_s + rng.exponential(mean_extra, n))
        times = np.concatenate([times, more])
    return times[times < horizon_s]


def write_routes(path: Path, penetration: float, seed: int, horizon_s: float,
                 demand: Demand = DEFAULT_DEMAND, cacc_kind: str = "external") -> RouteSet:
    """Write the route file of one run (atomically): every vehicle, its entry, type, departure.

    ``penetration`` is the probability p that a vehicle is CACC (of type ``CACC_TYPES[cacc_kind]``);
    ``horizon_s`` the last departure time (s).
    """
    if not 0.0 <= penetration <= 1.0:
        raise InputError(f"penetration rate must be in [0, 1], got {penetration}")
    arrivals_seq, model_seq, cacc_seq = np.random.SeedSequence(seed).spawn(3)
    arrivals_rng = np.random.default_rng(arrivals_seq)
    entries: list[tuple[str, str, int, float]] = [
        (f"main{lane}", "mainline", lane, q) for lane, q in enumerate(demand.mainline_vph)]
    entries.append(("ramp", "onramp", 0, demand.onramp_vph))
    rows: list[tuple[float, str, str, int]] = []
    for name, route, lane, q in entries:
        for k, t in enumerate(_arrivals(arrivals_rng, q, demand.min_headway_s, horizon_s)):
            rows.append((float(t), f"{name}.{k}", route, lane))
    rows.sort(key=lambda r: (r[0], r[1]))
    n = len(rows)
    krauss = np.random.default_rng(model_seq).random(n) < demand.krauss_share
    cacc = np.random.default_rng(cacc_seq).random(n) < penetration
    cacc_type = CACC_TYPES[cacc_kind]
    lines = ['<?xml version="1.0" encoding="UTF-8"?>',
             f"<!-- carl-sumo study demand: p={penetration}, seed={seed}, "
             f"{demand.total_vph:.0f} veh/h in total. Written by carl_sumo/sim/traffic.py. -->",
             "<routes>",
             f'    <route id="mainline" edges="{" ".join(MAINLINE_ROUTE)}"/>',
             f'    <route id="onramp" edges="{" ".join(ONRAMP_ROUTE)}"/>']
    cacc_ids: set[str] = set()
    for i, (t, vid, route, lane) in enumerate(rows):
        vtype = cacc_type if cacc[i] else HUMAN_TYPES[0 if krauss[i] else 1]
        if cacc[i]:
            cacc_ids.add(vid)
        lines.append(f'    <vehicle id="{vid}" type="{vtype}" route="{route}" depart="{t:.1f}" '
                     f'departLane="{lane}" departPos="base" departSpeed="max"/>')
    lines.append("</routes>")
    write_text_atomic(Path(path), "\n".join(lines) + "\n")
    return RouteSet(Path(path), n, cacc_ids)


def write_detectors(path: Path, n_lanes: int, position_m: float, begin_s: float, end_s: float,
                    period_s: float = 60.0) -> dict[str, Path]:
    """Write the additional file of a run: SUMO outputs that the study reads back.

    - an induction loop (E1) on every lane of ``i80_main`` at ``position_m`` (m from the start of
      the edge), aggregated every ``period_s`` s, into ``detectors.xml``;
    - ``edgeData`` (traffic: speed, sampled seconds) into ``edgedata.xml`` and ``edgeData`` of
      type emissions (SUMO's emission model, HBEFA default class of each type) into
      ``emissions.xml``, both over the measurement interval [begin_s, end_s) (s).

    Output paths are relative to the additional file's folder; returns them.
    """
    path = Path(path)
    outputs = {"detectors": path.parent / "detectors.xml",
               "edgedata": path.parent / "edgedata.xml",
               "emissions": path.parent / "emissions.xml"}
    lines = ['<?xml version="1.0" encoding="UTF-8"?>', "<additional>"]
    for lane in range(n_lanes):
        lines.append(f'    <inductionLoop id="det_{lane}" lane="{MAIN_EDGE}_{lane}" '
                     f'pos="{position_m:.1f}" period="{period_s:g}" file="detectors.xml"/>')
    lines.append(f'    <edgeData id="traffic" file="edgedata.xml" begin="{begin_s:g}" '
                 f'end="{end_s:g}" period="{end_s - begin_s:g}"/>')
    lines.append(f'    <edgeData id="emissions" type="emissions" file="emissions.xml" '
                 f'begin="{begin_s:g}" end="{end_s:g}" period="{end_s - begin_s:g}"/>')
    lines.append("</additional>")
    write_text_atomic(path, "\n".join(lines) + "\n")
    return outputs


