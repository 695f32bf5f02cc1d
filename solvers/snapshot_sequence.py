"""The epoch loop of the iterative snapshot estimators: validate, start, estimate, assemble.

A snapshot estimator that solves one epoch at a time (the SNR solvers, the
GEO boresight estimators, the MAP NLP) supplies a validation rule and an
estimate of one validated epoch from an optional start;
:func:`solve_in_sequence` turns that into a :class:`~attopt.solvers.results.Track`:

* an epoch without measurement (``None``) or one its validation rejects is
  flagged with the reason and the exception a single-epoch call raises;
* an estimate that did not converge (:attr:`EpochEstimate.failure`) is
  flagged with its reason, never returned as an attitude; its diagnostics
  are kept (e.g. the iterations IPOPT spent before giving up), those of
  epochs rejected before solving are NaN;
* an estimate whose residuals fail their chi-square test (:func:`residual_test`,
  for estimators whose loss is a weighted least-squares one) is flagged ``model
  mismatch`` by the estimator, also never returned as an attitude;
* with :class:`WarmStart` enabled each epoch starts from the most recent
  valid estimate if it is at most ``max_prior_age`` epochs old (the caller's
  prior counts as one before epoch 0), else without a start; disabled, every
  epoch gets the caller's prior.  Liu et al. 2023 (sec. 5.1) solve one epoch
  per second of a slowly moving Earth-pointing attitude, where the previous
  estimate is a good start.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.errors import (
    AttoptError,
    ConvergenceError,
    ModelMismatchError,
    UnobservableError,
)
from attopt.formulations.snr_problem import EpochIssue
from attopt.solvers.chi_square import chi_square_tail
from attopt.solvers.results import Track

Item = TypeVar("Item")
Start = TypeVar("Start")

DEFAULT_MAX_PRIOR_AGE = 10
"""Epochs a valid estimate stays usable as the next epochs' start."""
NO_MEASUREMENT = EpochIssue("no measurement at this epoch", UnobservableError)
MISMATCH_FALSE_ALARM = 1e-6
"""Probability that :func:`residual_test` flags an epoch whose model is right."""


@dataclass(frozen=True)
class WarmStart:
    """How a sequence starts its epochs (module docstring).

    Attributes:
        enabled: start each epoch from the most recent valid estimate.
        max_prior_age: epochs after which that estimate is too old to start from.
    """

    enabled: bool = True
    max_prior_age: int = DEFAULT_MAX_PRIOR_AGE


@dataclass(frozen=True)
class EpochEstimate:
    """One epoch's estimate.

    ``failure`` (with ``error``) marks a solve that did not converge; its
    attitude, covariance and loss are then ignored.
    """

    attitude: Rotation | None
    covariance: NDArray[np.float64]
    loss: float
    diagnostics: Mapping[str, float]
    failure: str | None = None
    error: type[AttoptError] = ConvergenceError

    @classmethod
    def failed(
        cls,
        reason: str,
        diagnostics: Mapping[str, float],
        error: type[AttoptError] = ConvergenceError,
    ) -> EpochEstimate:
        return cls(None, np.full((3, 3), np.nan), np.nan, diagnostics, reason, error)


def residual_test(
    chi_square: float, dof: int, false_alarm: float = MISMATCH_FALSE_ALARM
) -> str | None:
    """Why an estimate's residuals contradict the model's noise, or ``None``.

    ``chi_square`` is the sum of the squared standardised residuals at the estimate of
    ``m`` measurements (``sum_k w_k r_k^2 = 2 loss`` for a weighted least-squares fit,
    ``w_k = 1 / sigma_k^2``) with ``p`` parameters fitted: when the model and its sigmas
    are right it is chi-square with ``dof = m - p`` degrees of freedom (to first order
    in the noise), and an epoch where ``P(chi2(dof) >= chi_square) < false_alarm`` is a
    model mismatch (``false_alarm`` 0 or ``dof < 1``: no test).  A chi-square that is not
    finite (a measurement the model cannot predict at the estimate, e.g. an SNR from
    behind an antenna) is a mismatch too.

    Example::

        >>> from attopt.solvers.snapshot_sequence import residual_test
        >>> residual_test(310.0, 297) is None  # chi-square(297): 297 +/- 24
        True
        >>> residual_test(1480.0, 297)[:14]  # 2 dB offsets against 1 dB sigmas
        'model mismatch'
    """
    if false_alarm <= 0.0 or dof < 1:
        return None
    if not np.isfinite(chi_square):
        return (
            f"model mismatch: the residuals' chi-square is {chi_square} (a measurement the "
            "model cannot predict at the estimate)"
        )
    p = float(chi_square_tail(chi_square, dof))
    if p >= false_alarm:
        return None
    return (
        f"model mismatch: the residuals' chi-square {chi_square:.4g} with {dof} degrees of "
        f"freedom has p = {p:.2g} < {false_alarm:g}"
    )


def mismatched(estimate: EpochEstimate, reason: str | None) -> EpochEstimate:
    """``estimate`` flagged with the :func:`residual_test` ``reason`` (if any)."""
    if reason is None or estimate.failure is not None:
        return estimate
    return EpochEstimate.failed(reason, estimate.diagnostics, ModelMismatchError)


def solve_in_sequence(
    method: str,
    items: Sequence[Item | EpochIssue | None],
    prior: Start | None,
    warm_start: WarmStart,
    diagnostic_names: tuple[str, ...],
    issue: Callable[[Item], EpochIssue | None],
    estimate: Callable[[Item, Start | Rotation | None], EpochEstimate],
) -> Track:
    """The :class:`~attopt.solvers.results.Track` of consecutive epochs (module docstring).

    ``items`` holds one problem per epoch, ``None`` (no measurement) or an
    :class:`~attopt.formulations.snr_problem.EpochIssue` found while reading
    the epoch.  ``estimate`` gets the epoch and its start: ``prior`` (as the
    caller gave it) or the attitude of the most recent valid estimate.  The
    diagnostics are ``diagnostic_names`` plus ``warm_started`` (1 where an epoch
    started from an earlier epoch's estimate).
    """
    n = len(items)
    quaternion = np.full((n, 4), np.nan)
    covariance = np.full((n, 3, 3), np.nan)
    loss = np.full(n, np.nan)
    valid = np.zeros(n, dtype=bool)
    reason = np.full(n, "", dtype=object)
    error = np.full(n, None, dtype=object)
    diagnostics = {name: np.full(n, np.nan) for name in (*diagnostic_names, "warm_started")}
    # The most recent valid estimate (the prior counts as one before epoch 0).
    last: tuple[int, Any] | None = None if prior is None else (-1, prior)
    for i, item in enumerate(items):
        found = _issue_of(item, issue)
        if found is not None:
            reason[i], error[i] = found.reason, found.error
            continue
        start = prior
        if warm_start.enabled:
            fresh = last is not None and i - last[0] <= warm_start.max_prior_age
            start = last[1] if fresh else None
        est = estimate(item, start)
        for name, value in est.diagnostics.items():
            diagnostics[name][i] = value
        diagnostics["warm_started"][i] = float(
            warm_start.enabled and start is not None and last is not None and last[0] >= 0
        )
        if est.failure is not None or est.attitude is None:
            reason[i], error[i] = est.failure or "no attitude", est.error
            continue
        valid[i] = True
        quaternion[i] = est.attitude.as_quat(canonical=True)
        covariance[i] = est.covariance
        loss[i] = est.loss
        last = (i, est.attitude)
    return Track(method, quaternion, covariance, loss, valid, reason, error, diagnostics)


def _issue_of(item: Any, issue: Callable[[Any], EpochIssue | None]) -> EpochIssue | None:
    if item is None:
        return NO_MEASUREMENT
    if isinstance(item, EpochIssue):
        return item
    return issue(item)
