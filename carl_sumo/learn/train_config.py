"""What ``carl-sumo train`` is asked to do (:class:`TrainConfig`), and the events and conditions
it validates on: held-out training events, and the V2V and sensor impairments of validation."""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from carl_sumo.config import REWARD, RewardConfig
from carl_sumo.control.channel import Impairments, plant_impairments
from carl_sumo.data.events import Event, read_event_ids
from carl_sumo.errors import InputError
from carl_sumo.learn.agents import AgentConfig
from carl_sumo.learn.selection import VALIDATION_IMPAIRMENTS
from carl_sumo.sim.sumo import DEFAULT_NET


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
    val_events: str | None = None  # file of training event IDs also validated on (held out)
    exclude_events: str | None = None  # file of training event IDs left out of both
    oversample: str | None = None  # file of training event IDs drawn more often in training
    oversample_times: int = 4      # ... this many times as often as the others
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
    w_spacing: float = REWARD.w_spacing    # spacing term (reward.py) and its time gap h_s (s)
    spacing_gap: float = REWARD.spacing_gap_s
    spacing_head_gap: float | None = REWARD.spacing_head_gap_s  # the head's h_s (s; None: h_s)
    spacing_heavy_gap: float | None = REWARD.spacing_heavy_gap_s  # a heavy vehicle's h_s (s)
    w_critical: float = REWARD.w_critical  # penalty per step with 0 < TTC < 1.5 s (reward.py)
    w_amplify: float = REWARD.w_amplify    # amplification term's weight (reward.py)
    lagrange_lr: float = 0.0               # RCPO multiplier step on the close-call cost (0: off)
    jerk_scale: float = REWARD.jerk_scale_mps3
    message_dim: int = AgentConfig.message_dim            # V2V message width (CA models)
    hidden: int = AgentConfig.hidden                      # hidden layer width
    actor_lr: float = AgentConfig.actor_lr
    critic_lr: float = AgentConfig.critic_lr
    tau: float = AgentConfig.tau                          # targets' soft-update rate per update
    select: str = "margin"         # how the best checkpoint is chosen: see selection_score
    gate_string_stable: str | None = None  # "ideal"/"real": keep every validated checkpoint in
    # <out>.candidates/; the kept one is the best-scoring that is string stable on that plant
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
    comm_delay: float | None = None  # fixed impairments of every episode (channel.py; None: 0,
    # or the real plant's V2V delay with plant="real")
    comm_loss: float = 0.0
    comm_burst: float = 1.0
    comm_timeout: float = 1.0
    comm_fade: float = 1.0
    sensor_noise: bool = False
    sensor_filter: bool = False    # noisy measurements are tracked (sensors.py), fixed or random
    impairment_seed: int = 0
    plant: str = "ideal"           # the followers' vehicle dynamics (sim/vehicle.py): ideal, real
    fleet: str | None = None       # vehicle classes with fractions (--fleet)
    vehicle_lag: float | None = None      # τ of every follower (s)
    actuation_delay: float | None = None  # dead time of every follower (s)
    plant_randomize: bool = False  # every episode its own fleet, lags, V2V delay and loss
    comm_off: bool = False         # CA models: cut the messages (the communication ablation)
    init: str | None = None        # a policy file whose actor starts the run (a warm start)
    imitate: str | None = None     # a Ploeg CACC the actor copies first (carl_sumo.learn.imitation)
    imitate_updates: int = 4_000   # behaviour-cloning gradient steps at learning_starts
    imitate_target: str = "realised"  # on an ACC base: the predecessor's realised a or its command
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
                           shield_ttc_s=self.shield_ttc, comm_fallback=self.comm_fallback,
                           comm_off=self.comm_off)

    @property
    def fixed_impairments(self) -> Impairments | None:
        """The fixed impairments of every training episode (``--comm-loss`` ...), or None."""
        return Impairments.from_options(self)

    @property
    def reward(self) -> RewardConfig:
        return replace(REWARD, w_gap=self.w_gap, w_safe=self.w_safe, w_comfort=self.w_comfort,
                       w_accel=self.w_accel, w_spacing=self.w_spacing,
                       spacing_gap_s=self.spacing_gap, spacing_head_gap_s=self.spacing_head_gap,
                       spacing_heavy_gap_s=self.spacing_heavy_gap,
                       w_critical=self.w_critical, w_amplify=self.w_amplify,
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


def _check_known(option: str, ids: Sequence[str], events: Sequence[Event]) -> None:
    """InputError naming the IDs of an ``option``'s file that no event of ``events`` has."""
    known = {e.event_id for e in events}
    missing = [i for i in ids if i not in known]
    if missing:
        raise InputError(f"{option}: {len(missing)} event ID(s) not in the training events, "
                         f"e.g. {missing[0]!r}; list IDs of the --data file's training split")


def hold_out_named(train: Sequence[Event], val: Sequence[Event], ids: Sequence[str]
                   ) -> tuple[list[Event], list[Event]]:
    """(training, validation) with the events named by ``ids`` moved from training to
    validation (those already held out stay); InputError naming an ID that no event has."""
    _check_known("--val-events", ids, [*train, *val])
    named = set(ids)
    return ([e for e in train if e.event_id not in named],
            [*val, *(e for e in train if e.event_id in named)])


def oversampled(train: Sequence[Event], val: Sequence[Event], ids: Sequence[str], times: int
                ) -> list[Event]:
    """The training events with each event named by ``ids`` in it ``times`` times (an episode
    draws an event uniformly from the list); InputError naming an ID that is not a training
    event, or one that validation holds out."""
    held = {e.event_id for e in val}
    clash = [i for i in ids if i in held]
    if clash:
        raise InputError(f"--oversample: {clash[0]!r} is held out for validation; list training "
                         "events that --val-events and --eval-events do not hold out")
    _check_known("--oversample", ids, train)
    named = set(ids)
    return [*train, *(e for e in train if e.event_id in named for _ in range(times - 1))]


def held_out_split(events: Sequence[Event], cfg: TrainConfig) -> tuple[list[Event], list[Event]]:
    """(training, validation) events of a run: ``cfg.eval_events`` held out with ``cfg.val_seed``
    (the training seed when None), so runs of several seeds can share one validation set, from
    the events of ``cfg.val_source`` when given (e.g. the source most like the test set), plus
    the events named in ``cfg.val_events`` (e.g. the hardest training events); those named in
    ``cfg.oversample`` appear ``cfg.oversample_times`` times among the training events; with
    ``cfg.warmup`` every event starts with that many seconds of settling; those named in
    ``cfg.exclude_events`` are then dropped from both (the draws do not change)."""
    val_seed = cfg.seed if cfg.val_seed is None else cfg.val_seed
    train, val = split_validation(events, cfg.eval_events, val_seed, cfg.val_source)
    if cfg.val_events is not None:  # named events (e.g. the hardest ones) validate too
        train, val = hold_out_named(train, val, read_event_ids(cfg.val_events))
    if cfg.oversample is not None:  # named training events (e.g. hard ones) drawn more often
        train = oversampled(train, val, read_event_ids(cfg.oversample), cfg.oversample_times)
    if cfg.braking_events > 0:  # hard braking in training, and in the validation's safety check
        from carl_sumo.data.synthetic import braking_events

        braking = braking_events(cfg.braking_events, val_seed)
        k = max(1, cfg.braking_events // 4)
        train, val = train + braking[k:], val + braking[:k]
    if cfg.exclude_events is not None:  # e.g. recordings that start in a collision; the
        excluded = set(read_event_ids(cfg.exclude_events))  # draws above stay as without it
        _check_known("--exclude-events", sorted(excluded), events)
        train = [e for e in train if e.event_id not in excluded]
        val = [e for e in val if e.event_id not in excluded]
    if cfg.warmup:  # every episode first settles; validation scores the recorded part
        train = [e.with_warmup(cfg.warmup) for e in train]
        val = [e.with_warmup(cfg.warmup) for e in val]
    return train, val


def validation_conditions(cfg: TrainConfig) -> tuple:
    """What validation runs every event under: a perfect channel, and with ``--val-impaired``
    also :data:`carl_sumo.learn.selection.VALIDATION_IMPAIRMENTS` (with clean sensors for a run
    randomised without sensor noise, filtered with ``--sensor-filter``), or a run's fixed
    impairments (impairment seed 0). On a plant (``--plant``, ``--fleet`` ...) every condition
    has its vehicle dynamics and V2V delay."""
    fixed = cfg.fixed_impairments
    if cfg.plant_randomize:  # randomised plants: validate on the real plant
        return (plant_impairments("real"),)
    if fixed is not None and fixed.plant is not None:  # validation runs on the training plant
        plain = Impairments(delay_s=fixed.delay_s, plant=fixed.plant)
        return (plain,) if not cfg.val_impaired else (plain, replace(fixed, seed=0))
    if not cfg.val_impaired:
        return (None,)
    if fixed is not None:
        return (None, replace(fixed, seed=0))
    noisy = not cfg.comm_randomize or cfg.randomize_sensors
    return (None, replace(VALIDATION_IMPAIRMENTS, sensor_noise=noisy,
                          sensor_filter=noisy and cfg.sensor_filter))
