"""Fast policy inference: a loaded actor compiled to float64 numpy weights and numba functions.

``Agent.act`` runs torch once per 0.1 s step for one platoon, which costs about 1 ms for the
Communication-Aware actor on 10 vehicles (20 small sequential MLP calls, mostly torch overhead).
:class:`CompiledActor` does the same arithmetic as ``Agent._act`` (``normalise``, the actor,
``adj_max · tanh``) in numba on one platoon (n, 4); it matches ``Agent.act`` to float32 rounding
(well under 1e-5 m/s²) in about 40 µs per CA step on 10 vehicles
(``benchmarks/policy_inference.py``). Training keeps using torch; the policy file format is
unchanged.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from torch import nn

from carl_sumo.learn.agents import BASE_SCALE, GAP_CLIP_M, OBS_SCALE, Agent
from carl_sumo.control.channel import KeyedChannel, PlatoonLinks, heard_weights
from carl_sumo.learn.models import CommunicationAware, PerAgentActors, PerVehicle

_OBS_SCALE = np.array(OBS_SCALE, dtype=np.float64)

Layers = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
"""(W1, b1, W2, b2, W3, b3) of a 3-layer MLP; W transposed from nn.Linear's: (in, out)."""


@njit(cache=True)
def _dense(w_t: np.ndarray, b: np.ndarray, x: np.ndarray, relu: bool) -> np.ndarray:
    """x @ w_t + b, then ReLU if ``relu``; ``w_t`` is (in, out) so the inner loop vectorises."""
    out = b.copy()
    for k in range(w_t.shape[0]):
        xk = x[k]
        for j in range(w_t.shape[1]):
            out[j] += w_t[k, j] * xk
    if relu:
        for j in range(out.shape[0]):
            out[j] = max(out[j], 0.0)
    return out


@njit(cache=True)
def _mlp(x, w1, b1, w2, b2, w3, b3):
    """Linear-ReLU-Linear-ReLU-Linear (carl_sumo.learn.models.mlp with 3 layers)."""
    return _dense(w3, b3, _dense(w2, b2, _dense(w1, b1, x, True), True), False)


@njit(cache=True)
def _normalised(obs: np.ndarray) -> np.ndarray:
    """carl_sumo.learn.agents.normalise of one platoon (n, 4), or (n, 5) with a_base."""
    x = np.empty_like(obs)
    for i in range(obs.shape[0]):
        x[i, 0] = obs[i, 0] / _OBS_SCALE[0]
        x[i, 1] = obs[i, 1] / _OBS_SCALE[1]
        x[i, 2] = min(obs[i, 2], GAP_CLIP_M) / _OBS_SCALE[2]
        x[i, 3] = obs[i, 3] / _OBS_SCALE[3]
        for j in range(4, obs.shape[1]):
            x[i, j] = obs[i, j] / BASE_SCALE
    return x


@njit(cache=True)
def _communication_aware_act(obs, adj_max, forward_boundary, backward_boundary,
                             fw1, fb1, fw2, fb2, fw3, fb3, bw1, bb1, bw2, bb2, bw3, bb3):
    """a_adj (m/s², shape (n,)) of a CommunicationAware actor on one platoon (n, 4)."""
    x = _normalised(obs)
    n, n_in, m = x.shape[0], x.shape[1], forward_boundary.shape[0]
    forward_messages = np.empty((n, m))
    inp = np.empty(n_in + m)
    message = forward_boundary.copy()
    for i in range(n - 1, -1, -1):  # tail -> head
        inp[:n_in] = x[i]
        inp[n_in:] = message
        message = np.tanh(_mlp(inp, fw1, fb1, fw2, fb2, fw3, fb3))
        forward_messages[i] = message
    action = np.empty(n)
    inp = np.empty(2 * m)
    message = backward_boundary.copy()
    for i in range(n):  # head -> tail
        inp[:m] = forward_messages[i]
        inp[m:] = message
        out = _mlp(inp, bw1, bb1, bw2, bb2, bw3, bb3)
        message = np.tanh(out[:m])
        action[i] = adj_max * math.tanh(out[m])
    return action


@njit(cache=True)
def _communication_aware_act_channel(obs, adj_max, f_mode, f_held, b_mode, b_held,
                                     forward_boundary, backward_boundary,
                                     fw1, fb1, fw2, fb2, fw3, fb3, bw1, bb1, bw2, bb2, bw3, bb3):
    """The CommunicationAware actor when each message crosses a link (carl_sumo.control.channel):
    follower i hears i+1's forward and i-1's backward message as ``f_mode[i]`` / ``b_mode[i]``
    say (0 this step's, 1 the held ``f_held[i]`` / ``b_held[i]``, 2 none: the learned boundary
    message, as at a chain end). Returns (a_adj (n,), forward messages (n, m), backward messages
    (n, m)) of this step; with every mode 0 it is :func:`_communication_aware_act`."""
    x = _normalised(obs)
    n, n_in, m = x.shape[0], x.shape[1], forward_boundary.shape[0]
    forward_messages = np.empty((n, m))
    inp = np.empty(n_in + m)
    for i in range(n - 1, -1, -1):  # tail -> head
        inp[:n_in] = x[i]
        if i == n - 1 or f_mode[i] == 2:
            inp[n_in:] = forward_boundary
        elif f_mode[i] == 1:
            inp[n_in:] = f_held[i]
        else:
            inp[n_in:] = forward_messages[i + 1]
        forward_messages[i] = np.tanh(_mlp(inp, fw1, fb1, fw2, fb2, fw3, fb3))
    action = np.empty(n)
    backward_messages = np.empty((n, m))
    inp = np.empty(2 * m)
    for i in range(n):  # head -> tail
        inp[:m] = forward_messages[i]
        if i == 0 or b_mode[i] == 2:
            inp[m:] = backward_boundary
        elif b_mode[i] == 1:
            inp[m:] = b_held[i]
        else:
            inp[m:] = backward_messages[i - 1]
        out = _mlp(inp, bw1, bb1, bw2, bb2, bw3, bb3)
        backward_messages[i] = np.tanh(out[:m])
        action[i] = adj_max * math.tanh(out[m])
    return action, forward_messages, backward_messages


@njit(cache=True)
def _per_vehicle_act(obs, adj_max, w1, b1, w2, b2, w3, b3):
    """a_adj (m/s², shape (n,)) of per-vehicle MLPs stacked on axis 0: one shared by all vehicles
    (TD3/DDPG) or one per vehicle (MADDPG)."""
    x = _normalised(obs)
    shared = w1.shape[0] == 1
    action = np.empty(x.shape[0])
    for i in range(x.shape[0]):
        k = 0 if shared else i
        pre = _mlp(x[i], w1[k], b1[k], w2[k], b2[k], w3[k], b3[k])[0]
        action[i] = adj_max * math.tanh(pre)
    return action


def _mlp_weights(net: nn.Module) -> Layers:
    """(W1, b1, W2, b2, W3, b3) of a 3-layer MLP as contiguous float64 arrays, W as (in, out)."""
    linears = [m for m in net.modules() if isinstance(m, nn.Linear)]
    if len(linears) != 3:
        raise ValueError(f"expected a 3-layer MLP, got {len(linears)} linear layers")
    arrays: list[np.ndarray] = []
    for layer in linears:
        arrays += [np.ascontiguousarray(layer.weight.detach().double().numpy().T),
                   layer.bias.detach().double().numpy().copy()]
    return tuple(arrays)  # type: ignore[return-value]


def _stacked(per_net: list[Layers]) -> Layers:
    return tuple(np.ascontiguousarray(np.stack(arrays)) for arrays in zip(*per_net))  # type: ignore[return-value]


class CompiledActor:
    """The actor of an :class:`Agent` as numpy weights evaluated by numba (a snapshot: later
    training of the agent does not change it)."""

    def __init__(self, agent: Agent):
        self.adj_max = float(agent.cfg.adj_max)
        self.fixed_length = agent.cfg.n_vehicles if agent.cfg.algo == "maddpg" else None
        self._check_length = agent.cfg.check_length  # picklable: a validation helper runs it
        self.fallback_to_base = agent.cfg.comm_fallback == "base"
        actor = agent.actor
        self._communication_aware = False
        if isinstance(actor, CommunicationAware):
            self._act = _communication_aware_act
            self._communication_aware = True  # not by the function's identity: a pickled copy
            self._weights = (actor.forward_boundary.detach().double().numpy().copy(),
                             actor.backward_boundary.detach().double().numpy().copy(),
                             *_mlp_weights(actor.forward_net), *_mlp_weights(actor.backward_net))
        elif isinstance(actor, PerVehicle):
            self._act = _per_vehicle_act
            self._weights = _stacked([_mlp_weights(actor.net)])
        elif isinstance(actor, PerAgentActors):
            self._act = _per_vehicle_act
            self._weights = _stacked([_mlp_weights(net) for net in actor.nets])
        else:
            raise TypeError(f"cannot compile an actor of type {type(actor).__name__}")

    @property
    def message_dim(self) -> int:
        """Width of a V2V message (0: an actor without communication)."""
        return int(self._weights[0].shape[0]) if self._communication_aware else 0

    def act_over(self, obs: np.ndarray, links: PlatoonLinks) -> np.ndarray:
        """a_adj (m/s², shape (n,)) of a CA actor when its messages cross impaired ``links``
        (:class:`carl_sumo.control.channel.PlatoonLinks`; with ``comm_fallback`` "base" scaled by how
        much each vehicle hears, :meth:`~carl_sumo.control.channel.PlatoonLinks.heard`); sends this
        step's messages."""
        obs = np.ascontiguousarray(obs, dtype=np.float64)
        f_mode, f_held, b_mode, b_held = links.receive(self._weights[0], self._weights[1])
        action, f_out, b_out = _communication_aware_act_channel(
            obs, self.adj_max, f_mode.astype(np.int64), f_held, b_mode.astype(np.int64), b_held,
            *self._weights)
        if self.fallback_to_base:
            action = action * links.heard()
        links.send(f_out, b_out)
        return action

    def act_keyed(self, obs: np.ndarray, ids: list[str], forward: KeyedChannel,
                  backward: KeyedChannel, k: int) -> np.ndarray:
        """a_adj (m/s², shape (n,)) of a CA actor on a chain of vehicles ``ids`` (head first) at
        step k, its messages crossing the vehicle-keyed links of the study
        (:class:`carl_sumo.control.channel.KeyedChannel`; the fallback as in :meth:`act_over`); sends
        this step's messages."""
        obs = np.ascontiguousarray(obs, dtype=np.float64)
        n = len(ids)
        f_pairs = [(ids[j], ids[j + 1]) for j in range(n - 1)]  # i hears i+1
        b_pairs = [(ids[j], ids[j - 1]) for j in range(1, n)]  # i hears i-1
        f_mode, f_held = np.full(n, 2), np.zeros((n, self.message_dim))
        b_mode, b_held = np.full(n, 2), np.zeros((n, self.message_dim))
        f_mode[:n - 1], f_held[:n - 1] = forward.receive(k, f_pairs, self._weights[0])
        b_mode[1:], b_held[1:] = backward.receive(k, b_pairs, self._weights[1])
        action, f_out, b_out = _communication_aware_act_channel(
            obs, self.adj_max, f_mode.astype(np.int64), f_held, b_mode.astype(np.int64), b_held,
            *self._weights)
        if self.fallback_to_base:
            action = action * heard_weights(forward.heard, backward.heard)
        forward.send(k, f_pairs, f_out[1:])
        backward.send(k, b_pairs, b_out[:n - 1])
        return action

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        """a_adj (m/s², shape (n,)) for one platoon observation (n, 4) [v, a, d, Δv]."""
        if self.fixed_length is not None and obs.shape[0] != self.fixed_length:
            self._check_length(obs.shape[0])
        obs = np.ascontiguousarray(obs, dtype=np.float64)
        return self._act(obs, self.adj_max, *self._weights)
