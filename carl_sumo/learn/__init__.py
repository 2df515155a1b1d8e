"""Learning: the PettingZoo and vector environments, networks and the fused CA scan, agents,
replay buffer, reward, training, validation and selection, imitation, policy files and fast
inference. Imports ``scale``, ``control``, ``sim`` and below."""
