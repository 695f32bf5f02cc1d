"""Results of slow deterministic builders cached on disk, once per machine.

A scenario's true geometry (orbit propagation, astropy frame transformations,
the Sun, the geomagnetic field, traffic) is the same for every trial and every
worker process, and takes seconds to build.  :func:`disk_cached` stores a
builder's result in a cache directory the first time it is built, so that every
later process of this machine (sweep workers, pytest-xdist workers, later runs)
loads it instead::

    @functools.lru_cache(maxsize=4)  # per process, in front
    @disk_cached
    def build(orbit: TleOrbit, duration_s: float) -> Geometry: ...

Directory: :func:`attopt.cache.cache_directory` (``$ATTOPT_CACHE_DIR`` if set, else
``$XDG_CACHE_HOME/attopt``, default ``~/.cache/attopt``); ``ATTOPT_CACHE_DIR=off``
disables the cache (every call builds).  A directory that cannot be created, read or
written is skipped: the result is built, with a debug-level log message only.

Key.  An entry is named after the builder's qualified name, a digest of its
arguments (bound to its signature with defaults applied; pydantic models by
class and JSON, dataclasses by class and field values, floats by their exact
``repr``) and a digest of :func:`environment`: the cache format version, the
Python version, the version of attopt and a digest of its source files (so that
an edit of a development checkout is a new key), and the versions of the
libraries that determine the numbers (:data:`LIBRARIES`).  Storing an entry
deletes the entries of the same builder and arguments made under another
environment, so the directory does not grow with every edit or upgrade.

Format.  One ``.npz`` file per entry, read with ``allow_pickle=False``: the
arrays of the result, a JSON description of its structure (frozen dataclasses,
pydantic models, tuples, lists, scalars; a scipy ``Rotation`` as its
quaternions) and the full key, which a load checks.  Files are written to a
temporary name in the directory and renamed into place, so concurrent builders
of the same entry never see a partial file.  An entry that cannot be read or
decoded is rebuilt and overwritten.

Every result, built or loaded, goes through the same encoding (arrays as fresh
C-contiguous copies, rotations from their quaternions without renormalising),
so a loaded result equals a built one bit for bit, in the same array layout.
Results are shared: do not modify their arrays in place.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import importlib
import importlib.metadata
import importlib.util
import inspect
import json
import logging
import os
import platform
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any, ParamSpec, TypeVar

import numpy as np
from pydantic import BaseModel
from scipy.spatial.transform import Rotation

from attopt.cache import cache_directory

FORMAT_VERSION = 1
"""Version of the entry format; part of every key."""
LIBRARIES = (
    "numpy",
    "scipy",
    "astropy",
    "astropy-iers-data",
    "pyerfa",
    "sgp4",
    "ppigrf",
    "airportsdata",
    "pydantic",
)
"""Distributions whose versions are part of every key: they determine the numbers
(``astropy-iers-data``: the Earth orientation tables of the frame transformations)."""
SOURCE_PACKAGES = ("attopt", "attopt.formulations", "attopt.solvers", "attopt.experiments")
"""Packages whose ``.py`` files make the source digest of :func:`environment`."""

_KEY_ENTRY = "__key__"
_STRUCTURE_ENTRY = "__structure__"
_MISSING = object()

logger = logging.getLogger(__name__)

P = ParamSpec("P")
R = TypeVar("R")


@functools.cache
def environment() -> dict[str, str]:
    """The versions in every key: format, Python, attopt and its source digest, and
    :data:`LIBRARIES` (``"absent"`` for one not installed)."""
    versions = {
        "format": str(FORMAT_VERSION),
        "python": platform.python_version(),
        "attopt": importlib.metadata.version("attopt"),
        "attopt-source": _source_digest(),
    }
    for library in LIBRARIES:
        try:
            versions[library] = importlib.metadata.version(library)
        except importlib.metadata.PackageNotFoundError:
            versions[library] = "absent"
    return versions


def cache_key(builder: Callable[..., Any], *args: Any, **kwargs: Any) -> str:
    """The file name (without ``.npz``) of ``builder(*args, **kwargs)``'s entry:
    ``<qualified name>-<arguments digest>-<environment digest>``."""
    return _entry(builder, args, kwargs)[1]


def disk_cached(builder: Callable[P, R]) -> Callable[P, R]:
    """``builder`` with its results cached on disk (module docstring).

    ``builder`` must be deterministic, take arguments that :func:`cache_key` can
    describe and return a value the entry format holds (frozen dataclasses, pydantic
    models, numpy arrays and scalars, scipy rotations, tuples, lists, JSON scalars);
    anything else raises ``TypeError``.
    """
    name = _qualified_name(builder)

    @functools.wraps(builder)
    def cached(*args: P.args, **kwargs: P.kwargs) -> R:
        directory = cache_directory()
        if directory is None:
            return _decode(*_encode_result(builder(*args, **kwargs)))
        key, stem = _entry(builder, args, kwargs)
        path = directory / f"{stem}.npz"
        loaded = _load(path, key)
        if loaded is not _MISSING:
            return loaded
        structure, arrays = _encode_result(builder(*args, **kwargs))
        try:
            _store(path, key, structure, arrays)
        except OSError as error:
            logger.debug("not caching %s in %s: %s", name, directory, error)
        return _decode(structure, arrays)

    return cached


def _qualified_name(builder: Callable[..., Any]) -> str:
    return f"{builder.__module__}.{builder.__qualname__}"


def _entry(builder: Callable[..., Any], args: tuple, kwargs: dict) -> tuple[str, str]:
    """The full key as canonical JSON (builder, bound arguments, environment) and the
    entry's file stem (:func:`cache_key`)."""
    bound = inspect.signature(builder).bind(*args, **kwargs)
    bound.apply_defaults()
    name = _qualified_name(builder)
    arguments = {argument: _describe(value) for argument, value in bound.arguments.items()}
    versions = environment()
    key = _canonical({"builder": name, "arguments": arguments, "environment": versions})
    stem = f"{name}-{_sha256(_canonical(arguments))[:32]}-{_sha256(_canonical(versions))[:16]}"
    return key, stem


def _canonical(document: Any) -> str:
    return json.dumps(document, sort_keys=True, separators=(",", ":"), allow_nan=True)


def _sha256(text: str) -> str:
    return hashlib.sha256(text.encode()).hexdigest()


def _describe(value: Any) -> Any:
    """A builder argument as JSON data, exact and the same in every process."""
    if isinstance(value, BaseModel):
        return {"model": _class_name(type(value)), "json": value.model_dump(mode="json")}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        fields = {f.name: _describe(getattr(value, f.name)) for f in dataclasses.fields(value)}
        return {"dataclass": _class_name(type(value)), "fields": fields}
    if isinstance(value, tuple | list):
        return [_describe(item) for item in value]
    if value is None or isinstance(value, bool | int | float | str):
        return value
    raise TypeError(f"cannot make a cache key of {type(value).__name__} {value!r}")


def _source_digest() -> str:
    """SHA-256 of the ``.py`` files of :data:`SOURCE_PACKAGES`, by relative path."""
    digest = hashlib.sha256()
    for package in SOURCE_PACKAGES:
        spec = importlib.util.find_spec(package)
        assert spec is not None and spec.submodule_search_locations is not None
        root = Path(spec.submodule_search_locations[0])
        for path in sorted(root.rglob("*.py")):
            digest.update(f"{package}/{path.relative_to(root).as_posix()}\0".encode())
            digest.update(path.read_bytes())
    return digest.hexdigest()


def _class_name(cls: type) -> str:
    """``module:qualname`` of ``cls``, checked to name it (a class made in a function
    does not: it cannot be cached)."""
    name = f"{cls.__module__}:{cls.__qualname__}"
    try:
        found = _resolve_class(name)
    except (ImportError, AttributeError, ValueError):
        found = None
    if found is not cls:
        raise TypeError(f"cannot cache a {cls.__qualname__}: {name} does not import it")
    return name


def _resolve_class(name: str) -> type:
    """The dataclass or pydantic model named ``module:qualname``."""
    module, _, qualname = name.partition(":")
    cls: Any = importlib.import_module(module)
    for part in qualname.split("."):
        cls = getattr(cls, part)
    if not (dataclasses.is_dataclass(cls) or issubclass(cls, BaseModel)):
        raise ValueError(f"not a dataclass or pydantic model: {name}")
    return cls


def _encode_result(value: Any) -> tuple[Any, dict[str, np.ndarray]]:
    """``value`` as a JSON structure and the arrays it names."""
    arrays: dict[str, np.ndarray] = {}
    return _encode(value, arrays), arrays


def _encode(value: Any, arrays: dict[str, np.ndarray]) -> Any:
    """``value`` as JSON data, its arrays (as fresh C-contiguous copies) added to ``arrays``."""

    def add(array: np.ndarray) -> str:
        if array.dtype.hasobject:
            raise TypeError("cannot cache an array of Python objects")
        name = f"a{len(arrays)}"
        arrays[name] = np.array(array, order="C")
        return name

    if isinstance(value, np.ndarray):
        return {"array": add(value)}
    if isinstance(value, np.generic):
        return {"scalar": add(np.asarray(value))}
    if isinstance(value, Rotation):
        return {"rotation": add(value.as_quat())}
    if isinstance(value, BaseModel):
        return {"model": _class_name(type(value)), "json": value.model_dump_json()}
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        if not all(f.init for f in dataclasses.fields(value)):
            raise TypeError(f"cannot cache {type(value).__name__}: a field is not in __init__")
        fields = {
            f.name: _encode(getattr(value, f.name), arrays) for f in dataclasses.fields(value)
        }
        return {"dataclass": _class_name(type(value)), "fields": fields}
    if isinstance(value, tuple | list):
        return {type(value).__name__: [_encode(item, arrays) for item in value]}
    if value is None or isinstance(value, bool | int | float | str):
        return value
    raise TypeError(f"cannot cache a {type(value).__name__}")


def _decode(node: Any, arrays: Mapping[str, np.ndarray]) -> Any:
    """The value :func:`_encode` described as ``node``."""
    if not isinstance(node, dict):
        return node
    if "array" in node:
        return arrays[node["array"]]
    if "scalar" in node:
        return arrays[node["scalar"]][()]
    if "rotation" in node:
        return Rotation(arrays[node["rotation"]], normalize=False)
    if "model" in node:
        return _resolve_class(node["model"]).model_validate_json(node["json"])
    if "dataclass" in node:
        fields = {name: _decode(item, arrays) for name, item in node["fields"].items()}
        return _resolve_class(node["dataclass"])(**fields)
    if "tuple" in node:
        return tuple(_decode(item, arrays) for item in node["tuple"])
    if "list" in node:
        return [_decode(item, arrays) for item in node["list"]]
    raise ValueError(f"unknown cache entry node {sorted(node)}")


def _load(path: Path, key: str) -> Any:
    """The entry at ``path`` if it holds ``key``, else :data:`_MISSING` (absent,
    unreadable, corrupt or another key: the caller rebuilds and overwrites it)."""
    try:
        with np.load(path, allow_pickle=False) as entry:
            if str(entry[_KEY_ENTRY]) != key:
                logger.debug("cache entry %s holds another key; rebuilding", path)
                return _MISSING
            structure = json.loads(str(entry[_STRUCTURE_ENTRY]))
            arrays = {name: entry[name] for name in entry.files if not name.startswith("__")}
        return _decode(structure, arrays)
    except FileNotFoundError:
        return _MISSING
    except Exception as error:  # any damage to the file is a miss, never an error
        logger.debug(
            "cache entry %s unreadable (%s: %s); rebuilding", path, type(error).__name__, error
        )
        return _MISSING


def _store(path: Path, key: str, structure: Any, arrays: Mapping[str, np.ndarray]) -> None:
    """Write the entry atomically (temporary file, then ``os.replace``) and delete the
    entries of the same builder and arguments under another environment."""
    path.parent.mkdir(parents=True, exist_ok=True)
    descriptor, temporary = tempfile.mkstemp(dir=path.parent, prefix=".", suffix=".tmp")
    try:
        with os.fdopen(descriptor, "wb") as file:
            np.savez(
                file,
                allow_pickle=False,
                **{_KEY_ENTRY: np.array(key), _STRUCTURE_ENTRY: np.array(json.dumps(structure))},
                **arrays,
            )
        os.replace(temporary, path)
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise
    stem, _, _ = path.stem.rpartition("-")
    for stale in path.parent.glob(f"{stem}-*.npz"):
        if stale != path:
            stale.unlink(missing_ok=True)
