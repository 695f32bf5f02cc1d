"""Pins every line of docs/conventions.md."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from attopt.formulations.conventions import (
    attitude_error,
    attitude_from_euler321,
    attitude_from_shuster_quaternion,
    euler321_from_attitude,
    orbit_frame_attitude,
    shuster_quaternion,
)
from tests.strategies import attitudes

angles = st.floats(-np.pi + 1e-3, np.pi - 1e-3)
pitches = st.floats(-np.pi / 2 + 1e-3, np.pi / 2 - 1e-3)


def liu2023_eq8(psi: float, theta: float, phi: float) -> np.ndarray:
    """C_o^B of Liu et al. 2023 eq. 8, typed in from the paper."""
    c, s = np.cos, np.sin
    return np.array(
        [
            [c(theta) * c(psi), c(theta) * s(psi), -s(theta)],
            [
                s(phi) * s(theta) * c(psi) - c(phi) * s(psi),
                s(phi) * s(theta) * s(psi) + c(phi) * c(psi),
                s(phi) * c(theta),
            ],
            [
                c(phi) * s(theta) * c(psi) + s(phi) * s(psi),
                c(phi) * s(theta) * s(psi) - s(phi) * c(psi),
                c(phi) * c(theta),
            ],
        ]
    )


@given(psi=angles, theta=pitches, phi=angles)
def test_euler321_is_liu2023_eq8(psi, theta, phi):
    attitude = attitude_from_euler321(psi, theta, phi)
    np.testing.assert_allclose(attitude.as_matrix(), liu2023_eq8(psi, theta, phi), atol=1e-14)
    np.testing.assert_allclose(euler321_from_attitude(attitude), [psi, theta, phi], atol=1e-9)


def test_attitude_maps_reference_to_body():
    """b = A r: a +90 deg yaw puts the reference x axis on body -y (Liu et al. 2023 eq. 8)."""
    attitude = attitude_from_euler321(np.pi / 2, 0.0, 0.0)
    np.testing.assert_allclose(attitude.apply([1.0, 0, 0]), [0, -1.0, 0], atol=1e-15)
    np.testing.assert_allclose(attitude.as_matrix() @ [1.0, 0, 0], attitude.apply([1.0, 0, 0]))


@settings(max_examples=50)
@given(attitude=attitudes())
def test_shuster_quaternion_is_conjugate_of_scipy(attitude):
    """A(q) of Cilden Guler et al. 2017 eq. 21 evaluated on shuster_quaternion(A) gives A back."""
    q = shuster_quaternion(attitude)
    qv, q4 = q[:3], q[3]
    cross = np.array([[0, -qv[2], qv[1]], [qv[2], 0, -qv[0]], [-qv[1], qv[0], 0]])
    a_of_q = (q4**2 - qv @ qv) * np.eye(3) + 2 * np.outer(qv, qv) - 2 * q4 * cross
    np.testing.assert_allclose(a_of_q, attitude.as_matrix(), atol=1e-14)
    scipy_q = attitude.as_quat()
    conjugate = np.r_[-scipy_q[:3], scipy_q[3]]
    assert min(np.abs(q - conjugate).max(), np.abs(q + conjugate).max()) < 1e-15
    assert attitude_from_shuster_quaternion(q).approx_equal(attitude, atol=1e-14)


def test_quaternion_exchange_format_is_scipy_scalar_last():
    attitude = Rotation.from_rotvec([0.0, 0.0, 0.5])
    np.testing.assert_allclose(attitude.as_quat(), [0, 0, np.sin(0.25), np.cos(0.25)])


@settings(max_examples=50)
@given(truth=attitudes(), delta=st.lists(st.floats(-0.01, 0.01), min_size=3, max_size=3))
def test_attitude_error_is_body_frame_rotation_vector(truth, delta):
    """estimate = exp(delta) * truth gives error delta, whose axes are body axes."""
    estimate = Rotation.from_rotvec(delta) * truth
    np.testing.assert_allclose(attitude_error(estimate, truth), delta, atol=1e-12)


def test_attitude_error_axis_is_body_roll_axis():
    truth = attitude_from_euler321(1.2, 0.3, -0.4)
    # A body roll of 1 deg: rotate the body frame about its own x axis.
    roll = attitude_from_euler321(0.0, 0.0, np.radians(1.0))
    error = np.degrees(attitude_error(roll * truth, truth))
    np.testing.assert_allclose(np.abs(error), [1.0, 0.0, 0.0], atol=1e-12)


def test_orbit_frame_axes():
    """z_o nadir, y_o negative orbit normal, x_o along velocity (circular orbit)."""
    r = np.array([7000.0, 0.0, 0.0])
    v = np.array([0.0, 7.5, 0.0])
    a_oi = orbit_frame_attitude(r, v).as_matrix()
    np.testing.assert_allclose(a_oi[0], [0, 1, 0], atol=1e-15)
    np.testing.assert_allclose(a_oi[1], [0, 0, -1], atol=1e-15)
    np.testing.assert_allclose(a_oi[2], [-1, 0, 0], atol=1e-15)
    np.testing.assert_allclose(orbit_frame_attitude(r, v).apply(-r / 7000.0), [0, 0, 1], atol=1e-15)
