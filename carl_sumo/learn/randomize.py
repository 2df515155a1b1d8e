"""Impairments in training: with ``train --comm-randomize`` every training episode of every
environment draws its own V2V delay, loss, bursts and sensor noise
(:func:`carl_sumo.control.channel.random_impairments`); with fixed ones (``train --comm-loss P ...``)
every episode has those, with its own draws.

The environments' workers apply the sensor noise (and a classical base's impaired predecessor
link) themselves; the CA actor runs in the training process, so its messages cross
:class:`carl_sumo.control.channel.PlatoonLinks` here, one pair of links per environment. The draws come
from the training seed, on a generator of their own: a run without ``--comm-randomize`` draws
exactly what it drew before.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from carl_sumo.control.channel import Impairments, PlatoonLinks, random_impairments

STREAM = 7919
"""Seeds the impairment generator as [training seed, STREAM]."""

LinkArrays = tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]
"""Forward modes (E, n), forward held messages (E, n, M), backward modes, backward held."""


class RandomisedChannels:
    """The current and the next episode's impairments of ``num_envs`` environments of ``n``
    followers, and the CA links (messages of ``message_dim`` numbers; 0: an actor without
    messages, sensor noise only). ``sensor_noise`` False: the channel alone is randomised (the
    same channel draws), the sensors stay clean; ``sensor_filter``: the noisy ones are filtered
    (:mod:`carl_sumo.control.sensors`). ``fixed``: every episode has these impairments
    instead (``train --comm-loss ...``), with its own loss and noise draws (seeded by the training
    seed and ``fixed.seed``)."""

    def __init__(self, num_envs: int, n: int, message_dim: int, seed: int,
                 sensor_noise: bool = True, fixed: Impairments | None = None,
                 sensor_filter: bool = False):
        self.n, self.message_dim, self.fixed = n, message_dim, fixed
        self.rng = np.random.default_rng([seed, STREAM] if fixed is None
                                         else [seed, STREAM, fixed.seed])
        self.noise_share = 0.5 if sensor_noise else 0.0
        self.sensor_filter = sensor_filter
        self.current = [self._draw() for _ in range(num_envs)]
        self.upcoming = [self._draw() for _ in range(num_envs)]
        self.links = [self._links(imp) for imp in self.current]

    def _draw(self) -> Impairments:
        if self.fixed is not None:
            return replace(self.fixed, seed=int(self.rng.integers(2 ** 31)))
        return random_impairments(self.rng, self.noise_share, self.sensor_filter)

    def _links(self, impairments: Impairments) -> PlatoonLinks | None:
        if not self.message_dim:
            return None
        return PlatoonLinks(self.n, self.message_dim, impairments, "training")

    def receive(self, fallbacks: tuple[np.ndarray, np.ndarray] | None = None
                ) -> LinkArrays | None:
        """How every environment's messages arrive this step, stacked over environments (copies;
        None without messages); held messages past the timeout fade into ``fallbacks`` (the
        acting actor's forward and backward boundary messages, as a receiver has them)."""
        if not self.message_dim:
            return None
        parts = [links.receive(*(fallbacks or (None, None))) for links in self.links]
        return tuple(np.stack([p[j] for p in parts]) for j in range(4))  # type: ignore[return-value]

    def send(self, forward: np.ndarray, backward: np.ndarray) -> None:
        """The messages (E, n, M) each environment's vehicles sent this step."""
        for e, links in enumerate(self.links):
            if links is not None:
                links.send(forward[e], backward[e])

    def episodes_ended(self, ended: np.ndarray) -> None:
        """Environments whose episode ended (boolean (E,)) start the upcoming impairments (their
        workers have done so already) on fresh links, and draw the next ones."""
        for e in np.flatnonzero(ended):
            self.current[e] = self.upcoming[e]
            self.upcoming[e] = self._draw()
            self.links[e] = self._links(self.current[e])
