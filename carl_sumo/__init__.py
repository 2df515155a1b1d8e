"""carl-sumo: Communication-Aware Reinforcement Learning for CACC platoons in Eclipse SUMO.

The package is layered; each subpackage imports only from the ones below it (docs/usage.md,
"Layout of the code"; ``tests/test_imports.py`` holds the rule)::

    cli          the command line, one module per command group (and sweeps of `train`)
    study        the mixed-traffic study on the whole freeway
    experiments  simulate, evaluate and the paper's suite, robustness, tune, bench, figures
    learn        environments, networks, agents, training, selection, policy files, inference
    scale        worker processes and the Ray cluster
    control      the V2V channel, sensors, base models and the classical CACC
    sim          the SUMO coupling, network, traffic demand, metrics
    data, config, errors, files   leader events, parameters with units, errors, atomic outputs
"""

from __future__ import annotations

__version__ = "0.1.0"

ENV_ID = "carl_sumo/Platoon-v0"
"""The Gymnasium environment ``import carl_sumo`` registers (:mod:`carl_sumo.learn.gym_env`)."""


def _register_env() -> None:
    """Register :data:`ENV_ID` with Gymnasium, as ``import highway_env`` does; the environment
    module (and torch, SUMO) load only when it is made."""
    try:
        import gymnasium
    except ImportError:  # pragma: no cover - gymnasium is a dependency
        return
    if ENV_ID not in gymnasium.registry:
        gymnasium.register(id=ENV_ID, entry_point="carl_sumo.learn.gym_env:PlatoonGymEnv")


_register_env()
