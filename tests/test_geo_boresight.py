"""Seed 004 sec. IV: boresight by cone intersection (eq. 12) and least squares; LOS on the belt."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from attopt.experiments.geo_snr_stations.scenario import (
    SNR_SIGMA_DB,
    build_geo_snr_scenario,
    stations_ecef_km,
)
from attopt.formulations.errors import InvalidObservationError, UnobservableError
from attopt.formulations.geo_link import GARUDA1, attitude_pointing, geo_snr_db
from attopt.solvers.geo.boresight import (
    StationCones,
    boresight_error_rad,
    cone_intersection,
    least_squares_boresight,
    rf_sensitivity,
    station_cones,
)
from attopt.solvers.geo.los import (
    _belt_snr_function,
    belt_position,
    line_of_sight_errors,
    locate_on_geo_belt,
)


@pytest.fixture(scope="module")
def scenario():
    return build_geo_snr_scenario(3600.0, 300.0, manoeuvre=True)


def _cones(scenario, k, stations, snr=None):
    y = scenario.true_snr_db[k, stations] if snr is None else snr
    return station_cones(
        y,
        scenario.satellite_eci_km[k],
        scenario.stations_eci_km[k, stations],
        scenario.stations_up_eci[k, stations],
        SNR_SIGMA_DB,
    )


def test_noise_free_snrs_recover_the_boresight(scenario):
    for k in range(scenario.t.size):
        heard = np.flatnonzero(scenario.heard[k])
        assert heard.size >= 3
        for solve, stations in ((cone_intersection, heard[:3]), (least_squares_boresight, heard)):
            solution = solve(_cones(scenario, k, stations))
            assert not solution.fell_back
            error = boresight_error_rad(solution.direction, scenario.boresight_eci[k])
            assert error < 1e-8, (k, solve.__name__, error)


def test_noisy_snrs_give_small_errors_and_least_squares_is_better(scenario):
    rng = np.random.default_rng(11)
    errors = {"cone_intersection": [], "least_squares": []}
    for _ in range(20):
        y = scenario.simulate_snr(rng)
        heard = np.flatnonzero(scenario.heard[0])
        cones = _cones(scenario, 0, heard, y[0, heard])
        for solution in (cone_intersection(cones), least_squares_boresight(cones)):
            key = "least_squares" if solution.fell_back else solution.method
            errors[key].append(boresight_error_rad(solution.direction, scenario.boresight_eci[0]))
    rms = {key: np.sqrt(np.mean(np.square(value))) for key, value in errors.items()}
    assert rms["least_squares"] < rms["cone_intersection"] < np.radians(0.01)


def test_fewer_than_three_stations_is_unobservable(scenario):
    cones = _cones(scenario, 0, [2, 3])
    with pytest.raises(UnobservableError, match="needs three"):
        cone_intersection(cones)
    with pytest.raises(UnobservableError, match="three cones"):
        least_squares_boresight(cones)


def test_non_intersecting_cones_fall_back_to_least_squares_with_a_flag():
    # Cones of half-angle 0.5 deg about axes 2 deg apart cannot meet.
    axes = np.array([[0.0, 0.0, 1.0], [np.sin(0.035), 0.0, np.cos(0.035)], [0.0, 0.02, 1.0]])
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    cosine = np.cos(np.radians([0.5, 0.5, 1.0]))
    solution = cone_intersection(StationCones(axes, cosine, np.full(3, 1e-6), 0))
    assert solution.fell_back and solution.method == "least_squares"
    assert "do not intersect" in solution.reason
    assert np.linalg.norm(solution.direction) == pytest.approx(1.0)


def test_station_below_the_horizon_is_rejected(scenario):
    stations = [2, 3, 6]
    up = scenario.stations_up_eci[0, stations].copy()
    up[1] *= -1.0  # the satellite is now below station 1's horizon
    with pytest.raises(InvalidObservationError, match=r"station\(s\) \[1\].*below the horizon"):
        station_cones(
            scenario.true_snr_db[0, stations],
            scenario.satellite_eci_km[0],
            scenario.stations_eci_km[0, stations],
            up,
            SNR_SIGMA_DB,
        )


def test_wrong_rf_parameters_bias_the_boresight(scenario):
    stations = [2, 3, 6, 7]
    args = (
        scenario.truth[0],
        scenario.satellite_eci_km[0],
        scenario.stations_eci_km[0, stations],
        scenario.stations_up_eci[0, stations],
    )
    result = rf_sensitivity(*args, [12.0e3, 12.6e3], [12.0, 12.24])
    assert result.error_rad[0, 0] < 1e-8
    assert np.all(result.error_rad.ravel()[1:] > np.radians(0.01))


def test_belt_search_recovers_the_longitude_from_noise_free_snrs():
    stations, up = stations_ecef_km()
    satellite = belt_position(np.radians(123.0))
    attitude = attitude_pointing(-satellite)
    snr = geo_snr_db(attitude.as_matrix(), satellite, stations)
    heard = np.flatnonzero(snr >= 0.0)
    fit = locate_on_geo_belt(snr[heard], stations[heard], up[heard], attitude, SNR_SIGMA_DB)
    assert abs(fit.longitude_rad - np.radians(123.0)) < 1e-9
    assert line_of_sight_errors(fit.satellite_km, satellite, stations[heard]).max() < 1e-9


def test_belt_jacobian_by_ad_matches_finite_differences():
    stations, _ = stations_ecef_km()
    attitude = attitude_pointing(-belt_position(np.radians(123.0))).as_matrix()
    function = _belt_snr_function(GARUDA1, stations.shape[0])
    lon, step = np.radians(123.1), 1e-7
    value = lambda x: function(x, attitude, stations, 42_164.17)[0].full().ravel()  # noqa: E731
    numeric = (value(lon + step) - value(lon - step)) / (2 * step)
    analytic = function(lon, attitude, stations, 42_164.17)[1].full().ravel()
    np.testing.assert_allclose(analytic, numeric, rtol=1e-6, atol=1e-3)
    assert isinstance(function, ca.Function)


def test_belt_window_without_visibility_is_unobservable():
    stations, up = stations_ecef_km()
    attitude = attitude_pointing(-belt_position(np.radians(123.0)))
    with pytest.raises(UnobservableError, match="GEO belt"):
        locate_on_geo_belt([30.0], stations[:1], up[:1], attitude, 0.1, window_deg=(-60, -50))
