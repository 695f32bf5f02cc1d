"""Fixed-interval smoothing and the posterior bound of the seed-003 EKF (sec. 5, eqs. 23-33).

Smoother.  A multiplicative Rauch-Tung-Striebel backward pass over an
:class:`~solvers.doa.ekf.EkfResult` (the dynamics-driven filter of
:mod:`solvers.doa.ekf`, no gyro), state ``[delta_omega, delta]``.  With ``P_k``
the filtered covariance, ``P^-_{k+1}`` the predicted one and ``Phi_k`` the
transition from epoch ``k`` to ``k + 1`` (eq. 28),

    C_k = P_k Phi_k^T (P^-_{k+1})^-1,
    x_k = C_k [x^s_{k+1} (-) x^-_{k+1}],
    P^s_k = P_k + C_k (P^s_{k+1} - P^-_{k+1}) C_k^T,

where ``x_k`` is the smoothed state's offset from the filtered one
(``A^s_k = C(x_k[3:]) A_k``, ``omega^s_k = omega_k + x_k[:3]``) and ``(-)`` the
error state of the smoothed estimate relative to the predicted one: the rate
difference and the attitude error vector
(:func:`~solvers.filters.common.error_vector`, four times the MRPs of ``A^s
(A^-)^T``, the filters' convention).  That is the EKF's own error:
:func:`~solvers.filters.common.apply_error` is its update's retraction
``C(delta) A`` (:func:`~formulations.attitude_model.increment_matrix`) and
``Phi`` maps first-order body-frame rotation vectors, which the error vector
is to first order.  Since ``A^s_{k+1} = C(x_{k+1}) A_{k+1}`` and ``A_{k+1} =
C(c_{k+1}) A^-_{k+1}`` (``c`` the filter's correction), the attitude part is the
error vector of the composition ``C(x) C(c)``, computed from quaternions in
CasADi (:func:`composed_error`), so the whole backward pass runs in CasADi's
virtual machine (:func:`rts_backward`).  ``P^s_{k+1} <= P^-_{k+1}`` makes
``P^s_k <= P_k``: the smoothed covariance never exceeds the filtered one.

:func:`rts_backward` knows only where the attitude block sits; the gyro
MEKF's smoother (:func:`solvers.filters.rts.rts_smooth`, state ``[delta,
delta_beta]``) is the same recursion with ``attitude_start = 0``.

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
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from formulations.errors import InvalidObservationError
from solvers.doa.ekf import (
    INERTIA_SEED003,
    PROCESS_NOISE,
    EkfResult,
    accumulate,
    lower_symmetric,
    propagated_covariance,
    step_function,
    update_function,
    vector_arrays,
    vector_information_function,
)
from solvers.filters.common import apply_error, error_vector

Array = NDArray[np.float64]


def _quaternion(error: Any) -> tuple[Any, Any]:
    """Vector part and scalar of the (scalar-last) quaternion of ``C(error)``: MRPs
    ``p = error / 4``, ``q = [2 p, 1 - |p|^2] / (1 + |p|^2)``."""
    p = error / 4.0
    norm2 = ca.dot(p, p)
    return 2.0 * p / (1.0 + norm2), (1.0 - norm2) / (1.0 + norm2)


def composed_error(outer: Any, inner: Any) -> Any:
    """``error_vector(apply_error(outer, apply_error(inner, A)), A)`` in CasADi (``3 x 1``).

    Four times the MRPs of ``C(outer) C(inner)``: the Hamilton product of the
    two quaternions, the shadow set taken when its scalar is negative (as
    scipy's ``as_mrp``).
    """
    v1, w1 = _quaternion(outer)
    v2, w2 = _quaternion(inner)
    vector = w1 * v2 + w2 * v1 + ca.cross(v1, v2)
    scalar = w1 * w2 - ca.dot(v1, v2)
    sign = ca.if_else(scalar < 0, -1.0, 1.0)
    return 4.0 * sign * vector / (1.0 + sign * scalar)


@lru_cache(maxsize=8)
def _backward_function(size: int, attitude_start: int) -> ca.Function:
    """``(x_next, P^s_next, C, P, P^-_next, c_next) -> (x, P^s)``: one RTS step back."""
    offset = ca.SX.sym("offset", size)
    smoothed = ca.SX.sym("smoothed", size, size)
    gain = ca.SX.sym("gain", size, size)
    filtered = ca.SX.sym("filtered", size, size)
    predicted = ca.SX.sym("predicted", size, size)
    correction = ca.SX.sym("correction", size)
    block = slice(attitude_start, attitude_start + 3)
    difference = offset + correction
    difference[block] = composed_error(offset[block], correction[block])
    covariance = filtered + gain @ (smoothed - predicted) @ gain.T
    return ca.Function(
        "rts_backward_step",
        [offset, smoothed, gain, filtered, predicted, correction],
        [ca.densify(gain @ difference), ca.densify(lower_symmetric(covariance))],
        {"cse": True},
    )


def rts_backward(
    filtered_covariance: ArrayLike,
    predicted_covariance: ArrayLike,
    transition: ArrayLike,
    correction: ArrayLike,
    attitude_start: int,
) -> tuple[Array, Array]:
    """The multiplicative RTS backward pass (module docstring) on arrays.

    Args:
        filtered_covariance: ``(N, n, n)`` ``P_k`` after epoch ``k``'s update.
        predicted_covariance: ``(N, n, n)`` ``P^-_k`` before it (row 0 unused).
        transition: ``(N - 1, n, n)``, ``transition[k]`` from epoch ``k`` to ``k + 1``.
        correction: ``(N, n)`` filtered minus predicted state at each epoch:
            the attitude error vector (:func:`~solvers.filters.common.error_vector`
            of the filtered attitude relative to the predicted one) in the
            attitude block, plain differences elsewhere (row 0 unused).
        attitude_start: index of the three attitude-error components.

    Returns:
        ``(N, n)`` offsets of the smoothed state from the filtered one (zero at
        the last epoch; apply the attitude block with
        :func:`~solvers.filters.common.apply_error`) and the ``(N, n, n)``
        smoothed covariances.
    """
    filtered_covariance = np.asarray(filtered_covariance, dtype=float)
    predicted_covariance = np.asarray(predicted_covariance, dtype=float)
    transition = np.asarray(transition, dtype=float)
    correction = np.asarray(correction, dtype=float)
    n, size = correction.shape
    if (
        filtered_covariance.shape != (n, size, size)
        or predicted_covariance.shape != (n, size, size)
        or transition.shape != (n - 1, size, size)
    ):
        raise InvalidObservationError("inconsistent shapes for the RTS pass")
    # C_k^T = (P^-_{k+1})^-1 Phi_k P_k, all epochs at once
    gain = np.linalg.solve(predicted_covariance[1:], transition @ filtered_covariance[:-1])
    gain = np.swapaxes(gain, 1, 2)
    backward = np.s_[::-1]
    offsets, covariances = accumulate(
        _backward_function(size, attitude_start),
        2,
        [np.zeros(size), filtered_covariance[-1]],
        [
            gain[backward],
            filtered_covariance[:-1][backward],
            predicted_covariance[1:][backward],
            correction[1:][backward],
        ],
        n - 1,
    )
    return (
        np.concatenate([offsets[backward, :, 0], np.zeros((1, size))]),
        np.concatenate([covariances[backward], filtered_covariance[-1:]]),
    )


def rts_smooth_ekf(result: EkfResult) -> EkfResult:
    """Fixed-interval smoothed estimates of an EKF pass (module docstring).

    Returns an :class:`~solvers.doa.ekf.EkfResult` whose ``attitude``, ``rate``
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
    covariance = ca.SX.sym("covariance", 6, 6)
    rate = ca.SX.sym("omega", 3)
    attitude = ca.SX.sym("attitude", 3, 3)
    body = ca.SX.sym("body", slots, 3)
    reference = ca.SX.sym("reference", slots, 3)
    weight = ca.SX.sym("weight", slots)
    momentum = ca.SX.sym("h", 3)
    orbit_turn = ca.SX.sym("orbit_turn", 3, 3)
    process_noise = ca.SX.sym("q")
    information = vector_information_function(slots)(attitude, body, reference, weight)[0]
    posterior = update_function()(rate, attitude, covariance, information, ca.SX.zeros(3))[2]
    transition = step_function(dt, inertia)(rate, attitude, momentum, orbit_turn)[2]
    return ca.Function(
        "doa_ekf_bound",
        [covariance, rate, attitude, body, reference, weight, momentum, orbit_turn, process_noise],
        [
            ca.densify(x)
            for x in (
                propagated_covariance(posterior, transition, process_noise),
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

    The EKF's covariance recursion (:func:`~solvers.doa.ekf.update_function`,
    :func:`~solvers.doa.ekf.step_function`, ``Q = q E_6``) with ``Phi`` and
    ``H`` at the truth, then :func:`rts_backward` on it.

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
