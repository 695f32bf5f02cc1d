"""The symbolic measurement hook (``formulations/measurement_model.py``,
``AttitudeMeasurement.symbolic``): a new type written only as a symbolic model
gets values, AD Jacobians and innovations; each existing type's symbolic
model and innovation agree with its own numpy ``predict`` and ``innovation``.
"""

from __future__ import annotations

import pickle
from typing import Any

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import (
    Array,
    AttitudeMeasurement,
    EulerAngleMeasurement,
    ReferencedMeasurement,
    VectorMeasurement,
)
from attopt.formulations.doa_measurement import DoaMeasurement
from attopt.formulations.errors import UnsupportedMeasurementError
from attopt.formulations.measurement_model import SymbolicModel, geodesic_difference
from attopt.formulations.snapshot import StackedMeasurement
from tests.strategies import attitudes
from tests.test_attitude_measurement import _snr_measurement, _unit_vectors, central_differences
from tests.test_doa_measurement import ARRAY_DOAS, COVARIANCE, geometry


def direction_cosines_model(attitude: Any, axes: Any, reference: Any) -> Any:
    """``e_i . (A r)``: cosines between body axes ``e_i`` (rows) and one reference direction."""
    return axes @ (attitude @ reference)


class DirectionCosines(AttitudeMeasurement):
    """A measurement type written only as its symbolic model (no ``predict``)."""

    def __init__(self, cosines: Array, axes: Array, reference: Array, sigma: float) -> None:
        self.z = np.asarray(cosines, dtype=float)
        self.axes = np.asarray(axes, dtype=float)
        self.reference = np.asarray(reference, dtype=float)
        self.noise_covariance = np.full(self.z.size, sigma**2)
        self.blocks = np.zeros(self.z.size, dtype=np.intp)

    def symbolic(self) -> SymbolicModel:
        return SymbolicModel(direction_cosines_model, (self.axes, self.reference))


def direction_cosines(truth: Rotation, reference: Array, sigma: float = 1e-3) -> DirectionCosines:
    """Noise-free cosines of all three body axes: the body vector ``A r`` itself."""
    return DirectionCosines(truth.apply(reference), np.eye(3), reference, sigma)


@settings(max_examples=20, deadline=None)
@given(attitudes(), st.integers(0, 2**32 - 1))
def test_a_new_type_gets_values_jacobians_and_innovations(attitude, seed):
    reference = _unit_vectors(np.random.default_rng(seed), 1)[0]
    axes = _unit_vectors(np.random.default_rng(seed + 1), 4)
    measurement = DirectionCosines(np.zeros(4), axes, reference, 1e-3)
    h, jacobian = measurement.predict(attitude)
    np.testing.assert_allclose(h[0], axes @ attitude.apply(reference), atol=1e-14)
    numeric = central_differences(measurement, attitude)
    np.testing.assert_allclose(jacobian[0], numeric, rtol=1e-6, atol=1e-9)
    values, none = measurement.predict(attitude, jacobian=False)
    assert none is None and np.array_equal(values, h)
    np.testing.assert_array_equal(measurement.innovation(h), measurement.z - h)


def test_types_without_a_symbolic_model_say_so():
    stacked = StackedMeasurement([VectorMeasurement(np.eye(3)[:2], np.eye(3)[:2], 1e-3)])
    with pytest.raises(UnsupportedMeasurementError, match="StackedMeasurement"):
        stacked.symbolic()


@settings(max_examples=30, deadline=None)
@given(attitudes(), attitudes(), st.integers(1, 5), st.integers(0, 2**32 - 1))
def test_vector_model_and_geodesic_innovation_are_the_numpy_ones(attitude, other, k, seed):
    reference = _unit_vectors(np.random.default_rng(seed), k)
    body = 3.0 * other.apply(reference)  # not unit, far from the prediction
    measurement = VectorMeasurement(body, reference, 1e-3)
    model = measurement.symbolic_model()
    h, jacobian = model.evaluate(attitude)
    expected_h, expected_jacobian = measurement.predict(attitude)
    np.testing.assert_array_equal(h, expected_h)
    np.testing.assert_array_equal(jacobian, expected_jacobian)
    numpy = measurement.innovation(h)
    finite = np.isfinite(numpy)
    np.testing.assert_allclose(
        model.innovation_values(measurement.z, h)[finite], numpy[finite], atol=1e-12
    )


def test_geodesic_difference_is_smooth_through_zero():
    """The series branch below ``|p| = 1e-6 c`` joins the exact one, and the derivative at
    a perfect prediction is the linear model's ``I - u u^T`` (per unit length)."""
    z, h = ca.SX.sym("z", 3), ca.SX.sym("h", 3)
    nu = geodesic_difference(z, h)
    function = ca.Function("nu", [z, h], [nu, ca.jacobian(nu, z)])
    u = np.array([0.3, -0.4, 0.5])
    u /= np.linalg.norm(u)
    side = np.cross(u, [0.0, 0.0, 1.0])
    side /= np.linalg.norm(side)
    for angle in (1e-3, 1.000001e-6, 0.999999e-6, 1e-9):
        measured = np.cos(angle) * u + np.sin(angle) * side
        value = function(measured, 2.0 * u)[0].full().ravel()
        # p = z - c u cancels: its rounding is eps |z|, absolute.
        np.testing.assert_allclose(value, angle * side, rtol=1e-9, atol=4e-16)
    _, derivative = function(u, 2.0 * u)
    np.testing.assert_allclose(derivative.full(), np.eye(3) - np.outer(u, u), atol=1e-15)


@settings(max_examples=20, deadline=None)
@given(attitudes())
def test_euler_and_doa_wrapped_innovations_are_the_numpy_ones(attitude):
    rng = np.random.default_rng(3)
    euler = EulerAngleMeasurement(np.radians([179.0, 10.0, -179.5]), np.eye(3))
    h = euler.predict(attitude)[0]
    model = euler.symbolic_model()
    np.testing.assert_allclose(model.innovation_values(euler.z, h), euler.innovation(h), atol=1e-12)
    doa = DoaMeasurement(
        ARRAY_DOAS, COVARIANCE, geometry(attitude, Rotation.identity(), np.zeros(3))
    )
    predicted = doa.z + rng.uniform(-3.0, 3.0, (5, doa.size))  # azimuths off by up to 3 rad
    np.testing.assert_allclose(
        doa.symbolic_model().innovation_values(doa.z, predicted),
        doa.innovation(predicted),
        atol=1e-12,
    )


@settings(max_examples=20, deadline=None)
@given(attitudes(), st.integers(0, 2**32 - 1), st.booleans())
def test_snr_symbolic_model_is_the_predicted_snr(attitude, seed, truncated):
    """The symbolic model, evaluated for all observations at once, equals ``predict``'s
    per-observation AD evaluation (Gaussian and truncated models)."""
    measurement = _snr_measurement(attitude, seed, truncated=truncated)
    nearby = Rotation.from_rotvec([0.01, -0.02, 0.015]) * attitude
    h, jacobian = measurement.symbolic_model().evaluate(nearby)
    expected_h, expected_jacobian = measurement.predict(nearby)
    np.testing.assert_allclose(h, expected_h, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(jacobian, expected_jacobian, rtol=1e-10, atol=1e-10)


@settings(max_examples=20, deadline=None)
@given(attitudes(), attitudes())
def test_referenced_symbolic_model_is_the_inner_one_at_a_times_frame_inverse(inner_att, frame):
    doa = DoaMeasurement(
        ARRAY_DOAS, COVARIANCE, geometry(inner_att, Rotation.identity(), np.zeros(3))
    )
    referenced = ReferencedMeasurement(doa, frame)
    model = referenced.symbolic_model()
    assert model.rows == doa.symbolic_model().rows
    h, jacobian = model.evaluate(inner_att * frame)
    expected = doa.symbolic_model().evaluate(inner_att)
    np.testing.assert_allclose(h, expected[0], atol=1e-12)
    np.testing.assert_allclose(jacobian, expected[1], atol=1e-9)


def test_a_measurement_pickles_after_its_model_was_built():
    """The cached symbolic model (whose model may be a closure) is not pickled."""
    measurement = _snr_measurement(Rotation.identity(), 5)
    measurement.innovation(measurement.z)  # builds the cached model
    copy = pickle.loads(pickle.dumps(measurement))
    attitude = Rotation.from_rotvec([0.01, 0.0, -0.02])
    np.testing.assert_array_equal(copy.predict(attitude)[1], measurement.predict(attitude)[1])
    np.testing.assert_array_equal(
        copy.symbolic_model().evaluate(attitude)[0],
        measurement.symbolic_model().evaluate(attitude)[0],
    )
