"""QUEST (seed 002 eqs. 27-32) with Shuster's method of sequential rotations.

``lambda_max`` comes from Newton-Raphson on Davenport's characteristic
equation started at ``lambda_0 = sum a_i``; the quaternion from eqs. 27-31.
Eq. 31 loses accuracy as the rotation approaches 180 degrees (``gamma -> 0``),
so the solution is computed with the reference frame turned by 180 degrees
about x, y or z, whichever makes ``|q4|`` largest (Shuster and Oh 1981), and
turned back: attitudes near 180 degrees are exact.

Beyond the seed: ``lambda_max`` from the quartic carries a rounding error of
about ``eps lambda_0^2 / gap`` (``gap`` the eigen-gap of ``K``), which eq. 31
turns into an attitude error of about ``eps (lambda_0 / gap)^2``: 4e-6 rad for
nearly parallel Sun and field vectors.  One Rayleigh quotient ``q^T K q`` of
the first solution refines ``lambda_max`` before the final eqs. 27-31.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from formulations.conventions import attitude_from_shuster_quaternion
from formulations.vector_observations import ObservationBatch
from formulations.wahba import (
    attitude_profile_matrix,
    davenport_characteristic,
    davenport_matrix,
    det3,
    skew_axial,
    trace3,
)
from formulations.wahba_covariance import quest_covariance
from solvers.newton import largest_root_newton
from solvers.wahba.driver import Estimate

# Reference-frame turns of the sequential rotations: identity, 180 deg about x, y, z.
_TURN_SIGNS = np.array([(1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)], float)
_TURNS = np.array([np.diag(d) for d in _TURN_SIGNS])
# Composing with a turn, ``q -> (Rotation(q) * turn).as_quat()``, is linear in
# the scipy quaternion ``q``; these are its matrices, taken from scipy itself.
_TURN_COMPOSE = np.stack(
    [
        (Rotation.from_quat(np.eye(4)) * Rotation.from_matrix(turn)).as_quat(canonical=False).T
        for turn in _TURNS
    ]
)


def _quest_scalars(b_matrix: np.ndarray, lambda_max: np.ndarray):
    """``S``, ``alpha``, ``beta`` and ``gamma`` of seed 002 eqs. 24, 27-29."""
    s = b_matrix + np.swapaxes(b_matrix, 1, 2)
    sigma = trace3(b_matrix)
    trace_adj_s = 0.5 * ((2.0 * sigma) ** 2 - np.sum(s * s, axis=(1, 2)))
    alpha = lambda_max**2 - sigma**2 + trace_adj_s  # eq. 27
    beta = lambda_max - sigma  # eq. 28
    gamma = alpha * (lambda_max + sigma) - det3(s)  # eq. 29
    return s, alpha, beta, gamma


def _quest_quaternion(b_matrix: np.ndarray, lambda_max: np.ndarray) -> np.ndarray:
    """Normalised Shuster quaternion ``[x; gamma]`` of seed 002 eqs. 30-31."""
    s, alpha, beta, gamma = _quest_scalars(b_matrix, lambda_max)
    z = skew_axial(b_matrix)
    sz = (s @ z[:, :, None])[:, :, 0]
    x = alpha[:, None] * z + beta[:, None] * sz + (s @ sz[:, :, None])[:, :, 0]  # eq. 30
    q = np.concatenate([x, gamma[:, None]], axis=1)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def estimate(obs: ObservationBatch) -> Estimate:
    """QUEST for every epoch."""
    b = attitude_profile_matrix(obs.body, obs.reference, obs.weights)
    lambda_0 = obs.weights.sum(axis=1)
    lambda_max, iterations, converged = largest_root_newton(davenport_characteristic(b), lambda_0)
    # Sequential rotations: gamma of eq. 29 is the q4-entry of adj(lambda I - K),
    # proportional to q4^2 with a factor the turns do not change, so the turn
    # with the largest |gamma| is the frame with the largest |q4|.
    # (B R_i flips the signs of two columns of B.)
    gammas = np.stack([_quest_scalars(b * t, lambda_max)[3] for t in _TURN_SIGNS], axis=1)
    turn = np.argmax(np.abs(gammas), axis=1)
    turned_b = b * _TURN_SIGNS[turn][:, None, :]
    q = _quest_quaternion(turned_b, lambda_max)
    # Newton on the quartic leaves lambda with an error of about
    # eps lambda_0^2 / gap (gap: the eigen-gap of K); the Rayleigh quotient
    # q^T K q of that solution reduces it to about eps lambda_0.
    lambda_max = np.sum((davenport_matrix(turned_b) @ q[:, :, None])[:, :, 0] * q, axis=1)
    turned = attitude_from_shuster_quaternion(_quest_quaternion(turned_b, lambda_max)).as_quat()
    attitude = Rotation.from_quat((_TURN_COMPOSE[turn] @ turned[:, :, None])[:, :, 0])
    failure = "QUEST Newton-Raphson on lambda_max did not converge"
    return Estimate(
        attitude,
        quest_covariance(obs.body, obs.weights),
        {"iterations": iterations, "lambda_max": lambda_max, "sequential_rotation": turn},
        failed=~converged,
        failure=failure,
    )
