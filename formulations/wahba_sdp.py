"""Semidefinite relaxation of Wahba's problem, as a parametrised cvxpy problem.

``max tr(K X)  s.t.  tr X = 1,  X PSD`` with Davenport's ``K`` (Cilden Guler et al. 2017
eqs. 22-26) as a cvxpy ``Parameter``.  ``X = q q^T`` for the optimal Shuster
quaternion whenever ``lambda_max(K)`` is simple, so the relaxation is tight and
its value equals ``lambda_max(K)``.  The problem is DPP: repeated solves with a
new ``K`` reuse the compiled problem, with whichever installed conic solver
that handles semidefinite cones is asked for (Clarabel, SCS).  Its dual is
``min nu  s.t.  nu I - K PSD``, so the multiplier of ``tr X = 1`` is a certificate of optimality.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any

import cvxpy as cp
import numpy as np
from numpy.typing import NDArray


@dataclass(frozen=True)
class SDPSolution:
    """Primal matrix, primal value and the dual value (certificate) of one solve."""

    x: NDArray[np.float64]
    value: float
    dual_value: float
    status: str


class WahbaSDP:
    """The relaxation, built once; :meth:`solve` it with each ``K`` and any conic solver.

    cvxpy compiles the problem for a solver on its first solve and reuses that
    compilation while the solver stays the same (the problem is DPP), so keep
    one instance per solver and option set
    (:func:`attopt.solvers.wahba.sdp.relaxation`).
    """

    def __init__(self) -> None:
        self.k = cp.Parameter((4, 4), symmetric=True)
        self.x = cp.Variable((4, 4), symmetric=True)
        self.unit_trace = cp.trace(self.x) == 1
        self.problem = cp.Problem(
            cp.Maximize(cp.trace(self.k @ self.x)), [self.unit_trace, self.x >> 0]
        )

    def solve(
        self, k: NDArray[np.float64], solver: str = cp.CLARABEL, **solver_options: Any
    ) -> SDPSolution:
        """Solve for one (symmetric) Davenport matrix ``k`` with ``solver`` (a cvxpy name)."""
        self.k.value = 0.5 * (k + k.T)
        with warnings.catch_warnings():
            # "optimal_inaccurate" is reported in ``status``; callers check the certificate.
            warnings.filterwarnings("ignore", message="Solution may be inaccurate")
            self.problem.solve(solver=solver, **solver_options)
        x = self.x.value
        dual = self.unit_trace.dual_value
        return SDPSolution(
            x=np.full((4, 4), np.nan) if x is None else np.asarray(x),
            value=np.nan if self.problem.value is None else float(self.problem.value),
            dual_value=np.nan if dual is None else abs(float(dual)),
            status=str(self.problem.status),
        )
