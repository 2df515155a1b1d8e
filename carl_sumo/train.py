"""Training inside SUMO: rollouts in parallel libsumo workers, a replay buffer of joint platoon
transitions, DDPG/TD3-family updates, validation on held-out training events, atomic checkpoints.

``carl-sumo train`` calls :func:`train`. A step is one step of every environment at once (so
``num_envs`` platoon transitions). Validation runs the policy without exploration noise on held-out
training events; the best policy by :func:`selection_score` is the one written to ``--out``.
"""

from __future__ import annotations

import csv
import io
import random
import sys
import time
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch

from carl_sumo import __version__, imitation
from carl_sumo.agents import Agent, AgentConfig, ColoredNoise
from carl_sumo.ca_scan import keep_heap_memory
from carl_sumo.channel import Impairments
from carl_sumo.config import REWARD, RewardConfig
from carl_sumo.data.events import Event
from carl_sumo.controllers import adjustment_bounds
from carl_sumo.env import PlatoonEnv
from carl_sumo.imitation import teacher_adjustment
from carl_sumo.errors import InputError
from carl_sumo.metrics import aggregate
from carl_sumo.models import CommunicationAware
from carl_sumo.policy import load_torch, save_policy, save_torch_atomic
from carl_sumo.selection import (MARGIN_KEYS, VALIDATION_IMPAIRMENTS, BaseOnly, improvement_z,
                                 selection_score, validate_events)
from carl_sumo.randomize import RandomisedChannels
from carl_sumo.replay import ReplayBuffer
from carl_sumo.files import write_text_atomic
from carl_sumo.sumo import DEFAULT_NET, check_fits

CHECKPOINT_FORMAT = "carl-sumo-checkpoint"


@dataclass
class TrainConfig:
    """What ``carl-sumo train`` was asked to do."""

    algo: str = "ca-td3"
    n_vehicles: int = 10
    steps: int = 20_000            # vector steps (each steps every environment once)
    seed: int = 0
    num_envs: int = 2
    learning_starts: int = 1_000   # vector steps of pure exploration noise before updates
    critic_burn_in: int = 0        # vector steps after learning_starts that train the critics only
    updates_per_step: int = 1
    update_every: int = 1          # vector steps between update rounds (1: every step)
    scale_rates: bool = False      # learning rates and tau times update_every (agent_config)
    lr_decay: bool = False         # learning rates fall linearly to 0 from learning_starts to steps
    batch_size: int = AgentConfig.batch_size  # transitions per gradient update
    buffer_size: int = 200_000     # platoon transitions
    eval_every: int = 2_000        # vector steps between validations
    eval_events: int = 8           # held-out training events used for validation
    val_seed: int | None = None    # seed choosing those events (None: the training seed)
    val_source: str | None = None  # draw them from this event source only (None: any)
    braking_events: int = 0        # synthetic hard-braking leaders added (a quarter validates)
    warmup: float = 0.0            # s of settling before every event (Event.with_warmup)
    checkpoint_every: int = 5_000  # vector steps between checkpoints
    net: str = str(DEFAULT_NET)
    data: str = "default"
    split: str = "train"
    out: str = "policies/ca_td3.pt"
    command: str = ""
    w_gap: float = REWARD.w_gap            # reward weights (defaults: carl_sumo.config)
    w_safe: float = REWARD.w_safe
    w_comfort: float = REWARD.w_comfort
    w_accel: float = REWARD.w_accel
    jerk_scale: float = REWARD.jerk_scale_mps3
    message_dim: int = AgentConfig.message_dim            # V2V message width (CA models)
    hidden: int = AgentConfig.hidden                      # hidden layer width
    actor_lr: float = AgentConfig.actor_lr
    critic_lr: float = AgentConfig.critic_lr
    tau: float = AgentConfig.tau                          # targets' soft-update rate per update
    select: str = "margin"         # how the best checkpoint is chosen: see selection_score
    noise: float = AgentConfig.exploration_noise          # exploration std (fraction of adj_max)
    noise_correlation: float = AgentConfig.noise_correlation
    gamma: float = AgentConfig.gamma                      # discount per 0.1 s step
    adj_max: float = AgentConfig.adj_max                  # |a_adj| bound of the actor (m/s²)
    smooth_jerk: float = AgentConfig.smooth_jerk          # actor smoothness terms (agents.py)
    smooth_accel: float = AgentConfig.smooth_accel
    adj_l2: float = AgentConfig.adj_l2                    # actor loss weight on a_adj² (agents.py)
    base: str = AgentConfig.base          # base model under a_adj: idm or a classical CACC name
    observe_ahead: bool = False    # o has a fifth column a_ahead (controllers.AheadAcceleration)
    shield_ttc: float = 0.0        # safety shield of the policy (s; controllers.shield_adjustment)
    comm_fallback: str = AgentConfig.comm_fallback  # run time, hearing no neighbour (agents.py)
    comm_randomize: bool = False   # every episode its own V2V delay/loss and sensor noise (randomize.py)
    randomize_sensors: bool = True  # with comm_randomize: sensor noise in half the episodes
    val_impaired: bool = False     # validate also under selection.VALIDATION_IMPAIRMENTS
    comm_delay: float = 0.0        # fixed impairments of every training episode (channel.py)
    comm_loss: float = 0.0
    comm_burst: float = 1.0
    comm_timeout: float = 1.0
    comm_fade: float = 1.0
    sensor_noise: bool = False
    sensor_filter: bool = False    # noisy measurements are tracked (sensors.py), fixed or random
    impairment_seed: int = 0
    init: str | None = None        # a policy file whose actor starts the run (a warm start)
    imitate: str | None = None     # a Ploeg CACC the actor copies first (carl_sumo.imitation)
    imitate_updates: int = 4_000   # behaviour-cloning gradient steps at learning_starts
    imitate_lr: float = 1e-3       # their Adam learning rate

    def agent_config(self) -> AgentConfig:
        """The agent this run trains. With ``scale_rates`` its learning rates and target
        soft-update rate are ``update_every`` times the given ones, so that an update every K
        steps moves the networks about as far per env step as an update every step does
        (docs/bench.md: the same learning, measured over 10 seeds)."""
        k = self.update_every if self.scale_rates else 1
        return AgentConfig(algo=self.algo, n_vehicles=self.n_vehicles,
                           message_dim=self.message_dim, hidden=self.hidden,
                           actor_lr=k * self.actor_lr, critic_lr=k * self.critic_lr,
                           tau=k * self.tau,
                           exploration_noise=self.noise, noise_correlation=self.noise_correlation,
                           smooth_jerk=self.smooth_jerk, smooth_accel=self.smooth_accel,
                           adj_l2=self.adj_l2,
                           gamma=self.gamma, adj_max=self.adj_max, base=self.base,
                           batch_size=self.batch_size, observe_ahead=self.observe_ahead,
                           shield_ttc_s=self.shield_ttc, comm_fallback=self.comm_fallback)

    @property
    def fixed_impairments(self) -> Impairments | None:
        """The fixed impairments of every training episode (``--comm-loss`` ...), or None."""
        return Impairments.from_options(self)

    @property
    def reward(self) -> RewardConfig:
        return replace(REWARD, w_gap=self.w_gap, w_safe=self.w_safe, w_comfort=self.w_comfort,
                       w_accel=self.w_accel,
                       jerk_scale_mps3=self.jerk_scale)


def split_validation(events: Sequence[Event], k: int, seed: int, source: str | None = None
                     ) -> tuple[list[Event], list[Event]]:
    """(training events, held-out validation events): k events chosen with the seed, among the
    events of ``source`` only when one is given (at most half of them, so training still sees
    that source). InputError for a source that no event has."""
    if len(events) < 2:
        return list(events), list(events)
    if source is None:
        candidates = np.arange(len(events))
        k = min(k, max(1, len(events) // 5))
    else:
        candidates = np.array([i for i, e in enumerate(events) if e.source == source], dtype=int)
        if len(candidates) == 0:
            known = ", ".join(sorted({e.source for e in events}))
            raise InputError(f"--val-source {source!r}: no training event comes from it; "
                             f"choose one of {known}")
        k = min(k, max(1, len(candidates) // 2))
    held = set(candidates[np.random.default_rng(seed).permutation(len(candidates))[:k]].tolist())
    return ([e for i, e in enumerate(events) if i not in held],
            [e for i, e in enumerate(events) if i in held])


def held_out_split(events: Sequence[Event], cfg: TrainConfig) -> tuple[list[Event], list[Event]]:
    """(training, validation) events of a run: ``cfg.eval_events`` held out with ``cfg.val_seed``
    (the training seed when None), so runs of several seeds can share one validation set, from
    the events of ``cfg.val_source`` when given (e.g. the source most like the test set); with
    ``cfg.warmup`` every event starts with that many seconds of settling."""
    val_seed = cfg.seed if cfg.val_seed is None else cfg.val_seed
    train, val = split_validation(events, cfg.eval_events, val_seed, cfg.val_source)
    if cfg.braking_events > 0:  # hard braking in training, and in the validation's safety check
        from carl_sumo.data.synthetic import braking_events

        braking = braking_events(cfg.braking_events, val_seed)
        k = max(1, cfg.braking_events // 4)
        train, val = train + braking[k:], val + braking[:k]
    if cfg.warmup:  # every episode first settles; validation scores the recorded part
        train = [e.with_warmup(cfg.warmup) for e in train]
        val = [e.with_warmup(cfg.warmup) for e in val]
    return train, val


LOG_COLUMNS = ["step", "transitions", "wall_s", "train_reward", "val_reward", "headway_s",
               "jerk_mps3", "speed_mps", "dampening_ratio", "collisions",
               *(name for name, _ in MARGIN_KEYS.values())]
"""Columns of the learning-curve CSV written beside the policy."""


def _upgrade_log(path: Path) -> None:
    """Give a learning curve written by an older carl-sumo (fewer columns) the current header,
    its missing values empty, so that a resumed run can append to it."""
    with open(path, newline="") as f:
        rows = list(csv.reader(f))
    if not rows or rows[0] == LOG_COLUMNS:
        return
    width = len(LOG_COLUMNS)
    out = io.StringIO()
    csv.writer(out).writerows([LOG_COLUMNS] + [r + [""] * (width - len(r)) for r in rows[1:]])
    write_text_atomic(path, out.getvalue())


def validation_conditions(cfg: TrainConfig) -> tuple:
    """What validation runs every event under: a perfect channel, and with ``--val-impaired``
    also :data:`carl_sumo.selection.VALIDATION_IMPAIRMENTS` (with clean sensors for a run
    randomised without sensor noise, filtered with ``--sensor-filter``), or a run's fixed
    impairments (impairment seed 0)."""
    if not cfg.val_impaired:
        return (None,)
    if cfg.fixed_impairments is not None:
        return (None, replace(cfg.fixed_impairments, seed=0))
    noisy = not cfg.comm_randomize or cfg.randomize_sensors
    return (None, replace(VALIDATION_IMPAIRMENTS, sensor_noise=noisy,
                          sensor_filter=noisy and cfg.sensor_filter))


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def _boundaries(agent: Agent) -> tuple[np.ndarray, np.ndarray] | None:
    """The CA actor's boundary messages (forward, backward), which a receiver's held message fades
    into past the timeout (carl_sumo.channel); None for an actor without messages."""
    actor = agent.actor
    if not isinstance(actor, CommunicationAware):
        return None
    return (actor.forward_boundary.detach().double().numpy(),
            actor.backward_boundary.detach().double().numpy())


def _metadata(cfg: TrainConfig, agent: Agent, val: dict[str, float], wall_s: float,
              baseline: dict[str, float] | None = None,
              val_events: Sequence[Event] = ()) -> dict:
    import libsumo

    return {"algo": cfg.algo, "base": cfg.base, "trained_vehicles": cfg.n_vehicles,
            "seed": cfg.seed,
            "data": cfg.data, "split": cfg.split, "steps": cfg.steps,
            "observation": "[v m/s, a m/s^2, d m, dv m/s" + (
                ", a_base m/s^2]" if agent.cfg.residual else
                ", a_ahead m/s^2]" if agent.cfg.observe_ahead else "]"),
            "reward": asdict(cfg.reward), "comm_randomize": cfg.comm_randomize,
            "randomize_sensors": cfg.randomize_sensors, "sensor_filter": cfg.sensor_filter,
            "impairments": asdict(fixed) if (fixed := cfg.fixed_impairments) else None,
            "val_impaired": cfg.val_impaired, "init": cfg.init,
            "validation": {k: float(v) for k, v in val.items()},
            "validation_base": {k: float(v) for k, v in (baseline or {}).items()},
            "validation_events": [e.event_id for e in val_events],
            "wall_time_s": float(wall_s),
            "command": cfg.command, "sumo_version": str(libsumo.getVersion()[1]),
            "carl_sumo_version": __version__, "torch_version": str(torch.__version__)}


def train(cfg: TrainConfig, events: Sequence[Event], resume: Path | None = None,
          progress: bool = True, log=print, rollouts: str = "processes",
          on_checkpoint=None) -> dict[str, Any]:
    """Train an agent; writes the best policy to ``cfg.out``, checkpoints and a CSV log beside it.

    ``rollouts``: the environments run in spawned processes or, ``"ray"``, in Ray actors (the same
    steps). ``on_checkpoint(step)`` is called after each checkpoint is written (``sweep``
    hands it to Ray Tune).

    Returns the final validation metrics and timing. Long on purpose: the whole algorithm loop
    (act, step, store, update, validate, keep, checkpoint) reads top to bottom in one place, as in
    CleanRL; its parts that stand alone (validation, selection, checkpoints) are functions above.
    """
    from carl_sumo.vec_env import RayVecPlatoon, VecPlatoon

    train_events, val_events = held_out_split(events, cfg)  # InputError before any file
    teacher = _teacher(cfg)  # InputError before any file
    init_actor = initial_actor(cfg)  # InputError before any file
    out = Path(cfg.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    ckpt_path = out.with_suffix(".ckpt")
    log_path = out.with_suffix(".csv")
    n = cfg.n_vehicles
    torch.set_num_threads(1)  # the SUMO workers have the other cores; small nets gain nothing
    keep_heap_memory()  # no page faults on the update's temporaries
    seed_everything(cfg.seed)
    agent = Agent(cfg.agent_config())
    if init_actor is not None and resume is None:
        try:
            agent.start_from(init_actor)
        except RuntimeError:
            raise InputError(f"--init {cfg.init}: its actor does not fit this run's network "
                             "(--message-dim, --hidden); give a policy trained with the same "
                             "ones") from None
    fixed = cfg.fixed_impairments
    channels = RandomisedChannels(cfg.num_envs, n, cfg.message_dim if
                                  agent.cfg.communication_aware else 0, cfg.seed,
                                  cfg.randomize_sensors, fixed, cfg.sensor_filter) \
        if cfg.comm_randomize or fixed is not None else None
    buffer = ReplayBuffer(cfg.buffer_size, n, agent.cfg.obs_dim,
                          channels.message_dim if channels is not None else 0)
    rng = np.random.default_rng(cfg.seed)
    start_step, best, wall_before = 0, -np.inf, 0.0
    if resume is not None:
        state = load_torch(resume, "checkpoint")
        if state.get("format") != CHECKPOINT_FORMAT:
            raise InputError(f"{resume} is not a carl-sumo training checkpoint")
        if state["train_config"]["algo"] != cfg.algo or state["train_config"]["n_vehicles"] != n:
            raise InputError(f"checkpoint {resume} is for {state['train_config']['algo']} with "
                             f"{state['train_config']['n_vehicles']} vehicles; resume with the "
                             "same --algo and --vehicles")
        agent.load_state_dict(state["agent"])
        agent.actor_opt.load_state_dict(state["actor_opt"])
        agent.critic_opt.load_state_dict(state["critic_opt"])
        agent.updates = int(state["updates"])
        buffer = ReplayBuffer.from_state(state["buffer"])
        rng.bit_generator.state = _decode_rng(state["numpy_rng"])
        torch.set_rng_state(state["torch_rng"])
        start_step, best = int(state["step"]), float(state["best"])
        wall_before = float(state["wall_s"])
        log(f"resumed {resume} at step {start_step}")
    val_env = PlatoonEnv(val_events, n, cfg.net, reward=cfg.reward, base=cfg.base,
                         bounds=adjustment_bounds(cfg.adj_max), observe_ahead=cfg.observe_ahead,
                         shield_ttc_s=cfg.shield_ttc)
    for event in train_events:  # fail here, not in a worker, when an event does not fit the net
        check_fits(val_env.sim.route, event, n)
    conditions = validation_conditions(cfg)
    base_reward, baseline_events = validate_events(BaseOnly(), val_env, val_events,
                                                     conditions)  # same events
    baseline = {"val_reward": base_reward, **aggregate(baseline_events)}
    log(f"validation baseline ({cfg.base}): "
        + ", ".join(f"{k}={v:.3f}" for k, v in baseline.items()))
    if init_actor is not None and resume is None:
        # the warm start is the policy to beat: kept unless a trained checkpoint scores better
        best, start = _validate_and_keep(cfg, agent, val_env, val_events, baseline,
                                         baseline_events, out)
        log(f"validation of --init {cfg.init}: "
            + ", ".join(f"{k}={v:.3f}" for k, v in start.items()))
    elif agent.cfg.residual and resume is None:
        # the untrained actor is its base exactly (a_adj = 0): the policy to beat, kept unless a
        # trained checkpoint scores better on validation
        start = {**baseline, **improvement_z(baseline_events, baseline_events)}
        best = selection_score(start, cfg.select, baseline)
        save_policy(agent, out, _metadata(cfg, agent, start, 0.0, baseline, val_events))
    vec_class = RayVecPlatoon if rollouts == "ray" else VecPlatoon
    vec = vec_class(train_events, n, cfg.net, cfg.num_envs, cfg.seed + start_step, cfg.reward,
                    cfg.base, cfg.observe_ahead, adjustment_bounds(cfg.adj_max), cfg.shield_ttc)
    obs = vec.reset(cfg.seed + start_step, channels.current if channels is not None else None)
    links = channels.receive(_boundaries(agent)) if channels is not None else None
    new_log = not (resume is not None and log_path.exists())
    if not new_log:
        _upgrade_log(log_path)
    log_file = open(log_path, "w" if new_log else "a", newline="")
    writer = csv.writer(log_file)
    if new_log:
        writer.writerow(LOG_COLUMNS)
    board = _tensorboard(out.with_suffix(".tb"))
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=cfg.steps, initial=start_step, desc=cfg.algo, unit="step",
                   file=sys.stderr, dynamic_ncols=True)
    t0 = time.perf_counter()
    recent = []
    val: dict[str, float] = {}
    noise = ColoredNoise((cfg.num_envs, n), agent.cfg.exploration_noise * agent.cfg.adj_max,
                         agent.cfg.noise_correlation, rng)
    try:
        for step in range(start_step, cfg.steps):
            if step == cfg.learning_starts and teacher is not None:
                best = _clone_teacher(cfg, agent, teacher, buffer, rng, val_env, val_events,
                                      baseline, baseline_events, out, log)
            # a warm-started actor drives from the first step, others after learning_starts
            acting = step >= cfg.learning_starts or init_actor is not None
            if links is not None:  # the CA actor's messages cross impaired links
                action, sent_f, sent_b = agent.act_over(obs, links,
                                                        noise.sample() if acting else None)
                channels.send(sent_f, sent_b)
            if not acting:  # the base (or the teacher) plus exploration noise
                action = noise.sample()
                if teacher is not None:
                    action = action + teacher_adjustment(teacher, obs, agent.cfg.adj_max,
                                                         cfg.observe_ahead)
                action = np.clip(action, -agent.cfg.adj_max, agent.cfg.adj_max)
            elif links is None:
                action = agent.act(obs, noise.sample())
            next_obs, reward, term, trunc, final = vec.step(
                action, channels.upcoming if channels is not None else None)
            noise.reset(term | trunc)
            fallbacks = _boundaries(agent) if channels is not None else None
            next_links = channels.receive(fallbacks) if channels is not None else None  # at o'
            buffer.add(obs, action, reward, final, term.astype(np.float32), links, next_links)
            if channels is not None:  # a new episode's links, else this step's preview holds
                channels.episodes_ended(term | trunc)
                links = channels.receive(fallbacks) if (term | trunc).any() else next_links
            recent.append(float(reward.mean()))
            obs = next_obs
            if step >= cfg.learning_starts and (step - cfg.learning_starts) % cfg.update_every == 0:
                train_actor = step >= cfg.learning_starts + cfg.critic_burn_in
                if cfg.lr_decay:
                    agent.scale_learning_rates(1.0 - (step - cfg.learning_starts)
                                               / max(1, cfg.steps - cfg.learning_starts))
                for _ in range(cfg.updates_per_step):
                    agent.update(buffer.sample(agent.cfg.batch_size, rng), train_actor)
            done_steps = step + 1
            if done_steps % cfg.eval_every == 0 or done_steps == cfg.steps:
                val_reward, per_event = validate_events(agent, val_env, val_events, conditions)
                val = {"val_reward": val_reward, **aggregate(per_event),
                       **improvement_z(per_event, baseline_events)}
                wall = wall_before + time.perf_counter() - t0
                train_reward = float(np.mean(recent[-cfg.eval_every:])) if recent else float("nan")
                writer.writerow([done_steps, done_steps * cfg.num_envs, f"{wall:.1f}",
                                 f"{train_reward:.4f}", f"{val['val_reward']:.4f}",
                                 *(f"{val[k]:.4f}" for k in ("headway_s", "jerk_mps3",
                                                              "speed_mps", "dampening_ratio")),
                                 val["collisions"],
                                 *(f"{val[name]:.3f}" for name, _ in MARGIN_KEYS.values())])
                log_file.flush()
                if board is not None:
                    for key, value in val.items():
                        board.add_scalar(f"validation/{key}", value, done_steps)
                    board.add_scalar("train/reward", train_reward, done_steps)
                score = selection_score(val, cfg.select, baseline)
                # only a trained actor can be the best; the first validation is a fallback
                if agent.updates > 0 and score > best or not np.isfinite(best):
                    best = score if agent.updates > 0 else -np.inf
                    save_policy(agent, out, _metadata(cfg, agent, val, wall, baseline,
                                                      val_events))
                if bar is not None:
                    bar.set_postfix(reward=f"{train_reward:.3f}", val=f"{val['val_reward']:.3f}",
                                    jerk=f"{val['jerk_mps3']:.3f}", coll=val["collisions"],
                                    min_z=f"{min(val[k] for k, _ in MARGIN_KEYS.values()):.2f}")
            if done_steps % cfg.checkpoint_every == 0 or done_steps == cfg.steps:
                _save_checkpoint(ckpt_path, cfg, agent, buffer, rng, done_steps, best,
                                 wall_before + time.perf_counter() - t0)
                if on_checkpoint is not None:
                    log_file.flush()
                    on_checkpoint(done_steps)
            if bar is not None:
                bar.update(1)
    finally:
        vec.close()
        log_file.close()
        if board is not None:
            board.close()
        if bar is not None:
            bar.close()
    wall = wall_before + time.perf_counter() - t0
    return {"validation": val, "validation_base": baseline, "wall_time_s": wall,
            "best_score": best}


def _teacher(cfg: TrainConfig):
    """The controller a run imitates (None without ``--imitate``); InputError when it cannot."""
    if cfg.imitate is None:
        return None
    if cfg.base != "idm":
        raise InputError("--imitate warm-starts the paper's IDM-based adjustment; a run on a "
                         "classical --base starts on that base already: leave one of them out")
    if cfg.learning_starts < 1:
        raise InputError("--imitate needs --learning-starts steps of teacher driving to copy")
    return imitation.teacher(cfg.imitate)


def _clone_teacher(cfg: TrainConfig, agent: Agent, teacher, buffer: ReplayBuffer,
                   rng: np.random.Generator, val_env: PlatoonEnv, val_events: Sequence[Event],
                   baseline: dict[str, float], baseline_events: list[dict], out: Path,
                   log) -> float:
    """Fit the actor to the teacher on every stored state, validate it and keep it as the first
    candidate; returns its selection score (see :mod:`carl_sumo.imitation`)."""
    obs, target = imitation.dataset(teacher, buffer.obs[:buffer.size], agent.cfg.adj_max,
                                    cfg.observe_ahead)
    mse = agent.imitate(obs, target, cfg.imitate_updates, cfg.imitate_lr, 256, rng)
    score, val = _validate_and_keep(cfg, agent, val_env, val_events, baseline, baseline_events,
                                    out)
    log(f"imitated {cfg.imitate} on {len(obs)} platoon states (mse {mse:.4f} m²/s⁴): "
        + ", ".join(f"{k}={v:.3f}" for k, v in val.items()))
    return score


def _validate_and_keep(cfg: TrainConfig, agent: Agent, val_env: PlatoonEnv,
                       val_events: Sequence[Event], baseline: dict[str, float],
                       baseline_events: list[dict], out: Path) -> tuple[float, dict[str, float]]:
    """Validate the actor as it is, write it as the run's first candidate; its selection score
    and validation metrics."""
    val_reward, per_event = validate_events(agent, val_env, val_events, validation_conditions(cfg))
    val = {"val_reward": val_reward, **aggregate(per_event),
           **improvement_z(per_event, baseline_events)}
    save_policy(agent, out, _metadata(cfg, agent, val, 0.0, baseline, val_events))
    return selection_score(val, cfg.select, baseline), val


def initial_actor(cfg: TrainConfig) -> dict | None:
    """The actor weights of ``--init`` (None without it); InputError when the file is not a
    policy of this run's algorithm, base and observation."""
    if cfg.init is None:
        return None
    from carl_sumo.policy import read_policy_payload

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


def _tensorboard(logdir: Path):
    """A TensorBoard writer when the tensorboard package is installed, else None."""
    try:
        from torch.utils.tensorboard import SummaryWriter
    except ImportError:
        return None
    return SummaryWriter(str(logdir))


def _decode_rng(saved: dict) -> dict:
    return {"bit_generator": saved["bit_generator"],
            "state": {"state": int(saved["state_hi"]) << 64 | int(saved["state_lo"]),
                      "inc": int(saved["inc_hi"]) << 64 | int(saved["inc_lo"])},
            "has_uint32": int(saved["has_uint32"]), "uinteger": int(saved["uinteger"])}


def _rng_for_save(rng: np.random.Generator) -> dict:
    s = rng.bit_generator.state
    state, inc = int(s["state"]["state"]), int(s["state"]["inc"])
    mask = (1 << 64) - 1
    return {"bit_generator": s["bit_generator"], "state_hi": state >> 64, "state_lo": state & mask,
            "inc_hi": inc >> 64, "inc_lo": inc & mask, "has_uint32": int(s["has_uint32"]),
            "uinteger": int(s["uinteger"])}


def export_policy(checkpoint: Path, out: Path) -> dict[str, Any]:
    """Write the current actor of a training checkpoint as a policy file; its metadata."""
    state = load_torch(checkpoint, "checkpoint")
    if state.get("format") != CHECKPOINT_FORMAT:
        raise InputError(f"{checkpoint} is not a carl-sumo training checkpoint")
    cfg = TrainConfig(**state["train_config"])
    agent = Agent(cfg.agent_config())
    agent.load_state_dict(state["agent"])
    meta = _metadata(cfg, agent, {}, float(state["wall_s"]))
    meta["exported_from"] = f"{Path(checkpoint).name} at step {int(state['step'])}"
    save_policy(agent, Path(out), meta)
    return meta


def _save_checkpoint(path: Path, cfg: TrainConfig, agent: Agent, buffer: ReplayBuffer,
                     rng: np.random.Generator, step: int, best: float, wall_s: float) -> None:
    save_torch_atomic({"format": CHECKPOINT_FORMAT, "train_config": asdict(cfg),
                       "agent": agent.state_dict(), "actor_opt": agent.actor_opt.state_dict(),
                       "critic_opt": agent.critic_opt.state_dict(), "updates": agent.updates,
                       "buffer": buffer.state(), "numpy_rng": _rng_for_save(rng),
                       "torch_rng": torch.get_rng_state(), "step": step, "best": best,
                       "wall_s": wall_s}, path)
