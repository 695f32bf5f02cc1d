"""Pimienta-Penalver and Crassidis's link (eqs. 1-7): hand computation from Table 1,
numpy = CasADi, AD Jacobian."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.geo_fisher import snr_attitude_jacobian
from attopt.formulations.geo_link import (
    GARUDA1,
    GeoLink,
    attitude_pointing,
    geo_snr_db,
    main_lobe_snr_db,
)

SATELLITE = np.array([42_164.0, 0.0, 0.0])
BELOW = np.array([[6_378.0, 0.0, 0.0]])  # station directly below: d = h = 35,786 km


def test_link_budget_matches_hand_computation_from_table1():
    # Table 1: P_t = 12 kW, D = 12 m, C = 10, R_s = 2.4 kb/s, f = 1550 MHz; T_r = 38 K, eta = 0.55.
    wavelength = 299_792_458.0 / 1.55e9  # 0.193414 m
    g_max = 10 * math.log10(0.55 * (math.pi * 12 / 0.193414) ** 2)  # 0.55 * 194.92^2 = 20,896
    assert g_max == pytest.approx(43.200, abs=1e-3)
    eirp = 10 * math.log10(12_000) + 43.200  # 40.792 + 43.200 = 83.992 dBW
    free_space = 20 * math.log10(4 * math.pi * 35_786e3 / 0.193414)  # 20 lg(2.3251e9) = 187.329
    elevation_loss = 20 * math.log10(35_786 / 35_786)  # 0 dB at zenith
    g_over_t = 0.0 - 10 * math.log10(38)  # -15.798 dB/K
    boltzmann = 10 * math.log10(1.380649e-23)  # -228.599 dBW/(K Hz)
    rate = 10 * math.log10(2_400)  # 33.802 dB Hz
    snr = eirp - free_space - elevation_loss + g_over_t - boltzmann - rate  # 75.663 dB
    assert GARUDA1.wavelength_m == pytest.approx(wavelength)
    assert GARUDA1.peak_gain_dbi == pytest.approx(g_max, abs=1e-4)  # rounded lambda
    assert GARUDA1.peak_eirp_dbw == pytest.approx(83.992, abs=1e-3)
    assert snr == pytest.approx(75.663, abs=1e-3)
    nadir = attitude_pointing(-SATELLITE).as_matrix()
    assert geo_snr_db(nadir, SATELLITE, BELOW)[0] == pytest.approx(snr, abs=1e-3)
    # eq. 5 off the boresight: theta_3dB = 70 lambda / D = 1.12825 deg, C = 10.
    theta = math.radians(1.0)
    tilted = (Rotation.from_rotvec([theta, 0, 0]) * attitude_pointing(-SATELLITE)).as_matrix()
    drop = 10 * (1.0 / 1.12825) ** 2  # 7.856 dB
    assert geo_snr_db(tilted, SATELLITE, BELOW)[0] == pytest.approx(snr - drop, abs=1e-3)


def test_eq4_approximation_is_efficiency_0549():
    link = GeoLink(efficiency=6.9 / (4 * math.pi))
    area = math.pi * 12.0**2 / 4
    assert link.peak_gain_dbi == pytest.approx(10 * math.log10(6.9 * area / link.wavelength_m**2))


def test_elevation_attenuation_is_20_lg_d_over_h():
    station = np.array([6_378.0 * math.cos(0.3), 6_378.0 * math.sin(0.3), 0.0])
    d = np.linalg.norm(SATELLITE - station)
    h = 42_164.0 - 6_378.0
    expected = 20 * math.log10(4e3 * math.pi * d / GARUDA1.wavelength_m) + 20 * math.log10(d / h)
    assert GARUDA1.path_loss_db(d, h) == pytest.approx(expected)


def test_numpy_and_casadi_give_the_same_snr():
    rng = np.random.default_rng(3)
    stations = 6_378.0 * np.array([[1.0, 0.05, 0.02], [1.0, -0.04, 0.08], [1.0, 0.1, -0.1]])
    attitude = Rotation.from_rotvec(rng.normal(0, 0.02, 3)) * attitude_pointing(-SATELLITE)
    a, r, g = ca.SX.sym("a", 3, 3), ca.SX.sym("r", 3), ca.SX.sym("g", 3, 3)
    function = ca.Function("snr", [a, r, g], [geo_snr_db(a, r, g)])
    numpy_values = geo_snr_db(attitude.as_matrix(), SATELLITE, stations)
    casadi_values = function(attitude.as_matrix(), SATELLITE, stations).full().ravel()
    np.testing.assert_allclose(casadi_values, numpy_values, rtol=0, atol=1e-10)


def test_attitude_jacobian_by_ad_matches_finite_differences():
    stations = 6_378.0 * np.array([[1.0, 0.05, 0.02], [1.0, -0.04, 0.08], [1.0, 0.1, -0.1]])
    attitude = Rotation.from_rotvec([0.01, -0.02, 0.3]) * attitude_pointing(-SATELLITE)
    _, jacobian = snr_attitude_jacobian(attitude, SATELLITE, stations)
    step = 1e-6
    numeric = np.empty((3, 3))
    for i in range(3):
        delta = step * np.eye(3)[i]
        plus = geo_snr_db((Rotation.from_rotvec(delta) * attitude).as_matrix(), SATELLITE, stations)
        minus = geo_snr_db(
            (Rotation.from_rotvec(-delta) * attitude).as_matrix(), SATELLITE, stations
        )
        numeric[:, i] = (plus - minus) / (2 * step)
    np.testing.assert_allclose(jacobian, numeric, rtol=1e-6, atol=1e-4)


def test_bad_link_input_raises():
    with pytest.raises(InvalidObservationError, match="above every station"):
        geo_snr_db(np.eye(3), [6_000.0, 0, 0], BELOW)
    with pytest.raises(InvalidObservationError, match="finite and positive"):
        GeoLink(transmit_power_w=-1.0)
    with pytest.raises(InvalidObservationError, match="main lobe"):
        geo_snr_db(attitude_pointing(SATELLITE).as_matrix(), SATELLITE, BELOW)


def test_a_given_beamwidth_replaces_the_dishs_and_sets_the_roll_off_by_hand():
    # theta_3dB = 3 deg, C = 10: 1 deg off the boresight the gain drops by 10 (1/3)^2 dB.
    wide = GeoLink(beamwidth_deg=3.0)
    assert wide.theta_3db_rad == pytest.approx(math.radians(3.0), rel=1e-15)
    assert wide.peak_gain_dbi == GARUDA1.peak_gain_dbi  # the dish still sets G_max
    nadir = attitude_pointing(-SATELLITE)
    tilted = (Rotation.from_rotvec([math.radians(1.0), 0, 0]) * nadir).as_matrix()
    on_axis = geo_snr_db(nadir.as_matrix(), SATELLITE, BELOW, wide)[0]
    assert on_axis == pytest.approx(geo_snr_db(nadir.as_matrix(), SATELLITE, BELOW)[0], abs=1e-9)
    drop = on_axis - geo_snr_db(tilted, SATELLITE, BELOW, wide)[0]
    assert drop == pytest.approx(10.0 / 9.0, abs=1e-9)  # 1.111 dB
    steep = GeoLink(beamwidth_deg=3.0, size_factor_db=12.0)
    assert on_axis - geo_snr_db(tilted, SATELLITE, BELOW, steep)[0] == pytest.approx(12.0 / 9.0)


def test_the_main_lobe_ends_at_its_edge_and_main_lobe_snr_is_nan_beyond_it():
    narrow = GeoLink(lobe_edge_deg=2.0)
    assert narrow.pattern.max_off_boresight_rad == pytest.approx(math.radians(2.0), rel=1e-9)
    nadir = attitude_pointing(-SATELLITE).as_matrix()
    angles = np.array([0.0, 0.1, 0.3])  # geocentric: 0, 1.0 and 3.0 deg off the boresight
    stations = 6_378.0 * np.stack([np.cos(angles), np.sin(angles), np.zeros(3)], axis=1)
    with pytest.raises(InvalidObservationError, match="main lobe"):
        geo_snr_db(nadir, SATELLITE, stations, narrow)
    snr = main_lobe_snr_db(nadir, SATELLITE, stations, narrow)
    assert np.isnan(snr[2]) and np.isfinite(snr[:2]).all()
    np.testing.assert_array_equal(snr[:2], geo_snr_db(nadir, SATELLITE, stations[:2], narrow))
    # with every station in the lobe it is geo_snr_db itself, over leading axes too
    both = np.stack([nadir, nadir])
    np.testing.assert_array_equal(
        main_lobe_snr_db(both, np.stack([SATELLITE] * 2), np.stack([stations] * 2)),
        geo_snr_db(both, np.stack([SATELLITE] * 2), np.stack([stations] * 2)),
    )
    mixed = main_lobe_snr_db(both, np.stack([SATELLITE] * 2), np.stack([stations] * 2), narrow)
    np.testing.assert_array_equal(mixed, np.stack([snr, snr]))


def test_bad_beamwidth_or_lobe_edge_raises():
    with pytest.raises(InvalidObservationError, match="finite and positive"):
        GeoLink(beamwidth_deg=0.0)
    with pytest.raises(InvalidObservationError, match="below 90 deg"):
        GeoLink(lobe_edge_deg=90.0)
