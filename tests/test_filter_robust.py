"""The Huber loss in the MEKF's and USQUE's updates (``FilterOptions.huber_threshold``).

Scenario: :mod:`tests.filter_passes` (two unit vectors at 1 Hz, a 2 Hz MEMS-class gyro).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import VectorMeasurement
from attopt.formulations.conventions import attitude_error
from attopt.solvers.filters import FilterOptions, Mekf, Usque
from attopt.solvers.filters.common import robust_noise
from tests.filter_passes import drawn_prior, prior_covariance, simulate_pass, solve_with

OUTLIER = 10
SIGMA = 2e-3


def _outlier_pass():
    """Epoch 10's second vector turned by 2 deg (60 sigma); the same pass without it."""
    rng = np.random.default_rng(23)
    run = simulate_pass(rng, duration=30.0, sigma=SIGMA)
    prior = drawn_prior(rng, run, prior_covariance(np.radians(2.0)))
    clean = list(run.measurements)
    good = run.measurements[OUTLIER]
    body = good.z.reshape(-1, 3)
    clean[OUTLIER] = VectorMeasurement(body[:1], good.reference[:1], SIGMA)
    turned = Rotation.from_rotvec(np.radians(2.0) * body[0]).apply(body[1])
    run.measurements[OUTLIER] = VectorMeasurement(
        np.vstack([body[0], turned]), good.reference, SIGMA
    )
    return run, prior, clean


@pytest.mark.parametrize("filter_class", [Mekf, Usque])
def test_huber_loss_downweights_an_ungated_outlier(filter_class):
    """With gating off, the turned vector pulls the Gaussian update at epoch 10 by many
    sigmas; with the Huber loss (k = 3 on the block's whitened norm) the block is
    down-weighted, counted, and the error stays within a few times the clean pass's.
    Without an outlier about 1 % of the blocks (two here) pass k = 3 by chance (the
    norm of a vector block's innovation is chi with two degrees of freedom) and the
    Huber estimates stay within a quarter sigma of the Gaussian ones."""
    run, prior, clean = _outlier_pass()
    no_test = {"gate_probability": 1.0, "consistency_window": 0, "recovery": "none"}
    plain = filter_class(filter=FilterOptions(**no_test))
    huber = filter_class(filter=FilterOptions(**no_test, huber_threshold=3.0))
    truth = run.truth_at_epochs

    def error_deg(track) -> float:
        return float(np.degrees(np.abs(attitude_error(track.attitude(), truth)[OUTLIER]).max()))

    outlier_plain = solve_with(plain, run.gyro, run.t, run.measurements, prior)
    outlier_huber = solve_with(huber, run.gyro, run.t, run.measurements, prior)
    reference = solve_with(plain, run.gyro, run.t, clean, prior)
    assert outlier_plain.diagnostics["n_downweighted"].sum() == 0
    assert outlier_huber.diagnostics["n_downweighted"][OUTLIER] == 1
    assert error_deg(outlier_plain) > 5.0 * error_deg(reference)
    assert error_deg(outlier_huber) < 3.0 * error_deg(reference)
    clean_huber = solve_with(huber, run.gyro, run.t, clean, prior)
    assert clean_huber.diagnostics["n_downweighted"].sum() <= 3  # 1 % of the blocks, 0.6
    difference = attitude_error(clean_huber.attitude(), reference.attitude())
    sigma = np.sqrt(np.einsum("kii->ki", reference.covariance))
    assert np.all(np.abs(difference) < 0.25 * sigma)


def test_the_threshold_is_checked():
    with pytest.raises(ValueError, match="huber_threshold"):
        FilterOptions(huber_threshold=0.0)


@given(
    st.lists(st.floats(1e-6, 1e3), min_size=3, max_size=3),
    st.lists(st.floats(0.0, 1e4), min_size=3, max_size=3),
    st.floats(0.5, 5.0),
)
def test_variances_and_a_diagonal_matrix_are_weighted_alike(variances, nis, threshold):
    """Rows 0 and 2 of three, weights ``min(1, k / sqrt(nis))``: the variances divided by
    them equal the diagonal of the weighted matrix, and the off-diagonal stays zero."""
    rows = np.array([0, 2])
    variances, nis = np.array(variances), np.array(nis)[rows]
    weighted, down = robust_noise(variances, rows, nis, threshold)
    matrix, down_matrix = robust_noise(np.diag(variances), rows, nis, threshold)
    np.testing.assert_array_equal(down, down_matrix)
    np.testing.assert_allclose(np.diag(matrix), weighted, rtol=1e-12)
    assert np.count_nonzero(matrix - np.diag(np.diag(matrix))) == 0
    expected = variances.copy()
    with np.errstate(divide="ignore"):
        w = np.minimum(1.0, threshold / np.sqrt(nis))
    expected[rows] = variances[rows] / w
    np.testing.assert_allclose(weighted, expected, rtol=1e-12)
    assert weighted[1] == variances[1]
    np.testing.assert_array_equal(robust_noise(variances, rows, nis, None)[0], variances)
