"""``carl-sumo bench``: controlled env steps/s beside a bare libsumo loop, as a ratio from one run.

The bare loop does the same libsumo reads and writes per step as :class:`PlatoonSim` (per
follower: setSpeed, getSpeed, getDistance; for the leader: setSpeed, moveTo, setPreviousSpeed;
one simulationStep) with constant speeds and no other work. The env step adds the IDM base, the
controller's adjustment (zero), the observation and the reward. Both run the same scenario (a
leader cruising at 15 m/s, 20 m gaps), alternating in rounds so machine noise hits both alike.
"""

from __future__ import annotations

import time

import numpy as np

from carl_sumo.config import DT_S
from carl_sumo.data.events import Event
from carl_sumo.learn.env import PlatoonEnv
from carl_sumo.sim.sumo import DEFAULT_NET
from carl_sumo.sim.vehicle import Plant


def cruise_event(n_steps: int, speed_mps: float = 15.0, gap_m: float = 20.0) -> Event:
    """A leader at constant speed, followers starting at ``gap_m``: the benchmark scenario."""
    speed = np.full(n_steps + 1, speed_mps)
    pos = np.arange(n_steps + 1) * speed_mps * DT_S
    return Event("bench_cruise", "carl_sumo_bench", "bench", pos, speed, 5.0, speed.copy(),
                 np.full(n_steps + 1, gap_m))


def _bare_loop(env: PlatoonEnv, steps: int) -> float:
    """Seconds for ``steps`` bare libsumo steps with the env's reads and writes."""
    import libsumo

    sim = env.sim
    env.reset_array(event=env.events[0])
    ids, leader = sim.ids, sim.leader_id
    lanes, lane_pos, lead_speed = sim._leader_lane, sim._leader_lane_pos, sim._leader_speed
    set_speed, get_speed = libsumo.vehicle.setSpeed, libsumo.vehicle.getSpeed
    get_distance, move_to = libsumo.vehicle.getDistance, libsumo.vehicle.moveTo
    set_previous_speed, sim_step = libsumo.vehicle.setPreviousSpeed, libsumo.simulationStep
    speed = lead_speed[0]
    start = time.perf_counter()
    for k in range(1, steps + 1):
        for vid in ids:
            set_speed(vid, speed)
        set_speed(leader, lead_speed[k])
        sim_step()
        move_to(leader, lanes[k], lane_pos[k])
        set_previous_speed(leader, lead_speed[k])
        [get_speed(vid) for vid in ids]
        [get_distance(vid) for vid in ids]
    return time.perf_counter() - start


def _env_loop(env: PlatoonEnv, steps: int) -> float:
    """Seconds for ``steps`` env steps (zero adjustment) on the same scenario."""
    env.reset_array(event=env.events[0])
    zeros = np.zeros(env.n_followers)
    start = time.perf_counter()
    for _ in range(steps):
        env.step_array(zeros)
    return time.perf_counter() - start


def run_bench(sizes: tuple[int, ...] = (10, 20, 100), steps: int = 2000, rounds: int = 3,
              net_path=DEFAULT_NET, plant: Plant | None = None) -> list[dict[str, float]]:
    """Steps/s of the env and of the bare loop for each platoon size; best of ``rounds``. With
    a ``plant`` also the env on it (lag and dead time), in the same rounds: ``plant_ratio`` is
    its step time over the ideal plant's."""
    rows = []
    for n in sizes:
        env = PlatoonEnv([cruise_event(steps + 1)], n, net_path)
        real = PlatoonEnv([cruise_event(steps + 1)], n, net_path, plant=plant) \
            if plant is not None else None
        _env_loop(env, min(50, steps))  # compile the numba kernels and warm caches
        bare, controlled, on_plant = [], [], []
        for _ in range(rounds):
            bare.append(_bare_loop(env, steps))
            controlled.append(_env_loop(env, steps))
            if real is not None:
                on_plant.append(_env_loop(real, steps))
        bare_rate, env_rate = steps / min(bare), steps / min(controlled)
        row = {"followers": n, "env_steps_per_s": env_rate, "bare_steps_per_s": bare_rate,
               "ratio": bare_rate / env_rate}
        if on_plant:
            row.update({"plant_steps_per_s": steps / min(on_plant),
                        "plant_ratio": min(on_plant) / min(controlled)})
        rows.append(row)
    return rows


def format_bench(rows: list[dict[str, float]]) -> str:
    lines = ["followers  env steps/s  bare steps/s  env cost / bare cost",
             "---------  -----------  ------------  ---------------------"]
    for r in rows:
        lines.append(f"{r['followers']:>9}  {r['env_steps_per_s']:>11.0f}  "
                     f"{r['bare_steps_per_s']:>12.0f}  {r['ratio']:>20.2f}x")
    if any("plant_ratio" in r for r in rows):
        lines += ["", "followers  env on the plant steps/s  plant step time / ideal step time",
                  "---------  -----------------------  ---------------------------------"]
        lines += [f"{r['followers']:>9}  {r['plant_steps_per_s']:>23.0f}  "
                  f"{r['plant_ratio']:>32.3f}x" for r in rows]
    return "\n".join(lines)


def run_training_bench(algo: str = "ca-td3", sizes: tuple[int, ...] = (10, 20), num_envs: int = 2,
                       steps: int = 500, net_path=DEFAULT_NET, smooth_jerk: float = 0.0,
                       smooth_accel: float = 0.0, update_every: int = 1,
                       batch_size: int = 128) -> list[dict[str, float]]:
    """Training throughput per platoon size: env steps/s in the parallel SUMO workers with
    batched policy inference, without and with one gradient update (of ``batch_size``
    transitions) every ``update_every`` vector steps (with the actor smoothness terms of training
    when given), and the mean time of one update (sampling the batch included, ms)."""
    return [_training_rates(algo, n, num_envs, steps, net_path, smooth_jerk, smooth_accel,
                            update_every, batch_size) for n in sizes]


def _training_rates(algo: str, n: int, num_envs: int, steps: int, net_path, smooth_jerk: float,
                    smooth_accel: float, update_every: int = 1, batch_size: int = 128
                    ) -> dict[str, float]:
    import torch

    from carl_sumo.learn.agents import Agent, AgentConfig, ColoredNoise
    from carl_sumo.learn.train import ReplayBuffer
    from carl_sumo.learn.vec_env import VecPlatoon

    torch.set_num_threads(1)  # as in training: the SUMO workers have the other core
    try:  # as in training (older code, measured by benchmarks/training_bench_against.py, lacks it)
        from carl_sumo.learn.ca_scan import keep_heap_memory
        keep_heap_memory()
    except ImportError:
        pass
    agent = Agent(AgentConfig(algo=algo, n_vehicles=n, smooth_jerk=smooth_jerk,
                              smooth_accel=smooth_accel, batch_size=batch_size))
    buffer = ReplayBuffer(50_000, n)
    rng = np.random.default_rng(0)
    vec = VecPlatoon([cruise_event(400)], n, net_path, num_envs, seed=0)
    noise = ColoredNoise((num_envs, n), 0.45, 0.98, rng)
    row: dict[str, float] = {"algo": algo, "followers": n, "envs": num_envs,
                             "update_every": update_every, "batch_size": batch_size}
    try:
        obs = vec.reset(0)
        for phase in ("warm-up", "none", "updates"):
            updates = phase != "none"
            update_s, start = 0.0, time.perf_counter()
            n_updates = 0
            for k in range(min(steps, 20) if phase == "warm-up" else steps):
                action = agent.act(obs, noise.sample())
                next_obs, reward, term, _, final, _ = vec.step(action)
                buffer.add(obs, action, reward, final, term.astype(np.float32))
                obs = next_obs
                if updates and k % update_every == 0:
                    t0 = time.perf_counter()
                    agent.update(buffer.sample(agent.cfg.batch_size, rng))
                    update_s += time.perf_counter() - t0
                    n_updates += 1
            wall = time.perf_counter() - start
            if phase == "none":
                row["env_steps_per_s"] = steps * num_envs / wall
            elif phase == "updates":
                row["env_steps_per_s_updates"] = steps * num_envs / wall
                row["update_ms"] = 1000.0 * update_s / max(n_updates, 1)
    finally:
        vec.close()
    return row


def format_training_bench(rows: list[dict[str, float]]) -> str:
    lines = ["algo     followers  envs  env steps/s, no updates  env steps/s, with updates"
             "  update every  batch  update (ms)",
             "-------  ---------  ----  -----------------------  --------------------------"
             "  ------------  -----  -----------"]
    for r in rows:
        lines.append(f"{r['algo']:<7}  {r['followers']:>9}  {r['envs']:>4}  "
                     f"{r['env_steps_per_s']:>23.0f}  {r['env_steps_per_s_updates']:>26.0f}"
                     f"  {r.get('update_every', 1):>12}  {r.get('batch_size', 128):>5}"
                     f"  {r['update_ms']:>11.2f}")
    return "\n".join(lines)
