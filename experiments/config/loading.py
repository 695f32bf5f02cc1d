"""Resolve an experiment's parameters: defaults, quick variant, TOML file, overrides.

The TOML file holds the parameters themselves at its top level, nested tables
for the nested models (``[orbit]``, ``[[antennas]]``, ``[gyro]``).  It is
parsed with :mod:`tomllib` (which only reads data), deep-merged over the
defaults and validated by the experiment's pydantic schema in one pass, so
every bad key and value is reported at once, each with its key path.
"""

from __future__ import annotations

import tomllib
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from pydantic import BaseModel, ValidationError

from attopt.experiments.config.schema import Parameters, model_classes

if TYPE_CHECKING:
    from attopt.experiments.experiment import Experiment


class ConfigError(ValueError):
    """A configuration names unknown keys, holds bad values or cannot be read.

    ``problems`` holds one line per error (key path, bad value, what is expected).
    """

    def __init__(self, source: str, problems: list[str]) -> None:
        self.source = source
        self.problems = problems
        plural = "s" if len(problems) > 1 else ""
        super().__init__(f"{source}: {len(problems)} error{plural}: " + "; ".join(problems))


def resolve_parameters(
    experiment: Experiment,
    *,
    quick: bool = False,
    config: Path | None = None,
    overrides: Mapping[str, Any] | None = None,
) -> Parameters:
    """The experiment's validated parameters after the quick variant, the TOML file and
    ``overrides`` (later sources win; tables merge key by key, arrays are replaced).

    Raises :class:`ConfigError` listing every problem.

    Example::

        >>> from attopt.experiments.registry import get_experiment
        >>> resolve_parameters(get_experiment("noop"), overrides={"settings": 2}).settings
        2
    """
    document: dict[str, Any] = {}
    if quick:
        document = deep_merge(document, experiment.quick_parameters)
    source = "parameters"
    if config is not None:
        document = deep_merge(document, load_config(config))
        source = str(config)
    if overrides:
        document = deep_merge(document, overrides)
    return validate_parameters(experiment.schema, document, source)


def validate_parameters(
    schema: type[Parameters], document: Mapping[str, Any], source: str = "parameters"
) -> Parameters:
    """``schema`` validated from ``document``; :class:`ConfigError` lists every error.

    Example::

        >>> from attopt.experiments.registry import get_experiment
        >>> schema = get_experiment("noop").schema
        >>> validate_parameters(schema, {"settings": "many", "sleeps": 1}, "my.toml")
        Traceback (most recent call last):
        ...
        attopt.experiments.config.loading.ConfigError: my.toml: 2 errors: settings = 'many': ...
    """
    try:
        return schema.model_validate(dict(document))
    except ValidationError as error:
        raise ConfigError(source, [_problem(schema, item) for item in error.errors()]) from None


def load_config(path: Path) -> dict[str, Any]:
    """The parameter document of the TOML file at ``path``.

    Example::

        >>> import tempfile, pathlib
        >>> path = pathlib.Path(tempfile.mkdtemp()) / "noop.toml"
        >>> _ = path.write_text("settings = 2\\n")
        >>> load_config(path)
        {'settings': 2}
    """
    try:
        with Path(path).open("rb") as stream:
            return tomllib.load(stream)
    except tomllib.TOMLDecodeError as error:
        raise ConfigError(str(path), [f"invalid TOML: {error}"]) from None
    except OSError as error:
        raise ConfigError(str(path), [f"cannot read config: {error.strerror}"]) from None


def deep_merge(base: Mapping[str, Any], update: Mapping[str, Any]) -> dict[str, Any]:
    """``base`` updated by ``update``: tables merge key by key, anything else is replaced.

    Example::

        >>> deep_merge({"orbit": {"a": 1, "b": 2}, "n": 1}, {"orbit": {"b": 3}})
        {'orbit': {'a': 1, 'b': 3}, 'n': 1}
    """
    merged = dict(base)
    for key, value in update.items():
        if isinstance(value, Mapping) and isinstance(merged.get(key), Mapping):
            merged[key] = deep_merge(merged[key], value)
        else:
            merged[key] = value
    return merged


def _problem(schema: type[Parameters], error: Mapping[str, Any]) -> str:
    """One line for a pydantic error: key path, the bad value, what is expected."""
    location, _ = _follow(schema, list(error["loc"]))
    path = _path(location)
    if error["type"] == "extra_forbidden":
        _, parents = _follow(schema, location[:-1])
        valid = sorted({name for model in parents for name in model.model_fields})
        listing = f"; valid keys here: {', '.join(valid)}" if valid else ""
        return f"unknown key {path!r}{listing}"
    if error["type"] == "missing":
        return f"{path}: missing"
    return f"{path} = {error['input']!r}: {error['msg']}"


def _follow(
    schema: type[Parameters], location: list[Any]
) -> tuple[list[Any], list[type[BaseModel]]]:
    """The key path of a pydantic error location without the union variants' tags that
    pydantic inserts, and the models that can hold the last key."""
    models: list[type[BaseModel]] = [schema]
    path: list[Any] = []
    for index, part in enumerate(location):
        if isinstance(part, int):
            path.append(part)
            continue
        fields = [m.model_fields[part] for m in models if part in m.model_fields]
        if not fields and index < len(location) - 1:
            continue  # the tag or class name of a union's variant
        path.append(part)
        models = [m for f in fields for m in model_classes(f.annotation, items=True)]
    return path, models


def _path(location: list[Any]) -> str:
    path = ""
    for part in location:
        path += f"[{part}]" if isinstance(part, int) else (f".{part}" if path else str(part))
    return path or "(top level)"
