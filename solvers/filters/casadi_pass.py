"""Passes run in CasADi: the epoch loop (of the compiled kernel) and the symmetric covariance.

Shared by Yang et al. 2014's EKF and its smoother (:mod:`attopt.solvers.doa.ekf`,
:mod:`attopt.solvers.doa.eks`) and by the multiplicative RTS backward pass
(:mod:`attopt.solvers.filters.rts`).
"""

from __future__ import annotations

from collections.abc import Sequence
from functools import lru_cache
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray

from attopt.formulations.kernels import kernel

Array = NDArray[np.float64]

CHUNK = 512
"""Epochs per ``Function.mapaccum`` evaluation in :func:`accumulate` (building one
map over a whole 20 000-epoch pass takes longer than running it)."""


def lower_symmetric(matrix: Any) -> Any:
    """The symmetric matrix with ``matrix``'s lower triangle (CasADi).

    For a covariance that is symmetric up to rounding; the upper triangle's
    expressions are never evaluated, which saves about 40 % of a product.
    """
    return ca.tril2symm(ca.tril(matrix))


@lru_cache(maxsize=32)
def _mapaccum(function: ca.Function, n_accum: int) -> ca.Function:
    """The loop over :data:`CHUNK` epochs of ``function``'s compiled kernel
    (:func:`attopt.formulations.kernels.kernel`)."""
    return kernel(function).mapaccum(f"{function.name()}_pass", CHUNK, n_accum, {})


def _column_major(x: Array) -> Array:
    """``(n, r, c)`` as the C-ordered ``(n, c, r)``: the nonzeros of the ``r x n c``
    matrix that ``Function.mapaccum`` takes, in CasADi's (column-major) order."""
    return np.ascontiguousarray(np.swapaxes(x, 1, 2))


def accumulate(
    function: ca.Function,
    n_accum: int,
    initial: Sequence[ArrayLike],
    inputs: Sequence[ArrayLike],
    n: int,
) -> list[Array]:
    """Run ``function`` over ``n`` epochs, carrying its first ``n_accum`` inputs.

    Epoch ``k`` gets the carried values (``initial`` at ``k = 0``, else the
    first ``n_accum`` outputs of epoch ``k - 1``) and ``inputs[i][k]``; each
    input is ``(n, *shape)`` or one value for every epoch, ``shape`` the
    function's input shape (a ``c = 1`` axis may be left out).  The loop runs
    in CasADi (``Function.mapaccum`` over :data:`CHUNK` epochs, the last chunk
    padded by repeating epoch ``n - 1``), reading and writing numpy memory
    through ``Function.buffer``; ``function``'s inputs and outputs must be
    dense.  Returns every output stacked, ``(n, rows, columns)``.
    """
    sparsities = [function.sparsity_in(i) for i in range(function.n_in())]
    sparsities += [function.sparsity_out(i) for i in range(function.n_out())]
    if not all(sparsity.is_dense() for sparsity in sparsities):
        raise ValueError(f"{function.name()} must have dense inputs and outputs")
    buffer, evaluate = _mapaccum(function, n_accum).buffer()
    padded = -(-n // CHUNK) * CHUNK
    index = np.minimum(np.arange(padded), n - 1)
    shapes = [function.size_in(n_accum + i) for i in range(len(inputs))]
    stacked = [
        _column_major(
            np.broadcast_to(np.asarray(v, dtype=float).reshape(-1, *shape), (n, *shape))[index]
        )
        for v, shape in zip(inputs, shapes, strict=True)
    ]
    state = [
        _column_major(np.asarray(x, dtype=float).reshape(1, *function.size_in(i)))[0]
        for i, x in enumerate(initial)
    ]
    results = [np.empty((padded, *function.size_out(i)[::-1])) for i in range(function.n_out())]
    for start in range(0, padded, CHUNK):
        chunk = slice(start, start + CHUNK)
        arguments = [*state, *(x[chunk] for x in stacked)]
        for i, x in enumerate(arguments):
            buffer.set_arg(i, memoryview(x))
        for i, x in enumerate(results):
            buffer.set_res(i, memoryview(x[chunk]))
        evaluate()
        state = [results[i][start + CHUNK - 1] for i in range(n_accum)]
    return [np.swapaxes(x[:n], 1, 2) for x in results]
