"""carl-sumo: Communication-Aware Reinforcement Learning for CACC platoons in Eclipse SUMO.

The package is layered; each subpackage imports only from the ones below it (docs/usage.md,
"Layout of the code"; ``tests/test_imports.py`` holds the rule)::

    cli          the command line, one module per command group (and sweeps of `train`)
    study        the mixed-traffic study on the whole freeway
    manoeuvres   cut-ins, cut-outs, joins and merges: their simulation, metrics and tables
    experiments  simulate, evaluate and the paper's suite, robustness, tune, bench, figures
    learn        environments, networks, agents, training, selection, policy files, inference
    scale        worker processes and the Ray cluster
    control      the V2V channel, sensors, base models and the classical CACC
    sim          the SUMO coupling, network, traffic demand, metrics
    data, config, errors, files   leader events, parameters with units, errors, atomic outputs
"""

from __future__ import annotations

import os

__version__ = "0.1.0"

COMMAND_MARK = "CARL_SUMO_COMMAND"
"""Set in the environment while a ``carl-sumo`` command runs, so that its worker processes know
themselves from their first import."""


def _leave_ctrl_c_to_the_command() -> None:
    """In a worker process of a ``carl-sumo`` command, ignore Ctrl-C and hang-ups from the first
    import on (the command stops its workers itself; a terminal's Ctrl-C reaches every process
    of the group, also one still importing its modules, which would print a traceback)."""
    if not os.environ.get(COMMAND_MARK):
        return
    import multiprocessing
    import signal
    import threading

    if multiprocessing.parent_process() is None or \
            threading.current_thread() is not threading.main_thread():
        return
    for name in ("SIGINT", "SIGHUP"):
        if hasattr(signal, name):
            signal.signal(getattr(signal, name), signal.SIG_IGN)


_leave_ctrl_c_to_the_command()

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
