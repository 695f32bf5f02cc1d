"""TRIAD, the algebraic method (Cilden Guler et al. 2017 eqs. 5-10) with its covariance (eq. 11).

With more than two observations TRIAD uses two: the anchor ``u`` is the most
accurate one (largest weight) and the partner ``v`` the one that best fixes the
rotation about it (largest ``a_j |u x b_j|^2``, the information about that
axis).  The paper's magnetometer + Sun case anchors on the Sun sensor.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.vector_observations import ObservationBatch
from attopt.formulations.wahba_covariance import triad_covariance
from attopt.solvers.wahba.driver import Estimate


def _triad_frame(u: NDArray, v: NDArray) -> NDArray:
    """``M = [q : r : s]`` with ``q = u``, ``r = u x v / |u x v|``, ``s = q x r`` (eqs. 5-9)."""
    r = np.cross(u, v)
    r /= np.linalg.norm(r, axis=-1, keepdims=True)
    return np.stack([u, r, np.cross(u, r)], axis=-1)


def estimate(obs: ObservationBatch) -> Estimate:
    """``A = M_B M_R^T`` (Cilden Guler et al. 2017 eq. 10) for every epoch."""
    epochs = np.arange(obs.n_epochs)
    anchor = np.argmax(obs.weights, axis=1)
    u_b = obs.body[epochs, anchor]
    cross2 = np.sum(np.cross(u_b[:, None, :], obs.body) ** 2, axis=-1)
    score = obs.weights * cross2
    score[epochs, anchor] = -1.0
    partner = np.argmax(score, axis=1)
    m_b = _triad_frame(u_b, obs.body[epochs, partner])
    m_r = _triad_frame(obs.reference[epochs, anchor], obs.reference[epochs, partner])
    attitude = Rotation.from_matrix(m_b @ np.swapaxes(m_r, 1, 2))
    covariance = triad_covariance(
        u_b,
        obs.body[epochs, partner],
        1.0 / obs.weights[epochs, anchor],
        1.0 / obs.weights[epochs, partner],
    )
    return Estimate(attitude, covariance, {"anchor": anchor, "partner": partner})
