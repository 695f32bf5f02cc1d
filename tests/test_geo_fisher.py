"""Pimienta-Penalver and Crassidis sec. V: Fisher information of SNRs from AD Jacobians;
single-SNR nullspace (eq. 25)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from attopt.formulations.geo_fisher import (
    information_magnitude,
    information_map,
    single_snr_nullspace,
    snr_attitude_jacobian,
    snr_fisher_information,
)
from attopt.formulations.geo_geometry import belt_position
from attopt.formulations.geo_link import attitude_pointing

EARTH_KM = 6_378.0


def _station(latitude: float, longitude: float) -> np.ndarray:
    lat, lon = np.radians(latitude), np.radians(longitude)
    return EARTH_KM * np.array([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)])


def _attitude_off(satellite, station, theta_deg, azimuth, yaw) -> Rotation:
    """Attitude whose boresight is ``theta_deg`` from the line of sight to the station."""
    los = station - satellite
    pointing = attitude_pointing(los)
    tilt = Rotation.from_rotvec(
        np.radians(theta_deg) * np.array([np.cos(azimuth), np.sin(azimuth), 0])
    )
    return Rotation.from_rotvec([0.0, 0.0, yaw]) * tilt * pointing


@settings(max_examples=40, deadline=None)
@given(
    sat_lon=st.floats(-180, 180),
    lat=st.floats(-60, 60),
    dlon=st.floats(-60, 60),
    theta=st.floats(0.05, 8.0),
    azimuth=st.floats(0, 2 * np.pi),
    yaw=st.floats(-np.pi, np.pi),
)
def test_single_snr_nullspace_is_boresight_and_projected_los(
    sat_lon, lat, dlon, theta, azimuth, yaw
):
    satellite = belt_position(np.radians(sat_lon))
    station = _station(lat, sat_lon + dlon)
    attitude = _attitude_off(satellite, station, theta, azimuth, yaw)
    fisher = snr_fisher_information(attitude, satellite, station[None], 0.0148)
    eigenvalues, vectors = np.linalg.eigh(fisher)
    assert np.all(np.abs(eigenvalues[:2]) < 1e-9 * eigenvalues[2])  # rank one
    null = vectors[:, :2]
    paper = single_snr_nullspace(attitude, satellite, station)  # eq. 25
    basis, _ = np.linalg.qr(paper.T)
    np.testing.assert_allclose(null @ null.T, basis @ basis.T, atol=1e-8)


def test_information_vanishes_on_the_boresight_and_grows_off_it():
    satellite = belt_position(np.radians(123.0))
    surabaya = _station(-7.28, 112.83)
    angles = np.radians([0.0, 0.5, 1.0, 2.0, 4.0])
    info = information_map(satellite, surabaya, angles, [0.0], 0.0148)[:, 0]
    assert info[0] < 1e-12 * info[1]
    assert np.all(np.diff(info[1:]) > 0)


def test_fisher_of_several_stations_is_the_sum_and_keeps_the_boresight_null():
    satellite = belt_position(np.radians(123.0))
    stations = np.stack([_station(-7.3, 112.8), _station(6.1, 125.1), _station(5.3, 115.2)])
    attitude = _attitude_off(satellite, stations[0], 1.0, 0.3, 0.2)
    _, jacobian = snr_attitude_jacobian(attitude, satellite, stations)
    fisher = snr_fisher_information(attitude, satellite, stations, 0.0148)
    np.testing.assert_allclose(fisher, jacobian.T @ jacobian / 0.0148**2, rtol=1e-12)
    np.testing.assert_allclose(np.trace(fisher), information_magnitude(jacobian, 0.0148).sum())
    # Every station's Jacobian is orthogonal to the boresight: yaw stays unobservable.
    assert np.abs(fisher[2]).max() < 1e-9 * np.abs(fisher).max()
    assert np.linalg.matrix_rank(fisher[:2, :2]) == 2
