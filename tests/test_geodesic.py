"""The unit vectors' compiled geodesic difference against its numpy reference."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from attopt.formulations import attitude_measurement
from attopt.formulations.attitude_measurement import VectorMeasurement
from attopt.formulations.geodesic import geodesic_rows


def _unit(rng: np.random.Generator, k: int) -> np.ndarray:
    v = rng.normal(size=(k, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def _both_paths(
    measurement: VectorMeasurement, predicted: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The innovation on the compiled path and on the numpy path."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(attitude_measurement, "compiled_loops", lambda: True)
        compiled = measurement.innovation(predicted)
        patch.setattr(attitude_measurement, "compiled_loops", lambda: False)
        return compiled, measurement.innovation(predicted)


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    k=st.integers(1, 5),
    shape=st.sampled_from([(), (1,), (13,), (2, 3)]),
    spread=st.sampled_from([0.0, 1e-9, 1e-3, 0.5, 3.0]),
)
def test_compiled_innovation_equals_the_numpy_reference(
    seed: int, k: int, shape: tuple[int, ...], spread: float
) -> None:
    """Predictions near and far from the measured vectors, of any length, stacked on any
    leading axes: the two paths agree to round-off, with the same shape."""
    rng = np.random.default_rng(seed)
    z = _unit(rng, k)
    measurement = VectorMeasurement(z, z, 1e-3)
    predicted = (z + spread * rng.normal(size=(*shape, k, 3))) * rng.uniform(0.5, 2.0)
    predicted = predicted.reshape(*shape, 3 * k)
    compiled, reference = _both_paths(measurement, predicted)
    assert compiled.shape == reference.shape == predicted.shape
    np.testing.assert_allclose(compiled, reference, rtol=1e-14, atol=1e-15)


def test_the_edge_cases_agree() -> None:
    """Along the measured vector: 0; opposite, zero or not finite: NaN, on both paths."""
    z = np.array([[0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    measurement = VectorMeasurement(z, z, 1e-3)
    predicted = np.array([[0.0, 0.0, 2.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 0.0], [np.nan, 0.0, 1.0]])
    with np.errstate(invalid="ignore", divide="ignore"):
        compiled, reference = _both_paths(measurement, predicted.ravel())
    expected = [0.0, 0.0, 0.0] + [np.nan] * 9
    np.testing.assert_array_equal(compiled, expected)
    np.testing.assert_array_equal(reference, expected)


def test_a_quarter_turn_is_the_angle_along_the_measured_direction() -> None:
    """``u = x``, ``z = y``: the tangent vector at ``u`` towards ``z``, 90 deg long
    (independent of either implementation)."""
    out = geodesic_rows(np.array([[3.0, 0.0, 0.0]]), np.array([0.0, 1.0, 0.0]))
    np.testing.assert_allclose(out, [[0.0, np.pi / 2, 0.0]], atol=1e-15)
