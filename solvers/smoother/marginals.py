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
* with offsets (the problem's time ordering), the Bayes-tree queries recompute
  separator marginals of hundreds of offsets clique by clique (47 s for 300 s of
  ``adsb-snr``); a backward sweep over the sequential Bayes net gives the same
  values (to 1e-11) in about 1 s
  (:func:`~attopt.solvers.smoother.chain_marginals.sequential_marginals`).
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from attopt.solvers.filters.common import STATE_SIZE
from attopt.solvers.smoother.chain_marginals import sequential_marginals
from attopt.solvers.smoother.conventions import (
    Array,
    attitude_key,
    bias_key,
    error_state_covariance,
    node_marginal,
    offset_key,
)
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
    problem: SmootherProblem, values: gtsam.Values, options: MarginalOptions
) -> PassMarginals:
    """The marginals of ``problem`` linearised at ``values`` at its output epochs."""
    linear = problem.linearize(values)
    nodes = range(problem.offset, problem.n)
    try:
        covariance, variances = marginal_covariances(
            linear, nodes, options.cross_covariance, problem.n_offsets, problem.ordering
        )
    except RuntimeError as exc:  # an indefinite system (should not happen: prior + gyro chain)
        return PassMarginals(
            np.full((len(nodes), STATE_SIZE, STATE_SIZE), np.nan),
            np.full(problem.n_offsets, np.nan),
            f"marginal covariance failed: {exc}",
        )
    return PassMarginals(covariance, variances)


def marginal_covariances(
    linear: gtsam.GaussianFactorGraph,
    nodes: range,
    cross: bool,
    n_offsets: int = 0,
    ordering: gtsam.Ordering | None = None,
) -> tuple[Array, Array]:
    """Error-state covariances ``(len(nodes), 6, 6)`` and the transmitter offsets'
    variances ``(n_offsets,)`` of ``linear`` (module docstring); ``ordering``: the
    time ordering of a problem with offsets (sequential sweep), else ``None``
    (Bayes tree)."""
    if ordering is not None:
        covariance, variances = sequential_marginals(
            linear,
            ordering,
            [(attitude_key(k), bias_key(k)) for k in nodes],
            [offset_key(j) for j in range(n_offsets)],
        )
        if not cross:  # per-key blocks only, as the Bayes-tree path
            covariance[:, :3, 3:] = 0.0
            covariance[:, 3:, :3] = 0.0
        return error_state_covariance(covariance), variances
    ordering = (
        gtsam.Ordering.ColamdGaussianFactorGraph(linear)
        if has_isolated_keys(linear)
        else gtsam.Ordering.MetisGaussianFactorGraph(linear)
    )
    tree = linear.eliminateMultifrontal(ordering)
    out = np.zeros((len(nodes), STATE_SIZE, STATE_SIZE))
    for i, k in enumerate(nodes):
        out[i] = node_marginal(tree, k, cross)
    variances = np.array([tree.marginalCovariance(offset_key(j))[0, 0] for j in range(n_offsets)])
    return error_state_covariance(out), variances


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
