"""Compiled measurement kernels called from numba loops, through their C entry point.

A compiled kernel (:mod:`attopt.formulations.kernels`) is a shared library that CasADi's
code generator wrote for one symbolic function: its entry point
``int name(const double** arg, double** res, long long* iw, double* w, int mem)`` reads
each input's nonzeros (column-major) from ``arg[i]`` and writes each output's into
``res[i]``.  A numba loop can call it directly with ``ctypes``: a call costs tens of
nanoseconds inside the loop, where :func:`~attopt.formulations.kernels.evaluate_mapped`
costs tens of microseconds of Python per call.  That is what lets a whole filter update
(prediction, AD Jacobian, gate, gain, reset) run as one call of machine code while the
model stays the single CasADi definition (:mod:`attopt.solvers.filters.vector_update`).

:func:`kernel_call` loads a function's library once per process and thread and holds
the pointer arrays and work vectors a call needs; :func:`evaluate` is the call, for
numba loops.  There is no kernel call when kernels are interpreted
(``ATTOPT_KERNELS=interpreted``), without a C compiler, or for a function that could not
be compiled: callers then keep their interpreted path.

Example::

    >>> import casadi as ca
    >>> import numpy as np
    >>> x = ca.SX.sym("x", 2)
    >>> call = kernel_call(ca.Function("kernel_calls_doc", [x], [ca.sumsqr(x)]))
    >>> point, out = np.array([3.0, 4.0]), np.zeros(1)
    >>> call.arguments[0], call.results[0] = point.ctypes.data, out.ctypes.data
    >>> evaluate(call.function, call.buffers), out.tolist()
    (0, [25.0])
"""

from __future__ import annotations

import ctypes
import threading
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import casadi as ca
import numpy as np
from numba import njit
from numpy.typing import NDArray

from attopt.formulations import kernels

Array = NDArray[np.float64]
Buffers = tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.int64], Array]

ENTRY_POINT = [ctypes.c_void_p] * 4 + [ctypes.c_int]
"""The argument types of a CasADi-generated function: ``arg``, ``res``, ``iw``, ``w``
(pointers) and ``mem``."""


@dataclass(frozen=True)
class KernelCall:
    """A compiled kernel's entry point (a ``ctypes`` function, which numba calls) and the
    buffers of one call: the input and output pointer arrays (``arguments``, ``results``)
    and the integer and real work vectors (``iw``, ``w``) of CasADi's calling convention.
    ``outputs`` holds each output's nonzeros as ``(rows, columns)`` index arrays,
    ``input_sizes`` each input's number of nonzeros, ``dense_inputs`` whether every input
    is dense (its nonzeros are all its entries)."""

    function: Any
    arguments: NDArray[np.int64]
    results: NDArray[np.int64]
    iw: NDArray[np.int64]
    w: Array
    outputs: tuple[tuple[NDArray[np.intp], NDArray[np.intp]], ...]
    input_sizes: NDArray[np.intp]
    dense_inputs: bool

    @property
    def buffers(self) -> Buffers:
        """``(arguments, results, iw, w)``, as :func:`evaluate` takes them."""
        return self.arguments, self.results, self.iw, self.w


def kernel_call(function: ca.Function) -> KernelCall | None:
    """The :class:`KernelCall` of ``function``'s compiled library, one per process and
    thread (the buffers are written by each call); ``None`` when kernels are interpreted
    (``ATTOPT_KERNELS``, read once per process as for the numba loops that call it), there
    is no C compiler, or ``function`` has no library (module docstring)."""
    if not kernels.compiled_loops() or kernels.compiler() is None:  # both read once
        return None
    return _kernel_call(function, threading.get_ident())


@lru_cache(maxsize=256)
def _kernel_call(function: ca.Function, thread: int) -> KernelCall | None:
    path = kernels.kernel_library(function)
    if path is None:
        return None
    library = ctypes.CDLL(str(path))
    entry = getattr(library, function.name())
    entry.argtypes, entry.restype = ENTRY_POINT, ctypes.c_int
    sizes = [ctypes.c_longlong() for _ in range(4)]
    work = getattr(library, f"{function.name()}_work")
    work.argtypes = [ctypes.POINTER(ctypes.c_longlong)] * 4
    work(*[ctypes.byref(s) for s in sizes])
    n_arg, n_res, n_iw, n_w = (max(s.value, 1) for s in sizes)
    outputs = tuple(
        (
            np.array(function.sparsity_out(i).row(), dtype=np.intp),
            np.array(function.sparsity_out(i).get_col(), dtype=np.intp),
        )
        for i in range(function.n_out())
    )
    return KernelCall(
        entry,
        np.zeros(max(n_arg, function.n_in()), dtype=np.int64),
        np.zeros(max(n_res, function.n_out()), dtype=np.int64),
        np.zeros(n_iw, dtype=np.int64),
        np.zeros(n_w),
        outputs,
        np.array([function.nnz_in(i) for i in range(function.n_in())], dtype=np.intp),
        all(function.sparsity_in(i).is_dense() for i in range(function.n_in())),
    )


@njit(cache=True)
def evaluate(function: Any, buffers: Buffers) -> int:
    """Call the kernel ``function`` with the input and output addresses already written
    into the first two of its ``buffers`` (:attr:`KernelCall.buffers`; for numba loops:
    ``arguments[i] = x.ctypes.data``); returns the kernel's status (0: evaluated)."""
    arguments, results, iw, w = buffers
    return function(arguments.ctypes.data, results.ctypes.data, iw.ctypes.data, w.ctypes.data, 0)
