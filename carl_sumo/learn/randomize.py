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

from carl_sumo.config import DT_S
from carl_sumo.control.channel import Impairments, PlatoonLinks, random_impairments
from carl_sumo.sim.vehicle import Plant

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
                 sensor_filter: bool = False, comm_off: bool = False,
                 plant_randomize: bool = False):
        self.n, self.message_dim, self.fixed = n, message_dim, fixed
        self.comm_off, self.plant_randomize = comm_off, plant_randomize
        self.rng = np.random.default_rng([seed, STREAM] if fixed is None
                                         else [seed, STREAM, fixed.seed])
        self.noise_share = 0.5 if sensor_noise else 0.0
        self.sensor_filter = sensor_filter
        self.current = [self._draw() for _ in range(num_envs)]
        self.upcoming = [self._draw() for _ in range(num_envs)]
        self.links = [self._links(imp) for imp in self.current]

    def _draw(self) -> Impairments:
        if self.plant_randomize:
            return random_plant_impairments(self.rng)
        if self.fixed is not None:
            return replace(self.fixed, seed=int(self.rng.integers(2 ** 31)))
        return random_impairments(self.rng, self.noise_share, self.sensor_filter)

    def _links(self, impairments: Impairments) -> PlatoonLinks | None:
        if not self.message_dim:
            return None
        if self.comm_off:  # CA-off: the messages are cut, the base's link is not
            impairments = replace(impairments, loss=1.0)
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


RANDOM_TRUCK_SHARE = (0.0, 0.5)
RANDOM_LAG_S = (0.05, 0.8)
RANDOM_DEAD_STEPS = (0, 3)
RANDOM_DELAY_STEPS = (0, 3)
RANDOM_LOSS = (0.0, 0.3)
"""Ranges of ``train --plant-randomize``, wider than the real plant's (20 % trucks, τ 0.1-0.6 s,
dead time 0-0.2 s, 0.1 s V2V delay, no loss)."""


def random_plant_impairments(rng: np.random.Generator) -> Impairments:
    """One training episode's plant and channel (``train --plant-randomize``): a fleet of cars
    and a truck share drawn from :data:`RANDOM_TRUCK_SHARE`; in half of the episodes every
    follower's τ and dead time drawn from its class, in the other half one τ from
    :data:`RANDOM_LAG_S` and one dead time from :data:`RANDOM_DEAD_STEPS` for all; a V2V delay
    and a message loss probability drawn from their ranges."""
    seed = int(rng.integers(2 ** 31))
    trucks = float(rng.uniform(*RANDOM_TRUCK_SHARE))
    fleet = (("car", 1.0),) if trucks < 1e-3 else (("car", 1.0 - trucks), ("truck", trucks))
    if rng.random() < 0.5:
        plant = Plant(fleet)
    else:
        plant = Plant(fleet, float(rng.uniform(*RANDOM_LAG_S)),
                      round(int(rng.integers(RANDOM_DEAD_STEPS[0], RANDOM_DEAD_STEPS[1] + 1))
                            * DT_S, 10))
    delay = round(int(rng.integers(RANDOM_DELAY_STEPS[0], RANDOM_DELAY_STEPS[1] + 1)) * DT_S, 10)
    return Impairments(delay_s=delay, loss=float(rng.uniform(*RANDOM_LOSS)), seed=seed,
                       plant=plant)
