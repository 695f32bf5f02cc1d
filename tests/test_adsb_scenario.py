"""Tests of the ``adsb-snr`` geometry and the air-traffic model (Liu et al. 2023 sec. 5.1)."""

from __future__ import annotations

import dataclasses

import astropy.units as u
import numpy as np
import pytest
from astropy.coordinates import EarthLocation, get_sun
from astropy.time import Time
from sgp4.api import Satrec
from sgp4.io import verify_checksum

from attopt.experiments.adsb_snr.parameters import BETA_OPT_DEG, DEFAULT_TLE, AdsbScenario
from attopt.experiments.adsb_snr.scenario import (
    AdsbGeometry,
    above_limb,
    build_adsb_geometry,
    observation_table,
    visible_counts,
    visible_observations,
)
from attopt.experiments.environment.orbit import circular_orbit_tle
from attopt.experiments.environment.traffic import (
    Traffic,
    angle_from_origin,
    geodetic_normal,
    positions_ecef_km,
    sample_traffic,
)
from attopt.formulations.conventions import euler321_from_attitude

MAIN_LOBE_DEG = 41.67  # cos^6(a) = 10**0.4 / 14.4598: G >= 4 dBi (Liu et al. 2023 eq. 63)
TLE_EPOCH_UTC = "2025-06-01T00:00:00"
SIDEREAL_NODE_RATE_DEG_DAY = 0.9856473598  # 360 deg per tropical year


@pytest.fixture(scope="module")
def geometry() -> AdsbGeometry:
    return build_adsb_geometry()


def _geodetic(ecef_km: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Unit geodetic normals and heights (km) of ECEF positions."""
    location = EarthLocation.from_geocentric(*np.moveaxis(ecef_km, -1, 0), unit=u.km)
    lon, lat, height = location.to_geodetic("WGS84")
    return geodetic_normal(lat.to_value(u.deg), lon.to_value(u.deg)), height.to_value(u.km)


# --- orbit -------------------------------------------------------------------------------


def test_tle_is_valid_and_has_the_documented_elements() -> None:
    line1, line2 = DEFAULT_TLE
    assert DEFAULT_TLE == circular_orbit_tle(TLE_EPOCH_UTC, 99999, 600.0, 97.8, 226.31)
    verify_checksum(line1, line2)
    satellite = Satrec.twoline2rv(line1, line2)
    assert np.degrees(satellite.inclo) == pytest.approx(97.8)
    assert satellite.ecco == pytest.approx(1e-4)


def test_orbit_has_600_km_altitude_and_97_8_deg_inclination(geometry: AdsbGeometry) -> None:
    satellite = Satrec.twoline2rv(*DEFAULT_TLE)
    jd = satellite.jdsatepoch + np.linspace(0.0, 1.0, 200)
    _, position, velocity = satellite.sgp4_array(jd, np.full_like(jd, satellite.jdsatepochF))
    h = np.cross(position, velocity)
    inclination_teme = np.degrees(np.arccos(h[:, 2] / np.linalg.norm(h, axis=-1)))
    np.testing.assert_allclose(inclination_teme, 97.8, atol=0.02)
    h_eci = np.cross(geometry.position_eci_km, geometry.velocity_eci_kms)
    inclination_eci = np.degrees(np.arccos(h_eci[:, 2] / np.linalg.norm(h_eci, axis=-1)))
    np.testing.assert_allclose(inclination_eci, 97.8, atol=0.2)  # GCRS vs TEME of date
    altitude = np.linalg.norm(geometry.position_eci_km, axis=-1) - 6378.137
    assert np.mean(altitude) == pytest.approx(600.0, abs=5.0)
    assert np.ptp(altitude) < 20.0


def test_orbit_is_sun_synchronous_with_ltan_2230() -> None:
    satellite = Satrec.twoline2rv(*DEFAULT_TLE)
    days = np.arange(0.0, 4.0, 10.0 / 1440.0)
    jd = satellite.jdsatepoch + days
    _, position, velocity = satellite.sgp4_array(jd, np.full_like(jd, satellite.jdsatepochF))
    h = np.cross(position, velocity)
    node = np.unwrap(np.arctan2(h[:, 0], -h[:, 1]))
    drift_deg_day = np.degrees(np.polyfit(days, node, 1)[0])
    assert drift_deg_day == pytest.approx(SIDEREAL_NODE_RATE_DEG_DAY, abs=0.005)
    sun_ra = get_sun(Time(TLE_EPOCH_UTC, scale="utc")).ra.to_value(u.deg)
    ltan_h = (12.0 + (np.degrees(node[0]) - sun_ra) / 15.0) % 24.0
    assert ltan_h == pytest.approx(22.5, abs=0.1)


# --- attitude and antennas ---------------------------------------------------------------


def test_boresights_are_unit_symmetric_and_tilted_beta_opt(geometry: AdsbGeometry) -> None:
    boresights = geometry.boresights_body
    assert boresights.shape == (2, 3)
    np.testing.assert_allclose(np.linalg.norm(boresights, axis=-1), 1.0)
    off_nadir = np.degrees(np.arccos(boresights @ [0.0, 0.0, 1.0]))
    np.testing.assert_allclose(off_nadir, BETA_OPT_DEG)
    np.testing.assert_allclose(boresights[1], boresights[0] * [1.0, -1.0, 1.0])
    assert np.degrees(np.arccos(boresights[0] @ boresights[1])) == pytest.approx(2.0 * BETA_OPT_DEG)
    assert boresights[0, 1] > 0  # antenna 1 towards +y body (Liu et al. 2023 Fig. 7)


def test_true_attitude_wanders_a_few_degrees(geometry: AdsbGeometry) -> None:
    euler_deg = np.degrees(euler321_from_attitude(geometry.truth))
    assert np.all(np.abs(euler_deg) <= 5.0 + 1e-9)
    assert np.all(np.ptp(euler_deg, axis=0) > 5.0)


# --- traffic -----------------------------------------------------------------------------


def test_aircraft_fly_great_circles_at_cruise_height(geometry: AdsbGeometry) -> None:
    traffic = geometry.traffic
    times = np.array([0.0, 1234.0, 3599.0])[:, None]
    normal, height = _geodetic(positions_ecef_km(traffic, times))
    off_plane = np.abs(np.sum(normal * traffic.route_normal, axis=-1))
    assert off_plane.max() < 1e-9
    assert height.min() >= 9.0 - 1e-6
    assert height.max() <= 12.0 + 1e-6


def test_aircraft_speed_is_220_to_260_mps(geometry: AdsbGeometry) -> None:
    traffic = geometry.traffic
    t0, t1 = geometry.t[100], geometry.t[101]
    speed = (
        1000.0
        * np.linalg.norm(positions_ecef_km(traffic, t1) - positions_ecef_km(traffic, t0), axis=-1)
        / (t1 - t0)
    )
    turned = ~np.isclose(
        np.abs(angle_from_origin(traffic, t1) - angle_from_origin(traffic, t0)),
        traffic.angular_rate_rad_s * (t1 - t0),
        rtol=1e-6,
    )
    assert turned.mean() < 0.01
    # ground speed set on the mean sphere: WGS84 curvature changes it by < 0.6 %
    assert speed[~turned].min() >= 220.0 * 0.994
    assert speed[~turned].max() <= 260.0 * 1.006


def test_aircraft_fly_back_after_arrival(geometry: AdsbGeometry) -> None:
    traffic = geometry.traffic
    arrival_s = (traffic.route_angle_rad - traffic.start_angle_rad) / traffic.angular_rate_rad_s
    aircraft = np.flatnonzero(arrival_s < 3000.0)[:50]
    assert aircraft.size == 50
    before = positions_ecef_km(traffic, arrival_s[aircraft] - 300.0, aircraft)
    after = positions_ecef_km(traffic, arrival_s[aircraft] + 300.0, aircraft)
    np.testing.assert_allclose(after, before, atol=1e-6)


def test_traffic_is_dense_over_europe_and_north_america_not_south_pacific(
    geometry: AdsbGeometry,
) -> None:
    normal, _ = _geodetic(positions_ecef_km(geometry.traffic, 0.0))
    lat = np.degrees(np.arcsin(normal[:, 2]))
    lon = np.degrees(np.arctan2(normal[:, 1], normal[:, 0]))

    def density(lat_range: tuple[float, float], lon_range: tuple[float, float]) -> float:
        inside = (lat >= lat_range[0]) & (lat < lat_range[1])
        inside &= (lon >= lon_range[0]) & (lon < lon_range[1])
        area = np.radians(np.ptp(lon_range)) * np.ptp(np.sin(np.radians(lat_range)))
        return max(int(np.count_nonzero(inside)), 1) / area

    south_pacific = density((-50.0, -20.0), (-160.0, -100.0))
    assert density((40.0, 60.0), (-10.0, 30.0)) > 50.0 * south_pacific  # Europe
    assert density((30.0, 50.0), (-110.0, -70.0)) > 50.0 * south_pacific  # United States


def test_traffic_is_reproducible_from_the_seed() -> None:
    first = sample_traffic(500, np.random.default_rng(7))
    second = sample_traffic(500, np.random.default_rng(7))
    other = sample_traffic(500, np.random.default_rng(8))
    for field in dataclasses.fields(Traffic):
        np.testing.assert_array_equal(getattr(first, field.name), getattr(second, field.name))
    assert not np.array_equal(first.start_angle_rad, other.start_angle_rad)
    assert build_adsb_geometry() is build_adsb_geometry(AdsbScenario())


# --- visibility --------------------------------------------------------------------------


def test_limb_rejects_an_aircraft_below_the_horizon() -> None:
    satellite = np.array([6378.137 + 600.0, 0.0, 0.0])

    def aircraft_at(latitude_deg: float) -> np.ndarray:
        location = EarthLocation.from_geodetic(0.0 * u.deg, latitude_deg * u.deg, 10.0 * u.km)
        return np.array([axis.to_value(u.km) for axis in location.geocentric])

    # horizon of a 600 km satellite for a 10 km target: about 27 deg of central angle
    assert above_limb(satellite, aircraft_at(20.0))
    assert above_limb(satellite, aircraft_at(26.5))
    assert not above_limb(satellite, aircraft_at(28.0))
    assert not above_limb(satellite, aircraft_at(60.0))


def test_pipeline_rejects_aircraft_beyond_the_limb(geometry: AdsbGeometry) -> None:
    y_orbit_ecef = geometry.ecef_to_orbit[0][1]
    nadir = geometry.subsatellite_normal[0]
    tangent = y_orbit_ecef - (y_orbit_ecef @ nadir) * nadir
    tangent /= np.linalg.norm(tangent)
    central_deg = np.array([25.0, 29.5])  # both inside the pre-filter, the second hidden
    hovering = Traffic(
        origin=np.array(["AAA", "AAA"]),
        destination=np.array(["BBB", "BBB"]),
        origin_normal=np.tile(nadir, (2, 1)),
        route_tangent=np.tile(tangent, (2, 1)),
        route_angle_rad=np.full(2, np.pi / 2.0),
        start_angle_rad=np.radians(central_deg),
        height_km=np.full(2, 10.0),
        speed_mps=np.zeros(2),
    )
    assert np.radians(central_deg[1]) < geometry.prefilter_rad
    probe = dataclasses.replace(geometry, traffic=hovering)
    observations = visible_observations(probe, 0, 60.0)
    np.testing.assert_array_equal(observations.antennas[0].aircraft, [0])
    assert observations.antennas[1].aircraft.size == 0


def test_lines_of_sight_are_unit_and_point_to_the_aircraft(geometry: AdsbGeometry) -> None:
    table = observation_table(geometry, MAIN_LOBE_DEG, [0, 1800, 3599])
    assert table.range_m.size > 100
    np.testing.assert_allclose(np.linalg.norm(table.los_orbit, axis=-1), 1.0, atol=1e-12)
    to_ecef = np.swapaxes(geometry.ecef_to_orbit[table.epoch_index], -1, -2)
    displacement_km = np.einsum("pij,pj->pi", to_ecef, table.los_orbit) * table.range_m[:, None]
    expected_km = table.aircraft_ecef_km - geometry.position_ecef_km[table.epoch_index]
    np.testing.assert_allclose(displacement_km / 1000.0, expected_km, atol=1e-9)
    np.testing.assert_allclose(
        table.aircraft_ecef_km,
        positions_ecef_km(geometry.traffic, geometry.t[table.epoch_index], table.aircraft),
    )
    body = geometry.truth[table.epoch_index].apply(table.los_orbit)
    np.testing.assert_allclose(
        table.cos_off_boresight, np.sum(body * geometry.boresights_body[table.antenna], axis=-1)
    )
    assert np.all(table.cos_off_boresight >= np.cos(np.radians(MAIN_LOBE_DEG)))
    assert 590e3 < table.range_m.min() and table.range_m.max() < 3.3e6


def test_prefilter_drops_no_visible_aircraft(geometry: AdsbGeometry) -> None:
    epochs = [0, 1700, 3599]
    table = observation_table(geometry, MAIN_LOBE_DEG, epochs)
    for k in epochs:
        aircraft_ecef = positions_ecef_km(geometry.traffic, geometry.t[k])
        los = aircraft_ecef - geometry.position_ecef_km[k]
        los /= np.linalg.norm(los, axis=-1, keepdims=True)
        body = geometry.truth[k].apply(los @ geometry.ecef_to_orbit[k].T)
        cos_off = body @ geometry.boresights_body.T
        visible = above_limb(geometry.position_ecef_km[k], aircraft_ecef)[:, None]
        visible = visible & (cos_off >= np.cos(np.radians(MAIN_LOBE_DEG)))
        for antenna in range(2):
            rows = (table.epoch_index == k) & (table.antenna == antenna)
            np.testing.assert_array_equal(table.aircraft[rows], np.flatnonzero(visible[:, antenna]))


def test_counts_match_observations_and_cover_every_epoch(geometry: AdsbGeometry) -> None:
    counts = visible_counts(geometry, MAIN_LOBE_DEG)
    assert counts.shape == (geometry.t.size, 2)
    assert np.all(counts >= 3)  # Liu et al. 2023 sec. 5.1: at least three per antenna
    for k in (0, 2500):
        observations = visible_observations(geometry, k, MAIN_LOBE_DEG)
        assert [a.aircraft.size for a in observations.antennas] == counts[k].tolist()
        assert all(np.all(a.epoch_index == k) for a in observations.antennas)
