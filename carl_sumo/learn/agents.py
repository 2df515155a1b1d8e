"""DDPG-family agents over platoon tensors: CA-TD3, CA-DDPG, TD3, DDPG and MADDPG.

Every agent acts on a platoon observation tensor (batch, n, 4) with a mask of real vehicles and
outputs a_adj per vehicle, bounded to ±``adj_max`` by tanh. Critics give one Q per vehicle, trained
on that vehicle's reward; losses average over real vehicles only.

| algo | actor | critic | trained on |
|---|---|---|---|
| ``ca-td3``, ``ca-ddpg`` | CommunicationAware (shared weights) | CommunicationAware, own messages | 10 vehicles, runs any length |
| ``td3``, ``ddpg`` | PerVehicle MLP on o_i | PerVehicle MLP on (o_i, a_i) | 1 vehicle, runs any length |
| ``maddpg`` | one MLP per vehicle | central critic on all (o, a) | a fixed length only |

TD3 (Fujimoto et al. 2018) adds twin critics, target policy smoothing and delayed actor updates.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np
import torch
from torch import nn

from carl_sumo.learn.ca_scan import ca_forward
from carl_sumo.config import BOUNDS, DT_S, IDM
from carl_sumo.control.channel import Impairments
from carl_sumo.errors import InputError
from carl_sumo.options import check_choices, option
from carl_sumo.learn.models import CentralCritic, CommunicationAware, PerAgentActors, PerVehicle

Links = tuple[torch.Tensor, torch.Tensor, torch.Tensor, torch.Tensor]
"""How a CA actor's incoming messages arrived: forward modes, held, backward modes, held
(:meth:`carl_sumo.learn.models.CommunicationAware.forward_over`)."""

ALGOS = ("ca-td3", "ca-ddpg", "td3", "ddpg", "maddpg")
MAX_TRAIN_VEHICLES = 200
"""The longest platoon ``train`` accepts (its replay buffer grows with the platoon)."""
COMM_FALLBACKS = ("boundary", "base")
"""What a CA vehicle does when it hears no neighbour (past the timeout; :mod:`carl_sumo.control.channel`):
``boundary``: its CA module takes the learned boundary messages and it acts as a chain end;
``base``: that, and its adjustment fades out with its messages, so it drives on its base alone."""

OBS_SCALE = (20.0, 3.0, 50.0, 5.0)
"""Observations [v (m/s), a (m/s²), d (m), Δv (m/s)] are divided by these before the networks."""

GAP_CLIP_M = 150.0
"""Gaps above this are seen as this (m): beyond it a follower is effectively free."""

BASE_SCALE = 3.0
"""A fifth observation column, an acceleration (a_base on a classical base, or a_ahead), is
divided by this (m/s²)."""


@dataclass(frozen=True)
class AgentConfig:
    """Hyper-parameters of an agent (stored in every policy file)."""

    algo: str = option("ca-td3", "the algorithm", "agent", choices=ALGOS)
    n_vehicles: int = option(10, "CACC followers trained on (a shared-weight policy runs any "
                             "length; MADDPG only this one)", "agent", low=1,
                             high=MAX_TRAIN_VEHICLES, flag="vehicles")
    message_dim: int = option(16, "V2V message width (CA models)", "agent", low=1, high=4096)
    hidden: int = option(64, "hidden layer width", "agent", low=1, high=65_536)
    adj_max: float = option(3.0, "bound of the learned adjustment |a_adj|", "agent",
                            unit="m/s²", low=0.0, open_low=True, high=100.0)
    gamma: float = option(0.98, "discount per decision (a 0.1 s step; gh=S s on a base "
                          "that holds its learned gap)", "agent", low=0.0, high=1.0,
                          open_low=True)
    tau: float = option(0.005, "soft-update rate of the target networks per update", "agent",
                        low=0.0, high=1.0, open_low=True)
    actor_lr: float = option(3e-4, "actor learning rate", "agent", low=0.0, open_low=True)
    critic_lr: float = option(1e-3, "critic learning rate", "agent", low=0.0, open_low=True)
    batch_size: int = option(128, "transitions per gradient update", "agent", low=1,
                             high=1_000_000)
    policy_delay: int = option(2, "TD3: an actor update every this many critic updates",
                               "agent", cli=False)
    target_noise: float = option(0.2, "TD3: target policy smoothing noise, a fraction of "
                                 "adj_max", "agent", cli=False)
    target_noise_clip: float = option(0.5, "TD3: clip of that noise, a fraction of adj_max",
                                      "agent", cli=False)
    exploration_noise: float = option(0.15, "exploration noise std, a fraction of the a_adj "
                                      "bound", "agent", low=0.0, flag="noise")
    noise_correlation: float = option(0.98, "AR(1) coefficient of the exploration noise per "
                                      "step (0: white; 0.98: τ ≈ 5 s)", "agent", low=0.0,
                                      high=1.0, open_high=True)
    preactivation_l2: float = option(0.01, "actor loss penalty on tanh inputs (keeps tanh "
                                     "unsaturated)", "agent", cli=False)
    max_grad_norm: float = option(10.0, "gradient norm clipping of actor and critic updates",
                                  "agent", cli=False)
    smooth_jerk: float = option(0.0, "actor loss weight on the policy's jerk (CAPS-style)",
                                "agent", unit="1/(m/s³)²", low=0.0)
    smooth_accel: float = option(0.0, "actor loss weight on the policy's acceleration",
                                 "agent", unit="1/(m/s²)²", low=0.0)
    adj_l2: float = option(0.0, "actor loss weight on the adjustment itself, W·a_adj² (keeps "
                           "the learned term near its base)", "agent", unit="1/(m/s²)²",
                           low=0.0)
    base: str = option("idm", "base model under the learned adjustment: idm (the paper's) or a "
                       "classical law: a preset (product-base, cacc-real) or a name such as "
                       "ploeg-tuned:h=0.8 (the actor then starts at a_adj = 0)", "base",
                       metavar="NAME")
    observe_ahead: bool = option(False, "IDM base: each vehicle also observes the acceleration "
                                 "of the vehicle ahead as its radar measures it (a fifth "
                                 "column a_ahead; controllers.AheadAcceleration)", "base")
    command_history: int = option(0, "classical base: each vehicle also observes its own last "
                                  "K commands, which the lagged plant has not realised yet (Lin "
                                  "et al. 2019; the observation ends with them, the latest "
                                  "first; controllers.CommandHistory)", "base", unit="steps",
                                  low=0, high=50, metavar="K")
    shield_ttc_s: float = option(0.0, "safety shield: a follower closing in below this time "
                                 "to collision gets no positive adjustment (0: off); part of "
                                 "the policy", "base", unit="s", low=0.0, high=60.0,
                                 metavar="S", flag="shield-ttc")
    comm_fallback: str = option("boundary", "hearing no neighbour at run time: boundary (act "
                                "as a chain end) or base (also drop the adjustment, as Ploeg's "
                                "CACC drops to ACC; channel.py); part of the policy", "agent",
                                choices=COMM_FALLBACKS)
    comm_off: bool = option(False, "CA models: cut the V2V messages, every vehicle hears only "
                            "the boundary messages (the communication ablation, CA-off); part "
                            "of the policy", "agent")

    def __post_init__(self) -> None:
        check_choices(self)  # algo, comm_fallback
        if self.observe_ahead and self.base != "idm":
            raise InputError("--observe-ahead is for the IDM base; a classical base's command "
                             "a_base already carries its predecessor's acceleration")
        if self.command_history and self.base == "idm":
            raise InputError("--command-history is for a classical base (--base), whose law "
                             "sends the command the vehicle remembers")
        if self.comm_off and not self.communication_aware:
            raise InputError("--comm-off cuts the CA messages: it is for ca-td3 and ca-ddpg")
        if self.comm_fallback != "boundary" and not self.communication_aware:
            raise InputError("--comm-fallback is for CA models (ca-td3, ca-ddpg), whose vehicles "
                             "exchange messages; the others hear nothing to lose")

    def check_length(self, n: int) -> None:
        """InputError (one line) when a platoon of n vehicles is one this agent cannot run."""
        if self.algo == "maddpg" and n != self.n_vehicles:
            raise InputError(f"this MADDPG policy was trained for {self.n_vehicles} vehicles "
                             f"and cannot run {n}: MADDPG has one actor per vehicle; use "
                             f"--vehicles {self.n_vehicles} or a CA/DDPG/TD3 policy")

    def message_impairments(self, impairments: Impairments | None) -> Impairments | None:
        """What the CA messages cross: ``impairments`` (None: a perfect channel), or with
        ``comm_off`` a channel that loses every message."""
        if self.comm_off:
            return replace(impairments or Impairments(), loss=1.0)
        return impairments

    @property
    def residual(self) -> bool:
        """On a classical base the actor starts at a_adj = 0 (see :func:`zero_action_output`)."""
        return self.base != "idm"

    @property
    def common_mode_void(self) -> bool:
        """On a base whose learned gaps keep a headway budget (``gp=T:gb=1``) the law removes
        the platoon's common offset (:func:`carl_sumo.control.ploeg_names.budgeted_offsets` is
        unchanged when every target moves alike), so the critics see the actions without it."""
        if not self.residual:
            return False
        from carl_sumo.control.cacc import parse_ploeg

        params = parse_ploeg(self.base)
        return params.gap_policy_s is not None and params.gap_budget

    @property
    def adjustment_gain(self) -> float:
        """da/da_adj within one step (-): 1 on IDM (a = a_IDM + a_adj); dt/h on a Ploeg base,
        whose first-order law lets that share of a_adj through at once."""
        if not self.residual:
            return 1.0
        from carl_sumo.control.cacc import parse_ploeg

        return DT_S / parse_ploeg(self.base).time_gap_s

    @property
    def obs_dim(self) -> int:
        """4: o = [v, a, d, Δv]; 5 on a classical base, whose command a_base (m/s²) the vehicle
        knows (it computes it) and sees as a fifth column: the adjustment has to know what it
        adjusts, since a_base has a state and is not a function of o. 5 as well with
        ``observe_ahead``: the acceleration a_ahead of the vehicle ahead (m/s²). Then, with
        ``command_history`` k, the vehicle's own last k commands (m/s², the latest first)."""
        return (5 if self.residual or self.observe_ahead else 4) + self.command_history

    @property
    def communication_aware(self) -> bool:
        return self.algo.startswith("ca-")

    @property
    def twin(self) -> bool:
        return self.algo.endswith("td3")


def normalise(obs: torch.Tensor) -> torch.Tensor:
    """Scale observations for the networks (see OBS_SCALE, GAP_CLIP_M; a fifth column a_base
    by BASE_SCALE)."""
    scale = torch.tensor(OBS_SCALE + (BASE_SCALE,) * (obs.shape[-1] - 4), dtype=obs.dtype,
                         device=obs.device)
    obs = torch.cat([obs[..., :2], obs[..., 2:3].clamp(max=GAP_CLIP_M), obs[..., 3:]], dim=-1)
    return obs / scale


def idm_acceleration_torch(obs: torch.Tensor) -> torch.Tensor:
    """IDM acceleration (m/s²) of observations [v, a, d, Δv] (..., 4): the same expression as
    :func:`carl_sumo.control.controllers.idm_acceleration` (parameters in :data:`carl_sumo.config.IDM`),
    differentiable, for the actor's smoothness terms."""
    v, gap, dv = obs[..., 0], obs[..., 2].clamp(min=1e-6), obs[..., 3]
    s_star = IDM.min_gap_m + (v * IDM.time_headway_s
                              - v * dv / (2.0 * (IDM.accel_mps2 * IDM.decel_mps2) ** 0.5)).clamp(min=0)
    return IDM.accel_mps2 * (1.0 - (v / IDM.desired_speed_mps) ** IDM.delta - (s_star / gap) ** 2)


@torch.no_grad()
def zero_action_output(actor: nn.Module) -> None:
    """Zero the weights and bias of the actor's action output, so that a_adj = 0 for every
    input at the start: a residual policy starts exactly on its classical base and moves off it
    only where the critic says that pays. The layers below keep their random initialisation: the
    output row learns from the first actor update, and the layers below from the next."""
    last = [m for m in actor.modules() if isinstance(m, nn.Linear)][-1]
    last.weight[-1:].zero_()  # the action is the last output (after the CA message)
    last.bias[-1:].zero_()


def _networks(cfg: AgentConfig) -> tuple[nn.Module, nn.Module]:
    """(actor, critic) of an algorithm; actor outputs pre-tanh, critic one Q per vehicle."""
    d = cfg.obs_dim
    if cfg.communication_aware:
        return (CommunicationAware(d, 1, cfg.message_dim, cfg.hidden),
                CommunicationAware(d + 1, 1, cfg.message_dim, cfg.hidden))
    if cfg.algo == "maddpg":
        return (PerAgentActors(cfg.n_vehicles, d, 1, cfg.hidden),
                CentralCritic(cfg.n_vehicles, d + 1, 2 * cfg.hidden))
    return PerVehicle(d, 1, cfg.hidden), PerVehicle(d + 1, 1, cfg.hidden)


class Agent(nn.Module):
    """Actor, critic(s) and their targets for one algorithm."""

    def __init__(self, cfg: AgentConfig):
        super().__init__()
        self.cfg = cfg
        self.actor, self.critic1 = _networks(cfg)
        self._adjustment_gain = cfg.adjustment_gain
        self._common_mode_void = cfg.common_mode_void
        if cfg.residual:
            for net in getattr(self.actor, "nets", [self.actor]):  # MADDPG: one per vehicle
                zero_action_output(net)
        self.critic2 = _networks(cfg)[1] if cfg.twin else None
        self.actor_target = copy.deepcopy(self.actor)
        self.critic1_target = copy.deepcopy(self.critic1)
        self.critic2_target = copy.deepcopy(self.critic2) if cfg.twin else None
        for target in (self.actor_target, self.critic1_target, self.critic2_target):
            if target is not None:
                target.requires_grad_(False)
        critic_params = list(self.critic1.parameters())
        if self.critic2 is not None:
            critic_params += list(self.critic2.parameters())
        # fused: one kernel for all tensors (the same Adam; ~0.1 ms a step instead of ~0.45)
        self.actor_opt = torch.optim.Adam(self.actor.parameters(), lr=cfg.actor_lr, fused=True)
        self.critic_opt = torch.optim.Adam(critic_params, lr=cfg.critic_lr, fused=True)
        self.updates = 0
        self.actor_updates = 0
        self.bc_alpha = 0.0  # > 0: the behaviour-regularised actor loss (:meth:`anchor`)
        self.start_actor: nn.Module | None = None

    def check_length(self, n: int) -> None:
        self.cfg.check_length(n)

    # ------------------------------------------------------------------------------ acting
    def _act(self, actor: nn.Module, obs: torch.Tensor, mask: torch.Tensor | None,
             with_preactivation: bool = False):
        return self._act_normalised(actor, normalise(obs), mask, with_preactivation)

    def _act_normalised(self, actor: nn.Module, x: torch.Tensor, mask: torch.Tensor | None,
                        with_preactivation: bool = False, links: Links | None = None):
        """a_adj (m/s², (batch, n)) from normalised observations x (batch, n, 4); ``links``: how
        a CA actor's messages arrived (:meth:`carl_sumo.learn.models.CommunicationAware.forward_over`;
        None: all at once, unimpaired)."""
        pre = (actor(x, mask) if links is None else actor.forward_over(x, links)[0]).squeeze(-1)
        action = self.cfg.adj_max * torch.tanh(pre)
        return (action, pre) if with_preactivation else action

    def _q(self, critics: list[nn.Module], x: torch.Tensor, action: torch.Tensor,
           mask: torch.Tensor | None, detach_params: bool = False) -> torch.Tensor:
        """Q (G, batch, n) of G critics on normalised observations x and actions (m/s²); the CA
        critics run as one fused pass (``detach_params``: no gradient to their weights)."""
        if self._common_mode_void:  # what the law applies: the platoon's mean action removed
            action = without_common_mode(action, mask)
        inp = torch.cat([x, (action / self.cfg.adj_max).unsqueeze(-1)], dim=-1)
        if self.cfg.communication_aware:
            return ca_forward(critics, inp, mask, detach_params).squeeze(-1)
        return torch.stack([critic(inp, mask).squeeze(-1) for critic in critics])

    @staticmethod
    def total_acceleration(obs: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        """a = clip(a_IDM(o) + a_adj, acc_min, acc_max) (m/s²), as the simulation applies it."""
        return (idm_acceleration_torch(obs) + action).clamp(BOUNDS.acc_min_mps2,
                                                            BOUNDS.acc_max_mps2)

    @torch.no_grad()
    def act(self, obs: np.ndarray, noise: np.ndarray | None = None) -> np.ndarray:
        """a_adj (m/s²) for platoon observations (n, 4) or a batch (b, n, 4), plus ``noise``."""
        single = obs.ndim == 2
        x = torch.as_tensor(obs[None] if single else obs, dtype=torch.float32)
        self.check_length(x.shape[1])
        action = self._with_noise(self._act(self.actor, x, None).numpy(), noise)
        return action[0] if single else action

    @torch.no_grad()
    def act_over(self, obs: np.ndarray, links: Sequence[np.ndarray], noise: np.ndarray | None
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """A CA actor's a_adj (m/s², (b, n)) for a batch of platoon observations (b, n, d) whose
        incoming messages arrive as ``links`` say ((b, n) modes and (b, n, M) held messages,
        forward then backward; :class:`carl_sumo.control.channel.PlatoonLinks`), plus ``noise``; and the
        forward and backward messages (b, n, M) the vehicles send."""
        x = normalise(torch.as_tensor(obs, dtype=torch.float32))
        pre, sent_f, sent_b = self.actor.forward_over(x, links_tensors(links))
        action = self._with_noise((self.cfg.adj_max * torch.tanh(pre.squeeze(-1))).numpy(), noise)
        return action, sent_f.numpy().astype(np.float64), sent_b.numpy().astype(np.float64)

    def _with_noise(self, action: np.ndarray, noise: np.ndarray | None) -> np.ndarray:
        """a_adj (m/s², float64) plus exploration ``noise``, kept within ±adj_max."""
        action = action.astype(np.float64)
        if noise is None:
            return action
        return np.clip(action + noise.reshape(action.shape), -self.cfg.adj_max, self.cfg.adj_max)

    # ---------------------------------------------------------------------------- learning
    def start_from(self, actor_state: dict[str, torch.Tensor]) -> None:
        """A warm start: the actor and its target take these weights (a policy file's
        ``actor``); the critics stay as they are."""
        self.actor.load_state_dict(actor_state)
        self.actor_target.load_state_dict(actor_state)

    def anchor(self, alpha: float, start: dict[str, torch.Tensor] | None = None) -> None:
        """A behaviour-regularised actor from now on (TD3+BC, Fujimoto and Gu 2021): the actor
        minimises -α·Q/mean|Q| + ((a_adj - a_start)/adj_max)² instead of -Q, a_start the action
        of the start policy: a frozen copy of the actor as it is now (a residual start's 0, an
        imitated or ``--init`` actor's own output), or of the actor weights ``start`` (a resumed
        run's). α ≤ 0: plain -Q."""
        self.bc_alpha = float(alpha)
        if alpha <= 0:
            self.start_actor = None
            return
        self.start_actor = copy.deepcopy(self.actor).requires_grad_(False)
        if start is not None:
            self.start_actor.load_state_dict(start)

    def load_state_dict(self, state_dict, strict: bool = True, assign: bool = False):
        """As nn.Module's; the anchor's weights (``start_actor.*``, a run's checkpoint holds
        them) are left out where this agent has no anchor yet: a resumed run sets its anchor
        apart (:meth:`anchor` with the checkpoint's ``start_actor``), an exported one needs none."""
        if self.start_actor is None:
            state_dict = {k: v for k, v in state_dict.items() if not k.startswith("start_actor.")}
        return super().load_state_dict(state_dict, strict=strict, assign=assign)

    def revert_to_anchor(self) -> None:
        """The actor and its target back to the anchor of :meth:`anchor` (the actor it is held
        near), the actor optimiser's moments cleared (they point where the actor went)."""
        self.blend_toward_anchor(0.0)

    def blend_toward_anchor(self, kappa: float) -> None:
        """The actor and its target moved back along the straight line in weight space to the
        anchor of :meth:`anchor`: w ← w_anchor + κ·(w - w_anchor) (κ = 0: :meth:`revert_to_anchor`,
        1: unchanged); the actor optimiser's moments cleared (they point where the actor went)."""
        if self.start_actor is None:
            raise ValueError("going back to the anchor needs an anchored actor (bc_alpha > 0)")
        anchor = self.start_actor.state_dict()
        state = {k: anchor[k] + kappa * (v - anchor[k]) for k, v in self.actor.state_dict().items()}
        self.actor.load_state_dict(state)
        self.actor_target.load_state_dict(state)
        self.actor_opt.state.clear()

    def _q_objective(self, q: torch.Tensor, action_now: torch.Tensor, x: torch.Tensor,
                     mask: torch.Tensor | None, links: Links | None) -> torch.Tensor:
        """The per-vehicle actor loss's Q term: -Q, or with :meth:`anchor` the behaviour-
        regularised -α·Q/mean|Q| + ((a_adj - a_start)/adj_max)² (mean|Q| over the batch, held
        constant in the gradient)."""
        if self.start_actor is None:
            return -q
        with torch.no_grad():
            a_start = self._act_normalised(self.start_actor, x, mask, links=links)
            scale = q.abs().mean().clamp(min=1e-6)
        return -self.bc_alpha * q / scale + ((action_now - a_start) / self.cfg.adj_max) ** 2

    def imitate(self, obs: torch.Tensor, target: torch.Tensor, updates: int, lr: float,
                batch_size: int, rng: np.random.Generator) -> float:
        """Behaviour cloning: fit the actor to target a_adj (m/s², (N, n)) on platoon
        observations (N, n, obs_dim) by mean squared error (plus the usual small penalty on the
        tanh inputs), with its own Adam optimiser; the target actor is set to the result.
        Returns the last batch's mean squared error (m²/s⁴)."""
        x = normalise(obs)
        opt = torch.optim.Adam(self.actor.parameters(), lr=lr)
        mask = torch.ones(min(batch_size, len(x)), x.shape[1], dtype=torch.bool)
        mse = float("nan")
        for _ in range(updates):
            idx = torch.from_numpy(rng.integers(0, len(x), size=len(mask)))
            action, pre = self._act_normalised(self.actor, x[idx], mask, True)
            error = ((action - target[idx]) ** 2).mean()
            loss = error + self.cfg.preactivation_l2 * (pre ** 2).mean()
            opt.zero_grad()
            loss.backward()
            nn.utils.clip_grad_norm_(self.actor.parameters(), self.cfg.max_grad_norm)
            opt.step()
            mse = float(error.detach())
        self.actor_target.load_state_dict(self.actor.state_dict())
        return mse

    def update(self, batch: dict[str, torch.Tensor], train_actor: bool = True
               ) -> dict[str, float]:
        """One gradient step on a replay batch: obs, action, reward, next_obs, done, mask, and
        with ``links`` / ``next_links`` how the actor's messages arrived at o and o' (randomised
        impairments: the actor acts on those; the critics, a training device that sends nothing
        at run time, see their own messages unimpaired). ``train_actor=False``: the critics only,
        as in a critic burn-in."""
        cfg = self.cfg
        links, next_links = batch.get("links"), batch.get("next_links")
        obs, action, reward = batch["obs"], batch["action"], batch["reward"]
        next_obs, done, mask = batch["next_obs"], batch["done"], batch["mask"]
        maskf = mask.float()
        x, next_x = normalise(obs), normalise(next_obs)
        critics = [self.critic1, self.critic2] if cfg.twin else [self.critic1]
        with torch.no_grad():
            next_action = self._act_normalised(self.actor_target, next_x, mask, links=next_links)
            if cfg.twin:
                noise = (torch.randn_like(next_action) * cfg.target_noise * cfg.adj_max).clamp(
                    -cfg.target_noise_clip * cfg.adj_max, cfg.target_noise_clip * cfg.adj_max)
                next_action = (next_action + noise).clamp(-cfg.adj_max, cfg.adj_max)
            targets = [self.critic1_target, self.critic2_target] if cfg.twin else \
                [self.critic1_target]
            target_q = self._q(targets, next_x, next_action, mask).amin(0)
            y = reward + cfg.gamma * (1.0 - done).unsqueeze(-1) * target_q
        q = self._q(critics, x, action, mask)
        loss = _masked_mse(q[0], y, maskf)
        if cfg.twin:
            loss = loss + _masked_mse(q[1], y, maskf)
        self.critic_opt.zero_grad()
        loss.backward()
        nn.utils.clip_grad_norm_(self.critic_opt.param_groups[0]["params"], cfg.max_grad_norm)
        self.critic_opt.step()
        with torch.no_grad():  # the mean Q estimate of the batch (its real vehicles)
            q_mean = (q[0] * maskf).sum() / maskf.sum()
        stats = {"critic_loss": float(loss.detach()), "q_mean": float(q_mean)}
        self.updates += 1
        if train_actor and (not cfg.twin or self.updates % cfg.policy_delay == 0):
            stats["actor_loss"] = self._update_actor(x, next_x, obs, next_obs, mask, maskf,
                                                     action, links, next_links)
            self._soft_update()
        return stats

    def _update_actor(self, x: torch.Tensor, next_x: torch.Tensor, obs: torch.Tensor,
                      next_obs: torch.Tensor, mask: torch.Tensor, maskf: torch.Tensor,
                      stored_action: torch.Tensor, links: Links | None = None,
                      next_links: Links | None = None) -> float:
        """One actor step on -Q1 (+ penalties); the critic's weights get no gradient."""
        cfg = self.cfg
        if cfg.residual and (cfg.smooth_jerk > 0 or cfg.smooth_accel > 0):
            action_now, pre = self._act_normalised(self.actor, x, mask, True, links)
            q = self._q([self.critic1], x, action_now, mask, detach_params=True)[0]
            per_vehicle = cfg.preactivation_l2 * pre ** 2 + self._q_objective(
                q, action_now, x, mask, links) + self._residual_smoothness(
                obs, next_obs, stored_action, action_now)
            return self._actor_step(per_vehicle + cfg.adj_l2 * action_now ** 2, maskf)
        jerk = cfg.smooth_jerk > 0
        if jerk:  # the actor on o and o' in one pass (rows are independent)
            both_links = None if links is None else \
                tuple(torch.cat(pair) for pair in zip(links, next_links))
            both, pre_both = self._act_normalised(self.actor, torch.cat([x, next_x]),
                                                  torch.cat([mask, mask]), True, both_links)
            action_now, action_next = both.chunk(2)
            pre = pre_both.chunk(2)[0]
        else:
            action_now, pre = self._act_normalised(self.actor, x, mask, True, links)
            action_next = None
        q = self._q([self.critic1], x, action_now, mask, detach_params=True)[0]
        per_vehicle = cfg.preactivation_l2 * pre ** 2 + self._q_objective(
            q, action_now, x, mask, links) + cfg.adj_l2 * action_now ** 2
        if jerk or cfg.smooth_accel > 0:
            per_vehicle = per_vehicle + self._smoothness(obs, next_obs, action_now, mask,
                                                          action_next, next_links)
        return self._actor_step(per_vehicle, maskf)

    def _actor_step(self, per_vehicle: torch.Tensor, maskf: torch.Tensor) -> float:
        """One optimiser step on the mean of a per-vehicle actor loss over real vehicles."""
        actor_loss = (per_vehicle * maskf).sum() / maskf.sum()
        self.actor_updates += 1
        self.actor_opt.zero_grad()
        actor_loss.backward()
        nn.utils.clip_grad_norm_(self.actor.parameters(), self.cfg.max_grad_norm)
        self.actor_opt.step()
        return float(actor_loss.detach())

    def _smoothness(self, obs: torch.Tensor, next_obs: torch.Tensor, action_now: torch.Tensor,
                    mask: torch.Tensor | None, action_next: torch.Tensor | None = None,
                    next_links: Links | None = None) -> torch.Tensor:
        """Per-vehicle smoothness penalty of the total acceleration a = a_IDM + a_adj (unclipped):
        ``smooth_jerk``·((a(o') - a(o))/dt)² + ``smooth_accel``·a(o)², o → o' a stored transition.
        It regularises the actor directly, as CAPS (Mysore et al. 2021) does, instead of waiting for
        the critic to learn the jerk the reward punishes. ``action_next``: the actor's a_adj on o'
        when already computed."""
        acc_now = self.total_acceleration(obs, action_now)
        penalty = self.cfg.smooth_accel * acc_now ** 2
        if self.cfg.smooth_jerk > 0:
            if action_next is None:
                action_next = self._act_normalised(self.actor, normalise(next_obs), mask,
                                                   links=next_links)
            acc_next = self.total_acceleration(next_obs, action_next)
            penalty = penalty + self.cfg.smooth_jerk * ((acc_next - acc_now) / DT_S) ** 2
        return penalty

    def _residual_smoothness(self, obs: torch.Tensor, next_obs: torch.Tensor,
                             stored_action: torch.Tensor, action_now: torch.Tensor
                             ) -> torch.Tensor:
        """The smoothness penalty on a classical base, whose a_base has a state and is not a
        function of o: it is read back from the transition instead. o' holds the acceleration
        a' applied at the step with the stored a_adj, and a moves by ``adjustment_gain`` g per
        m/s² of a_adj, so with the actor's a_adj now, a(o) = a' + g·(a_adj - a_adj(stored)) and
        the step's jerk is (a(o) - a_o)/dt: ``smooth_jerk``·jerk² + ``smooth_accel``·a(o)²,
        exactly the jerk and acceleration the reward and the metrics see (while a stays inside
        the bounds and below the cruise cap)."""
        acc_now = next_obs[..., 1] + self._adjustment_gain * (action_now - stored_action)
        penalty = self.cfg.smooth_accel * acc_now ** 2
        if self.cfg.smooth_jerk > 0:
            penalty = penalty + self.cfg.smooth_jerk * ((acc_now - obs[..., 1]) / DT_S) ** 2
        return penalty

    def scale_learning_rates(self, fraction: float) -> None:
        """Set both optimizers' learning rates to ``fraction`` of the configured ones."""
        for opt, lr in ((self.actor_opt, self.cfg.actor_lr), (self.critic_opt, self.cfg.critic_lr)):
            for group in opt.param_groups:
                group["lr"] = fraction * lr

    @torch.no_grad()
    def _soft_update(self) -> None:
        pairs = [(self.actor, self.actor_target), (self.critic1, self.critic1_target)]
        if self.cfg.twin:
            pairs.append((self.critic2, self.critic2_target))
        sources = [p for net, _ in pairs for p in net.parameters()]
        targets = [p for _, target in pairs for p in target.parameters()]
        torch._foreach_lerp_(targets, sources, self.cfg.tau)  # one op for all tensors


class ColoredNoise:
    """Exploration noise that is smooth in time: an AR(1) Gaussian process per vehicle.

    White noise on an acceleration is white noise on jerk, which the comfort reward punishes
    whatever the policy; correlated noise explores speeds and gaps without that.
    """

    def __init__(self, shape: tuple[int, ...], std: float, correlation: float,
                 rng: np.random.Generator):
        self.std, self.rho, self.rng = std, correlation, rng
        self.value = rng.normal(0.0, std, shape)

    def sample(self) -> np.ndarray:
        innovation = self.rng.normal(0.0, self.std * np.sqrt(1.0 - self.rho ** 2), self.value.shape)
        self.value = self.rho * self.value + innovation
        return self.value

    def reset(self, index: np.ndarray) -> None:
        """Draw fresh noise for the environments whose episode ended (boolean mask)."""
        self.value[index] = self.rng.normal(0.0, self.std, self.value[index].shape)


def links_tensors(links: Sequence[np.ndarray]) -> Links:
    """Link arrays (modes, held, modes, held) as the tensors ``forward_over`` takes."""
    f_mode, f_held, b_mode, b_held = links
    return (torch.as_tensor(f_mode, dtype=torch.long), torch.as_tensor(f_held, dtype=torch.float32),
            torch.as_tensor(b_mode, dtype=torch.long), torch.as_tensor(b_held, dtype=torch.float32))


def without_common_mode(action: torch.Tensor, mask: torch.Tensor | None) -> torch.Tensor:
    """Each vehicle's action (batch, n) less the mean over the platoon's vehicles in ``mask``."""
    if mask is None:
        return action - action.mean(dim=-1, keepdim=True)
    m = mask.to(action.dtype)
    mean = (action * m).sum(dim=-1, keepdim=True) / m.sum(dim=-1, keepdim=True).clamp(min=1.0)
    return (action - mean) * m


def _masked_mse(q: torch.Tensor, y: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
    return (((q - y) ** 2) * mask).sum() / mask.sum()

