"""Wahba's problem as a semidefinite program, solved by a conic solver through cvxpy.

The program is :mod:`attopt.formulations.wahba_sdp` (Cilden Guler et al. 2017
eqs. 22-26 relaxed): built once per process and per :class:`SdpOptions`
(:func:`relaxation`), solved by the solver the options name (Clarabel by
default, or SCS) to their ``tolerance``.

The quaternion is the top eigenvector of the optimal ``X``.  The certificate
is reported per epoch: the duality gap ``|tr(K X) - nu|`` and the rank-one
ratio ``lambda_2 / lambda_1`` of ``X`` (both for ``K`` scaled by
``1 / sum a_i``).  A solve the solver calls optimal or "optimal_inaccurate"
(tight tolerances are sometimes just missed) is accepted when that
certificate holds: ``X`` rank one to ``rank_one_tolerance`` and the gap below
``gap_tolerance``; any other epoch is flagged as a convergence failure.

Accuracy: the eigenvector error is about the solver tolerance divided by the
eigen-gap of ``K``, so it grows with the dynamic range of the weights (the
contract tests hold it to 1e-10 rad over a 100:1 weight range).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np

from attopt.formulations.conventions import attitude_from_shuster_quaternion
from attopt.formulations.vector_observations import ObservationBatch
from attopt.formulations.wahba import davenport_matrix
from attopt.formulations.wahba_covariance import quest_covariance
from attopt.formulations.wahba_sdp import WahbaSDP
from attopt.solvers.wahba.driver import Estimate

_ACCEPTED = ("optimal", "optimal_inaccurate")
TOLERANCE_OPTIONS = {
    "CLARABEL": ("tol_gap_abs", "tol_gap_rel", "tol_feas"),
    "SCS": ("eps_abs", "eps_rel"),
}
"""The stopping tolerances of each supported solver that :attr:`SdpOptions.tolerance` sets."""


@dataclass(frozen=True)
class SdpOptions:
    """Solver and tolerances of the SDP estimator (module docstring); hashable.

    Attributes:
        solver: cvxpy name of a conic solver with semidefinite cones
            (:data:`TOLERANCE_OPTIONS`: ``"CLARABEL"``, ``"SCS"``).
        tolerance: the solver's gap and feasibility tolerances.  Clarabel's
            defaults (1e-8) leave ``X`` rank one only to ~1e-6 when the
            eigen-gap of ``K`` is small; tight ones cost about 2 iterations.
        rank_one_tolerance: largest accepted ``lambda_2 / lambda_1`` of ``X``.
        gap_tolerance: largest accepted duality gap.

    Example::

        >>> import numpy as np
        >>> from attopt import SdpOptions, Snapshot, estimator
        >>> snapshot = Snapshot.from_vectors(np.eye(3)[:2], np.eye(3)[:2], sigma=1e-3)
        >>> scs = estimator("sdp", options=SdpOptions(solver="SCS", tolerance=1e-9))
        >>> bool(scs.solve(snapshot).attitude.magnitude() < 1e-6)
        True
    """

    solver: str = "CLARABEL"
    tolerance: float = 1e-12
    rank_one_tolerance: float = 1e-6
    gap_tolerance: float = 1e-8

    def __post_init__(self) -> None:
        if self.solver not in TOLERANCE_OPTIONS:
            raise ValueError(
                f"unsupported SDP solver {self.solver!r}; supported: {sorted(TOLERANCE_OPTIONS)}"
            )

    def solver_options(self) -> dict[str, Any]:
        """Keyword options of ``cvxpy.Problem.solve`` for :attr:`solver`."""
        return dict.fromkeys(TOLERANCE_OPTIONS[self.solver], self.tolerance)


@lru_cache(maxsize=8)
def relaxation(options: SdpOptions) -> WahbaSDP:
    """The relaxation solved with ``options``, built once per process and option set
    (cvxpy problems are not shared across worker processes)."""
    return WahbaSDP()


def estimate(obs: ObservationBatch, options: SdpOptions) -> Estimate:
    """One SDP solve per valid epoch."""
    n = obs.n_epochs
    lambda_0 = obs.weights.sum(axis=1)
    k = davenport_matrix(obs.profile_matrix)
    q = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1))
    gap = np.full(n, np.nan)
    ratio = np.full(n, np.nan)
    value = np.full(n, np.nan)
    failure = np.full(n, "", dtype=object)
    problem = relaxation(options)
    solver_options = options.solver_options()
    for i in np.flatnonzero(obs.valid):
        sol = problem.solve(k[i] / lambda_0[i], options.solver, **solver_options)
        if sol.status not in _ACCEPTED or not np.isfinite(sol.x).all():
            failure[i] = f"SDP solver status {sol.status}"
            continue
        w, v = np.linalg.eigh(sol.x)
        q[i] = v[:, -1]
        ratio[i] = abs(w[-2]) / w[-1]
        gap[i] = abs(sol.value - sol.dual_value)
        value[i] = sol.value * lambda_0[i]
        if not ratio[i] < options.rank_one_tolerance:
            failure[i] = f"SDP relaxation not rank one (lambda2/lambda1 = {ratio[i]:.2e})"
        elif not gap[i] < options.gap_tolerance:
            failure[i] = f"SDP duality gap {gap[i]:.2e} above {options.gap_tolerance:g}"
    return Estimate(
        attitude_from_shuster_quaternion(q),
        quest_covariance(obs.body, obs.weights),
        {"duality_gap": gap, "rank_one_ratio": ratio, "sdp_value": value},
        failed=failure != "",
        failure=failure,
    )
