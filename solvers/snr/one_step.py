"""What the one-step SNR solvers (NLSE, NLP; Liu et al. 2023 sec. 3.3) share.

A one-step solver supplies a local solve (epoch, start attitude ->
:class:`~attopt.solvers.snr.initialisation.LocalResult`).  This class starts it by
:func:`~attopt.solvers.snr.initialisation.initialise`, flags a solve that does not
converge with the solver's status as reason, and scores a converged one with
the shared loss and covariance (Liu et al. 2023 eqs. 19, 22; :mod:`attopt.solvers.snr.fit`).
"""

from __future__ import annotations

from abc import abstractmethod
from typing import ClassVar

from scipy.spatial.transform import Rotation

from attopt.formulations.snr_problem import SnrEpoch
from attopt.solvers.snapshot_sequence import EpochEstimate
from attopt.solvers.snr.driver import SnrSolver
from attopt.solvers.snr.exclusion import EXCLUSION_DIAGNOSTICS
from attopt.solvers.snr.fit import SELECTION_BIAS_DIAGNOSTICS, fit_at
from attopt.solvers.snr.initialisation import INITIALISATION_DIAGNOSTICS, LocalResult, initialise

ONE_STEP_DIAGNOSTICS = (
    *INITIALISATION_DIAGNOSTICS,
    "outside_lobe",
    *EXCLUSION_DIAGNOSTICS,
    *SELECTION_BIAS_DIAGNOSTICS,
)
"""Initialisation diagnostics, observations beyond the main lobe at the estimate, the
fault exclusion's (:mod:`attopt.solvers.snr.exclusion`) and the selection bias the
covariance covers (:mod:`attopt.solvers.snr.fit`)."""


class OneStepSolver(SnrSolver):
    """A one-step solver; subclasses set :attr:`status_label` and implement :meth:`local_solve`."""

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
        return EpochEstimate(init.result.attitude, fit.covariance, fit.loss, diagnostics)
