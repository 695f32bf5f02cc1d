"""The extended Kalman filter of Yang et al. 2014 (sec. 5, eqs. 23-33) on DOA measurements.

State (eq. 26): the inertial body rate ``omega_bi`` (body axes, rad/s) and the
attitude ``A = C_bo`` (orbit -> body, ``docs/conventions.md``).

Dynamics (eqs. 23, 24, 27).  Euler's equation with the wheels' angular
momentum ``h`` (body axes, N m s), ``I omega_dot = -omega x (I omega + h)``,
with ``h_dot``, the magnetorquer and the disturbance torques set to zero (the
filter does not know them; ``Q`` absorbs them, as in the paper), and the
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
  :class:`~attopt.formulations.errors.ConvergenceError`.

Error state and transition matrix (eqs. 28-29).  The attitude error is
multiplicative and in the body frame, ``A_true = C(delta) A_est``
(``attopt.formulations.attitude_model.increment_matrix``, the convention of every
filter here), so ``[delta_omega, delta]`` replaces the paper's additive
``[delta_omega, delta q_bo]``; to first order ``delta = 2 delta q_bo``, the
the paper's eq. 29 lower-left block ``0.5 E`` becomes ``E`` and the lower-right
``-[omega x]`` stays, but the quaternion never leaves the unit sphere.  The
transition matrix is the AD Jacobian of the step map above (not the Euler
approximation ``E + A dt`` of eq. 28).

Measurement (eqs. 30-33).  Any
:class:`~attopt.formulations.attitude_measurement.AttitudeMeasurement` of
``C_bo``; its AD Jacobian ``J`` with respect to the body-frame error
``delta`` is the attitude block of ``H`` and the rate block is zero (eq. 32).
Rows without a finite innovation or Jacobian are left out.  The paper's form
is a :class:`~attopt.formulations.attitude_measurement.VectorMeasurement` per epoch:
the measured unit vectors ``S_dr`` of eq. 12 against ``S_o`` of eq. 17, for
which ``J = [(C_bo S_o) x]`` up to the sign of ``delta`` (eq. 33 with ``delta
= 2 delta q``).  The angle form :class:`~attopt.formulations.doa_measurement.DoaMeasurement`
has no prediction for a station the estimate puts behind the array plane, so
from the paper's 98 deg initial error the filter can get stuck with the array
facing away (measured: noise-free, 160-180 deg after 2500 s); the unit
vector has a prediction and a restoring innovation everywhere.

Update.  Since ``H = [0, J]``, the measurement enters only through the
information ``M = J^T R^-1 J`` (``3 x 3``) and ``z = J^T R^-1 nu`` (``nu`` the
innovation); with ``G = P E (I + M P_aa)^-1`` (``E`` selecting the attitude
block, ``P_aa = E^T P E``) the Kalman gain of the paper's EKF satisfies
``K nu = G z``, ``K H = G M E^T`` and ``K R K^T = G M G^T``, so the Joseph form
``(I - K H) P (I - K H)^T + K R K^T`` needs a ``3 x 3`` solve whatever the
number of rows (:func:`update_function`).  An epoch without rows (``M = 0``,
``z = 0``) leaves the estimate exactly unchanged.  The attitude is corrected
multiplicatively, ``A <- C(delta) A``.

Two paths share these pieces and give the same track (to rounding).  The
filter is a :class:`~attopt.solvers.sequential.SequentialFilter`
(:class:`DoaEkfFilter`: its ``predict`` steps the dynamics epoch by epoch,
its ``update`` is the information-form update above, after gating each block
on its innovation when ``gate_probability < 1``), run by the one sequential
loop (:func:`attopt.solvers.sequential.run_filter`, with its lost-track
monitor) over any measurements, about 0.5 ms per epoch.  With unit vectors
only (:class:`~attopt.formulations.attitude_measurement.VectorMeasurement`s
with per-vector sigmas) and no gate, :func:`run_vectors` runs whole epochs
(:func:`epoch_function`) in CasADi, as a compiled kernel, with
``Function.mapaccum`` (:func:`accumulate`), about 30 times faster; the
monitor would never fire there (nothing is gated).  Both keep the history a
fixed-interval smoother needs (:func:`attopt.solvers.filters.rts.rts_smooth`);
the posterior bound of this model is in :mod:`attopt.solvers.doa.eks`.

The pass (:class:`~attopt.formulations.passes.Pass`): uniform epochs ``dt``
apart, the :class:`~attopt.formulations.passes.RigidBody` (inertia, wheel
momentum, orbit frames at the epochs) and a
:class:`~attopt.formulations.passes.Prior` at epoch 0 with a rate, its
covariance of ``[attitude, rate]`` permuted to the filter's ``[delta_omega,
delta]`` (:func:`ekf_prior`).

Noise.  ``Q = q E_6`` per step with ``q = 1e-9`` (sec. 5.2).  ``R`` comes
with the measurement; for MUSIC DOAs the experiment uses ``R_W = sigma^2 E``
per station with ``sigma^2 = tr(J Sigma J^T) / 2``, ``Sigma`` MUSIC's
``(theta, phi)`` covariance (the CRB at the estimate) and ``J`` eq. 12's
Jacobian (:func:`attopt.formulations.doa_array.unit_vector_covariance`): the
isotropic form of eq. 22, whose diagonal the paper fits to simulations.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any, NamedTuple

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import AttitudeMeasurement, body_vectors_model
from attopt.formulations.attitude_model import attitude_model_function, increment_matrix
from attopt.formulations.errors import ConvergenceError, InvalidObservationError
from attopt.formulations.passes import Pass, Prior
from attopt.formulations.rigid_body import angular_acceleration
from attopt.solvers.filters.casadi_pass import accumulate, lower_symmetric
from attopt.solvers.filters.common import (
    FilterOptions,
    gate,
    huber_noise,
    log_det_noise,
    noise_subset,
    solve_noise,
)
from attopt.solvers.results import Track
from attopt.solvers.sequential import (
    NON_FINITE,
    EpochRecord,
    FilterHistory,
    SequentialFilter,
    TrackMonitor,
    filter_result,
)

Array = NDArray[np.float64]

PROCESS_NOISE = 1.0e-9
"""Diagonal of ``Q`` per step (Yang et al. 2014 sec. 5.2)."""
MAX_STEP_ANGLE = 0.1
"""Largest rotation per step (rad) for which the series ``Exp`` is exact to rounding."""


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


def _orthonormalised(matrix: Any) -> Any:
    """One Newton step towards the nearest rotation, ``X (3 I - X^T X) / 2``: removes
    the rounding drift (about 2e-16 per step) so it cannot accumulate over a pass."""
    return 0.5 * matrix @ (3.0 * ca.DM.eye(3) - matrix.T @ matrix)


@lru_cache(maxsize=8)
def step_function(dt: float, inertia: tuple[float, ...]) -> ca.Function:
    """One filter step (module docstring) and its transition matrix by CasADi AD.

    ``(omega, A, h, orbit_turn) -> (omega_next, A_next, Phi)`` with ``A`` and
    ``orbit_turn = O_{k+1} O_k^T`` ``3 x 3``, ``h`` ``3 x 1``; ``Phi`` is the
    ``6 x 6`` Jacobian of ``[omega_next, delta_next]`` with respect to
    ``[omega, delta]`` at ``delta = 0`` (Yang et al. 2014 eqs. 28-29).  With ``E =
    Exp(phi)``, ``phi = -omega_bar dt``, the perturbed attitude times the
    nominal one's transpose is ``Exp(phi + d_phi) C(delta) E^T`` (``A`` and the
    orbit turn cancel), so ``Phi``'s rows are ``[d omega_next / d omega, 0]``
    (AD of the Runge-Kutta step) and ``[J d_phi / d omega, E]`` with ``J`` the
    AD Jacobian of ``vee(Exp(phi + e) E^T)`` at ``e = 0`` (``E [delta x] E^T =
    [(E delta) x]``): the chain rule, about half the instructions of
    differentiating the whole step map at once.  ``A_next`` is re-orthonormalised
    (:func:`_orthonormalised`).
    """
    inertia_matrix = np.reshape(inertia, (3, 3))
    omega = ca.SX.sym("omega", 3)
    attitude = ca.SX.sym("attitude", 3, 3)
    momentum = ca.SX.sym("h", 3)
    orbit_turn = ca.SX.sym("orbit_turn", 3, 3)
    k1 = angular_acceleration(omega, momentum, inertia_matrix)
    k2 = angular_acceleration(omega + 0.5 * dt * k1, momentum, inertia_matrix)
    k3 = angular_acceleration(omega + 0.5 * dt * k2, momentum, inertia_matrix)
    k4 = angular_acceleration(omega + dt * k3, momentum, inertia_matrix)
    omega_next = omega + dt / 6.0 * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    rate_transition = ca.jacobian(omega_next, omega)
    phi = -0.5 * dt * (omega + omega_next)
    turn = rotation_exp(phi)
    e = ca.SX.sym("e", 3)
    exp_jacobian = ca.jacobian(_vee_skew(rotation_exp(phi + e) @ turn.T), e)
    exp_jacobian = ca.substitute(exp_jacobian, e, ca.DM.zeros(3))
    transition = ca.vertcat(
        ca.horzcat(rate_transition, ca.SX(3, 3)),
        ca.horzcat(-0.5 * dt * exp_jacobian @ (ca.DM.eye(3) + rate_transition), turn),
    )
    return ca.Function(
        "doa_ekf_step",
        [omega, attitude, momentum, orbit_turn],
        [omega_next, _orthonormalised(turn @ attitude @ orbit_turn.T), transition],
    )


def propagated_covariance(covariance: Any, transition: Any, process_noise: Any) -> Any:
    """``Phi P Phi^T + q E_6`` (Yang et al. 2014 eq. 28 and sec. 5.2; CasADi, ``6 x 6``)."""
    return lower_symmetric(transition @ covariance @ transition.T + process_noise * ca.DM.eye(6))


@lru_cache(maxsize=8)
def propagate_function(dt: float, inertia: tuple[float, ...]) -> ca.Function:
    """``(omega, A, P, h, orbit_turn, q) -> (omega_next, A_next, P_next, Phi)``.

    :func:`step_function` and the covariance prediction ``Phi P Phi^T + q E_6``
    (Yang et al. 2014 eqs. 27-29, ``Q`` of sec. 5.2).
    """
    rate = ca.SX.sym("omega", 3)
    attitude = ca.SX.sym("attitude", 3, 3)
    covariance = ca.SX.sym("covariance", 6, 6)
    momentum = ca.SX.sym("h", 3)
    orbit_turn = ca.SX.sym("orbit_turn", 3, 3)
    process_noise = ca.SX.sym("q")
    rate_next, attitude_next, transition = step_function(dt, inertia)(
        rate, attitude, momentum, orbit_turn
    )
    return ca.Function(
        "doa_ekf_propagate",
        [rate, attitude, covariance, momentum, orbit_turn, process_noise],
        [
            rate_next,
            attitude_next,
            propagated_covariance(covariance, transition, process_noise),
            transition,
        ],
    )


@lru_cache(maxsize=1)
def update_function() -> ca.Function:
    """``(omega, A, P, M, z) -> (omega+, A+, P+)``: the Kalman update in information form.

    ``M = J^T R^-1 J`` and ``z = J^T R^-1 nu`` of the epoch's rows (module
    docstring); ``H = [0, J]`` (Yang et al. 2014 eqs. 31-33).  Joseph form of ``P+``
    with ``G = P E (I + M P_aa)^-1``; the attitude is corrected by
    ``C(delta)`` (:func:`~attopt.formulations.attitude_model.increment_matrix`, i.e.
    ``Rotation.from_mrp(delta / 4)``) and ``P+`` taken symmetric from its
    lower triangle.
    """
    rate = ca.SX.sym("omega", 3)
    attitude = ca.SX.sym("attitude", 3, 3)
    covariance = ca.SX.sym("covariance", 6, 6)
    information = ca.SX.sym("information", 3, 3)
    residual = ca.SX.sym("residual", 3)
    gain = ca.solve(ca.DM.eye(3) + covariance[3:, 3:] @ information, covariance[3:, :]).T
    correction = gain @ residual
    # Joseph form with K H = [0, L]: (I - K H) P (I - K H)^T + K R K^T, K R K^T = L G^T
    shrink = gain @ information
    kept = covariance - shrink @ covariance[3:, :]
    posterior = kept - kept[:, 3:] @ shrink.T + shrink @ gain.T
    return ca.Function(
        "doa_ekf_update",
        [rate, attitude, covariance, information, residual],
        [
            rate + correction[:3],
            increment_matrix(correction[3:]) @ attitude,
            lower_symmetric(posterior),
        ],
    )


def geodesic_innovation(measured: Any, predicted: Any) -> tuple[Any, Any]:
    """The geodesic innovation of one vector (``VectorMeasurement.innovation``,
    :mod:`attopt.formulations.attitude_measurement`) in CasADi, and whether it is defined
    (not exactly antipodal)."""
    unit = predicted / ca.norm_2(predicted)
    cosine = ca.dot(measured, unit)
    perpendicular = measured - cosine * unit
    sine = ca.norm_2(perpendicular)
    geodesic = ca.if_else(sine > 0, ca.atan2(sine, cosine) / sine * perpendicular, ca.DM.zeros(3))
    return geodesic, ca.logic_or(sine > 0, cosine > 0)


def slot_innovations(
    attitude: ca.SX, body: ca.SX, reference: ca.SX, slots: int
) -> list[tuple[ca.SX, ca.SX, ca.SX]]:
    """Per slot of ``slots`` unit vectors (``body``, ``reference`` ``slots x 3``), its
    geodesic innovation at ``attitude``, its ``3 x 3`` Jacobian
    (:func:`~attopt.formulations.attitude_measurement.body_vectors_model`, eqs. 30-33) and
    whether the innovation is defined (:func:`geodesic_innovation`); CasADi."""
    predicted, jacobian = attitude_model_function(body_vectors_model, ((slots, 3),))(
        attitude, reference
    )
    out = []
    for i in range(slots):
        innovation, defined = geodesic_innovation(body[i, :].T, predicted[3 * i : 3 * i + 3])
        out.append((innovation, jacobian[3 * i : 3 * i + 3, :], defined))
    return out


@lru_cache(maxsize=8)
def vector_information_function(slots: int) -> ca.Function:
    """``(A, body, reference, weight) -> (M, z, rows, cost, log_det_noise)`` of up to
    ``slots`` unit vectors.

    ``body`` and ``reference`` are ``slots x 3`` (Yang et al. 2014 eqs. 12, 17),
    ``weight`` the ``slots`` inverse variances ``1 / sigma^2`` of ``R_W =
    sigma^2 E`` (eq. 22), zero for an absent vector.  The model and its
    Jacobian are :class:`~attopt.formulations.attitude_measurement.VectorMeasurement`'s
    (:func:`~attopt.formulations.attitude_measurement.body_vectors_model`, eqs. 30-33),
    the innovation its geodesic one; a vector with weight zero or an exactly
    antipodal innovation adds nothing.  ``rows`` counts three per vector used,
    as the measurement's rows; ``cost = sum w |nu|^2`` is the weighted squared
    innovation (twice the negative log-likelihood up to a constant) and
    ``log_det_noise = sum -3 log w`` the ``log det R`` of the rows used.
    """
    attitude = ca.SX.sym("attitude", 3, 3)
    body = ca.SX.sym("body", slots, 3)
    reference = ca.SX.sym("reference", slots, 3)
    weight = ca.SX.sym("weight", slots)
    information, residual, rows = ca.SX.zeros(3, 3), ca.SX.zeros(3), ca.SX.zeros(1)
    cost, log_det_noise = ca.SX.zeros(1), ca.SX.zeros(1)
    for i, (innovation, j, defined) in enumerate(
        slot_innovations(attitude, body, reference, slots)
    ):
        used = ca.if_else(defined, weight[i], 0.0)
        information += used * (j.T @ j)
        residual += used * (j.T @ innovation)
        rows += 3.0 * (used > 0)
        cost += used * ca.dot(innovation, innovation)
        log_det_noise -= ca.if_else(used > 0, 3.0 * ca.log(weight[i]), 0.0)
    return ca.Function(
        "doa_vector_information",
        [attitude, body, reference, weight],
        [information, residual, rows, cost, log_det_noise],
    )


@lru_cache(maxsize=8)
def huber_function(slots: int) -> ca.Function:
    """``(A, body, reference, weight, P_aa, k) -> (weight, n_downweighted)``: each vector's
    weight (inverse variance) times its Huber weight ``min(1, k / sqrt(nu^T S^-1 nu))``,
    ``S = J P_aa J^T + R`` at the prior (:func:`~attopt.solvers.filters.common.robust_noise`,
    the rule of the MEKF's and USQUE's updates); ``k = inf``: the weights unchanged."""
    attitude = ca.SX.sym("attitude", 3, 3)
    body = ca.SX.sym("body", slots, 3)
    reference = ca.SX.sym("reference", slots, 3)
    weight = ca.SX.sym("weight", slots)
    covariance = ca.SX.sym("covariance", 3, 3)
    threshold = ca.SX.sym("huber")
    weighted, downweighted = [], ca.SX.zeros(1)
    for i, (innovation, j, _) in enumerate(slot_innovations(attitude, body, reference, slots)):
        variance = ca.if_else(weight[i] > 0, 1.0 / weight[i], 1.0)
        s = j @ covariance @ j.T + variance * ca.DM.eye(3)
        norm = ca.sqrt(ca.dot(innovation, ca.solve(s, innovation)))
        beyond = ca.logic_and(weight[i] > 0, norm > threshold)
        weighted.append(ca.if_else(beyond, weight[i] * threshold / norm, weight[i]))
        downweighted += beyond
    return ca.Function(
        "doa_vector_huber",
        [attitude, body, reference, weight, covariance, threshold],
        [ca.vertcat(*weighted), downweighted],
    )


class EpochSymbols(NamedTuple):
    """CasADi symbols of one epoch, in the order :func:`epoch_function` takes them."""

    rate: ca.SX
    attitude: ca.SX
    covariance: ca.SX
    body: ca.SX
    reference: ca.SX
    weight: ca.SX
    momentum: ca.SX
    orbit_turn: ca.SX
    process_noise: ca.SX


def epoch_symbols(slots: int) -> EpochSymbols:
    """CasADi symbols of one epoch with ``slots`` vectors: ``(omega, A, P, body, reference,
    weight, h, orbit_turn, q)``, shaped as :func:`epoch_function` takes them."""
    return EpochSymbols(
        ca.SX.sym("omega", 3),
        ca.SX.sym("attitude", 3, 3),
        ca.SX.sym("covariance", 6, 6),
        ca.SX.sym("body", slots, 3),
        ca.SX.sym("reference", slots, 3),
        ca.SX.sym("weight", slots),
        ca.SX.sym("h", 3),
        ca.SX.sym("orbit_turn", 3, 3),
        ca.SX.sym("q"),
    )


@lru_cache(maxsize=8)
def epoch_function(dt: float, inertia: tuple[float, ...], slots: int) -> ca.Function:
    """One whole filter epoch on unit vectors: update, then predict (Yang et al. 2014 eqs. 27-33).

    ``(omega^-, A^-, P^-, body, reference, weight, h, orbit_turn, q, k) ->
    (omega^-_next, A^-_next, P^-_next, omega+, A+, P+, Phi, rows, step_angle, nis,
    log_likelihood, n_downweighted)``, composed of :func:`huber_function` (``k``:
    the Huber threshold, ``inf`` for none), :func:`vector_information_function`,
    :func:`update_function` and :func:`propagate_function`; ``step_angle = |omega+| dt``,
    ``nis`` the update's normalised innovation squared (:func:`normalised_innovation`)
    and ``log_likelihood`` its innovations' (:func:`innovation_log_likelihood`).
    """
    x = epoch_symbols(slots)
    threshold = ca.SX.sym("huber")
    weight, downweighted = huber_function(slots)(
        x.attitude, x.body, x.reference, x.weight, x.covariance[3:, 3:], threshold
    )
    information, residual, rows, cost, log_det_noise = vector_information_function(slots)(
        x.attitude, x.body, x.reference, weight
    )
    nis = normalised_innovation(cost, information, residual, x.covariance[3:, 3:])
    log_likelihood = innovation_log_likelihood(
        nis, information, x.covariance[3:, 3:], log_det_noise, rows
    )
    filtered = update_function()(x.rate, x.attitude, x.covariance, information, residual)
    predicted = propagate_function(dt, inertia)(
        *filtered, x.momentum, x.orbit_turn, x.process_noise
    )
    return ca.Function(
        "doa_ekf_epoch",
        [*x, threshold],
        [
            ca.densify(x)
            for x in (
                *predicted[:3],
                *filtered,
                predicted[3],
                rows,
                ca.norm_2(filtered[0]) * dt,
                nis,
                log_likelihood,
                downweighted,
            )
        ],
        {"cse": True},
    )


ROBUST_CHECK = 3.0
"""Huber threshold of the check's robust run (a unit-vector block's whitened norm is about
``sqrt(2)`` for Gaussian noise, :mod:`attopt.solvers.robust`)."""
EKF_FAULTS = FilterOptions(gate_probability=1.0, max_attitude_sigma=np.inf)
"""The EKF's default fault handling: no innovation gate (as in Yang et al. 2014, so the
lost-track monitor never fires) and no validity limit on the attitude sigma (the
paper's prior is 60 deg)."""
DIAGNOSTICS = (
    "rows",
    "n_used",
    "n_gated",
    "n_downweighted",
    "recoveries",
    "nis",
    "nis_dof",
    "log_likelihood",
)
"""Per-epoch counts: measurement rows and blocks used, blocks gated and down-weighted
(``FilterOptions.huber_threshold``), re-acquisitions, the update's normalised innovation
squared, its rows and its innovations' log-likelihood."""
PRIOR_ORDER = np.array([3, 4, 5, 0, 1, 2])
"""The filter's ``[delta_omega, delta]`` from a prior's ``[attitude, rate]``."""
UNIFORM_TOLERANCE = 1e-6
"""Relative spread of the epochs' spacing below which they count as uniform."""


@dataclass(frozen=True)
class EkfDynamics:
    """A pass's rigid-body dynamics as the filter steps them (module docstring).

    Attributes:
        dt: the epoch spacing (s).
        inertia: ``3 x 3`` inertia (kg m^2, eq. 25), flattened (a cache key).
        turns: ``(N - 1, 3, 3)`` orbit-frame turns ``O_{k+1} O_k^T``.
        momentum: ``(N, 3)`` wheel momentum (N m s, body).
    """

    dt: float
    inertia: tuple[float, ...]
    turns: Array
    momentum: Array


def ekf_dynamics(pass_: Pass) -> EkfDynamics:
    """The dynamics of ``pass_`` at its epochs.

    Raises:
        InvalidObservationError: no dynamics, epochs not uniform, or a wheel
            momentum that is neither ``(3,)`` nor ``(N, 3)``.
    """
    if pass_.dynamics is None:
        raise InvalidObservationError("Yang et al. 2014's EKF needs the pass's rigid-body dynamics")
    t, n = pass_.t, len(pass_)
    dt = float((t[-1] - t[0]) / (n - 1)) if n > 1 else 0.0
    if n > 1 and not np.allclose(np.diff(t), dt, rtol=UNIFORM_TOLERANCE, atol=0.0):
        raise InvalidObservationError("Yang et al. 2014's EKF steps uniformly spaced epochs")
    try:
        momentum = np.broadcast_to(pass_.dynamics.wheel_momentum, (n, 3))
    except ValueError:
        raise InvalidObservationError("wheel momentum must be (3,) or (N, 3)") from None
    return EkfDynamics(
        dt,
        tuple(pass_.dynamics.inertia.ravel()),
        pass_.dynamics.orbit_turns.as_matrix().reshape(-1, 3, 3),
        momentum,
    )


def ekf_prior(prior: Prior | None) -> tuple[Rotation, Array, Array]:
    """Attitude, rate and the ``[delta_omega, delta]`` covariance of a prior with a rate
    (its ``[attitude, rate]`` covariance permuted, no arithmetic).

    Raises:
        InvalidObservationError: no prior, or one without a rate.
    """
    if prior is None or prior.rate is None:
        raise InvalidObservationError(
            "Yang et al. 2014's EKF needs a prior with a body rate: "
            "Prior(attitude, (6, 6) covariance of [attitude, rate], rate=...)"
        )
    covariance = prior.covariance[np.ix_(PRIOR_ORDER, PRIOR_ORDER)]
    return prior.attitude, np.asarray(prior.rate, dtype=float), covariance


def ekf_monitor(options: FilterOptions, covariance: Array) -> TrackMonitor:
    """The lost-track monitor: re-acquisition inflates the attitude covariance by
    ``recover_sigma^2 I`` and the rate covariance by the prior's ``covariance`` block."""
    inflation = np.zeros((6, 6))
    inflation[:3, :3] = covariance[:3, :3]
    inflation[3:, 3:] = options.recover_sigma**2 * np.eye(3)
    return TrackMonitor(options.max_rejected_epochs, inflation)


def check_steps(rate: Array, dt: float, first: int = 0) -> None:
    """Raise at the first of the ``(k, 3)`` rates (epochs ``first``, ``first + 1``, ...)
    that turns more than :data:`MAX_STEP_ANGLE` in a step (or is not finite)."""
    bad = np.flatnonzero(~(np.linalg.norm(rate, axis=-1) * dt <= MAX_STEP_ANGLE))
    if bad.size:
        k = int(bad[0])
        raise ConvergenceError(
            f"estimated rate {np.linalg.norm(rate[k]):.3g} rad/s at epoch {first + k}"
        )


def _measurement_information(
    measurement: AttitudeMeasurement,
    attitude: Array,
    attitude_covariance: Array,
    options: FilterOptions,
) -> tuple[Array, Array, dict[str, float]]:
    """``M = J^T R^-1 J``, ``z = J^T R^-1 nu`` of the rows with a finite innovation and
    Jacobian whose block passes the gate at ``options.gate_probability`` (``S = J P_aa J^T
    + R``), ``R`` Huber-weighted at ``options.huber_threshold``
    (:func:`~attopt.solvers.filters.common.huber_noise`), and the counts."""
    predicted, jacobian = measurement.predict(Rotation.from_matrix(attitude))
    predicted, jacobian = predicted[0], jacobian[0]
    innovation = measurement.innovation(predicted)
    rows = np.flatnonzero(np.isfinite(innovation) & np.isfinite(jacobian).all(axis=1))
    noise = np.asarray(measurement.noise_covariance, dtype=float)
    blocks = measurement.blocks
    accepted = gate(
        innovation[rows],
        jacobian[rows].T,
        attitude_covariance,
        noise_subset(noise, rows),
        blocks[rows],
        options.gate_probability,
    )
    gated = np.unique(blocks[rows[~accepted]]).size
    rows = rows[accepted]
    counts = {"n_downweighted": 0.0}
    noise = huber_noise(
        noise,
        rows,
        innovation[rows],
        jacobian[rows].T,
        attitude_covariance,
        blocks[rows],
        options,
        counts,
    )
    weighted = solve_noise(
        noise_subset(noise, rows), np.column_stack([jacobian[rows], innovation[rows]])
    )
    information = jacobian[rows].T @ weighted[:, :3]
    information = 0.5 * (information + information.T)
    residual = jacobian[rows].T @ weighted[:, 3]
    counts |= {"rows": float(rows.size), "n_used": float(np.unique(blocks[rows]).size)}
    counts["n_gated"] = float(gated)
    counts["nis"] = normalised_innovation(
        innovation[rows] @ weighted[:, 3], information, residual, attitude_covariance
    )
    counts["nis_dof"] = float(rows.size)
    if rows.size:
        counts["log_likelihood"] = innovation_log_likelihood(
            counts["nis"],
            information,
            attitude_covariance,
            log_det_noise(noise_subset(noise, rows)),
            rows.size,
        )
    return information, residual, counts


def normalised_innovation(cost: Any, information: Any, residual: Any, covariance: Any) -> Any:
    """``nu^T S^-1 nu`` with ``S = J P_aa J^T + R`` from the information form: ``cost -
    z^T (I + P_aa M)^-1 P_aa z`` (the matrix-inversion lemma), ``cost = nu^T R^-1 nu``,
    ``M = J^T R^-1 J``, ``z = J^T R^-1 nu``; numpy or CasADi (NaN, numpy: no rows)."""
    if isinstance(information, np.ndarray):
        if not np.any(information):
            return np.nan
        return float(
            cost
            - residual
            @ np.linalg.solve(np.eye(3) + covariance @ information, covariance @ residual)
        )
    return cost - residual.T @ ca.solve(
        ca.DM.eye(3) + covariance @ information, covariance @ residual
    )


def innovation_log_likelihood(
    nis: Any, information: Any, covariance: Any, log_det_noise: Any, rows: Any
) -> Any:
    """The log-density of an update's innovations, ``-(nu^T S^-1 nu + log det S + m log
    2 pi) / 2`` with ``S = J P_aa J^T + R`` (``m`` rows), the term one epoch adds to the
    log-likelihood of the measurements in the prediction-error decomposition (Schweppe
    1965); ``log det S = log det R + log det(I + P_aa M)`` (the matrix determinant lemma,
    ``M = J^T R^-1 J``); numpy or CasADi."""
    if isinstance(information, np.ndarray):
        log_det = np.linalg.slogdet(np.eye(3) + covariance @ information)[1]
        return float(-0.5 * (nis + log_det + log_det_noise + rows * np.log(2.0 * np.pi)))
    log_det = ca.log(ca.det(ca.DM.eye(3) + covariance @ information))
    return -0.5 * (nis + log_det + log_det_noise + rows * np.log(2.0 * np.pi))


class DoaEkfFilter(SequentialFilter):
    """The EKF's state and steps (module docstring), for
    :func:`attopt.solvers.sequential.run_filter`.

    State ``rate`` (``omega_bi``), ``attitude`` (``C_bo``; carried as a matrix,
    :meth:`attitude_values`) and the covariance of ``[delta_omega, delta]``,
    starting at epoch 0 with the prior; :meth:`predict` steps the dynamics to
    a later epoch of the pass, :meth:`update` is the update with gating at
    ``options.gate_probability``.

    Raises:
        ConvergenceError: (:meth:`predict`) an estimated rate turns more than
            :data:`MAX_STEP_ANGLE` per step.
    """

    state = ("rate", "attitude")
    diagnostics = DIAGNOSTICS
    smoothable = True

    def __init__(
        self,
        t: ArrayLike,
        dynamics: EkfDynamics,
        prior: tuple[Rotation, Array, Array],
        process_noise: float,
        options: FilterOptions,
    ) -> None:
        attitude, rate, covariance = prior
        self.t = np.asarray(t, dtype=float)
        self.dynamics, self.process_noise, self.options = dynamics, process_noise, options
        self._rate = np.reshape(rate, (3, 1))
        self._attitude = attitude.as_matrix()
        self.covariance = covariance
        self.k = 0

    @property
    def rate(self) -> Array:
        """``omega_bi`` (rad/s, body)."""
        return self._rate[:, 0]

    @property
    def attitude(self) -> Rotation:
        """``C_bo``."""
        return Rotation.from_matrix(self._attitude)

    def attitude_values(self) -> Array:
        return self._attitude

    def predict(self, t: float) -> dict[str, float]:
        dt = self.dynamics.dt
        slack = UNIFORM_TOLERANCE * dt
        stop = int(np.clip(np.searchsorted(self.t, t - slack), 0, self.t.size - 1))
        if not abs(self.t[stop] - t) <= slack or stop < self.k:
            raise InvalidObservationError(f"t = {t:g} s is not a later epoch of the pass")
        propagate = propagate_function(dt, self.dynamics.inertia)
        transition = np.eye(6) if stop == self.k else None
        for j in range(self.k, stop):
            check_steps(self._rate.reshape(1, 3), dt, j)
            self._rate, self._attitude, self.covariance, step = (
                x.full()
                for x in propagate(
                    self._rate,
                    self._attitude,
                    self.covariance,
                    self.dynamics.momentum[j],
                    self.dynamics.turns[j],
                    self.process_noise,
                )
            )
            transition = step if transition is None else step @ transition
        self.transition, self.k = transition, stop
        return {}

    def update(self, measurement: AttitudeMeasurement | None) -> dict[str, float] | None:
        if measurement is None:
            return None
        if not measurement.z.size:
            return {"rows": 0.0, "n_used": 0.0, "n_gated": 0.0}
        information, residual, counts = _measurement_information(
            measurement, self._attitude, self.covariance[3:, 3:], self.options
        )
        self._rate, self._attitude, self.covariance = (
            x.full()
            for x in update_function()(
                self._rate, self._attitude, self.covariance, information, residual
            )
        )
        return counts


def run_vectors(
    t: Array,
    vectors: tuple[Array, Array, Array],
    dynamics: EkfDynamics,
    prior: tuple[Rotation, Array, Array],
    process_noise: float,
    options: FilterOptions,
    method: str,
) -> Track:
    """The filter on a pass of unit vectors with the epoch loop in CasADi (module docstring).

    The same filter as :class:`DoaEkfFilter` without a gate (results equal to
    rounding), at about 15 us per epoch (measured with up to two vectors per
    epoch); the same track, with its history.  ``t`` are the pass's epochs and
    ``vectors`` its unit vectors in slots, ``vector_arrays(*vector_slots(snapshots))``
    (:mod:`attopt.solvers.doa.vector_slots`: they raise
    :class:`~attopt.formulations.errors.InvalidObservationError` for measurements other
    than unit vectors with sigmas, or bad sigmas).

    Raises:
        ConvergenceError: an estimated rate turns more than :data:`MAX_STEP_ANGLE`
            per step (reported for the first such epoch, after the pass).
    """
    body, reference, weight = vectors
    n, slots = weight.shape
    turns = np.concatenate([dynamics.turns, np.eye(3)[None]])
    epoch = epoch_function(dynamics.dt, dynamics.inertia, slots)
    attitude, rate, covariance = prior
    initial = [rate, attitude.as_matrix(), covariance]
    huber = np.inf if options.huber_threshold is None else options.huber_threshold
    inputs = [body, reference, weight, dynamics.momentum, turns, process_noise, huber]
    outputs = accumulate(epoch, 3, initial, inputs, n)
    check_steps(outputs[3][:-1, :, 0], dynamics.dt)
    record = EpochRecord(n, DoaEkfFilter.state, DIAGNOSTICS)
    filtered_attitude = outputs[4]
    record.vector, record.covariance = outputs[3][:, :, 0], outputs[5]
    finite = np.isfinite(filtered_attitude).all(axis=(1, 2)) & np.isfinite(record.vector).all(1)
    finite &= np.isfinite(record.covariance).all(axis=(1, 2))
    bad = np.flatnonzero(~finite)
    stored = n if bad.size == 0 else int(bad[0])
    record.quaternion[:stored] = Rotation.from_matrix(filtered_attitude[:stored]).as_quat()
    record.vector[stored:], record.covariance[stored:] = np.nan, np.nan
    record.reason[stored:] = NON_FINITE
    rows = np.rint(outputs[7][:, 0, 0])
    record.diagnostics["rows"], record.diagnostics["n_used"] = rows, rows / 3.0
    record.diagnostics["nis"] = np.where(rows > 0, outputs[9][:, 0, 0], np.nan)
    record.diagnostics["nis_dof"] = rows
    record.diagnostics["log_likelihood"] = np.where(rows > 0, outputs[10][:, 0, 0], np.nan)
    record.diagnostics["n_downweighted"] = outputs[11][:, 0, 0]
    history = FilterHistory(
        predicted_attitude=np.concatenate([initial[1][None], outputs[1][:-1]]),
        predicted_vector=np.concatenate([np.reshape(rate, (1, 3)), outputs[0][:-1, :, 0]]),
        predicted_covariance=np.concatenate([covariance[None], outputs[2][:-1]]),
        transition=np.concatenate([np.eye(6)[None], outputs[6][:-1]]),
        filtered_attitude=filtered_attitude,
        filtered_vector=record.vector,
        filtered_covariance=record.covariance,
    )
    return filter_result(method, record, options, t, history, np.zeros(n, dtype=bool))
