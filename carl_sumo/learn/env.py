"""PettingZoo ``ParallelEnv`` of a CACC platoon in SUMO: agents are the CACC followers.

Each agent observes o_i = [v_i, a_i, d_i, Δv_i] (m/s, m/s², m, m/s) and acts with its acceleration
adjustment a_adj (m/s², bounded by ``ControlBounds.adj_max_mps2``); it applies
a = clip(a_IDM + a_adj) on the paper's IDM base, or a_adj enters the law of a classical CACC base
such as ``ploeg-tuned:h=0.8`` (:func:`carl_sumo.control.controllers.base_controller`), whose command
a_base is then a fifth observation. Episodes replay one event each; a collision terminates every
agent, the end of the event truncates them. :meth:`PlatoonEnv.step_array` is the same step on arrays,
for batched (communication-aware) controllers.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Sequence

import numpy as np
from gymnasium import spaces
from pettingzoo import ParallelEnv

from carl_sumo.config import BOUNDS, IDM, REWARD, SCENARIO, ControlBounds, IDMParams, \
    RewardConfig, ScenarioConfig
from carl_sumo.control import controllers
from carl_sumo.learn import reward as reward_module
from carl_sumo.control.channel import Impairments
from carl_sumo.data.events import Event
from carl_sumo.errors import InputError
from carl_sumo.control.sensors import Sensors
from carl_sumo.sim.sumo import DEFAULT_NET, PlatoonSim, check_fits
from carl_sumo.sim.vehicle import Plant


class PlatoonEnv(ParallelEnv):
    """A platoon of ``n_followers`` CACC vehicles behind a leader replaying NGSIM events."""

    metadata = {"name": "carl_sumo_platoon_v0", "render_modes": []}

    def __init__(self, events: Sequence[Event], n_followers: int = 10,
                 net_path: str | Path = DEFAULT_NET, reward: RewardConfig = REWARD,
                 idm: IDMParams = IDM, bounds: ControlBounds = BOUNDS,
                 scenario: ScenarioConfig = SCENARIO, base: str = "idm",
                 observe_ahead: bool = False, shield_ttc_s: float = 0.0,
                 plant: Plant | None = None, command_history: int = 0):
        if not events:
            raise InputError("the environment needs at least one event")
        self.events = list(events)
        self.sim = PlatoonSim(net_path, "external", scenario)
        for event in self.events:
            check_fits(self.sim.route, event, n_followers, scenario)
        self.n_followers = n_followers
        self.plant = plant  # the followers' vehicle dynamics (None: the ideal plant)
        self.reward_cfg, self.idm, self.bounds = reward, idm, bounds
        self.base = base
        self._base = controllers.base_controller(base)  # None: IDM, in the compiled kernel
        if observe_ahead and self._base is not None:
            raise InputError("observe_ahead is for the IDM base (a classical base's a_base "
                             "already carries the predecessor's acceleration)")
        self._ahead = controllers.AheadAcceleration() if observe_ahead else None
        if command_history and self._base is None:
            raise InputError("command_history is for a classical base, whose law sends the "
                             "command the vehicle remembers")
        self._history = controllers.CommandHistory(command_history) if command_history else None
        self.shield_ttc_s = shield_ttc_s  # the policy's safety shield (controllers.shield_adjustment)
        # kernels and their parameters, bound once: step_array runs every 0.1 s simulated
        self._control = controllers._total_acceleration
        self._control_params = controllers._params(idm, bounds)
        self._reward = reward_module._platoon_reward
        self._reward_params = reward_module._params(reward)
        self._spacing_gaps = reward_module.spacing_gaps(reward, n_followers)  # per episode (s)
        self.possible_agents = [f"cacc_{i}" for i in range(n_followers)]
        self.agents: list[str] = []
        high = np.float32(bounds.adj_max_mps2)
        self._action_space = spaces.Box(-high, high, shape=(1,), dtype=np.float32)
        # a classical base adds its command a_base, observe_ahead the acceleration ahead, a
        # command history the last k commands
        obs_dim = (4 if self._base is None and self._ahead is None else 5) + command_history
        self._observation_space = spaces.Box(-np.inf, np.inf, shape=(obs_dim,), dtype=np.float32)
        self._rng = np.random.default_rng()
        self._sensors: Sensors | None = None
        self.event: Event | None = None

    @property
    def hold_steps(self) -> int:
        """Steps (0.1 s) per decision of the learned term: a base with ``gh=S`` reads it only
        every S s (:mod:`carl_sumo.control.cacc`), so a trainer steps S s per action (1: every
        step)."""
        return controllers.decision_steps(self._base)

    def observation_space(self, agent: str) -> spaces.Box:
        return self._observation_space

    def action_space(self, agent: str) -> spaces.Box:
        return self._action_space

    # -------------------------------------------------------------------------------- arrays
    def reset_array(self, seed: int | None = None, event: Event | None = None,
                    impairments: Impairments | None = None) -> np.ndarray:
        """Start an episode on ``event`` (default: a random one); observations (n, 4).
        ``impairments`` (:mod:`carl_sumo.control.channel`): this episode's vehicles measure their gap and
        relative speed with noise (control, observations and shield use the measured values,
        the reward the true ones), and a classical base's predecessor messages cross impaired
        links; the CA module's own messages are the caller's (``channel.PlatoonLinks``); its
        ``plant`` (else the env's) gives the followers' vehicle dynamics."""
        if seed is not None:
            self._rng = np.random.default_rng(seed)
        self.event = event if event is not None else \
            self.events[int(self._rng.integers(len(self.events)))]
        plant = impairments.plant if impairments is not None and impairments.plant is not None \
            else self.plant
        self.sim.reset(self.event, self.n_followers, plant=plant,
                       plant_seed=impairments.seed if impairments is not None else 0)
        self._sensors = Sensors.of(impairments, self.event.event_id)
        b_max = self.sim.powertrains.b_max if self.sim.powertrains is not None else None
        self._spacing_gaps = reward_module.spacing_gaps(self.reward_cfg, self.n_followers, b_max)
        if self._base is not None:
            self._base.reset(self.n_followers)
            if self.sim.powertrains is not None:
                self._base.know_vehicles(self.sim.powertrains.a_max, self.sim.powertrains.b_max)
            if impairments is not None and not impairments.perfect_channel:
                self._base.connect(impairments, self.event.event_id)
        if self._ahead is not None:
            self._ahead.reset()
        if self._history is not None:
            self._history.reset(self.n_followers)
        self._obs = self._observe()
        self._first_step = True
        return self._obs

    def _observe(self) -> np.ndarray:
        """o = [v, a, d, Δv] per follower; on a classical base also a_base (m/s²), what the
        base alone would apply at the coming step (a preview: its state moves in the step); with
        observe_ahead also a_ahead (m/s², :class:`carl_sumo.control.controllers.AheadAcceleration`);
        with a command history the last k commands (m/s², the latest first)."""
        obs = self._true = self.sim.observation()
        if self._sensors is not None:
            obs = self._sensors.measure(obs)
        if self._ahead is not None:
            return np.column_stack([obs, self._ahead(obs)])
        if self._base is None:
            return obs
        obs = np.column_stack([obs, self._base.acceleration(obs, commit=False)])
        return obs if self._history is None else np.column_stack([obs, self._history.columns()])

    @property
    def true_observation(self) -> np.ndarray:
        """This step's [v, a, d, Δv] (n, 4) as they are (what the vehicles see may be noisy)."""
        return self._true

    def step_array(self, adjustment: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, bool, bool, np.ndarray]:
        """Apply a_adj (m/s², shape (n,)); returns obs, rewards, terminated, truncated, a."""
        if adjustment.dtype != np.float64:
            adjustment = adjustment.astype(np.float64)
        if self.shield_ttc_s > 0:
            adjustment = controllers.shield_adjustment(self._obs, adjustment, self.shield_ttc_s)
        if self._base is None:
            accel = self._control(self._obs, adjustment, *self._control_params)
        else:
            adj = np.clip(adjustment, -self.bounds.adj_max_mps2, self.bounds.adj_max_mps2)
            accel = self._base.acceleration(self._obs[:, :4], adj)
            if self._history is not None:
                self._history.push(accel)
        # the first step has no previous acceleration: its jerk is taken as 0, not (a - 0)/dt
        prev_acc = accel if self._first_step else self.sim.acc
        self._first_step = False
        self.sim.step(accel)
        self._obs = self._observe()
        rewards, collided = self._reward(self._true, prev_acc, self._spacing_gaps,
                                         *self._reward_params)
        terminated = bool(collided.any())
        return self._obs, rewards, terminated, self.sim.done and not terminated, accel

    # ---------------------------------------------------------------------------- PettingZoo
    def reset(self, seed: int | None = None, options: dict[str, Any] | None = None
              ) -> tuple[dict[str, np.ndarray], dict[str, dict]]:
        event = None
        if options and "event_id" in options:
            matches = [e for e in self.events if e.event_id == options["event_id"]]
            if not matches:
                raise InputError(f"unknown event {options['event_id']!r}")
            event = matches[0]
        obs = self.reset_array(seed, event).astype(np.float32)
        self.agents = list(self.possible_agents)
        return ({a: obs[i] for i, a in enumerate(self.agents)},
                {a: {"event_id": self.event.event_id} for a in self.agents})

    def step(self, actions: dict[str, np.ndarray]):
        adjustment = np.array([float(np.asarray(actions[a]).reshape(-1)[0]) for a in self.agents])
        obs, rewards, terminated, truncated, accel = self.step_array(adjustment)
        obs32 = obs.astype(np.float32)
        agents = self.agents
        observations = {a: obs32[i] for i, a in enumerate(agents)}
        reward_dict = {a: float(r) for a, r in zip(agents, rewards.tolist())}
        terms = dict.fromkeys(agents, terminated)
        truncs = dict.fromkeys(agents, truncated)
        infos = {a: {"acceleration": float(x)} for a, x in zip(agents, accel.tolist())}
        if terminated or truncated:
            self.agents = []
        return observations, reward_dict, terms, truncs, infos

    def close(self) -> None:
        pass
