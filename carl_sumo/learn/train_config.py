"""What ``carl-sumo train`` is asked to do (:class:`TrainConfig`), and the events and conditions
it validates on: held-out training events, and the V2V and sensor impairments of validation.

Every training option is defined once, as a dataclass field made by
:func:`carl_sumo.options.option`: its type (the annotation), default, unit, one-line doc, range
and the section of the recipe file it belongs to (data, plant, base, reward, agent, training,
validation). The reward's live in :class:`carl_sumo.config.RewardConfig`, the agent's in
:class:`carl_sumo.learn.agents.AgentConfig` and the V2V channel's and sensors' in
:class:`carl_sumo.control.channel.Impairments`, which :class:`TrainConfig` gathers with
:func:`carl_sumo.options.shared` (and gives back as :attr:`TrainConfig.reward`,
:meth:`TrainConfig.agent_config` and :attr:`TrainConfig.fixed_impairments`); the rest are its
own. ``carl-sumo train``'s options
(:mod:`carl_sumo.cli.config_options`), their ``--help``, the recipe files
(:mod:`carl_sumo.learn.recipe`) and :meth:`TrainConfig.check` all derive from these fields.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, replace
from typing import Sequence

import numpy as np

from carl_sumo.config import DT_S, REWARD, RewardConfig
from carl_sumo.control.channel import Impairments, plant_impairments
from carl_sumo.data.events import MAX_WARMUP_S, Event, check_whole_steps, read_event_ids
from carl_sumo.errors import InputError
from carl_sumo.learn.agents import AgentConfig
from carl_sumo.learn.selection import VALIDATION_IMPAIRMENTS
from carl_sumo.options import (SECTIONS, bounds_text, check_choices,  # noqa: F401
                               check_range, flag_of, option, shared, sourced)
from carl_sumo.resources import EVENT_LISTS, NETWORKS
from carl_sumo.sim.sumo import DEFAULT_NET
from carl_sumo.sim.vehicle import MAX_DEAD_TIME_S, MAX_LAG_S

MAX_STEPS = 100_000_000
"""The most vector steps one run may take (a bound, so that a typo cannot allocate forever)."""


MAX_COMM_DELAY_S = 5.0
"""The longest fixed V2V delay a run accepts (s)."""


@dataclass
class TrainConfig:
    """What ``carl-sumo train`` is asked to do: every option, once (see the module docstring)."""

    # data
    data: str = option("default", "default | stop-and-go | PATH of an event table or a raw "
                       "NGSIM CSV", "data", metavar="PATH")
    split: str = option("train", "the data's split trained on: train | test | us101 | all", "data")
    net: str = option(str(DEFAULT_NET), "SUMO network (.net.xml; a shipped network's file "
                      "name works from any folder)", "data", metavar="PATH", folder=NETWORKS)
    warmup: float = option(0.0, "settling run before every event, the leader holding its first "
                           "speed (a multiple of 0.1 s), so that the platoon settles at its own "
                           "spacing; metrics and validation score the recorded part only",
                           "data", unit="s", low=0.0, high=MAX_WARMUP_S, metavar="S")
    braking_events: int = option(0, "synthetic hard-braking leaders (15-30 m/s, -3 to -6 m/s²) "
                                 "added to training, a quarter of them to validation", "data",
                                 low=0, high=10_000, metavar="N")
    sine_events: int = option(0, "synthetic sinusoidal leaders (the string-stability test's "
                              "excitation, 0.1-3 rad/s) added to training, a quarter of them to "
                              "validation", "data", low=0, high=1000, metavar="N")
    sine_share: float = option(0.25, "the share of training episodes that replay one of the "
                               "--sine-events (they are repeated in the draw to reach it)",
                               "data", low=0.0, high=0.9, metavar="F")
    exclude_events: str | None = option(None, "file of training event IDs (one per line) left "
                                        "out of training and validation (a shipped list's "
                                        "file name works from any folder)", "data",
                                        metavar="FILE", folder=EVENT_LISTS)
    oversample: str | None = option(None, "file of training event IDs drawn --oversample-times "
                                    "as often as the others in training", "data", metavar="FILE",
                                    folder=EVENT_LISTS)
    oversample_times: int = option(4, "how many times as often the --oversample events are "
                                   "drawn", "data", low=1, high=1_000, metavar="K")
    # plant
    plant: str = option("ideal", "ideal: every follower applies its command at once (the "
                        "paper's); real: the default fleet (80 % cars, 20 % trucks, lag and dead "
                        "time drawn per class) and a 0.1 s V2V delay (--fleet, --vehicle-lag, "
                        "--actuation-delay and --comm-delay replace its parts)", "plant",
                        choices=("ideal", "real"))
    fleet: str | None = option(None, "vehicle classes with fractions, e.g. car:0.7,truck:0.3 "
                               "(each follower's class drawn per event; docs/vehicles.md)",
                               "plant", metavar="SPEC")
    vehicle_lag: float | None = option(None, "powertrain lag tau of every follower (first "
                                       "order)", "plant", unit="s", low=0.0, high=MAX_LAG_S,
                                       metavar="S")
    actuation_delay: float | None = option(None, "actuation dead time of every follower (a "
                                           "multiple of 0.1 s)", "plant", unit="s", low=0.0,
                                           high=MAX_DEAD_TIME_S, metavar="S")
    plant_randomize: bool = option(False, "every episode its own fleet (0-50 % trucks), lags, "
                                   "V2V delay (0-0.3 s) and loss (0-30 %); validation on the "
                                   "real plant", "plant")
    comm_delay: float | None = option(None, "every V2V message arrives this late (a multiple of "
                                      "0.1 s; none: 0, or 0.1 with --plant real)", "plant",
                                      unit="s", low=0.0, high=MAX_COMM_DELAY_S, metavar="S")
    comm_loss: float = shared(Impairments, "loss")
    comm_burst: float = shared(Impairments, "burst")
    comm_timeout: float = shared(Impairments, "timeout_s")
    comm_fade: float = shared(Impairments, "fade_s")
    sensor_noise: bool = shared(Impairments, "sensor_noise")
    sensor_filter: bool = shared(Impairments, "sensor_filter")
    impairment_seed: int = shared(Impairments, "seed")
    comm_randomize: bool = option(False, "robust training: every episode draws its own V2V "
                                  "delay (0-0.5 s), loss (0-100 %, bursts half the time) and "
                                  "sensor noise (half the time), a quarter perfect", "plant")
    randomize_sensors: bool = option(True, "with --comm-randomize: sensor noise in half the "
                                     "episodes (--no-sensor-randomize: clean sensors, the same "
                                     "channel draws)", "plant", flag="sensor-randomize")
    # base
    base: str = shared(AgentConfig, "base")
    shield_ttc: float = shared(AgentConfig, "shield_ttc_s")
    observe_ahead: bool = shared(AgentConfig, "observe_ahead")
    command_history: int = shared(AgentConfig, "command_history")
    # reward
    w_gap: float = shared(RewardConfig, "w_gap")
    w_safe: float = shared(RewardConfig, "w_safe")
    w_comfort: float = shared(RewardConfig, "w_comfort")
    w_accel: float = shared(RewardConfig, "w_accel")
    w_spacing: float = shared(RewardConfig, "w_spacing")
    spacing_gap: float = shared(RewardConfig, "spacing_gap_s")
    spacing_head_gap: float | None = shared(RewardConfig, "spacing_head_gap_s")
    spacing_heavy_gap: float | None = shared(RewardConfig, "spacing_heavy_gap_s")
    spacing_budget: bool = shared(RewardConfig, "spacing_budget")
    paired_base: bool = shared(RewardConfig, "paired_base")
    w_critical: float = shared(RewardConfig, "w_critical")
    w_amplify: float = shared(RewardConfig, "w_amplify")
    lagrange_lr: float = option(0.0, "RCPO: step of a learned multiplier pricing close calls "
                                "while they are more frequent than the base's (0: off)",
                                "reward", low=0.0)
    jerk_scale: float = shared(RewardConfig, "jerk_scale_mps3")
    # agent
    algo: str = shared(AgentConfig, "algo")
    n_vehicles: int = shared(AgentConfig, "n_vehicles")
    message_dim: int = shared(AgentConfig, "message_dim")
    hidden: int = shared(AgentConfig, "hidden")
    actor_lr: float = shared(AgentConfig, "actor_lr")
    critic_lr: float = shared(AgentConfig, "critic_lr")
    tau: float = shared(AgentConfig, "tau")
    gamma: float = shared(AgentConfig, "gamma")
    batch_size: int = shared(AgentConfig, "batch_size")
    noise: float = shared(AgentConfig, "exploration_noise")
    noise_correlation: float = shared(AgentConfig, "noise_correlation")
    adj_max: float = shared(AgentConfig, "adj_max")
    smooth_jerk: float = shared(AgentConfig, "smooth_jerk")
    smooth_accel: float = shared(AgentConfig, "smooth_accel")
    adj_l2: float = shared(AgentConfig, "adj_l2")
    comm_fallback: str = shared(AgentConfig, "comm_fallback")
    comm_off: bool = shared(AgentConfig, "comm_off")
    bc_alpha: float = option(0.0, "behaviour-regularised actor (TD3+BC): it minimises "
                             "-α·Q/mean|Q| + ((a_adj - a_start)/adj_max)², a_start the start "
                             "policy's a_adj (0 on a residual start, the imitated or --init "
                             "actor's output), so it leaves the start only where Q says so "
                             "strongly; TD3+BC's α is 2.5 (0: off, the actor minimises -Q)",
                             "agent", low=0.0, high=1e6, metavar="ALPHA")
    # training
    steps: int = option(20_000, "vector steps (each steps every environment once)", "training",
                        low=1, high=MAX_STEPS)
    seed: int = option(0, "training seed", "training", low=0, high=2**31 - 1)
    num_envs: int = option(2, "parallel SUMO worker processes", "training", low=1, high=512,
                           flag="envs")
    learning_starts: int = option(1_000, "vector steps of exploration (or teacher) data before "
                                  "the first update", "training", low=0, high=MAX_STEPS)
    critic_burn_in: int = option(0, "vector steps after --learning-starts that train the "
                                 "critics only, the actor staying as it is (with "
                                 "--critic-calibration: at most)", "training", low=0,
                                 high=MAX_STEPS, metavar="STEPS")
    critic_holdout: float = option(0.0, "fraction of the start's data (stored by "
                                   "--learning-starts) held out of the critics' training, in "
                                   "blocks of 50 steps; the critic's TD error and rank "
                                   "correlation with realised returns there are logged at every "
                                   "validation (0: none; learn/calibration.py)", "training",
                                   low=0.0, high=0.5, metavar="F")
    critic_calibration: str = option("off", "the critic burn-in ends when the held-out TD "
                                     "error (td) or rank correlation of Q with realised returns "
                                     "(rank) has not improved for --calibration-patience "
                                     "checks (needs --critic-holdout and --critic-burn-in, its "
                                     "longest)", "training", choices=("off", "td", "rank"))
    calibration_every: int = option(250, "vector steps between checks of "
                                    "--critic-calibration", "training", low=1, high=MAX_STEPS)
    calibration_patience: int = option(3, "checks without improvement that end "
                                       "--critic-calibration", "training", low=1, high=1_000)
    updates_per_step: int = option(1, "gradient updates per update round", "training", low=1,
                                   high=1_000)
    update_every: int = option(1, "vector steps between update rounds (give --scale-rates to "
                               "learn as much per env step)", "training", low=1, high=1_000,
                               metavar="K")
    scale_rates: bool = option(False, "with --update-every K: learning rates and tau times K",
                               "training")
    lr_decay: bool = option(False, "learning rates fall linearly from --learning-starts to 0 "
                            "at --steps", "training")
    buffer_size: int = option(200_000, "replay buffer size", "training", unit="platoon "
                              "transitions", low=1, high=10_000_000)
    checkpoint_every: int = option(5_000, "vector steps between checkpoints", "training", low=1,
                                   high=MAX_STEPS)
    init: str | None = option(None, "warm start from a trained policy of the same "
                              "configuration (critics start fresh)", "training",
                              metavar="POLICY.pt")
    imitate: str | None = option(None, "warm start: a teacher (a Ploeg CACC, or two-ahead:c=C "
                                 "on a CACC base) drives for --learning-starts steps, then the "
                                 "actor is fitted to it", "training", metavar="TEACHER")
    imitate_updates: int = option(4_000, "behaviour-cloning gradient steps of --imitate",
                                  "training", low=1, high=10_000_000)
    imitate_target: str = option("realised", "on an ACC base, what the copied feed-forward "
                                 "carries: the predecessor's realised acceleration or its "
                                 "command", "training", choices=("realised", "command"))
    imitate_lr: float = option(1e-3, "Adam learning rate of --imitate", "training", low=0.0,
                               open_low=True)
    out: str | None = option(None, "policy file (none: policies/ALGO.pt)", "training",
                             metavar="PATH")
    command: str = option("", "the command line that ran (recorded in the policy file)",
                          "training", cli=False)
    # validation
    eval_every: int = option(2_000, "vector steps between validations", "validation", low=1,
                             high=MAX_STEPS)
    eval_events: int = option(8, "held-out training events validated on", "validation", low=1,
                              high=1_000_000)
    val_seed: int | None = option(None, "seed choosing the held-out events (none: --seed); "
                                  "one value compares runs of several seeds on the same "
                                  "events", "validation", low=0, high=2**31 - 1)
    val_source: str | None = option(None, "hold the validation events out of this event source "
                                    "only (the data file's source column)", "validation")
    val_events: str | None = option(None, "file of training event IDs held out and validated "
                                    "on too, e.g. the hardest", "validation", metavar="FILE",
                                    folder=EVENT_LISTS)
    select: str = option("margin", "how the kept checkpoint is chosen: margin, comfort, "
                         "metrics or reward (learn/selection.py)", "validation",
                         choices=("margin", "comfort", "metrics", "reward"))
    gate_string_stable: str | None = option(None, "keep every validated checkpoint in "
                                            "OUT.candidates/; the kept one is the best-scoring "
                                            "string stable on this plant", "validation",
                                            choices=("ideal", "real"))
    trust_string_stable: bool = option(False, "check each validated checkpoint's ‖Γ‖∞ as it "
                                       "is validated (the gate's plant, frequencies and "
                                       "amplitudes): an amplifying actor goes back to its "
                                       "anchor and --bc-alpha halves; a string-stable best "
                                       "becomes the anchor (learn/trust.py; needs "
                                       "--gate-string-stable and --bc-alpha)", "validation")
    trust_backtrack: int = option(0, "with --trust-string-stable, an amplifying actor first "
                                  "moves back towards its anchor in weight space, halving its "
                                  "step up to N times, and stays at the first string-stable "
                                  "point, validated there (a backtracking line search with "
                                  "‖Γ‖∞ ≤ 1 as its test; learn/trust.py); only if none is "
                                  "does it go back to the anchor (0: straight back)",
                                  "validation", low=0, high=8)
    val_workers: int = option(1, "processes validation runs in: this one and N - 1 spawned "
                              "ones, each with its own SUMO, sharing the events (the same "
                              "numbers; on 2 free cores, 2 about halve validation's wall time)",
                              "validation", low=1, high=64)
    val_impaired: bool = option(False, "validate also under 30 % loss in bursts, 0.2 s delay and "
                                "sensor noise (or under the fixed --comm-* options)",
                                "validation")

    def agent_config(self) -> AgentConfig:
        """The agent this run trains. With ``scale_rates`` its learning rates and target
        soft-update rate are ``update_every`` times the given ones, so that an update every K
        steps moves the networks about as far per env step as an update every step does
        (docs/bench.md: the same learning, measured over 10 seeds)."""
        k = self.update_every if self.scale_rates else 1
        return AgentConfig(**{**sourced(self, AgentConfig), "actor_lr": k * self.actor_lr,
                              "critic_lr": k * self.critic_lr, "tau": k * self.tau})

    @property
    def fixed_impairments(self) -> Impairments | None:
        """The fixed impairments of every training episode (``--comm-loss`` ...), or None."""
        return Impairments.from_options(self)

    @property
    def reward(self) -> RewardConfig:
        """The reward this run trains on: :data:`carl_sumo.config.REWARD` with its options."""
        return replace(REWARD, **sourced(self, RewardConfig))

    @property
    def policy_path(self) -> str:
        """The policy file this run writes: ``out``, or ``policies/ALGO.pt`` when none."""
        return self.out or f"policies/{self.algo.replace('-', '_')}.pt"

    def check(self) -> TrainConfig:
        """InputError, one line, for any value out of its range or any inconsistent pair of
        options (before anything runs); the config itself."""
        check_choices(self)
        for f in fields(self):
            check_range(flag_of(f), getattr(self, f.name), f.metadata)
        check_whole_steps(self.warmup)
        self._check_schedule()
        self._check_calibration()
        self._check_impairments()
        self._check_start()
        from carl_sumo.control.controllers import check_base

        check_base(self.base)
        self.agent_config()  # InputError for an inconsistent agent (AgentConfig's own checks)
        if self.learning_starts >= self.steps:
            raise InputError(f"--learning-starts {self.learning_starts} leaves no training step "
                             f"in --steps {self.steps}; give fewer learning starts or more steps")
        return self

    def _check_schedule(self) -> None:
        if self.scale_rates:
            if self.update_every == 1:
                raise InputError("--scale-rates multiplies the rates by --update-every K; give "
                                 "--update-every 2 or more, or leave --scale-rates out")
            if self.update_every * self.tau > 1:
                raise InputError(f"--scale-rates: --tau times --update-every is "
                                 f"{self.update_every * self.tau:g}, above 1; give a smaller "
                                 "--tau or --update-every")
        if self.sine_share != 0.25 and self.sine_events == 0:
            raise InputError("--sine-share is the share of episodes with a --sine-events "
                             "leader; give --sine-events N too, or leave it out")
        if self.oversample_times != 4 and self.oversample is None:
            raise InputError("--oversample-times weights the --oversample events; give "
                             "--oversample FILE too, or leave it out")
        if self.trust_backtrack and not self.trust_string_stable:
            raise InputError("--trust-backtrack shortens the steps --trust-string-stable "
                             "refuses; give --trust-string-stable too, or leave it out")
        if self.trust_string_stable and (self.gate_string_stable is None or self.bc_alpha <= 0):
            raise InputError("--trust-string-stable checks each checkpoint on the plant of "
                             "--gate-string-stable and moves the anchor of --bc-alpha; give "
                             "both (e.g. --gate-string-stable real --bc-alpha 2.5)")
        if self.gate_string_stable is not None and self.algo == "maddpg":
            raise InputError("--gate-string-stable tests a policy on a 5-vehicle platoon; "
                             "maddpg runs only its trained length: leave the gate out")

    def _check_calibration(self) -> None:
        from carl_sumo.learn.calibration import steps_needed

        if self.critic_calibration != "off":
            if self.critic_holdout == 0 or self.critic_burn_in == 0:
                raise InputError("--critic-calibration measures the critic on held-out data "
                                 "for at most --critic-burn-in steps: give --critic-holdout F "
                                 "and --critic-burn-in STEPS too")
        elif (self.calibration_every, self.calibration_patience) != (250, 3):
            raise InputError("--calibration-every and --calibration-patience set "
                             "--critic-calibration; give it too, or leave them out")
        if self.critic_holdout > 0:
            need = steps_needed(self.critic_holdout, self.gamma)
            if self.learning_starts < need:
                raise InputError(f"--critic-holdout {self.critic_holdout:g} holds out blocks "
                                 f"of the --learning-starts data: give --learning-starts "
                                 f"{need} or more (got {self.learning_starts})")

    def _check_impairments(self) -> None:
        if self.sensor_filter and not self.sensor_noise and not self.comm_randomize:
            raise InputError("--sensor-filter filters noisy measurements: give it with "
                             "--sensor-noise or --comm-randomize")
        fixed = self.fixed_impairments  # InputError for a bad value
        if self.plant_randomize and (self.comm_randomize or fixed is not None):
            raise InputError("--plant-randomize draws every episode's plant and channel itself; "
                             "leave out --comm-randomize, --plant and the --comm-* options")
        if not self.randomize_sensors and not self.comm_randomize:
            raise InputError("--no-sensor-randomize narrows --comm-randomize; give both, or "
                             "neither")
        if fixed is not None and self.comm_randomize:
            raise InputError("--comm-randomize draws every episode's impairments itself; give "
                             "it or fixed --comm-*/--sensor-noise options, not both")

    def _check_start(self) -> None:
        if self.init is not None:
            if self.imitate is not None:
                raise InputError("--init starts a new run from a policy and --imitate starts "
                                 "from a teacher: give one of them")
            from carl_sumo.learn.policy import read_policy_payload

            read_policy_payload(self.init)
        if self.imitate_target != "realised" and (self.imitate is None or self.base == "idm"):
            raise InputError("--imitate-target is for --imitate on an ACC base (--base acc:...)")
        if self.imitate_updates != 4_000 and self.imitate is None:
            raise InputError("--imitate-updates sets the steps of --imitate; give --imitate "
                             "TEACHER too, or leave it out")
        if self.imitate is not None:
            from carl_sumo.learn.imitation import check_teacher_base, teacher

            teacher(self.imitate)
            check_teacher_base(self.imitate, self.base)


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
    if cfg.sine_events > 0:  # the string-stability test's excitation, in training and validation
        from carl_sumo.data.synthetic import sine_events

        sine = sine_events(cfg.sine_events, val_seed)
        k = max(1, cfg.sine_events // 4)
        times = max(1, round(cfg.sine_share * len(train) /
                             ((1 - cfg.sine_share) * max(1, len(sine) - k))))
        train, val = train + sine[k:] * times, val + sine[:k]
    if cfg.exclude_events is not None:  # e.g. recordings that start in a collision; the
        excluded = set(read_event_ids(cfg.exclude_events))  # draws above stay as without it
        _check_known("--exclude-events", sorted(excluded), events)
        train = [e for e in train if e.event_id not in excluded]
        val = [e for e in val if e.event_id not in excluded]
    if not train:
        raise InputError(f"no training event is left after holding out {len(val)} for "
                         "validation (--val-events, --eval-events) and --exclude-events; hold "
                         "out fewer events")
    if cfg.warmup:  # every episode first settles; validation scores the recorded part
        train = [e.with_warmup(cfg.warmup) for e in train]
        val = [e.with_warmup(cfg.warmup) for e in val]
    _check_paired(cfg, train)
    return train, val


def _check_paired(cfg: TrainConfig, train: Sequence[Event]) -> None:
    """``--paired-base`` measures a decision against the base from its episode's start: the
    base must hold its learned gap (``gh``) for longer than every training episode."""
    if not cfg.paired_base:
        return
    from carl_sumo.control.controllers import hold_steps

    longest = max(e.n_samples for e in train)
    if hold_steps(cfg.base) < longest:
        raise InputError(f"--paired-base measures each decision against the base over its "
                         f"whole episode: name the base with a gh of at least "
                         f"{longest * DT_S:.0f} s (its longest training episode), e.g. "
                         "...:gh=1000")


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
