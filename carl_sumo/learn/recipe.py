"""Recipe files: a training configuration (:class:`TrainConfig`) as TOML, one table per section.

A recipe names the options it sets, by the name of their command-line flag with underscores
(``--eval-every`` is ``eval_every``), each in its section, and may extend another recipe
(``extends``, a path relative to the recipe), whose values it overrides::

    extends = "paper.toml"
    description = "CA-TD3 on the IDM base, 10 followers"

    [agent]
    algo = "ca-td3"
    vehicles = 10

    [training]
    steps = 10000

``carl-sumo train --config RECIPE.toml`` trains it (options given on the command line override
the recipe); every policy file stores its resolved configuration, and ``carl-sumo policy-info
--recipe POLICY.pt`` prints it back as a recipe that re-trains it. Paths in a recipe (``data``,
``val_events`` ...) are read from the folder ``train`` runs in, as on the command line.
"""

from __future__ import annotations

import functools
import json
import math
import tomllib
from dataclasses import fields
from pathlib import Path
from typing import Any, get_type_hints

from carl_sumo.errors import InputError
from carl_sumo.learn.train_config import SECTIONS, TrainConfig, flag_of
from carl_sumo.resources import shipped_name

TOP_KEYS = ("extends", "description")
"""Keys of a recipe outside its sections."""


def key_of(f) -> str:
    """A field's key in a recipe (and ``dest`` on the command line): its flag, underscored."""
    return flag_of(f).replace("-", "_")


def option_fields() -> dict[str, Any]:
    """The fields of :class:`TrainConfig` a user sets, by recipe key."""
    return {key_of(f): f for f in fields(TrainConfig) if f.metadata.get("cli", True)}


@functools.cache
def _hints() -> dict[str, Any]:
    return get_type_hints(TrainConfig)


def base_type(f) -> type:
    """The value type of a field (``float`` for ``float | None``)."""
    hint = _hints()[f.name]
    args = [a for a in getattr(hint, "__args__", ()) if a is not type(None)]
    return args[0] if args else hint


def coerce(key: str, value: Any, f, where: str) -> Any:
    """``value`` as the type of field ``f`` (an int is a float where a float is asked for);
    InputError naming ``where`` and the key if it is not of that type."""
    kind = base_type(f)
    if kind is float and isinstance(value, int) and not isinstance(value, bool):
        return float(value)
    if isinstance(value, kind) and not (kind is int and isinstance(value, bool)):
        return value
    wanted = {bool: "true or false", int: "a whole number", float: "a number"}.get(kind, "text")
    raise InputError(f"{where}: {key} = {value!r} is not {kind.__name__}; give {wanted}")


def read_recipe(path: Path | str, _seen: tuple[Path, ...] = ()) -> dict[str, Any]:
    """The options a recipe file sets (with those of the recipes it extends), by field name.
    InputError, one line, for a missing or malformed file, an unknown section or key, a key in
    the wrong section, a value of the wrong type or a cycle of ``extends``."""
    path = Path(path)
    if path.resolve() in _seen:
        raise InputError(f"{path}: extends itself (through {', '.join(p.name for p in _seen)})")
    try:
        with open(path, "rb") as fh:
            doc = tomllib.load(fh)
    except FileNotFoundError:
        raise InputError(f"recipe {path} does not exist; give the path of a recipe file, e.g. "
                         "recipes/product.toml") from None
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as exc:
        raise InputError(f"recipe {path} is not readable TOML: {exc}") from None
    values: dict[str, Any] = {}
    if "extends" in doc:
        if not isinstance(doc["extends"], str):
            raise InputError(f"{path}: extends = {doc['extends']!r} is not a path")
        values.update(read_recipe(path.parent / doc["extends"], (*_seen, path.resolve())))
    known = option_fields()
    for name, table in doc.items():
        if name in TOP_KEYS:
            continue
        if name not in SECTIONS or not isinstance(table, dict):
            raise InputError(f"{path}: unknown entry {name!r}; a recipe has extends, description "
                             f"and the sections {', '.join(SECTIONS)}")
        for key, value in table.items():
            f = known.get(key)
            if f is None:
                raise InputError(f"{path}: [{name}] {key} is not a training option (`carl-sumo "
                                 "train --help` lists them, with underscores for dashes)")
            if f.metadata["section"] != name:
                raise InputError(f"{path}: {key} belongs in [{f.metadata['section']}], not "
                                 f"[{name}]")
            values[f.name] = coerce(key, value, f, str(path))
    return values


def _toml_value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else ("nan" if math.isnan(value) else
                                                         ("inf" if value > 0 else "-inf"))
    if isinstance(value, int):
        return str(value)
    return json.dumps(str(value), ensure_ascii=False)


def recipe_toml(cfg: TrainConfig, description: str = "") -> str:
    """``cfg`` as a complete recipe (every option, section by section; an option without a
    value as a comment), which ``train --config`` reads back into the same configuration."""
    lines = [f"description = {_toml_value(description)}"] if description else []
    by_section: dict[str, list[str]] = {s: [] for s in SECTIONS}
    for key, f in option_fields().items():
        value = getattr(cfg, f.name)
        if isinstance(value, str) and f.metadata.get("folder") is not None:
            value = shipped_name(value, f.metadata["folder"])  # by name: it reads from anywhere
        unit = f" ({f.metadata['unit']})" if f.metadata["unit"] else ""
        text = f"{key} = {_toml_value(value)}" if value is not None else f"# {key} = (none)"
        by_section[f.metadata["section"]] += [f"# {f.metadata['doc']}{unit}", text]
    for section, rows in by_section.items():
        lines += ["", f"[{section}]", *rows]
    return "\n".join(lines) + "\n"


def stored_config(cfg: TrainConfig) -> dict[str, Any]:
    """The options of ``cfg`` by recipe key, as a policy file stores them."""
    return {key: getattr(cfg, f.name) for key, f in option_fields().items()}


def config_from_stored(stored: dict[str, Any]) -> TrainConfig:
    """The :class:`TrainConfig` of a policy file's stored options (keys it does not know are
    InputError: a policy from a newer carl-sumo)."""
    known = option_fields()
    unknown = sorted(set(stored) - set(known))
    if unknown:
        raise InputError(f"the policy's configuration has options this carl-sumo does not know "
                         f"({', '.join(unknown)}); use the version that trained it")
    return TrainConfig(**{known[k].name: v for k, v in stored.items()})
