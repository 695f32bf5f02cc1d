"""One model definition, two back-ends: numpy arrays and CasADi expressions.

Measurement models are written once against the small namespace below and run
unchanged on numpy arrays (vectorised over epochs and observations) and on
CasADi ``SX``/``MX``/``DM`` values (for automatic differentiation).  The model
code only uses ``+ - * / **``, comparisons, ``@`` and the namespace's
functions, which both back-ends provide with the same meaning.

Layout: a vector is the last axis of a numpy array (``(..., m, 3)``) or a row
of an ``m x 3`` CasADi matrix; a CasADi ``3 x 1`` column is a single vector.
``components`` splits vectors into their three coordinates and ``entry``
returns a matrix entry that broadcasts against those coordinates.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any, Protocol

import casadi as ca
import numpy as np
import scipy.special

from attopt.formulations.kernels import evaluate_mapped


class ArrayNamespace(Protocol):
    """Operations a model may use besides arithmetic operators."""

    name: str

    def sqrt(self, x: Any) -> Any: ...
    def log10(self, x: Any) -> Any: ...
    def exp(self, x: Any) -> Any: ...
    def log(self, x: Any) -> Any: ...
    def log1p(self, x: Any) -> Any: ...
    def erf(self, x: Any) -> Any: ...
    def atan2(self, y: Any, x: Any) -> Any: ...
    def fmax(self, x: Any, y: Any) -> Any: ...
    def where(self, condition: Any, if_true: Any, if_false: Any) -> Any: ...
    def components(self, vectors: Any) -> tuple[Any, Any, Any]: ...
    def entry(self, matrix: Any, row: int, column: int) -> Any: ...
    def matrix(self, rows: Sequence[Sequence[Any]]) -> Any: ...
    def apply(self, function: ca.Function, x: Any) -> Any: ...


class NumpyNamespace:
    """numpy back-end; leading axes are epochs/observations and broadcast."""

    name = "numpy"

    def sqrt(self, x: Any) -> Any:
        return np.sqrt(x)

    def log10(self, x: Any) -> Any:
        return np.log10(x)

    def exp(self, x: Any) -> Any:
        return np.exp(x)

    def log(self, x: Any) -> Any:
        return np.log(x)

    def log1p(self, x: Any) -> Any:
        return np.log1p(x)

    def erf(self, x: Any) -> Any:
        return scipy.special.erf(x)

    def atan2(self, y: Any, x: Any) -> Any:
        return np.arctan2(y, x)

    def fmax(self, x: Any, y: Any) -> Any:
        """Elementwise maximum (propagates NaN, unlike ``np.fmax``)."""
        return np.maximum(x, y)

    def where(self, condition: Any, if_true: Any, if_false: Any) -> Any:
        return np.where(condition, if_true, if_false)

    def components(self, vectors: Any) -> tuple[Any, Any, Any]:
        v = np.asarray(vectors, dtype=float)
        return v[..., 0], v[..., 1], v[..., 2]

    def entry(self, matrix: Any, row: int, column: int) -> Any:
        """Entry of ``(..., 3, 3)`` matrices with a trailing unit axis for observations."""
        return np.asarray(matrix, dtype=float)[..., row, column, None]

    def matrix(self, rows: Sequence[Sequence[Any]]) -> Any:
        entries = np.broadcast_arrays(*(np.asarray(e, dtype=float) for row in rows for e in row))
        return np.stack(entries, axis=-1).reshape(*entries[0].shape, len(rows), len(rows[0]))

    def apply(self, function: ca.Function, x: Any) -> Any:
        """Evaluate a scalar CasADi ``function`` elementwise on an array of any shape (as a
        measurement kernel, :func:`attopt.formulations.kernels.evaluate_mapped`)."""
        x = np.asarray(x, dtype=float)
        if x.size == 0:
            return np.empty(x.shape)
        (values,) = evaluate_mapped(function, x.reshape(-1))
        return values.reshape(x.shape)


class CasadiNamespace:
    """CasADi back-end for ``SX``, ``MX`` and ``DM`` values (one epoch at a time)."""

    name = "casadi"

    def sqrt(self, x: Any) -> Any:
        return ca.sqrt(x)

    def log10(self, x: Any) -> Any:
        return ca.log10(x)

    def exp(self, x: Any) -> Any:
        return ca.exp(x)

    def log(self, x: Any) -> Any:
        return ca.log(x)

    def log1p(self, x: Any) -> Any:
        return ca.log1p(x)

    def erf(self, x: Any) -> Any:
        """CasADi's ``erf`` (C's ``std::erf``); CasADi 3.8 has no ``erfc``."""
        return ca.erf(x)

    def atan2(self, y: Any, x: Any) -> Any:
        return ca.atan2(y, x)

    def fmax(self, x: Any, y: Any) -> Any:
        return ca.fmax(x, y)

    def where(self, condition: Any, if_true: Any, if_false: Any) -> Any:
        """Elementwise ``if_else``; both branches are evaluated, so both must stay finite."""
        return ca.if_else(condition, if_true, if_false)

    def components(self, vectors: Any) -> tuple[Any, Any, Any]:
        if vectors.size2() == 3:
            return vectors[:, 0], vectors[:, 1], vectors[:, 2]
        if vectors.shape == (3, 1):
            return vectors[0], vectors[1], vectors[2]
        raise ValueError(f"expected m x 3 or 3 x 1 vectors, got {vectors.shape}")

    def entry(self, matrix: Any, row: int, column: int) -> Any:
        return matrix[row, column]

    def matrix(self, rows: Sequence[Sequence[Any]]) -> Any:
        return ca.vertcat(*(ca.horzcat(*row) for row in rows))

    def apply(self, function: ca.Function, x: Any) -> Any:
        """Evaluate a scalar CasADi ``function`` elementwise on a CasADi matrix."""
        n = x.numel()
        return ca.reshape(function.map(n)(ca.reshape(x, 1, n)), x.size1(), x.size2())


NUMPY = NumpyNamespace()
CASADI = CasadiNamespace()


def namespace_of(*values: Any) -> ArrayNamespace:
    """``CASADI`` if any value is a CasADi ``SX``/``MX``/``DM``, else ``NUMPY``."""
    if any(isinstance(v, ca.SX | ca.MX | ca.DM) for v in values):
        return CASADI
    return NUMPY
