"""The environment models and the ``wahba-mag-sun`` geometry (Cilden Guler et al. 2017 sec. 3)."""

from __future__ import annotations

import numpy as np
import pytest
from astropy import units as u
from astropy.coordinates import EarthLocation
from astropy.time import Time

from attopt.experiments.environment.geomagnetic import (
    enu_to_ecef_matrices,
    geomagnetic_field_eci,
    igrf_enu,
)
from attopt.experiments.environment.orbit import ecef_to_eci_matrices, propagate, satellite_from_tle
from attopt.experiments.environment.shadow import EARTH_RADIUS_KM, in_cylindrical_shadow
from attopt.experiments.environment.sun import sun_direction_eci
from attopt.experiments.wahba_mag_sun.experiment import WahbaMagSunParameters
from attopt.experiments.wahba_mag_sun.scenario import (
    VectorGeometry,
    build_geometry,
    simulate_measurements,
)
from attopt.formulations.conventions import euler321_from_attitude, orbit_frame_attitude

CHECK_ENU_NT = np.array([874.0, 18540.0, -32983.0])  # ppigrf: 45N 10E, 500 km, 2025-06-01
DEFAULTS = WahbaMagSunParameters()
"""The paper's scenario: TIMED, 6000 s at 1 Hz, sigmas 0.008 and 0.002."""
TLE_LINES = DEFAULTS.orbit.tle()
MAG_SIGMA = DEFAULTS.magnetometer.sigma_rad
SUN_SIGMA = DEFAULTS.sun_sensor.sigma_rad
SIGMAS = {"mag_sigma_rad": MAG_SIGMA, "sun_sigma_rad": SUN_SIGMA}


def scenario_geometry(**window: float) -> VectorGeometry:
    """The default scenario's geometry, with ``duration_s`` or ``step_s`` changed."""
    p = DEFAULTS.model_copy(update=window)
    return build_geometry(p.orbit, p.start_utc, p.duration_s, p.step_s, p.attitude)


@pytest.fixture(scope="module")
def geometry() -> VectorGeometry:
    return scenario_geometry()


@pytest.fixture(scope="module")
def times(geometry: VectorGeometry) -> Time:
    return Time(geometry.start_utc, scale="utc") + geometry.t * u.s


def _angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cosine = np.sum(a * b, axis=-1) / np.linalg.norm(a, axis=-1) / np.linalg.norm(b, axis=-1)
    return np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))


# --- geomagnetic field -------------------------------------------------------------------


def test_igrf_check_value_round_trips_through_eci() -> None:
    when = Time(["2025-06-01T00:00:00"], scale="utc")
    field_eci = geomagnetic_field_eci(when, 10.0, 45.0, 500.0)
    to_enu = enu_to_ecef_matrices(10.0, 45.0).T @ ecef_to_eci_matrices(when)[0].T
    np.testing.assert_allclose(to_enu @ field_eci[0], CHECK_ENU_NT, atol=2.0)
    assert np.linalg.norm(field_eci[0]) == pytest.approx(np.linalg.norm(CHECK_ENU_NT), abs=2.0)


def test_igrf_time_interpolation_is_exact_across_model_epochs() -> None:
    when = Time(["2019-12-01", "2020-01-01", "2024-06-01", "2025-06-01T00:00:00"], scale="utc")
    batched = igrf_enu(when, 10.0, 45.0, 500.0)
    one_by_one = np.concatenate([igrf_enu(when[[k]], 10.0, 45.0, 500.0) for k in range(4)])
    np.testing.assert_allclose(batched, one_by_one, atol=1e-6)
    np.testing.assert_allclose(batched[-1], CHECK_ENU_NT, atol=2.0)


def test_enu_up_is_the_wgs84_normal_and_basis_is_right_handed() -> None:
    lon, lat = np.array([10.0, -120.0, 75.0]), np.array([45.0, -30.0, 80.0])
    basis = enu_to_ecef_matrices(lon, lat)
    np.testing.assert_allclose(
        basis @ np.swapaxes(basis, -1, -2), np.broadcast_to(np.eye(3), (3, 3, 3)), atol=1e-12
    )
    np.testing.assert_allclose(np.linalg.det(basis), 1.0)

    def displacement(d_lon: float, d_lat: float, d_height: float) -> np.ndarray:
        """Unit ECEF displacement of a small geodetic step, from astropy."""
        here = EarthLocation.from_geodetic(lon, lat, 0.0 * u.km)
        there = EarthLocation.from_geodetic(lon + d_lon, lat + d_lat, d_height * u.km)
        step = (there.get_itrs().cartesian.xyz - here.get_itrs().cartesian.xyz).to_value(u.km).T
        return step / np.linalg.norm(step, axis=-1, keepdims=True)

    np.testing.assert_allclose(basis[..., 0], displacement(1e-6, 0.0, 0.0), atol=1e-6)
    np.testing.assert_allclose(basis[..., 1], displacement(0.0, 1e-6, 0.0), atol=1e-6)
    np.testing.assert_allclose(basis[..., 2], displacement(0.0, 0.0, 1.0), atol=1e-9)


# --- Sun ---------------------------------------------------------------------------------


def test_sun_near_march_equinox_is_along_x() -> None:
    when = Time(["2026-03-20T14:46:00"], scale="utc")
    direction = sun_direction_eci(when, np.zeros((1, 3)))[0]
    # GCRS axes are J2000's: 26 years of precession move the equinox by ~0.36 deg.
    assert _angle_deg(direction, np.array([1.0, 0.0, 0.0])) < 0.5


def test_sun_near_june_solstice_has_obliquity_declination() -> None:
    when = Time(["2026-06-21T08:24:00"], scale="utc")
    direction = sun_direction_eci(when, np.zeros((1, 3)))[0]
    assert np.degrees(np.arcsin(direction[2])) == pytest.approx(23.44, abs=0.02)


def test_sun_parallax_shifts_direction_by_position_over_distance() -> None:
    when = Time(["2026-06-21T08:24:00"], scale="utc")
    geocentric = sun_direction_eci(when, np.zeros((1, 3)))[0]
    sideways = np.cross(geocentric, [0.0, 0.0, 1.0])
    position = 7000.0 * sideways / np.linalg.norm(sideways)
    shifted = sun_direction_eci(when, position[None, :])[0]
    expected = np.degrees(7000.0 / (1.016 * u.au).to_value(u.km))  # Earth-Sun ~1.016 au in June
    assert _angle_deg(shifted, geocentric) == pytest.approx(expected, rel=0.01)


# --- orbit -------------------------------------------------------------------------------


def test_orbit_altitude_and_inclination(geometry: VectorGeometry, times: Time) -> None:
    orbit = propagate(satellite_from_tle(*TLE_LINES), times[::60])
    # 14.952 rev/day: a = 6961 km, i.e. about 583 km above the equator (TIMED has decayed
    # from its 625 km launch orbit); geodetic heights vary with latitude and eccentricity.
    assert 570.0 < orbit.height_km.min() < orbit.height_km.max() < 615.0
    momentum = np.cross(geometry.position_eci_km, geometry.velocity_eci_kms)
    inclination = np.degrees(np.arccos(momentum[:, 2] / np.linalg.norm(momentum, axis=-1)))
    # GCRS (J2000 axes) vs the TLE's true-of-date TEME: about 0.1 deg of precession
    assert np.all(np.abs(inclination - 74.07) < 0.2)
    speed = np.linalg.norm(geometry.velocity_eci_kms, axis=-1)
    assert np.all((speed > 7.5) & (speed < 7.65))


def test_ecef_to_eci_matrices_rotate_positions(times: Time) -> None:
    orbit = propagate(satellite_from_tle(*TLE_LINES), times[::500])
    matrices = ecef_to_eci_matrices(orbit.times)
    np.testing.assert_allclose(
        matrices @ np.swapaxes(matrices, -1, -2),
        np.broadcast_to(np.eye(3), matrices.shape),
        atol=1e-12,
    )
    np.testing.assert_allclose(np.linalg.det(matrices), 1.0)
    rotated = (matrices @ orbit.position_ecef_km[..., None])[..., 0]
    np.testing.assert_allclose(rotated, orbit.position_eci_km, atol=1e-6)


def test_sgp4_error_is_raised() -> None:
    # SGP4 verification case 29141 (sgp4's SGP4-VER.TLE): decays within 420 min of epoch.
    satellite = satellite_from_tle(
        "1 29141U 85108AA  06170.26783845  .99999999  00000-0  13519-0 0   718",
        "2 29141  82.4288 273.4882 0015848 277.2124  83.9133 15.93343074  6828",
    )
    with pytest.raises(RuntimeError, match="SGP4 error 6"):
        propagate(satellite, Time(["2006-06-19T18:00:00", "2006-06-20T18:00:00"], scale="utc"))


def test_orbit_frame_is_orthonormal_with_z_nadir(geometry: VectorGeometry) -> None:
    matrices = orbit_frame_attitude(geometry.position_eci_km, geometry.velocity_eci_kms).as_matrix()
    np.testing.assert_allclose(
        matrices @ np.swapaxes(matrices, -1, -2),
        np.broadcast_to(np.eye(3), matrices.shape),
        atol=1e-12,
    )
    nadir = -geometry.position_eci_km / np.linalg.norm(
        geometry.position_eci_km, axis=-1, keepdims=True
    )
    np.testing.assert_allclose(matrices[:, 2, :], nadir, atol=1e-12)
    # near-circular orbit: x_o is along the velocity
    assert np.all(_angle_deg(matrices[:, 0, :], geometry.velocity_eci_kms) < 0.1)


# --- shadow and scenario geometry ------------------------------------------------------------


def test_shadow_predicate_on_constructed_points() -> None:
    sun = np.array([1.0, 0.0, 0.0])
    points = np.array(
        [[-7000.0, 0.0, 0.0], [7000.0, 0.0, 0.0], [-7000.0, 6400.0, 0.0], [-7000.0, 0.0, 6300.0]]
    )
    np.testing.assert_array_equal(in_cylindrical_shadow(points, sun), [True, False, False, True])


def test_geometry_vectors_are_consistent(geometry: VectorGeometry, times: Time) -> None:
    assert geometry.t.shape == (6000,) and geometry.start_utc == DEFAULTS.start_utc
    np.testing.assert_allclose(np.linalg.norm(geometry.sun_orbit, axis=-1), 1.0)
    np.testing.assert_allclose(np.linalg.norm(geometry.mag_orbit, axis=-1), 1.0)
    assert 15_000.0 < geometry.mag_nT.min() < geometry.mag_nT.max() < 60_000.0
    eci_to_orbit = orbit_frame_attitude(geometry.position_eci_km, geometry.velocity_eci_kms)
    sun_eci = sun_direction_eci(times, geometry.position_eci_km)
    np.testing.assert_allclose(eci_to_orbit.apply(sun_eci), geometry.sun_orbit, atol=1e-12)
    # Sun and field never (anti)parallel, as in Cilden Guler et al. 2017 Fig. 2
    angle = _angle_deg(geometry.sun_orbit, geometry.mag_orbit)
    assert 20.0 < angle.min() and angle.max() < 160.0


def test_eclipse_matches_shadow_predicate_and_blocked_sun(geometry: VectorGeometry) -> None:
    sun_eci = (
        orbit_frame_attitude(geometry.position_eci_km, geometry.velocity_eci_kms)
        .inv()
        .apply(geometry.sun_orbit)
    )
    np.testing.assert_array_equal(
        geometry.in_eclipse, in_cylindrical_shadow(geometry.position_eci_km, sun_eci)
    )
    radius = np.linalg.norm(geometry.position_eci_km, axis=-1)
    sun_to_nadir = np.arccos(np.clip(geometry.sun_orbit[:, 2], -1.0, 1.0))  # nadir is +z_o
    blocked = sun_to_nadir < np.arcsin(EARTH_RADIUS_KM / radius)
    np.testing.assert_array_equal(geometry.in_eclipse, blocked)


def test_single_contiguous_eclipse_of_plausible_duration(geometry: VectorGeometry) -> None:
    assert len(geometry.eclipses) == 1
    ((start, end),) = geometry.eclipses
    np.testing.assert_array_equal(geometry.in_eclipse, (geometry.t >= start) & (geometry.t < end))
    assert 300.0 <= start <= 1500.0 and end < geometry.t[-1]
    # cylindrical shadow, circular orbit: duration = T/pi acos(sqrt(1 - (R/r)^2) / cos(beta))
    middle = int(np.mean(np.flatnonzero(geometry.in_eclipse)))
    r, v = geometry.position_eci_km, geometry.velocity_eci_kms
    normal = np.cross(r[middle], v[middle])
    sun_eci = orbit_frame_attitude(r[middle], v[middle]).inv().apply(geometry.sun_orbit[middle])
    beta = np.arcsin(np.dot(normal, sun_eci) / np.linalg.norm(normal))
    radius = np.linalg.norm(r, axis=-1).mean()
    period = 86400.0 / 14.95201872
    ratio = np.sqrt(1.0 - (EARTH_RADIUS_KM / radius) ** 2) / np.cos(beta)
    assert end - start == pytest.approx(period / np.pi * np.arccos(ratio), abs=30.0)
    assert 1300.0 < end - start < 1600.0  # beta about -55 deg near the TLE epoch


def test_short_window_without_eclipse() -> None:
    geometry = scenario_geometry(duration_s=600.0, step_s=10.0)
    assert geometry.eclipses == () and not geometry.in_eclipse.any()


def test_a_longer_window_holds_two_eclipses_one_orbit_apart() -> None:
    geometry = scenario_geometry(duration_s=9000.0, step_s=10.0)
    (first_start, first_end), (second_start, second_end) = geometry.eclipses
    inside = np.zeros_like(geometry.in_eclipse)
    for start, end in geometry.eclipses:
        inside |= (geometry.t >= start) & (geometry.t < end)
    np.testing.assert_array_equal(geometry.in_eclipse, inside)
    period = 86400.0 / 14.95201872
    assert second_start - first_start == pytest.approx(period, abs=30.0)
    assert second_end - second_start == pytest.approx(first_end - first_start, abs=30.0)


def test_true_pitch_profile(geometry: VectorGeometry) -> None:
    yaw, pitch, roll = np.degrees(euler321_from_attitude(geometry.truth)).T
    assert pitch[1000] == pytest.approx(87.0) and pitch[3800] == pytest.approx(-87.0)
    assert np.max(np.abs(pitch)) == pytest.approx(87.0)
    assert np.max(np.abs(roll)) == pytest.approx(3.0, abs=1e-3)
    assert np.max(np.abs(yaw)) == pytest.approx(4.0, abs=1e-3)


# --- measurements ------------------------------------------------------------------------


def test_noise_free_measurements_are_the_true_body_vectors(geometry: VectorGeometry) -> None:
    sun, mag = simulate_measurements(
        geometry, np.random.default_rng(0), mag_sigma_rad=0.0, sun_sigma_rad=0.0
    )
    np.testing.assert_allclose(mag, geometry.truth.apply(geometry.mag_orbit), atol=1e-12)
    lit = ~geometry.in_eclipse
    np.testing.assert_allclose(sun[lit], geometry.truth.apply(geometry.sun_orbit)[lit], atol=1e-12)


def test_measurement_noise_statistics(geometry: VectorGeometry) -> None:
    sun, mag = simulate_measurements(geometry, np.random.default_rng(12345), **SIGMAS)
    assert np.all(np.isnan(sun[geometry.in_eclipse]))
    assert not np.any(np.isnan(sun[~geometry.in_eclipse])) and not np.any(np.isnan(mag))
    np.testing.assert_allclose(np.linalg.norm(mag, axis=-1), 1.0)
    lit = ~geometry.in_eclipse
    for measured, reference, sigma in (
        (mag, geometry.truth.apply(geometry.mag_orbit), MAG_SIGMA),
        (sun[lit], geometry.truth.apply(geometry.sun_orbit)[lit], SUN_SIGMA),
    ):
        error = measured - reference
        # normalisation removes the component along the true vector (to first order)
        expected = sigma**2 * np.mean(1.0 - reference**2, axis=0)
        np.testing.assert_allclose(np.mean(error**2, axis=0), expected, rtol=0.1)
        assert np.mean(np.sum(error * reference, axis=-1)) == pytest.approx(-(sigma**2), rel=0.2)


def test_measurements_are_reproducible(geometry: VectorGeometry) -> None:
    first = simulate_measurements(geometry, np.random.default_rng(7), **SIGMAS)
    again = simulate_measurements(geometry, np.random.default_rng(7), **SIGMAS)
    other = simulate_measurements(geometry, np.random.default_rng(8), **SIGMAS)
    for a, b, c in zip(first, again, other, strict=True):
        np.testing.assert_array_equal(a, b)
        assert not np.allclose(np.nan_to_num(a), np.nan_to_num(c))
    # magnetometer noise is drawn first, so it does not depend on the Sun noise
    mag_only = simulate_measurements(
        geometry, np.random.default_rng(7), mag_sigma_rad=MAG_SIGMA, sun_sigma_rad=0.0
    )[1]
    np.testing.assert_array_equal(mag_only, first[1])
