"""Marginal covariances of the batch smoother's solution (as GTSAM's ``Marginals``).

The marginals of the final undamped linear system
(:meth:`~attopt.solvers.smoother.problem.SmootherProblem.linearize`: built-in
factors, prior, measurement factors with their final IRLS weights) that
``gtsam.Marginals`` computes, per epoch the joint ``6 x 6`` of ``[xi, d]``
(``jointMarginalCovariance``; ``cross_covariance=False`` keeps only the per-key
blocks, block-diagonal, several times cheaper), converted to the error state
``[delta, delta_beta]`` (cross block negated,
:func:`~attopt.solvers.smoother.conventions.error_state_covariance`), and the
transmitter offsets' variances.  At the truth the inverse of this information is
the posterior Cramer-Rao bound of the pass (:func:`attopt.solvers.bounds.posterior_bound`).

Two eliminations, both measured faster than ``gtsam.Marginals`` itself:

* without offsets, a ``GaussianBayesTree`` eliminated in METIS (nested-dissection)
  order: ``Marginals`` eliminates in COLAMD order, whose tree for this chain is
  deep, and its joint queries then cost time growing with the pass (45 s for the
  6-state joints of 14,400 epochs, against 4 s here; same values to rounding);
  gtsam 4.3.0's METIS ordering crashes on a graph with an isolated variable (a
  node in a long gyro gap without measurements), which is then ordered by COLAMD;
* with offsets, the normal equations eliminated in time order and swept back in
  numpy (:meth:`~attopt.solvers.smoother.offset_elimination.NormalEquations.marginals`):
  GTSAM's Bayes-tree queries recompute separator marginals of hundreds of offsets
  clique by clique (47 s for 300 s of ``adsb-snr``).
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from attopt.solvers.filters.common import STATE_SIZE
from attopt.solvers.smoother.conventions import (
    Array,
    error_state_covariance,
    node_marginal,
)
from attopt.solvers.smoother.offset_elimination import NormalEquations
from attopt.solvers.smoother.problem import SmootherProblem


@dataclass(frozen=True)
class MarginalOptions:
    """Which marginals :func:`problem_marginals` computes.

    Attributes:
        cross_covariance: joint attitude-bias marginals (else block-diagonal,
            several times cheaper).
    """

    cross_covariance: bool = True


@dataclass(frozen=True)
class PassMarginals:
    """Error-state covariances ``(N, 6, 6)`` at the output epochs, the offsets' variances
    ``(n_offsets,)`` and, if the elimination failed, why (then both are NaN)."""

    covariance: Array
    offset_variances: Array
    error: str = ""


def problem_marginals(
    problem: SmootherProblem,
    values: gtsam.Values,
    options: MarginalOptions,
    system: gtsam.GaussianFactorGraph | NormalEquations | None = None,
) -> PassMarginals:
    """The marginals of ``problem`` linearised at ``values`` at its output epochs;
    ``system``: that linearisation when the caller holds it (the optimiser's last,
    :attr:`~attopt.solvers.smoother.optimiser.LevenbergMarquardtResult.system`: a graph,
    or with offsets the normal equations), else it is built here."""
    nodes = range(problem.offset, problem.n)
    try:
        if problem.n_offsets:
            if system is None:
                system = problem.normal_equations(values)
            joint, variances = system.marginals()
            covariance = error_state_covariance(joint[problem.offset :])
            if not options.cross_covariance:  # per-key blocks only, as the Bayes-tree path
                covariance[:, :3, 3:] = 0.0
                covariance[:, 3:, :3] = 0.0
        else:
            if system is None:
                system = problem.linearize(values)
            covariance = marginal_covariances(system, nodes, options.cross_covariance)
            variances = np.zeros(0)
    except (RuntimeError, np.linalg.LinAlgError) as exc:
        # an indefinite system (should not happen: prior + gyro chain)
        return PassMarginals(
            np.full((len(nodes), STATE_SIZE, STATE_SIZE), np.nan),
            np.full(problem.n_offsets, np.nan),
            f"marginal covariance failed: {exc}",
        )
    return PassMarginals(covariance, variances)


def marginal_covariances(linear: gtsam.GaussianFactorGraph, nodes: range, cross: bool) -> Array:
    """Error-state covariances ``(len(nodes), 6, 6)`` of ``linear`` (a problem without
    offsets; module docstring)."""
    ordering = (
        gtsam.Ordering.ColamdGaussianFactorGraph(linear)
        if has_isolated_keys(linear)
        else gtsam.Ordering.MetisGaussianFactorGraph(linear)
    )
    tree = linear.eliminateMultifrontal(ordering)
    out = np.zeros((len(nodes), STATE_SIZE, STATE_SIZE))
    for i, k in enumerate(nodes):
        out[i] = node_marginal(tree, k, cross)
    return error_state_covariance(out)


def has_isolated_keys(linear: gtsam.GaussianFactorGraph) -> bool:
    """Whether some variable shares no factor with another (a node in a long gyro gap
    without measurements): gtsam 4.3.0's METIS ordering crashes on such graphs."""
    keys, linked = set(), set()
    for i in range(linear.size()):
        factor_keys = linear.at(i).keys()
        keys.update(factor_keys)
        if len(factor_keys) > 1:
            linked.update(factor_keys)
    return keys != linked
