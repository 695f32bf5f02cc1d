"""The part every Wahba solver shares: validate, estimate, mask, score.

A solver supplies only its method: a function from validated observations
(:class:`attopt.formulations.vector_observations.ObservationBatch`) to an
:class:`Estimate` for every epoch (:meth:`attopt.solvers.wahba.WahbaSolver.estimate`).
This module turns that into a :class:`attopt.solvers.results.Track` with
Wahba's loss (Cilden Guler et al. 2017 eq. 14), the validity mask and reasons.
The compiled methods (:mod:`attopt.solvers.wahba.compiled`) validate, solve and score
in one call; :func:`solve_compiled` and :func:`solve_one_compiled` give their results
the same form.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.errors import ConvergenceError
from attopt.formulations.vector_observations import CHECKS, ObservationBatch, check_outcomes
from attopt.formulations.wahba import wahba_loss
from attopt.solvers.results import Solution, Track
from attopt.solvers.wahba import compiled


@dataclass(frozen=True)
class Estimate:
    """What an estimator returns for all ``N`` epochs of a batch.

    ``failed`` marks epochs where the method itself did not converge (with
    ``failure`` the reason, one for all or one per epoch); their attitude is
    ignored.
    """

    attitude: Rotation
    covariance: NDArray[np.float64]
    diagnostics: Mapping[str, NDArray[np.float64]] = field(default_factory=dict)
    failed: NDArray[np.bool_] | None = None
    failure: str | NDArray[np.object_] | None = None


Method = Callable[[ObservationBatch], Estimate]
"""A Wahba method: validated observations -> the estimate of every epoch."""


def solve_prepared(name: str, method: Method, obs: ObservationBatch) -> Track:
    """Run ``method`` on validated observations and assemble the batch result."""
    n = obs.n_epochs
    valid = obs.valid.copy()
    reason = obs.reason.copy()
    error = obs.error.copy()
    if not valid.any():
        nan = np.full(n, np.nan)
        return Track(
            name,
            np.full((n, 4), np.nan),
            np.full((n, 3, 3), np.nan),
            nan,
            valid,
            reason,
            error,
            {},
        )
    est = method(obs)
    if est.failed is not None:
        newly = est.failed & valid
        valid &= ~est.failed
        reason[newly] = est.failure if isinstance(est.failure, str) else est.failure[newly]
        error[newly] = ConvergenceError
    quaternion = est.attitude.as_quat(canonical=True)
    loss = wahba_loss(est.attitude.as_matrix(), obs.profile_matrix, obs.weights)
    covariance = np.array(est.covariance, dtype=float)
    quaternion[~valid] = np.nan
    covariance[~valid] = np.nan
    loss[~valid] = np.nan
    diagnostics = {
        k: np.where(valid, np.asarray(v, dtype=float), np.nan) for k, v in est.diagnostics.items()
    }
    return Track(name, quaternion, covariance, loss, valid, reason, error, diagnostics)


def solve_compiled(
    name: str,
    kernel: int,
    failure: str,
    batch: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]],
    tolerance: float,
) -> Track:
    """The batch result of the compiled method ``kernel`` (:mod:`attopt.solvers.wahba.compiled`)
    on ``batch``, the arrays of :func:`~attopt.formulations.vector_observations.as_batch`:
    the same columns, reasons and masking as :func:`solve_prepared`."""
    solved = compiled.Solved.of(compiled.solve_epochs(kernel, *batch, tolerance))
    reason, error = check_outcomes(solved.code, tolerance)
    failed = ~solved.converged
    if failed.any():
        reason[failed] = failure
        error[failed] = ConvergenceError
    valid = (solved.code == 0) & solved.converged
    names = compiled.DIAGNOSTICS[kernel] if valid.any() else ()
    diagnostics = {k: solved.diagnostics[:, i] for i, k in enumerate(names)}
    return Track(
        name, solved.quaternion, solved.covariance, solved.loss, valid, reason, error, diagnostics
    )


def solve_one_compiled(
    name: str,
    kernel: int,
    failure: str,
    epoch: tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]],
    tolerance: float,
) -> Solution:
    """One epoch (``epoch`` as in :func:`solve_compiled`, ``N = 1``) as a valid
    :class:`Solution`; raises the specific error of an invalid one."""
    row = compiled.solve_epochs(kernel, *epoch, tolerance)[0]
    code = int(row[compiled.CODE])
    if code:
        text, exc = CHECKS[code]
        raise exc(f"{name}: {text.format(tolerance=tolerance)}")
    if not row[compiled.CONVERGED]:
        raise ConvergenceError(f"{name}: {failure}")
    values = row[compiled.DIAGNOSTIC :].tolist()
    return Solution(
        name,
        row[compiled.QUATERNION : compiled.COVARIANCE],
        row[compiled.COVARIANCE : compiled.LOSS].reshape(3, 3),
        float(row[compiled.LOSS]),
        dict(zip(compiled.DIAGNOSTICS[kernel], values, strict=False)),
    )
