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
each CACC chain is a platoon of its own (:class:`carl_sumo.experiments.chain_controllers.ExternalChains`).

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


def _shown(value) -> str:
    """What a controller returned, on one short line."""
    try:
        arr = np.asarray(value)
        if arr.dtype.kind in "biufc" and arr.ndim <= 2:
            text = np.array2string(arr, threshold=8, edgeitems=3, max_line_width=10_000)
            return f"{text} ({type(value).__name__}, shape {arr.shape})"
    except Exception:  # noqa: BLE001 - anything odd is shown by its repr
        pass
    text = repr(value)
    return (text if len(text) <= 80 else text[:77] + "...") + f" ({type(value).__name__})"


def _raised(exc: BaseException) -> str:
    """What a controller raised, on one line."""
    if isinstance(exc, SystemExit):
        return f"called sys.exit({exc.code!r})"
    text = " ".join(str(exc).split())
    if len(text) > 200:
        text = text[:197] + "..."
    return f"raised {type(exc).__name__}" + (f": {text}" if text else "")


USER_ERRORS = (Exception, SystemExit)
"""What user code may raise that carl-sumo reports as one line (not KeyboardInterrupt: Ctrl-C and
the signals stop the command as they always do)."""


class ExternalController:
    """The one boundary between carl-sumo and a controller of its user, for classes and plain
    callables alike: every call (reset, connect, acceleration or adjustment) is made here, and
    whatever it raises (any exception, ``sys.exit``) or returns that is not a finite array of
    one value per follower becomes an :class:`InputError` naming the controller, the step and
    what it returned or raised: one line, exit status 2, the same line from a worker process.

    ``step`` counts the calls since ``reset`` (the simulation step of a platoon run); a caller
    that resets the controller every step (``study``'s chains) sets ``step`` itself and
    ``counting = False``."""

    kind = "acceleration"

    def __init__(self, inner, name: str):
        self.inner, self.spec = inner, name
        self.name = getattr(inner, "name", None) if not isinstance(inner, _Function) else None
        if not isinstance(self.name, str) or not self.name:
            self.name = name
        self.step, self.counting = 0, True

    def _fail(self, what: str) -> InputError:
        return InputError(f"controller {self.spec} {what}; fix the controller")

    def _label(self, method: str) -> str:
        """How a call is named in an error: ``acceleration()``, or the function's own name."""
        if isinstance(self.inner, _Function) and method == "acceleration":
            return f"{self.spec.rpartition(':')[2]}(observations)"
        return f"{method}()"

    def _call(self, method: str, *args):
        try:
            return getattr(self.inner, method)(*args)
        except KeyboardInterrupt:
            raise
        except USER_ERRORS as exc:
            where = f"at step {self.step}: " if method in ("acceleration", "adjustment") \
                else "in "
            raise self._fail(f"{where}{self._label(method)} {_raised(exc)}") from None

    def reset(self, n_followers: int) -> None:
        if self.counting:
            self.step = 0
        self._call("reset", n_followers)

    def __getattr__(self, attr: str):
        """Anything else of the controller (``connect``, ``know_vehicles``, ``bounds``): its
        methods called through the same boundary."""
        if attr in ("inner", "spec", "step", "counting", "name") or attr.startswith("__"):
            raise AttributeError(attr)
        value = getattr(self.inner, attr)
        if not callable(value):
            return value
        return lambda *args: self._call(attr, *args)

    def _act(self, obs: np.ndarray) -> np.ndarray:
        method = self.kind
        raw = self._call(method, obs)
        n = obs.shape[0]
        try:
            a = np.asarray(raw, dtype=np.float64)
        except KeyboardInterrupt:
            raise
        except USER_ERRORS:
            a = None
        if a is None or a.shape != (n,) or not np.all(np.isfinite(a)):
            raise self._fail(f"at step {self.step}: {self._label(method)} returned "
                             f"{_shown(raw)}, not {n} finite accelerations in m/s² (shape "
                             f"({n},), one per follower, head first)")
        if self.counting:
            self.step += 1
        return a


class ExternalAcceleration(ExternalController):
    """An external controller that sets the whole acceleration."""

    def acceleration(self, obs: np.ndarray) -> np.ndarray:
        return np.clip(self._act(obs), BOUNDS.acc_min_mps2, BOUNDS.acc_max_mps2)


class ExternalAdjustment(ExternalController):
    """An external controller whose output is added to IDM."""

    kind = "adjustment"

    def adjustment(self, obs: np.ndarray) -> np.ndarray:
        return self._act(obs)


class _Function:
    """A plain callable f(obs) -> accelerations as a controller (inside the boundary)."""

    def __init__(self, fn):
        self.fn = fn

    def reset(self, n_followers: int) -> None:
        pass

    def acceleration(self, obs: np.ndarray):
        return self.fn(np.array(obs[:, :4], dtype=np.float64))


def _import(name: str, target: str):
    """The module of ``target`` (a dotted name or a .py file)."""
    try:
        if target.endswith(".py"):
            path = Path(target)
            if not path.is_file():
                raise InputError(f"controller {name}: no file {path}")
            spec = importlib.util.spec_from_file_location(f"carl_sumo_external_{path.stem}", path)
            module = importlib.util.module_from_spec(spec)
            spec.loader.exec_module(module)
            return module
        return importlib.import_module(target)
    except (InputError, KeyboardInterrupt):
        raise
    except USER_ERRORS as exc:
        raise InputError(f"controller {name}: {target} does not import "
                         f"({_raised(exc)})") from None


def load_external(name: str) -> ExternalController:
    """The controller of ``module:attribute`` or ``file.py:attribute``, behind the boundary of
    :class:`ExternalController`; InputError naming what is missing or what its import or
    constructor raised."""
    target, _, attr = name.rpartition(":")
    module = _import(name, target)
    if not hasattr(module, attr):
        raise InputError(f"controller {name}: {target} has no attribute {attr!r}")
    obj = getattr(module, attr)
    if inspect.isclass(obj):
        try:
            obj = obj()
        except KeyboardInterrupt:
            raise
        except USER_ERRORS as exc:
            hint = " (give a class that takes no arguments, or a factory function that builds " \
                "one)" if isinstance(exc, TypeError) else ""
            raise InputError(f"controller {name}: constructing {attr}() {_raised(exc)}"
                             f"{hint}") from None
    if hasattr(obj, "reset") and hasattr(obj, "acceleration"):
        return ExternalAcceleration(obj, name)
    if hasattr(obj, "reset") and hasattr(obj, "adjustment"):
        return ExternalAdjustment(obj, name)
    if callable(obj):
        return ExternalAcceleration(_Function(obj), name)
    raise InputError(f"controller {name}: {attr} is neither a controller (reset + acceleration "
                     "or adjustment) nor a callable f(observations) -> accelerations")
