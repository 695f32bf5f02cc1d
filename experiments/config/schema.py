"""The base of every parameter model, its listing, and its starter TOML file.

Units are part of the parameter names (``duration_s``, ``altitude_km``,
``snr_sigma_db``): :func:`unit_of` reads them back for ``attopt show``, so a
name without a unit suffix is a count, a flag, a name or a dimensionless
number.
"""

from __future__ import annotations

import types
import typing
from collections.abc import Iterator, Mapping
from dataclasses import dataclass
from typing import Any

import tomli_w
from pydantic import BaseModel, ConfigDict

UNITS: dict[str, str] = {
    "_deg_h_sqrt_h": "deg/h/sqrt(h)",
    "_deg_sqrt_h": "deg/sqrt(h)",
    "_deg_s": "deg/s",
    "_deg_h": "deg/h",
    "_deg": "deg",
    "_rad": "rad",
    "_utc": "UTC (ISO 8601)",
    "_km": "km",
    "_m": "m",
    "_m_s": "m/s",
    "_kt": "kt",
    "_ft": "ft",
    "_s": "s",
    "_h": "h",
    "_hz": "Hz",
    "_dbi": "dBi",
    "_dbw": "dBW",
    "_db": "dB",
    "_k": "K",
    "_kg_m2": "kg m^2",
    "_nms": "N m s",
    "_w": "W",
}
"""Name suffix -> unit, longest suffixes first (:func:`unit_of`)."""


class Parameters(BaseModel):
    """Base of the experiments' parameter models and of their nested tables.

    Unknown keys are errors, values are validated strictly on construction (no
    strings for numbers or flags; an integer is accepted for a float) and the
    model is immutable.  Give every field a default and a one-line
    ``description``, and put its unit in its name.

    Example::

        >>> from pydantic import Field
        >>> class Pass(Parameters):
        ...     duration_s: float = Field(60.0, gt=0, description="Length of the pass.")
        >>> Pass(duration_s=30).duration_s
        30.0
    """

    model_config = ConfigDict(extra="forbid", frozen=True, validate_default=True, strict=True)


class _Required:
    """The default of a field that its table must set (``attopt show`` prints ``required``)."""

    def __repr__(self) -> str:
        return "required"


REQUIRED = _Required()
"""The :attr:`ParameterInfo.default` of a table's field without a default."""


@dataclass(frozen=True)
class ParameterInfo:
    """One leaf of a parameter model: its key path, default, unit and meaning."""

    path: str
    default: Any
    unit: str
    description: str


def unit_of(name: str) -> str:
    """The unit a parameter's name ends in, or ``""``.

    Example::

        >>> unit_of("rate_rrw_deg_h_sqrt_h"), unit_of("altitude_km"), unit_of("n_aircraft")
        ('deg/h/sqrt(h)', 'km', '')
    """
    for suffix, unit in UNITS.items():
        if name.endswith(suffix):
            return unit
    return ""


def describe(schema: type[Parameters], defaults: Parameters | None = None) -> list[ParameterInfo]:
    """Every leaf parameter of ``schema`` with its default (from ``defaults``, else the
    schema's own), unit and description; the fields of a table's other variants are
    listed with the variant that has them.

    Example::

        >>> from pydantic import Field
        >>> class Pass(Parameters):
        ...     duration_s: float = Field(60.0, description="Length of the pass.")
        >>> [(p.path, p.default, p.unit) for p in describe(Pass)]
        [('duration_s', 60.0, 's')]
    """
    instance = defaults if defaults is not None else schema()
    return list(_leaves(type(instance), instance, ""))


def _leaves(
    schema: type[BaseModel], instance: BaseModel | None, prefix: str
) -> Iterator[ParameterInfo]:
    for name, info in schema.model_fields.items():
        path = f"{prefix}{name}"
        if instance is not None:
            value = getattr(instance, name)
        else:
            value = REQUIRED if info.is_required() else info.default
        description = info.description or ""
        if isinstance(value, BaseModel):
            yield from _leaves(type(value), value, f"{path}.")
            for variant in model_classes(info.annotation):
                if variant is not type(value):
                    yield from _variant_leaves(variant, path)
        elif (
            isinstance(value, list | tuple)
            and value
            and all(isinstance(item, BaseModel) for item in value)
        ):
            for index, item in enumerate(value):
                yield from _leaves(type(item), item, f"{path}[{index}].")
        elif instance is None and model_classes(info.annotation):
            yield from _variant_leaves(model_classes(info.annotation)[0], path)
        else:
            yield ParameterInfo(path, _plain(value), unit_of(name), description)
            for variant in model_classes(info.annotation):
                yield from _variant_leaves(variant, path)
            if isinstance(value, list | tuple):  # a list that may hold tables, e.g. gyros
                for variant in model_classes(info.annotation, items=True):
                    yield from _variant_leaves(variant, f"{path}[]")


def _variant_leaves(variant: type[BaseModel], path: str) -> Iterator[ParameterInfo]:
    tag = _tag(variant)
    label = f"{path}({tag or 'table'})."
    yield from _leaves(variant, None, label)


def _tag(variant: type[BaseModel]) -> str:
    """``type = 'x'`` of a tagged union's variant (its ``type`` field's literal), else ``""``."""
    field = variant.model_fields.get("type")
    if field is None:
        return ""
    return f"type={field.default}"


def model_classes(annotation: Any, *, items: bool = False) -> list[type[BaseModel]]:
    """The model classes an annotation admits (through unions, Annotated and Optional;
    with ``items``, also as the elements of a list or tuple)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    origin = typing.get_origin(annotation)
    if origin in (typing.Union, types.UnionType, typing.Annotated) or (
        items and origin in (list, tuple)
    ):
        return [m for arg in typing.get_args(annotation) for m in model_classes(arg, items=items)]
    return []


def _plain(value: Any) -> Any:
    if isinstance(value, BaseModel):
        return value.model_dump(mode="json")
    if isinstance(value, tuple):
        return list(value)
    return value


def flat_items(document: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    """``{key path: value}`` of a nested parameter document (tables joined by ``.``,
    array elements by ``[i]``).

    Example::

        >>> flat_items({"orbit": {"altitude_km": 600.0}, "antennas": [{"n": 1}], "seed": 0})
        {'orbit.altitude_km': 600.0, 'antennas[0].n': 1, 'seed': 0}
    """
    items: dict[str, Any] = {}
    for key, value in document.items():
        path = f"{prefix}{key}"
        if isinstance(value, Mapping):
            items |= flat_items(value, f"{path}.")
        elif isinstance(value, list) and value and all(isinstance(v, Mapping) for v in value):
            for index, item in enumerate(value):
                items |= flat_items(item, f"{path}[{index}].")
        else:
            items[path] = value
    return items


def starter_toml(parameters: Parameters, header: str = "") -> str:
    """A complete TOML config of ``parameters``, each key preceded by its description
    and unit as a comment; loading it gives ``parameters`` back.

    ``None`` values (an optional table left out) are omitted: TOML has no null.

    Example::

        >>> from pydantic import Field
        >>> class Pass(Parameters):
        ...     duration_s: float = Field(60.0, description="Length of the pass.")
        >>> print(starter_toml(Pass()))
        # Length of the pass. [s]
        duration_s = 60.0
        <BLANKLINE>
    """
    lines = [f"# {line}".rstrip() for line in header.splitlines()] + ([""] if header else [])
    lines += _table_lines(parameters, [])
    return "\n".join(lines).lstrip("\n") + "\n"


def _table_lines(model: BaseModel, path: list[str]) -> list[str]:
    scalars, tables = [], []
    for name, info in type(model).model_fields.items():
        value = getattr(model, name)
        if value is None:
            continue
        comment = _comment(info.description or "", unit_of(name))
        if isinstance(value, BaseModel):
            tables += ["", *comment, f"[{'.'.join([*path, name])}]"]
            tables += _table_lines(value, [*path, name])
        elif (
            isinstance(value, list | tuple)
            and value
            and all(isinstance(item, BaseModel) for item in value)
        ):
            tables += ["", *comment]
            for item in value:
                tables += [f"[[{'.'.join([*path, name])}]]", *_table_lines(item, [*path, name])]
        elif isinstance(value, dict):  # a free-form table: after the scalars, as TOML needs
            nested: Any = _plain(value)
            for key in reversed([*path, name]):
                nested = {key: nested}
            tables += ["", *comment, tomli_w.dumps(nested).rstrip("\n")]
        else:
            scalars += [*comment, tomli_w.dumps({name: _plain(value)}).rstrip("\n")]
    return scalars + tables


def _comment(description: str, unit: str) -> list[str]:
    text = f"{description} [{unit}]" if unit else description
    return [f"# {text}"] if text else []
