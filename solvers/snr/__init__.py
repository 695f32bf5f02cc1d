"""Solvers of the SNR attitude problem of seed 000 and their registry.

Every solver is an :class:`~attopt.solvers.snr.driver.SnrSolver` in
:data:`SNR_SOLVERS` with the common contract

* ``solve(problem, prior=None) -> Solution`` for one
  :class:`~attopt.formulations.snr_problem.SnrEpoch` (raises the specific
  :mod:`attopt.formulations.errors` exception on bad input or a failed solve), and
* ``solve_sequence(problems, prior=None, *, warm_start=True, max_prior_age=10)
  -> Track`` for consecutive epochs (invalid ones flagged with the
  reason, each epoch warm-started from the previous valid estimate).

Names: ``"deterministic"`` (two-step: pattern inverse, boresight cones,
QUEST; seed 000 sec. 3.2), ``"nlse"`` (Levenberg-Marquardt on 3-2-1 Euler
angles; sec. 3.3) and ``"nlp"`` (CasADi NLP on an MRP increment, IPOPT), the
last two minimising eq. 19, and ``"nlp_truncated"`` (the same NLP maximising
the likelihood of the threshold-truncated measurements of sec. 5.1,
:mod:`attopt.formulations.snr_truncation`).
"""

from __future__ import annotations

from attopt.solvers.snr.deterministic import DeterministicSolver
from attopt.solvers.snr.driver import SnrSolver
from attopt.solvers.snr.nlp import TRUNCATED_NLP, IpoptOptions, NlpSolver
from attopt.solvers.snr.nlse import LmOptions, NlseSolver

SNR_SOLVERS: dict[str, SnrSolver] = {
    s.name: s for s in (DeterministicSolver(), NlseSolver(), NlpSolver(), TRUNCATED_NLP)
}

__all__ = [
    "SNR_SOLVERS",
    "DeterministicSolver",
    "IpoptOptions",
    "LmOptions",
    "NlpSolver",
    "NlseSolver",
    "SnrSolver",
]
