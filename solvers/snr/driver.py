"""The part every SNR solver shares: validate, warm-start, estimate, assemble.

A solver (:class:`SnrSolver` subclass) supplies its validation rule
(``min_per_antenna``, :func:`attopt.formulations.snr_problem.epoch_issue`) and an
:meth:`SnrSolver.estimate` for one validated epoch with an optional a-priori
attitude.  This module turns that into the project's result types
(:mod:`attopt.solvers.results`):

* :meth:`SnrSolver.solve` solves one epoch and raises the specific exception
  of bad input (:class:`~attopt.formulations.errors.InvalidObservationError`,
  :class:`~attopt.formulations.errors.UnobservableError`) or of a failed solve
  (:class:`~attopt.formulations.errors.ConvergenceError`, with the solver status as
  message);
* :meth:`SnrSolver.solve_sequence` solves consecutive epochs, flags invalid or
  failed ones with the reason (never an attitude) and warm-starts each epoch
  from the most recent valid estimate (seed 000 sec. 5.1 solves one epoch per
  second of a slowly moving Earth-pointing attitude).

Diagnostics of failed solves are kept (e.g. the iterations IPOPT spent before
giving up); those of epochs rejected before solving are NaN.
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.errors import AttoptError, ConvergenceError
from attopt.formulations.snr_problem import EpochIssue, SnrEpoch, epoch_issue
from attopt.solvers.results import Solution, Track

DEFAULT_MAX_PRIOR_AGE = 10
"""Epochs a valid estimate stays usable as the next epochs' warm start."""


@dataclass(frozen=True)
class EpochEstimate:
    """What :meth:`SnrSolver.estimate` returns for one epoch.

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


class SnrSolver(ABC):
    """A solver of the SNR attitude problem (seed 000 secs. 3.2-3.3).

    Subclasses set :attr:`name`, :attr:`description`, :attr:`diagnostic_names`
    and :attr:`min_per_antenna` (``None``: the one-step observability rule)
    and implement :meth:`estimate`.
    """

    name: str
    description: str
    diagnostic_names: tuple[str, ...]
    min_per_antenna: int | None = None

    def issue(self, problem: SnrEpoch) -> EpochIssue | None:
        """Why ``problem`` cannot be solved by this method, or ``None``."""
        return epoch_issue(problem, min_per_antenna=self.min_per_antenna)

    @abstractmethod
    def estimate(self, problem: SnrEpoch, prior: Rotation | None) -> EpochEstimate:
        """Estimate one validated epoch; ``prior`` is an a-priori attitude or ``None``."""

    def solve(self, problem: SnrEpoch, prior: Rotation | None = None) -> Solution:
        """Solve one epoch; raises the recorded exception if it is invalid or fails."""
        return self.solve_sequence([problem], prior=prior).epoch(0).raise_if_invalid()

    def solve_sequence(
        self,
        problems: Sequence[SnrEpoch],
        prior: Rotation | None = None,
        *,
        warm_start: bool = True,
        max_prior_age: int = DEFAULT_MAX_PRIOR_AGE,
    ) -> Track:
        """Solve consecutive epochs; invalid ones are flagged, not raised.

        ``prior`` is the a-priori attitude of the first epoch.  With
        ``warm_start``, each later epoch starts from the most recent valid
        estimate if it is at most ``max_prior_age`` epochs old, and otherwise
        (first epoch without ``prior``, or after a gap) is initialised without
        a prior.  Without ``warm_start`` every epoch gets ``prior``.
        """
        n = len(problems)
        quaternion = np.full((n, 4), np.nan)
        covariance = np.full((n, 3, 3), np.nan)
        loss = np.full(n, np.nan)
        valid = np.zeros(n, dtype=bool)
        reason = np.full(n, "", dtype=object)
        error = np.full(n, None, dtype=object)
        names = (*self.diagnostic_names, "warm_started")
        diagnostics = {name: np.full(n, np.nan) for name in names}
        # The most recent valid estimate (the prior counts as one before epoch 0).
        last: tuple[int, Rotation] | None = None if prior is None else (-1, prior)
        for i, problem in enumerate(problems):
            issue = self.issue(problem)
            if issue is not None:
                reason[i], error[i] = issue.reason, issue.error
                continue
            start = prior
            if warm_start:
                fresh = last is not None and i - last[0] <= max_prior_age
                start = last[1] if fresh else None
            est = self.estimate(problem, start)
            for name, value in est.diagnostics.items():
                diagnostics[name][i] = value
            diagnostics["warm_started"][i] = float(
                warm_start and start is not None and last is not None and last[0] >= 0
            )
            if est.failure is not None or est.attitude is None:
                reason[i], error[i] = est.failure or "no attitude", est.error
                continue
            valid[i] = True
            quaternion[i] = est.attitude.as_quat(canonical=True)
            covariance[i] = est.covariance
            loss[i] = est.loss
            last = (i, est.attitude)
        return Track(self.name, quaternion, covariance, loss, valid, reason, error, diagnostics)
