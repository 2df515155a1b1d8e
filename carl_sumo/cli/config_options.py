"""Command-line options generated from :class:`carl_sumo.learn.train_config.TrainConfig`.

``train``: every field becomes one option (``--flag``, its type from the annotation, its help
from the field's doc, unit, default and range), grouped by the field's section. A parsed value
is None unless given, so that a recipe (``--config``) supplies the rest: :func:`config_from_args` merges
the defaults, the recipe and the options given, in that order of precedence. The commands
that share some of these options (``simulate``, ``evaluate``, ``study`` ...: the V2V channel,
sensors and plant) take them from the same fields (:func:`add_shared_options`).
"""

from __future__ import annotations

import argparse
import functools
from dataclasses import fields
from pathlib import Path
from typing import Any, Callable, Sequence

from carl_sumo.errors import InputError
from carl_sumo.learn.recipe import base_type, coerce, key_of, option_fields, read_recipe
from carl_sumo.learn.train_config import TrainConfig
from carl_sumo.options import SECTIONS, bounds_text, check_range, flag_of
from carl_sumo.resources import shipped


def _shown(value: Any) -> str:
    if value is None:
        return "none"
    if isinstance(value, str) and Path(value).is_absolute():
        return Path(value).name  # a shipped file, found by name
    return f"{value:g}" if isinstance(value, float) else str(value).lower() \
        if isinstance(value, bool) else str(value)


def help_of(f) -> str:
    """The ``--help`` text of a field: its doc, unit, allowed values, range and default."""
    meta = f.metadata
    parts = [meta["doc"].replace("%", "%%")]
    extra = [meta["unit"]] if meta["unit"] else []
    if meta["choices"]:
        extra.append("one of " + ", ".join(meta["choices"]))
    if bounds_text(meta):
        extra.append("in " + bounds_text(meta))
    if not (f.default is None and "none:" in meta["doc"]):
        extra.append("default " + _shown(f.default))
    return f"{parts[0]} ({'; '.join(extra)})"


def _metavar(f, kind: type) -> str:
    choices = f.metadata["choices"]
    return f.metadata["metavar"] or ("{" + ",".join(choices) + "}" if choices else
                                     {int: "N", float: "X"}.get(kind, "TEXT"))


def field_converters(converters: dict[str, Callable[[str], Any]] | None = None
                     ) -> dict[str, Callable[[str], Any]]:
    """The functions that read the :class:`TrainConfig` fields given as text: for a field with
    a shipped ``folder`` (``net``, the event lists), a shipped file found by its name
    (:func:`carl_sumo.resources.shipped`); ``converters`` add to and replace them."""
    shipped_in = {f.name: functools.partial(shipped, folder=f.metadata["folder"])
                  for f in fields(TrainConfig) if f.metadata.get("folder") is not None}
    return {**shipped_in, **(converters or {})}


def add_config_options(p: argparse.ArgumentParser,
                       converters: dict[str, Callable[[str], Any]] | None = None) -> None:
    """One option per :class:`TrainConfig` field, in an argument group per section;
    ``converters`` replace the type of named fields (:func:`field_converters`)."""
    converters = field_converters(converters)
    groups = {s: p.add_argument_group(f"{s} options", doc) for s, doc in SECTIONS.items()}
    for key, f in option_fields().items():
        group = groups[f.metadata["section"]]
        flag = "--" + key.replace("_", "-")
        kind = base_type(f)
        if kind is bool:
            group.add_argument(flag, dest=key, action=argparse.BooleanOptionalAction,
                               default=None, help=help_of(f))
        else:
            group.add_argument(flag, dest=key, type=converters.get(f.name, kind), default=None,
                               metavar=_metavar(f, kind), help=help_of(f))


def add_shared_options(p: argparse.ArgumentParser, names: Sequence[str]) -> None:
    """``train``'s options of the :class:`TrainConfig` fields ``names`` for a command that reads
    no recipe (simulate, evaluate, study ...): the same flag, type, allowed values and help, the
    field's default as the default, a switch (``store_true``) for a boolean. Their ranges are
    checked by :func:`check_shared_options`."""
    by_name = {f.name: f for f in fields(TrainConfig)}
    for name in names:
        f = by_name[name]
        kind, flag = base_type(f), "--" + flag_of(f)
        if kind is bool:
            p.add_argument(flag, dest=key_of(f), action="store_true", help=help_of(f))
        else:
            p.add_argument(flag, dest=key_of(f), type=kind, default=f.default,
                           choices=f.metadata["choices"], metavar=_metavar(f, kind),
                           help=help_of(f))


def check_shared_options(args: argparse.Namespace, names: Sequence[str]) -> None:
    """InputError, one line, for a value of the options of fields ``names``
    (:func:`add_shared_options`) outside its field's range."""
    by_name = {f.name: f for f in fields(TrainConfig)}
    for name in names:
        f = by_name[name]
        check_range(flag_of(f), getattr(args, key_of(f), None), f.metadata)


def config_from_args(args: argparse.Namespace, command: str = "",
                     converters: dict[str, Callable[[str], Any]] | None = None,
                     check: bool = True) -> TrainConfig:
    """The :class:`TrainConfig` of parsed options: the defaults, then the recipe of
    ``args.config`` (when given), then every option given on the command line (``none`` unsets
    an option whose default is none, e.g. a recipe's ``--imitate``); checked
    (:meth:`TrainConfig.check`) unless ``check`` is False. InputError, one line, for a bad
    recipe or value."""
    values: dict[str, Any] = {}
    if getattr(args, "config", None) is not None:
        values.update(read_recipe(args.config))
    for key, f in option_fields().items():
        given = getattr(args, key, None)
        if given is not None and f.default is None and given == "none":
            values[f.name] = None  # e.g. --imitate none: a recipe's option left out
        elif given is not None:
            values[f.name] = coerce(key, given, f, "--" + key.replace("_", "-"))
    for name, convert in field_converters(converters).items():
        if isinstance(values.get(name), str):
            values[name] = convert(values[name])
    try:
        cfg = TrainConfig(**values, command=command)
        return cfg.check() if check else cfg
    except TypeError as exc:  # pragma: no cover - a field the generator missed
        raise InputError(f"bad training options: {exc}") from None
