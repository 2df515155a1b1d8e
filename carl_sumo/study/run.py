"""Mixed human/CACC traffic studies on the I-80-like freeway: ``carl-sumo study``.

One run = one penetration rate p and one seed: SUMO (libsumo) simulates the human demand of
:mod:`carl_sumo.sim.traffic` in which each vehicle is CACC with probability p, for ``warmup_s`` +
``duration_s`` simulated seconds; metrics are taken over the last ``duration_s`` only (the warm-up
fills the 8.4 km road: a vehicle at 30 m/s crosses it in 280 s).

CACC vehicles (controller ``idm-external`` or a policy file) are driven by carl-sumo every 0.1 s:

- the vehicle ahead is what SUMO says it is (``vehicle.getLeader`` up to the sensing range
  ``max(v2v_range_m, SENSOR_RANGE_M)``), whoever it is: humans may cut in;
- the observation is o_i = [v_i (m/s), a_i (m/s²), d_i (m, bumper gap), Δv_i = v_ahead - v_i
  (m/s)]; with no vehicle within the sensing range d_i = the sensing range and Δv_i = 0;
- chains (:func:`carl_sumo.experiments.chain_formation.form_chains`): consecutive CACC vehicles in one lane, each within ``v2v_range_m``
  of the one ahead; a human or a longer gap ends a chain. The policy runs on each chain as one
  platoon (the numba-compiled actor of :mod:`carl_sumo.learn.inference`; the Communication-Aware module
  gives the boundary messages to each chain's ends);
- a = clip(a_IDM + a_adj) (:func:`carl_sumo.control.controllers.total_acceleration`), or for a policy
  trained on a classical base, that CACC on the same chains with a_adj in its law, applied exactly with
  ``setSpeed(max(v + a·dt, 0))`` (speedMode 0); lane changes off (laneChangeMode 0).

Controllers ``ploeg``, ``ploeg:h=..`` and ``ploeg-tuned:h=..``: Ploeg's CACC
(:class:`carl_sumo.control.cacc.PloegChains`) on the same chains, applied the same way; a chain's head
takes the acceleration of the vehicle ahead over the last step where a platoon's first follower
takes the leader's. At a zipper merge a law with ``gs``/``gn`` (and a policy on such a base) is
told each vehicle's distance to the merge point while its vehicle ahead is still on the other
feeding lane, and reaches that point behind it
(:meth:`carl_sumo.control.cacc.PloegChains.merge_behind`).

Controller ``sumo-cacc``: CACC vehicles are of type ``cacc_sumo`` (SUMO's CACC car-following
model) and SUMO drives them; only their lane changes are switched off.

Metrics of a run (over the measurement interval, every vehicle on the network):

| key | unit | definition |
|---|---|---|
| ``throughput_vph`` | veh/h | vehicles counted by SUMO's induction loops on all lanes of ``i80_main`` at ``detector_pos_m`` / measured hours |
| ``speed_mps`` | m/s | SUMO edgeData: total distance / total time of all vehicles on all edges |
| ``headway_s`` | s | mean of d/v over samples with v > 0.5 m/s and a vehicle ahead within 150 m |
| ``ttc_lt_4s_per_vh``, ``ttc_lt_1_5s_per_vh`` | 1/veh-h | 0.1 s samples with 0 < TTC < 4 s (1.5 s), TTC = d/(v - v_ahead) when v > v_ahead, per vehicle-hour |
| ``jerk_mps3`` | m/s³ | mean \\|j\\|, j = Δa/dt and a = Δv/dt from SUMO speeds every 0.1 s |
| ``collisions`` | - | SUMO collisions (bumper overlap; both vehicles are removed) |
| ``co2_g_per_km``, ``fuel_g_per_km`` | g/veh-km | SUMO emission model (edgeData emissions, default HBEFA class) / vehicle-km |
"""

from __future__ import annotations

import math
import os
import shutil
import time
import xml.etree.ElementTree as ET
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from carl_sumo.config import DT_S, HEADWAY_MIN_SPEED_MPS
from carl_sumo.progress import track
from carl_sumo.control.cacc import PloegChains
from carl_sumo.control.channel import Impairments
from carl_sumo.errors import InputError
from carl_sumo.control.sensors import Sensors
from carl_sumo.files import check_xml, output_error, write_text_atomic
from carl_sumo.experiments.chain_controllers import ChainController, know_vehicle, resolve_study_controller
from carl_sumo.experiments.chain_formation import cacc_observations, form_chains, merging_lanes, zipper_aheads
from carl_sumo.study.results import RunResult, markdown_table, run_name, summarise, write_csv
from carl_sumo.sim.sumo import DEFAULT_NET, VTYPES_FILE, close_sumo, lane_route, start_sumo
from carl_sumo.sim.traffic import (CACC_TYPES, DEFAULT_DEMAND, HUMAN_TYPES, MAIN_EDGE, Demand,
                               write_detectors, write_routes)

SENSOR_RANGE_M = 300.0
"""Range within which a CACC vehicle sees the vehicle ahead (radar), m; at least the V2V range."""

FOLLOWING_GAP_M = 150.0
"""A vehicle counts as following (headway metric) when the vehicle ahead is within this (m)."""

SPEED_MODE_CACC = 0
"""speedMode of carl-sumo's CACC vehicles: the commanded speed is applied exactly, no SUMO checks."""


def insertion_tau_s() -> float:
    """The tau (s) SUMO inserts carl-sumo's CACC vehicles with: that of SUMO's own CACC type
    (``cacc_sumo`` in ``routes/vtypes.add.xml``, 0.6 s), so every CACC controller of the study
    enters the road alike and what the road then carries is decided by the controller. SUMO
    keeps a vehicle at its entry until the gap ahead is safe for its vType's tau: with the
    ``cacc`` type's IDM tau of 1.5 s the entries, not the controllers, set the throughput
    (measured at demand x1.5, p = 1, seeds 0-1: ``ploeg-tuned:h=0.8`` carries 18,567 veh/h with
    0.6 s; ``ploeg-tuned:h=1`` carried 10,821 with 1.5 s, in free flow)."""
    for vtype in ET.parse(VTYPES_FILE).getroot().iter("vType"):
        if vtype.get("id") == CACC_TYPES["sumo"]:
            return float(vtype.get("tau"))
    raise InputError(f"{VTYPES_FILE} has no vType {CACC_TYPES['sumo']!r}; restore it from git")

HEATMAP_BIN_S = 10.0
"""Time bin of the time-space speed map (s)."""

HEATMAP_BIN_M = 100.0
"""Space bin of the time-space speed map (m)."""

@dataclass(frozen=True)
class StudyConfig:
    """Everything that defines a study (units in the names)."""

    controller: str = "idm-external"
    penetrations: tuple[float, ...] = (0.0, 0.25, 0.5, 0.75, 1.0)
    seeds: tuple[int, ...] = (0, 1, 2)
    duration_s: float = 900.0          # measured simulated time (s)
    warmup_s: float = 300.0            # simulated time before measuring (s)
    v2v_range_m: float = 300.0         # V2V range between consecutive CACC vehicles (m)
    detector_pos_m: float = 5000.0     # induction loops, m from the start of i80_main
    heatmap_lane: int = 6              # NGSIM lane of the time-space map (6 = rightmost)
    net: str = str(DEFAULT_NET)
    demand: Demand = DEFAULT_DEMAND
    fcd: bool = False                  # FCD output of the first seed of each rate
    workers: int = 2
    human_sigma: float = 0.0           # human driver imperfection (see set_human_variability)
    impairments: Impairments | None = None  # V2V delay/loss and sensor noise of the CACC vehicles

    @property
    def plant_key(self) -> str:
        """The plant a ``-tuned`` law reads its gains for (``ideal`` without impairments)."""
        return self.impairments.plant_key if self.impairments is not None else "ideal"


# ------------------------------------------------------------------------------------ runs
@dataclass
class _Accumulator:
    """Running sums of the per-sample metrics over the measurement interval."""

    samples: int = 0
    headway_sum: float = 0.0
    headway_n: int = 0
    ttc4: int = 0
    ttc15: int = 0
    jerk_sum: float = 0.0
    jerk_n: int = 0
    collisions: int = 0
    vehicles_sum: int = 0
    vehicles_max: int = 0
    steps: int = 0
    cacc_samples: int = 0
    chain_sum: int = 0
    chain_n: int = 0
    chain_max: int = 0


def _sumo_study_args(cfg: StudyConfig, routes: Path, additional: Path,
                     fcd: Path | None, seed: int) -> list[str]:
    end = cfg.warmup_s + cfg.duration_s
    args = ["-n", str(cfg.net), "-a", f"{VTYPES_FILE},{additional}", "-r", str(routes),
            "--step-length", str(DT_S), "--seed", str(seed), "--begin", "0", "--end", f"{end:g}",
            "--no-step-log", "true", "--no-warnings", "true",
            "--collision.action", "remove", "--collision.mingap-factor", "0",
            "--time-to-teleport", "-1",
            "--collision-output", str(Path(additional).parent / "collisions.xml")]
    if fcd is not None:
        args += ["--fcd-output", str(fcd), "--fcd-output.acceleration", "true",
                 "--device.fcd.period", "1", "--device.fcd.begin", f"{cfg.warmup_s:g}"]
    return args


HUMAN_SPEED_DEV_PER_SIGMA = 0.2
"""speedDev of the human types per unit of ``--human-sigma``: SUMO's own defaults pair sigma 0.5
with speedDev 0.1."""


def set_human_variability(ls, sigma: float) -> None:
    """Make the human drivers of the running simulation non-deterministic (``--human-sigma``):
    SUMO's driver imperfection ``sigma`` (the Krauss humans' random dawdling; SUMO's IDM does not
    use it) and a spread of desired speeds, speedDev = :data:`HUMAN_SPEED_DEV_PER_SIGMA`·sigma,
    for both human types. Their draws come from SUMO's ``--seed`` (the run's seed). 0 changes
    nothing: the humans of ``routes/vtypes.add.xml`` are deterministic."""
    if sigma <= 0:
        return
    for vtype in HUMAN_TYPES:
        ls.vehicletype.setImperfection(vtype, sigma)
        ls.vehicletype.setSpeedDeviation(vtype, HUMAN_SPEED_DEV_PER_SIGMA * sigma)


def run_one(cfg: StudyConfig, penetration: float, seed: int, out_dir: Path) -> RunResult:
    """Simulate one (p, seed) run in this process and score it; its SUMO files go to out_dir."""
    import libsumo as ls

    kind, controller = resolve_study_controller(cfg.controller, cfg.plant_key)
    out_dir = Path(out_dir)
    name = run_name(penetration, seed)
    final = out_dir / "runs" / name
    work = out_dir / "runs" / f".{name}.{os.getpid()}.tmp"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir(parents=True)
    end_s = cfg.warmup_s + cfg.duration_s
    try:
        routes = write_routes(work / "routes.rou.xml", penetration, seed, end_s, cfg.demand, kind)
        outputs = write_detectors(work / "outputs.add.xml", _main_lanes(cfg.net),
                                  cfg.detector_pos_m, cfg.warmup_s, end_s)
        fcd = work / f"fcd_{name}.xml.gz" if cfg.fcd and seed == cfg.seeds[0] else None
        lane_chain = lane_route(cfg.net, cfg.heatmap_lane)
        start_sumo(_sumo_study_args(cfg, routes.path, work / "outputs.add.xml", fcd, seed))
        if kind == "external":
            ls.vehicletype.setTau(CACC_TYPES["external"], insertion_tau_s())
        set_human_variability(ls, cfg.human_sigma)
        sensors = Sensors.of(cfg.impairments, name)  # every run its own draws: by its name
        if cfg.impairments is not None and not cfg.impairments.perfect_channel \
                and hasattr(controller, "connect"):
            controller.connect(cfg.impairments, name)
        try:
            acc, heat, timing = _simulate(ls, cfg, kind, controller, routes.cacc_ids, lane_chain,
                                          sensors)
        finally:
            close_sumo()  # SUMO writes and closes its output files
        for output in sorted(work.glob("*.xml*")):  # whole, or the run is not kept (full disk)
            check_xml(output, f"SUMO's output {final / output.name}")
        metrics = _score(cfg, acc, outputs)
        metrics.update(timing)
        shutil.rmtree(final, ignore_errors=True)
        os.replace(work, final)
    except OSError as exc:
        shutil.rmtree(work, ignore_errors=True)
        raise output_error(exc, final) from None
    except BaseException:
        shutil.rmtree(work, ignore_errors=True)
        raise
    t_bins = heat[0].shape[0]
    extent = (cfg.warmup_s, cfg.warmup_s + t_bins * HEATMAP_BIN_S, 0.0, lane_chain.length_m)
    with np.errstate(invalid="ignore"):
        grid = np.where(heat[1] > 0, heat[0] / np.maximum(heat[1], 1), np.nan)
    return RunResult(penetration, seed, metrics, grid.tolist(), extent, str(final))


def _main_lanes(net: str) -> int:
    import sumolib

    return sumolib.net.readNet(str(net)).getEdge(MAIN_EDGE).getLaneNumber()


def _simulate(ls, cfg: StudyConfig, kind: str,
              controller: ChainController | PloegChains | None, cacc_ids: set[str],
              lane_chain, sensors: Sensors | None = None) -> tuple[_Accumulator, tuple, dict]:
    """The 0.1 s loop of one run: control, metrics, time-space map (``sensors``: the CACC
    vehicles measure their gaps and relative speeds with noise). Returns sums and timings.

    One function on purpose: it runs every 0.1 s for about a thousand vehicles, and its libsumo
    calls are bound to locals once, outside the loop."""
    vehicle = ls.vehicle
    get_speed, get_leader = vehicle.getSpeed, vehicle.getLeader
    sim_step, get_ids = ls.simulationStep, vehicle.getIDList
    departed_ids, get_collisions = ls.simulation.getDepartedIDList, ls.simulation.getCollisions
    n_steps = int(round((cfg.warmup_s + cfg.duration_s) / DT_S))
    first_measured = int(round(cfg.warmup_s / DT_S)) + 1
    lookahead = max(cfg.v2v_range_m, SENSOR_RANGE_M)
    external = kind == "external"
    plant = cfg.impairments.plant if cfg.impairments is not None else None
    seed = cfg.impairments.seed if cfg.impairments is not None else 0
    powertrains: dict = {}
    acc = _Accumulator()
    min_gap: dict[str, float] = {}
    prev_speed: dict[str, float] = {}
    prev_acc: dict[str, float] = {}
    n_t = int(math.ceil(cfg.duration_s / HEATMAP_BIN_S))
    n_x = int(math.ceil(lane_chain.length_m / HEATMAP_BIN_M))
    heat_sum, heat_n = np.zeros((n_t, n_x)), np.zeros((n_t, n_x))
    lane_ids = ls.lane.getLastStepVehicleIDs
    inv_dt = 1.0 / DT_S
    merging = merging_lanes(cfg.net)
    sumo_time, start = 0.0, time.perf_counter()
    for k in range(1, n_steps + 1):
        t0 = time.perf_counter()
        sim_step()
        sumo_time += time.perf_counter() - t0
        for vid in departed_ids():
            min_gap[vid] = vehicle.getMinGap(vid)
            if vid in cacc_ids:
                vehicle.setLaneChangeMode(vid, 0)
                if external:
                    vehicle.setSpeedMode(vid, SPEED_MODE_CACC)
                    if plant is not None:  # its class (vType) and powertrain, drawn by its ID
                        powertrains[vid] = plant.draw(1, vid, seed)
                        know_vehicle(controller, vid, float(powertrains[vid].a_max[0]),
                                     float(powertrains[vid].b_max[0]))
                        if powertrains[vid].vtypes[0] != CACC_TYPES["external"]:
                            vehicle.setType(vid, powertrains[vid].vtypes[0])
        measuring = k >= first_measured
        ids = get_ids()
        cidx = [i for i, v in enumerate(ids) if v in cacc_ids] if external or measuring else []
        speeds = list(map(get_speed, ids))
        speed_of = dict(zip(ids, speeds))
        prev_v = [prev_speed.get(v) for v in ids]
        accel = [(s - p) * inv_dt if p is not None else None for s, p in zip(speeds, prev_v)]
        if measuring:
            acc.collisions += len(get_collisions())
            ahead = [get_leader(v, lookahead) for v in ids]
            _measure(acc, ids, speeds, accel, ahead, speed_of, min_gap, prev_acc, inv_dt)
            if k % 10 == 0:
                _add_to_heatmap(vehicle, lane_ids, lane_chain, speed_of, heat_sum, heat_n,
                                min((k - first_measured) * DT_S // HEATMAP_BIN_S, n_t - 1))
        else:
            ahead = None
        prev_speed = speed_of
        prev_acc = {v: a for v, a in zip(ids, accel) if a is not None}
        if measuring:
            acc.cacc_samples += len(cidx)
        if external and cidx:
            _drive_cacc(ls, cfg, controller, sensors, [ids[i] for i in cidx],
                        [ahead[i] for i in cidx] if ahead is not None else None,
                        [speeds[i] for i in cidx], [accel[i] for i in cidx], speed_of, min_gap,
                        prev_acc, merging, acc if measuring else None, powertrains)
    wall = time.perf_counter() - start
    sim_s = n_steps * DT_S
    return acc, (heat_sum, heat_n), {"sim_speed": sim_s / wall, "sumo_share": sumo_time / wall,
                                     "wall_s": wall}


def _add_to_heatmap(vehicle, lane_ids, lane_chain, speed_of: dict[str, float],
                    heat_sum: np.ndarray, heat_n: np.ndarray, row: float) -> None:
    """Add the speeds (m/s) of the vehicles on the time-space map's lanes to time bin ``row``."""
    n_x = heat_sum.shape[1]
    for lane, x0 in zip(lane_chain.lanes, lane_chain.lane_starts):
        for vid in lane_ids(lane):
            col = min(int((x0 + vehicle.getLanePosition(vid)) // HEATMAP_BIN_M), n_x - 1)
            heat_sum[int(row), col] += speed_of[vid]
            heat_n[int(row), col] += 1


def _drive_cacc(ls, cfg: StudyConfig, controller: ChainController | PloegChains,
                sensors: Sensors | None, cids: list[str],
                cahead: list[tuple[str, float] | None] | None, speeds: list[float],
                accel: list[float | None], speed_of: dict[str, float], min_gap: dict[str, float],
                prev_acc: dict[str, float], merging: dict, acc: _Accumulator | None,
                powertrains: dict | None = None) -> None:
    """One step of carl-sumo's CACC vehicles ``cids``: what each sees ahead (zipper merges
    included), their chains, the controller's accelerations applied with setSpeed, through each
    vehicle's powertrain when the study has a plant (``powertrains`` by vehicle ID); ``acc``: add
    the chain statistics (None outside the measurement interval)."""
    vehicle = ls.vehicle
    lookahead = max(cfg.v2v_range_m, SENSOR_RANGE_M)
    if cahead is None:
        cahead = [vehicle.getLeader(v, lookahead) for v in cids]
    merge_m = zipper_aheads(ls, cids, cahead, merging, min_gap, lookahead)
    if hasattr(controller, "merge_behind"):  # a law with gs/gn reaches the merge point behind
        controller.merge_behind(merge_m)
    obs, chain_ahead = cacc_observations(cids, speeds, accel, cahead, speed_of, min_gap, lookahead)
    chains = form_chains(cids, chain_ahead, cfg.v2v_range_m)
    if sensors is not None:  # a track per vehicle and its current predecessor
        obs = sensors.measure(obs, cids, [None if c is None else c[0] for c in chain_ahead])
    accel_cmd = controller.acceleration(obs, chains, cids, chain_ahead, prev_acc)
    if powertrains:  # the commands through each vehicle's lag and dead time
        accel_cmd = np.array([powertrains[v].step(np.array([a]))[0]
                              for v, a in zip(cids, accel_cmd.tolist())])
    set_speed = vehicle.setSpeed
    for vid, v, a in zip(cids, obs[:, 0].tolist(), accel_cmd.tolist()):
        v += a * DT_S
        set_speed(vid, v if v > 0.0 else 0.0)
    if acc is not None:
        acc.chain_sum += len(cids)
        acc.chain_n += len(chains)
        acc.chain_max = max(acc.chain_max, max(len(c) for c in chains))


def _measure(acc: _Accumulator, ids, speeds, accel, ahead, speed_of, min_gap, prev_acc,
             inv_dt: float) -> None:
    """Add one step's samples of every vehicle to the accumulator."""
    n = len(ids)
    acc.samples += n
    acc.steps += 1
    acc.vehicles_sum += n
    acc.vehicles_max = max(acc.vehicles_max, n)
    for vid, v, a, item in zip(ids, speeds, accel, ahead):
        if a is not None:
            pa = prev_acc.get(vid)
            if pa is not None:
                acc.jerk_sum += abs(a - pa) * inv_dt
                acc.jerk_n += 1
        if item is None or item[0] == "":
            continue
        gap = item[1] + min_gap[vid]
        if gap <= FOLLOWING_GAP_M and v > HEADWAY_MIN_SPEED_MPS:
            acc.headway_sum += gap / v
            acc.headway_n += 1
        closing = v - speed_of[item[0]]
        if closing > 0.0 and gap > 0.0:
            ttc = gap / closing
            if ttc < 4.0:
                acc.ttc4 += 1
                if ttc < 1.5:
                    acc.ttc15 += 1


def _score(cfg: StudyConfig, acc: _Accumulator, outputs: dict[str, Path]) -> dict[str, float]:
    """The run's metrics from the accumulator and SUMO's detector, edge and emission outputs."""
    hours = cfg.duration_s / 3600.0
    counted = 0.0
    for interval in ET.parse(outputs["detectors"]).getroot().iter("interval"):
        if float(interval.get("begin")) >= cfg.warmup_s - 1e-6:
            counted += float(interval.get("nVehContrib"))
    distance_m = time_s = 0.0
    for edge in ET.parse(outputs["edgedata"]).getroot().iter("edge"):
        sampled = float(edge.get("sampledSeconds", 0.0))
        if sampled > 0:
            distance_m += float(edge.get("speed")) * sampled
            time_s += sampled
    co2_mg = fuel_mg = 0.0
    for edge in ET.parse(outputs["emissions"]).getroot().iter("edge"):
        co2_mg += float(edge.get("CO2_abs", 0.0))
        fuel_mg += float(edge.get("fuel_abs", 0.0))
    veh_hours = acc.samples * DT_S / 3600.0
    km = distance_m / 1000.0
    nan = float("nan")
    return {
        "throughput_vph": counted / hours,
        "speed_mps": distance_m / time_s if time_s > 0 else nan,
        "headway_s": acc.headway_sum / acc.headway_n if acc.headway_n else nan,
        "ttc_lt_4s_per_vh": acc.ttc4 / veh_hours if veh_hours > 0 else nan,
        "ttc_lt_1_5s_per_vh": acc.ttc15 / veh_hours if veh_hours > 0 else nan,
        "jerk_mps3": acc.jerk_sum / acc.jerk_n if acc.jerk_n else nan,
        "collisions": float(acc.collisions),
        "co2_g_per_km": co2_mg / 1000.0 / km if km > 0 else nan,
        "fuel_g_per_km": fuel_mg / 1000.0 / km if km > 0 else nan,
        "mean_vehicles": acc.vehicles_sum / acc.steps if acc.steps else 0.0,
        "max_vehicles": float(acc.vehicles_max),
        "cacc_share": acc.cacc_samples / acc.samples if acc.samples else 0.0,
        "mean_chain_length": acc.chain_sum / acc.chain_n if acc.chain_n else nan,
        "max_chain_length": float(acc.chain_max) if acc.chain_n else nan,
    }


# ----------------------------------------------------------------------------------- study
def _worker(cfg: StudyConfig, penetration: float, seed: int, out_dir: str) -> RunResult:
    return run_one(cfg, penetration, seed, Path(out_dir))


def run_study(cfg: StudyConfig, out_dir: Path, progress: bool | float = False
              ) -> list[RunResult]:
    """All (p, seed) runs, in ``cfg.workers`` spawned processes (one libsumo each); progress as
    :class:`carl_sumo.progress.Tracker` shows it."""
    resolve_study_controller(cfg.controller, cfg.plant_key)  # fails before any simulation starts
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    tasks = sorted(((p, s) for p in cfg.penetrations for s in cfg.seeds),
                   key=lambda t: (-t[0], t[1]))  # heaviest (most CACC vehicles) first
    workers = max(1, min(cfg.workers, len(tasks)))
    if workers == 1:
        from carl_sumo.scale.workers import worker_init

        worker_init()  # one torch thread: the batches are small, threads only contend
        results = [run_one(cfg, p, s, out_dir)
                   for p, s in track(tasks, len(tasks), "study", "run", progress)]
    else:
        from carl_sumo.scale.workers import run_parallel

        results = list(track(run_parallel(_worker, [(cfg, p, s, str(out_dir)) for p, s in tasks],
                                          workers, ordered=False,
                                          describe=lambda a: f"run {run_name(a[1], a[2])}"),
                             len(tasks), "study", "run", progress))
    return sorted(results, key=lambda r: (r.penetration, r.seed))


def write_outputs(cfg: StudyConfig, results: list[RunResult], out_dir: Path,
                  command: str = "", wall_s: float | None = None) -> list[Path]:
    """Write ``study.csv``, ``runs.csv``, ``study.md`` and the figures (each atomically)."""
    out_dir = Path(out_dir)
    rows = summarise(results)
    written = [write_csv(out_dir / "study.csv", rows),
               write_csv(out_dir / "runs.csv",
                          [{"penetration": r.penetration, "seed": r.seed, **r.metrics}
                           for r in results])]
    from carl_sumo.study.figures import plot_heatmap, plot_metrics

    written.append(plot_metrics(rows, out_dir / "metrics_vs_penetration.png", cfg.controller))
    rates = sorted({r.penetration for r in results})
    for p in {rates[0], rates[-1]}:
        first = min((r for r in results if r.penetration == p), key=lambda r: r.seed)
        written.append(plot_heatmap(first, out_dir / f"heatmap_p{p:g}.png", cfg.heatmap_lane))
    settings = {k: v for k, v in asdict(cfg).items() if k not in ("demand",)}
    text = ["# carl-sumo study", "", f"command: `{command}`" if command else "",
            f"wall time: {wall_s:.0f} s" if wall_s is not None else "",
            f"settings: {settings}", f"demand: {asdict(cfg.demand)}", "",
            markdown_table(rows), ""]
    written.append(write_text_atomic(out_dir / "study.md", "\n".join(t for t in text if t is not None)))
    return written


