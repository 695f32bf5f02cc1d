"""What the one-step SNR solvers (NLSE, NLP; Liu et al. 2023 sec. 3.3) share.

A one-step solver supplies a local solve (epoch, start attitude ->
:class:`~attopt.solvers.snr.initialisation.LocalResult`).  This class starts it by
:func:`~attopt.solvers.snr.initialisation.initialise`, flags a solve that does not
converge with the solver's status as reason, and scores a converged one with
the shared loss and covariance (Liu et al. 2023 eqs. 19, 22; :mod:`attopt.solvers.snr.fit`).
"""

from __future__ import annotations

from abc import abstractmethod
from dataclasses import dataclass
from typing import ClassVar

from scipy.spatial.transform import Rotation

from attopt.formulations.errors import UnobservableError
from attopt.formulations.snr_problem import SnrEpoch
from attopt.solvers.snapshot_sequence import EpochEstimate
from attopt.solvers.snr.driver import SnrSolver
from attopt.solvers.snr.exclusion import EXCLUSION_DIAGNOSTICS
from attopt.solvers.snr.fit import SELECTION_BIAS_DIAGNOSTICS, fit_at
from attopt.solvers.snr.initialisation import (
    INITIALISATION_DIAGNOSTICS,
    LocalResult,
    StartSource,
    initialise,
    rival_minimum,
)

ONE_STEP_DIAGNOSTICS = (
    *INITIALISATION_DIAGNOSTICS,
    "outside_lobe",
    "start_loss",
    *EXCLUSION_DIAGNOSTICS,
    *SELECTION_BIAS_DIAGNOSTICS,
)
"""Initialisation diagnostics, observations beyond the main lobe at the estimate, the
local solve's own loss (what :func:`~attopt.solvers.snr.initialisation.rival_minimum`
compares), the fault exclusion's (:mod:`attopt.solvers.snr.exclusion`) and the selection bias the
covariance covers (:mod:`attopt.solvers.snr.fit`)."""


@dataclass(frozen=True, repr=False)
class OneStepSolver(SnrSolver):
    """A one-step solver; subclasses set :attr:`status_label` and implement :meth:`local_solve`.

    Attributes:
        ambiguity_check: at an epoch started without a prior (the first, or after an
            invalid one), the local solves from every multi-start attitude look for a
            second minimum the data cannot tell from the estimate
            (:func:`~attopt.solvers.snr.initialisation.rival_minimum`), once the estimate
            has passed its residual test with every transmitter; if there is one the
            epoch is flagged ``ambiguous``
            (:class:`~attopt.formulations.errors.UnobservableError`), and the next
            epoch starts without a prior again.  Warm-started epochs are not checked
            (24 more local solves at each cold start only).
    """

    ambiguity_check: bool = True

    status_label: ClassVar[str]
    diagnostic_names: ClassVar[tuple[str, ...]] = ONE_STEP_DIAGNOSTICS

    @abstractmethod
    def local_solve(self, problem: SnrEpoch, start: Rotation) -> LocalResult:
        """Minimise the SNR loss of ``problem`` from ``start``."""

    def estimate_epoch(self, problem: SnrEpoch, prior: Rotation | None) -> EpochEstimate:
        init = initialise(problem, self.local_solve, prior)
        diagnostics = init.diagnostics()
        if not init.result.converged:
            return EpochEstimate.failed(f"{self.status_label}: {init.result.status}", diagnostics)
        fit = fit_at(problem, init.result.attitude)
        diagnostics["outside_lobe"] = float(fit.outside_lobe)
        diagnostics["start_loss"] = init.result.loss
        return EpochEstimate(init.result.attitude, fit.covariance, fit.loss, diagnostics)

    def tested_estimate(self, problem: SnrEpoch, prior: Rotation | None) -> EpochEstimate:
        """The driver's tested estimate, flagged ``ambiguous`` when it was started without
        a prior, passed its residual test with every transmitter, and a second minimum
        fits about as well (:attr:`ambiguity_check`)."""
        estimate = super().tested_estimate(problem, prior)
        diagnostics = estimate.diagnostics
        if not (
            self.ambiguity_check
            and estimate.failure is None
            and diagnostics.get("start_source") != StartSource.PRIOR
            and not diagnostics.get("n_excluded")
        ):
            return estimate
        rival = rival_minimum(
            problem,
            self.local_solve,
            estimate.attitude,
            diagnostics["start_loss"],
            estimate.covariance,
        )
        if rival is None:
            return estimate
        angle, gap = rival
        return EpochEstimate.failed(
            f"ambiguous: a second minimum {angle:.1f} deg away fits as well "
            f"(2 dL = {gap:.3g}, within the chi-square(3) 1 - 1e-4 quantile)",
            diagnostics,
            UnobservableError,
        )
