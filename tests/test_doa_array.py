"""Yang et al. 2014's array (``formulations/doa_array.py``) and the DOA Cramer-Rao bound
(``formulations/doa_crb.py``): conventions, steering-vector properties, AD
Jacobians, snapshot and sample-covariance statistics and the closed-form UCA
bound."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import ks_2samp

from attopt.formulations.doa_array import (
    YANG2014_UCA,
    doa_from_unit_vector,
    doa_jacobian,
    doa_unit_vector,
    evaluate_mapped,
    simulate_sample_covariance,
    simulate_snapshots,
    steering_vector,
    unit_vector_covariance,
)
from attopt.formulations.doa_crb import stochastic_crb
from attopt.formulations.errors import InvalidObservationError

M = YANG2014_UCA.n_elements
KR = 2.0 * np.pi  # k r with r = lambda = 150 mm
thetas = st.floats(0.0, np.pi / 2)
phis = st.floats(0.0, 2.0 * np.pi)


def test_steering_vector_is_yang2014_eq21() -> None:
    """Pins the DOA convention: theta from the array axis +z, phi from +x towards
    +y, element 1 on +x, elements counter-clockwise, phase lead ``+k r sin theta
    cos(phi - varphi_m)`` (eq. 21)."""
    assert YANG2014_UCA.radius_m == 0.15 and YANG2014_UCA.wavelength_m == 0.15 and M == 12
    np.testing.assert_allclose(YANG2014_UCA.element_directions[3], [0.0, 1.0, 0.0], atol=1e-15)
    np.testing.assert_allclose(doa_unit_vector(np.pi / 2, np.pi / 2), [0.0, 1.0, 0.0], atol=1e-16)
    a = steering_vector(np.arcsin(0.25), 0.0)  # source towards +x: k r sin theta = pi / 2
    np.testing.assert_allclose(a[[0, 3, 6]], [1j, 1.0, -1j], atol=1e-12)  # +x leads, -x lags
    theta, phi = 0.7, 2.0
    m = np.arange(M)
    expected = np.exp(1j * KR * np.sin(theta) * np.cos(phi - 2 * np.pi * m / 12))
    np.testing.assert_allclose(steering_vector(theta, phi), expected, atol=1e-13)


@settings(max_examples=50, deadline=None)
@given(thetas, phis)
def test_steering_vector_properties(theta: float, phi: float) -> None:
    """Unit modulus; ``a^H a = M``; rotating the source by one element spacing
    shifts the elements cyclically; ``phi + pi`` conjugates; ``theta`` and
    ``pi - theta`` are indistinguishable (planar array)."""
    a = steering_vector(theta, phi)
    np.testing.assert_allclose(np.abs(a), 1.0, rtol=1e-14)
    assert np.vdot(a, a).real == pytest.approx(M)
    np.testing.assert_allclose(steering_vector(theta, phi + 2 * np.pi / M), np.roll(a, 1))
    np.testing.assert_allclose(steering_vector(theta, phi + np.pi), np.conj(a), atol=1e-12)
    np.testing.assert_allclose(steering_vector(np.pi - theta, phi), a, atol=1e-12)


@settings(max_examples=50, deadline=None)
@given(st.floats(1e-3, np.pi - 1e-3), phis)
def test_unit_vector_round_trip(theta: float, phi: float) -> None:
    """Eq. 12 and its inverse; the inverse ignores the vector's length."""
    u = doa_unit_vector(theta, phi)
    assert np.linalg.norm(u) == pytest.approx(1.0)
    back_theta, back_phi = doa_from_unit_vector(3.7 * u)
    assert back_theta == pytest.approx(theta, abs=1e-12)
    assert np.angle(np.exp(1j * (back_phi - phi))) == pytest.approx(0.0, abs=1e-12)


@settings(max_examples=25, deadline=None)
@given(thetas, phis)
def test_unit_vector_jacobian_matches_finite_differences(theta: float, phi: float) -> None:
    step = 1e-6
    numeric = np.column_stack(
        [
            (doa_unit_vector(theta + step, phi) - doa_unit_vector(theta - step, phi)) / (2 * step),
            (doa_unit_vector(theta, phi + step) - doa_unit_vector(theta, phi - step)) / (2 * step),
        ]
    )
    np.testing.assert_allclose(doa_jacobian(theta, phi), numeric, atol=1e-9)


def test_unit_vector_covariance_matches_monte_carlo() -> None:
    """First-order ``R_W`` (eq. 22's block) against the scatter of eq. 12 under
    Gaussian angle errors of 0.3 deg (20000 draws, seed 7): within 5 %."""
    rng = np.random.default_rng(7)
    theta, phi = 0.6, 1.2
    covariance = np.diag(np.radians([0.3, 0.3]) ** 2)
    draws = rng.multivariate_normal([theta, phi], covariance, size=20000)
    scatter = np.cov(doa_unit_vector(draws[:, 0], draws[:, 1]).T)
    predicted = unit_vector_covariance(theta, phi, covariance)
    assert np.linalg.norm(scatter - predicted) < 0.05 * np.linalg.norm(predicted)


def test_snapshot_covariance_is_the_model() -> None:
    """Eq. 9: ``E[X X^H] = P a a^H + I`` (SNR 3 dB, 20000 snapshots, seed 11):
    every entry within 4 standard errors (``sqrt((P + 1)^2 / L)``); the same
    seed gives the same snapshots."""
    theta, phi, snr_db, n = 0.5, 4.0, 3.0, 20000
    x = simulate_snapshots(theta, phi, snr_db, n, np.random.default_rng(11))
    assert x.shape == (M, n)
    power = 10 ** (snr_db / 10)
    a = steering_vector(theta, phi)
    expected = power * np.outer(a, a.conj()) + np.eye(M)
    sample = x @ x.conj().T / n
    assert np.abs(sample - expected).max() < 4 * (power + 1) / np.sqrt(n)
    again = simulate_snapshots(theta, phi, snr_db, n, np.random.default_rng(11))
    np.testing.assert_array_equal(x, again)
    with pytest.raises(InvalidObservationError):
        simulate_snapshots(theta, phi, snr_db, -1, np.random.default_rng(11))


def sample_covariances(
    draw: str, snr_db: float, n_snapshots: int, count: int, seed: int
) -> np.ndarray:
    """``count`` sample covariances ``X X^H / L`` at ``theta = 0.5``, ``phi = 4``: drawn
    directly (``"wishart"``) or from :func:`simulate_snapshots` (``"snapshots"``)."""
    rng = np.random.default_rng(seed)
    theta, phi = np.full(count, 0.5), np.full(count, 4.0)
    if draw == "wishart":
        return simulate_sample_covariance(theta, phi, snr_db, n_snapshots, rng)
    x = simulate_snapshots(theta, phi, snr_db, n_snapshots, rng)
    return x @ np.conj(np.swapaxes(x, 1, 2)) / n_snapshots


@pytest.mark.parametrize("n_snapshots", [5, 15])
@pytest.mark.parametrize("draw", ["wishart", "snapshots"])
def test_sample_covariance_moments_are_the_model(draw: str, n_snapshots: int) -> None:
    """Eqs. 9-10 for both draws (20000 covariances at 3 dB, seeded; ``L = 5 < M``
    and ``L = 15``): every entry's mean is ``R = P a a^H + I`` and its variance
    ``E|R_hat_ij - R_ij|^2 = R_ii R_jj / L`` (circular Gaussian columns), each
    within 5 standard errors of the 20000-draw average (the mean's
    ``sqrt(R_ii R_jj / (L n))``, the variance's from the draws' own spread).  A
    chi-square with ``2 (L - k) +- 2`` degrees of freedom biases the mean by
    ``R / L``, 30 or more standard errors."""
    snr_db, count = 3.0, 20000
    a = steering_vector(0.5, 4.0)
    model = 10 ** (snr_db / 10) * np.outer(a, a.conj()) + np.eye(M)
    expected_variance = np.outer(np.diag(model).real, np.diag(model).real) / n_snapshots
    deviation = sample_covariances(draw, snr_db, n_snapshots, count, 5) - model
    mean_error = np.abs(deviation.mean(axis=0)) / np.sqrt(expected_variance / count)
    assert mean_error.max() < 5.0
    squared = np.abs(deviation) ** 2
    variance_error = np.abs(squared.mean(axis=0) - expected_variance) / (
        squared.std(axis=0) / np.sqrt(count)
    )
    assert variance_error.max() < 5.0


@pytest.mark.parametrize("n_snapshots", [1, 5, 20])
def test_sample_covariance_eigenvalues_match_the_snapshot_draw(n_snapshots: int) -> None:
    """Two-sample Kolmogorov-Smirnov on the largest and the smallest nonzero
    eigenvalue (index ``M - min(L, M)``) of 3000 covariances from each draw at
    -10 dB (seeded): p > 0.001; both draws have rank ``min(L, M)``."""
    eigenvalues = [
        np.linalg.eigvalsh(sample_covariances(draw, -10.0, n_snapshots, 3000, seed))
        for draw, seed in [("wishart", 21), ("snapshots", 22)]
    ]
    smallest = M - min(n_snapshots, M)
    for index in {smallest, M - 1}:
        assert ks_2samp(eigenvalues[0][:, index], eigenvalues[1][:, index]).pvalue > 1e-3
    for values in eigenvalues:
        assert (values[:, smallest] > 1e-6).all()
        assert smallest == 0 or np.abs(values[:, smallest - 1]).max() < 1e-12


def test_sample_covariance_cost_does_not_grow_with_the_snapshots() -> None:
    """``L = 10^12`` snapshots take no longer than a few (a snapshot draw would need
    10^13 samples per set): ``R_hat`` is Hermitian, equals ``R`` to ``1e-5``
    relative (its error is ``1 / sqrt(L)``) and has the broadcast shape; the
    same seed gives the same draw; ``L < 1`` raises."""
    theta, phi = np.full((2, 3), 0.5), np.linspace(0.0, 6.0, 6).reshape(2, 3)
    r = simulate_sample_covariance(theta, phi, 3.0, 10**12, np.random.default_rng(2))
    assert r.shape == (2, 3, M, M)
    np.testing.assert_allclose(r, np.conj(np.swapaxes(r, -1, -2)), atol=1e-12)
    a = steering_vector(theta, phi)
    model = 10**0.3 * a[..., :, None] * np.conj(a[..., None, :]) + np.eye(M)
    assert np.abs(r - model).max() < 1e-5 * (10**0.3 + 1)
    again = simulate_sample_covariance(theta, phi, 3.0, 10**12, np.random.default_rng(2))
    np.testing.assert_array_equal(r, again)
    with pytest.raises(InvalidObservationError):
        simulate_sample_covariance(0.5, 4.0, 3.0, 0, np.random.default_rng(2))


@settings(max_examples=40, deadline=None)
@given(st.floats(0.05, 1.5), phis, st.floats(-20.0, 20.0), st.integers(1, 1000))
def test_crb_is_the_closed_form_uca_bound(theta: float, phi: float, snr_db: float, n: int) -> None:
    """The AD bound equals Stoica-Nehorai's closed form for one source on a UCA:
    ``(1 + 1/(M SNR)) / (L M SNR (k r cos theta)^2)`` for theta, ``sin`` for phi,
    uncorrelated."""
    snr = 10 ** (snr_db / 10)
    factor = (1 + 1 / (M * snr)) / (n * M * snr * KR**2)
    crb = stochastic_crb(theta, phi, snr, n)
    expected = np.diag([factor / np.cos(theta) ** 2, factor / np.sin(theta) ** 2])
    np.testing.assert_allclose(crb, expected, rtol=1e-10, atol=1e-12 * factor)


def test_crb_is_infinite_for_unobservable_angles() -> None:
    """``phi`` on the array axis; ``theta`` at the horizon (``cos theta`` = 6e-17: huge)."""
    axis = stochastic_crb(0.0, 1.0, 1.0, 100)
    assert np.isinf(axis[1, 1]) and np.isfinite(axis[0, 0])
    assert stochastic_crb(np.pi / 2, 1.0, 1.0, 100)[0, 0] > 1e20
    np.testing.assert_array_equal(stochastic_crb(0.5, 1.0, np.inf, 100), np.zeros((2, 2)))


def test_mapped_functions_of_no_points_are_empty() -> None:
    """A pass that sees no station: a mapped CasADi function of no points gives empty
    outputs of the function's shapes (MUSIC's refinement of no sets relies on it)."""
    x = ca.SX.sym("x", 2)
    function = ca.Function("f", [x, ca.SX.sym("w")], [x @ x.T, ca.sum1(x)])
    outer, total = evaluate_mapped(function, np.empty((0, 2)), 1.0)
    assert outer.shape == (0, 2, 2) and total.shape == (0, 1, 1)
    (value, _) = evaluate_mapped(function, np.array([[1.0, 2.0]]), 1.0)
    np.testing.assert_array_equal(value[0], [[1.0, 2.0], [2.0, 4.0]])
