"""Pimienta-Penalver and Crassidis sec. IV: boresight by cone intersection (eq. 12) and least
squares; LOS on the belt."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest

from attopt.experiments.geo_snr_stations.parameters import TABLE2_STATIONS, GeoWorld
from attopt.experiments.geo_snr_stations.scenario import build_geo_snr_scenario, stations_ecef_km
from attopt.formulations.errors import InvalidObservationError, UnobservableError
from attopt.formulations.geo_geometry import belt_position, line_of_sight_errors
from attopt.formulations.geo_link import GARUDA1, attitude_pointing, geo_snr_db, geo_snr_epoch
from attopt.formulations.snapshot import Snapshot
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.formulations.snr_problem import SnrEpoch
from attopt.solvers.bounds import crb
from attopt.solvers.geo import ESTIMATORS
from attopt.solvers.geo.boresight import (
    GEO_CONE,
    GEO_LSQ,
    StationCones,
    boresight_error_rad,
    check_elevations,
    estimated_boresight,
    intersect_cones,
    rf_sensitivity,
)
from attopt.solvers.geo.los import _belt_snr_function, locate_on_geo_belt

SNR_SIGMA_DB = GeoWorld().receiver.snr_sigma_db


@pytest.fixture(scope="module")
def scenario():
    return build_geo_snr_scenario(GeoWorld(step_s=300.0), manoeuvre=True)


def _snapshot(scenario, k, stations, snr=None) -> Snapshot:
    y = scenario.true_snr_db[k, stations] if snr is None else snr
    epoch = geo_snr_epoch(
        y, scenario.satellite_eci_km[k], scenario.stations_eci_km[k, stations], SNR_SIGMA_DB
    )
    return Snapshot.of(SnrMeasurement(epoch))


def test_registry_names():
    assert [e.name for e in ESTIMATORS] == ["geo_cone", "geo_lsq"]


def test_noise_free_snrs_recover_the_boresight(scenario):
    for k in range(scenario.t.size):
        heard = np.flatnonzero(scenario.heard[k])
        assert heard.size >= 3
        for estimator, stations in ((GEO_CONE, heard[:3]), (GEO_LSQ, heard)):
            solution = estimator.solve(_snapshot(scenario, k, stations))
            assert solution.diagnostics.get("fell_back", 0.0) == 0.0
            direction = [solution.diagnostics[f"boresight_{a}"] for a in "xyz"]
            error = boresight_error_rad(direction, scenario.boresight_eci[k])
            assert error < 1e-8, (k, estimator.name, error)
            # The attitude points the body z axis along the estimated boresight.
            pointing = solution.attitude.inv().apply([0.0, 0.0, 1.0])
            assert boresight_error_rad(pointing, direction) < 1e-12
            assert solution.loss < 1e-12


def test_the_covariance_is_infinite_about_the_boresight_and_the_crb_across_it(scenario):
    heard = np.flatnonzero(scenario.heard[0])
    snapshot = _snapshot(scenario, 0, heard)
    solution = GEO_LSQ.solve(snapshot, prior=scenario.truth[0])
    # With the truth's yaw as reference, noise-free SNRs give the true attitude itself.
    assert np.linalg.norm((solution.attitude * scenario.truth[0].inv()).as_rotvec()) < 1e-8
    covariance = solution.covariance
    assert covariance[2, 2] == np.inf and np.all(np.isfinite(covariance[:2, :2]))
    np.testing.assert_array_equal(covariance[:2, 2], 0.0)
    # Noise free, at the truth: the first-order covariance of the cones is the SNRs' CRB.
    bound = crb(snapshot, scenario.truth[0])
    assert bound[2, 2] == np.inf
    np.testing.assert_allclose(covariance[:2, :2], bound[:2, :2], rtol=1e-5)
    frame = solution.to_dataframe(scenario.truth[:1])
    assert np.isnan(frame["sigma_z_deg"][0]) and np.isnan(frame["err_z_deg"][0])
    assert np.isfinite(frame[["sigma_x_deg", "sigma_y_deg", "nees"]].to_numpy()).all()


@pytest.mark.parametrize("estimator", ESTIMATORS, ids=lambda e: e.name)
def test_covariance_across_the_boresight_matches_monte_carlo(scenario, estimator):
    rng = np.random.default_rng(12)
    heard = np.flatnonzero(scenario.heard[0])
    stations = heard[:3] if estimator is GEO_CONE else heard
    truth = scenario.truth[0]
    trials = 300
    errors = np.empty((trials, 2))
    reported = np.zeros((2, 2))
    for i in range(trials):
        y = scenario.simulate_snr(rng)[0, stations]
        solution = estimator.solve(_snapshot(scenario, 0, stations, y), prior=truth)
        errors[i] = (solution.attitude * truth.inv()).as_rotvec()[:2]
        reported += solution.covariance[:2, :2] / trials
    scatter = errors.T @ errors / trials
    assert np.trace(scatter) == pytest.approx(np.trace(reported), rel=0.2)
    assert np.linalg.norm(scatter - reported) < 0.25 * np.trace(reported)


def test_noisy_snrs_give_small_errors_and_least_squares_is_better(scenario):
    rng = np.random.default_rng(11)
    errors = {"cone": [], "lsq": []}
    heard = np.flatnonzero(scenario.heard[0])
    snapshots = [
        _snapshot(scenario, 0, heard, scenario.simulate_snr(rng)[0, heard]) for _ in range(20)
    ]
    for estimator in ESTIMATORS:
        track = estimator.solve_sequence(snapshots)
        assert track.valid.all()
        fell_back = track.diagnostics.get("fell_back", np.zeros(len(track))) == 1.0
        for direction, back in zip(estimated_boresight(track), fell_back, strict=True):
            key = "lsq" if back or estimator is GEO_LSQ else "cone"
            errors[key].append(boresight_error_rad(direction, scenario.boresight_eci[0]))
    rms = {key: np.sqrt(np.mean(np.square(value))) for key, value in errors.items()}
    assert rms["lsq"] < rms["cone"] < np.radians(0.01)


def test_fewer_than_three_stations_is_unobservable(scenario):
    snapshot = _snapshot(scenario, 0, [2, 3])
    with pytest.raises(UnobservableError, match="needs three"):
        GEO_CONE.solve(snapshot)
    with pytest.raises(UnobservableError, match="three cones"):
        GEO_LSQ.solve(snapshot)
    track = GEO_LSQ.solve_sequence([snapshot, None, _snapshot(scenario, 0, [2, 3, 6])])
    np.testing.assert_array_equal(track.valid, [False, False, True])
    assert "three cones" in track.reason[0] and track.error[0] is UnobservableError
    assert np.isnan(estimated_boresight(track)[0]).all()


def test_non_intersecting_cones_fall_back_to_least_squares_with_a_flag():
    # Cones of half-angle 0.5 deg about axes 2 deg apart cannot meet.
    axes = np.array([[0.0, 0.0, 1.0], [np.sin(0.035), 0.0, np.cos(0.035)], [0.0, 0.02, 1.0]])
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    cosine = np.cos(np.radians([0.5, 0.5, 1.0]))
    fit = intersect_cones(StationCones(axes, cosine, np.full(3, 1e-6), 0))
    assert fit.diagnostics["fell_back"] == 1.0 and np.isnan(fit.diagnostics["selection_margin"])
    assert fit.cones.los.shape == (3, 3)  # least squares over the three stations
    assert np.linalg.norm(fit.direction) == pytest.approx(1.0)


def test_station_below_the_horizon_is_rejected(scenario):
    stations = [2, 3, 6]
    up = scenario.stations_up_eci[0, stations].copy()
    up[1] *= -1.0  # the satellite is now below station 1's horizon
    with pytest.raises(InvalidObservationError, match=r"station\(s\) \[1\].*below the horizon"):
        check_elevations(scenario.stations_eci_km[0, stations], up, scenario.satellite_eci_km[0])


def test_lines_of_sight_must_be_unit_vectors_and_other_types_are_refused(scenario):
    epoch = _snapshot(scenario, 0, [2, 3, 6]).measurements[0].epoch
    longer = SnrEpoch(
        epoch.snr_db,
        2.0 * epoch.los_orbit,
        epoch.antenna,
        epoch.boresights_body,
        epoch.p0_dbw,
        epoch.noise_dbw,
        epoch.pattern,
        threshold_db=epoch.threshold_db,
    )
    with pytest.raises(InvalidObservationError, match="unit lines of sight"):
        GEO_CONE.solve(Snapshot.of(SnrMeasurement(longer)))
    with pytest.raises(InvalidObservationError, match="one SnrMeasurement"):
        GEO_LSQ.solve(Snapshot.of(SnrMeasurement(epoch), SnrMeasurement(epoch)))


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
    stations, up = stations_ecef_km(TABLE2_STATIONS)
    satellite = belt_position(np.radians(123.0))
    attitude = attitude_pointing(-satellite)
    snr = geo_snr_db(attitude.as_matrix(), satellite, stations)
    heard = np.flatnonzero(snr >= 0.0)
    fit = locate_on_geo_belt(snr[heard], stations[heard], up[heard], attitude, SNR_SIGMA_DB)
    assert abs(fit.longitude_rad - np.radians(123.0)) < 1e-9
    assert line_of_sight_errors(fit.satellite_km, satellite, stations[heard]).max() < 1e-9


def test_belt_jacobian_by_ad_matches_finite_differences():
    stations, _ = stations_ecef_km(TABLE2_STATIONS)
    attitude = attitude_pointing(-belt_position(np.radians(123.0))).as_matrix()
    function = _belt_snr_function(GARUDA1, stations.shape[0])
    lon, step = np.radians(123.1), 1e-7
    value = lambda x: function(x, attitude, stations, 42_164.17)[0].full().ravel()  # noqa: E731
    numeric = (value(lon + step) - value(lon - step)) / (2 * step)
    analytic = function(lon, attitude, stations, 42_164.17)[1].full().ravel()
    np.testing.assert_allclose(analytic, numeric, rtol=1e-6, atol=1e-3)
    assert isinstance(function, ca.Function)


def test_belt_window_without_visibility_is_unobservable():
    stations, up = stations_ecef_km(TABLE2_STATIONS)
    attitude = attitude_pointing(-belt_position(np.radians(123.0)))
    with pytest.raises(UnobservableError, match="GEO belt"):
        locate_on_geo_belt([30.0], stations[:1], up[:1], attitude, 0.1, window_deg=(-60, -50))
