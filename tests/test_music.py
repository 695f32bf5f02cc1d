"""MUSIC (``solvers/doa/music.py``, Yang et al. 2014 eq. 11): exactness, agreement with
pyroomacoustics, efficiency against the CRB, the flagged bad inputs, the grid
peak search against a plain reference and the sample-covariance entry point."""

from __future__ import annotations

import numpy as np
import pyroomacoustics as pra
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from attopt.formulations.doa_array import (
    YANG2014_UCA,
    doa_unit_vector,
    simulate_sample_covariance,
    simulate_snapshots,
    steering_vector,
)
from attopt.formulations.doa_crb import stochastic_crb
from attopt.formulations.errors import InvalidObservationError, UnobservableError
from attopt.solvers.doa import MusicEstimator

MUSIC = MusicEstimator()
M = YANG2014_UCA.n_elements


def wrapped(angle: np.ndarray) -> np.ndarray:
    return np.angle(np.exp(1j * angle))


def noise_free(theta: float, phi: float, n_snapshots: int, seed: int) -> np.ndarray:
    """``X = a s`` with complex Gaussian ``s`` and no noise."""
    rng = np.random.default_rng(seed)
    s = rng.standard_normal(n_snapshots) + 1j * rng.standard_normal(n_snapshots)
    return np.outer(steering_vector(theta, phi), s)


@settings(max_examples=30, deadline=None)
@given(
    st.floats(0.01, np.radians(84.0)),
    st.floats(0.0, 2 * np.pi),
    st.integers(2, 50),
    st.integers(0, 2**32 - 1),
)
def test_noise_free_snapshots_recover_the_doa(
    theta: float, phi: float, n_snapshots: int, seed: int
) -> None:
    """To 1e-6 rad, anywhere up to 84 deg (beyond the grid's 70 deg cone);
    the estimated SNR is infinite, so the covariance is zero."""
    result = MUSIC.estimate(noise_free(theta, phi, n_snapshots, seed))
    assert result.valid[0], result.reason[0]
    assert abs(result.theta[0] - theta) < 1e-6
    assert abs(wrapped(result.phi[0] - phi)) < 1e-6
    assert 0.0 <= result.phi[0] < 2 * np.pi
    assert np.abs(result.covariance[0]).max() < 1e-12


def test_estimate_is_the_peak_of_eq11() -> None:
    """The refined DOA maximises ``1 / (a^H V_M V_M^H a)`` with ``V_M`` the ``M - 1``
    noise eigenvectors of ``R`` (0 dB, L = 20): no neighbour 1e-4 rad away is higher."""
    x = simulate_snapshots(0.8, 2.0, 0.0, 20, np.random.default_rng(5))
    result = MUSIC.estimate(x)
    _, vectors = np.linalg.eigh(x @ x.conj().T / 20)
    noise = vectors[:, :-1]

    def spectrum(theta: float, phi: float) -> float:
        projection = noise.conj().T @ steering_vector(theta, phi)
        return 1.0 / np.vdot(projection, projection).real

    theta, phi = result.theta[0], result.phi[0]
    peak = spectrum(theta, phi)
    for d_theta, d_phi in [(1e-4, 0), (-1e-4, 0), (0, 1e-4), (0, -1e-4)]:
        assert spectrum(theta + d_theta, phi + d_phi) < peak


def test_agrees_with_pyroomacoustics_music() -> None:
    """pyroomacoustics' MUSIC on the same snapshots, placed in STFT bin 1 of
    ``nfft = 2`` at ``fs = 2 c / lambda`` (so the bin's wavelength is 150 mm),
    on a 1-degree (azimuth x colatitude) grid: its peak lies within 0.75 deg
    (great circle; half a grid cell's diagonal is 0.71 deg) of ours."""
    c = 299792458.0
    fs = 2.0 * c / YANG2014_UCA.wavelength_m
    positions = (YANG2014_UCA.radius_m * YANG2014_UCA.element_directions).T
    reference = pra.doa.algorithms["MUSIC"](
        positions,
        fs,
        2,
        c=c,
        num_src=1,
        dim=3,
        azimuth=np.radians(np.arange(0.0, 360.0, 1.0)),
        colatitude=np.radians(np.arange(0.5, 70.0, 1.0)),
    )
    rng = np.random.default_rng(2024)
    for theta, phi in [(0.4, 1.0), (0.9, 4.0), (0.2, 2.5)]:
        x = simulate_snapshots(theta, phi, 0.0, 100, rng)
        stft = np.zeros((M, 2, 100), dtype=complex)
        stft[:, 1, :] = x
        reference.locate_sources(stft, freq_bins=[1])
        theirs = doa_unit_vector(reference.colatitude_recon[0], reference.azimuth_recon[0])
        ours = MUSIC.estimate(x)
        mine = doa_unit_vector(ours.theta[0], ours.phi[0])
        assert np.degrees(np.arccos(min(1.0, theirs @ mine))) < 0.75


def test_rmse_approaches_the_crb_at_high_snr() -> None:
    """400 seeded trials at 10 dB, L = 100, theta = 45 deg, phi = 60 deg: RMSE of
    theta and phi within 15 % of the CRB's standard deviation (the RMSE's own
    relative standard error is 3.5 %); the reported covariance (CRB at the
    estimate with the estimated SNR) has median within 10 % of the true CRB."""
    theta, phi, snr_db, n = np.radians(45.0), np.radians(60.0), 10.0, 400
    x = simulate_snapshots(
        np.full(n, theta), np.full(n, phi), snr_db, 100, np.random.default_rng(9)
    )
    result = MUSIC.estimate(x)
    assert result.valid.all()
    crb = stochastic_crb(theta, phi, 10 ** (snr_db / 10), 100)
    rmse_theta = np.sqrt(np.mean((result.theta - theta) ** 2))
    rmse_phi = np.sqrt(np.mean(wrapped(result.phi - phi) ** 2))
    assert rmse_theta / np.sqrt(crb[0, 0]) == pytest.approx(1.0, abs=0.15)
    assert rmse_phi / np.sqrt(crb[1, 1]) == pytest.approx(1.0, abs=0.15)
    reported = np.median(result.covariance[:, [0, 1], [0, 1]], axis=0)
    np.testing.assert_allclose(reported, np.diag(crb), rtol=0.10)


def test_shape_errors_raise() -> None:
    with pytest.raises(InvalidObservationError, match="L = 0"):
        MUSIC.estimate(np.zeros((M, 0), dtype=complex))
    with pytest.raises(InvalidObservationError, match="12"):
        MUSIC.estimate(np.zeros((8, 10), dtype=complex))


def test_non_finite_and_empty_sets_are_rejected_with_a_reason() -> None:
    x = simulate_snapshots(np.full(3, 0.5), np.full(3, 1.0), 10.0, 20, np.random.default_rng(1))
    x[0, 4, 7] = np.nan
    x[1] = 0.0
    result = MUSIC.estimate(x)
    assert list(result.valid) == [False, False, True]
    assert "non-finite" in result.reason[0] and "no signal" in result.reason[1]
    assert np.isnan(result.theta[0]) and np.isnan(result.covariance[1]).all()
    with pytest.raises(InvalidObservationError):
        result.raise_if_invalid(0)


def test_rank_deficient_covariance_is_flagged_and_still_estimated() -> None:
    """L = 5 < M = 12 at 10 dB: valid (noise projector ``I - e e^H``), flagged
    ``rank_deficient``, within 3 deg; L = 1 needs the SNR for its covariance."""
    theta, phi = 0.6, 3.0
    x = simulate_snapshots(theta, phi, 10.0, 5, np.random.default_rng(4))
    result = MUSIC.estimate(x)
    assert result.valid[0] and result.diagnostics["rank_deficient"][0]
    assert abs(result.theta[0] - theta) < np.radians(3.0)
    assert abs(wrapped(result.phi[0] - phi)) < np.radians(3.0)
    single = simulate_snapshots(theta, phi, 10.0, 1, np.random.default_rng(4))
    unknown = MUSIC.estimate(single)
    assert not unknown.valid[0] and "one snapshot" in unknown.reason[0]
    known = MUSIC.estimate(single, snr_db=10.0)
    assert known.valid[0] and np.isfinite(known.covariance[0]).all()


def test_ambiguous_peaks_are_rejected_not_reported() -> None:
    """At -25 dB, L = 10 (seeded, 200 sets) the peak-ratio test rejects at least
    95 % as ambiguous; at -14 dB, L = 100 (400 sets, random directions in the
    paper's 62-degree cone) at most 1 % of the accepted estimates are outside the
    main lobe of the truth (measured: 0.2 %)."""
    rng = np.random.default_rng(12)
    hopeless = MUSIC.estimate(
        simulate_snapshots(np.full(200, 0.5), np.full(200, 1.0), -25.0, 10, rng)
    )
    ambiguous = np.array(["ambiguous" in r for r in hopeless.reason])
    assert ambiguous.mean() >= 0.95
    assert all(e is UnobservableError for e in hopeless.error[ambiguous])
    n = 400
    theta = np.arccos(rng.uniform(np.cos(np.radians(62.0)), 1.0, n))
    phi = rng.uniform(0.0, 2 * np.pi, n)
    result = MUSIC.estimate(simulate_snapshots(theta, phi, -14.0, 100, rng))
    truth = doa_unit_vector(theta, phi)[result.valid, :2]
    estimate = doa_unit_vector(result.theta, result.phi)[result.valid, :2]
    outside = np.linalg.norm(estimate - truth, axis=1) > YANG2014_UCA.first_null_radius / 2
    assert result.valid.sum() > 50
    assert outside.mean() <= 0.01


def test_source_at_the_horizon_is_rejected() -> None:
    """theta = 88 deg (beyond the 85-deg horizon limit) at 20 dB is rejected;
    80 deg, outside the grid's 70-deg cone, is still found."""
    rng = np.random.default_rng(3)
    thetas = np.radians([88.0, 80.0])
    result = MUSIC.estimate(simulate_snapshots(thetas, np.full(2, 1.0), 20.0, 100, rng))
    assert not result.valid[0] and "horizon" in result.reason[0]
    assert result.valid[1] and abs(result.theta[1] - thetas[1]) < np.radians(1.0)


def gather_candidates(
    estimator: MusicEstimator, spectrum: np.ndarray, at_least: np.ufunc = np.greater_equal
) -> tuple[np.ndarray, np.ndarray]:
    """Reference grid peak search: each point's 8 lattice neighbours gathered by index
    (``-inf`` outside the cone); a local maximum is ``at_least`` its highest one."""
    lattice = np.rint(estimator.grid / estimator.grid_step).astype(int)
    index = {(i, j): k for k, (i, j) in enumerate(lattice)}
    offsets = [(a, b) for a in (-1, 0, 1) for b in (-1, 0, 1) if (a, b) != (0, 0)]
    neighbours = np.array([[index.get((i + a, j + b), -1) for a, b in offsets] for i, j in lattice])
    padded = np.concatenate([spectrum, np.full((len(spectrum), 1), -np.inf)], axis=1)
    highest = padded[:, neighbours].max(axis=-1)
    main = np.argmax(spectrum, axis=1)
    distance = np.linalg.norm(estimator.grid[:, None] - estimator.grid[None], axis=-1)
    outside = distance > estimator.array.first_null_radius
    masked = np.where(at_least(spectrum, highest) & outside[main], spectrum, -np.inf)
    second = np.argmax(masked, axis=1)
    found = np.isfinite(masked[np.arange(len(main)), second])
    return main, np.where(found, second, main)


def grid_spectra(snr_db: float, n_snapshots: int, n: int, rng: np.random.Generator) -> np.ndarray:
    """``s = |e^H a|^2 / M`` on MUSIC's grid for ``n`` random directions in the 62-deg cone."""
    theta = np.arccos(rng.uniform(np.cos(np.radians(62.0)), 1.0, n))
    x = simulate_snapshots(theta, rng.uniform(0.0, 2 * np.pi, n), snr_db, n_snapshots, rng)
    principal = np.linalg.eigh(x @ np.conj(np.swapaxes(x, 1, 2)))[1][:, :, -1]
    return np.abs(np.conj(principal) @ MUSIC._grid_steering) ** 2 / M


def test_grid_peaks_equal_the_neighbour_gather_reference() -> None:
    """The grid peak search returns exactly the reference's main and second grid
    indices on noisy spectra (-14 dB, L = 100; 0 dB, L = 1 and 10; 20 dB, L = 100;
    seeded), on spectra quantised to steps of 0.05 (plateaus: a local maximum
    ties with a neighbour), on a flat spectrum (every point ties), on NaN and
    infinite values and on cones ``exp(-|p - p0|)`` with a small bump elsewhere, where the highest
    point outside the main lobe lies on the cone's slope (no local maximum), so
    all local maxima are searched.  The quantised spectra exercise the tie
    rule: with a strict ``>`` the reference's answers change."""
    rng = np.random.default_rng(31)
    noisy = np.concatenate(
        [grid_spectra(snr, n, 250, rng) for snr, n in [(-14, 100), (0, 1), (0, 10), (20, 100)]]
    )
    quantised = np.round(noisy[:500] * 20.0) / 20.0
    flat = np.full((3, len(MUSIC.grid)), 1.0 / M)
    non_finite = noisy[:5].copy()
    non_finite[np.arange(4), [0, 500, np.argmax(noisy[2]), np.argmin(noisy[3])]] = np.nan
    non_finite[4, [0, -1]] = np.inf  # two infinite peaks, far apart
    centres = rng.uniform(-0.6, 0.6, (40, 2, 1, 2))
    distance = np.linalg.norm(MUSIC.grid - centres, axis=-1)
    slopes = np.exp(-distance[:, 0]) + 0.2 * np.exp(-((distance[:, 1] / 0.1) ** 2))
    for spectra in (noisy, quantised, flat, non_finite, slopes):
        main, second = MUSIC._candidates(spectra)
        expected_main, expected_second = gather_candidates(MUSIC, spectra)
        np.testing.assert_array_equal(main, expected_main)
        np.testing.assert_array_equal(second, expected_second)
    lobe = np.linalg.norm(MUSIC.grid[main][:, None] - MUSIC.grid, axis=-1)
    outside = lobe > YANG2014_UCA.first_null_radius
    highest_outside = np.argmax(np.where(outside, slopes, -np.inf), axis=1)
    assert ((second != highest_outside) & (second != main)).any()
    assert (second == main).any()
    strict = gather_candidates(MUSIC, quantised, np.greater)[1]
    assert (strict != MUSIC._candidates(quantised)[1]).any()


def test_covariance_entry_point_equals_the_snapshot_one() -> None:
    """``estimate_covariance(X X^H / L, L)`` gives what ``estimate(X)`` gives, bit for
    bit (0 dB at L = 1 with and without the SNR, L = 5 (rank-deficient) and
    L = 30, one set with NaN, one all-zero); bad shapes and ``L`` raise."""
    rng = np.random.default_rng(8)
    for n_snapshots in (1, 5, 30):
        x = simulate_snapshots(
            rng.uniform(0.1, 1.0, 40), rng.uniform(0, 6, 40), 0.0, n_snapshots, rng
        )
        x[3, 2, 0] = np.nan
        x[4] = 0.0
        finite = np.where(np.isfinite(x), x, 0.0)
        covariance = finite @ np.conj(np.swapaxes(finite, 1, 2)) / n_snapshots
        covariance[3, 0, 0] = np.inf
        for snr_db in (None, 0.0):
            ours = MUSIC.estimate_covariance(covariance, n_snapshots, snr_db=snr_db)
            reference = MUSIC.estimate(x, snr_db=snr_db)
            for name in ("theta", "phi", "covariance", "valid", "error"):
                np.testing.assert_array_equal(getattr(ours, name), getattr(reference, name))
            for name, values in reference.diagnostics.items():
                np.testing.assert_array_equal(ours.diagnostics[name], values)
            assert ours.reason[3] == "non-finite covariance"
            others = np.arange(len(x)) != 3
            np.testing.assert_array_equal(ours.reason[others], reference.reason[others])
    with pytest.raises(InvalidObservationError, match="12, 12"):
        MUSIC.estimate_covariance(np.zeros((M, M - 1)), 10)
    with pytest.raises(InvalidObservationError, match=">= 1"):
        MUSIC.estimate_covariance(np.eye(M), 0)


def test_rmse_and_acceptance_agree_between_the_covariance_and_snapshot_draws() -> None:
    """MUSIC on covariances drawn by ``simulate_sample_covariance`` and on those of
    ``simulate_snapshots`` (2000 sets each, random directions, seeded) at
    -12 dB, L = 100 (about 80 % accepted) and 0 dB, L = 5: the accepted fractions
    and the mean squared direction-cosine errors of the accepted estimates agree
    within 4 standard errors of their difference."""
    n = 2000
    for snr_db, n_snapshots, seed in [(-12.0, 100, 40), (0.0, 5, 41)]:
        rng = np.random.default_rng(seed)
        theta = np.arccos(rng.uniform(np.cos(np.radians(62.0)), 1.0, n))
        phi = rng.uniform(0.0, 2 * np.pi, n)
        truth = doa_unit_vector(theta, phi)[:, :2]
        drawn = simulate_sample_covariance(theta, phi, snr_db, n_snapshots, rng)
        direct = MUSIC.estimate_covariance(drawn, n_snapshots, snr_db=snr_db)
        snapshots = MUSIC.estimate(
            simulate_snapshots(theta, phi, snr_db, n_snapshots, rng), snr_db=snr_db
        )
        accepted = [r.valid.mean() for r in (direct, snapshots)]
        pooled = np.mean(accepted)
        assert abs(accepted[0] - accepted[1]) < 4.0 * np.sqrt(2 * pooled * (1 - pooled) / n)
        squared = [
            np.sum((doa_unit_vector(r.theta, r.phi)[r.valid, :2] - truth[r.valid]) ** 2, axis=1)
            for r in (direct, snapshots)
        ]
        error = np.sqrt(sum(e.var() / e.size for e in squared))
        assert abs(squared[0].mean() - squared[1].mean()) < 4.0 * error


def test_no_sets_give_no_estimates() -> None:
    """Zero covariances (no station visible) give empty estimates of every field."""
    result = MUSIC.estimate_covariance(np.empty((0, M, M), dtype=complex), 100, snr_db=0.0)
    assert result.theta.shape == result.valid.shape == (0,) and result.covariance.shape == (0, 2, 2)
    assert all(value.shape == (0,) for value in result.diagnostics.values())


CRB_ONLY = MusicEstimator(threshold_variance_factor=1.0)
"""MUSIC whose covariance is the CRB at every output SNR."""


def _nees(
    snr_db: float, n_snapshots: int, n: int, seed: int, music: MusicEstimator = CRB_ONLY
) -> np.ndarray:
    """NEES (2 dof) of ``n`` estimates (random directions in the paper's 62 deg cone,
    seeded; the accepted ones) against the covariance ``music`` reports."""
    rng = np.random.default_rng(seed)
    theta = np.arccos(rng.uniform(np.cos(np.radians(62.0)), 1.0, n))
    phi = rng.uniform(0.0, 2.0 * np.pi, n)
    r = simulate_sample_covariance(theta, phi, snr_db, n_snapshots, rng, YANG2014_UCA)
    result = music.estimate_covariance(r, n_snapshots, snr_db=snr_db)
    v = result.valid
    error = np.column_stack([result.theta[v] - theta[v], wrapped(result.phi[v] - phi[v])])
    return np.einsum("ni,nij,nj->n", error, np.linalg.inv(result.covariance[v]), error)


def _share_beyond_quantile(nees: np.ndarray) -> float:
    """Share of ``nees`` beyond the chi-square(2) 1 - 1e-4 quantile."""
    return float(np.mean(nees > -2.0 * np.log(1e-4)))


@pytest.mark.slow
def test_estimates_below_the_threshold_output_snr_are_marked_and_have_heavier_tails() -> None:
    """``below_threshold`` marks ``L M SNR < 150``; 30,000 sets each: at 0 dB, L = 10
    (output SNR 120) the share beyond the CRB's 1 - 1e-4 quantile is above 0.001, at 0 dB,
    L = 50 (600) below 0.0006 (the module docstring's threshold region)."""
    r = simulate_sample_covariance(
        np.full(2, 0.5), np.full(2, 1.0), 0.0, 10, np.random.default_rng(2), YANG2014_UCA
    )
    for n_snapshots, below in [(10, True), (13, False)]:
        result = MUSIC.estimate_covariance(r, n_snapshots, snr_db=0.0)
        assert (result.diagnostics["below_threshold"] == below).all()
        np.testing.assert_allclose(result.diagnostics["output_snr"], 12.0 * n_snapshots)
    assert _share_beyond_quantile(_nees(0.0, 10, 30_000, seed=5)) > 0.001
    assert _share_beyond_quantile(_nees(0.0, 50, 30_000, seed=6)) < 0.0006


def test_below_the_threshold_the_covariance_is_the_crb_widened() -> None:
    """Below ``threshold_output_snr`` the covariance is the CRB times
    ``threshold_variance_factor``, above it the CRB; at 0 dB, L = 10 (output SNR 120) the
    errors' mean NEES against the CRB exceeds its 2 by more than 10 % (8,000 sets;
    measured 2.3), and against the widened covariance it is below 2."""
    r = simulate_sample_covariance(
        np.full(2, 0.5), np.full(2, 1.0), 0.0, 10, np.random.default_rng(3), YANG2014_UCA
    )
    for n_snapshots, factor in [(10, 2.0), (13, 1.0)]:
        widened = MUSIC.estimate_covariance(r, n_snapshots, snr_db=0.0)
        crb = CRB_ONLY.estimate_covariance(r, n_snapshots, snr_db=0.0)
        np.testing.assert_allclose(widened.theta, crb.theta)
        np.testing.assert_allclose(widened.covariance, factor * crb.covariance, rtol=1e-12)
    assert np.mean(_nees(0.0, 10, 8_000, seed=7)) > 2.2
    assert np.mean(_nees(0.0, 10, 8_000, seed=7, music=MUSIC)) < 2.0
