"""Neural networks of the agents (PyTorch): the Communication-Aware module and plain MLPs.

All networks map a platoon tensor ``x`` of shape (batch, n, features), vehicles head first, and a
mask (batch, n) of real vehicles to an output of shape (batch, n, out). Platoons shorter than ``n``
are padded at the tail and masked.

The Communication-Aware (CA) module passes V2V messages along the platoon with weights shared by
all vehicles, so one set of weights runs any platoon length:

- forward network, tail → head: ``F_i = f_F(x_i, F_{i+1})``, the last vehicle receives ``F_bound``;
- backward network, head → tail: ``(B_i, y_i) = f_B(F_i, B_{i-1})``, the first vehicle receives
  ``B_bound``. ``y_i`` is the output (an action, or a Q-value for a critic).

Both boundary messages are learned vectors. The passes run fused (:mod:`carl_sumo.learn.ca_scan`): a
few batched tensor ops per vehicle and a hand-written backward pass.
"""

from __future__ import annotations

from typing import Sequence

import torch
from torch import nn

from carl_sumo.learn.ca_scan import ca_forward


def mlp(sizes: list[int], activation: type[nn.Module] = nn.ReLU) -> nn.Sequential:
    """Linear layers with ``activation`` between them (none after the last)."""
    layers: list[nn.Module] = []
    for i in range(len(sizes) - 1):
        layers.append(nn.Linear(sizes[i], sizes[i + 1]))
        if i < len(sizes) - 2:
            layers.append(activation())
    return nn.Sequential(*layers)


class CommunicationAware(nn.Module):
    """Forward-then-backward message passing along a platoon (see the module docstring)."""

    def __init__(self, in_dim: int, out_dim: int, message_dim: int = 16, hidden: int = 64):
        super().__init__()
        self.message_dim = message_dim
        self.forward_net = nn.Sequential(mlp([in_dim + message_dim, hidden, hidden, message_dim]),
                                         nn.Tanh())
        self.backward_net = mlp([message_dim + message_dim, hidden, hidden, message_dim + out_dim])
        self.forward_boundary = nn.Parameter(torch.zeros(message_dim))
        self.backward_boundary = nn.Parameter(torch.zeros(message_dim))

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        """Outputs (batch, n, out) for inputs x (batch, n, in) and a mask (batch, n) of real
        vehicles (padding at the tail)."""
        return ca_forward([self], x, mask)[0]

    def forward_over(self, x: torch.Tensor, links: Sequence[torch.Tensor]
                     ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """Outputs (batch, n, out) when each message crosses an impaired link, and the forward
        and backward messages (batch, n, M) the vehicles send. ``links`` = (forward modes,
        forward held, backward modes, backward held): modes (batch, n) of vehicle i's incoming
        message (LIVE = 0: this step's, HELD = 1: ``held[:, i]`` (batch, n, M), which past the
        timeout the channel has already faded toward the boundary message the acting actor had,
        FALLBACK = 2: the boundary message, as at a chain end), as :mod:`carl_sumo.control.channel`
        delivers them. A
        per-vehicle loop under autograd (no padding): all modes LIVE give :meth:`forward`."""
        f_mode, f_held, b_mode, b_held = links
        batch, n, _ = x.shape
        m = self.message_dim

        def incoming(i: int, mode: torch.Tensor, live: torch.Tensor | None, held: torch.Tensor,
                     boundary: torch.Tensor) -> torch.Tensor:
            if live is None:  # a chain end
                return boundary
            pick = mode[:, i:i + 1]
            return torch.where(pick == 0, live, torch.where(pick == 1, held[:, i], boundary))

        forward_boundary = self.forward_boundary.expand(batch, m)
        sent_f: list[torch.Tensor | None] = [None] * n
        for i in range(n - 1, -1, -1):  # tail -> head
            inc = incoming(i, f_mode, sent_f[i + 1] if i + 1 < n else None, f_held,
                           forward_boundary)
            sent_f[i] = self.forward_net(torch.cat([x[:, i], inc], -1))
        backward_boundary = self.backward_boundary.expand(batch, m)
        sent_b: list[torch.Tensor] = []
        outputs = []
        for i in range(n):  # head -> tail
            inc = incoming(i, b_mode, sent_b[i - 1] if i else None, b_held, backward_boundary)
            out = self.backward_net(torch.cat([sent_f[i], inc], -1))
            sent_b.append(torch.tanh(out[:, :m]))
            outputs.append(out[:, m:])
        return torch.stack(outputs, 1), torch.stack(sent_f, 1), torch.stack(sent_b, 1)


class PerVehicle(nn.Module):
    """The same MLP applied to every vehicle independently (DDPG/TD3: no communication)."""

    def __init__(self, in_dim: int, out_dim: int, hidden: int = 64):
        super().__init__()
        self.net = mlp([in_dim, hidden, hidden, out_dim])

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        return self.net(x)


class PerAgentActors(nn.Module):
    """MADDPG actors: one MLP per vehicle position, for a fixed platoon length."""

    def __init__(self, n_vehicles: int, in_dim: int, out_dim: int, hidden: int = 64):
        super().__init__()
        self.n_vehicles = n_vehicles
        self.nets = nn.ModuleList(mlp([in_dim, hidden, hidden, out_dim]) for _ in range(n_vehicles))

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        return torch.stack([net(x[:, i]) for i, net in enumerate(self.nets)], dim=1)


class CentralCritic(nn.Module):
    """MADDPG critic: every vehicle's Q from all observations and actions of the platoon."""

    def __init__(self, n_vehicles: int, in_dim: int, hidden: int = 128):
        super().__init__()
        self.n_vehicles = n_vehicles
        self.net = mlp([n_vehicles * in_dim, hidden, hidden, n_vehicles])

    def forward(self, x: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        return self.net(x.reshape(x.shape[0], -1)).unsqueeze(-1)
