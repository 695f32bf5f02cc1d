"""The SNR attitude problem as a CasADi NLP solved by IPOPT (Liu et al. 2023 eqs. 19-20, 22).

The same NLP can be solved by CasADi's SQP method instead (``NlpOptions(solver="sqpmethod")``,
:mod:`attopt.solvers.nlpsol`): the options below are IPOPT's, the default.

Problem.  ``min_v 1/2 sum_k w_k (y_k - f_k(C(v) A_ref))^2`` with ``f_k`` the
SNR model of Liu et al. 2023 eq. 13 (:func:`attopt.formulations.snr_model.snr_function`),
``w_k = 1 / sigma_k^2`` (the ``C`` of eq. 22; 0 for padding rows) and
``C(v)`` :func:`attopt.formulations.snr_model.increment_matrix`, the rotation with
modified Rodrigues parameters ``v / 4``.

Objective (:attr:`NlpSolver.objective`, :data:`attopt.solvers.snr.fit.Objective`).
``"least_squares"`` (registry ``"nlp"``) is the loss above, Liu et al. 2023 eq. 19.
It is the maximum-likelihood estimator only if every measurement is
``N(f_k, sigma_k^2)``; but messages are decoded only when the MEASURED SNR
reaches the threshold ``tau`` (sec. 5.1), so the received ones are truncated
normals, biased upward near ``tau``, and eq. 19's minimiser is biased.
``"truncated_ml"`` (registry ``"nlp_truncated"``) minimises instead their
negative log-likelihood ``sum_k [1/2 w_k (y_k - f_k)^2 + w_k sigma_k^2 log
Phi((f_k - tau) / sigma_k)]`` (:func:`attopt.solvers.snr.fit.truncated_loss`,
:mod:`attopt.formulations.snr_truncation`), with the standard deviations (1 on
padding rows, whose weight 0 removes both terms) and ``tau`` as extra
parameters; its covariance is the inverse Fisher information of the truncated
model at the estimate (:func:`attopt.solvers.snr.fit.fit_at`).  Both objectives share
the builder, parametrisation and options below.  With ``tau`` far below every
SNR the extra term vanishes and the two coincide; with noise-free data the
truncated ML does NOT return the truth (``y = f`` is not what a selection on
the noise produces).

Parametrisation.  The decision variable is the 3-vector ``v``, a local
attitude increment about a reference ``A_ref`` that is re-centred every epoch
(the prior, i.e. the previous epoch's estimate while tracking, or a start of
:mod:`attopt.solvers.snr.initialisation`), so ``v = 0`` at the start and ``v`` is the
body-frame rotation-vector error to first order (``docs/conventions.md``).
Compared with a unit quaternion ``q`` (4 variables) and the equality
constraint ``|q| = 1``:

* unconstrained: IPOPT runs a damped Newton method with line search, with no
  constraint Jacobian, multiplier or feasibility phase, and every iterate is
  a rotation (``C(v)`` is exactly orthogonal), whereas iterates of the
  constrained quaternion leave ``|q| = 1``, where ``A(q)`` is not a rotation
  and ``cos(alpha)`` is not a cosine;
* no gauge freedom: ``q`` and ``-q`` are the same attitude, and normalising
  instead of constraining (``A(q / |q|)``) makes the loss flat along ``q``, a
  singular Hessian that IPOPT must regularise; ``v`` maps one to one to
  attitudes within 360 deg of ``A_ref``;
* smooth and rational in ``v`` (no trigonometric functions), singular only at
  ``|v| -> inf`` (a 360 deg turn), far from any increment a re-centred epoch
  needs;
* three variables, the problem's true dimension, and ``v`` is directly the
  error vector in which the covariance (eq. 22) is expressed.

Euler angles (the NLSE's parametrisation, Liu et al. 2023 eq. 8) would do as well
near nadir pointing but are singular at 90 deg pitch and not body-frame.

Size classes.  The NLP is built once per (pattern, bucket size, options) and
per process (``functools.lru_cache``; ``nlpsol`` objects pickle, but each
worker process builds its own and uses it from one thread).  All epoch data are parameters:
``A_ref`` (9), lines of sight and boresight rows (``3 x size`` each),
``P0`` (size), ``P_n`` (1), weights (size) and SNRs (size), when the antennas'
patterns differ the rows' antennas (size), and for the truncated objective
standard deviations (size) and ``tau`` (1), with epochs padded to the buckets
of :mod:`attopt.solvers.snr.padding`.  IPOPT's gradient and Hessian of the loss are
compiled per size (:mod:`attopt.solvers.snr.nlp_derivatives`: the truncated
likelihood's solve 3-3.5x faster at 256 rows, the least squares' 1.1-1.3x).

IPOPT options (:class:`attopt.solvers.nlpsol.NlpOptions`, shared with the
MAP NLP).  ``print_level 0``, ``sb yes``, no timing print and no CasADi
evaluation warnings: silent (IPOPT itself cuts back steps into
``cos(alpha) <= 0``, where ``lg cos(alpha)`` is undefined).
``nlp_scaling_method = none``: the loss is already in units of the SNR
variance, and IPOPT's gradient-based scaling would make the stopping test
depend on the start.  ``tol = 1e-6`` on the gradient (dB^2/rad): the attitude
error it leaves is about ``tol / lambda_min(F) = tol sigma_max^2`` (``F`` the
Fisher information), ~3e-9 rad for the 2-3 deg (0.05 rad) uncertainty of a
20-observation epoch.  Tighter is not better: once the Newton step is below ~1e-10 rad the
loss change is below the rounding of the loss (~m/2 eps), the line search
backtracks without progress, and with ``tol = 1e-8`` a noisy epoch took 8
instead of 4 iterations; at 1e-9 and 1e-10, 1 of 300 noisy epochs ended at
the acceptable level.  ``max_iter = 100``: a warm-started epoch takes a median
4 iterations (``experiments/benchmarks/snr.py``); converged multi-starts from
45-90 deg away took a median 9 and at most 15 in a 40-epoch trial.
``hessian_approximation = exact`` (CasADi AD of the 3 x 3 Hessian): on the
benchmark's 20-observation epochs L-BFGS needed a median 8 iterations
against 4 and twice the time per epoch.  Multipliers are not computed
(``calc_lam_x``, ``calc_lam_p`` off): the problem has no constraints.

Status (IPOPT's; the SQP method's: :mod:`attopt.solvers.nlpsol`).  Only
``Solve_Succeeded`` converges.  ``Solved_To_Acceptable_Level`` (IPOPT's relaxed
tolerance ``acceptable_tol = 1e-4`` held for 15 iterations) is accepted too and
flagged with ``acceptable = 1`` in the diagnostics.
Anything else (iteration limit, restoration failure, invalid numbers at the
start, ...) flags the epoch invalid with the IPOPT status as reason; no
attitude is returned for it.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import lru_cache

import casadi as ca
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.gain_patterns import AntennaPatterns
from attopt.formulations.kernels import compiled_kernels
from attopt.formulations.snr_model import Pattern, snr_function
from attopt.formulations.snr_problem import SnrEpoch
from attopt.solvers.nlpsol import NlpOptions
from attopt.solvers.snapshot_sequence import EpochEstimate
from attopt.solvers.snr.fit import (
    OBJECTIVES,
    Objective,
    Residuals,
    fit_at,
    objective_loss,
    standardised_residuals,
    truncated_chi_square,
)
from attopt.solvers.snr.initialisation import LocalResult, increment_solve
from attopt.solvers.snr.nlp_derivatives import compiled_derivatives
from attopt.solvers.snr.one_step import OneStepSolver
from attopt.solvers.snr.padding import PaddedEpoch, pad_epoch

Array = NDArray[np.float64]


def _parameter_symbols(
    size: int, objective: Objective = "least_squares", per_antenna: bool = False
) -> dict[str, ca.SX]:
    symbols = {
        "attitude_ref": ca.SX.sym("attitude_ref", 3, 3),
        "los": ca.SX.sym("los_orbit", size, 3),
        "boresight": ca.SX.sym("boresight_body", size, 3),
        "p0": ca.SX.sym("p0_dbw", size),
        "noise": ca.SX.sym("noise_dbw"),
        "weights": ca.SX.sym("weights", size),
        "snr": ca.SX.sym("snr_db", size),
    }
    if per_antenna:
        symbols["antenna"] = ca.SX.sym("antenna", size)
    if objective == "truncated_ml":
        symbols["sigma"] = ca.SX.sym("sigma_db", size)
        symbols["threshold"] = ca.SX.sym("threshold_db")
    return symbols


def parameter_vector(
    padded: PaddedEpoch, attitude_ref: Array, threshold_db: float | None = None
) -> Array:
    """The NLP's parameter vector, in the order of :func:`_parameter_symbols` (column-major).

    With one pattern per antenna the rows' antennas follow; with ``threshold_db``
    (the truncated objective) the padded standard deviations (``1 / sqrt(w_k)``, 1 on
    padding rows) and the threshold.
    """
    parts = [
        attitude_ref.ravel(order="F"),
        padded.los.ravel(order="F"),
        padded.boresight.ravel(order="F"),
        padded.p0,
        [padded.noise],
        padded.weights,
        padded.snr,
    ]
    if padded.antenna is not None:
        parts.append(padded.antenna)
    if threshold_db is not None:
        observed = padded.weights > 0
        sigma = np.ones(padded.size)
        sigma[observed] = padded.weights[observed] ** -0.5
        parts += [sigma, [threshold_db]]
    return np.concatenate(parts)


def nlp_solver(
    pattern: Pattern,
    size: int,
    options: NlpOptions,
    objective: Objective = "least_squares",
) -> ca.Function:
    """The ``nlpsol`` of the ``objective``'s loss for ``size`` rows by ``options.solver`` (built
    once per process and kernel mode; IPOPT's gradient and Hessian compiled:
    :mod:`attopt.solvers.snr.nlp_derivatives`)."""
    return _nlp_solver(pattern, size, options, objective, compiled_kernels())


@lru_cache(maxsize=32)
def _nlp_solver(
    pattern: Pattern, size: int, options: NlpOptions, objective: Objective, compiled: bool
) -> ca.Function:
    if objective not in OBJECTIVES:
        raise ValueError(f"unknown objective {objective!r}; expected one of {OBJECTIVES}")
    v = ca.SX.sym("v", 3)
    p = _parameter_symbols(size, objective, isinstance(pattern, AntennaPatterns))
    data = [p[name] for name in ("los", "boresight", "p0", "noise", "antenna") if name in p]
    predicted = snr_function(pattern, size)(v, p["attitude_ref"], *data)
    loss = objective_loss(
        objective, p["snr"], predicted, p["weights"], p.get("sigma"), p.get("threshold")
    )
    parameters = ca.vertcat(*(ca.vec(symbol) for symbol in p.values()))
    problem = {"x": v, "p": parameters, "f": loss}
    name = f"snr_nlp_{size}" if objective == "least_squares" else f"snr_nlp_{objective}_{size}"
    derivatives = compiled_derivatives(pattern, size, objective, options, p) if compiled else {}
    return ca.nlpsol(name, options.solver, problem, {**options.nlpsol_options(), **derivatives})


def solve_local(
    problem: SnrEpoch,
    start: Rotation,
    options: NlpOptions,
    objective: Objective = "least_squares",
) -> LocalResult:
    """One solve of ``objective`` with ``A_ref = start`` and ``v_0 = 0`` by ``options.solver``
    (:func:`~attopt.solvers.snr.initialisation.increment_solve`)."""
    a_ref = start.as_matrix()
    padded = pad_epoch(problem, a_ref)
    threshold = problem.threshold_db if objective == "truncated_ml" else None
    return increment_solve(
        lambda o: nlp_solver(problem.pattern, padded.size, o, objective),
        options,
        parameter_vector(padded, a_ref, threshold),
        start,
    )


@dataclass(frozen=True, repr=False)
class NlpSolver(OneStepSolver):
    """Registry entries ``"nlp"`` and ``"nlp_truncated"``: the NLP of :attr:`objective`,
    solved by IPOPT or CasADi's SQP method (``options.solver``, :mod:`attopt.solvers.nlpsol`).

    Initialised by :mod:`attopt.solvers.snr.initialisation`; the loss and covariance
    of the estimate are those of :attr:`objective` (:func:`attopt.solvers.snr.fit.fit_at`).
    """

    options: NlpOptions = field(default_factory=NlpOptions)
    objective: Objective = "least_squares"
    name: str = "nlp"
    description: str = "CasADi NLP on the MRP increment, IPOPT (Liu et al. 2023 eqs. 19-20, 22)"

    def __post_init__(self) -> None:
        super().__post_init__()
        if self.objective not in OBJECTIVES:
            raise ValueError(f"unknown objective {self.objective!r}; expected one of {OBJECTIVES}")

    @property
    def status_label(self) -> str:  # the base's class constant, here the options' solver
        return self.options.label

    @property
    def models_the_threshold(self) -> bool:
        """The truncated likelihood models the reception threshold."""
        return self.objective == "truncated_ml"

    def residual_chi_square(self, problem: SnrEpoch, estimate: EpochEstimate) -> float:
        """Twice the eq. 19 loss for the least squares; for the truncated likelihood, whose
        loss is not a chi-square, the residuals standardised by the moments of the
        truncated measurements (:func:`~attopt.solvers.snr.fit.truncated_chi_square`)."""
        if self.objective == "least_squares":
            return super().residual_chi_square(problem, estimate)
        return truncated_chi_square(problem, estimate.attitude)

    def residuals(self, problem: SnrEpoch, estimate: EpochEstimate) -> Residuals:
        """The standardised residuals of :attr:`objective` (those whose squares
        :meth:`residual_chi_square` sums) and their whitened Jacobian."""
        return standardised_residuals(problem, estimate.attitude, self.objective)

    def local_solve(self, problem: SnrEpoch, start: Rotation) -> LocalResult:
        return solve_local(problem, start, self.options, self.objective)

    def estimate_epoch(self, problem: SnrEpoch, prior: Rotation | None) -> EpochEstimate:
        estimate = super().estimate_epoch(problem, prior)
        if self.objective == "least_squares" or estimate.attitude is None:
            return estimate
        # The shared one-step estimate scores with eq. 19 and eq. 22; score the truncated model.
        fit = fit_at(problem, estimate.attitude, self.objective)
        return replace(estimate, covariance=fit.covariance, loss=fit.loss)


TRUNCATED_NLP = NlpSolver(
    objective="truncated_ml",
    name="nlp_truncated",
    description=(
        "CasADi NLP on the MRP increment, IPOPT, maximum likelihood of the threshold-"
        "truncated SNRs (Liu et al. 2023 eqs. 19, 22 with the sec. 5.1 reception threshold)"
    ),
)
"""Registry entry ``"nlp_truncated"``: the NLP of the truncated likelihood (module docstring)."""
