"""SVD solution of Wahba's problem (Cilden Guler et al. 2017 eqs. 17-19)."""

from __future__ import annotations

from scipy.spatial.transform import Rotation

from attopt.formulations.vector_observations import ObservationBatch
from attopt.formulations.wahba import proper_svd
from attopt.formulations.wahba_covariance import svd_covariance
from attopt.solvers.wahba.driver import Estimate


def estimate(obs: ObservationBatch) -> Estimate:
    """``A = U diag[1, 1, det U det V] V^T`` for ``B = U Sigma V^T`` (eqs. 17-18)."""
    b = obs.profile_matrix
    u, s, vt, d = proper_svd(b)
    u[:, :, 2] *= d[:, None]  # U diag[1, 1, d] (eq. 18)
    a = u @ vt
    return Estimate(Rotation.from_matrix(a), svd_covariance(b, a), {"s3": d * s[:, 2]})
