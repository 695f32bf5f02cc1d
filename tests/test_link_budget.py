"""Link budget (Liu et al. 2023 eqs. 2-4) against hand computations."""

from __future__ import annotations

import math

import numpy as np
import pytest

from attopt.formulations.gain_patterns import LIU2023_HELIX
from attopt.formulations.link_budget import (
    LinkBudget,
    free_space_loss_db,
    isotropic_power_dbw,
    noise_power_dbw,
)
from attopt.formulations.snr_model import snr_db


def test_noise_power_by_hand():
    # k_B T B = 1.380649e-23 J/K * 500 K * 2.6e6 Hz = 1.7948437e-14 W
    # 10 lg: -228.5991 + 26.9897 + 64.1497 = -137.4597 dBW
    assert noise_power_dbw(500.0, 2.6e6) == pytest.approx(-137.4597, abs=1e-4)
    assert LinkBudget().noise_power_dbw == pytest.approx(-137.4597, abs=1e-4)


def test_free_space_loss_by_hand():
    # lambda = c / f = 299792458 / 1.09e9 = 0.2750389 m
    # 4 pi d / lambda = 4 pi 1e6 / 0.2750389 = 4.568932e7, 20 lg = 153.1963 dB
    assert free_space_loss_db(1.0e6, 1.09e9) == pytest.approx(153.1963, abs=1e-4)
    # Twice the distance: + 20 lg 2 = 6.0206 dB.
    assert free_space_loss_db(2.0e6) - free_space_loss_db(1.0e6) == pytest.approx(6.0206, abs=1e-4)


def test_isotropic_power_by_hand():
    # 250 W = 23.9794 dBW; P0 = 23.9794 + 0 dBi - 153.1963 dB - 3 dB = -132.2169 dBW
    assert LinkBudget().transmit_power_dbw == pytest.approx(23.9794, abs=1e-4)
    assert LinkBudget().isotropic_power_dbw(1.0e6) == pytest.approx(-132.2169, abs=1e-4)
    direct = isotropic_power_dbw(10 * math.log10(250.0), 1.0e6, 0.0, 1.09e9, 3.0)
    assert direct == pytest.approx(-132.2169, abs=1e-4)
    # Vectorised over distances.
    np.testing.assert_allclose(
        LinkBudget().isotropic_power_dbw(np.array([1.0e6, 2.0e6])),
        [-132.2169, -138.2375],
        atol=1e-4,
    )


@pytest.mark.parametrize(
    ("distance_km", "expected_db"),
    # 11.6016 dBi + P0 + 137.4597 dB: 11.6016 - 132.2169 + 137.4597 = 16.8444 at 1000 km,
    # 16.8444 - 6.0206 = 10.8238 at 2000 km.
    [(1000.0, 16.8444), (2000.0, 10.8238)],
)
def test_boresight_snr_is_plausible(distance_km, expected_db):
    budget = LinkBudget()
    boresight = np.array([[0.0, 0.0, 1.0]])
    snr = snr_db(
        np.eye(3),
        boresight,  # aircraft straight below: LOS along the nadir boresight
        boresight,
        budget.isotropic_power_dbw(distance_km * 1e3),
        budget.noise_power_dbw,
        LIU2023_HELIX,
    )
    print(f"boresight SNR at {distance_km:.0f} km: {snr[0]:.2f} dB")
    assert snr[0] == pytest.approx(expected_db, abs=1e-4)
    # Above the 6 dB reception threshold of Liu et al. 2023 sec. 5.1, below a strong-signal 30 dB.
    assert 6.0 < snr[0] < 30.0
