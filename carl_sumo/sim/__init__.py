"""The simulator: the SUMO coupling (lane route, leader replay, exact accelerations), the network,
traffic demand and the metrics. Imports only ``data``, ``config``, ``errors`` and ``files``."""
