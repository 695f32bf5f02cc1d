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
        raise ConfigError(source, _problems(schema, error.errors())) from None


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


def _problems(schema: type[Parameters], errors: list[Any]) -> list[str]:
    """One line per bad key: a value that fits no variant of a union (``gyro = "x"``, a
    preset or a table) gets one line joining what each variant expects."""
    lines: dict[str, list[str]] = {}
    for error in errors:
        unknown = error["type"] == "extra_forbidden"
        location, _ = _follow(schema, list(error["loc"]), keep_unknown_key=unknown)
        path = _path(location)
        if unknown:
            _, parents = _follow(schema, location[:-1])
            valid = sorted({name for model in parents for name in model.model_fields})
            listing = f"; valid keys here: {', '.join(valid)}" if valid else ""
            lines[f"unknown {path}"] = [f"unknown key {path!r}{listing}"]
        elif error["type"] == "missing":
            lines.setdefault(path, []).append(f"{path}: missing")
        else:
            head = f"{path} = {error['input']!r}: "
            lines.setdefault(path, []).append(head + error["msg"])
    return [_joined(group) for group in lines.values()]


def _joined(group: list[str]) -> str:
    """The messages of one key path as one line."""
    head = group[0][: group[0].index(": ") + 2] if ": " in group[0] else ""
    return head + ", or ".join(message[len(head) :] for message in group)


def _follow(
    schema: type[Parameters], location: list[Any], *, keep_unknown_key: bool = False
) -> tuple[list[Any], list[type[BaseModel]]]:
    """The key path of a pydantic error location without the union variants' tags that
    pydantic inserts (a last part that is no field is an unknown key only with
    ``keep_unknown_key``), and the models that can hold the last key."""
    models: list[type[BaseModel]] = [schema]
    path: list[Any] = []
    for index, part in enumerate(location):
        if isinstance(part, int):
            path.append(part)
            continue
        fields = [m.model_fields[part] for m in models if part in m.model_fields]
        if not fields and (index < len(location) - 1 or not keep_unknown_key):
            continue  # the tag or class name of a union's variant
        path.append(part)
        models = [m for f in fields for m in model_classes(f.annotation, items=True)]
    return path, models


def _path(location: list[Any]) -> str:
    path = ""
    for part in location:
        path += f"[{part}]" if isinstance(part, int) else (f".{part}" if path else str(part))
    return path or "(top level)"
