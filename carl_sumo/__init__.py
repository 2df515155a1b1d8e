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

Modules moved into the subpackages keep their old import paths (``carl_sumo.sumo`` is
``carl_sumo.sim.sumo``): :data:`MOVED` maps each old name to its new home.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys

__version__ = "0.1.0"

#: old module name (before the subpackages) -> its module now, both under ``carl_sumo``
MOVED = {
    "sumo": "sim.sumo", "network": "sim.network", "traffic": "sim.traffic",
    "metrics": "sim.metrics",
    "channel": "control.channel", "sensors": "control.sensors", "cacc": "control.cacc",
    "controllers": "control.controllers",
    "workers": "scale.workers", "cluster": "scale.cluster",
    "env": "learn.env", "vec_env": "learn.vec_env", "reward": "learn.reward",
    "randomize": "learn.randomize", "models": "learn.models", "ca_scan": "learn.ca_scan",
    "agents": "learn.agents", "replay": "learn.replay_buffer", "train": "learn.train",
    "selection": "learn.selection", "imitation": "learn.imitation", "policy": "learn.policy",
    "inference": "learn.inference",
    "simulate": "experiments.simulate", "evaluate": "experiments.evaluate",
    "suite": "experiments.suite", "suite_report": "experiments.suite_report",
    "suite_stats": "experiments.suite_stats", "robustness": "experiments.robustness",
    "tune": "experiments.tune", "bench": "experiments.bench", "figures": "experiments.figures",
    "study_chains": "study.chains", "study_figures": "study.figures",
    "study_results": "study.results",
    "cli_common": "cli.common", "cli_policies": "cli.policies", "cli_sweep": "cli.sweep",
    "sweep": "cli.sweep_trials", "sweep_report": "cli.sweep_report",
}


class _MovedModule(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Imports ``carl_sumo.<old name>`` as the module it moved to (the same module object)."""

    def find_spec(self, fullname, path=None, target=None):
        package, _, name = fullname.partition(".")
        if package != __name__ or name not in MOVED:
            return None
        return importlib.util.spec_from_loader(fullname, self)

    def create_module(self, spec):
        return None

    def exec_module(self, module) -> None:
        old = module.__name__
        sys.modules[old] = importlib.import_module(f"{__name__}.{MOVED[old.partition('.')[2]]}")


if not any(isinstance(f, _MovedModule) for f in sys.meta_path):
    sys.meta_path.append(_MovedModule())
