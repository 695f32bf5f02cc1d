"""The filters' compiled update algebra (:mod:`attopt.solvers.filters.update_kernels`)
against its numpy reference, and the dispatch between them."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from attopt.solvers.filters import common, update_kernels, usque


def _blocks_case(seed: int, k: int, full: bool) -> tuple[np.ndarray, ...]:
    """Innovations, factor ``(k, m)``, weight, noise and shuffled labels of blocks of sizes
    1-4; the weight has a negative centre entry when ``k = 13`` (USQUE's covariance
    weights)."""
    rng = np.random.default_rng(seed)
    sizes = rng.integers(1, 5, size=rng.integers(1, 7))
    labels = np.repeat(rng.permutation(50)[: sizes.size], sizes)
    labels = labels[rng.permutation(labels.size)]
    m = labels.size
    factor = rng.normal(size=(k, m)) * 10.0 ** rng.uniform(-4, 0)
    if k == 13:
        weight = np.diag(usque.COVARIANCE_WEIGHTS)
    else:
        a = rng.normal(size=(k, k))
        weight = a @ a.T
    variances = 10.0 ** rng.uniform(-8, 0, size=m)
    if not full:
        return rng.normal(size=m), factor, weight, variances, labels
    noise = np.diag(variances)
    for label in np.unique(labels):  # correlated within a block, as R is
        rows = np.flatnonzero(labels == label)
        b = rng.normal(size=(rows.size, rows.size)) * np.sqrt(variances[rows])[:, None]
        noise[np.ix_(rows, rows)] += b @ b.T
    return rng.normal(size=m), factor, weight, noise, labels


ROUND_OFF = 1e-13
"""Relative difference allowed per unit of a block's condition number (about 450 machine
epsilons; 32,000 random blocks of this test's kinds gave at most 2.7e-15)."""


@settings(max_examples=80, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.sampled_from([3, 6, 7, 13]), full=st.booleans())
def test_compiled_block_nis_equals_the_numpy_reference(seed: int, k: int, full: bool) -> None:
    """Blocks of mixed sizes in any order, variances or a full ``R``, any factor: the same
    normalised innovations and sizes, to round-off: relative to each block's ``cond(S_b)``
    times :data:`ROUND_OFF` (the two solve ``S_b`` by elimination in other orders: 1.3e-9
    relative at a condition number of 6e7)."""
    innovation, factor, weight, noise, labels = _blocks_case(seed, k, full)
    members = common.block_structure(labels).members.members
    nis, sizes = update_kernels.block_nis(innovation, factor, weight, noise, members)
    nis_ref, sizes_ref = common.block_nis_reference(innovation, factor, weight, noise, labels)
    np.testing.assert_array_equal(sizes, sizes_ref)
    for label in np.unique(labels):
        rows = np.flatnonzero(labels == label)
        columns = factor[:, rows]
        s = columns.T @ weight @ columns + (
            noise[np.ix_(rows, rows)] if full else np.diag(noise[rows])
        )
        tolerance = max(1e-12, ROUND_OFF * np.linalg.cond(s))
        np.testing.assert_allclose(nis[rows], nis_ref[rows], rtol=tolerance)


@pytest.mark.parametrize("enabled", [True, False])
def test_the_gate_takes_either_path_and_rejects_what_is_not_finite(
    monkeypatch: pytest.MonkeyPatch, enabled: bool
) -> None:
    """A NaN innovation row, and a non-finite factor column, reject their whole block and no
    other; the others are gated alike on both paths."""
    monkeypatch.setattr(common, "compiled_loops", lambda: enabled)
    weight = _blocks_case(7, 6, False)[2]
    labels = np.repeat(np.arange(4), 3)
    innovation, factor, noise = np.zeros(12), 1e-3 * np.ones((6, 12)), np.full(12, 1e-6)
    innovation[[0, 4, 8]] = [1e-3, np.nan, 1.0]  # small, NaN, far beyond the gate
    factor[2, 10] = np.inf
    nis, sizes = common.block_nis(innovation, factor, weight, noise, labels)
    assert np.isnan(nis[3:6]).all() and np.isnan(nis[9:]).all() and (sizes == 3).all()
    keep = common.gate(innovation, factor, weight, noise, labels, 0.9999)
    np.testing.assert_array_equal(keep, np.repeat([True, False, False, False], 3))


@settings(max_examples=80, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    m=st.integers(0, 30),
    n=st.sampled_from([6, 7, 9]),
    scale=st.sampled_from([1e-6, 1e-3, 1.0, 1e3]),
)
def test_compiled_gain_equals_the_numpy_reference(seed: int, m: int, n: int, scale: float) -> None:
    """Any number of rows (none included), states with offsets, Jacobians of any scale:
    the same gain, normalised innovation and posterior to round-off (relative to the
    largest entry, times the posterior information's condition number)."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(n, n))
    information = np.linalg.inv(1e-4 * (a @ a.T) + 1e-6 * np.eye(n))
    h, innovation = scale * rng.normal(size=(m, n)), rng.normal(size=m)
    variances = 10.0 ** rng.uniform(-8, 0, size=m)
    out = update_kernels.information_gain(information, h, variances, innovation)
    reference = common.gain_reference(information, h, variances, innovation)
    # round-off of the two summation orders, amplified by the posterior's conditioning
    condition = np.linalg.cond(information + h.T @ (h / variances[:, None]))
    (gain, nis, posterior), (gain_ref, nis_ref, posterior_ref) = out, reference
    for x, y in ((gain, gain_ref), (posterior, posterior_ref)):
        scale = np.max(np.abs(y), initial=0.0)
        np.testing.assert_allclose(x, y, rtol=0, atol=1e-14 * condition * scale)
    # nu^T R^-1 nu less the projection: a difference of terms up to nu^T R^-1 nu
    terms = float(innovation @ (innovation / variances))
    assert abs(nis - nis_ref) <= 1e-14 * condition * terms


@pytest.mark.parametrize("enabled", [True, False])
def test_the_gain_takes_either_path_and_a_full_noise_matrix_the_numpy_one(
    monkeypatch: pytest.MonkeyPatch, enabled: bool
) -> None:
    """``kalman_gain`` gives the same results on both paths, from the covariance or the
    information; a full ``R`` always goes through the reference."""
    monkeypatch.setattr(common, "compiled_loops", lambda: enabled)
    rng = np.random.default_rng(2)
    a = rng.normal(size=(6, 6))
    covariance = 1e-4 * (a @ a.T) + 1e-6 * np.eye(6)
    h, innovation, variances = rng.normal(size=(4, 6)), rng.normal(size=4), np.full(4, 1e-3)
    expected = common.gain_reference(np.linalg.inv(covariance), h, variances, innovation)
    for given_information in (None, np.linalg.inv(covariance)):
        out = common.kalman_gain(covariance, h, variances, innovation, given_information)
        for x, y in zip(out, expected, strict=True):
            np.testing.assert_allclose(x, y, rtol=1e-9)
    full = common.kalman_gain(covariance, h, np.diag(variances), innovation)
    for x, y in zip(full, expected, strict=True):
        np.testing.assert_allclose(x, y, rtol=1e-9)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(0, 13), scale=st.sampled_from([0, 1e-6, 2]))
def test_compiled_error_reset_equals_the_numpy_reference(seed: int, k: int, scale: float) -> None:
    """One error, ``k`` errors on one attitude, ``k`` errors on ``k`` attitudes: the same
    quaternions to round-off; a shape the loop does not take goes through numpy."""
    rng = np.random.default_rng(seed)
    one, many = Rotation.random(rng=rng).as_quat(), Rotation.random(k, rng=rng).as_quat()
    deltas = scale * rng.normal(size=(k, 3))
    cases = [(deltas[0] if k else np.zeros(3), one), (deltas, one), (deltas, many)]
    cases.append((np.zeros(3), many))  # one error on many attitudes: numpy broadcasting
    for delta, reference in cases:
        out = common.perturb_quaternion(delta, reference)
        expected = common.perturbation_reference(delta, reference)
        assert out.shape == expected.shape
        np.testing.assert_allclose(out, expected, rtol=1e-14, atol=1e-15)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), shift=st.sampled_from([-1.0, -1e-9, 0.0, 1e-9, 1.0]))
def test_the_definiteness_test_and_the_smallest_variance_agree_with_lapack(
    seed: int, shift: float
) -> None:
    """Symmetric matrices near and beyond positive definiteness: the compiled test agrees
    with numpy's Cholesky factorisation, the repair gives the same matrix on both paths,
    and the smallest attitude variance is numpy's ``eigvalsh``'s."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(6, 6))
    values = np.abs(rng.normal(size=6))
    values[0] = shift
    q = np.linalg.qr(a)[0]
    p = (q * values) @ q.T
    p[0, 1] += 1e-17  # not exactly symmetric
    symmetric, positive = update_kernels.symmetric_positive(p)
    np.testing.assert_array_equal(symmetric, 0.5 * (p + p.T))
    try:
        np.linalg.cholesky(symmetric)
        numpy_positive = True
    except np.linalg.LinAlgError:
        numpy_positive = False
    if abs(shift) > 1e-12:  # at the boundary either answer is round-off
        assert positive == numpy_positive == (shift > 0)
    with pytest.MonkeyPatch.context() as patch:
        repaired = []
        for enabled in (True, False):
            patch.setattr(common, "compiled_loops", lambda enabled=enabled: enabled)
            repaired.append(common.repair_covariance(p))
    if abs(shift) > 1e-12:
        np.testing.assert_allclose(repaired[0][0], repaired[1][0], rtol=1e-12, atol=1e-15)
        assert repaired[0][1] == repaired[1][1]
    expected = np.linalg.eigvalsh(symmetric[:3, :3])[0]
    assert update_kernels.smallest_attitude_variance(symmetric) == pytest.approx(
        expected, abs=1e-14
    )


def test_a_covariance_that_is_not_finite_is_passed_on_unrepaired_on_both_paths(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """numpy's factorisation does not raise for NaN: the repair returns it as it is, so the
    filter's own finiteness test reports it."""
    for enabled in (True, False):
        monkeypatch.setattr(common, "compiled_loops", lambda enabled=enabled: enabled)
        out, repaired = common.repair_covariance(np.full((6, 6), np.nan))
        assert np.isnan(out).all() and not repaired


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_an_attitude_block_that_is_not_finite_asks_for_another_iteration(bad: float) -> None:
    """The compiled smallest variance of a block with a NaN or infinite entry is NaN (no
    exception), so the iteration test is not met and the filter's own finiteness checks
    report the update."""
    covariance = np.eye(6)
    covariance[1, 1] = bad
    assert np.isnan(update_kernels.smallest_attitude_variance(covariance))
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(common, "compiled_loops", lambda: True)
        assert not common.linearised(np.zeros(6), covariance, 0.1)
