"""Semidefinite relaxation of Wahba's problem, as a parametrised cvxpy problem.

``max tr(K X)  s.t.  tr X = 1,  X PSD`` with Davenport's ``K`` (Cilden Guler et al. 2017
eqs. 22-26) as a cvxpy ``Parameter``.  ``X = q q^T`` for the optimal Shuster
quaternion whenever ``lambda_max(K)`` is simple, so the relaxation is tight and
its value equals ``lambda_max(K)``.  The problem is DPP: repeated solves with a
new ``K`` reuse the compiled problem, with whichever installed conic solver
that handles semidefinite cones is asked for (Clarabel, SCS).  Its dual is
``min nu  s.t.  nu I - K PSD``, so the multiplier of ``tr X = 1`` is a certificate of optimality.

A problem of ``size`` blocks holds that many independent relaxations, one
per epoch: ``max sum_b tr(K_b X_b)  s.t.  tr X_b = 1,  X_b PSD``.  The blocks
share nothing, so each block's optimum, value ``tr(K_b X_b)`` and multiplier
of its own ``tr X_b = 1`` are those of its epoch's relaxation; one solve
replaces ``size`` and pays cvxpy's per-solve overhead once.  Every block's ``X_b``
is held by its ten upper-triangle entries in one variable ``(size, 10)``, its
``K_b`` by the matching objective weights in one parameter (the off-diagonal entries
doubled: ``tr(K X) = sum_{i <= j} (2 - [i = j]) K_ij X_ij``), and the unit traces
form one vector constraint: cvxpy's work per solve then does not grow with the
number of parameters and variables, which it sets, checks and recovers one by one
(1.8x faster per solve of 64 blocks than one symmetric parameter and variable per
block, the same answers to 1e-12).
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any

import cvxpy as cp
import numpy as np
from numpy.typing import NDArray

_UPPER = np.triu_indices(4)
"""The ten upper-triangle entries ``(i, j)``, ``i <= j``, of a block, row by row."""
_ENTRIES = _UPPER[0].size
_TO_FULL = np.zeros((_ENTRIES, 16))
"""Upper-triangle entries -> the symmetric matrix, row-major (``entries @ _TO_FULL``)."""
_TO_FULL[np.arange(_ENTRIES), 4 * _UPPER[0] + _UPPER[1]] = 1.0
_TO_FULL[np.arange(_ENTRIES), 4 * _UPPER[1] + _UPPER[0]] = 1.0
_DIAGONAL = (_UPPER[0] == _UPPER[1]).astype(float)
"""The trace of a block from its entries."""
_OFF_DIAGONAL_TWICE = 2.0 - _DIAGONAL
"""``tr(K X)`` from the entries: the off-diagonal ones count twice."""


@dataclass(frozen=True)
class SDPSolution:
    """Primal matrix, primal value and the dual value (certificate) of one solve."""

    x: NDArray[np.float64]
    value: float
    dual_value: float
    status: str


@dataclass(frozen=True)
class BlockSolution:
    """Every block's primal matrix ``(size, 4, 4)``, primal value ``tr(K_b X_b)`` and dual
    value (the multiplier of its ``tr X_b = 1``), and the status of the one solve."""

    x: NDArray[np.float64]
    value: NDArray[np.float64]
    dual_value: NDArray[np.float64]
    status: str


class WahbaSDP:
    """The relaxation of ``size`` epochs (module docstring), built once; solve it with any
    conic solver: :meth:`solve` for one epoch (``size`` 1), :meth:`solve_blocks` for
    ``size``.

    cvxpy compiles the problem for a solver on its first solve and reuses that
    compilation while the solver stays the same (the problem is DPP), so keep
    one instance per solver, option set and size
    (:func:`attopt.solvers.wahba.sdp.relaxation`).
    """

    def __init__(self, size: int = 1) -> None:
        self.size = size
        self.weights = cp.Parameter((size, _ENTRIES))
        self.entries = cp.Variable((size, _ENTRIES))
        full = self.entries @ _TO_FULL  # each row X_b, row-major
        self.unit_trace = self.entries @ _DIAGONAL == 1
        definite = [cp.reshape(full[b], (4, 4), order="C") >> 0 for b in range(size)]
        objective = cp.Maximize(cp.sum(cp.multiply(self.weights, self.entries)))
        self.problem = cp.Problem(objective, [self.unit_trace, *definite])

    def solve(
        self, k: NDArray[np.float64], solver: str = cp.CLARABEL, **solver_options: Any
    ) -> SDPSolution:
        """Solve for one (symmetric) Davenport matrix ``k`` with ``solver`` (a cvxpy name)."""
        if self.size != 1:
            raise ValueError(f"solve() is for one epoch; this relaxation has {self.size} blocks")
        sol = self.solve_blocks(k[None], solver, **solver_options)
        value = self.problem.value
        return SDPSolution(
            x=sol.x[0],
            value=np.nan if value is None else float(value),
            dual_value=float(sol.dual_value[0]),
            status=sol.status,
        )

    def solve_blocks(
        self, k: NDArray[np.float64], solver: str = cp.CLARABEL, **solver_options: Any
    ) -> BlockSolution:
        """Solve for ``size`` (symmetric) Davenport matrices ``k`` ``(size, 4, 4)``."""
        symmetric = 0.5 * (k + np.swapaxes(k, 1, 2))
        self.weights.value = symmetric[:, _UPPER[0], _UPPER[1]] * _OFF_DIAGONAL_TWICE
        with warnings.catch_warnings():
            # "optimal_inaccurate" is reported in ``status``; callers check the certificate.
            warnings.filterwarnings("ignore", message="Solution may be inaccurate")
            self.problem.solve(solver=solver, **solver_options)
        x = np.full((self.size, 4, 4), np.nan)
        dual = np.full(self.size, np.nan)
        if self.entries.value is not None:
            x = (self.entries.value @ _TO_FULL).reshape(self.size, 4, 4)
        if self.unit_trace.dual_value is not None:
            dual = np.abs(np.asarray(self.unit_trace.dual_value, dtype=float).reshape(self.size))
        value = np.einsum("bij,bij->b", symmetric, x)
        return BlockSolution(x=x, value=value, dual_value=dual, status=str(self.problem.status))
