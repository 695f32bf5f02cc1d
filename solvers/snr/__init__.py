"""Solvers of the SNR attitude problem of Liu et al. 2023 as snapshot estimators.

Every solver is an :class:`~attopt.solvers.snr.driver.SnrSolver` in
:data:`ESTIMATORS`: a :class:`~attopt.solvers.estimator.SnapshotEstimator`
that accepts one :class:`~attopt.formulations.snr_measurement.SnrMeasurement`
per snapshot, with

* ``solve(snapshot, prior=None) -> Solution`` (raises the specific
  :mod:`attopt.formulations.errors` exception on bad input or a failed solve), and
* ``solve_sequence(snapshots, prior=None) -> Track`` for consecutive epochs
  (invalid ones flagged with the reason, each epoch warm-started from the
  previous valid estimate as the ``warm_start`` field says);
* ``solve_epochs(epochs, prior=None) -> Track``, the same on
  :class:`~attopt.formulations.snr_problem.SnrEpoch` s.

Names: ``"deterministic"`` (two-step: pattern inverse, boresight cones, QUEST;
Liu et al. 2023 sec. 3.2), ``"nlse"`` (Levenberg-Marquardt on 3-2-1 Euler
angles; sec. 3.3) and ``"nlp"`` (CasADi NLP on an MRP increment, IPOPT), the
last two minimising eq. 19, and ``"nlp_truncated"`` (the same NLP maximising
the likelihood of the threshold-truncated measurements of sec. 5.1,
:mod:`attopt.formulations.snr_truncation`).
"""

from __future__ import annotations

from attopt.solvers.snr.deterministic import DeterministicSolver
from attopt.solvers.snr.driver import SnrSolver
from attopt.solvers.snr.nlp import TRUNCATED_NLP, NlpSolver
from attopt.solvers.snr.nlse import LmOptions, NlseSolver

DETERMINISTIC = DeterministicSolver()
NLSE = NlseSolver()
NLP = NlpSolver()

ESTIMATORS: tuple[SnrSolver, ...] = (DETERMINISTIC, NLSE, NLP, TRUNCATED_NLP)
"""The four SNR solvers."""

__all__ = [
    "DETERMINISTIC",
    "ESTIMATORS",
    "NLP",
    "NLSE",
    "TRUNCATED_NLP",
    "DeterministicSolver",
    "LmOptions",
    "NlpSolver",
    "NlseSolver",
    "SnrSolver",
]
