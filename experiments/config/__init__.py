"""Experiment parameters: pydantic schemas, TOML configs, and their listing.

Every experiment declares its parameters as a :class:`Parameters` model (one
field per physical choice, the unit in the field's name, a one-line
description); nested tables (``[orbit]``, ``[[antennas]]``, ``[gyro]``, ...)
are models of their own (:mod:`attopt.experiments.config.components`).
:func:`resolve_parameters` merges the quick variant, a TOML file and
overrides and validates them once, reporting every error at once
(:class:`ConfigError`); :func:`describe` and :func:`starter_toml` are what
``attopt show`` prints.  See ``docs/configuration.md``.
"""

from attopt.experiments.config.loading import (
    ConfigError,
    load_config,
    resolve_parameters,
    validate_parameters,
)
from attopt.experiments.config.schema import (
    ParameterInfo,
    Parameters,
    describe,
    flat_items,
    starter_toml,
    unit_of,
)

__all__ = [
    "ConfigError",
    "ParameterInfo",
    "Parameters",
    "describe",
    "flat_items",
    "load_config",
    "resolve_parameters",
    "starter_toml",
    "unit_of",
    "validate_parameters",
]
