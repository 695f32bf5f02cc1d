"""Resolve an experiment's parameters: defaults, quick variant, TOML overrides.

The TOML file may only contain a ``[parameters]`` table whose keys are the
experiment's parameter names.  Each value is checked against the type of the
default value (an int is accepted where a float is expected, and list elements
are checked against the default list's elements).  The file is parsed with
:mod:`tomllib`, which only reads data.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from attopt.experiments.experiment import Experiment

CONFIG_TABLES = ("parameters",)


class ConfigError(ValueError):
    """A parameter override names an unknown key or has the wrong type."""


def resolve_parameters(
    experiment: Experiment,
    *,
    quick: bool = False,
    config: Path | None = None,
    overrides: Mapping[str, Any] | None = None,
) -> dict[str, Any]:
    """Return the experiment's parameters after the quick variant, the TOML file and overrides.

    Later sources win: ``experiment.parameters``, then ``experiment.quick_parameters``
    when ``quick``, then the ``[parameters]`` table of ``config``, then ``overrides``.
    Raises :class:`ConfigError` naming the offending key.
    """
    parameters = dict(experiment.parameters)
    if quick:
        parameters = apply_overrides(
            parameters, experiment.quick_parameters, f"{experiment.name}.quick_parameters"
        )
    if config is not None:
        parameters = apply_overrides(parameters, load_config(config), str(config))
    if overrides:
        parameters = apply_overrides(parameters, overrides, "overrides")
    return parameters


def load_config(path: Path) -> dict[str, Any]:
    """Return the ``[parameters]`` table of the TOML file at ``path``."""
    try:
        with Path(path).open("rb") as stream:
            document = tomllib.load(stream)
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(f"{path}: invalid TOML: {error}") from None
    except OSError as error:
        raise ConfigError(f"{path}: cannot read config: {error.strerror}") from None
    for key in document:
        if key not in CONFIG_TABLES:
            raise ConfigError(
                f"{path}: unknown key {key!r}; allowed top-level tables: {', '.join(CONFIG_TABLES)}"
            )
    table = document.get("parameters", {})
    if not isinstance(table, dict):
        raise ConfigError(f"{path}: 'parameters' must be a table ([parameters])")
    return table


def apply_overrides(
    parameters: Mapping[str, Any], overrides: Mapping[str, Any], source: str
) -> dict[str, Any]:
    """Return ``parameters`` updated from ``overrides``, each checked against its default."""
    updated = dict(parameters)
    for key, value in overrides.items():
        if key not in parameters:
            valid = ", ".join(sorted(parameters)) or "(none)"
            raise ConfigError(f"unknown parameter {key!r} in {source}; valid parameters: {valid}")
        updated[key] = coerce(key, value, parameters[key], source)
    return updated


def coerce(name: str, value: Any, default: Any, source: str) -> Any:
    """Return ``value`` converted to the type of ``default``; raise ConfigError naming ``name``."""
    if default is None:
        return value
    if isinstance(default, bool):
        return _require(name, value, isinstance(value, bool), "a boolean", source)
    if isinstance(default, int):
        ok = isinstance(value, int) and not isinstance(value, bool)
        return _require(name, value, ok, "an integer", source)
    if isinstance(default, float):
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        return float(_require(name, value, ok, "a number", source))
    if isinstance(default, str):
        return _require(name, value, isinstance(value, str), "a string", source)
    if isinstance(default, list | tuple):
        _require(name, value, isinstance(value, list | tuple), "an array", source)
        prototype = _element_prototype(default)
        if prototype is not None:
            value = [
                coerce(f"{name}[{index}]", item, prototype, source)
                for index, item in enumerate(value)
            ]
        return type(default)(value)
    if isinstance(default, Mapping):
        _require(name, value, isinstance(value, Mapping), "a table", source)
        return apply_overrides(default, value, f"{source} (table {name!r})")
    ok = isinstance(value, type(default))
    return _require(name, value, ok, f"of type {type(default).__name__}", source)


def _require(name: str, value: Any, ok: bool, expected: str, source: str) -> Any:
    if not ok:
        raise ConfigError(
            f"parameter {name!r} in {source} must be {expected}, "
            f"got {type(value).__name__} {value!r}"
        )
    return value


def _element_prototype(default: list[Any] | tuple[Any, ...]) -> Any:
    """Return a value whose type every element must have, or None to skip element checks."""
    types = {type(item) for item in default}
    if types == {int, float}:
        return 0.0
    if len(types) == 1:
        return default[0]
    return None
