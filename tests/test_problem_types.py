"""The problem's nouns: snapshots and passes from arrays and pandas frames, the gyro record's
declared rate, priors, stacked measurements, vector noise as sigmas or covariances."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
from hypothesis import given, settings
from scipy.spatial.transform import Rotation

from attopt import (
    MEMS_GYRO,
    EulerAngleMeasurement,
    GyroRateMismatchError,
    GyroRecord,
    InvalidObservationError,
    Pass,
    Prior,
    Snapshot,
    StackedMeasurement,
    VectorMeasurement,
    estimator,
)
from attopt.formulations.snapshot import VECTOR_COLUMNS
from tests.strategies import attitudes

REFERENCE = np.array([[1.0, 0.0, 0.0], [0.0, 0.6, 0.8], [0.48, -0.6, 0.64]])
SIGMA = np.array([1e-3, 2e-3, 4e-3])


def _vector_frame(truth: Rotation, times: np.ndarray) -> pd.DataFrame:
    rows = []
    for t in times:
        for reference, body, sigma in zip(REFERENCE, truth.apply(REFERENCE), SIGMA, strict=True):
            rows.append({"t": t, **dict(zip(VECTOR_COLUMNS, [*body, *reference], strict=True))})
            rows[-1]["sigma"] = sigma
    return pd.DataFrame(rows)


@settings(max_examples=10, deadline=None)
@given(attitudes())
def test_a_snapshot_from_a_frame_equals_one_from_arrays(truth: Rotation) -> None:
    frame = _vector_frame(truth, np.array([3.5]))
    from_frame = Snapshot.from_dataframe(frame)
    from_arrays = Snapshot.from_vectors(truth.apply(REFERENCE), REFERENCE, SIGMA, t=3.5)
    assert from_frame.t == 3.5
    (a,), (b,) = from_frame.measurements, from_arrays.measurements
    np.testing.assert_array_equal(a.z, b.z)
    np.testing.assert_array_equal(a.noise_covariance, b.noise_covariance)
    solution = estimator("quest").solve(from_frame)
    assert (solution.attitude * truth.inv()).magnitude() < 1e-10


def test_a_frame_without_the_columns_or_with_two_times_is_refused() -> None:
    frame = _vector_frame(Rotation.identity(), np.array([0.0, 1.0]))
    with pytest.raises(InvalidObservationError, match="one time"):
        Snapshot.from_dataframe(frame)
    with pytest.raises(InvalidObservationError, match="sigma"):
        Snapshot.from_dataframe(frame.drop(columns="sigma"))


def test_a_pass_from_long_frames_groups_rows_by_time() -> None:
    truth = Rotation.from_euler("xyz", [10.0, 20.0, 30.0], degrees=True)
    times = np.array([0.25, 1.25, 2.25])
    frame = _vector_frame(truth, times).sample(frac=1.0, random_state=0)  # any row order
    rates = pd.DataFrame({"t": np.arange(31) / 10.0, "rate_x": 0.0, "rate_y": 0.0, "rate_z": 0.0})
    gyro = GyroRecord.from_dataframe(rates, MEMS_GYRO)
    pass_ = Pass.from_dataframe(frame, gyro, Prior(truth, 1e-4 * np.eye(3)))
    assert np.array_equal(pass_.t, times) and all(s.size == 9 for s in pass_.snapshots)
    assert gyro.rates.shape == (30, 3)
    track = estimator("mekf").solve(pass_)
    assert track.valid.all() and np.array_equal(track.t, times)
    errors = track.to_dataframe(Rotation.concatenate([truth] * 3))
    assert np.abs(errors[["err_x_deg", "err_y_deg", "err_z_deg"]].to_numpy()).max() < 1e-8


def test_the_gyro_must_follow_its_declared_rate_and_cover_the_epochs() -> None:
    with pytest.raises(GyroRateMismatchError, match="10 Hz"):
        GyroRecord(np.arange(21) / 20.0, np.zeros((20, 3)), MEMS_GYRO)  # 20 Hz samples
    gyro = GyroRecord(np.arange(11) / 10.0, np.zeros((10, 3)), MEMS_GYRO)
    snapshot = Snapshot.from_vectors(REFERENCE, REFERENCE, SIGMA)
    with pytest.raises(InvalidObservationError, match="cover"):
        Pass([0.5, 1.5], [snapshot, snapshot], gyro)
    with pytest.raises(InvalidObservationError, match="increasing"):
        Pass([0.5, 0.5], [snapshot, snapshot], gyro)
    with pytest.raises(InvalidObservationError, match="snapshots for"):
        Pass([0.5], [snapshot, snapshot], gyro)


def test_priors_are_checked_and_extended_with_the_gyro_bias() -> None:
    with pytest.raises(InvalidObservationError, match="positive definite"):
        Prior(Rotation.identity(), -np.eye(3))
    with pytest.raises(InvalidObservationError, match=r"\(6, 6\)"):
        Prior(Rotation.identity(), np.eye(3), bias=np.zeros(3))
    extended = Prior(Rotation.identity(), 4e-4 * np.eye(3)).with_bias_covariance(1e-3)
    assert np.array_equal(np.diag(extended.covariance), [4e-4] * 3 + [1e-6] * 3)
    assert np.array_equal(extended.bias, np.zeros(3))


@settings(max_examples=10, deadline=None)
@given(attitudes())
def test_a_stacked_measurement_is_its_parts_side_by_side(truth: Rotation) -> None:
    vectors = VectorMeasurement(truth.apply(REFERENCE), REFERENCE, SIGMA)
    angles = EulerAngleMeasurement(truth.inv().as_euler("ZYX"), 1e-4 * np.eye(3))
    stacked = Snapshot.of(vectors, angles).measurement()
    assert isinstance(stacked, StackedMeasurement) and stacked.size == 12
    h, jacobian = stacked.predict(truth)
    for part, rows in ((vectors, slice(0, 9)), (angles, slice(9, 12))):
        own_h, own_jacobian = part.predict(truth)
        np.testing.assert_array_equal(h[:, rows], own_h)
        np.testing.assert_array_equal(jacobian[:, rows], own_jacobian)
    assert stacked.noise_covariance.shape == (12, 12)  # the Euler angles' R is a matrix
    assert np.unique(stacked.blocks).size == 4  # three vectors and one angle triple
    np.testing.assert_allclose(stacked.innovation(h), 0.0, atol=1e-12)


def test_vector_noise_as_covariances_gives_the_isotropic_sigma_for_wahba() -> None:
    """``C = s^2 I`` is the sigma ``s``; a covariance along the vector adds nothing to the
    Wahba weight (it does not move the attitude to first order)."""
    body = REFERENCE
    isotropic = VectorMeasurement(body, REFERENCE, covariance=SIGMA[:, None, None] ** 2 * np.eye(3))
    np.testing.assert_allclose(isotropic.sigma, SIGMA, rtol=1e-12)
    along = np.einsum("ki,kj->kij", body, body) * 1e-2
    stretched = VectorMeasurement(
        body, REFERENCE, covariance=SIGMA[:, None, None] ** 2 * np.eye(3) + along
    )
    np.testing.assert_allclose(stretched.sigma, SIGMA, rtol=1e-12)
    with pytest.raises(InvalidObservationError, match="sigma or as covariance"):
        VectorMeasurement(body, REFERENCE)
    with pytest.raises(InvalidObservationError, match="positive definite"):
        VectorMeasurement(body, REFERENCE, covariance=np.zeros((3, 3, 3)))
