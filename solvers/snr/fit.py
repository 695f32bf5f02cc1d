"""Loss and covariance of an attitude for an SNR epoch, shared by every SNR solver.

* Loss: ``F = 1/2 sum_k (y_k - f_k(A))^2 / sigma_k^2``, Liu et al. 2023 eq. 19
  weighted by the ``C`` of eq. 22 (with ``sigma = 1 dB`` exactly eq. 19).
* Covariance: ``R = (J^T C J)^-1`` (Liu et al. 2023 eq. 22) with ``J`` the Jacobian of
  the predicted SNRs with respect to the body-frame rotation-vector error at
  ``A`` (``docs/conventions.md``), i.e. the Cramer-Rao bound of the epoch
  evaluated at the estimate instead of the truth
  (:func:`attopt.formulations.snr_model.fisher_information`,
  :func:`attopt.formulations.snr_model.cramer_rao_bound`; infinite along unobservable
  directions).  ``J`` is the CasADi AD Jacobian
  :func:`attopt.formulations.snr_model.snr_jacobian_function` at ``v = 0``, the one
  :func:`attopt.formulations.snr_model.predict_snr` wraps, called directly (on the
  padded bucket) because ``predict_snr`` rejects observations beyond the main
  lobe, and at a noisy estimate an observation near the lobe edge may fall
  just outside it while it still is part of the loss that was minimised.  The
  number of such observations is reported (:attr:`Fit.outside_lobe`).

Objectives (:data:`Objective`).  ``"least_squares"`` is the above (Liu et al. 2023
eqs. 19, 22).  ``"truncated_ml"`` models the reception threshold
(:mod:`attopt.formulations.snr_truncation`): the loss is the negative log-likelihood
of the received, threshold-truncated measurements,
``sum_k [1/2 w_k (y_k - f_k)^2 + log Phi((f_k - tau) / sigma_k)]`` (up to a
constant), and the covariance the inverse of its Fisher information, eq. 22
with row ``k`` weighted by
:func:`~attopt.formulations.snr_truncation.truncated_information_factor` at the
predicted ``f_k``, through the same AD Jacobian.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any, Literal

import casadi as ca
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation
from scipy.special import log_ndtr, ndtri_exp

from attopt.formulations.snr_model import (
    cramer_rao_bound,
    fisher_information,
    observation_mask,
    snr_jacobian_function,
)
from attopt.formulations.snr_problem import SnrEpoch
from attopt.formulations.snr_truncation import (
    truncated_fisher_information,
    truncated_information_factor,
    truncated_nll,
)
from attopt.solvers.snr.padding import pad_epoch

Array = NDArray[np.float64]

Objective = Literal["least_squares", "truncated_ml"]
"""The likelihood a one-step solver maximises (module docstring)."""
OBJECTIVES: tuple[Objective, ...] = ("least_squares", "truncated_ml")
SELECTION_BIAS_DIAGNOSTICS = ("selection_bias_x", "selection_bias_y", "selection_bias_z")
"""Diagnostics of a widened estimate: the selection bias ``d`` its covariance covers (rad,
body frame, :func:`widened`); NaN where it is not widened."""


def snr_loss(measured: Any, predicted: Any, weights: Any) -> Any:
    """``1/2 sum_k w_k (y_k - f_k)^2`` (Liu et al. 2023 eq. 19, ``w_k = 1/sigma_k^2``), numpy
    or CasADi."""
    residual = measured - predicted
    if isinstance(residual, ca.SX | ca.MX | ca.DM):
        return 0.5 * ca.dot(weights, residual * residual)
    return 0.5 * float(np.dot(weights, residual * residual))


def truncated_loss(
    measured: Any, predicted: Any, weights: Any, sigma_db: Any, threshold_db: Any
) -> Any:
    """``sum_k w_k sigma_k^2 l_k``, ``l_k`` the truncated negative log-likelihood.

    ``l_k`` is :func:`~attopt.formulations.snr_truncation.truncated_nll`.

    ``w_k sigma_k^2`` is 1 for an observation and 0 for a padding row
    (:mod:`attopt.solvers.snr.padding`), so a padding row contributes nothing to
    either term; on observations this is the truncated negative
    log-likelihood ``sum_k [1/2 w_k (y_k - f_k)^2 + log Phi((f_k - tau) / sigma_k)]``.
    numpy or CasADi (``sigma_db`` must be finite and positive on padding rows too).
    """
    terms = weights * sigma_db**2 * truncated_nll(measured, predicted, sigma_db, threshold_db)
    if isinstance(terms, ca.SX | ca.MX | ca.DM):
        return ca.sum1(terms)
    return float(np.sum(terms))


def objective_loss(
    objective: Objective,
    measured: Any,
    predicted: Any,
    weights: Any,
    sigma_db: Any,
    threshold_db: Any,
) -> Any:
    """The loss of ``objective``: :func:`snr_loss` or :func:`truncated_loss` (numpy or CasADi)."""
    if objective == "least_squares":
        return snr_loss(measured, predicted, weights)
    if objective == "truncated_ml":
        return truncated_loss(measured, predicted, weights, sigma_db, threshold_db)
    raise ValueError(f"unknown objective {objective!r}; expected one of {OBJECTIVES}")


def model_at(problem: SnrEpoch, attitude: Rotation) -> tuple[Array, Array]:
    """Predicted SNR ``(m,)`` and its Jacobian ``(m, 3)`` (dB/rad, body-frame error),
    read-only.

    An epoch's estimate, its covariance (:func:`fit_at`), its residual test and its
    threshold bias evaluate the model at the same attitude three or four times: the
    last evaluation (per thread) is returned again for the same ``problem`` and
    ``attitude`` objects (both immutable)."""
    last = getattr(_LAST_MODEL, "value", None)
    if last is not None and last[0] is problem and last[1] is attitude:
        return last[2], last[3]
    a = attitude.as_matrix()
    padded = pad_epoch(problem, a)
    snr, jac = snr_jacobian_function(problem.pattern, padded.size)(
        np.zeros(3), a, *padded.model_inputs
    )
    predicted, jacobian = snr.full().ravel()[: problem.m], jac.full()[: problem.m]
    predicted.flags.writeable = jacobian.flags.writeable = False
    _LAST_MODEL.value = (problem, attitude, predicted, jacobian)
    return predicted, jacobian


_LAST_MODEL = threading.local()


def truncated_chi_square(problem: SnrEpoch, attitude: Rotation) -> float:
    """``sum_k z_k^2`` at ``attitude``, ``z_k`` the normal score of measurement ``y_k``
    under the truncated model: ``z_k = Phi^-1(F_k(y_k))`` with ``F_k`` the CDF of
    ``N(f_k, sigma_k^2)`` truncated below at the threshold (the law of a received SNR,
    :mod:`attopt.formulations.snr_truncation`).  The scores are exactly standard normal
    when the model is right, so the sum is about chi-square with ``m - 3`` degrees of
    freedom: the residual test of ``nlp_truncated``.  Computed from the upper tail, ``z_k
    = -Phi^-1(Phi(-r_k) / Phi(-a_k))`` with ``r_k = (y_k - f_k) / sigma_k`` and ``a_k =
    (tau - f_k) / sigma_k``, in logarithms (``scipy.special.log_ndtr``, ``ndtri_exp``), so
    a far outlier keeps its score."""
    predicted, _ = model_at(problem, attitude)
    z = truncated_scores(problem, predicted)
    return float(np.sum(z * z))


def truncated_scores(problem: SnrEpoch, predicted: Array) -> Array:
    """The normal scores ``z_k`` of :func:`truncated_chi_square` at the predicted SNRs."""
    sigma = np.asarray(problem.sigma_db, dtype=float)
    r = (problem.snr_db - predicted) / sigma
    a = (problem.threshold_db - predicted) / sigma
    return -ndtri_exp(log_ndtr(-r) - log_ndtr(-a))


@dataclass(frozen=True)
class Residuals:
    """An epoch's standardised residuals at an attitude and their linearisation.

    Attributes:
        scores: ``(m,)`` residuals standardised to unit variance under the objective's
            model: ``(y_k - f_k) / sigma_k`` for the least squares, the normal scores of
            :func:`truncated_chi_square` for the truncated likelihood; their sum of
            squares is the residual test's chi-square.
        jacobian: ``(m, 3)`` the whitened Jacobian ``sqrt(I_k) d f_k / d delta`` (``I_k``
            the Fisher information of measurement ``k`` about ``f_k``: ``1 / sigma_k^2``,
            or :func:`~attopt.formulations.snr_truncation.truncated_information_factor`
            ``/ sigma_k^2``), so ``jacobian^T jacobian`` is the inverse covariance of
            :func:`fit_at`.
    """

    scores: Array
    jacobian: Array


def standardised_residuals(
    problem: SnrEpoch, attitude: Rotation, objective: Objective = "least_squares"
) -> Residuals:
    """The :class:`Residuals` of ``objective`` at ``attitude`` for ``problem``."""
    predicted, jac = model_at(problem, attitude)
    sigma = np.asarray(problem.sigma_db, dtype=float)
    if objective == "truncated_ml":
        scores = truncated_scores(problem, predicted)
        factor = truncated_information_factor(predicted, sigma, problem.threshold_db)
        scale = np.sqrt(factor) / sigma
    else:
        scores = (problem.snr_db - predicted) / sigma
        scale = 1.0 / sigma
    return Residuals(scores, scale[:, None] * jac)


@dataclass(frozen=True)
class Fit:
    """What an attitude explains of an epoch.

    Attributes:
        loss: the objective's loss: Liu et al. 2023 eq. 19 weighted by ``C``, or the
            truncated negative log-likelihood (see the module docstring).
        covariance: ``(3, 3)`` inverse Fisher information of the objective's
            model (eq. 22, or eq. 22 of the truncated measurements), rad^2, body frame.
        outside_lobe: observations beyond their pattern's main lobe at the attitude.
    """

    loss: float
    covariance: Array
    outside_lobe: int


def fit_at(problem: SnrEpoch, attitude: Rotation, objective: Objective = "least_squares") -> Fit:
    """Loss and covariance (eq. 22, or its truncated-model form) of ``attitude`` for ``problem``."""
    predicted, jac = model_at(problem, attitude)
    # On a validated epoch observation_mask is False only beyond the main lobe.
    in_lobe = observation_mask(
        attitude.as_matrix(),
        problem.unit_los,
        problem.boresight_rows,
        problem.pattern,
        problem.pattern_antenna,
    )
    sigma, threshold = problem.sigma_db, problem.threshold_db
    if objective == "truncated_ml":
        fisher = truncated_fisher_information(jac, predicted, sigma, threshold)
    else:
        fisher = fisher_information(jac, sigma)
    loss = objective_loss(objective, problem.snr_db, predicted, problem.weights, sigma, threshold)
    return Fit(
        loss=loss,
        covariance=cramer_rao_bound(fisher),
        outside_lobe=int(np.count_nonzero(~in_lobe)),
    )


def threshold_bias(problem: SnrEpoch, predicted: Array) -> Array:
    """The mean error of each received SNR that the reception threshold selects:
    ``b_k = sigma_k phi(a_k) / (1 - Phi(a_k))``, ``a_k = (tau - f_k) / sigma_k`` at the
    predicted ``f_k`` (the mean of a normal truncated below ``tau``, Johnson, Kotz and
    Balakrishnan 1994 eq. 13.134), which Liu et al. 2023 eq. 19 does not model."""
    sigma = np.asarray(problem.sigma_db, dtype=float)
    a = (problem.threshold_db - predicted) / sigma
    return sigma * np.exp(_log_normal_pdf(a) - log_ndtr(-a))


_LOG_SQRT_2PI = np.log(np.sqrt(2 * np.pi))


def _log_normal_pdf(x: Array) -> Array:
    """``log phi(x)`` of the standard normal: the formula of ``scipy.stats.norm.logpdf``
    (and with ``log_ndtr(-x)`` its ``logsf``), the same numbers, called directly because
    every SNR epoch evaluates :func:`threshold_bias`, where ``scipy.stats``'s argument
    handling costs about 250 us a call against 10-17 us."""
    return -(x**2) / 2.0 - _LOG_SQRT_2PI


def least_squares_shifts(
    jacobian: Array, sigma_db: Array | float, covariance: Array, errors: Array
) -> Array:
    """``(k, 3)``: the attitude error ``P J^T C e`` that each row ``e`` of the SNR errors
    ``errors`` (``(k, m)`` or ``(m,)``, dB) causes through the least-squares gain
    (Liu et al. 2023 eq. 22: ``P = (J^T C J)^-1``, ``C = diag(1 / sigma_k^2)``; ``J`` the
    ``(m, 3)`` SNRs' Jacobian at the estimate, :func:`model_at`); not finite along an
    unobservable rotation."""
    weighted = np.atleast_2d(errors) / np.asarray(sigma_db, dtype=float) ** 2
    with np.errstate(invalid="ignore"):
        return (np.asarray(covariance, dtype=float) @ (jacobian.T @ weighted.T)).T


def common_offsets(problem: SnrEpoch, sigma_db: float) -> Array:
    """``(a, m)``: one row per antenna heard in the epoch, ``sigma_db`` on that
    antenna's SNRs and 0 elsewhere: the SNR errors of an offset of one standard
    deviation shared by every transmitter the antenna hears
    (:attr:`~attopt.solvers.snr.driver.SnrSolver.power_offset_common_sigma_db`)."""
    heard = np.unique(problem.antenna)
    return sigma_db * (problem.antenna[None, :] == heard[:, None]).astype(float)


def widened(covariance: Array, shifts: Array) -> Array:
    """``P + sum_i d_i d_i^T`` over the attitude errors ``d_i`` (rows of ``shifts``, or
    one ``(3,)`` bias): the mean squared error matrix of an estimate of bias ``d``, or
    its covariance under independent zero-mean errors of those shapes (``P`` itself
    when a ``d_i`` is not finite)."""
    d = np.atleast_2d(shifts)
    if not np.all(np.isfinite(d)):
        return covariance
    return covariance + d.T @ d
