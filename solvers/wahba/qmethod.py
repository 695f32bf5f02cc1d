"""Davenport's q-method (Cilden Guler et al. 2017 eqs. 20-26): the top eigenvector of ``K``."""

from __future__ import annotations

import numpy as np

from attopt.formulations.conventions import attitude_from_shuster_quaternion
from attopt.formulations.vector_observations import ObservationBatch
from attopt.formulations.wahba import davenport_matrix
from attopt.formulations.wahba_covariance import svd_covariance
from attopt.solvers.wahba.driver import Estimate


def estimate(obs: ObservationBatch) -> Estimate:
    """Symmetric eigensolver on ``K`` (eq. 26); covariance from eq. 19 as in Cilden Guler et al.
    2017 sec. 2.4."""
    b = obs.profile_matrix
    eigenvalues, eigenvectors = np.linalg.eigh(davenport_matrix(b))
    attitude = attitude_from_shuster_quaternion(eigenvectors[:, :, -1])
    diagnostics = {
        "lambda_max": eigenvalues[:, -1],
        "eigen_gap": eigenvalues[:, -1] - eigenvalues[:, -2],
    }
    return Estimate(attitude, svd_covariance(b, attitude.as_matrix()), diagnostics)
