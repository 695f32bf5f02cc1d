"""SVD solution of Wahba's problem (seed 002 eqs. 17-19)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from formulations.vector_observations import ObservationBatch
from formulations.wahba import attitude_profile_matrix, proper_svd
from formulations.wahba_covariance import svd_covariance
from solvers.wahba.driver import Estimate


def estimate(obs: ObservationBatch) -> Estimate:
    """``A = U diag[1, 1, det U det V] V^T`` for ``B = U Sigma V^T`` (eqs. 17-18)."""
    b = attitude_profile_matrix(obs.body, obs.reference, obs.weights)
    u, s, vt, d = proper_svd(b)
    a = np.einsum("eij,ej,ejk->eik", u, np.stack([np.ones_like(d), np.ones_like(d), d], -1), vt)
    return Estimate(Rotation.from_matrix(a), svd_covariance(b), {"s3": d * s[:, 2]})
