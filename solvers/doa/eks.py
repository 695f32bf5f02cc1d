"""Fixed-interval smoothing and the posterior bound of the seed-003 EKF (sec. 5, eqs. 23-33).

Smoother.  A multiplicative Rauch-Tung-Striebel backward pass over an
:class:`~attopt.solvers.doa.ekf.EkfResult` (the dynamics-driven filter of
:mod:`attopt.solvers.doa.ekf`, no gyro), state ``[delta_omega, delta]``.  With ``P_k``
the filtered covariance, ``P^-_{k+1}`` the predicted one and ``Phi_k`` the
transition from epoch ``k`` to ``k + 1`` (eq. 28),

    C_k = P_k Phi_k^T (P^-_{k+1})^-1,
    x_k = C_k [x^s_{k+1} (-) x^-_{k+1}],
    P^s_k = P_k + C_k (P^s_{k+1} - P^-_{k+1}) C_k^T,

where ``x_k`` is the smoothed state's offset from the filtered one
(``A^s_k = C(x_k[3:]) A_k``, ``omega^s_k = omega_k + x_k[:3]``) and ``(-)`` the
error state of the smoothed estimate relative to the predicted one: the rate
difference and the attitude error vector
(:func:`~attopt.solvers.filters.common.error_vector`, four times the MRPs of ``A^s
(A^-)^T``, the filters' convention).  That is the EKF's own error:
:func:`~attopt.solvers.filters.common.apply_error` is its update's retraction
``C(delta) A`` (:func:`~attopt.formulations.attitude_model.increment_matrix`) and
``Phi`` maps first-order body-frame rotation vectors, which the error vector
is to first order.  The pass is the generic one of :mod:`attopt.solvers.filters.rts`
(:func:`~attopt.solvers.filters.rts.rts_backward`, run in CasADi's virtual machine)
with the attitude block last, ``attitude_start = 3``; the gyro MEKF's smoother
(:func:`~attopt.solvers.filters.rts.rts_smooth`, state ``[delta, delta_beta]``) runs
it with ``attitude_start = 0``.  ``P^s_{k+1} <= P^-_{k+1}`` makes ``P^s_k <=
P_k``: the smoothed covariance never exceeds the filtered one.

Bound.  The posterior Cramer-Rao bound of Tichavsky, Muravchik and Nehorai
(IEEE Trans. SP 46(5), 1998) for this model, linearised at the truth: with
additive Gaussian process noise ``Q`` per step and measurement noise ``R``
the information recursion reduces to the Kalman covariance recursion with
``Phi`` evaluated along the true rate and attitude and ``H`` at the true
attitudes, no state update (:func:`posterior_bound_ekf`); its RTS pass is the
smoother's bound.  It bounds any estimator of *this model*, dynamics with
``Q = q E_6`` per step (sec. 5.2): it is the EKF's own bound, not one for a
truth driven by unmodelled torques.
"""

from __future__ import annotations

from dataclasses import replace
from functools import lru_cache

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.errors import InvalidObservationError
from attopt.solvers.doa.ekf import (
    INERTIA_SEED003,
    PROCESS_NOISE,
    EkfResult,
    epoch_symbols,
    propagated_covariance,
    step_function,
    update_function,
    vector_arrays,
    vector_information_function,
)
from attopt.solvers.filters.casadi_pass import accumulate
from attopt.solvers.filters.common import apply_error, error_vector
from attopt.solvers.filters.rts import rts_backward

Array = NDArray[np.float64]


def rts_smooth_ekf(result: EkfResult) -> EkfResult:
    """Fixed-interval smoothed estimates of an EKF pass (module docstring).

    Returns an :class:`~attopt.solvers.doa.ekf.EkfResult` whose ``attitude``, ``rate``
    and ``covariance`` are smoothed; ``updates``, the ``predicted_*`` fields
    and ``transition`` are the filter's (the pass's inputs).  The last epoch's
    estimate is the filter's.
    """
    correction = np.concatenate(
        [
            result.rate - result.predicted_rate,
            error_vector(result.attitude, result.predicted_attitude),
        ],
        axis=1,
    )
    offset, covariance = rts_backward(
        result.covariance, result.predicted_covariance, result.transition, correction, 3
    )
    attitude = Rotation.concatenate(
        [apply_error(offset[:-1, 3:], result.attitude[:-1]), result.attitude[-1:]]
    )
    return replace(
        result, attitude=attitude, rate=result.rate + offset[:, :3], covariance=covariance
    )


@lru_cache(maxsize=8)
def _bound_function(dt: float, inertia: tuple[float, ...], slots: int) -> ca.Function:
    """``(P^-, omega, A, body, reference, weight, h, orbit_turn, q) -> (P^-_next, P+, Phi)``:
    the EKF epoch's covariance recursion at a given state (no state update)."""
    x = epoch_symbols(slots)
    information = vector_information_function(slots)(x.attitude, x.body, x.reference, x.weight)[0]
    update = update_function()(x.rate, x.attitude, x.covariance, information, ca.SX.zeros(3))
    posterior = update[2]
    transition = step_function(dt, inertia)(x.rate, x.attitude, x.momentum, x.orbit_turn)[2]
    return ca.Function(
        "doa_ekf_bound",
        [x.covariance, x.rate, x.attitude, *x[3:]],
        [
            ca.densify(y)
            for y in (
                propagated_covariance(posterior, transition, x.process_noise),
                posterior,
                transition,
            )
        ],
        {"cse": True},
    )


def posterior_bound_ekf(
    truth_attitude: Rotation,
    truth_rate: ArrayLike,
    reference: ArrayLike,
    sigma: ArrayLike,
    present: ArrayLike,
    orbit_turns: Rotation,
    wheel_momentum: ArrayLike,
    dt: float,
    prior_covariance: ArrayLike,
    inertia: ArrayLike = INERTIA_SEED003,
    process_noise: float = PROCESS_NOISE,
) -> tuple[Array, Array]:
    """Posterior Cramer-Rao bounds of the filter and of the smoother (module docstring).

    The EKF's covariance recursion (:func:`~attopt.solvers.doa.ekf.update_function`,
    :func:`~attopt.solvers.doa.ekf.step_function`, ``Q = q E_6``) with ``Phi`` and
    ``H`` at the truth, then :func:`~attopt.solvers.filters.rts.rts_backward` on it.

    Args:
        truth_attitude: ``N`` true ``C_bo``.
        truth_rate: ``(N, 3)`` true ``omega_bi`` (rad/s).
        reference: ``(N, S, 3)`` reference vectors ``S_o`` (eq. 17).
        sigma: ``(N, S)`` standard deviations of the measured vectors (eq. 22).
        present: ``(N, S)`` whether each vector is measured.
        orbit_turns: ``N - 1`` rotations ``O_{k+1} O_k^T`` of the orbit frame.
        wheel_momentum: ``(3,)`` or ``(N, 3)`` (N m s, body).
        dt: step (s).
        prior_covariance: ``6 x 6`` of ``[delta_omega, delta]`` at epoch 0.
        inertia: ``3 x 3`` (kg m^2, eq. 25).
        process_noise: ``q`` of ``Q = q E_6`` per step.

    Returns:
        ``(N, 6, 6)`` bounds on the covariance of ``[delta_omega, delta]``
        after each epoch's measurement (filter) and given all of them (smoother).
    """
    attitude = truth_attitude.as_matrix().reshape(-1, 3, 3)
    n = attitude.shape[0]
    reference = np.asarray(reference, dtype=float)
    mask = np.broadcast_to(np.asarray(present, dtype=bool), reference.shape[:2])
    exact = np.where(mask[..., None], np.einsum("nij,nsj->nsi", attitude, reference), np.nan)
    body, reference, weight = vector_arrays(exact, reference, sigma)
    if len(orbit_turns) != n - 1 or np.shape(truth_rate) != (n, 3):
        raise InvalidObservationError("need N true rates and N - 1 orbit-frame turns")
    turns = np.concatenate([orbit_turns.as_matrix().reshape(-1, 3, 3), np.eye(3)[None]])
    bound = _bound_function(
        float(dt), tuple(np.asarray(inertia, dtype=float).ravel()), weight.shape[1]
    )
    predicted, filtered, transition = accumulate(
        bound,
        1,
        [prior_covariance],
        [truth_rate, attitude, body, reference, weight, wheel_momentum, turns, process_noise],
        n,
    )
    predicted = np.concatenate([np.reshape(prior_covariance, (1, 6, 6)), predicted[:-1]])
    smoothed = rts_backward(filtered, predicted, transition[:-1], np.zeros((n, 6)), 3)[1]
    return filtered, smoothed
