"""QUEST (seed 002 eqs. 27-32) with Shuster's method of sequential rotations.

``lambda_max`` comes from Newton-Raphson on Davenport's characteristic
equation started at ``lambda_0 = sum a_i``; the quaternion from eqs. 27-31.
Eq. 31 loses accuracy as the rotation approaches 180 degrees (``gamma -> 0``),
so the solution is also computed with the reference frame turned by 180
degrees about x, y and z (Shuster and Oh 1981), and per epoch the frame with
the largest ``|gamma|`` (largest ``|q4|``) is kept and turned back: attitudes near 180 degrees are
exact.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from formulations.conventions import attitude_from_shuster_quaternion
from formulations.vector_observations import ObservationBatch
from formulations.wahba import attitude_profile_matrix, davenport_characteristic, skew_axial
from formulations.wahba_covariance import quest_covariance
from solvers.newton import largest_root_newton
from solvers.wahba.driver import Estimate

# Reference-frame turns of the sequential rotations: identity, 180 deg about x, y, z.
_TURNS = np.array([np.diag(d) for d in ((1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1))], float)


def _quest_quaternion(b_matrix: np.ndarray, lambda_max: np.ndarray) -> np.ndarray:
    """Unnormalised ``[x; gamma]`` of seed 002 eqs. 27-31."""
    s = b_matrix + np.swapaxes(b_matrix, 1, 2)
    sigma = np.trace(b_matrix, axis1=1, axis2=2)
    z = skew_axial(b_matrix)
    trace_adj_s = 0.5 * (np.trace(s, axis1=1, axis2=2) ** 2 - np.einsum("eij,eji->e", s, s))
    alpha = lambda_max**2 - sigma**2 + trace_adj_s
    beta = lambda_max - sigma
    gamma = alpha * (lambda_max + sigma) - np.linalg.det(s)
    sz = np.einsum("eij,ej->ei", s, z)
    x = alpha[:, None] * z + beta[:, None] * sz + np.einsum("eij,ej->ei", s, sz)
    return np.concatenate([x, gamma[:, None]], axis=-1)


def estimate(obs: ObservationBatch) -> Estimate:
    """QUEST for every epoch."""
    b = attitude_profile_matrix(obs.body, obs.reference, obs.weights)
    lambda_0 = obs.weights.sum(axis=1)
    lambda_max, iterations, converged = largest_root_newton(davenport_characteristic(b), lambda_0)
    candidates = np.stack(
        [_quest_quaternion(b @ turn, lambda_max) for turn in _TURNS], axis=1
    )  # (N, 4 turns, 4)
    # [x; gamma] is the q4-column of adj(lambda I - K), proportional to q4 * q
    # with a factor the turns do not change, so the largest gamma marks the
    # frame with the largest |q4|; gamma is tiny and inaccurate in the others.
    best = np.argmax(np.abs(candidates[:, :, 3]), axis=1)
    epochs = np.arange(b.shape[0])
    turned = attitude_from_shuster_quaternion(candidates[epochs, best])
    attitude = turned * Rotation.from_matrix(_TURNS[best])
    failure = np.full(
        b.shape[0], "QUEST Newton-Raphson on lambda_max did not converge", dtype=object
    )
    return Estimate(
        attitude,
        quest_covariance(obs.body, obs.weights),
        {"iterations": iterations, "lambda_max": lambda_max, "sequential_rotation": best},
        failed=~converged,
        failure=failure,
    )
