"""Simulated vector-measurement passes shared by the filter and smoother tests."""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence

import numpy as np
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import AttitudeMeasurement, VectorMeasurement
from attopt.formulations.gyro import MEMS_GYRO, GyroModel, GyroSamples, simulate_gyro
from attopt.formulations.passes import GyroRecord, Pass, Prior, epoch_snapshots
from attopt.solvers.estimator import PassEstimator
from attopt.solvers.results import Track

GYRO = dataclasses.replace(MEMS_GYRO, name="mems-2hz", rate_hz=2.0)
RATE = np.array([0.01, -0.02, 0.015])
REFERENCES = np.array([[1.0, 0.0, 0.0], [0.0, 0.6, 0.8]])
SIGMA = 1e-3
"""Vector noise per axis (rad): a coarse star tracker or fine Sun sensor."""


@dataclasses.dataclass
class SimulatedPass:
    """One simulated pass: truth at the gyro times, gyro record, epochs and measurements."""

    truth: Rotation
    gyro: GyroSamples
    bias: np.ndarray
    t: np.ndarray
    index: np.ndarray
    measurements: list

    @property
    def truth_at_epochs(self) -> Rotation:
        return self.truth[self.index]

    @property
    def bias_at_epochs(self) -> np.ndarray:
        return self.bias[self.index]


def gyro_pass(
    gyro: GyroSamples,
    t: np.ndarray,
    measurements: Sequence[AttitudeMeasurement | None],
    prior: Prior,
    model: GyroModel = GYRO,
) -> Pass:
    """The :class:`~attopt.formulations.passes.Pass` of a gyro record (with ``model``),
    epochs, their measurements and a prior."""
    return Pass(t, epoch_snapshots(measurements, t), GyroRecord(gyro.t, gyro.rates, model), prior)


def solve_with(
    estimator: PassEstimator,
    gyro: GyroSamples,
    t: np.ndarray,
    measurements: Sequence[AttitudeMeasurement | None],
    prior: Prior,
    model: GyroModel = GYRO,
    initial: Track | None = None,
) -> Track:
    """``estimator`` on :func:`gyro_pass` of the arguments."""
    return estimator.solve(gyro_pass(gyro, t, measurements, prior, model), initial)


def simulate_pass(
    rng: np.random.Generator,
    duration: float = 300.0,
    sigma: float = SIGMA,
    noisy: bool = True,
    simulated_gyro: GyroModel = GYRO,
    rate: np.ndarray = RATE,
    references: np.ndarray = REFERENCES,
) -> SimulatedPass:
    """Truth turning at ``rate`` from a random start, its gyro record, and noisy (or
    exact) unit-vector measurements of ``references`` at 1 s epochs."""
    dt = simulated_gyro.dt
    t_gyro = np.arange(round(duration / dt) + 1) * dt
    start = Rotation.random(random_state=rng)
    truth = Rotation.from_rotvec(-np.outer(t_gyro, rate)) * start
    simulated = simulate_gyro(t_gyro, truth, simulated_gyro, rng)
    t = np.arange(int(duration) + 1, dtype=float)
    index = np.round(t / dt).astype(int)
    measurements = []
    for i in index:
        body = truth[i].apply(references)
        if noisy:
            body = body + sigma * rng.standard_normal(body.shape)
        measurements.append(VectorMeasurement(body, references, sigma))
    return SimulatedPass(truth, simulated.samples, simulated.bias, t, index, measurements)


def prior_covariance(attitude_sigma: float, model: GyroModel = GYRO) -> np.ndarray:
    return np.diag([attitude_sigma**2] * 3 + [model.initial_bias_sigma**2] * 3)


def drawn_prior(rng: np.random.Generator, run: SimulatedPass, covariance: np.ndarray) -> Prior:
    """Prior whose error ``[delta, delta_beta]`` is drawn from ``covariance``."""
    error = rng.multivariate_normal(np.zeros(6), covariance)
    attitude = Rotation.from_rotvec(-error[:3]) * run.truth[0]  # A_true = exp(delta) A_est
    return Prior(attitude, covariance, bias=run.bias[0] - error[3:])
