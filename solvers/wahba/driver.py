"""The part every Wahba solver shares: validate, estimate, mask, score.

A solver supplies only its method: a function from validated observations
(:class:`attopt.formulations.vector_observations.ObservationBatch`) to an
:class:`Estimate` for every epoch (:meth:`attopt.solvers.wahba.WahbaSolver.estimate`).
This module turns that into a :class:`attopt.solvers.results.Track` with
Wahba's loss (Cilden Guler et al. 2017 eq. 14), the validity mask and reasons.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.errors import ConvergenceError
from attopt.formulations.vector_observations import ObservationBatch
from attopt.formulations.wahba import wahba_loss
from attopt.solvers.results import Track


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
