"""Measurement kernels: a CasADi function evaluated at many points in one call into C.

Every symbolic model (SNR, unit vector, DOA, Euler angles, their truncated
variants, and the innovations) is a CasADi ``SX`` function built once from its
single definition (:mod:`attopt.formulations.attitude_model`,
:mod:`attopt.formulations.measurement_model`).  :func:`evaluate_mapped` evaluates
one at ``N`` points -- a whole pass, or one epoch's observations -- in a single
call: a CasADi ``map`` over the points, on numpy buffers (no CasADi matrices, no
Python loop over points).

Compiled kernels.  The function evaluated is :func:`kernel` ``(function)``: the
same function generated as C by CasADi's code generator, compiled with the
system C compiler (``$CC``, default ``cc``; flags :data:`FLAGS`) into a shared
library and loaded with ``casadi.external``.  CasADi's own interpreter (its SX
virtual machine) stays the reference and the fallback:

* ``ATTOPT_KERNELS=interpreted`` selects it;
* so does a machine without a compiler, or a function CasADi cannot generate
  or the compiler cannot build (one warning per function says why).

The generated code performs the interpreter's operations in the interpreter's
order, and ``-ffp-contract=off`` forbids fused multiply-adds, so the two agree
bit for bit on the machines measured; the tests hold them to ``1e-13``
relative (``tests/test_kernels.py``).

Libraries are cached on disk, once per machine, in the ``kernels`` folder of
:func:`attopt.cache.cache_directory`, named after the function and a digest of
the generated source, the CasADi version, the compiler's version and the
flags: a changed model, CasADi or compiler is a new library.  Building one
prints its cost to standard error (a fraction of a second for the SNR model);
with the cache disabled they are built in a temporary folder per process.
Written here rather than with CasADi's ``jit`` option because that option
compiles again in every process and has no cache on disk.

Example::

    >>> import casadi as ca
    >>> import numpy as np
    >>> x = ca.SX.sym("x", 2)
    >>> square = ca.Function("square_norm", [x], [ca.sumsqr(x)])
    >>> (value,) = evaluate_mapped(square, np.array([[1.0, 2.0], [3.0, 4.0]]))
    >>> value.ravel().tolist()
    [5.0, 25.0]
"""

from __future__ import annotations

import atexit
import hashlib
import logging
import os
import shutil
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from functools import cache, lru_cache
from pathlib import Path
from typing import Any, TypeVar

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray

from attopt.cache import cache_directory

Array = NDArray[np.float64]
T = TypeVar("T")

logger = logging.getLogger(__name__)

KERNELS_ENV = "ATTOPT_KERNELS"
"""Environment variable: ``compiled`` (default) or ``interpreted``."""
INTERPRETED = "interpreted"
"""Value of :data:`KERNELS_ENV` that selects CasADi's interpreter."""
BLOCK = 4096
"""Most points of one mapped call (:func:`evaluate_mapped`)."""
FLAGS = ("-O1", "-ffp-contract=off", "-fPIC", "-shared")
"""C compiler flags of a kernel (no ``-ffast-math``: results must match the interpreter)."""


def bucket(n: int) -> int:
    """``n`` rounded up to one of eight sizes per octave (at most 12.5 % padding).

    Mapped functions are built per size; rounding bounds how many are built.
    """
    if n <= 8:
        return max(n, 1)
    step = 1 << (n.bit_length() - 4)
    return -(-n // step) * step


@cache
def compiler() -> str | None:
    """Path of the C compiler (``$CC``, default ``cc``, looked up once per process), ``None``
    if there is none."""
    return shutil.which(os.environ.get("CC") or "cc")


def interpreted() -> bool:
    """Whether :data:`KERNELS_ENV` asks for the interpreted paths (read at each call)."""
    return os.environ.get(KERNELS_ENV, "").lower() == INTERPRETED


def compiled_kernels() -> bool:
    """Whether kernels are compiled: not disabled by :data:`KERNELS_ENV`, and a compiler."""
    return not interpreted() and compiler() is not None


def kernel(function: ca.Function) -> ca.Function:
    """``function`` compiled to a shared library (module docstring), or ``function`` itself
    when kernels are interpreted or it cannot be compiled."""
    return _compiled(function) if compiled_kernels() else function


@lru_cache(maxsize=1024)
def _mapped(function: ca.Function, n: int, compiled: bool) -> ca.Function:
    """:func:`kernel` ``(function)`` mapped over ``n`` points (serially), once per function,
    size and mode."""
    return _map(_compiled(function) if compiled else function, n)


@lru_cache(maxsize=512)
def _compiled(function: ca.Function) -> ca.Function:
    try:
        return ca.external(function.name(), str(_library(function)))
    except (OSError, RuntimeError) as error:
        _not_compiled(function, error)
        return function


@lru_cache(maxsize=512)
def kernel_library(function: ca.Function) -> Path | None:
    """The shared library of ``function`` (built once per machine, module docstring), for
    callers of its C entry point (:mod:`attopt.formulations.kernel_calls`); ``None`` when
    it cannot be generated or compiled."""
    try:
        return _library(function)
    except (OSError, RuntimeError) as error:
        _not_compiled(function, error)
        return None


def _not_compiled(function: ca.Function, error: Exception) -> None:
    logger.warning(
        "measurement kernel %s not compiled (%s); using CasADi's interpreter",
        function.name(),
        error,
    )


@lru_cache(maxsize=512)
def _map(function: ca.Function, n: int) -> ca.Function:
    return function.map(n)


def evaluate_mapped(function: ca.Function, *inputs: ArrayLike) -> list[Array]:
    """Outputs ``(N, rows, columns)`` of ``function`` at ``N`` points.

    Input ``i`` is ``N`` stacked values of the function's input shape
    (``(N, rows, columns)``, or ``(N, rows)`` for a column), or one value
    shared by every point.  Evaluated on numpy buffers: each point's nonzeros,
    column-major, follow the previous point's.  Up to :data:`BLOCK` points the map
    is built for :func:`bucket` ``(N)`` points (the last repeated); beyond, the
    points are padded to whole blocks and the map of :data:`BLOCK` points runs
    block after block on views of the same buffers (a CasADi map's construction
    costs about 1 us per point, its evaluation of the SNR model 0.15 us).  No
    points (an input with none and none shared) give empty outputs.
    """
    layout = _layout(function)
    arrays = [
        np.asarray(x, dtype=float).reshape(-1, *shape)
        for x, shape in zip(inputs, layout.shapes_in, strict=True)
    ]
    n = max(a.shape[0] for a in arrays)
    if n == 0 or min(a.shape[0] for a in arrays) == 0:
        return [np.zeros((0, *shape)) for shape in layout.shapes_out]
    block = bucket(n) if n <= BLOCK else BLOCK
    size = -(-n // block) * block
    pad, shared = _point_indices(size, n)
    stacked = [  # (size, nnz), C-contiguous: one copy (a fancy index where it pads)
        _column_major(a)
        if dense and a.shape[0] == size
        else a[pad if a.shape[0] == n else shared, rows, columns]
        for a, (rows, columns), dense in zip(
            arrays, layout.entries_in, layout.dense_in, strict=True
        )
    ]
    outputs = [np.empty((size, rows.size)) for rows, _ in layout.entries_out]
    buffer, evaluate = _buffer(function, block, compiled_kernels(), threading.get_ident())
    for start in range(0, size, block):
        for i, values in enumerate(stacked):
            buffer.set_arg(i, memoryview(values[start : start + block]))
        for i, out in enumerate(outputs):
            buffer.set_res(i, memoryview(out[start : start + block]))
        evaluate()
    result = []
    for out, shape, (rows, columns), dense in zip(
        outputs, layout.shapes_out, layout.entries_out, layout.dense_out, strict=True
    ):
        if dense:  # the nonzeros are every entry, column by column
            result.append(np.ascontiguousarray(out[:n].reshape(n, *shape[::-1]).swapaxes(1, 2)))
            continue
        full = np.zeros((n, *shape))
        full[:, rows[0], columns[0]] = out[:n]
        result.append(full)
    return result


def _column_major(points: Array) -> Array:
    """``(N, rows, columns)`` as ``(N, rows columns)``, each point's entries column by
    column (a dense input's nonzeros in CasADi's order), C-contiguous."""
    return np.ascontiguousarray(points.swapaxes(1, 2)).reshape(points.shape[0], -1)


@lru_cache(maxsize=1024)
def _buffer(function: ca.Function, n: int, compiled: bool, thread: int) -> tuple[Any, Any]:
    """``Function.buffer()`` of ``function`` mapped over ``n`` points, one per thread (a buffer
    holds the pointers of one evaluation; :func:`evaluate_mapped` sets every argument and
    result before each): building one costs about 20 us, as much as evaluating a map of a
    few points."""
    return _mapped(function, n, compiled).buffer()


@lru_cache(maxsize=256)
def _point_indices(size: int, n: int) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """``(size, 1)`` indices of ``n`` points padded to ``size`` (the last repeated), and of
    one shared point (read-only)."""
    pad = np.minimum(np.arange(size), n - 1)[:, None]
    shared = np.zeros((size, 1), dtype=np.intp)
    pad.flags.writeable = shared.flags.writeable = False
    return pad, shared


@dataclass(frozen=True)
class _Layout:
    """A function's input and output shapes and the (row, column) of their nonzeros in
    CasADi's column-major order (rows and columns as ``(1, nnz)`` index arrays)."""

    shapes_in: tuple[tuple[int, int], ...]
    shapes_out: tuple[tuple[int, int], ...]
    entries_in: tuple[tuple[NDArray[np.intp], NDArray[np.intp]], ...]
    entries_out: tuple[tuple[NDArray[np.intp], NDArray[np.intp]], ...]
    dense_in: tuple[bool, ...]
    dense_out: tuple[bool, ...]


@lru_cache(maxsize=512)
def _layout(function: ca.Function) -> _Layout:
    def entries(sparsity: ca.Sparsity) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
        rows = np.array(sparsity.row(), dtype=np.intp)[None, :]
        return rows, np.array(sparsity.get_col(), dtype=np.intp)[None, :]

    return _Layout(
        tuple(function.size_in(i) for i in range(function.n_in())),
        tuple(function.size_out(i) for i in range(function.n_out())),
        tuple(entries(function.sparsity_in(i)) for i in range(function.n_in())),
        tuple(entries(function.sparsity_out(i)) for i in range(function.n_out())),
        tuple(function.sparsity_in(i).is_dense() for i in range(function.n_in())),
        tuple(function.sparsity_out(i).is_dense() for i in range(function.n_out())),
    )


def _library(function: ca.Function) -> Path:
    """The shared library of ``function``: from the cache, or generated and compiled."""
    generator = ca.CodeGenerator(f"{function.name()}.c", {"with_header": False})
    generator.add(function)
    source = generator.dump()
    digest = hashlib.sha256(
        "\n".join([source, ca.__version__, _compiler_version(str(compiler())), *FLAGS]).encode()
    ).hexdigest()[:24]
    path = _directory() / f"{function.name()}-{digest}.so"
    if not path.exists():
        _compile(function.name(), source, path)
    return path


def _compile(name: str, source: str, path: Path) -> None:
    """Compile ``source`` into ``path`` (written to a temporary name, then renamed, so that
    concurrent builders never load a partial library) and print the cost."""
    start = time.perf_counter()
    with tempfile.TemporaryDirectory(dir=path.parent) as work:
        c_file = Path(work) / f"{name}.c"
        c_file.write_text(source)
        library = Path(work) / path.name
        command = [str(compiler()), *FLAGS, "-o", str(library), str(c_file), "-lm"]
        result = subprocess.run(command, capture_output=True, text=True)
        if result.returncode != 0:
            raise RuntimeError(f"{command[0]} failed: {result.stderr.strip()[-500:]}")
        os.replace(library, path)
    print(
        f"attopt: compiled measurement kernel {name} in {time.perf_counter() - start:.2f} s "
        f"(once per machine, in {path.parent})",
        file=sys.stderr,
    )


@cache
def _compiler_version(path: str) -> str:
    result = subprocess.run([path, "--version"], capture_output=True, text=True)
    return result.stdout.splitlines()[0] if result.stdout else ""


def _directory() -> Path:
    """The ``kernels`` folder of the cache directory, or a temporary one for this process
    when the cache is disabled or cannot be created."""
    base = cache_directory()
    if base is not None:
        directory = base / "kernels"
        try:
            directory.mkdir(parents=True, exist_ok=True)
            return directory
        except OSError as error:
            logger.debug("kernel cache %s not usable: %s", directory, error)
    return _process_directory()


@cache
def _process_directory() -> Path:
    directory = Path(tempfile.mkdtemp(prefix="attopt-kernels-"))
    atexit.register(shutil.rmtree, directory, ignore_errors=True)
    return directory


@cache
def compiled_loops() -> bool:
    """Whether the numba loops (the Wahba solvers', the filters' propagation) are used: not
    disabled by :data:`KERNELS_ENV`, read once per process (reading the environment costs a
    tenth of a compiled call)."""
    return not interpreted()


def report_compilation(label: str, seconds: float, stats: object) -> bool:
    """Print the cost of a first call that compiled a numba loop (``stats``, the loop's
    ``.stats``, count a cache miss), as the CasADi kernels' compilation is printed; nothing
    when it was loaded from numba's cache.  Returns whether it printed."""
    if not sum(stats.cache_misses.values()):
        return False
    print(
        f"attopt: compiled {label} in {seconds:.2f} s (once per machine, in {stats.cache_path})",
        file=sys.stderr,
    )
    return True


WARM_UPS: dict[str, Callable[[], object]] = {}
"""Per numba loop, by name (``"wahba.quest"``, ``"filters.gate"``...), a call of it on a
small input of the types its callers pass: running it compiles the loop, or loads it from
numba's cache (:mod:`attopt.solvers.compilation` runs them ahead of a sweep, split
across its workers).  Filled by :func:`register_warm_up` where each loop is defined."""


def register_warm_up(name: str, call: Callable[[], object]) -> None:
    """Register ``call`` as the warm-up of the numba loop ``name`` (:data:`WARM_UPS`).

    Example::

        >>> register_warm_up("examples.square", lambda: None)
        >>> "examples.square" in WARM_UPS
        True
        >>> del WARM_UPS["examples.square"]
    """
    WARM_UPS[name] = call


_CALLED: set[str] = set()
"""The labels of the numba loops this process has called (compiled or loaded)."""


def first_call(loop: Callable[..., T], label: str, *args: object) -> T:
    """``loop(*args)`` (a numba loop), printing by :func:`report_compilation` what compiling
    it cost if this is the process's first call of ``label``."""
    if label in _CALLED:
        return loop(*args)
    start = time.perf_counter()
    out = loop(*args)
    _CALLED.add(label)
    report_compilation(label, time.perf_counter() - start, loop.stats)
    return out
