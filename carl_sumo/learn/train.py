"""Training inside SUMO: rollouts in parallel libsumo workers, a replay buffer of joint platoon
transitions, DDPG/TD3-family updates, validation on held-out training events, atomic checkpoints.

``carl-sumo train`` calls :func:`train`. A step is one step of every environment at once (so
``num_envs`` platoon transitions). Validation runs the policy without exploration noise on held-out
training events; the best policy by :func:`selection_score` is the one written to ``--out``.
"""

from __future__ import annotations

import random
import shutil
import time
from dataclasses import asdict
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch

from carl_sumo import __version__
from carl_sumo.learn import imitation
from carl_sumo.learn.agents import Agent, AgentConfig, ColoredNoise
from carl_sumo.learn.calibration import Calibration, CriticProbe
from carl_sumo.learn.ca_scan import keep_heap_memory
from carl_sumo.learn.constraint import CostMultiplier
from carl_sumo.data.events import Event
from carl_sumo.control.controllers import adjustment_bounds
from carl_sumo.learn.env import PlatoonEnv
from carl_sumo.learn.imitation import target_adjustment
from carl_sumo.errors import InputError
from carl_sumo.sim.metrics import aggregate
from carl_sumo.learn.models import CommunicationAware
from carl_sumo.learn.policy import save_policy
from carl_sumo.learn.selection import (BaseOnly, Validation, ValidationHelper, improvement_z,
                                       selection_score)
from carl_sumo.control.channel import Impairments
from carl_sumo.learn.randomize import RandomisedChannels
from carl_sumo.learn.replay_buffer import ReplayBuffer
from carl_sumo.learn.checkpoint import (CHECKPOINT_FORMAT, read_checkpoint,  # noqa: F401
                                        candidate_dir, restore_checkpoint, save_candidate,
                                        save_checkpoint)
from carl_sumo.learn.recipe import stored_config
from carl_sumo.learn.train_config import (TrainConfig, held_out_split,  # noqa: F401
                                          split_validation, validation_conditions)
from carl_sumo.files import atomic_path
from carl_sumo.sim.sumo import check_fits

from carl_sumo.learn.curve import LOG_COLUMNS, LearningCurve  # noqa: F401
from carl_sumo.learn.report import Report
from carl_sumo.learn.trust import StableTrust
from carl_sumo.learn.curve import upgrade_log as _upgrade_log  # noqa: F401


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def _boundaries(agent: Agent) -> tuple[np.ndarray, np.ndarray] | None:
    """The CA actor's boundary messages (forward, backward), which a receiver's held message fades
    into past the timeout (carl_sumo.control.channel); None for an actor without messages."""
    actor = agent.actor
    if not isinstance(actor, CommunicationAware):
        return None
    return (actor.forward_boundary.detach().double().numpy(),
            actor.backward_boundary.detach().double().numpy())


def _metadata(cfg: TrainConfig, agent: Agent, val: dict[str, float], wall_s: float,
              baseline: dict[str, float] | None = None,
              val_events: Sequence[Event] = (), step: int | None = None) -> dict:
    """A policy file's metadata; ``step``: the vector step whose actor it holds (0: the start
    before any training step; an imitating run's clone: ``--learning-starts``)."""
    import libsumo

    return {"algo": cfg.algo, "step": step, "base": cfg.base, "trained_vehicles": cfg.n_vehicles,
            "seed": cfg.seed,
            "data": cfg.data, "split": cfg.split, "steps": cfg.steps,
            "observation": "[v m/s, a m/s^2, d m, dv m/s" + (
                ", a_base m/s^2]" if agent.cfg.residual else
                ", a_ahead m/s^2]" if agent.cfg.observe_ahead else "]"),
            "reward": asdict(cfg.reward), "comm_randomize": cfg.comm_randomize,
            "plant": "randomised per episode (--plant-randomize)" if cfg.plant_randomize
            else cfg.plant, "comm_off": cfg.comm_off,
            "randomize_sensors": cfg.randomize_sensors, "sensor_filter": cfg.sensor_filter,
            "impairments": asdict(fixed) if (fixed := cfg.fixed_impairments) else None,
            "val_impaired": cfg.val_impaired, "init": cfg.init,
            "validation": {k: float(v) for k, v in val.items()},
            "validation_base": {k: float(v) for k, v in (baseline or {}).items()},
            "validation_events": [e.event_id for e in val_events],
            "wall_time_s": float(wall_s),
            "command": cfg.command, "config": stored_config(cfg), "sumo_version": str(libsumo.getVersion()[1]),
            "carl_sumo_version": __version__, "torch_version": str(torch.__version__)}


def train(cfg: TrainConfig, events: Sequence[Event], resume: Path | None = None,
          progress: bool | float = True, log=print, rollouts: str = "processes",
          on_checkpoint=None, tensorboard: Path | None = None,
          stability_check=None) -> dict[str, Any]:
    """Train an agent into ``cfg.policy_path`` (checkpoints and a CSV log beside it); the loop
    (act, step, store, update, validate, keep, checkpoint) reads top to bottom, as in CleanRL.
    ``rollouts``: processes or ``"ray"`` actors; ``on_checkpoint(step)``: after each checkpoint;
    ``stability_check(policy) -> worst ‖Γ‖∞``: :mod:`carl_sumo.learn.trust`; returns metrics."""
    clock = WallClock()
    train_events, val_events = held_out_split(events, cfg)  # InputError before any file
    teacher, trust = _teacher(cfg), _trust(cfg, stability_check)  # InputError before any file
    init_actor = initial_actor(cfg)  # InputError before any file
    out = _prepare_out(Path(cfg.policy_path), resume)
    agent, channels, buffer, rng = _build(cfg, init_actor if resume is None else None)
    start_step, best, wall_before, saved = 0, -np.inf, 0.0, {}
    if resume is not None:
        buffer, start_step, best, wall_before = restore_checkpoint(resume, cfg, agent, rng, saved)
        if _keep_policy(resume, out, start_step, cfg, log):  # nothing left to train
            return dict(validation={}, validation_base={}, wall_time_s=wall_before, best_score=best)
    with clock("validation"):
        val_env, baseline, baseline_events, best = _start_validation(
            cfg, agent, init_actor, resume is None, train_events, val_events, out, log, best)
    report = Report(cfg, out, resume, start_step, progress, tensorboard)  # before any worker
    with clock("simulation"):
        vec, obs, history = _start_rollouts(cfg, train_events, rollouts, start_step, channels,
                                            saved)
    links = channels.receive(_boundaries(agent)) if channels is not None else None
    t0 = time.perf_counter()
    recent, val = [float(r) for r in saved.get("recent", ())], {}
    noise, lagrange, calibration = _schedules(cfg, agent, rng, saved)
    first_actor = _restore_start(cfg, agent, buffer, calibration, saved, start_step, log, trust)
    probe = _probe(cfg, buffer, calibration, log) if start_step > cfg.learning_starts else None
    try:
        for step in range(start_step, cfg.steps):
            if step == cfg.learning_starts:  # the start policy is complete: RL begins
                best, probe = _begin_rl(cfg, agent, teacher, buffer, rng, val_env, val_events,
                                        baseline, baseline_events, out, log, clock, calibration,
                                        best)
            # a warm-started actor drives from the first step, others after learning_starts
            acting = step >= cfg.learning_starts or init_actor is not None
            with clock("acting"):
                action = _choose_action(cfg, agent, obs, links, channels, noise, teacher,
                                        acting)
            with clock("simulation"):
                next_obs, reward, term, trunc, final, cost = vec.step(
                    action, channels.upcoming if channels is not None else None)
            with clock("acting"):
                links = _after_step(buffer, channels, agent, history, noise, recent, lagrange,
                                    step, obs, action, reward, final, term, trunc, links, cost)
            obs = next_obs
            with clock("updates"):
                report.updated(step, _update(cfg, agent, buffer, rng, step, lagrange,
                                             calibration.actor_from))
            done_steps = step + 1
            first_actor = _after_update(cfg, agent, buffer, calibration, probe, first_actor,
                                        done_steps, log, clock)
            if done_steps % cfg.eval_every == 0 or done_steps == cfg.steps:
                with clock("validation"):
                    val, best = _validate_step(cfg, agent, buffer, val_env, val_events, baseline,
                                               baseline_events, out, best, done_steps, report,
                                               probe, lagrange, recent,
                                               wall_before + time.perf_counter() - t0, trust)
            if done_steps % cfg.checkpoint_every == 0 or done_steps == cfg.steps:
                with clock("checkpoints"):
                    save_checkpoint(out.with_suffix(".ckpt"), cfg, agent, buffer, rng, done_steps,
                                    best, wall_before + time.perf_counter() - t0,
                                    _rollout_state(history, noise, recent, cfg.eval_every, lagrange)
                                    | _start_state(agent, calibration, first_actor, trust))
                _checkpoint_written(report, on_checkpoint, done_steps)
            report.advance()
    finally:
        with clock("simulation"):
            vec.close()
        val_env.close()
        report.close()
    training = _training_record(cfg, calibration, first_actor, clock, agent, trust)
    _record_training(out, training)
    log(clock.line())
    return {"validation": val, "validation_base": baseline, "best_score": best,
            "wall_time_s": wall_before + time.perf_counter() - t0, "training": training}





def _start_validation(cfg: TrainConfig, agent: Agent, init_actor, new_run: bool, train_events,
                      val_events, out: Path, log, best: float) -> tuple:
    """The validation environment, the base's validation (metrics and per event) and, for a new
    run, its first candidate (the start policy) kept; (env, baseline, its events, best)."""
    val_env = _validation_env(cfg, train_events, val_events)
    baseline, baseline_events = _validate_base(cfg, val_env, val_events, log)
    if new_run:
        best = _first_candidate(cfg, agent, init_actor, val_env, val_events, baseline,
                                baseline_events, out, log, best)
    return val_env, baseline, baseline_events, best


def _schedules(cfg: TrainConfig, agent: Agent, rng, saved: dict) -> tuple:
    """The exploration noise, the close-call multiplier and the critic's calibration of a run
    (restored from ``saved`` when it resumes)."""
    return (_noise(cfg, agent, rng, saved), _multiplier(cfg, saved),
            Calibration(cfg.critic_calibration, cfg.calibration_patience,
                        cfg.learning_starts + cfg.critic_burn_in))


def _checkpoint_written(report, on_checkpoint, done_steps: int) -> None:
    """Hand a written checkpoint to ``on_checkpoint`` (``sweep``: Ray Tune), the curve flushed."""
    if on_checkpoint is not None:
        report.flush()
        on_checkpoint(done_steps)

def _build(cfg: TrainConfig, init_actor) -> tuple:
    """The run's agent (started from ``init_actor`` when given), randomised channels, replay
    buffer and random generator."""
    _prepare_process(cfg.seed)
    agent = _new_agent(cfg, init_actor)
    channels = _randomised_channels(cfg, agent)
    buffer = ReplayBuffer(cfg.buffer_size, cfg.n_vehicles, agent.cfg.obs_dim,
                          channels.message_dim if channels is not None else 0)
    return agent, channels, buffer, np.random.default_rng(cfg.seed)


def _after_step(buffer: ReplayBuffer, channels, agent: Agent, history, noise, recent, lagrange,
                step: int, obs, action, reward, final, term, trunc, links, cost):
    """Store a vector step's transitions and keep what a resumed run needs; the next links."""
    if history is not None:  # what a resumed run replays its environments with
        history.append(np.asarray(action, dtype=np.float64))
    noise.reset(term | trunc)
    links = _store(buffer, channels, agent, obs, action, reward, final, term, trunc, links, cost)
    recent.append(float(reward.mean()))
    lagrange.observe(step, cost)
    return links


def _after_update(cfg: TrainConfig, agent: Agent, buffer: ReplayBuffer, calibration, probe,
                  first_actor: int | None, done_steps: int, log, clock) -> int | None:
    """Note RL's first actor update, and check the critic's calibration when it is due; the
    step of the first actor update (None before it)."""
    if first_actor is None and agent.actor_updates > 0:
        first_actor = done_steps
        log(f"RL's first actor update: step {done_steps}")
    if probe is not None and calibration.active and done_steps < calibration.actor_from \
            and (done_steps - cfg.learning_starts) % cfg.calibration_every == 0:
        with clock("validation"):  # only the check's own time counts as validation
            _calibration_check(calibration, probe, agent, buffer, done_steps, log)
    return first_actor

def _begin_rl(cfg: TrainConfig, agent: Agent, teacher, buffer: ReplayBuffer, rng, val_env,
              val_events, baseline, baseline_events, out: Path, log, clock, calibration, best):
    """At ``learning_starts``: the actor copies the teacher (if any), the critic's probe is set
    up and the actor is anchored at its start (``bc_alpha``); (best score, probe)."""
    if teacher is not None:
        with clock("updates"):
            best = _clone_teacher(cfg, agent, teacher, buffer, rng, val_env, val_events,
                                  baseline, baseline_events, out, log)
    probe = _probe(cfg, buffer, calibration, log)
    agent.anchor(cfg.bc_alpha)  # the start the actor is held near (0: none)
    return best, probe


def _validate_step(cfg: TrainConfig, agent: Agent, buffer: ReplayBuffer, val_env, val_events,
                   baseline, baseline_events, out: Path, best: float, done_steps: int, report,
                   probe, lagrange, recent: list[float], wall: float,
                   trust: StableTrust | None = None):
    """One validation: the candidate scored and kept if best, the curve's row written;
    (validation metrics, best score)."""
    train_reward = float(np.mean(recent[-cfg.eval_every:])) if recent else float("nan")
    val, best = _validate_and_select(cfg, agent, val_env, val_events, baseline, baseline_events,
                                     out, wall, best, done_steps, trust)
    logged = {"score": selection_score(val, cfg.select, baseline),
              **(probe.measure(agent, buffer) if probe is not None else {})}
    report.validation(done_steps, wall, train_reward, val | lagrange.logged() | logged)
    return val, best

class WallClock:
    """Where a run's wall time goes: seconds per part (simulation, acting, updates, validation,
    checkpoints) since the run (or its resumption) started, the rest as ``other``."""

    PARTS = ("simulation", "acting", "updates", "validation", "checkpoints")

    def __init__(self):
        self.t0 = time.perf_counter()
        self.seconds = {part: 0.0 for part in self.PARTS}

    def __call__(self, part: str):
        import contextlib

        @contextlib.contextmanager
        def timed():
            start = time.perf_counter()
            try:
                yield
            finally:
                self.seconds[part] += time.perf_counter() - start
        return timed()

    def totals(self) -> dict[str, float]:
        """Seconds per part, ``other`` and ``total``."""
        total = round(time.perf_counter() - self.t0, 1)
        parts = {k: round(v, 1) for k, v in self.seconds.items()}
        return {**parts, "other": round(total - sum(parts.values()), 1), "total": total}

    def line(self) -> str:
        t = self.totals()
        return (f"wall time {t['total']:.0f} s: " + ", ".join(
            f"{k} {t[k]:.0f} s" for k in (*self.PARTS, "other")))


def _probe(cfg: TrainConfig, buffer: ReplayBuffer, calibration: Calibration, log
           ) -> CriticProbe | None:
    """With ``--critic-holdout``: the held-out transitions of the start's data (rows stored by
    ``--learning-starts``), kept out of the critics' training from now on; None without."""
    if cfg.critic_holdout == 0:
        return None
    probe = CriticProbe.build(buffer, cfg.learning_starts * cfg.num_envs, cfg.num_envs,
                              cfg.gamma, cfg.critic_holdout)
    buffer.hold_out(probe.rows)
    log(f"critic hold-out: {len(probe.rows)} of the start's {cfg.learning_starts * cfg.num_envs}"
        " platoon transitions")
    if len(probe.rows) == 0 and calibration.active:
        calibration.criterion = "off"
        log("--critic-calibration: no held-out transition has the episode it needs after it "
            f"(episodes too short); the burn-in lasts --critic-burn-in {cfg.critic_burn_in} steps")
    return probe


def _calibration_check(calibration: Calibration, probe: CriticProbe, agent: Agent,
                       buffer: ReplayBuffer, done_steps: int, log) -> None:
    """One check of ``--critic-calibration``; says when the actor may move."""
    measured = probe.measure(agent, buffer)
    if calibration.check(done_steps, measured):
        log(f"critic calibrated at step {done_steps} (critic_td {measured['critic_td']:.4g}, "
            f"critic_rank {measured['critic_rank']:.3f}): the actor moves from here")


def _start_state(agent: Agent, calibration: Calibration, first_actor: int | None,
                 trust: StableTrust | None = None) -> dict:
    """What a checkpoint keeps of the RL start: the calibration's state, the step of the first
    actor update (-1: none yet), the actor the behaviour regulariser holds to and its α now
    (``--trust-string-stable`` moves both), and the trust region's record."""
    state = {"calibration": torch.tensor(calibration.state(), dtype=torch.float64),
             "first_actor": torch.tensor(-1 if first_actor is None else first_actor),
             "bc_alpha_now": torch.tensor(agent.bc_alpha, dtype=torch.float64)}
    if agent.start_actor is not None:
        state["start_actor"] = agent.start_actor.state_dict()
    if trust is not None:
        state["trust"] = torch.tensor(trust.state(), dtype=torch.int64)
        state["trust_shortened"] = torch.tensor(trust.shortened, dtype=torch.int64)
    return state


def _restore_start(cfg: TrainConfig, agent: Agent, buffer: ReplayBuffer,
                   calibration: Calibration, saved: dict, start_step: int, log,
                   trust: StableTrust | None = None) -> int | None:
    """A resumed run's RL start as its checkpoint left it (see :func:`_start_state`); the step
    of the first actor update (None: none yet)."""
    if saved.get("calibration") is not None:
        calibration.restore(saved["calibration"].tolist())
    if start_step > cfg.learning_starts:
        alpha = saved.get("bc_alpha_now")
        agent.anchor(cfg.bc_alpha if alpha is None else float(alpha), saved.get("start_actor"))
    if trust is not None and saved.get("trust") is not None:
        shortened = saved.get("trust_shortened")
        trust.restore(saved["trust"].tolist(), None if shortened is None else shortened.tolist())
    first = int(saved["first_actor"]) if saved.get("first_actor") is not None else -1
    return None if first < 0 else first


def _training_record(cfg: TrainConfig, calibration: Calibration, first_actor: int | None,
                     clock: WallClock, agent: Agent | None = None,
                     trust: StableTrust | None = None) -> dict:
    """What the run's policy files record of how it trained: the step of RL's first actor
    update, the critic burn-in's end and checks, the behaviour regulariser (and, with
    ``--trust-string-stable``, its rejections, accepted steps and final α) and the wall time's
    parts (s)."""
    record = {"first_actor_update_step": first_actor, "actor_from_step": calibration.actor_from,
              "critic_calibration": {"criterion": cfg.critic_calibration,
                                     "checks": [[s, v] for s, v in calibration.checks]},
              "bc_alpha": cfg.bc_alpha, "wall_s": clock.totals()}
    if trust is not None:
        record["trust_string_stable"] = {"rejected": trust.rejected,
                                         "accepted_steps": trust.accepted,
                                         "shortened_steps": trust.shortened,
                                         "final_bc_alpha": agent.bc_alpha}
    return record


def _record_training(out: Path, training: dict) -> None:
    """Write ``training`` into the metadata of the kept policy and of every candidate (the
    gate keeps one of them), which were written before the run knew it."""
    from carl_sumo.learn.policy import read_policy_payload, save_torch_atomic

    for path in [out, *sorted(candidate_dir(out).glob("step*.pt"))]:
        if not path.is_file():
            continue
        payload = read_policy_payload(path)
        payload["metadata"]["training"] = training
        save_torch_atomic(payload, path)


def _start_rollouts(cfg: TrainConfig, train_events: Sequence[Event], rollouts: str,
                    start_step: int, channels: RandomisedChannels | None, saved: dict):
    """(environments, their observations, the actions sent to them so far or None when not
    recorded). A resumed run whose checkpoint holds every action sent (a run without randomised
    channels) replays them from the run's first reset, which puts every environment exactly where
    the stopped run had it; other resumed runs start new episodes (seeded by the step)."""
    from carl_sumo.learn.vec_env import RayVecPlatoon, VecPlatoon

    actions = saved.get("actions")
    replay = channels is None and actions is not None and len(actions) == start_step
    seed = cfg.seed if replay or start_step == 0 else cfg.seed + start_step
    vec_class = RayVecPlatoon if rollouts == "ray" else VecPlatoon
    vec = vec_class(train_events, cfg.n_vehicles, cfg.net, cfg.num_envs, seed, cfg.reward,
                    cfg.base, cfg.observe_ahead, adjustment_bounds(cfg.adj_max), cfg.shield_ttc,
                    cfg.command_history)
    try:
        obs = vec.reset(seed, channels.current if channels is not None else None)
        for action in actions.numpy() if replay else ():
            obs = vec.step(action)[0]
    except BaseException:
        vec.close()
        raise
    if replay:
        return vec, obs, list(actions.numpy())
    return vec, obs, [] if channels is None and start_step == 0 else None


def _noise(cfg: TrainConfig, agent: Agent, rng: np.random.Generator, saved: dict
           ) -> ColoredNoise:
    """The exploration noise: new, or a resumed run's as it was at its checkpoint, with the
    random generators as the checkpoint left them (whatever ran since the restore drew)."""
    noise = ColoredNoise((cfg.num_envs, cfg.n_vehicles),
                         agent.cfg.exploration_noise * agent.cfg.adj_max,
                         agent.cfg.noise_correlation, rng)
    if saved.get("noise") is not None:
        noise.value = saved["noise"].numpy().copy()
        rng.bit_generator.state = saved["numpy_rng"]
        torch.set_rng_state(saved["torch_rng"])
    return noise


def _rollout_state(history: list[np.ndarray] | None, noise: ColoredNoise, recent: list[float],
                   eval_every: int, lagrange: CostMultiplier) -> dict[str, torch.Tensor]:
    """The rollouts' state a checkpoint stores (see :func:`_start_rollouts`) and the safety
    constraint's multiplier."""
    state = {"noise": torch.from_numpy(noise.value.copy()),
             "recent": torch.tensor(recent[-eval_every:], dtype=torch.float64),
             "lagrange": torch.tensor(list(lagrange.state().values()), dtype=torch.float64)}
    if history:
        state["actions"] = torch.from_numpy(np.stack(history))
    return state


def _keep_policy(resume: Path, out: Path, start_step: int, cfg: TrainConfig, log) -> bool:
    """A resumed run has its policy file at ``out`` from the start: where ``out`` is new, the
    kept policy of the run that wrote the checkpoint (its ``--out``) is copied there, or, where
    that file is gone, the checkpoint's actor is written. True (and says so) when the checkpoint
    is at ``--steps`` already: nothing is left to train."""
    log(f"resumed {resume} at step {start_step}")
    done = start_step >= cfg.steps
    if done:
        log(f"{resume} is at step {start_step} already (--steps {cfg.steps}): nothing to train")
    if out.exists():
        return done
    kept = Path(read_checkpoint(resume)["train_config"]["out"])
    if kept.is_file() and kept.resolve() != out.resolve():
        with atomic_path(out) as tmp:
            shutil.copyfile(kept, tmp)
        log(f"copied the run's kept policy {kept} to {out}")
    else:
        export_policy(resume, out)
        log(f"wrote the checkpoint's actor to {out} (the run's kept policy {kept} is missing)")
    return done


def _validation_env(cfg: TrainConfig, train_events: Sequence[Event], val_events: Sequence[Event]
                    ) -> Validation:
    """Where validation runs: an environment in this process and ``val_workers`` - 1 helpers;
    InputError here, not in a worker, when a training event does not fit the network."""
    kwargs = dict(events=list(val_events), n_followers=cfg.n_vehicles, net_path=cfg.net,
                  reward=cfg.reward, base=cfg.base, bounds=adjustment_bounds(cfg.adj_max),
                  observe_ahead=cfg.observe_ahead, shield_ttc_s=cfg.shield_ttc,
                  command_history=cfg.command_history)
    val_env = PlatoonEnv(**kwargs)
    for event in train_events:
        check_fits(val_env.sim.route, event, cfg.n_vehicles)
    return Validation(val_env, [ValidationHelper(kwargs) for _ in range(cfg.val_workers - 1)])


def _store(buffer: ReplayBuffer, channels: RandomisedChannels | None, agent: Agent,
           obs: np.ndarray, action: np.ndarray, reward: np.ndarray, final: np.ndarray,
           term: np.ndarray, trunc: np.ndarray, links, cost: np.ndarray):
    """Store one vector step's transitions with the links heard at o and at o'; returns the
    links of the next step (a new episode's where one ended, else this step's preview)."""
    fallbacks = _boundaries(agent) if channels is not None else None
    next_links = channels.receive(fallbacks) if channels is not None else None  # at o'
    buffer.add(obs, action, reward, final, term.astype(np.float32), links, next_links, cost)
    if channels is None:
        return links
    channels.episodes_ended(term | trunc)
    return channels.receive(fallbacks) if (term | trunc).any() else next_links


def _validate_and_select(cfg: TrainConfig, agent: Agent, val_env: Validation,
                         val_events: Sequence[Event], baseline: dict[str, float],
                         baseline_events: list[dict], out: Path, wall_s: float, best: float,
                         step: int, trust: StableTrust | None = None
                         ) -> tuple[dict[str, float], float]:
    """Validate the actor; write it to ``out`` when it scores better than ``best`` (and, with
    ``--gate-string-stable``, every trained one to the candidates). With ``trust`` the actor's
    ‖Γ‖∞ is checked next (``worst_hinf`` in the metrics): an amplifying actor is never kept
    and goes back to its anchor, or with ``--trust-backtrack`` to the first string-stable point
    on the way there, which is validated in its place (its metrics returned, with ``kappa``,
    ``raw_score`` and ``raw_worst_hinf``: :mod:`carl_sumo.learn.trust`). Returns the
    validation metrics and the best score so far."""
    val = _validate(cfg, agent, val_env, val_events, baseline_events)
    score = selection_score(val, cfg.select, baseline)
    meta = _metadata(cfg, agent, val, wall_s, baseline, val_events, step)
    if agent.updates > 0:
        save_candidate(cfg, agent, out, step, meta)
    stable = True
    if trust is not None and agent.actor_updates > 0:
        candidate = candidate_dir(out) / f"step{step:06d}.pt"
        point = candidate_dir(out) / "backtrack.pt"  # (not a step*.pt: no candidate)

        def rewrite() -> Path:  # a backtracked point
            save_policy(agent, point, meta)
            return point

        hinf, kappa, there = trust.judge(agent, candidate, step, score > best, rewrite)
        point.unlink(missing_ok=True)
        val["worst_hinf"] = hinf
        moved = 0.0 < kappa < 1.0
        if moved:  # backtracked to a string-stable point: validate it there
            raw = {"raw_score": score, "raw_worst_hinf": hinf}
            val = _validate(cfg, agent, val_env, val_events, baseline_events)
            score = selection_score(val, cfg.select, baseline)
            val |= raw | {"kappa": kappa, "worst_hinf": there}
            meta = _metadata(cfg, agent, val, wall_s, baseline, val_events, step)
            if score > best:
                trust.accept(agent, step)
        stable = bool(there <= 1.0)  # (nan: sent back to the anchor)
        meta["string_stability_gate"] = {
            "plant": cfg.gate_string_stable, "worst_hinf": val["worst_hinf"], "kappa": kappa,
            "candidate": f"step{step:06d}.pt", "checked": "as validated (--trust-string-stable)"}
        if moved:  # the point kept is the candidate; the amplifying actor a record
            candidate.replace(candidate.with_name(f"amplifying_{candidate.name}"))
            save_candidate(cfg, agent, out, step, meta)
    # only a trained actor can be the best; the first validation is a fallback
    if agent.updates > 0 and stable and score > best or not np.isfinite(best):
        best = score if agent.updates > 0 else -np.inf
        save_policy(agent, out, meta)  # (a stable actor: the one validated, not reverted)
    return val, best


def _prepare_out(out: Path, resume: Path | None) -> Path:
    """``out`` with its folder made; a fresh run drops the gate's candidates of an earlier run
    that wrote the same file."""
    out.parent.mkdir(parents=True, exist_ok=True)
    if resume is None:
        shutil.rmtree(candidate_dir(out), ignore_errors=True)
    return out


def _prepare_process(seed: int) -> None:
    """One torch thread (the SUMO workers have the other cores; small nets gain nothing), no page
    faults on the update's temporaries, and every random generator seeded."""
    torch.set_num_threads(1)
    keep_heap_memory()
    seed_everything(seed)


def _new_agent(cfg: TrainConfig, init_actor: dict | None) -> Agent:
    """The run's agent, its actor warm-started from ``init_actor`` when given."""
    agent = Agent(cfg.agent_config())
    if init_actor is not None:
        try:
            agent.start_from(init_actor)
        except RuntimeError:
            raise InputError(f"--init {cfg.init}: its actor does not fit this run's network "
                             "(--message-dim, --hidden); give a policy trained with the same "
                             "ones") from None
    return agent


def _randomised_channels(cfg: TrainConfig, agent: Agent) -> RandomisedChannels | None:
    """The impaired V2V links, sensors and plants of the training episodes (``--comm-randomize``,
    fixed impairments, ``--plant-randomize``; ``--comm-off`` cuts the CA messages), or None for
    a perfect channel on the ideal plant."""
    fixed = cfg.fixed_impairments
    if not (cfg.comm_randomize or fixed is not None or cfg.comm_off or cfg.plant_randomize):
        return None
    if fixed is None and not cfg.comm_randomize:  # CA-off or random plants alone
        fixed = Impairments()
    return RandomisedChannels(cfg.num_envs, cfg.n_vehicles, cfg.message_dim if
                              agent.cfg.communication_aware else 0, cfg.seed,
                              cfg.randomize_sensors, fixed, cfg.sensor_filter, cfg.comm_off,
                              cfg.plant_randomize)


def _validate_base(cfg: TrainConfig, val_env: Validation, val_events: Sequence[Event], log
                   ) -> tuple[dict[str, float], list[dict]]:
    """The base model alone on the validation events: the metrics every candidate is compared
    with, and its per-event results."""
    base_reward, baseline_events = val_env.run(BaseOnly(), val_events,
                                               validation_conditions(cfg))  # same events
    baseline = {"val_reward": base_reward, **aggregate(baseline_events)}
    log(f"validation baseline ({cfg.base}): "
        + ", ".join(f"{k}={v:.3f}" for k, v in baseline.items()))
    return baseline, baseline_events


def _first_candidate(cfg: TrainConfig, agent: Agent, init_actor: dict | None,
                     val_env: Validation, val_events: Sequence[Event],
                     baseline: dict[str, float], baseline_events: list[dict], out: Path, log,
                     best: float) -> float:
    """Write the policy to beat before any training and return its selection score: the warm
    start (``--init``), or for a residual actor its base exactly (a_adj = 0); kept unless a
    trained checkpoint scores better on validation. Other runs keep ``best``."""
    if init_actor is not None:
        best, start = _validate_and_keep(cfg, agent, val_env, val_events, baseline,
                                         baseline_events, out)
        log(f"validation of --init {cfg.init}: "
            + ", ".join(f"{k}={v:.3f}" for k, v in start.items()))
    elif agent.cfg.residual:
        start = {**baseline, **improvement_z(baseline_events, baseline_events)}
        best = selection_score(start, cfg.select, baseline)
        meta = _metadata(cfg, agent, start, 0.0, baseline, val_events, 0)
        save_policy(agent, out, meta)
        save_candidate(cfg, agent, out, 0, meta)
    return best


def _choose_action(cfg: TrainConfig, agent: Agent, obs: np.ndarray, links, channels,
                   noise: ColoredNoise, teacher, acting: bool) -> np.ndarray:
    """a_adj of every vehicle of every environment (num_envs, n): the actor with exploration
    noise when ``acting``, else the base (or the teacher) plus noise. The CA actor's messages
    cross impaired ``links`` and are sent on ``channels`` even while it is not acting."""
    if links is not None:  # the CA actor's messages cross impaired links
        action, sent_f, sent_b = agent.act_over(obs, links, noise.sample() if acting else None)
        channels.send(sent_f, sent_b)
    if not acting:  # the base (or the teacher) plus exploration noise
        action = noise.sample()
        if teacher is not None:
            action = action + target_adjustment(teacher, obs, agent.cfg.adj_max,
                                                cfg.observe_ahead, cfg.base, cfg.imitate_target)
        action = np.clip(action, -agent.cfg.adj_max, agent.cfg.adj_max)
    elif links is None:
        action = agent.act(obs, noise.sample())
    return action


def _multiplier(cfg: TrainConfig, saved: dict) -> CostMultiplier:
    """The safety constraint's λ (``--lagrange-lr``), from a resumed run's checkpoint."""
    state = saved.get("lagrange")
    keys = ("value", "target", "sum", "count")
    return CostMultiplier(cfg.lagrange_lr, cfg.learning_starts,
                          None if state is None else dict(zip(keys, state.tolist())))


def _update(cfg: TrainConfig, agent: Agent, buffer: ReplayBuffer, rng: np.random.Generator,
            step: int, lagrange: CostMultiplier, actor_from: int) -> dict[str, float] | None:
    """The gradient updates after vector step ``step``: every ``update_every`` steps from
    ``learning_starts`` on, the critics alone before step ``actor_from`` (the critic burn-in),
    on the reward less λ·cost (:mod:`carl_sumo.learn.constraint`); the last update's
    statistics (None without an update)."""
    if step < cfg.learning_starts or (step - cfg.learning_starts) % cfg.update_every != 0:
        return None
    train_actor = step >= actor_from
    if cfg.lr_decay:
        agent.scale_learning_rates(1.0 - (step - cfg.learning_starts)
                                   / max(1, cfg.steps - cfg.learning_starts))
    stats = None
    for _ in range(cfg.updates_per_step):
        stats = agent.update(lagrange.penalise(buffer.sample(agent.cfg.batch_size, rng)),
                             train_actor)
    return stats


def _validate(cfg: TrainConfig, agent: Agent, val_env: Validation, val_events: Sequence[Event],
              baseline_events: list[dict]) -> dict[str, float]:
    """The actor without exploration noise on the validation events: reward, metrics and its
    improvement over the base."""
    val_reward, per_event = val_env.run(agent, val_events, validation_conditions(cfg))
    return {"val_reward": val_reward, **aggregate(per_event),
            **improvement_z(per_event, baseline_events)}


def _trust(cfg: TrainConfig, stability_check) -> StableTrust | None:
    """The trust region of ``--trust-string-stable`` (None without it); InputError when the
    caller gave no string-stability check to run it with."""
    if not cfg.trust_string_stable:
        return None
    if stability_check is None:
        raise InputError("--trust-string-stable needs the string-stability check that "
                         "`carl-sumo train` gives it; run it from the command line")
    return StableTrust(stability_check, backtrack=cfg.trust_backtrack)


def _teacher(cfg: TrainConfig):
    """The controller a run imitates (None without ``--imitate``); InputError when it cannot."""
    if cfg.imitate is None:
        return None
    imitation.check_teacher_base(cfg.imitate, cfg.base)
    if cfg.learning_starts < 1:
        raise InputError("--imitate needs --learning-starts steps of teacher driving to copy")
    return imitation.teacher(cfg.imitate)


def _clone_teacher(cfg: TrainConfig, agent: Agent, teacher, buffer: ReplayBuffer,
                   rng: np.random.Generator, val_env: Validation, val_events: Sequence[Event],
                   baseline: dict[str, float], baseline_events: list[dict], out: Path,
                   log) -> float:
    """Fit the actor to the teacher on every stored state, validate it and keep it as the first
    candidate; returns its selection score (see :mod:`carl_sumo.learn.imitation`)."""
    obs, target = imitation.dataset(teacher, buffer.obs[:buffer.size], agent.cfg.adj_max,
                                    cfg.observe_ahead, cfg.base, cfg.imitate_target)
    mse = agent.imitate(obs, target, cfg.imitate_updates, cfg.imitate_lr, 256, rng)
    score, val = _validate_and_keep(cfg, agent, val_env, val_events, baseline, baseline_events,
                                    out)
    log(f"imitated {cfg.imitate} on {len(obs)} platoon states (mse {mse:.4f} m²/s⁴): "
        + ", ".join(f"{k}={v:.3f}" for k, v in val.items()))
    return score


def _validate_and_keep(cfg: TrainConfig, agent: Agent, val_env: Validation,
                       val_events: Sequence[Event], baseline: dict[str, float],
                       baseline_events: list[dict], out: Path) -> tuple[float, dict[str, float]]:
    """Validate the actor as it is, write it as the run's first candidate; its selection score
    and validation metrics."""
    val = _validate(cfg, agent, val_env, val_events, baseline_events)
    step = 0 if cfg.init is not None else cfg.learning_starts
    meta = _metadata(cfg, agent, val, 0.0, baseline, val_events, step)
    save_policy(agent, out, meta)
    save_candidate(cfg, agent, out, step, meta)
    return selection_score(val, cfg.select, baseline), val


def initial_actor(cfg: TrainConfig) -> dict | None:
    """The actor weights of ``--init`` (None without it); InputError when the file is not a
    policy of this run's algorithm, base and observation."""
    if cfg.init is None:
        return None
    from carl_sumo.learn.policy import read_policy_payload

    payload = read_policy_payload(Path(cfg.init))
    theirs = AgentConfig(**payload["agent_config"])  # older files: the defaults they had
    ours = {"algo": cfg.algo, "base": cfg.base, "observe_ahead": cfg.observe_ahead,
            "adj_max": cfg.adj_max}
    differ = [f"{k} {getattr(theirs, k)!r}" for k, v in ours.items() if getattr(theirs, k) != v]
    if differ:
        raise InputError(f"--init {cfg.init} is a policy of another configuration "
                         f"({', '.join(differ)}); give one trained with this run's --algo, "
                         "--base, --observe-ahead and --adj-max")
    return payload["actor"]


def export_policy(checkpoint: Path, out: Path) -> dict[str, Any]:
    """Write the current actor of a training checkpoint as a policy file; its metadata."""
    state = read_checkpoint(checkpoint)
    cfg = TrainConfig(**state["train_config"])
    agent = Agent(cfg.agent_config())
    agent.load_state_dict(state["agent"])
    meta = _metadata(cfg, agent, {}, float(state["wall_s"]))
    meta["exported_from"] = f"{Path(checkpoint).name} at step {int(state['step'])}"
    save_policy(agent, Path(out), meta)
    return meta
