"""The extended Kalman filter of seed 003 (sec. 5, eqs. 23-33) on DOA measurements.

State (eq. 26): the inertial body rate ``omega_bi`` (body axes, rad/s) and the
attitude ``A = C_bo`` (orbit -> body, ``docs/conventions.md``).

Dynamics (eqs. 23, 24, 27).  Euler's equation with the wheels' angular
momentum ``h`` (body axes, N m s), ``I omega_dot = -omega x (I omega + h)``,
with ``h_dot``, the magnetorquer and the disturbance torques set to zero (the
filter does not know them; ``Q`` absorbs them, as in the seed), and the
kinematics ``A_dot = -[omega_bo x] A``, ``omega_bo = omega_bi - A omega_o``
(eq. 24).  One step of ``dt`` is written once, in CasADi
(:func:`step_function`):

* ``omega`` by one classical Runge-Kutta step of Euler's equation;
* ``A_{k+1} = Exp(-omega_bar dt) A_k (O_{k+1} O_k^T)^T`` with ``O = A_oi`` the
  orbit frame's attitude from the ephemeris and ``omega_bar`` the mean of the
  step's start and end rates.  The orbit frame's own turn ``O_{k+1} O_k^T``
  replaces ``omega_o`` of eq. 24 exactly, so the orbit rate's variation with
  eccentricity and ``J2`` needs no model.  ``Exp`` is the Rodrigues formula with
  its coefficients as Taylor series to ``|phi|^8``, exact to rounding for
  ``|phi| <= 0.1 rad`` (23 deg/s at 250 ms); larger steps raise
  :class:`~formulations.errors.ConvergenceError`.

Error state and transition matrix (eqs. 28-29).  The attitude error is
multiplicative and in the body frame, ``A_true = C(delta) A_est``
(``formulations.attitude_model.increment_matrix``, the convention of every
filter here), so ``[delta_omega, delta]`` replaces the seed's additive
``[delta_omega, delta q_bo]``; to first order ``delta = 2 delta q_bo``, the
seed's eq. 29 lower-left block ``0.5 E`` becomes ``E`` and the lower-right
``-[omega x]`` stays, but the quaternion never leaves the unit sphere.  The
transition matrix is the AD Jacobian of the step map above (not the Euler
approximation ``E + A dt`` of eq. 28).

Measurement (eqs. 30-33).  Any :class:`~formulations.attitude_measurement.AttitudeMeasurement`
of ``C_bo``; its AD Jacobian with respect to the body-frame error ``delta``
is the attitude block of ``H`` and the rate block is zero (eq. 32).  Rows
without a finite innovation or Jacobian are left out.  The seed's form is a
:class:`~formulations.attitude_measurement.VectorMeasurement` per epoch: the
measured unit vectors ``S_dr`` of eq. 12 against ``S_o`` of eq. 17, for which
``H``'s attitude block is ``[(C_bo S_o) x]`` (eq. 33 with ``delta = 2 delta q``).
The angle form :class:`~formulations.doa_measurement.DoaMeasurement` has no
prediction for a station the estimate puts behind the array plane, so from
the seed's 98 deg initial error the filter can get stuck with the array
facing away (measured: noise-free, 160-180 deg after 2500 s); the unit
vector has a prediction and a restoring innovation everywhere.

Noise.  ``Q = q E_6`` per step with ``q = 1e-9`` (sec. 5.2).  ``R`` comes
with the measurement; for MUSIC DOAs the experiment uses ``R_W = sigma^2 E``
per station with ``sigma^2 = tr(J Sigma J^T) / 2``, ``Sigma`` MUSIC's
``(theta, phi)`` covariance (the CRB at the estimate) and ``J`` eq. 12's
Jacobian (:func:`formulations.doa_array.unit_vector_covariance`): the
isotropic form of eq. 22, whose diagonal the seed fits to simulations.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from formulations.attitude_measurement import AttitudeMeasurement
from formulations.attitude_model import increment_matrix
from formulations.errors import ConvergenceError, InvalidObservationError
from formulations.symbolic import CASADI, namespace_of

Array = NDArray[np.float64]

INERTIA_SEED003 = np.array(
    [[6.6199, 0.01636, 0.2363], [0.01636, 8.95, 0.2247], [0.2363, 0.2247, 9.4968]]
)
"""Inertia matrix of seed 003 eq. 25 (kg m^2)."""
PROCESS_NOISE = 1.0e-9
"""Diagonal of ``Q`` per step (seed 003 sec. 5.2)."""
MAX_STEP_ANGLE = 0.1
"""Largest rotation per step (rad) for which the series ``Exp`` is exact to rounding."""


def angular_acceleration(omega: Any, wheel_momentum: Any, inertia: ArrayLike) -> Any:
    """``omega_dot = I^-1 (-omega x (I omega + h))`` (seed 003 eq. 23, torque free, ``h_dot = 0``).

    numpy: ``(..., 3)`` rates and momenta; CasADi: ``3 x 1`` columns.
    """
    inertia = np.asarray(inertia, dtype=float)
    if namespace_of(omega, wheel_momentum) is CASADI:
        momentum = ca.DM(inertia) @ omega + wheel_momentum
        return ca.solve(ca.DM(inertia), -ca.cross(omega, momentum))
    omega = np.asarray(omega, dtype=float)
    momentum = omega @ inertia.T + wheel_momentum
    return np.linalg.solve(inertia, -np.cross(omega, momentum)[..., None])[..., 0]


def _skew(v: Any) -> Any:
    return ca.vertcat(
        ca.horzcat(0.0, -v[2], v[1]), ca.horzcat(v[2], 0.0, -v[0]), ca.horzcat(-v[1], v[0], 0.0)
    )


def rotation_exp(phi: Any) -> Any:
    """``Exp(phi) = I + a K + b K^2``, ``K = [phi x]`` (CasADi ``3 x 1``), as Taylor series.

    ``a = sin|phi| / |phi|`` and ``b = (1 - cos|phi|) / |phi|^2`` to ``|phi|^8``:
    smooth at zero for AD, truncation below ``|phi|^10 / 4e7`` (2.5e-18 at 0.1 rad).
    """
    t = ca.dot(phi, phi)
    a = 1.0 - t / 6.0 + t**2 / 120.0 - t**3 / 5040.0 + t**4 / 362880.0
    b = 0.5 - t / 24.0 + t**2 / 720.0 - t**3 / 40320.0 + t**4 / 3628800.0
    k = _skew(phi)
    return ca.DM.eye(3) + a * k + b * (k @ k)


def _vee_skew(matrix: Any) -> Any:
    """Rotation vector of a rotation matrix near the identity, to first order."""
    return 0.5 * ca.vertcat(
        matrix[2, 1] - matrix[1, 2], matrix[0, 2] - matrix[2, 0], matrix[1, 0] - matrix[0, 1]
    )


@lru_cache(maxsize=8)
def step_function(dt: float, inertia: tuple[float, ...]) -> ca.Function:
    """One filter step (module docstring) and its transition matrix by CasADi AD.

    ``(omega, A, h, orbit_turn) -> (omega_next, A_next, Phi)`` with ``A`` and
    ``orbit_turn = O_{k+1} O_k^T`` ``3 x 3``, ``h`` ``3 x 1``; ``Phi`` is the
    ``6 x 6`` Jacobian of ``[omega_next, delta_next]`` with respect to
    ``[omega, delta]`` at ``delta = 0`` (seed 003 eqs. 28-29).
    """
    inertia_matrix = np.reshape(inertia, (3, 3))
    omega = ca.SX.sym("omega", 3)
    d_omega = ca.SX.sym("d_omega", 3)
    delta = ca.SX.sym("delta", 3)
    attitude = ca.SX.sym("attitude", 3, 3)
    momentum = ca.SX.sym("h", 3)
    orbit_turn = ca.SX.sym("orbit_turn", 3, 3)

    def propagate(w: Any, a: Any) -> tuple[Any, Any]:
        k1 = angular_acceleration(w, momentum, inertia_matrix)
        k2 = angular_acceleration(w + 0.5 * dt * k1, momentum, inertia_matrix)
        k3 = angular_acceleration(w + 0.5 * dt * k2, momentum, inertia_matrix)
        k4 = angular_acceleration(w + dt * k3, momentum, inertia_matrix)
        w_next = w + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
        return w_next, rotation_exp(-0.5 * dt * (w + w_next)) @ a @ orbit_turn.T

    nominal_omega, nominal_attitude = propagate(omega, attitude)
    perturbed_omega, perturbed_attitude = propagate(
        omega + d_omega, increment_matrix(delta) @ attitude
    )
    error = ca.vertcat(
        perturbed_omega - nominal_omega, _vee_skew(perturbed_attitude @ nominal_attitude.T)
    )
    transition = ca.jacobian(error, ca.vertcat(d_omega, delta))
    transition = ca.substitute(transition, ca.vertcat(d_omega, delta), ca.DM.zeros(6))
    return ca.Function(
        "doa_ekf_step",
        [omega, attitude, momentum, orbit_turn],
        [nominal_omega, nominal_attitude, transition],
    )


@dataclass(frozen=True)
class EkfPrior:
    """Initial estimate: ``attitude`` ``C_bo``, ``rate`` ``omega_bi`` (rad/s), covariance ``6 x 6``.

    The covariance is of ``[delta_omega, delta]`` (module docstring).
    """

    attitude: Rotation
    rate: Array
    covariance: Array


@dataclass(frozen=True)
class EkfResult:
    """Posterior at every epoch.

    Attributes:
        attitude: ``C_bo`` estimates, ``N`` rotations.
        rate: ``(N, 3)`` ``omega_bi`` estimates (rad/s).
        covariance: ``(N, 6, 6)`` of ``[delta_omega, delta]`` (rad^2/s^2, rad^2).
        updates: ``(N,)`` number of measurement rows used at each epoch.
    """

    attitude: Rotation
    rate: Array
    covariance: Array
    updates: NDArray[np.intp]


def run_ekf(
    prior: EkfPrior,
    measurements: Sequence[AttitudeMeasurement | None],
    orbit_turns: Rotation,
    wheel_momentum: ArrayLike,
    dt: float,
    inertia: ArrayLike = INERTIA_SEED003,
    process_noise: float = PROCESS_NOISE,
) -> EkfResult:
    """Filter ``N`` epochs ``dt`` apart: update with epoch ``k``'s measurement, then predict.

    Args:
        prior: the estimate at epoch 0, before its measurement.
        measurements: ``N`` measurements of ``C_bo`` (None or empty: propagate only).
        orbit_turns: ``N - 1`` rotations ``O_{k+1} O_k^T`` of the orbit frame.
        wheel_momentum: ``(3,)`` or ``(N, 3)`` wheel momentum (N m s, body).
        dt: step (s).

    Raises:
        InvalidObservationError: inconsistent lengths.
        ConvergenceError: an estimated rate turns more than :data:`MAX_STEP_ANGLE` per step.
    """
    n = len(measurements)
    if len(orbit_turns) != n - 1:
        raise InvalidObservationError(f"need {n - 1} orbit-frame turns, got {len(orbit_turns)}")
    momentum = np.broadcast_to(np.asarray(wheel_momentum, dtype=float), (n, 3))
    step = step_function(float(dt), tuple(np.asarray(inertia, dtype=float).ravel()))
    turns = orbit_turns.as_matrix()
    attitude = prior.attitude.as_matrix()
    rate = np.asarray(prior.rate, dtype=float).copy()
    covariance = np.asarray(prior.covariance, dtype=float).copy()
    attitudes, rates = np.empty((n, 3, 3)), np.empty((n, 3))
    covariances, updates = np.empty((n, 6, 6)), np.zeros(n, dtype=np.intp)
    for k, measurement in enumerate(measurements):
        if measurement is not None and measurement.z.size:
            rate, attitude, covariance, updates[k] = _update(
                measurement, rate, attitude, covariance
            )
        attitudes[k], rates[k], covariances[k] = attitude, rate, covariance
        if k == n - 1:
            break
        if np.linalg.norm(rate) * dt > MAX_STEP_ANGLE:
            raise ConvergenceError(f"estimated rate {np.linalg.norm(rate):.3g} rad/s at epoch {k}")
        next_rate, next_attitude, transition = step(rate, attitude, momentum[k], turns[k])
        rate = next_rate.full().ravel()
        attitude = Rotation.from_matrix(next_attitude.full()).as_matrix()
        transition = transition.full()
        covariance = transition @ covariance @ transition.T + process_noise * np.eye(6)
    return EkfResult(Rotation.from_matrix(attitudes), rates, covariances, updates)


def _update(
    measurement: AttitudeMeasurement, rate: Array, attitude: Array, covariance: Array
) -> tuple[Array, Array, Array, int]:
    """Kalman update (Joseph form) with the rows that have a finite innovation and Jacobian."""
    predicted, jacobian = measurement.predict(Rotation.from_matrix(attitude))
    predicted, jacobian = predicted[0], jacobian[0]
    innovation = measurement.innovation(predicted)
    rows = np.isfinite(innovation) & np.isfinite(jacobian).all(axis=1)
    if not rows.any():
        return rate, attitude, covariance, 0
    h = np.hstack([np.zeros((int(rows.sum()), 3)), jacobian[rows]])
    noise = np.asarray(measurement.noise_covariance, dtype=float)
    noise = (np.diag(noise) if noise.ndim == 1 else noise)[np.ix_(rows, rows)]
    innovation = innovation[rows]
    gain = np.linalg.solve(h @ covariance @ h.T + noise, h @ covariance).T
    correction = gain @ innovation
    keep = np.eye(6) - gain @ h
    covariance = keep @ covariance @ keep.T + gain @ noise @ gain.T
    attitude = Rotation.from_mrp(correction[3:] / 4.0).as_matrix() @ attitude
    return rate + correction[:3], attitude, 0.5 * (covariance + covariance.T), int(rows.sum())
