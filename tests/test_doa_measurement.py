"""The DOA attitude measurement (``formulations/doa_measurement.py``, Yang et al. 2014
eqs. 13-18): invertibility, AD Jacobian, far-field error, the array-axis and
horizon treatments, angle wrapping and input checks."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from attopt.formulations.doa_array import doa_jacobian, doa_unit_vector
from attopt.formulations.doa_measurement import DoaMeasurement
from attopt.formulations.errors import InvalidObservationError
from tests.strategies import attitudes
from tests.test_attitude_measurement import central_differences

ARRAY_DOAS = np.radians([[20.0, 30.0], [55.0, 200.0], [2.0, 300.0], [40.0, 350.0]])
RANGES_KM = np.array([900.0, 2500.0, 805.0, 1500.0])
COVARIANCE = np.tile(np.diag(np.radians([0.3, 0.4]) ** 2), (4, 1, 1))


def geometry(truth: Rotation, mounting: Rotation, lever_arm: np.ndarray) -> np.ndarray:
    """Reference-frame ``D_o`` (eq. 13) of stations seen at ``ARRAY_DOAS`` from the
    array centre."""
    seen = doa_unit_vector(ARRAY_DOAS[:, 0], ARRAY_DOAS[:, 1])
    body = mounting.inv().apply(seen) * RANGES_KM[:, None] + lever_arm
    return truth.inv().apply(body)


mountings = st.builds(
    lambda v: Rotation.from_rotvec(v), st.lists(st.floats(-0.5, 0.5), min_size=3, max_size=3)
)
lever_arms = st.lists(st.floats(-0.002, 0.002), min_size=3, max_size=3).map(np.array)


@settings(max_examples=30, deadline=None)
@given(attitudes(), mountings, lever_arms)
def test_measurement_is_invertible_at_zero_noise(
    truth: Rotation, mounting: Rotation, lever_arm: np.ndarray
) -> None:
    """``h`` at the truth is the measured DOA, and eq. 12 maps it back to the line
    of sight from the array centre: ``A^T C_rb^T S_r = (D_o - A^T R_b) / |...|``."""
    los = geometry(truth, mounting, lever_arm)
    measurement = DoaMeasurement(ARRAY_DOAS, COVARIANCE, los, lever_arm, mounting)
    h, _ = measurement.predict(truth)
    np.testing.assert_allclose(measurement.innovation(h[0]), 0.0, atol=1e-9)
    station = ~measurement.near_axis
    angles = h[0].reshape(-1, 2)[station]
    recovered = truth.inv().apply(mounting.inv().apply(doa_unit_vector(*angles.T)))
    expected = los[station] - truth.inv().apply(lever_arm)
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    np.testing.assert_allclose(recovered, expected, atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(attitudes(), mountings, lever_arms, attitudes())
def test_jacobian_matches_finite_differences(
    truth: Rotation, mounting: Rotation, lever_arm: np.ndarray, offset: Rotation
) -> None:
    """AD Jacobian of every row (angles and near-axis direction cosines) against
    central differences of ``predict``, at the truth and at a point up to 20 deg away."""
    los = geometry(truth, mounting, lever_arm)
    measurement = DoaMeasurement(ARRAY_DOAS, COVARIANCE, los, lever_arm, mounting)
    nearby = Rotation.from_rotvec(0.35 * offset.as_rotvec() / np.pi) * truth
    for attitude in (truth, nearby):
        h, jacobian = measurement.predict(attitude)
        if not np.isfinite(h).all():  # a station moved behind the array plane
            continue
        numeric = central_differences(measurement, attitude, angles=True)
        scale = max(1.0, np.abs(jacobian[0]).max())
        np.testing.assert_allclose(jacobian[0], numeric, atol=1e-6 * scale)


def test_far_field_error_is_bounded_by_lever_arm_over_range() -> None:
    """Eq. 17 turns each line of sight by at most ``asin(|R_b| / |D_o|)``; for a
    1 m lever arm that is at most 1.25 microradians at 800 km or more."""
    truth = Rotation.from_euler("ZYX", [50.0, 50.0, 50.0], degrees=True).inv()
    lever_arm = np.array([0.0006, -0.0008, 0.0])  # 1 m, in the array plane
    los = geometry(truth, Rotation.identity(), lever_arm)
    exact = DoaMeasurement(ARRAY_DOAS, COVARIANCE, los, lever_arm)
    approximate = DoaMeasurement(ARRAY_DOAS, COVARIANCE, los, lever_arm, far_field=True)
    directions = [
        doa_unit_vector(*m.predict(truth)[0][0].reshape(-1, 2)[~m.near_axis].T)
        for m in (exact, approximate)
    ]
    turn = np.arccos(np.clip(np.sum(directions[0] * directions[1], axis=1), -1.0, 1.0))
    bound = np.arcsin(np.linalg.norm(lever_arm) / np.linalg.norm(los, axis=1))[~exact.near_axis]
    assert np.all(turn <= bound * (1 + 1e-6) + 1e-15)
    assert turn.max() > 0.1 * bound.max()  # the bound is nearly reached, not vacuous
    assert bound.max() <= 1.25e-6


def test_station_near_the_axis_is_measured_by_direction_cosines() -> None:
    """The 2-deg station's rows are ``sin theta (cos phi, sin phi)`` with covariance
    ``J Sigma J^T``; a CRB-shaped covariance (``Var theta ~ 1 / cos^2 theta``,
    ``Var phi ~ 1 / sin^2 theta``) maps to an isotropic one; prediction and
    Jacobian stay finite on the axis."""
    truth = Rotation.identity()
    los = geometry(truth, Rotation.identity(), np.zeros(3))
    measurement = DoaMeasurement(ARRAY_DOAS, COVARIANCE, los)
    assert list(measurement.near_axis) == [False, False, True, False]
    theta, phi = ARRAY_DOAS[2]
    np.testing.assert_allclose(measurement.z[4:6], doa_unit_vector(theta, phi)[:2])
    jacobian = doa_jacobian(theta, phi)[:2]
    np.testing.assert_allclose(
        measurement.noise_covariance[4:6, 4:6], jacobian @ COVARIANCE[2] @ jacobian.T
    )
    variance = 1e-5
    crb_shaped = np.diag([variance / np.cos(theta) ** 2, variance / np.sin(theta) ** 2])
    isotropic = DoaMeasurement([[theta, phi]], [crb_shaped], los[2:3])
    np.testing.assert_allclose(
        isotropic.noise_covariance, variance * np.eye(2), rtol=1e-12, atol=1e-18
    )
    near = 1e-3
    on_axis = DoaMeasurement(
        [[near, 0.0]], [np.diag([variance, variance / near**2])], [[0.0, 0.0, 800.0]]
    )
    h, jac = on_axis.predict(truth)  # the station exactly on the axis
    np.testing.assert_allclose(h, 0.0, atol=1e-15)
    assert np.isfinite(jac).all()


def test_station_behind_the_array_plane_is_unpredictable() -> None:
    """A station the predicted attitude puts at ``theta >= 90 deg`` is NaN (rows and
    Jacobian) at every stacked attitude; the others are predicted."""
    truth = Rotation.identity()
    los = geometry(truth, Rotation.identity(), np.zeros(3))
    measurement = DoaMeasurement(ARRAY_DOAS, COVARIANCE, los)
    tilted = Rotation.from_euler("y", [[0.0], [-40.0]], degrees=True)  # tips the 55-deg one over
    h, jacobian = measurement.predict(tilted)
    behind = np.zeros(8, dtype=bool)
    behind[2:4] = True
    assert np.isnan(h[:, behind]).all() and np.isnan(jacobian[:, behind]).all()
    assert np.isfinite(h[:, ~behind]).all()


def test_innovation_wraps_phi_only() -> None:
    """``phi`` 359 deg measured, 1 deg predicted: innovation -2 deg; theta and
    direction-cosine rows are plain differences."""
    measurement = DoaMeasurement(
        np.radians([[30.0, 359.0], [1.0, 0.0]]),
        COVARIANCE[:2],
        [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]],
    )
    predicted = np.concatenate([np.radians([31.0, 1.0]), measurement.z[2:] + 4.0])
    np.testing.assert_allclose(
        measurement.innovation(predicted), [np.radians(-1.0), np.radians(-2.0), -4.0, -4.0]
    )


def test_bad_input() -> None:
    """NaN stations are left out; theta at/behind the horizon, a covariance that is
    not positive definite, a zero line of sight and mismatched shapes raise."""
    los = [[0.0, 0.0, 800.0], [100.0, 0.0, 800.0]]
    kept = DoaMeasurement([[0.3, 1.0], [np.nan, 1.0]], COVARIANCE[:2], los)
    assert kept.size == 2 and kept.blocks.tolist() == [0, 0]
    with pytest.raises(InvalidObservationError, match="horizon"):
        DoaMeasurement([[np.pi / 2, 1.0]], COVARIANCE[:1], los[:1])
    with pytest.raises(InvalidObservationError, match="positive definite"):
        DoaMeasurement([[0.3, 1.0]], [np.diag([1e-4, -1e-4])], los[:1])
    with pytest.raises(InvalidObservationError, match="zero length"):
        DoaMeasurement([[0.3, 1.0]], COVARIANCE[:1], [[0.0, 0.0, 0.0]])
    with pytest.raises(InvalidObservationError):
        DoaMeasurement([[0.3, 1.0]], COVARIANCE[:2], los[:1])
    empty = DoaMeasurement(np.zeros((0, 2)), np.zeros((0, 2, 2)), np.zeros((0, 3)))
    h, jacobian = empty.predict(Rotation.identity())
    assert h.shape == (1, 0) and jacobian.shape == (1, 0, 3)
