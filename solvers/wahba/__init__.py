"""Solvers of Wahba's problem (seed 002) and their registry.

Every solver is a :class:`WahbaSolver` in :data:`WAHBA_SOLVERS`; experiments,
benchmarks and the contract tests iterate over that registry.
"""

from __future__ import annotations

from dataclasses import dataclass

from numpy.typing import ArrayLike

from attopt.formulations.vector_observations import PARALLEL_TOLERANCE, prepare_observations
from attopt.solvers.results import Solution, Track
from attopt.solvers.wahba import foam, qmethod, quest, sdp, svd, triad
from attopt.solvers.wahba.driver import Estimator, solve_prepared


@dataclass(frozen=True)
class WahbaSolver:
    """A registered solver of Wahba's problem.

    Attributes:
        name: registry key, also the ``method`` column of results.
        estimator: the method itself (see :mod:`attopt.solvers.wahba.driver`).
        optimal: whether it minimises Wahba's loss exactly (TRIAD does not).
        vectorised: whether a batch is solved without a Python loop per epoch.
        description: one line with the seed equations it implements.
    """

    name: str
    estimator: Estimator
    optimal: bool
    vectorised: bool
    description: str

    def solve_batch(
        self,
        body: ArrayLike,
        reference: ArrayLike,
        weights: ArrayLike,
        present: ArrayLike | None = None,
        *,
        parallel_tolerance: float = PARALLEL_TOLERANCE,
    ) -> Track:
        """Solve ``N`` epochs (``(N, n, 3)`` vectors); invalid epochs are flagged, not raised."""
        obs = prepare_observations(
            body, reference, weights, present, parallel_tolerance=parallel_tolerance
        )
        return solve_prepared(self.name, self.estimator, obs)

    def solve(
        self,
        body: ArrayLike,
        reference: ArrayLike,
        weights: ArrayLike,
        *,
        parallel_tolerance: float = PARALLEL_TOLERANCE,
    ) -> Solution:
        """Solve one epoch (``(n, 3)`` vectors); raises a specific error on bad input."""
        obs = prepare_observations(body, reference, weights, parallel_tolerance=parallel_tolerance)
        if obs.n_epochs != 1:
            raise ValueError("solve() takes one epoch of (n, 3) vectors; use solve_batch()")
        return solve_prepared(self.name, self.estimator, obs).epoch(0).raise_if_invalid()


WAHBA_SOLVERS: dict[str, WahbaSolver] = {
    s.name: s
    for s in (
        WahbaSolver("triad", triad.estimate, False, True, "TRIAD/algebraic, seed 002 eqs. 5-11"),
        WahbaSolver("svd", svd.estimate, True, True, "SVD, seed 002 eqs. 17-19"),
        WahbaSolver(
            "q_method", qmethod.estimate, True, True, "Davenport q-method, seed 002 eqs. 20-26"
        ),
        WahbaSolver("quest", quest.estimate, True, True, "QUEST, seed 002 eqs. 27-32"),
        WahbaSolver("foam", foam.estimate, True, True, "FOAM, seed 002 eqs. 33-37"),
        WahbaSolver(
            "sdp", sdp.estimate, True, False, "SDP relaxation (cvxpy + Clarabel), eqs. 22-26"
        ),
    )
}
