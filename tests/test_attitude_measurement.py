"""The measurement interface of the filters (``formulations/attitude_measurement.py``,
``formulations/snr_measurement.py``): values, body-frame Jacobians, innovations
and input checks.

Every Jacobian is checked against central differences of ``predict`` under
the body-frame perturbation ``A -> Rotation.from_rotvec(e) * A``, i.e. the
error ``delta`` of ``A_true = exp(delta) A`` (``docs/conventions.md``).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import (
    AttitudeMeasurement,
    EulerAngleMeasurement,
    ReferencedMeasurement,
    VectorMeasurement,
)
from attopt.formulations.conventions import attitude_from_euler321, euler321_from_attitude
from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.gain_patterns import LIU2023_HELIX
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.formulations.snr_model import observation_mask
from attopt.formulations.snr_problem import SnrEpoch
from tests.strategies import attitudes
from tests.test_snr_solvers import BORESIGHTS, BUDGET, TRUTH, _epoch, _geometry

STEP = 1e-6


def wrap(angle: np.ndarray) -> np.ndarray:
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


def central_differences(
    measurement: AttitudeMeasurement, attitude: Rotation, angles: bool = False
) -> np.ndarray:
    """``(m, 3)`` derivative of ``predict`` w.r.t. ``e`` of ``from_rotvec(e) * attitude``.

    The six perturbed attitudes are predicted in one stacked call; ``angles``
    wraps the differences (Euler angles jump by 2 pi across +/-180 deg).
    """
    perturbed = Rotation.concatenate(
        [
            Rotation.from_rotvec(sign * STEP * axis) * attitude
            for axis in np.eye(3)
            for sign in (1, -1)
        ]
    )
    h, _ = measurement.predict(perturbed)
    difference = h[0::2] - h[1::2]
    if angles:
        difference = wrap(difference)
    return (difference / (2.0 * STEP)).T


def euler_rate_matrix(pitch: float, roll: float) -> np.ndarray:
    """Liu et al. 2023 eq. 42 / eq. 44's ``H_v``: body rates ``(x, y, z)`` to
    ``(yaw, pitch, roll)`` rates."""
    st_, ct = math.sin(pitch), math.cos(pitch)
    sr, cr = math.sin(roll), math.cos(roll)
    return np.array(
        [
            [0.0, sr / ct, cr / ct],
            [0.0, cr, -sr],
            [1.0, st_ / ct * sr, st_ / ct * cr],
        ]
    )


def _pitch(attitude: Rotation) -> float:
    """Pitch from the matrix (scipy's Euler angles warn at gimbal lock)."""
    return float(-np.arcsin(np.clip(attitude.as_matrix()[0, 2], -1.0, 1.0)))


def _unit_vectors(rng: np.random.Generator, k: int) -> np.ndarray:
    v = rng.normal(size=(k, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _snr_measurement(
    attitude: Rotation, seed: int, per_antenna=(4, 4), truncated: bool = False
) -> SnrMeasurement:
    """Noise-free SNRs of observations inside the main lobes at ``attitude`` (orbit -> body)."""
    geometry = _geometry(np.random.default_rng(seed), attitude, per_antenna)
    return SnrMeasurement(_epoch(geometry), truncated=truncated)


# --- Jacobians ---------------------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(attitudes())
def test_euler_jacobian_matches_central_differences(attitude):
    assume(abs(math.cos(_pitch(attitude))) > 0.1)  # away from gimbal lock
    measurement = EulerAngleMeasurement(np.zeros(3), np.eye(3))
    _, jacobian = measurement.predict(attitude)
    numeric = central_differences(measurement, attitude, angles=True)
    np.testing.assert_allclose(jacobian[0], numeric, rtol=1e-6, atol=1e-7)


@settings(max_examples=60, deadline=None)
@given(attitudes(), st.integers(1, 6), st.integers(0, 2**32 - 1))
def test_vector_jacobian_matches_central_differences(attitude, k, seed):
    reference = _unit_vectors(np.random.default_rng(seed), k)
    measurement = VectorMeasurement(attitude.apply(reference), reference, 1e-3)
    values, jacobian = measurement.predict(attitude)
    np.testing.assert_allclose(values[0], attitude.apply(reference).ravel(), atol=1e-14)
    numeric = central_differences(measurement, attitude)
    np.testing.assert_allclose(jacobian[0], numeric, rtol=1e-6, atol=1e-8)
    # d(A r)/d delta = -[A r x]: rows perpendicular to each prediction
    for i, b in enumerate(attitude.apply(reference)):
        np.testing.assert_allclose(b @ jacobian[0, 3 * i : 3 * i + 3], 0.0, atol=1e-14)


@settings(max_examples=25, deadline=None)
@given(attitudes(), st.integers(0, 2**32 - 1), st.booleans())
def test_snr_jacobian_matches_central_differences(attitude, seed, truncated):
    """Both SNR models: Gaussian (the prediction is the noise-free SNR) and the
    threshold-truncated mean (above it, by ``sigma lambda(x)``)."""
    measurement = _snr_measurement(attitude, seed, truncated=truncated)
    values, jacobian = measurement.predict(attitude)
    assert np.all(np.isfinite(values)) and np.all(np.isfinite(jacobian))
    if truncated:
        assert np.all(values[0] >= measurement.z - 1e-10)
    else:
        np.testing.assert_allclose(values[0], measurement.z, atol=1e-10)  # noise-free epoch
    numeric = central_differences(measurement, attitude)
    assert np.abs(jacobian).max() > 1.0  # not trivially zero (dB/rad)
    np.testing.assert_allclose(jacobian[0], numeric, rtol=1e-5, atol=1e-5)


@settings(max_examples=25, deadline=None)
@given(attitudes(), attitudes(), st.integers(0, 2**32 - 1))
def test_referenced_snr_jacobian_matches_central_differences(body_from_orbit, frame, seed):
    """The filters' attitude is inertial -> body, ``A_bi = A_bo A_oi``; the
    body-frame error and so the Jacobian are the same as the inner model's."""
    inner = _snr_measurement(body_from_orbit, seed)
    measurement = ReferencedMeasurement(inner, frame)
    inertial = body_from_orbit * frame
    values, jacobian = measurement.predict(inertial)
    np.testing.assert_allclose(values[0], inner.z, atol=1e-9)
    numeric = central_differences(measurement, inertial)
    np.testing.assert_allclose(jacobian[0], numeric, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(jacobian, inner.predict(body_from_orbit)[1], rtol=1e-9, atol=1e-9)


@settings(max_examples=30, deadline=None)
@given(attitudes(), attitudes())
def test_referenced_euler_jacobian_matches_central_differences(body_from_orbit, frame):
    assume(abs(math.cos(_pitch(body_from_orbit))) > 0.1)
    measurement = ReferencedMeasurement(EulerAngleMeasurement(np.zeros(3), np.eye(3)), frame)
    inertial = body_from_orbit * frame
    _, jacobian = measurement.predict(inertial)
    numeric = central_differences(measurement, inertial, angles=True)
    np.testing.assert_allclose(jacobian[0], numeric, rtol=1e-6, atol=1e-7)


# --- Euler angles (Liu et al. 2023 eqs. 41-46) ----------------------------------------------


@settings(max_examples=100, deadline=None)
@given(attitudes())
def test_euler_prediction_is_conventions_euler321(attitude):
    assume(abs(math.cos(_pitch(attitude))) > 1e-2)
    values, _ = EulerAngleMeasurement(np.zeros(3), np.eye(3)).predict(attitude)
    np.testing.assert_allclose(
        wrap(values[0] - euler321_from_attitude(attitude)), 0.0, rtol=0, atol=1e-10
    )


def test_euler_prediction_is_vectorised_over_attitudes():
    angles = np.random.default_rng(2).uniform([-3, -1.4, -3], [3, 1.4, 3], size=(7, 3))
    stack = attitude_from_euler321(*angles.T)
    values, jacobian = EulerAngleMeasurement(np.zeros(3), np.eye(3)).predict(stack)
    assert values.shape == (7, 3) and jacobian.shape == (7, 3, 3)
    np.testing.assert_allclose(values, angles, atol=1e-12)


def test_seed_euler_rate_matrix_maps_body_rates_to_euler_rates():
    """Eq. 42 of Liu et al. 2023 (``H_v`` of eq. 44 at the estimate) with ``dA/dt = -[w x] A``."""
    rng = np.random.default_rng(4)
    for yaw, pitch, roll in rng.uniform([-3, -1.3, -3], [3, 1.3, 3], size=(20, 3)):
        attitude = attitude_from_euler321(yaw, pitch, roll)
        w = rng.normal(size=3)
        h = 1e-6
        ahead = euler321_from_attitude(Rotation.from_rotvec(-w * h) * attitude)
        behind = euler321_from_attitude(Rotation.from_rotvec(w * h) * attitude)
        rates = wrap(ahead - behind) / (2 * h)
        np.testing.assert_allclose(rates, euler_rate_matrix(pitch, roll) @ w, rtol=1e-6, atol=1e-8)


@settings(max_examples=100, deadline=None)
@given(
    st.floats(-math.pi, math.pi),
    st.floats(-1.45, 1.45),
    st.floats(-math.pi, math.pi),
)
def test_euler_jacobian_is_minus_liu2023_h_v(yaw, pitch, roll):
    """The Jacobian w.r.t. attopt's error ``delta`` (``A_true = exp(delta) A_est``)
    is ``-H_v`` of Liu et al. 2023 eq. 44.  The paper's error vector ``v`` is the
    opposite rotation: its ``delta q(v) (x) q_hat`` in Shuster's product has
    ``A(delta q) = I - [v x]``, and its eq. 36 reads ``-[w x] v - delta_beta``
    where attopt's reads ``+ delta_beta`` (``formulations/gyro.py``); so
    ``v = -delta`` and ``Z = H_v v = -H_v delta``."""
    attitude = attitude_from_euler321(yaw, pitch, roll)
    _, jacobian = EulerAngleMeasurement(np.zeros(3), np.eye(3)).predict(attitude)
    expected = -euler_rate_matrix(pitch, roll)
    np.testing.assert_allclose(jacobian[0], expected, rtol=0, atol=1e-12 / math.cos(pitch) ** 2)


# --- innovations --------------------------------------------------------------------------


def test_euler_innovation_wraps_angles():
    measurement = EulerAngleMeasurement(np.radians([179.0, 10.0, -179.5]), np.eye(3))
    predicted = np.radians([[-179.0, 9.0, 179.5], [179.0, 10.0, -179.5]])
    innovation = measurement.innovation(predicted)
    np.testing.assert_allclose(
        np.degrees(innovation), [[-2.0, 1.0, 1.0], [0.0, 0.0, 0.0]], atol=1e-12
    )
    assert np.all(np.abs(innovation) <= np.pi)


def test_vector_innovation_is_perpendicular_to_each_prediction():
    rng = np.random.default_rng(8)
    reference = _unit_vectors(rng, 4)
    truth = Rotation.random(random_state=9)
    body = truth.apply(reference) + 0.01 * rng.normal(size=(4, 3))
    measurement = VectorMeasurement(body, reference, 0.01)
    estimates = Rotation.from_rotvec(np.radians(20.0) * _unit_vectors(rng, 5)) * truth
    predicted, _ = measurement.predict(estimates)
    innovation = measurement.innovation(predicted)
    assert innovation.shape == (5, 12)
    h = predicted.reshape(5, 4, 3)
    nu = innovation.reshape(5, 4, 3)
    np.testing.assert_allclose(np.sum(nu * h, axis=-1), 0.0, atol=1e-15)
    # it is the geodesic difference: the angle between z and h, along z's
    # component perpendicular to h
    z = measurement.z.reshape(4, 3) / np.linalg.norm(measurement.z.reshape(4, 3), axis=-1)[:, None]
    angle = np.arccos(np.clip(np.sum(z[None] * h, axis=-1), -1.0, 1.0))
    np.testing.assert_allclose(np.linalg.norm(nu, axis=-1), angle, rtol=1e-12)
    perpendicular = z[None] - np.sum(z[None] * h, axis=-1, keepdims=True) * h
    np.testing.assert_allclose(
        np.sum(nu * perpendicular, axis=-1), angle * np.linalg.norm(perpendicular, axis=-1)
    )


def test_vector_measurement_drops_nan_vectors():
    rng = np.random.default_rng(1)
    reference = _unit_vectors(rng, 4)
    body = reference.copy()
    body[1] = np.nan
    reference_with_nan = reference.copy()
    reference_with_nan[3, 0] = np.nan
    measurement = VectorMeasurement(body, reference_with_nan, [1e-3, np.nan, 2e-3, 3e-3])
    assert measurement.size == 6
    np.testing.assert_array_equal(measurement.z, body[[0, 2]].ravel())
    np.testing.assert_array_equal(measurement.reference, reference[[0, 2]])
    np.testing.assert_array_equal(measurement.noise_covariance, [1e-6] * 3 + [4e-6] * 3)
    np.testing.assert_array_equal(measurement.blocks, [0, 0, 0, 1, 1, 1])
    values, jacobian = measurement.predict(Rotation.identity())
    assert values.shape == (1, 6) and jacobian.shape == (1, 6, 3)


def test_vector_measurement_with_covariances_drops_nan_vectors_as_if_never_given():
    """With full covariances, a NaN vector is dropped with its covariance: the measurement
    equals the one of the other vectors alone (isotropic sigmas from the right rows)."""
    rng = np.random.default_rng(2)
    reference = _unit_vectors(rng, 4)
    body = Rotation.from_rotvec([0.01, -0.02, 0.03]).apply(reference)
    factor = rng.normal(size=(4, 3, 3))
    covariance = 1e-6 * (factor @ factor.transpose(0, 2, 1) + np.eye(3))
    body_with_nan = body.copy()
    body_with_nan[1, 2] = np.nan
    kept = [0, 2, 3]
    measurement = VectorMeasurement(body_with_nan, reference, covariance=covariance)
    alone = VectorMeasurement(body[kept], reference[kept], covariance=covariance[kept])
    for name in ("z", "reference", "sigma", "noise_covariance", "blocks"):
        np.testing.assert_array_equal(getattr(measurement, name), getattr(alone, name))


def test_referenced_measurement_is_inner_at_attitude_times_frame_inverse():
    rng = np.random.default_rng(6)
    reference = _unit_vectors(rng, 3)
    frame = Rotation.random(random_state=10)
    attitudes_ = Rotation.random(4, random_state=11)
    for inner in (
        VectorMeasurement(reference, reference, 1e-3),
        EulerAngleMeasurement(np.radians([179.0, 5.0, -3.0]), np.eye(3)),
    ):
        referenced = ReferencedMeasurement(inner, frame)
        values, jacobian = referenced.predict(attitudes_)
        inner_values, inner_jacobian = inner.predict(attitudes_ * frame.inv())
        np.testing.assert_array_equal(values, inner_values)
        np.testing.assert_array_equal(jacobian, inner_jacobian)
        assert referenced.z is inner.z and referenced.blocks is inner.blocks
        assert referenced.noise_covariance is inner.noise_covariance
        np.testing.assert_array_equal(referenced.innovation(values), inner.innovation(values))
    # the Euler inner model's wrapping is kept
    euler = ReferencedMeasurement(
        EulerAngleMeasurement(np.radians([179.0, 0, 0]), np.eye(3)), frame
    )
    np.testing.assert_allclose(
        np.degrees(euler.innovation(np.radians([-179.0, 0, 0]))), [-2.0, 0, 0], atol=1e-12
    )


# --- SNR measurements -----------------------------------------------------------------------


def test_snr_measurement_values_noise_and_blocks():
    geometry = _geometry(np.random.default_rng(12), TRUTH, (5, 4))
    sigma = np.linspace(0.5, 1.5, 9)
    measurement = SnrMeasurement(_epoch(geometry, sigma_db=sigma))
    np.testing.assert_array_equal(measurement.z, geometry[3])
    np.testing.assert_allclose(measurement.noise_covariance, sigma**2)
    np.testing.assert_array_equal(measurement.blocks, np.arange(9))
    values, jacobian = measurement.predict(TRUTH)
    np.testing.assert_allclose(values[0], geometry[3], atol=1e-10)
    np.testing.assert_allclose(jacobian[0], geometry[4], atol=1e-10)


def test_snr_measurement_nan_rows_outside_the_main_lobe_at_any_stacked_attitude():
    geometry = _geometry(np.random.default_rng(13), TRUTH, (10, 10))
    measurement = SnrMeasurement(_epoch(geometry))
    stack = Rotation.concatenate(
        [TRUTH, Rotation.from_rotvec(np.radians([15.0, 0, 0])) * TRUTH, TRUTH]
    )
    values, jacobian = measurement.predict(stack)
    los, antenna = geometry[0], geometry[1]
    inside = observation_mask(stack.as_matrix(), los, BORESIGHTS[antenna], LIU2023_HELIX)
    usable = inside.all(axis=0)
    assert 0 < usable.sum() < usable.size  # some observations leave the lobe
    assert np.all(np.isnan(values[:, ~usable])) and np.all(np.isnan(jacobian[:, ~usable]))
    assert np.all(np.isfinite(values[:, usable])) and np.all(np.isfinite(jacobian[:, usable]))
    alone, alone_jacobian = measurement.predict(TRUTH)
    np.testing.assert_allclose(values[0, usable], alone[0, usable], atol=1e-12)
    np.testing.assert_allclose(jacobian[0, usable], alone_jacobian[0, usable], atol=1e-12)
    np.testing.assert_array_equal(values[0], values[2])


def test_values_without_jacobian_equal_the_ad_values():
    """``predict(..., jacobian=False)`` (the numpy path of the sigma-point filters)
    gives the AD path's values, NaN rows included, and no Jacobian."""
    rng = np.random.default_rng(15)
    reference = _unit_vectors(rng, 3)
    geometry = _geometry(rng, TRUTH, (10, 10))
    stack = Rotation.concatenate(
        [
            TRUTH,
            Rotation.from_rotvec(np.radians([15.0, 0, 0])) * TRUTH,
            Rotation.random(random_state=3),
        ]
    )
    snr = SnrMeasurement(_epoch(geometry))
    cases = [
        (EulerAngleMeasurement(np.zeros(3), np.eye(3)), stack, True),
        (VectorMeasurement(reference, reference, 1e-3), stack, False),
        (snr, stack[:2], False),
        (SnrMeasurement(_epoch(geometry), truncated=True), stack[:2], False),
        (ReferencedMeasurement(snr, Rotation.random(random_state=4)), None, False),
    ]
    for measurement, at, angles in cases:
        if at is None:
            at = stack[:2] * Rotation.random(random_state=4)
        values, jacobian = measurement.predict(at, jacobian=False)
        expected, _ = measurement.predict(at)
        assert jacobian is None and values.shape == expected.shape
        np.testing.assert_array_equal(np.isnan(values), np.isnan(expected))
        difference = values - expected
        if angles:
            difference = wrap(difference)
        np.testing.assert_allclose(difference[np.isfinite(difference)], 0.0, atol=1e-10)
    assert np.isnan(snr.predict(stack[:2], jacobian=False)[0]).any()


# --- bad input ------------------------------------------------------------------------------


@pytest.mark.parametrize(
    "angles, covariance",
    [
        (np.zeros(2), np.eye(3)),
        (np.zeros((3, 1)), np.eye(3)),
        (np.zeros(3), np.eye(2)),
        (np.zeros(3), np.eye(3)[:, :2]),
    ],
)
def test_euler_measurement_rejects_bad_shapes(angles, covariance):
    with pytest.raises(InvalidObservationError):
        EulerAngleMeasurement(angles, covariance)


@pytest.mark.parametrize(
    "body, reference, sigma",
    [
        (np.ones((2, 3)), np.ones((3, 3)), 1e-3),  # different counts
        (np.ones((2, 3)), np.ones((2, 3)), [1e-3, 1e-3, 1e-3]),  # sigma of the wrong length
        (np.ones(4), np.ones(4), 1e-3),  # not triples
        (np.ones((2, 3)), np.ones((2, 3)), 0.0),  # zero sigma
        (np.ones((2, 3)), np.ones((2, 3)), [1e-3, -1e-3]),  # negative sigma
        (np.ones((2, 3)), np.ones((2, 3)), [1e-3, np.inf]),  # infinite sigma of a kept vector
    ],
    ids=["counts", "sigma-length", "not-triples", "zero-sigma", "negative-sigma", "inf-sigma"],
)
def test_vector_measurement_rejects_bad_input(body, reference, sigma):
    with pytest.raises(InvalidObservationError):
        VectorMeasurement(body, reference, sigma)


def test_snr_measurement_bad_shapes_are_rejected_by_the_epoch():
    los, antenna, ranges, snr, _ = _geometry(np.random.default_rng(14), TRUTH, (3, 3))
    with pytest.raises(InvalidObservationError):
        SnrMeasurement(
            SnrEpoch.from_ranges(snr[:-1], los, antenna, BORESIGHTS, ranges, LIU2023_HELIX, BUDGET)
        )
    with pytest.raises(InvalidObservationError):
        SnrMeasurement(
            SnrEpoch.from_ranges(
                snr, los[:, :2], antenna, BORESIGHTS, ranges, LIU2023_HELIX, BUDGET
            )
        )
