"""The posterior bound of Yang et al. 2014's EKF (sec. 5, eqs. 23-33): filter and smoother.

The EKF is :mod:`attopt.solvers.doa.ekf`; its fixed-interval smoother is the
multiplicative RTS pass every filter's track shares
(:func:`attopt.solvers.filters.rts.rts_smooth`, attitude block last).

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

from functools import lru_cache

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.passes import Pass
from attopt.solvers.doa.ekf import (
    PROCESS_NOISE,
    ekf_dynamics,
    ekf_prior,
    epoch_symbols,
    propagated_covariance,
    step_function,
    update_function,
    vector_information_function,
)
from attopt.solvers.doa.vector_slots import vector_arrays, vector_slots
from attopt.solvers.filters.casadi_pass import accumulate
from attopt.solvers.filters.rts import rts_backward

Array = NDArray[np.float64]


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
    pass_: Pass,
    truth_attitude: Rotation,
    truth_rate: ArrayLike,
    process_noise: float = PROCESS_NOISE,
) -> tuple[Array, Array]:
    """Posterior Cramer-Rao bounds of the filter and of the smoother (module docstring).

    The EKF's covariance recursion (:func:`~attopt.solvers.doa.ekf.update_function`,
    :func:`~attopt.solvers.doa.ekf.step_function`, ``Q = q E_6``) with ``Phi`` and
    ``H`` at the truth, then :func:`~attopt.solvers.filters.rts.rts_backward` on it.

    Args:
        pass_: the unit vectors whose reference directions ``S_o`` (eq. 17) and
            sigmas (eq. 22) are measured at each epoch (their measured values are
            replaced by the truth's), the pass's dynamics, and the prior whose
            covariance of ``[attitude, rate]`` starts the recursion (its estimate
            is not used).
        truth_attitude: ``N`` true ``C_bo``.
        truth_rate: ``(N, 3)`` true ``omega_bi`` (rad/s).
        process_noise: ``q`` of ``Q = q E_6`` per step.

    Returns:
        ``(N, 6, 6)`` bounds on the covariance of ``[delta_omega, delta]``
        after each epoch's measurement (filter) and given all of them (smoother).
    """
    dynamics = ekf_dynamics(pass_)
    prior_covariance = ekf_prior(pass_.prior)[2]
    _, reference, sigma = vector_slots(pass_.snapshots)
    attitude = truth_attitude.as_matrix().reshape(-1, 3, 3)
    n = attitude.shape[0]
    mask = np.isfinite(reference).all(axis=-1)
    exact = np.where(mask[..., None], np.einsum("nij,nsj->nsi", attitude, reference), np.nan)
    body, reference, weight = vector_arrays(exact, reference, sigma)
    if n != len(pass_) or np.shape(truth_rate) != (n, 3):
        raise InvalidObservationError("need a true attitude and rate per epoch")
    turns = np.concatenate([dynamics.turns, np.eye(3)[None]])
    bound = _bound_function(dynamics.dt, dynamics.inertia, weight.shape[1])
    predicted, filtered, transition = accumulate(
        bound,
        1,
        [prior_covariance],
        [truth_rate, attitude, body, reference, weight, dynamics.momentum, turns, process_noise],
        n,
    )
    predicted = np.concatenate([np.reshape(prior_covariance, (1, 6, 6)), predicted[:-1]])
    smoothed = rts_backward(filtered, predicted, transition[:-1], np.zeros((n, 6)), 3)[1]
    return filtered, smoothed
