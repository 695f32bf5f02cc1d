"""TOML text of a document of plain values, read back exactly by :mod:`tomllib`.

Floats are written as Python's shortest round-trip representation (``repr``;
``inf``, ``-inf`` and ``nan`` are TOML's spellings too), so a number read back
is the number written, to the last bit.  Supported values: strings, booleans,
integers, floats, lists (or tuples) of them and of lists, nested tables
(dicts) and arrays of tables (lists of dicts).
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from typing import Any


def _value(value: Any) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        return repr(value)
    if isinstance(value, str):
        return json.dumps(value, ensure_ascii=False)
    if isinstance(value, list | tuple):
        return "[" + ", ".join(_value(item) for item in value) + "]"
    raise TypeError(f"cannot write {type(value).__name__} {value!r} as a TOML value")


def _is_table_array(value: Any) -> bool:
    return isinstance(value, list | tuple) and bool(value) and isinstance(value[0], Mapping)


def _table(document: Mapping[str, Any], path: tuple[str, ...], lines: list[str]) -> None:
    scalars = {
        k: v for k, v in document.items() if not isinstance(v, Mapping) and not _is_table_array(v)
    }
    lines.extend(f"{_key(key)} = {_value(value)}" for key, value in scalars.items())
    for key, value in document.items():
        if isinstance(value, Mapping):
            lines.extend(["", f"[{'.'.join(_key(k) for k in (*path, key))}]"])
            _table(value, (*path, key), lines)
        elif _is_table_array(value):
            for item in value:
                lines.extend(["", f"[[{'.'.join(_key(k) for k in (*path, key))}]]"])
                _table(item, (*path, key), lines)


def _key(key: str) -> str:
    bare = key.replace("_", "").replace("-", "").isalnum() and key.isascii()
    return key if bare else json.dumps(key)


def dumps(document: Mapping[str, Any]) -> str:
    """The TOML text of ``document`` (module docstring).

    Example::

        >>> import tomllib
        >>> from attopt.experiments.recorded.toml_text import dumps
        >>> document = {"rate_hz": 0.1 + 0.2, "antennas": [{"name": "a", "pattern": {"n": 6}}]}
        >>> print(dumps(document))
        rate_hz = 0.30000000000000004
        <BLANKLINE>
        [[antennas]]
        name = "a"
        <BLANKLINE>
        [antennas.pattern]
        n = 6
        <BLANKLINE>
        >>> tomllib.loads(dumps(document)) == document
        True
    """
    lines: list[str] = []
    _table(document, (), lines)
    return "\n".join(lines) + "\n"
