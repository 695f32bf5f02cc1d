"""Fault detection and exclusion of one transmitter for the snapshot SNR solvers (RAIM-style).

Detection is the residual test every SNR solver applies
(:func:`~attopt.solvers.snapshot_sequence.residual_test`): the sum of the squared
standardised residuals at the estimate against chi-square with ``m - 3`` degrees of
freedom at ``mismatch_false_alarm``, the sum-of-squared-residuals statistic of
Parkinson and Axelrad 1988 (Brown 1992 shows it equivalent to the parity-space and
range-comparison tests).  An epoch that passes it is never touched.

Exclusion (:func:`exclude_one_transmitter`), for an epoch that fails it, assumes one
faulty transmitter (an aircraft with a wrong broadcast position, or one outlier):

1. *Isolation.*  With the residuals ``s`` standardised to unit variance and ``A``
   their whitened Jacobian at the estimate (:class:`~attopt.solvers.snr.fit.Residuals`),
   the linearised least-squares residuals are ``e = P s``, ``P = I - A A^+`` the
   projection onto the parity space.  For the rows ``g`` of one transmitter, excluding
   them lowers the chi-square by ``T_g = e_g^T (P_gg)^-1 e_g``, chi-square with
   ``m_g`` degrees of freedom when the transmitter is fault-free (for one row this is
   ``w_g^2``, Baarda 1968's normalised residual; :func:`exclusion_statistics`).  The
   transmitters are ranked by the tail probability of ``T_g``, most significant first.
2. *Candidates.*  A transmitter is a candidate only where its residuals are separable
   (``P_gg`` not singular: its rows do not alone determine a direction of the attitude)
   and the epoch without it is solvable by the method and still testable (``m - m_g -
   3 >= 1``).  With no candidate, the aircraft cannot be isolated and the epoch is
   flagged.
3. *Exclusion.*  The epoch without the best candidate is solved again from the same
   start and tested again at the same false alarm (``m - m_g - 3`` degrees of freedom).
   If it fails, the epoch is flagged (two or more faults, or a model mismatch that no
   single transmitter explains).
4. *Uniqueness.*  If it passes and there is a second candidate, the epoch without
   that one is solved and tested too; if it also passes, the data do not say which
   aircraft is faulty and the epoch is flagged rather than guessed.  Otherwise the
   re-solved estimate is returned, valid, with ``n_excluded = 1`` and
   ``excluded_transmitter`` (the transmitter identifier of
   :attr:`~attopt.formulations.snr_problem.SnrEpoch.transmitter`, or the row index
   when the epoch has none) in its diagnostics.

Flagged epochs keep the residual test's reason (``model mismatch: ...``,
:class:`~attopt.formulations.errors.ModelMismatchError`) followed by why no exclusion
repaired them.  One transmitter at most is excluded per epoch.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2

from attopt.formulations.snr_problem import SnrEpoch
from attopt.solvers.snapshot_sequence import EpochEstimate, mismatched
from attopt.solvers.snr.fit import Residuals

EXCLUSION_DIAGNOSTICS = ("n_excluded", "excluded_transmitter")
"""Diagnostics of every tested epoch: transmitters excluded (0 or 1) and which one (NaN
for none)."""
SEPARABILITY_TOLERANCE = 1e-9
"""Smallest eigenvalue of ``P_gg`` for which a transmitter's residuals are separable."""
RANK_TOLERANCE = 1e-10
"""Singular values of the whitened Jacobian below this times the largest span no
direction of the projection."""

NO_CANDIDATE = (
    "without any one of them the method cannot solve the epoch or too few observations "
    "remain to test it, or their residuals are not separable"
)
"""Why no transmitter is a candidate (module docstring, 2)."""
Tested = tuple[EpochEstimate, str | None]
"""An estimate of an epoch and its residual test's reason (``None``: it passed)."""


@dataclass(frozen=True)
class Candidate:
    """A transmitter whose exclusion is tested: its identifier, the rows kept without it
    and the log tail probability of its statistic ``T_g`` (module docstring, 1)."""

    transmitter: int
    keep: NDArray[np.bool_]
    log_p: float


def transmitter_rows(problem: SnrEpoch) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """The distinct transmitters of the epoch and each row's index into them (each row
    its own transmitter when the epoch names none)."""
    ids = np.arange(problem.m) if problem.transmitter is None else problem.transmitter
    return np.unique(ids, return_inverse=True)


def parity_projection(jacobian: NDArray[np.float64]) -> NDArray[np.float64]:
    """``P = I - A A^+``: the projection orthogonal to the columns of ``A`` ``(m, 3)``."""
    u, singular, _ = np.linalg.svd(jacobian, full_matrices=False)
    span = u[:, singular > RANK_TOLERANCE * singular.max(initial=0.0)]
    return np.eye(jacobian.shape[0]) - span @ span.T


def exclusion_statistics(residuals: Residuals, group: NDArray[np.intp], n_groups: int) -> NDArray:
    """``T_g = e_g^T (P_gg)^-1 e_g`` per group of rows (``group`` ``(m,)`` the group of each
    row), NaN where ``P_gg`` is singular (module docstring, 1-2).  A group with a residual
    the model cannot predict (not finite) gets ``inf``: the others' are those of the
    finite rows."""
    finite = np.isfinite(residuals.scores) & np.isfinite(residuals.jacobian).all(axis=1)
    projection = parity_projection(residuals.jacobian[finite])
    e = projection @ residuals.scores[finite]
    kept = group[finite]
    statistics = np.full(n_groups, np.inf)
    for g in np.unique(kept[np.isin(kept, group[~finite], invert=True)]):
        rows = np.flatnonzero(kept == g)
        block = projection[np.ix_(rows, rows)]
        separable = np.linalg.eigvalsh(block).min() > SEPARABILITY_TOLERANCE
        statistics[g] = float(e[rows] @ np.linalg.solve(block, e[rows])) if separable else np.nan
    return statistics


def candidates(
    problem: SnrEpoch, residuals: Residuals, solvable: Callable[[SnrEpoch], bool]
) -> list[Candidate]:
    """The transmitters whose exclusion can be tested, most significant first (module
    docstring, 1-2)."""
    ids, group = transmitter_rows(problem)
    statistics = exclusion_statistics(residuals, group, ids.size)
    found = []
    for g, statistic in enumerate(statistics):
        keep = group != g
        n_rows = problem.m - int(keep.sum())
        if np.isnan(statistic) or problem.m - n_rows - 3 < 1 or not solvable(problem.take(keep)):
            continue
        found.append(Candidate(int(ids[g]), keep, float(chi2.logsf(statistic, n_rows))))
    return sorted(found, key=lambda c: c.log_p)


def exclude_one_transmitter(
    problem: SnrEpoch,
    estimate: EpochEstimate,
    reason: str,
    residuals: Residuals,
    solvable: Callable[[SnrEpoch], bool],
    solve: Callable[[SnrEpoch], Tested],
) -> EpochEstimate:
    """The epoch ``problem`` whose ``estimate`` failed the residual test with ``reason``,
    repaired by excluding one transmitter, or flagged (module docstring).

    ``residuals`` are the estimate's; ``solvable`` tells whether the method can solve an
    epoch; ``solve`` solves and tests one from the original start.
    """
    found = candidates(problem, residuals, solvable)
    if not found:
        return mismatched(estimate, f"{reason}; no aircraft can be isolated ({NO_CANDIDATE})")
    best, best_reason = solve(problem.take(found[0].keep))
    why = best_reason or best.failure
    if why is not None:
        return mismatched(
            estimate, f"{reason}; excluding transmitter {found[0].transmitter} fails too: {why}"
        )
    if len(found) > 1 and _passes(solve(problem.take(found[1].keep))):
        return mismatched(
            estimate,
            f"{reason}; not isolated: excluding transmitter {found[0].transmitter} or "
            f"{found[1].transmitter} each restores the fit",
        )
    diagnostics = {
        **best.diagnostics,
        "n_excluded": 1.0,
        "excluded_transmitter": float(found[0].transmitter),
    }
    return replace(best, diagnostics=diagnostics)


def _passes(tested: Tested) -> bool:
    estimate, reason = tested
    return reason is None and estimate.failure is None
