"""The CACC controllers of a study: built-in laws and policy files, run on the CACC chains that
form and break in traffic (:func:`carl_sumo.experiments.chain_formation.form_chains`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from carl_sumo.config import BOUNDS
from carl_sumo.control.cacc import PloegChains, parse_ploeg
from carl_sumo.control.classical import classical_chains, is_classical_name
from carl_sumo.control.mpc import MPCChains
from carl_sumo.control.channel import Impairments, KeyedChannel
from carl_sumo.control.controllers import (CommandHistory, adjustment_bounds, applied_acceleration,
                                           shield_adjustment, total_acceleration)
from carl_sumo.control.external import is_external_name, load_external
from carl_sumo.errors import InputError

STUDY_CONTROLLERS = ("idm-external", "sumo-cacc", "ploeg[:h=H:kp=KP:kd=KD]", "ploeg-tuned:h=H",
                     "mpc[:h=H:...]")
"""Built-in CACC controllers of a study; a policy file (.pt) and ``module:attribute`` /
``file.py:attribute`` (:mod:`carl_sumo.control.external`) are the others."""


class ExternalChains:
    """An external controller (:func:`carl_sumo.control.external.load_external`) on the CACC
    chains of a study: each chain is a platoon of its own, observations (len(chain), 4) head
    first. Chains form and break every step in traffic, so ``reset(len(chain))`` comes before
    each chain's call: the controller keeps no state from one step to the next here."""

    def __init__(self, name: str):
        self.name = name
        self.inner = load_external(name)
        self.inner.counting = False  # reset every step here: the step is counted below
        self._step = 0

    def reset(self) -> None:
        """A new run: nothing to forget (``reset(len(chain))`` comes before every chain's call)."""
        self._step = 0

    def connect(self, impairments: Impairments, run_id: str) -> None:
        """Hand the impaired channel to the controller when it takes one."""
        if hasattr(self.inner, "connect"):
            self.inner.connect(impairments, run_id)

    def acceleration(self, obs: np.ndarray, chains: list[list[int]], ids: list[str],
                     ahead: list[tuple[str, float] | None],
                     last_acc: dict[str, float]) -> np.ndarray:
        """a (m/s², shape (m,)) of the CACC vehicles, one chain at a time (the interface of
        :class:`ChainController`)."""
        out = np.zeros(obs.shape[0])
        self.inner.step, self._step = self._step, self._step + 1
        for chain in chains:
            self.inner.reset(len(chain))
            out[chain] = applied_acceleration(self.inner, np.ascontiguousarray(obs[chain]))
        return np.clip(out, BOUNDS.acc_min_mps2, BOUNDS.acc_max_mps2)


class ChainController:
    """a_adj of all CACC vehicles from their chains: zero (``idm-external``) or a policy, on IDM
    or, for a policy trained on a classical base, on that base run on the same chains."""

    def __init__(self, name: str):
        self.name = name
        self.agent = None
        self.compiled = None
        self.base: PloegChains | None = None
        self.links: tuple[KeyedChannel, KeyedChannel] | None = None
        self.history: CommandHistory | None = None  # the vehicles' last commands, by ID
        self._k = 0
        if name != "idm-external":
            from carl_sumo.learn.policy import load_policy

            agent, _ = load_policy(Path(name))
            if agent.cfg.algo == "maddpg":
                raise InputError(f"policy {name} is MADDPG: it has one actor per platoon position "
                                 f"for exactly {agent.cfg.n_vehicles} vehicles and cannot run CACC "
                                 "chains that form and break in traffic; use a CA-TD3, CA-DDPG, "
                                 "TD3 or DDPG policy")
            from carl_sumo.learn.inference import CompiledActor

            self.agent = agent
            self.compiled = CompiledActor(agent)
            if agent.cfg.residual:
                self.base = PloegChains(parse_ploeg(agent.cfg.base), agent.cfg.base)
                if agent.cfg.command_history:
                    self.history = CommandHistory(agent.cfg.command_history)

    def reset(self) -> None:
        """Forget the links and the base's states: a new run starts."""
        self.links, self._k = None, 0
        if self.base is not None:
            self.base.reset()
        if self.history is not None:
            self.history.reset()

    def arm(self, vehicle_ids: set[str]) -> None:
        """Arm a classical base's reaction layer of these vehicles (PloegChains.arm)."""
        if self.base is not None:
            self.base.arm(vehicle_ids)

    def merge_behind(self, merge_m: dict[str, float]) -> None:
        """Tell a classical base each vehicle's distance to a zipper merge's point while its
        vehicle ahead is still on the other feeding lane (PloegChains.merge_behind)."""
        if self.base is not None:
            self.base.merge_behind(merge_m)

    def connect(self, impairments: Impairments, run_id: str) -> None:
        """Carry the CA messages (streams 2 and 3 of ``run_id``) and a classical base's
        predecessor states over impaired vehicle-keyed links (:class:`KeyedChannel`)."""
        m = self.compiled.message_dim if self.compiled is not None else 0
        if m:
            self.links = (KeyedChannel(m, impairments, impairments.rng(run_id, 2)),
                          KeyedChannel(m, impairments, impairments.rng(run_id, 3)))
        if self.base is not None:
            self.base.connect(impairments, run_id)

    def acceleration(self, obs: np.ndarray, chains: list[list[int]], ids: list[str],
                     ahead: list[tuple[str, float] | None],
                     last_acc: dict[str, float]) -> np.ndarray:
        """a (m/s², shape (m,)) of the CACC vehicles: clip(a_IDM + a_adj), or a_adj in the law of
        a classical base (the interface of
        :class:`carl_sumo.control.cacc.PloegChains`; ids, ahead and last_acc serve a classical base)."""
        if self.base is None:
            if self.agent is not None and self.agent.cfg.observe_ahead:
                # the acceleration of the vehicle ahead over the last step (as the policy's
                # AheadAcceleration measures it in a platoon); 0 with no vehicle ahead
                a_ahead = [last_acc.get(a[0], 0.0) if a is not None else 0.0 for a in ahead]
                adj = self.adjustment(np.column_stack([obs, a_ahead]), chains, ids)
            else:
                adj = self.adjustment(obs, chains, ids)
            bounds = adjustment_bounds(self.agent.cfg.adj_max) if self.agent else BOUNDS
            return total_acceleration(obs, adj, bounds=bounds)
        seen = np.column_stack([obs, self.base.acceleration(obs, chains, ids, ahead, last_acc,
                                                            commit=False)])
        if self.history is None:
            return self.base.acceleration(obs, chains, ids, ahead, last_acc,
                                          self.adjustment(seen, chains, ids))
        adj = self.adjustment(np.column_stack([seen, self.history.columns(ids)]), chains, ids)
        accel = self.base.acceleration(obs, chains, ids, ahead, last_acc, adj)
        self.history.push(accel, ids)
        return accel

    def adjustment(self, obs: np.ndarray, chains: list[list[int]],
                   ids: list[str] | None = None) -> np.ndarray:
        """a_adj (m/s², shape (m,)) for observations (m, 4) of the CACC vehicles ``ids`` and
        their chains (the IDs key the impaired links, when there are any)."""
        m = obs.shape[0]
        if self.compiled is None or m == 0:
            return np.zeros(m)
        out = np.empty(m)
        for chain in chains:  # one chain at a time: the cost grows with the vehicles, not the chains
            chain_obs = np.ascontiguousarray(obs[chain])
            if self.links is None or ids is None:
                out[chain] = self.compiled(chain_obs)
            else:
                out[chain] = self.compiled.act_keyed(chain_obs, [ids[i] for i in chain],
                                                     *self.links, self._k)
        self._k += 1
        return shield_adjustment(obs, out, self.agent.cfg.shield_ttc_s)


def know_vehicle(controller, vehicle_id: str, a_max_mps2: float, b_max_mps2: float) -> None:
    """Tell a classical law (:meth:`carl_sumo.control.cacc.PloegChains.know_vehicle`) or a
    policy's classical base what one vehicle's powertrain can do (m/s², positive; only a law named
    with ``aw=1`` uses it); any other controller ignores it."""
    law = getattr(controller, "base", controller)
    if hasattr(law, "know_vehicle"):
        law.know_vehicle(vehicle_id, a_max_mps2, b_max_mps2)


def resolve_study_controller(name: str, plant: str = "ideal"
                             ) -> tuple[str, ChainController | PloegChains | MPCChains
                                        | ExternalChains | None]:
    """(CACC kind of :data:`carl_sumo.sim.traffic.CACC_TYPES`, controller); InputError if unknown.
    ``plant``: the plant a ``-tuned`` law's gains are read for (:attr:`Impairments.plant_key`)."""
    if name == "sumo-cacc":
        return "sumo", None
    if is_classical_name(name):
        return "external", classical_chains(name, plant)
    if name == "idm-external" or name.endswith(".pt"):
        return "external", ChainController(name)
    if is_external_name(name):
        return "external", ExternalChains(name)
    raise InputError(f"unknown study controller {name!r}; choose {', '.join(STUDY_CONTROLLERS)}, "
                     "the path of a policy file (.pt) or module:attribute / file.py:attribute")
