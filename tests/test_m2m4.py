"""M2M4 SNR estimator (Pimienta-Penalver and Crassidis eqs. 8-11, Table 3): unbiased at high
SNR, flags invalid input."""

from __future__ import annotations

import numpy as np
import pytest

from attopt.formulations.errors import InvalidObservationError
from attopt.solvers.geo.m2m4 import (
    NEGATIVE_DISCRIMINANT,
    TABLE3_PAPER_DB,
    TABLE3_SNR_DB,
    ZERO_NOISE,
    estimate_snr,
    simulate_psk,
    snr_table,
)


def test_simulated_samples_have_the_requested_powers():
    y = simulate_psk(np.array([3.0]), 200_000, np.random.default_rng(1), signal_power=2.0)
    power = np.mean(np.abs(y) ** 2)  # S + N = 2 (1 + 10^-0.3)
    assert power == pytest.approx(2.0 * (1 + 10**-0.3), rel=5e-3)


def test_unbiased_at_high_snr_with_many_samples():
    # 200 records of 4096 QPSK samples per SNR, seed 7: std of one estimate ~0.1 dB,
    # so the mean's standard error is ~0.008 dB; tolerance 0.03 dB.
    table = snr_table(np.random.default_rng(7), 4096, 200, true_db=(10.0, 20.0))
    np.testing.assert_allclose(table.mean_db, [10.0, 20.0], atol=0.03)
    assert np.all(table.invalid_fraction == 0)


def test_biased_upward_at_low_snr_and_few_samples():
    # -5 dB with 64 samples: about +3 dB and a quarter of the estimates invalid.
    table = snr_table(np.random.default_rng(8), 64, 2000, true_db=(-5.0,))
    assert table.mean_db[0] > -5.0 + 1.5
    assert table.invalid_fraction[0] > 0.1


def test_table3_reproduced():
    # 1024 QPSK samples, 300 records per SNR, seed 0: within 0.1 dB of the truth and of the paper.
    table = snr_table(np.random.default_rng(0), 1024, 300)
    np.testing.assert_allclose(table.mean_db, TABLE3_SNR_DB, atol=0.1)
    np.testing.assert_allclose(table.mean_db, TABLE3_PAPER_DB, atol=0.15)


def test_negative_discriminant_is_flagged_invalid_not_nan():
    # One strong sample among zeros: M2 = 25, M4 = 2500, 2 M2^2 - M4 = 1250 - 2500 < 0.
    estimate = estimate_snr(np.array([10.0, 0.0, 0.0, 0.0], dtype=complex))
    assert not estimate.valid
    assert estimate.reason == NEGATIVE_DISCRIMINANT
    assert np.ma.is_masked(estimate.snr_db)


def test_noise_free_samples_are_flagged_unbounded():
    estimate = estimate_snr(np.exp(2j * np.pi * np.arange(16) / 4))
    assert not estimate.valid and estimate.reason == ZERO_NOISE
    assert estimate.signal_power == pytest.approx(1.0)


def test_bad_samples_raise():
    with pytest.raises(InvalidObservationError):
        estimate_snr(np.array([1.0 + 0j]))
    with pytest.raises(InvalidObservationError):
        estimate_snr(np.array([1.0, np.nan]))
