"""The covariance sweep of the chain marginals against GTSAM's Bayes tree.

:mod:`attopt.solvers.smoother.chain_marginals`.

Graphs with the smoother's structure (with transmitter offsets): a chain of
3-dimensional attitude and bias keys (prior on the first node, a 3-row
factor on each attitude, AHRS-like
factors on ``(x_k, b_k, x_k+1)``, bias walks on ``(b_k, b_k+1)``),
1-dimensional offsets with priors, and single-row factors on ``(x_k, o_a)``
over each offset's window of nodes; random whitened Jacobians.
"""

from __future__ import annotations

import gtsam
import numpy as np
import pytest

from attopt.solvers.smoother.chain_marginals import sequential_marginals
from attopt.solvers.smoother.conventions import attitude_key, bias_key, offset_key

UNIT1, UNIT3, UNIT6 = (gtsam.noiseModel.Unit.Create(d) for d in (1, 3, 6))


def _graph(
    rng: np.random.Generator, n: int, n_offsets: int
) -> tuple[gtsam.GaussianFactorGraph, gtsam.Ordering]:
    """Random chain graph and its time ordering (each offset after the last node seeing it)."""
    g = gtsam.GaussianFactorGraph()
    x, b, o = attitude_key, bias_key, offset_key

    def a(rows: int, cols: int) -> np.ndarray:
        return rng.standard_normal((rows, cols))

    g.add(gtsam.JacobianFactor(x(0), a(6, 3), b(0), a(6, 3), a(6, 1)[:, 0], UNIT6))
    for k in range(n):
        g.add(gtsam.JacobianFactor(x(k), a(3, 3), a(3, 1)[:, 0], UNIT3))
    for k in range(n - 1):
        g.add(
            gtsam.JacobianFactor(
                x(k), a(3, 3), b(k), a(3, 3), x(k + 1), a(3, 3), a(3, 1)[:, 0], UNIT3
            )
        )
        g.add(gtsam.JacobianFactor(b(k), a(3, 3), b(k + 1), a(3, 3), a(3, 1)[:, 0], UNIT3))
    starts = rng.integers(0, n, n_offsets)
    stops = np.minimum(starts + rng.integers(1, n // 2 + 2, n_offsets), n)
    for j in range(n_offsets):
        g.add(gtsam.JacobianFactor(o(j), a(1, 1), a(1, 1)[:, 0], UNIT1))
        for k in range(starts[j], stops[j]):
            g.add(gtsam.JacobianFactor(x(k), a(1, 3), o(j), a(1, 1), a(1, 1)[:, 0], UNIT1))
    ordering = gtsam.Ordering()
    for k in range(n):
        ordering.push_back(x(k))
        ordering.push_back(b(k))
        for j in np.flatnonzero(stops - 1 == k):
            ordering.push_back(o(int(j)))
    return g, ordering


def _max_correlation_error(c: np.ndarray, reference: np.ndarray) -> float:
    """Largest difference in units of the reference standard deviations."""
    sd = np.sqrt(np.einsum("...ii->...i", reference))
    return float((np.abs(c - reference) / (sd[..., :, None] * sd[..., None, :])).max())


@pytest.mark.parametrize(("n", "n_offsets", "seed"), [(40, 25, 1), (40, 0, 2), (1, 3, 3)])
def test_matches_bayes_tree_joint_marginals(n: int, n_offsets: int, seed: int) -> None:
    g, ordering = _graph(np.random.default_rng(seed), n, n_offsets)
    nodes = [(attitude_key(k), bias_key(k)) for k in range(n)]
    offsets = [offset_key(j) for j in range(n_offsets)]
    covariance, variances = sequential_marginals(g, ordering, nodes, offsets)

    tree = g.eliminateMultifrontal(ordering)
    reference = np.zeros((n, 6, 6))
    for k, (xk, bk) in enumerate(nodes):
        joint = tree.jointMarginalCovariance([xk, bk])
        reference[k] = np.block(
            [[joint.at(xk, xk), joint.at(xk, bk)], [joint.at(bk, xk), joint.at(bk, bk)]]
        )
    assert np.abs(reference[:, :3, 3:]).max() > 1e-3  # the cross blocks are exercised
    assert _max_correlation_error(covariance, reference) < 1e-9
    expected = np.array([tree.marginalCovariance(key)[0, 0] for key in offsets])
    np.testing.assert_allclose(variances, expected, rtol=1e-9)


def test_any_elimination_order_gives_the_same_marginals() -> None:
    rng = np.random.default_rng(4)
    g, ordering = _graph(rng, 15, 8)
    keys = [ordering.at(i) for i in range(ordering.size())]
    shuffled = gtsam.Ordering()
    for i in rng.permutation(len(keys)):
        shuffled.push_back(keys[i])
    nodes = [(attitude_key(k), bias_key(k)) for k in range(15)]
    offsets = [offset_key(j) for j in range(8)]
    time_ordered = sequential_marginals(g, ordering, nodes, offsets)
    permuted = sequential_marginals(g, shuffled, nodes, offsets)
    assert _max_correlation_error(permuted[0], time_ordered[0]) < 1e-9
    np.testing.assert_allclose(permuted[1], time_ordered[1], rtol=1e-9)


def test_constrained_conditional_is_rejected() -> None:
    g, ordering = _graph(np.random.default_rng(5), 3, 0)
    g.add(
        gtsam.JacobianFactor(
            bias_key(1), np.eye(3), np.zeros(3), gtsam.noiseModel.Constrained.All(3)
        )
    )
    with pytest.raises(ValueError, match="non-unit"):
        sequential_marginals(g, ordering, [(attitude_key(0), bias_key(0))], [])
