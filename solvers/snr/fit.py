"""Loss and covariance of an attitude for an SNR epoch, shared by every SNR solver.

* Loss: ``F = 1/2 sum_k (y_k - f_k(A))^2 / sigma_k^2``, seed 000 eq. 19
  weighted by the ``C`` of eq. 22 (with ``sigma = 1 dB`` exactly eq. 19).
* Covariance: ``R = (J^T C J)^-1`` (seed 000 eq. 22) with ``J`` the Jacobian of
  the predicted SNRs with respect to the body-frame rotation-vector error at
  ``A`` (``docs/conventions.md``), i.e. the Cramer-Rao bound of the epoch
  evaluated at the estimate instead of the truth
  (:func:`formulations.snr_model.fisher_information`,
  :func:`formulations.snr_model.cramer_rao_bound`; infinite along unobservable
  directions).  ``J`` is the CasADi AD Jacobian
  :func:`formulations.snr_model.snr_jacobian_function` at ``v = 0``, the one
  :func:`formulations.snr_model.predict_snr` wraps, called directly (on the
  padded bucket) because ``predict_snr`` rejects observations beyond the main
  lobe, and at a noisy estimate an observation near the lobe edge may fall
  just outside it while it still is part of the loss that was minimised.  The
  number of such observations is reported (:attr:`Fit.outside_lobe`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from formulations.snr_model import (
    cramer_rao_bound,
    fisher_information,
    observation_mask,
    snr_jacobian_function,
)
from formulations.snr_problem import SnrEpoch
from solvers.snr.padding import pad_epoch

Array = NDArray[np.float64]


def snr_loss(measured: Any, predicted: Any, weights: Any) -> Any:
    """``1/2 sum_k w_k (y_k - f_k)^2`` (seed 000 eq. 19, ``w_k = 1/sigma_k^2``), numpy or CasADi."""
    residual = measured - predicted
    if isinstance(residual, ca.SX | ca.MX | ca.DM):
        return 0.5 * ca.dot(weights, residual * residual)
    return 0.5 * float(np.dot(weights, residual * residual))


def model_at(problem: SnrEpoch, attitude: Rotation) -> tuple[Array, Array]:
    """Predicted SNR ``(m,)`` and its Jacobian ``(m, 3)`` (dB/rad, body-frame error)."""
    a = attitude.as_matrix()
    padded = pad_epoch(problem, a)
    snr, jac = snr_jacobian_function(problem.pattern, padded.size)(
        np.zeros(3), a, padded.los, padded.boresight, padded.p0, padded.noise
    )
    return snr.full().ravel()[: problem.m], jac.full()[: problem.m]


@dataclass(frozen=True)
class Fit:
    """What an attitude explains of an epoch.

    Attributes:
        loss: seed 000 eq. 19 weighted by ``C`` (see the module docstring).
        covariance: ``(3, 3)`` eq. 22, rad^2, body frame.
        outside_lobe: observations beyond the pattern's main lobe at the attitude.
    """

    loss: float
    covariance: Array
    outside_lobe: int


def fit_at(problem: SnrEpoch, attitude: Rotation) -> Fit:
    """Loss and eq. 22 covariance of ``attitude`` for ``problem``."""
    predicted, jac = model_at(problem, attitude)
    # On a validated epoch observation_mask is False only beyond the main lobe.
    in_lobe = observation_mask(
        attitude.as_matrix(), problem.unit_los, problem.boresight_rows, problem.pattern
    )
    return Fit(
        loss=snr_loss(problem.snr_db, predicted, problem.weights),
        covariance=cramer_rao_bound(fisher_information(jac, problem.sigma_db)),
        outside_lobe=int(np.count_nonzero(~in_lobe)),
    )
