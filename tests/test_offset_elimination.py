"""The smoother's normal equations with transmitter offsets, eliminated in time order
(:mod:`attopt.solvers.smoother.offset_elimination`), against dense linear algebra on
random systems of the same structure: a chain of 6-dimensional nodes, offsets each
seen over a window of nodes (some by two rows of a node, some by none), diagonal
offset priors.  The smoother's own system is checked against GTSAM in
``tests/test_smoother_pieces.py`` (marginals) and ``tests/test_smoother_offsets.py``."""

from __future__ import annotations

import gtsam
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from attopt.solvers.smoother import compiled
from attopt.solvers.smoother.conventions import attitude_key, bias_key, offset_key
from attopt.solvers.smoother.offset_elimination import (
    NODE,
    NormalEquations,
    active_counts,
    structure_keys,
)


def _random_system(
    seed: int, n: int, n_offsets: int
) -> tuple[NormalEquations, np.ndarray, np.ndarray]:
    """Random equations by blocks and the same ``H``, ``g`` assembled densely."""
    rng = np.random.default_rng(seed)
    equations = NormalEquations.empty(n, n_offsets)
    size = n * NODE + n_offsets
    h, g = np.zeros((size, size)), np.zeros(size)
    for k in range(n):  # a factor on node k and k + 1 (a gyro interval), or k alone
        width = 2 * NODE if k + 1 < n else NODE
        a, b = rng.standard_normal((8, width)), rng.standard_normal(8)
        block = slice(k * NODE, k * NODE + width)
        h[block, block] += a.T @ a
        g[block] += a.T @ b
        equations.node[k] += (a.T @ a)[:NODE, :NODE]
        equations.node_gradient[k] += (a.T @ b)[:NODE]
        if k + 1 < n:
            equations.node[k + 1] += (a.T @ a)[NODE:, NODE:]
            equations.node_gradient[k + 1] += (a.T @ b)[NODE:]
            equations.chain[k] += (a.T @ a)[:NODE, NODE:]
    equations.offset += 0.25  # the priors
    h[n * NODE :, n * NODE :] += 0.25 * np.eye(n_offsets)
    first = rng.integers(0, n, n_offsets)
    length = rng.integers(0, max(2, n // 2), n_offsets)  # 0: never seen
    for k in range(n):
        seen = np.flatnonzero((first <= k) & (k < first + length))
        if not seen.size:
            continue
        ids = np.repeat(seen, rng.integers(1, 3, seen.size))  # some seen by two rows
        system, column = rng.standard_normal((ids.size, 4)), rng.standard_normal(ids.size)
        a, b = system[:, :3], system[:, 3]
        attitude = slice(k * NODE, k * NODE + 3)
        h[attitude, attitude] += a.T @ a
        g[attitude] += a.T @ b
        no_column = rng.random() < 0.1  # before the factors gain the offsets' column
        equations.add_rows(k, system, None if no_column else column, ids)
        if no_column:
            continue
        for row, j in enumerate(n * NODE + ids):
            h[j, j] += column[row] ** 2
            g[j] += column[row] * b[row]
            h[attitude, j] += a[row] * column[row]
            h[j, attitude] += a[row] * column[row]
    return equations, h, g


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    n=st.integers(1, 14),
    n_offsets=st.integers(1, 24),
    damping=st.sampled_from([0.0, 1e-3, 0.5]),
)
def test_solution_and_predicted_decrease_equal_dense_algebra(seed, n, n_offsets, damping):
    """``solve`` equals ``(H + damping I)^-1 g`` and ``predicted_decrease`` equals
    ``g.x - x.H.x / 2`` with the undamped ``H``, to 1e-9."""
    equations, h, g = _random_system(seed, n, n_offsets)
    expected = np.linalg.solve(h + damping * np.eye(g.size), g)
    x = equations.solve(damping)
    got = np.concatenate([x.nodes.ravel(), x.offsets])
    np.testing.assert_allclose(got, expected, rtol=1e-9, atol=1e-9)
    decrease = g @ expected - 0.5 * expected @ h @ expected
    assert equations.predicted_decrease(x, damping) == pytest.approx(decrease, rel=1e-9, abs=1e-9)


@settings(max_examples=60, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 14), n_offsets=st.integers(1, 24))
def test_marginals_equal_the_inverse(seed, n, n_offsets):
    """The backward sweep's node blocks and offset variances equal those of ``H^-1``."""
    equations, h, _ = _random_system(seed, n, n_offsets)
    covariance = np.linalg.inv(h)
    nodes, variances = equations.marginals()
    for k in range(n):
        block = slice(k * NODE, (k + 1) * NODE)
        np.testing.assert_allclose(nodes[k], covariance[block, block], rtol=1e-8, atol=1e-10)
    np.testing.assert_allclose(variances, np.diagonal(covariance)[n * NODE :], rtol=1e-8)


def test_an_indefinite_system_raises():
    equations, _, _ = _random_system(3, 5, 4)
    equations.node[2] = -np.eye(NODE)
    with pytest.raises(np.linalg.LinAlgError):
        equations.solve()


def test_gtsam_factors_are_scattered_by_key():
    """``add_linear`` adds a factor on two consecutive nodes' attitudes and biases and
    an offset's prior where the dense ``A^T A`` puts them, and refuses a factor between
    nodes that are not neighbours."""
    rng = np.random.default_rng(0)
    keys = structure_keys(3, 2)
    a1, a2, a3, b = (rng.standard_normal((5, 3)) for _ in range(4))
    unit = gtsam.noiseModel.Unit.Create(5)
    graph = gtsam.GaussianFactorGraph()
    graph.add(
        gtsam.JacobianFactor(
            attitude_key(1), a1, attitude_key(2), a2, bias_key(1), a3, b[:, 0], unit
        )
    )
    graph.add(
        gtsam.JacobianFactor(
            offset_key(1), np.array([[2.0]]), np.array([3.0]), gtsam.noiseModel.Unit.Create(1)
        )
    )
    equations = NormalEquations.empty(3, 2)
    equations.add_linear(graph, keys)
    np.testing.assert_allclose(equations.node[1][:3, :3], a1.T @ a1)
    np.testing.assert_allclose(equations.node[1][:3, 3:], a1.T @ a3)
    np.testing.assert_allclose(equations.node[1][3:, 3:], a3.T @ a3)
    np.testing.assert_allclose(equations.node[2][:3, :3], a2.T @ a2)
    np.testing.assert_allclose(equations.chain[1][:3, :3], a1.T @ a2)
    np.testing.assert_allclose(equations.chain[1][3:, :3], a3.T @ a2)
    np.testing.assert_allclose(equations.node_gradient[1][:3], a1.T @ b[:, 0])
    assert equations.offset.tolist() == [0.0, 4.0] and equations.offset_gradient.tolist() == [
        0.0,
        6.0,
    ]
    assert not equations.node[0].any() and not equations.chain[0].any()
    far = gtsam.GaussianFactorGraph()
    far.add(gtsam.JacobianFactor(attitude_key(0), a1, attitude_key(2), a2, b[:, 0], unit))
    with pytest.raises(ValueError, match="joins nodes"):
        NormalEquations.empty(3, 2).add_linear(far, keys)


def _steady_sky(n: int, heard: int = 40) -> NormalEquations:
    """``n`` nodes; aircraft ``j`` rises at node ``j`` and is heard by one row at each of the
    next ``heard`` nodes (so about ``heard`` are in view at once)."""
    rng = np.random.default_rng(n)
    n_offsets = n
    equations = NormalEquations.empty(n, n_offsets)
    equations.node[:] = 2.0 * np.eye(NODE)
    equations.chain[:] = -0.5 * np.eye(NODE)
    equations.offset[:] = 0.25
    for k in range(n):
        ids = np.arange(max(0, k - heard + 1), k + 1)
        equations.add_rows(
            k, rng.standard_normal((ids.size, 4)), rng.standard_normal(ids.size), ids
        )
    return equations


def test_elimination_work_is_linear_in_the_pass_for_a_steady_sky():
    """Each offset leaves the elimination when its aircraft has set: the dense block of each
    node's pivot is 6 plus the aircraft active at it (:func:`active_counts`, bounded in a
    steady sky), so the work, the sum of those blocks' squares, grows at most 2.2x per
    doubling of the pass (the times: ``attopt.experiments.benchmarks.offsets``)."""
    work = []
    for n in (150, 300, 600):
        equations = _steady_sky(n)
        conditionals, isolated = equations.eliminate()
        sizes = np.array([c.parents.size for c in conditionals if c.node >= 0])
        active = active_counts(equations.seen, n)
        assert isolated.size == 0 and np.array_equal(sizes, active)
        assert active.max() <= 40
        work.append(float(np.sum((NODE + sizes) ** 2)))
    assert work[1] / work[0] <= 2.2 and work[2] / work[1] <= 2.2


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), rows=st.integers(1, 12), m=st.integers(0, 80))
def test_the_compiled_update_equals_numpy(seed, rows, m):
    """``downdate`` (numba, in place on the buffer's corner) equals numpy's ``M -= U^T U``
    to round-off, and leaves the rest of the buffer alone."""
    rng = np.random.default_rng(seed)
    buffer = rng.standard_normal((m + 5, m + 5))
    update = rng.standard_normal((rows, m))
    expected = buffer.copy()
    expected[:m, :m] -= update.T @ update
    compiled._downdate(buffer, update, m)
    np.testing.assert_allclose(buffer, expected, rtol=1e-12, atol=1e-12)


@pytest.mark.parametrize("enabled", [True, False])
def test_both_paths_of_the_update_solve_alike(monkeypatch, enabled):
    """The elimination with the compiled update and with numpy's gives the same solution."""
    monkeypatch.setattr(compiled, "compiled_loops", lambda: enabled)
    equations, h, g = _random_system(5, 9, 15)
    x = equations.solve()
    np.testing.assert_allclose(
        np.concatenate([x.nodes.ravel(), x.offsets]), np.linalg.solve(h, g), rtol=1e-9, atol=1e-9
    )
