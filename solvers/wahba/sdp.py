"""Wahba's problem as a semidefinite program, solved by a conic solver through cvxpy.

The program is :mod:`attopt.formulations.wahba_sdp` (Cilden Guler et al. 2017
eqs. 22-26 relaxed): built once per process, :class:`SdpOptions` and size
(:func:`relaxation`), solved by the solver the options name (Clarabel by
default, or SCS) to their ``tolerance``.

Batches are solved :attr:`SdpOptions.block_size` epochs per cvxpy solve: one
problem of that many independent blocks (each epoch's ``4 x 4`` ``X`` with its
own ``tr X = 1`` and its own ``K``), which pays cvxpy's per-solve overhead
(most of the 2 ms of a one-epoch solve) once per block.  The last, partial
block is padded with a well-conditioned stand-in ``K`` (that of three
orthogonal vector pairs) whose solution is ignored: a padded block costs
little more than a full one, while a problem of another size would be
compiled anew (seconds) for every remainder.  A single epoch is solved by the
one-epoch problem.

The quaternion is the top eigenvector of the optimal ``X``.  The certificate
is reported per epoch: the duality gap ``|tr(K X) - nu|`` (``nu`` the
multiplier of the epoch's own ``tr X = 1``) and the rank-one ratio
``lambda_2 / lambda_1`` of ``X`` (both for ``K`` scaled by ``1 / sum a_i``).
A solve the solver calls optimal or "optimal_inaccurate" (tight tolerances
are sometimes just missed) is accepted when that certificate holds: ``X``
rank one to ``rank_one_tolerance`` and the gap below ``gap_tolerance``.  An
epoch of a block that fails the certificate, and every epoch of a block whose
solve fails, is solved again on its own, so that one hard epoch (e.g. a
repeated ``lambda_max``, where ``X`` is not rank one) cannot fail its
neighbours; an epoch that fails on its own too is flagged as a convergence
failure.

Accuracy: the eigenvector error is about the solver tolerance divided by the
eigen-gap of ``K``, so it grows with the dynamic range of the weights (the
contract tests hold it to 1e-10 rad over a 100:1 weight range).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import NDArray

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
        block_size: epochs per cvxpy solve of a batch (module docstring); 1
            solves every epoch on its own.  The default is the fastest
            measured with Clarabel (``docs/benchmarks.md``).

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
    block_size: int = 64

    def __post_init__(self) -> None:
        if self.solver not in TOLERANCE_OPTIONS:
            raise ValueError(
                f"unsupported SDP solver {self.solver!r}; supported: {sorted(TOLERANCE_OPTIONS)}"
            )
        if self.block_size < 1:
            raise ValueError(f"block_size must be at least 1, got {self.block_size}")

    def solver_options(self) -> dict[str, Any]:
        """Keyword options of ``cvxpy.Problem.solve`` for :attr:`solver`."""
        return dict.fromkeys(TOLERANCE_OPTIONS[self.solver], self.tolerance)


_PADDING = np.diag([-1.0, -1.0, -1.0, 3.0]) / 3.0
"""``K / lambda_0`` of three orthogonal unit-weight vector pairs at the identity: the stand-in
epoch of a partial block (eigen-gap 4/3)."""


@lru_cache(maxsize=16)
def relaxation(options: SdpOptions, size: int = 1) -> WahbaSDP:
    """The relaxation of ``size`` epochs solved with ``options``, built once per process,
    option set and size (cvxpy problems are not shared across worker processes)."""
    return WahbaSDP(size)


@dataclass
class _Certificates:
    """Per-epoch Shuster quaternion, certificate and failure reason (module docstring)."""

    q: NDArray[np.float64]
    gap: NDArray[np.float64]
    ratio: NDArray[np.float64]
    value: NDArray[np.float64]
    failure: NDArray[np.object_]

    @classmethod
    def empty(cls, n: int) -> _Certificates:
        return cls(
            np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)),
            np.full(n, np.nan),
            np.full(n, np.nan),
            np.full(n, np.nan),
            np.full(n, "", dtype=object),
        )

    def record(
        self,
        i: int,
        x: NDArray,
        value: float,
        dual: float,
        status: str,
        scale: float,
        options: SdpOptions,
    ) -> bool:
        """Certify epoch ``i``'s solution ``x`` (value and dual for ``K / scale``); returns
        whether it holds, else records why not."""
        if status not in _ACCEPTED or not np.isfinite(x).all():
            self.failure[i] = f"SDP solver status {status}"
            return False
        w, v = np.linalg.eigh(x)
        self.q[i] = v[:, -1]
        self.ratio[i] = abs(w[-2]) / w[-1]
        self.gap[i] = abs(value - dual)
        self.value[i] = value * scale
        if not self.ratio[i] < options.rank_one_tolerance:
            self.failure[i] = f"SDP relaxation not rank one (lambda2/lambda1 = {self.ratio[i]:.2e})"
        elif not self.gap[i] < options.gap_tolerance:
            self.failure[i] = f"SDP duality gap {self.gap[i]:.2e} above {options.gap_tolerance:g}"
        else:
            self.failure[i] = ""
        return self.failure[i] == ""


def _solve_blocks(
    rows: NDArray[np.intp],
    k: NDArray[np.float64],
    scale: NDArray[np.float64],
    options: SdpOptions,
    out: _Certificates,
) -> list[int]:
    """Solve epochs ``rows`` block by block; returns those to solve again on their own."""
    size = options.block_size
    problem = relaxation(options, size)
    retry: list[int] = []
    for start in range(0, rows.size, size):
        block = rows[start : start + size]
        padded = np.concatenate([k[block], np.broadcast_to(_PADDING, (size - block.size, 4, 4))])
        sol = problem.solve_blocks(padded, options.solver, **options.solver_options())
        for b, i in enumerate(block):
            if not out.record(
                i, sol.x[b], sol.value[b], sol.dual_value[b], sol.status, scale[i], options
            ):
                retry.append(int(i))
    return retry


def estimate(obs: ObservationBatch, options: SdpOptions) -> Estimate:
    """Every valid epoch's SDP, in blocks of :attr:`SdpOptions.block_size` (module docstring)."""
    lambda_0 = obs.weights.sum(axis=1)
    k = davenport_matrix(obs.profile_matrix) / lambda_0[:, None, None]
    out = _Certificates.empty(obs.n_epochs)
    rows = np.flatnonzero(obs.valid)
    if options.block_size > 1 and rows.size > 1:
        rows = np.array(_solve_blocks(rows, k, lambda_0, options, out), dtype=np.intp)
    problem = relaxation(options)
    for i in rows:
        sol = problem.solve(k[i], options.solver, **options.solver_options())
        out.record(i, sol.x, sol.value, sol.dual_value, sol.status, lambda_0[i], options)
    return Estimate(
        attitude_from_shuster_quaternion(out.q),
        quest_covariance(obs.body, obs.weights),
        {"duality_gap": out.gap, "rank_one_ratio": out.ratio, "sdp_value": out.value},
        failed=out.failure != "",
        failure=out.failure,
    )
