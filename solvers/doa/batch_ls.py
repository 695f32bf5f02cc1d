"""Whole-pass batch least squares over Yang et al. 2014's deterministic dynamics (``Q = 0``).

The truth of Yang et al. 2014's problem is torque free with known inertia, wheel
momentum and orbit (sec. 4.2, eqs. 23-25), so the whole pass is fixed by the
state at epoch 0, ``x_0 = [omega_bi, C_bo]``.  Its maximum-likelihood
estimate minimises the weighted squared innovations of every unit vector of
the pass (eqs. 12, 17, 22, 30-33)::

    J(x_0) = sum_k sum_i w_ki |nu_ki(x_k(x_0))|^2,   x_{k+1} = f(x_k),

with ``f`` the EKF's step map (:func:`attopt.solvers.doa.ekf.step_function`, eq. 27)
and ``nu`` the geodesic innovation of the filters.  The Cramer-Rao bound of
this problem is the ``crb_*`` column of experiment ``doa-ground`` (the EKF's
posterior bound with ``Q = 0``, :func:`attopt.solvers.doa.eks.posterior_bound_ekf`),
so this estimator shows how much of the gap between the paper's EKF and the
bound an estimator can close.

Gauss-Newton with Levenberg-Marquardt damping on the error state ``delta_0 =
[delta_omega, delta]`` of epoch 0 (``A_true = C(delta) A``, the EKF's
convention).  One pass (:func:`pass_function`, run by
:func:`~attopt.solvers.filters.casadi_pass.accumulate`) propagates the trajectory
and the sensitivity ``S_k = d delta_k / d delta_0`` (``S_{k+1} = Phi_k S_k``,
``Phi_k`` the step's AD transition matrix, eq. 28) and sums the normal
equations ``N = sum S_k^T E M_k E^T S_k``, ``g = sum S_k^T E z_k`` and the
cost ``J``, with ``M = J^T R^-1 J`` and ``z = J^T R^-1 nu`` of the epoch's
vectors (:func:`~attopt.solvers.doa.ekf.vector_information_function`) and ``E``
selecting the attitude block.  The step solves ``(N + lambda diag N) delta_0
= g``; it is accepted if the next pass's cost is lower (then ``lambda``
shrinks tenfold), else refused (``lambda`` grows tenfold).  Converged when the
accepted step's Mahalanobis length ``sqrt(delta_0^T N delta_0)`` is below
``tolerance`` (the step is a negligible fraction of the estimate's standard
deviation); such a step is taken without the cost test, which rounding
decides at the minimum.  A step whose trajectory turns faster than the EKF's
step limit is refused like one that raises the cost.  The covariance of the
estimate at epoch ``k`` is ``S_k N^-1 S_k^T`` at the solution: the
Cramer-Rao bound evaluated at the estimate.

No prior enters: the pass's information dwarfs any prior (the ``crb_*``
column's 60 deg, 0.5 deg/s prior changes it by less than 1e-4 relative), and
the start only has to lie in the basin of the minimum (the first epoch of the
RTS pass over the EKF, ``rts_yang2014``: registry estimator ``bls_yang2014``,
:mod:`attopt.solvers.doa.estimators`).  The result is a
:class:`~attopt.solvers.results.Track` (state ``("rate", "attitude")``)
with the pass's :class:`BatchLsReport`.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_model import increment_matrix
from attopt.formulations.errors import ConvergenceError, ModelMismatchError, UnobservableError
from attopt.solvers.chi_square import chi_square_tail
from attopt.solvers.doa.ekf import (
    EkfDynamics,
    check_steps,
    epoch_symbols,
    step_function,
    vector_information_function,
)
from attopt.solvers.doa.vector_slots import vector_arrays
from attopt.solvers.filters.casadi_pass import accumulate
from attopt.solvers.filters.common import CONSISTENCY_FALSE_ALARM, CONSISTENCY_WINDOW
from attopt.solvers.results import Track
from attopt.solvers.sequential import inconsistent_epochs

Array = NDArray[np.float64]

MAX_CONDITION = 1e14
"""Largest condition number of the normal matrix ``N`` (scaled to unit diagonal) for
which the initial state counts as observable."""


@dataclass(frozen=True)
class BatchLsOptions:
    """Gauss-Newton settings (module docstring).

    Attributes:
        tolerance: Mahalanobis length of the last step at convergence.
        max_iterations: passes before giving up.
        flag_unconverged: flag every epoch invalid when the solve did not
            converge; ``False`` keeps the estimates valid (the track's
            :class:`BatchLsReport` says whether it converged).
        consistency_window: epochs with vectors whose residuals at the solution
            (``sum w |nu|^2`` over their rows) are summed in the filters' windowed
            chi-square test (:func:`~attopt.solvers.sequential.inconsistent_epochs`;
            conservative: the fit absorbs six degrees of freedom of the pass and a unit
            vector's three rows carry two); a failing epoch is flagged
            ``inconsistent``; 0 turns the test off.
        consistency_false_alarm: that test's false-alarm probability, also the level
            of the report's whole-pass verdict (``consistent``).
    """

    tolerance: float = 1e-6
    max_iterations: int = 20
    flag_unconverged: bool = True
    consistency_window: int = CONSISTENCY_WINDOW
    consistency_false_alarm: float = CONSISTENCY_FALSE_ALARM


@dataclass(frozen=True)
class BatchLsReport:
    """How the whole-pass solve went.

    Attributes:
        cost: the final ``J`` (weighted squared innovations).
        rows: number of vector components (3 per vector) in ``J``.
        iterations: passes run (each one propagation of the whole trajectory).
        converged: whether the last accepted step met the tolerance.
        reason: empty if converged, else why not.
        chi_square_p: the whole-pass test, ``P(chi2(rows - 6) >= J)``: ``J`` is
            chi-square with the rows less the six parameters at the minimum of a
            consistent pass (Bar-Shalom, Li and Kirubarajan 2001, ch. 3;
            conservative for unit vectors, whose three rows carry two).
        consistent: ``chi_square_p >= consistency_false_alarm``.
    """

    cost: float
    rows: int
    iterations: int
    converged: bool
    reason: str
    chi_square_p: float
    consistent: bool


@lru_cache(maxsize=8)
def pass_function(dt: float, inertia: tuple[float, ...], slots: int) -> ca.Function:
    """One epoch of a Gauss-Newton pass (module docstring).

    ``(omega, A, S, N, g, J, body, reference, weight, h, orbit_turn) ->
    (omega_next, A_next, S_next, N, g, J, rows)``: the epoch's vectors are
    added to the normal equations and the cost at ``(omega, A)``, then the
    state and the sensitivity ``S`` are stepped to the next epoch.
    """
    x = epoch_symbols(slots)
    sensitivity = ca.SX.sym("sensitivity", 6, 6)
    normal = ca.SX.sym("normal", 6, 6)
    gradient = ca.SX.sym("gradient", 6)
    cost = ca.SX.sym("cost")
    information, residual, rows, epoch_cost, _ = vector_information_function(slots)(
        x.attitude, x.body, x.reference, x.weight
    )
    attitude_rows = sensitivity[3:, :]
    rate_next, attitude_next, transition = step_function(dt, inertia)(
        x.rate, x.attitude, x.momentum, x.orbit_turn
    )
    return ca.Function(
        "doa_batch_ls_epoch",
        [x.rate, x.attitude, sensitivity, normal, gradient, cost, *x[3:8]],
        [
            ca.densify(y)
            for y in (
                rate_next,
                attitude_next,
                transition @ sensitivity,
                normal + attitude_rows.T @ information @ attitude_rows,
                gradient + attitude_rows.T @ residual,
                cost + epoch_cost,
                rows,
            )
        ],
        {"cse": True},
    )


@dataclass(frozen=True)
class _Pass:
    """A Gauss-Newton pass from one initial state: trajectory, sensitivities, sums."""

    rate: Array
    attitude: Array
    sensitivity: Array
    normal: Array
    gradient: Array
    cost: float
    rows: int
    epoch_cost: Array
    """``(N,)`` each epoch's ``sum w |nu|^2``."""
    epoch_rows: Array
    """``(N,)`` each epoch's rows in it."""


def batch_least_squares(
    start_attitude: Rotation,
    start_rate: ArrayLike,
    vectors: tuple[ArrayLike, ArrayLike, ArrayLike],
    dynamics: EkfDynamics,
    t: ArrayLike,
    options: BatchLsOptions,
    method: str,
) -> Track:
    """Whole-pass least-squares estimate of the dynamics' initial state (module docstring).

    Args:
        start_attitude, start_rate: the start at epoch 0 (``C_bo``,
            ``omega_bi`` in rad/s), in the basin of the minimum.
        vectors: ``(body, reference, sigma)``, ``(N, S, 3)``, ``(N, S, 3)``,
            ``(N, S)`` (NaN body rows absent;
            :func:`~attopt.solvers.doa.vector_slots.vector_slots`).
        dynamics: the pass's dynamics at its ``N`` epochs ``t``.
        options: tolerance, passes and flagging.
        method: the track's method.

    Returns:
        The trajectory from the estimated ``x_0`` at every epoch with the
        covariance ``S_k N^-1 S_k^T`` of ``[delta_omega, delta]``, and the
        :class:`BatchLsReport`; all epochs flagged if not converged (unless
        ``options.flag_unconverged`` is off).

    Raises:
        InvalidObservationError: inconsistent shapes or bad sigmas.
        UnobservableError: the vectors do not determine the initial state
            (normal matrix singular to :data:`MAX_CONDITION`).
        ConvergenceError: the start's trajectory turns more than
            :data:`~attopt.solvers.doa.ekf.MAX_STEP_ANGLE` per step.
    """
    body, reference, weight = vector_arrays(*vectors)
    n, slots = weight.shape
    dt, momentum = dynamics.dt, dynamics.momentum
    turns = np.concatenate([dynamics.turns, np.eye(3)[None]])
    epoch = pass_function(dt, dynamics.inertia, slots)

    def run(rate: Array, attitude: Array) -> _Pass:
        outputs = accumulate(
            epoch,
            6,
            [rate, attitude, np.eye(6), np.zeros((6, 6)), np.zeros(6), 0.0],
            [body, reference, weight, momentum, turns],
            n,
        )
        rates = np.concatenate([[rate], outputs[0][:-1, :, 0]])
        check_steps(rates, dt)
        return _Pass(
            rate=rates,
            attitude=np.concatenate([[attitude], outputs[1][:-1]]),
            sensitivity=np.concatenate([[np.eye(6)], outputs[2][:-1]]),
            normal=outputs[3][-1],
            gradient=outputs[4][-1, :, 0],
            cost=float(outputs[5][-1, 0, 0]),
            rows=int(np.rint(outputs[6][:, 0, 0].sum())),
            epoch_cost=np.diff(outputs[5][:, 0, 0], prepend=0.0),
            epoch_rows=outputs[6][:, 0, 0],
        )

    current = run(np.asarray(start_rate, dtype=float).reshape(3), start_attitude.as_matrix())
    _check_observable(current.normal)
    damping, iterations, converged = 1e-3, 1, False
    while iterations < options.max_iterations:
        normal = current.normal
        step = np.linalg.solve(normal + damping * np.diag(np.diag(normal)), current.gradient)
        final = bool(np.sqrt(step @ normal @ step) < options.tolerance)
        try:
            candidate = run(
                current.rate[0] + step[:3],
                np.asarray(increment_matrix(step[3:])) @ current.attitude[0],
            )
        except ConvergenceError:  # the step spins the body up beyond the step limit
            candidate = None
        iterations += 1
        if candidate is not None and (final or candidate.cost <= current.cost):
            # a negligible step is taken without the cost test (rounding decides it)
            current, damping, converged = candidate, damping / 10.0, final
            if final:
                break
        else:
            damping *= 10.0
    _check_observable(current.normal)
    spread = np.linalg.inv(current.normal)
    covariance = current.sensitivity @ spread @ np.swapaxes(current.sensitivity, 1, 2)
    covariance = 0.5 * (covariance + np.swapaxes(covariance, 1, 2))
    unconverged = "" if converged else f"not converged in {options.max_iterations} passes"
    reason = np.full(n, unconverged, dtype=object)
    p = float(chi_square_tail(current.cost, current.rows - 6)) if current.rows > 6 else np.nan
    report = BatchLsReport(
        current.cost,
        current.rows,
        iterations,
        converged,
        unconverged,
        p,
        bool(p >= options.consistency_false_alarm),
    )
    valid = np.full(n, converged or not options.flag_unconverged)
    error = np.full(n, None, dtype=object)
    error[~valid] = ConvergenceError
    if converged and options.consistency_window:
        nis = np.where(current.epoch_rows > 0, current.epoch_cost, np.nan)
        inconsistent = inconsistent_epochs(
            nis,
            current.epoch_rows,
            options.consistency_window,
            options.consistency_false_alarm,
        )
        reason[inconsistent] = (
            f"inconsistent: the residuals at the solution of the last "
            f"{options.consistency_window} epochs with vectors fail the chi-square test at "
            f"{options.consistency_false_alarm:g}"
        )
        error[inconsistent] = ModelMismatchError
        valid &= ~inconsistent
    return Track(
        method=method,
        quaternion=np.where(
            valid[:, None], Rotation.from_matrix(current.attitude).as_quat(), np.nan
        ),
        covariance=np.where(valid[:, None, None], covariance[:, 3:, 3:], np.nan),
        loss=np.where(current.epoch_rows > 0, current.epoch_cost, np.nan),
        valid=valid,
        reason=np.where(valid, "", reason).astype(object),
        error=error,
        diagnostics={"nis": current.epoch_cost, "nis_dof": current.epoch_rows},
        t=np.array(t, dtype=float),
        rate=np.where(valid[:, None], current.rate, np.nan),
        state_covariance=np.where(valid[:, None, None], covariance, np.nan),
        state=("rate", "attitude"),
        report=report,
    )


def _check_observable(normal: Array) -> None:
    """Raise :class:`UnobservableError` unless ``normal`` is well conditioned."""
    scale = np.sqrt(np.diag(normal))
    if not np.all(scale > 0.0):
        raise UnobservableError("the vectors do not determine the initial state")
    condition = np.linalg.cond(normal / np.outer(scale, scale))
    if not condition < MAX_CONDITION:
        raise UnobservableError(
            f"the vectors do not determine the initial state (condition {condition:.3g})"
        )
