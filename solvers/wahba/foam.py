"""FOAM, Markley's fast optimal attitude matrix (Cilden Guler et al. 2017 eqs. 33-37)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from attopt.formulations.vector_observations import ObservationBatch
from attopt.formulations.wahba import adjugate, det3, foam_characteristic
from attopt.formulations.wahba_covariance import foam_covariance
from attopt.solvers.newton import largest_root_newton
from attopt.solvers.wahba.driver import Estimate

FAILURE = "FOAM Newton-Raphson on lambda_max did not converge"
"""The reason of an epoch whose Newton iteration did not converge."""


def estimate(obs: ObservationBatch) -> Estimate:
    """``A = [(kappa + |B|^2) B + lambda adj(B^T) - B B^T B] / (kappa lambda - det B)`` (eq. 35)."""
    b = obs.profile_matrix
    lambda_0 = obs.weights.sum(axis=1)
    lam, iterations, converged = largest_root_newton(foam_characteristic(b), lambda_0)
    fro2 = np.einsum("eij,eij->e", b, b)
    kappa = 0.5 * (lam**2 - fro2)
    zeta = kappa * lam - det3(b)
    bbtb = b @ np.swapaxes(b, 1, 2) @ b
    a = (
        (kappa + fro2)[:, None, None] * b
        + lam[:, None, None] * adjugate(np.swapaxes(b, 1, 2))
        - bbtb
    ) / zeta[:, None, None]
    return Estimate(
        Rotation.from_matrix(a),
        foam_covariance(b, lam),
        {"iterations": iterations, "lambda_max": lam},
        failed=~converged,
        failure=FAILURE,
    )
