"""Controllers from outside carl-sumo: ``--controller module:attribute`` or
``--controller path/to/file.py:attribute`` on simulate, replay, evaluate, study and
string-stability.

The attribute is one of

- a class (or factory) whose instance has ``reset(n_followers)`` and either
  ``acceleration(obs) -> a`` (the whole acceleration) or ``adjustment(obs) -> a_adj`` (added to IDM,
  within carl-sumo's bounds); ``connect(impairments, event_id)`` is called too when it has one and
  the V2V channel is impaired;
- an object with those methods;
- a plain callable ``f(observations) -> accelerations``: observations an (n, 4) array
  [v m/s, a m/s², d m, Δv m/s] head first, accelerations an (n,) array in m/s², applied as they are
  (clipped to the followers' bounds) and through the vehicle dynamics of the plant.

A vehicle with nothing ahead within its sensors' range (a free road in ``study``) sees d = that
range and Δv = 0: a controller that is not added to IDM keeps its own cruise speed. In ``study``
each CACC chain is a platoon of its own (:class:`carl_sumo.study.controllers.ExternalChains`).

An RLlib checkpoint or an SB3 model is scored by wrapping its ``compute_single_action`` /
``predict`` in such a callable (``examples/``).
"""

from __future__ import annotations

import importlib
import importlib.util
import inspect
from pathlib import Path

import numpy as np

from carl_sumo.config import BOUNDS
from carl_sumo.errors import InputError


def is_external_name(name: str) -> bool:
    """Whether a controller name is ``module:attribute`` or ``file.py:attribute``."""
    head, sep, attr = name.rpartition(":")
    return bool(sep and head and attr.isidentifier() and "=" not in name
                and (head.endswith(".py") or all(p.isidentifier() for p in head.split("."))))


class CallableController:
    """A plain callable f(obs) -> accelerations as an acceleration controller."""

    def __init__(self, fn, name: str):
        self.fn, self.name = fn, name
        self.n = 0

    def reset(self, n_followers: int) -> None:
        self.n = n_followers

    def acceleration(self, obs: np.ndarray) -> np.ndarray:
        a = np.asarray(self.fn(np.array(obs[:, :4], dtype=np.float64)), dtype=np.float64)
        if a.shape != (obs.shape[0],) or not np.all(np.isfinite(a)):
            raise InputError(f"controller {self.name} returned {a.shape} accelerations (finite "
                             f"values needed, shape ({obs.shape[0]},))")
        return np.clip(a, BOUNDS.acc_min_mps2, BOUNDS.acc_max_mps2)


def load_external(name: str):
    """The controller of ``module:attribute`` or ``file.py:attribute``; InputError naming what
    is missing."""
    target, _, attr = name.rpartition(":")
    try:
        if target.endswith(".py"):
            path = Path(target)
            if not path.is_file():
                raise InputError(f"controller {name}: no file {path}")
            spec = importlib.util.spec_from_file_location(f"carl_sumo_external_{path.stem}", path)
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
        else:
            module = importlib.import_module(target)
    except InputError:
        raise
    except Exception as exc:
        raise InputError(f"controller {name}: {target} does not import "
                         f"({type(exc).__name__}: {exc})") from None
    if not hasattr(module, attr):
        raise InputError(f"controller {name}: {target} has no attribute {attr!r}")
    obj = getattr(module, attr)
    if inspect.isclass(obj):
        obj = obj()
    if hasattr(obj, "reset") and (hasattr(obj, "acceleration") or hasattr(obj, "adjustment")):
        if not hasattr(obj, "name"):
            obj.name = name
        return obj
    if callable(obj):
        return CallableController(obj, name)
    raise InputError(f"controller {name}: {attr} is neither a controller (reset + acceleration "
                     "or adjustment) nor a callable f(observations) -> accelerations")
