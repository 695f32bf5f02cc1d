"""The smoothers' central differences of the innovation: the compiled arithmetic against
the numpy reference, and the chain rule against known derivatives."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import VectorMeasurement
from attopt.solvers.blocks import block_structure
from attopt.solvers.smoother import measurement_factors
from attopt.solvers.smoother.measurement_factors import innovation_jacobian


def _both_paths(measurement, predicted, jacobian, labels) -> tuple[np.ndarray, np.ndarray]:
    """``innovation_jacobian`` on the compiled path and on the numpy path."""
    members = block_structure(labels).members
    out = []
    with pytest.MonkeyPatch.context() as patch:
        for enabled in (True, False):
            patch.setattr(measurement_factors, "compiled_loops", lambda enabled=enabled: enabled)
            out.append(innovation_jacobian(measurement, predicted, jacobian, members))
    return out[0], out[1]


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), k=st.integers(1, 6), spread=st.sampled_from([0, 1e-3, 0.3]))
def test_compiled_differences_equal_the_numpy_reference_for_unit_vectors(
    seed: int, k: int, spread: float
) -> None:
    """Unit vectors (blocks of three, the geodesic innovation) measured near or far from
    their predictions: both paths give the same derivative to round-off."""
    rng = np.random.default_rng(seed)
    reference = rng.normal(size=(k, 3))
    reference /= np.linalg.norm(reference, axis=1, keepdims=True)
    attitude = Rotation.random(rng=rng)
    body = attitude.apply(reference) + spread * rng.normal(size=(k, 3))
    measurement = VectorMeasurement(body, reference, 1e-3)
    predicted, jacobian = measurement.predict(attitude)
    compiled, numpy = _both_paths(measurement, predicted[0], jacobian[0], measurement.blocks)
    np.testing.assert_allclose(compiled, numpy, rtol=1e-12, atol=1e-15)


def test_a_difference_innovation_gives_the_models_jacobian_and_padding_stays_out() -> None:
    """``nu = z - h`` (SNRs, angles): the derivative is ``-(-I) J = J`` up to the
    differences' round-off.  Blocks of sizes 1, 2 and 3 pad the smaller ones; a NaN
    Jacobian in the row the padding points at (row 0) reaches no other block."""
    rng = np.random.default_rng(4)
    labels = np.array([7, 3, 3, 5, 5, 5])
    z = rng.normal(size=6)
    measurement = SimpleNamespace(innovation=lambda h: z - h)
    predicted, jacobian = 10.0 * rng.normal(size=6), rng.normal(size=(6, 3))
    compiled, numpy = _both_paths(measurement, predicted, jacobian, labels)
    np.testing.assert_allclose(compiled, jacobian, rtol=1e-8)
    np.testing.assert_allclose(numpy, compiled, rtol=1e-12)
    jacobian[0] = np.nan
    compiled, numpy = _both_paths(measurement, predicted, jacobian, labels)
    assert np.isnan(compiled[0]).all() and np.isnan(numpy[0]).all()
    np.testing.assert_allclose(compiled[1:], jacobian[1:], rtol=1e-8)
    np.testing.assert_allclose(numpy[1:], compiled[1:], rtol=1e-12)
