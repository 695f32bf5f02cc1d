"""Measurements predicted together (``predict_each``, ``noise_covariance_each``,
``offset_slope_each``): equal, bit for bit and in order, to one ``predict`` per measurement,
for every type and for a mix of types."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import (
    AttitudeMeasurement,
    ReferencedMeasurement,
    VectorMeasurement,
    noise_covariance_each,
    offset_slope_each,
    predict_each,
)
from attopt.formulations.passes import Pass
from attopt.formulations.snr_measurement import SnrMeasurement
from tests.contract_cases import CASES


def _measurements_and_attitudes(seed: int) -> tuple[list[AttitudeMeasurement], Rotation]:
    """Every measurement of every contract case (each epoch of the passes), with its truth."""
    measurements, attitudes = [], []
    for case in CASES.values():
        drawn = case.draw(seed, True)
        problem = drawn.problem
        if isinstance(problem, Pass):
            for k, measurement in enumerate(problem.measurements()):
                if measurement is not None and measurement.size:
                    measurements.append(measurement)
                    attitudes.append(drawn.truth[k])
        else:
            for measurement in problem.measurements:
                measurements.append(measurement)
                attitudes.append(drawn.truth)
    return measurements, Rotation.concatenate(attitudes)


def _assert_identical(batch: list, loop: list) -> None:
    assert len(batch) == len(loop)
    for (h, j), (h0, j0) in zip(batch, loop, strict=True):
        assert h.shape == h0.shape and j.shape == j0.shape
        assert np.array_equal(h, h0, equal_nan=True) and np.array_equal(j, j0, equal_nan=True)


@pytest.fixture(scope="module")
def drawn() -> tuple[list[AttitudeMeasurement], Rotation]:
    return _measurements_and_attitudes(11)


def test_a_mix_of_every_type_is_predicted_as_one_at_a_time(drawn) -> None:
    measurements, attitudes = drawn
    frame = Rotation.from_rotvec([0.3, -0.2, 0.5])
    referenced = [ReferencedMeasurement(m, frame) for m in measurements[::3]]
    every = [*measurements, *referenced]
    attitudes = Rotation.concatenate([attitudes, attitudes[::3] * frame])
    assert {VectorMeasurement, SnrMeasurement, ReferencedMeasurement} <= {type(m) for m in every}
    order = np.random.default_rng(0).permutation(len(every))  # types interleaved
    mixed = [every[i] for i in order]
    loop = [m.predict(attitudes[i]) for m, i in zip(mixed, order, strict=True)]
    _assert_identical(predict_each(mixed, attitudes[order]), loop)


def test_batched_types_give_keys_and_the_others_are_predicted_alone(drawn) -> None:
    measurements, _ = drawn
    keyed = {type(m).__name__ for m in measurements if m.batch_key() is not None}
    assert {"VectorMeasurement", "SnrMeasurement"} <= keyed
    truncated = next(m for m in measurements if isinstance(m, SnrMeasurement))
    plain_key = truncated.batch_key()
    truncated = SnrMeasurement(truncated.epoch, truncated=True)
    assert truncated.batch_key() != plain_key  # another model: another call


def test_referenced_snr_epochs_of_a_pass_with_the_truncated_model() -> None:
    drawn = CASES["fg_batch_offsets"].draw(5, True)
    pass_ = drawn.problem
    epochs = [k for k, m in enumerate(pass_.measurements()) if m is not None and m.size]
    measurements = [pass_.measurements()[k] for k in epochs]
    assert all(isinstance(m, SnrMeasurement) for m in measurements)
    frame = Rotation.from_rotvec([0.1, 0.2, -0.3])  # a model relative to another frame
    threshold = float(np.median(np.concatenate([m.z for m in measurements])))  # truncating
    truncated = [
        ReferencedMeasurement(
            SnrMeasurement(replace(m.epoch, threshold_db=threshold), truncated=True), frame
        )
        for m in measurements
    ]
    attitudes = drawn.truth[epochs] * Rotation.from_rotvec([0.02, -0.01, 0.03])  # off the truth
    for group, at in ((measurements, attitudes), (truncated, attitudes * frame)):
        loop = [m.predict(at[i]) for i, m in enumerate(group)]
        _assert_identical(predict_each(group, at), loop)
        noise = [m.noise_covariance_at(at[i]) for i, m in enumerate(group)]
        for r, r0 in zip(noise_covariance_each(group, at), noise, strict=True):
            assert r.shape == r0.shape and np.array_equal(r, r0, equal_nan=True)
        slopes = [m.offset_slope(at[i]) for i, m in enumerate(group)]
        for c, c0 in zip(offset_slope_each(group, at), slopes, strict=True):
            assert c.shape == c0.shape and np.array_equal(c, c0, equal_nan=True)
    assert not np.array_equal(  # the truncated model's R depends on the attitude
        noise_covariance_each(truncated, attitudes * frame)[0], truncated[0].noise_covariance
    )
    slope = np.concatenate(offset_slope_each(truncated, attitudes * frame))  # so does dh/do
    assert np.nanmin(slope) < 0.99 and np.nanmax(slope) <= 1.0


def test_the_noise_of_a_mix_of_types_is_each_ones(drawn) -> None:
    measurements, attitudes = drawn
    loop = [m.noise_covariance_at(attitudes[i]) for i, m in enumerate(measurements)]
    for r, r0 in zip(noise_covariance_each(measurements, attitudes), loop, strict=True):
        assert np.array_equal(r, r0, equal_nan=True)
