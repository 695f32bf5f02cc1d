"""QUEST (Cilden Guler et al. 2017 eqs. 27-32) with Shuster's method of sequential rotations.

``lambda_max`` comes from Newton-Raphson on Davenport's characteristic
equation started at ``lambda_0 = sum a_i``; the quaternion from eqs. 27-31.
Eq. 31 loses accuracy as the rotation approaches 180 degrees (``gamma -> 0``),
so the solution is computed with the reference frame turned by 180 degrees
about x, y or z, whichever makes ``|q4|`` largest (Shuster and Oh 1981), and
turned back: attitudes near 180 degrees are exact.

Beyond the paper: ``lambda_max`` from the quartic carries a rounding error of
about ``eps lambda_0^2 / gap`` (``gap`` the eigen-gap of ``K``), which eq. 31
turns into an attitude error of about ``eps (lambda_0 / gap)^2``: 4e-6 rad for
nearly parallel Sun and field vectors.  One Rayleigh quotient ``q^T K q`` of
the first solution refines ``lambda_max`` before the final eqs. 27-31.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from attopt.formulations.vector_observations import ObservationBatch
from attopt.formulations.wahba import (
    davenport_characteristic,
    davenport_matrix,
    det3,
    skew_axial,
    trace3,
)
from attopt.formulations.wahba_covariance import quest_covariance
from attopt.solvers.newton import largest_root_newton
from attopt.solvers.wahba.driver import Estimate

FAILURE = "QUEST Newton-Raphson on lambda_max did not converge"
"""The reason of an epoch whose Newton iteration did not converge."""
TURN_SIGNS = np.array([(1, 1, 1), (1, -1, -1), (-1, 1, -1), (-1, -1, 1)], float)
"""Reference-frame turns of the sequential rotations (identity, 180 deg about x, y, z):
the diagonal of each turn's matrix."""
_TURNS = np.array([np.diag(d) for d in TURN_SIGNS])
_KEEP = [np.array([j for j in range(4) if j != i]) for i in range(4)]
_CONJUGATE = np.array([-1.0, -1.0, -1.0, 1.0])
TURN_COMPOSE = np.stack(
    [
        (Rotation.from_quat(np.eye(4)) * Rotation.from_matrix(turn)).as_quat(canonical=False).T
        for turn in _TURNS
    ]
)
"""Composing with a turn, ``q -> (Rotation(q) * turn).as_quat()``, is linear in the scipy
quaternion ``q``: its ``(4, 4)`` matrices, taken from scipy itself."""


def _quest_scalars(b_matrix: np.ndarray, lambda_max: np.ndarray):
    """``S``, ``alpha``, ``beta`` and ``gamma`` of Cilden Guler et al. 2017 eqs. 24, 27-29."""
    s = b_matrix + np.swapaxes(b_matrix, 1, 2)
    sigma = trace3(b_matrix)
    trace_adj_s = 0.5 * ((2.0 * sigma) ** 2 - np.sum(s * s, axis=(1, 2)))
    alpha = lambda_max**2 - sigma**2 + trace_adj_s  # eq. 27
    beta = lambda_max - sigma  # eq. 28
    gamma = alpha * (lambda_max + sigma) - det3(s)  # eq. 29
    return s, alpha, beta, gamma


def _quest_quaternion(b_matrix: np.ndarray, lambda_max: np.ndarray) -> np.ndarray:
    """Normalised Shuster quaternion ``[x; gamma]`` of Cilden Guler et al. 2017 eqs. 30-31."""
    s, alpha, beta, gamma = _quest_scalars(b_matrix, lambda_max)
    z = skew_axial(b_matrix)
    sz = (s @ z[:, :, None])[:, :, 0]
    x = alpha[:, None] * z + beta[:, None] * sz + (s @ sz[:, :, None])[:, :, 0]  # eq. 30
    q = np.concatenate([x, gamma[:, None]], axis=1)
    return q / np.linalg.norm(q, axis=1, keepdims=True)


def _principal_minors(m: np.ndarray) -> np.ndarray:
    """The 3x3 principal minors of each ``(4, 4)`` matrix (minor ``i`` drops row/column ``i``)."""
    return np.stack([det3(m[:, keep][:, :, keep]) for keep in _KEEP], axis=1)


def _conjugate(q: np.ndarray) -> np.ndarray:
    """Shuster <-> scipy quaternion (conjugate; ``docs/conventions.md``)."""
    return q * _CONJUGATE


def estimate(obs: ObservationBatch) -> Estimate:
    """QUEST for every epoch."""
    b = obs.profile_matrix
    k = davenport_matrix(b)
    lambda_0 = obs.weights.sum(axis=1)
    lambda_max, iterations, converged = largest_root_newton(davenport_characteristic(b), lambda_0)
    # Sequential rotations.  The diagonal of adj(lambda I - K) is c q_i^2 (c > 0
    # common), and turning the reference frame by 180 deg about axis i makes
    # q_i the new q4; so the largest principal minor picks the turn
    # (identity when it is q4's: then gamma of eq. 29 is that minor).
    minors = _principal_minors(lambda_max[:, None, None] * np.eye(4) - k)
    turn = (np.argmax(np.abs(minors), axis=1) + 1) % 4
    turned_b = b * TURN_SIGNS[turn][:, None, :]
    compose = TURN_COMPOSE[turn]
    q = _quest_quaternion(turned_b, lambda_max)
    # Newton on the quartic leaves lambda with an error of about
    # eps lambda_0^2 / gap (gap: the eigen-gap of K); the Rayleigh quotient
    # q^T K q of that solution (in the untouched frame) reduces it to about
    # eps lambda_0.
    q = _conjugate((compose @ _conjugate(q)[:, :, None])[:, :, 0])
    lambda_max = np.sum((k @ q[:, :, None])[:, :, 0] * q, axis=1)
    turned = _conjugate(_quest_quaternion(turned_b, lambda_max))
    attitude = Rotation.from_quat((compose @ turned[:, :, None])[:, :, 0])
    return Estimate(
        attitude,
        quest_covariance(obs.body, obs.weights),
        {"iterations": iterations, "lambda_max": lambda_max, "sequential_rotation": turn},
        failed=~converged,
        failure=FAILURE,
    )
