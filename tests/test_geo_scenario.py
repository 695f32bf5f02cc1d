"""Scenario geo-snr-stations (Pimienta-Penalver and Crassidis secs. II.A, V.B): orbit,
stations, attitude, SNRs."""

from __future__ import annotations

import astropy.units as u
import numpy as np
import pytest
from astropy.coordinates import EarthLocation
from scipy.spatial.transform import Rotation

from attopt.experiments.geo_snr_stations.parameters import (
    EQ27_QUATERNION,
    GARUDA1_TLE,
    TABLE2_STATIONS,
    GeoWorld,
)
from attopt.experiments.geo_snr_stations.scenario import build_geo_snr_scenario, stations_ecef_km
from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.formulations.conventions import attitude_from_shuster_quaternion
from attopt.formulations.errors import InvalidObservationError


@pytest.fixture(scope="module")
def scenario():
    return build_geo_snr_scenario(GeoWorld(step_s=60.0))


@pytest.fixture(scope="module")
def manoeuvring():
    return build_geo_snr_scenario(GeoWorld(step_s=60.0), manoeuvre=True)


def _checksum(line: str) -> int:
    return sum(int(c) if c.isdigit() else c == "-" for c in line[:68]) % 10


def _nadir_angle_deg(scenario) -> np.ndarray:
    nadir = -scenario.satellite_eci_km / np.linalg.norm(scenario.satellite_eci_km, axis=1)[:, None]
    cosine = np.sum(nadir * scenario.boresight_eci, axis=1)
    return np.degrees(np.arccos(np.clip(cosine, -1, 1)))


def test_tle_is_the_papers_with_valid_checksums(scenario):
    assert all(len(line) == 69 and _checksum(line) == int(line[68]) for line in GARUDA1_TLE)
    radius = np.linalg.norm(scenario.satellite_ecef_km, axis=1)
    np.testing.assert_allclose(radius, 42_164.0, atol=5.0)
    longitude = np.degrees(
        np.arctan2(scenario.satellite_ecef_km[:, 1], scenario.satellite_ecef_km[:, 0])
    )
    np.testing.assert_allclose(longitude, 123.0, atol=0.01)


def test_eq27_quaternion_is_shuster_and_points_the_beam_at_nadir(scenario):
    assert _nadir_angle_deg(scenario)[0] < 0.01
    scipy_reading = Rotation.from_quat(EQ27_QUATERNION)  # the other convention is 3 deg off
    nadir = -scenario.satellite_eci_km[0] / np.linalg.norm(scenario.satellite_eci_km[0])
    assert np.degrees(np.arccos(scipy_reading.inv().apply([0, 0, 1]) @ nadir)) > 2.0
    assert scenario.truth[0].approx_equal(attitude_from_shuster_quaternion(EQ27_QUATERNION))


def test_stations_are_table2_on_wgs84():
    position, up = stations_ecef_km(TABLE2_STATIONS)
    location = EarthLocation.from_geocentric(*(position.T * u.km))
    geodetic = location.to_geodetic("WGS84")
    np.testing.assert_allclose(
        geodetic.lat.deg, [s.latitude_deg for s in TABLE2_STATIONS], atol=1e-9
    )
    np.testing.assert_allclose(
        geodetic.lon.deg, [s.longitude_deg for s in TABLE2_STATIONS], atol=1e-9
    )
    np.testing.assert_allclose(
        geodetic.height.to_value(u.m), [s.height_m for s in TABLE2_STATIONS], atol=1e-6
    )
    np.testing.assert_allclose(np.linalg.norm(up, axis=1), 1.0)


def test_beam_slews_slowly_west(scenario):
    angle = _nadir_angle_deg(scenario)
    assert 0.9 < angle[-1] < 1.05  # 1 deg/h
    kuala_lumpur, darwin = 1, 3  # west and east of Garuda-1
    assert scenario.true_snr_db[-1, kuala_lumpur] > scenario.true_snr_db[0, kuala_lumpur] + 20
    assert scenario.true_snr_db[-1, darwin] < scenario.true_snr_db[0, darwin] - 20
    assert np.all(scenario.elevation_rad > 0)
    assert scenario.heard.sum(axis=1).min() >= 3


def test_manoeuvre_turns_25_degrees_at_30_minutes(scenario, manoeuvring):
    before = scenario.t < 1800.0
    relative = (manoeuvring.truth * scenario.truth.inv()).magnitude()
    np.testing.assert_allclose(relative[before], 0.0, atol=1e-12)
    assert np.degrees(relative[-1]) == pytest.approx(
        GeoWorld().attitude.manoeuvre.angle_deg, abs=0.5
    )
    swing = np.abs(manoeuvring.true_snr_db[-1] - scenario.true_snr_db[-1])
    assert swing[manoeuvring.heard[-1]].max() > 1.0  # observable in dB


def test_simulated_snrs_are_seeded_and_feed_the_filter_interface(scenario):
    first = scenario.simulate_snr(np.random.default_rng(5))
    np.testing.assert_array_equal(first, scenario.simulate_snr(np.random.default_rng(5)))
    assert np.array_equal(np.isfinite(first), scenario.heard)
    k = 10
    measurement = scenario.measurement(k, first[k])
    assert isinstance(measurement, AttitudeMeasurement)
    values, jacobian = measurement.predict(scenario.truth[k])
    np.testing.assert_allclose(values[0], scenario.true_snr_db[k, scenario.heard[k]], atol=1e-9)
    assert jacobian.shape == (1, scenario.heard[k].sum(), 3)
    with pytest.raises(InvalidObservationError):
        scenario.measurement(k, np.full(len(TABLE2_STATIONS), np.nan))
