"""Options: a dataclass field that carries its doc, unit, range, allowed values, the section of a
recipe file it belongs to and its command-line flag (:func:`option`).

A parameter is declared once, with :func:`option`, in the dataclass that uses it
(:class:`carl_sumo.config.RewardConfig`, :class:`carl_sumo.learn.agents.AgentConfig`,
:class:`carl_sumo.learn.train_config.TrainConfig`); a configuration that gathers it from there
takes it with :func:`shared` (same default and metadata, the source recorded). The command-line
options (:mod:`carl_sumo.cli.config_options`), their ``--help``, the recipe files
(:mod:`carl_sumo.learn.recipe`) and the range checks (:func:`check_range`) derive from them.
"""

from __future__ import annotations

import math
from dataclasses import MISSING, field, fields
from pathlib import Path
from typing import Any, Sequence

from carl_sumo.errors import InputError

SECTIONS = {
    "data": "the events trained and validated on",
    "plant": "the followers' vehicle dynamics, V2V channel and sensors",
    "base": "the classical law under the learned adjustment and its safety layers",
    "reward": "the reward's terms and weights (carl_sumo.config.RewardConfig)",
    "agent": "the algorithm, its networks, optimisers and exploration "
             "(carl_sumo.learn.agents.AgentConfig)",
    "training": "how long and how the run trains, and how it starts",
    "validation": "the held-out events and how the kept checkpoint is chosen",
}
"""The sections of a recipe file, in order, with what each holds."""

INF = math.inf


def option(default: Any, doc: str, section: str, *, unit: str = "", low: float | None = None,
           high: float | None = None, open_low: bool = False, open_high: bool = False,
           choices: Sequence[str] | None = None, flag: str | None = None, metavar: str | None = None,
           cli: bool = True, folder: Path | None = None) -> Any:
    """An option: a dataclass field with its doc, unit, range ([low, high], ends open where
    said; finite in any case), allowed values, section and command-line flag (default: the
    field name with dashes); ``cli`` False: a parameter no command line or recipe sets;
    ``folder``: a path whose file, when it does not exist, is the file of that name shipped in
    ``folder`` (:func:`carl_sumo.resources.shipped`)."""
    if section not in SECTIONS:
        raise ValueError(f"unknown section {section!r}")
    return field(default=default, metadata=dict(
        doc=doc, section=section, unit=unit, low=low, high=high, open_low=open_low,
        open_high=open_high, choices=tuple(choices) if choices else None, flag=flag,
        metavar=metavar, cli=cli, folder=folder))


def shared(source: type, name: str) -> Any:
    """The option ``name`` of the dataclass ``source``, for a configuration that gathers it:
    the same default, doc, unit, range, section and flag, with ``source`` = (class, field name)
    recorded (:func:`sourced` gives them back as ``source``'s keyword arguments)."""
    f = next((f for f in fields(source) if f.name == name), None)
    if f is None or f.default is MISSING or "doc" not in f.metadata:
        raise ValueError(f"{source.__name__}.{name} is not an option")
    return field(default=f.default, metadata={**f.metadata, "source": (source, name)})


def sourced(config: Any, source: type) -> dict[str, Any]:
    """The values of ``config``'s options taken from ``source`` (:func:`shared`), by their name
    in ``source``: the keyword arguments of a ``source`` with them."""
    return {f.metadata["source"][1]: getattr(config, f.name) for f in fields(config)
            if f.metadata.get("source", (None,))[0] is source}


def flag_of(f) -> str:
    """The command-line flag of an option's field (without the dashes)."""
    return f.metadata.get("flag") or f.name.replace("_", "-")


def bounds_text(meta: dict) -> str:
    """``[0, inf)``-style text of a field's range ('' without one)."""
    low, high = meta.get("low"), meta.get("high")
    if low is None and high is None:
        return ""
    low = -INF if low is None else low
    high = INF if high is None else high
    left = "(" if meta["open_low"] or low == -INF else "["
    right = ")" if meta["open_high"] or high == INF else "]"
    return f"{left}{_number(low)}, {_number(high)}{right}"


def _number(x: float) -> str:
    return str(int(x)) if math.isfinite(x) and x == int(x) and abs(x) < 1e12 else f"{x:g}"


def check_choices(config: Any) -> None:
    """InputError, one line, for a field of ``config`` whose value is not one of its allowed
    values (``choices``; None passes)."""
    for f in fields(config):
        choices, value = f.metadata.get("choices"), getattr(config, f.name)
        if choices and value is not None and value not in choices:
            raise InputError(f"unknown --{flag_of(f)} {value!r}; choose one of "
                             + ", ".join(choices))


def check_range(name: str, value: Any, meta: dict) -> None:
    """InputError, one line, for a value outside its field's range (``name``: the flag)."""
    low, high = meta.get("low"), meta.get("high")
    if value is None or isinstance(value, (bool, str)) or (low is None and high is None):
        return
    low = -INF if low is None else low
    high = INF if high is None else high
    inside = math.isfinite(value) \
        and (low < value if meta["open_low"] else low <= value) \
        and (value < high if meta["open_high"] else value <= high)
    if not inside:
        kind = "a whole number" if isinstance(value, int) else "a finite number"
        raise InputError(f"--{name} must be {kind} in {bounds_text(meta)}, got {value}")
