"""The NLSE of Liu et al. 2023 sec. 3.3: Levenberg-Marquardt over 3-2-1 Euler angles.

``z = [psi, theta, phi]`` (yaw, pitch, roll, Liu et al. 2023 eq. 8) minimises
``F(z) = 1/2 sum_k (y_k - f_k(z))^2 / sigma_k^2`` (eq. 19, weighted by the
``C`` of eq. 22; equal to eq. 19 for ``sigma = 1 dB``) by MINPACK's
Levenberg-Marquardt (``scipy.optimize.least_squares(method="lm")``, eq. 21).
Residuals ``(f_k(z) - y_k) / sigma_k`` and their Jacobian come from one call
of the CasADi function :func:`attopt.formulations.snr_euler.snr_euler_jacobian_function`
(the Jacobian by AD through the same model, eq. 13); MINPACK asks for the
Jacobian at the point whose residuals it just evaluated, so that call is
cached.  Epochs are padded to the buckets of :mod:`attopt.solvers.snr.padding`
(zero residual rows), so the functions are built once per size class.

Convergence: ``least_squares`` status ``> 0`` (``ftol``, ``xtol`` or ``gtol``
met) converges; status 0 (evaluation limit) or non-finite residuals flag the
epoch with the message.  Tolerances are ``1e-12`` (noise-free epochs are
solved to better than 1e-8 rad, ``tests/test_snr_solvers.py``) and
``max_nfev = 200``; a warm-started 20-observation epoch takes a median 8
evaluations (``experiments/benchmarks/snr.py``).  With 1 dB noise the residuals
do not vanish at the optimum, so Levenberg-Marquardt (a Gauss-Newton method)
converges only linearly there and stops on ``ftol`` when the loss no longer
changes in double precision: in a 150-epoch trial it ended within 5e-7 rad of
the IPOPT optimum (exact Hessian, quadratic convergence).

Covariance: eq. 22 in the Euler angles is ``R_z = (J_z^T C J_z)^-1``; with
``J_z = J_b M`` (``J_b`` the Jacobian with respect to the body-frame error,
``M = d delta / d z``) the body-frame covariance is ``M R_z M^T = (J_b^T C J_b)^-1``,
which :mod:`attopt.solvers.snr.fit` evaluates at the solution for every one-step
solver (``tests/test_snr_solvers.py`` checks the mapping).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from attopt.formulations.conventions import attitude_from_euler321, euler321_from_attitude
from attopt.formulations.snr_euler import snr_euler_jacobian_function
from attopt.formulations.snr_problem import SnrEpoch
from attopt.solvers.snr.initialisation import LocalResult
from attopt.solvers.snr.one_step import OneStepSolver
from attopt.solvers.snr.padding import pad_epoch

Array = NDArray[np.float64]


@dataclass(frozen=True)
class LmOptions:
    """Tolerances of ``scipy.optimize.least_squares(method="lm")`` (module docstring)."""

    ftol: float = 1e-12
    xtol: float = 1e-12
    gtol: float = 1e-12
    max_nfev: int = 200


class EulerResiduals:
    """Weighted residuals ``(f_k(z) - y_k) / sigma_k`` and Jacobian, one CasADi call per ``z``."""

    def __init__(self, problem: SnrEpoch, attitude_ref: Array) -> None:
        padded = pad_epoch(problem, attitude_ref)
        self._function = snr_euler_jacobian_function(problem.pattern, padded.size)
        self._args = padded.model_inputs
        self._scale = np.sqrt(padded.weights)
        self._snr = padded.snr
        self._z: Array | None = None
        self._values: tuple[Array, Array] = (np.empty(0), np.empty((0, 3)))

    def _evaluate(self, z: Array) -> tuple[Array, Array]:
        if self._z is None or not np.array_equal(z, self._z):
            snr, jac = self._function(z, *self._args)
            residual = self._scale * (snr.full().ravel() - self._snr)
            self._values = (residual, self._scale[:, None] * jac.full())
            self._z = np.array(z, dtype=float)
        return self._values

    def residuals(self, z: Array) -> Array:
        return self._evaluate(z)[0]

    def jacobian(self, z: Array) -> Array:
        return self._evaluate(z)[1]


def solve_local(problem: SnrEpoch, start: Rotation, options: LmOptions) -> LocalResult:
    """Levenberg-Marquardt from the Euler angles of ``start``."""
    residuals = EulerResiduals(problem, start.as_matrix())
    z0 = euler321_from_attitude(start)
    if not np.all(np.isfinite(residuals.residuals(z0))):
        return LocalResult(start, np.nan, False, "residuals are not finite at the start", 0)
    result = least_squares(
        residuals.residuals,
        z0,
        jac=residuals.jacobian,
        method="lm",
        ftol=options.ftol,
        xtol=options.xtol,
        gtol=options.gtol,
        max_nfev=options.max_nfev,
    )
    finite = bool(np.all(np.isfinite(result.x)) and np.isfinite(result.cost))
    return LocalResult(
        attitude=attitude_from_euler321(*result.x) if finite else start,
        loss=float(result.cost) if finite else np.nan,
        converged=finite and result.status > 0,
        status=str(result.message),
        iterations=int(result.nfev),
    )


@dataclass(frozen=True, repr=False)
class NlseSolver(OneStepSolver):
    """Registry entry ``"nlse"``: Liu et al. 2023's NLSE.

    Initialised by :mod:`attopt.solvers.snr.initialisation`.

    ``iterations`` in the diagnostics are MINPACK's residual evaluations.
    """

    options: LmOptions = field(default_factory=LmOptions)
    name: str = "nlse"
    description: str = "Levenberg-Marquardt on 3-2-1 Euler angles (Liu et al. 2023 eqs. 8, 18-22)"
    status_label: ClassVar[str] = "least_squares(lm)"

    def local_solve(self, problem: SnrEpoch, start: Rotation) -> LocalResult:
        return solve_local(problem, start, self.options)
