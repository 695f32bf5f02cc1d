"""The simulated world of a gyro-aided pass: gyro truth, gyro samples and the prior.

The scenarios define the true attitude relative to the orbit frame (``A_bo``)
at the measurement epochs.  A gyro measures the body rate relative to the
inertial frame (ECI, GCRS), so the gyro-aided estimators estimate ``A_bi =
A_bo A_oi`` and their measurements are wrapped in
:class:`~attopt.formulations.attitude_measurement.ReferencedMeasurement` with the
epoch's ``A_oi`` (:func:`referenced`).  Between epochs the orbit frame is
interpolated by spherical linear interpolation (``scipy.spatial.transform.Slerp``:
the orbit frame turns at the nearly constant orbit rate, so the interpolation
error is far below a microradian for 1 s epochs) and ``A_bo`` is the
scenario's analytic profile, giving the truth at the gyro rate
(:func:`gyro_truth`).  At the epochs the truth is exactly the scenario's.

:func:`simulate_filter_inputs` draws the gyro samples
(:func:`attopt.formulations.gyro.simulate_gyro`) and the prior;
:meth:`FilterInputs.gyro_pass` assembles the
:class:`~attopt.formulations.passes.Pass` the estimators solve with the truth
at its epochs (:class:`GyroPass`), which the metrics
(:mod:`attopt.experiments.metrics`) compare the tracks with.

Random streams of a trial: the scenario's measurement noise uses the trial's
seed; the gyro and the prior draw from a child stream (:func:`child_rng`), so
adding gyro-aided estimators does not change the single-frame methods' data.

Gyro faults (``[gyro_fault]``,
:class:`~attopt.experiments.config.components.GyroFault`) are applied here, once, to
the samples drawn: they change :attr:`FilterInputs.measured`, the record the
estimators get, never the truth (:attr:`FilterInputs.gyro`: the true rates and
bias, the fault-free samples) nor a random draw.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation, Slerp

from attopt.formulations.attitude_measurement import AttitudeMeasurement, ReferencedMeasurement
from attopt.formulations.gyro import GyroModel, GyroSamples, SimulatedGyro, simulate_gyro
from attopt.formulations.passes import GyroRecord, Pass, Prior, epoch_snapshots
from attopt.formulations.snapshot import Snapshot

if TYPE_CHECKING:
    from attopt.experiments.config.components import GyroFault

Array = NDArray[np.float64]

GYRO_STREAM = 1
"""Spawn-key suffix of the gyro-and-prior stream of a trial."""
INITIAL_ATTITUDE_SIGMA_DEG = 10.0
"""Default per-axis standard deviation of the prior's attitude error."""


def child_rng(seed: np.random.SeedSequence, stream: int) -> np.random.Generator:
    """Generator of an independent child stream of the trial's ``seed``."""
    child = np.random.SeedSequence(seed.entropy, spawn_key=(*seed.spawn_key, stream))
    return np.random.default_rng(child)


@dataclass(frozen=True)
class GyroTruth:
    """True inertial attitude at the gyro sample times of a pass.

    Attributes:
        t: ``(n,)`` gyro sample times (s), covering the epochs.
        attitude: ``A_bi`` at ``t``.
        epoch_frames: ``A_oi`` at the epochs.
        epoch_samples: index into ``t`` of each epoch.
    """

    t: Array
    attitude: Rotation
    epoch_frames: Rotation
    epoch_samples: NDArray[np.intp]


def gyro_truth(
    t_epochs: Array,
    eci_to_orbit: Rotation,
    attitude_orbit: Callable[[Array], Rotation],
    rate_hz: float,
) -> GyroTruth:
    """Truth at ``rate_hz`` from the scenario's ``A_bo(t)`` and the epochs' ``A_oi`` (docstring)."""
    t_epochs = np.asarray(t_epochs, dtype=float)
    per_epoch = (t_epochs - t_epochs[0]) * rate_hz
    samples = np.rint(per_epoch).astype(np.intp)
    if np.any(np.abs(per_epoch - samples) > 1e-6):
        raise ValueError(f"epochs must be multiples of the gyro step 1/{rate_hz} s")
    t = t_epochs[0] + np.arange(samples[-1] + 1) / rate_hz
    frame = Slerp(t_epochs, eci_to_orbit)(t)
    return GyroTruth(t, attitude_orbit(t) * frame, eci_to_orbit, samples)


@dataclass(frozen=True)
class GyroPass:
    """A simulated gyro-aided pass and its truth at the epochs.

    Attributes:
        pass_: what the gyro-aided estimators solve (inertial attitude).
        attitude: true ``A_bi`` at the epochs.
        bias: ``(N, 3)`` true gyro bias at the epochs (rad/s).
        frames: ``A_oi`` at the epochs (to report estimates in the orbit frame).
    """

    pass_: Pass
    attitude: Rotation
    bias: Array
    frames: Rotation


@dataclass(frozen=True)
class FilterInputs:
    """One trial's gyro record and prior (drawn from :func:`child_rng`).

    Attributes:
        gyro: the simulated gyro: the true rates and bias and the fault-free samples.
        prior: the estimators' prior.
        model: the gyro's noise model.
        measured: the samples the estimators are given: ``gyro.samples`` with the
            trial's gyro fault, if any (module docstring).
    """

    gyro: SimulatedGyro
    prior: Prior
    model: GyroModel
    measured: GyroSamples

    @property
    def record(self) -> GyroRecord:
        """:attr:`measured` as the record of a :class:`~attopt.formulations.passes.Pass`."""
        return GyroRecord(self.measured.t, self.measured.rates, self.model)

    def gyro_pass(
        self,
        truth: GyroTruth,
        measurements: Sequence[AttitudeMeasurement | Snapshot | None],
    ) -> GyroPass:
        """The epochs' orbit-frame ``measurements`` re-expressed for the inertial attitude
        (:func:`referenced`) with the gyro record and the prior, and the truth at the
        epochs."""
        t = truth.t[truth.epoch_samples]
        inertial = referenced(measurements, truth.epoch_frames)
        return GyroPass(
            Pass(t, epoch_snapshots(inertial, t), self.record, self.prior),
            truth.attitude[truth.epoch_samples],
            self.gyro.bias[truth.epoch_samples],
            truth.epoch_frames,
        )


def simulate_filter_inputs(
    truth: GyroTruth,
    model: GyroModel,
    rng: np.random.Generator,
    initial_sigma_deg: float = INITIAL_ATTITUDE_SIGMA_DEG,
    fault: GyroFault | None = None,
) -> FilterInputs:
    """Gyro samples, then the prior: attitude error ``~ N(0, sigma0^2 I3)``, bias estimate 0.

    The prior covariance is ``diag(sigma0^2 I3, initial_bias_sigma^2 I3)``, the
    statistics the truth was drawn from, so the estimators start consistent.  A
    ``fault`` changes the measured samples after every draw
    (:meth:`~attopt.experiments.config.components.GyroFault.measured`).
    """
    gyro = simulate_gyro(truth.t, truth.attitude, model, rng)
    sigma0 = np.radians(initial_sigma_deg)
    error = sigma0 * rng.standard_normal(3)
    prior = Prior(
        attitude=Rotation.from_rotvec(error) * truth.attitude[0],
        covariance=np.diag([sigma0**2] * 3 + [model.initial_bias_sigma**2] * 3),
        bias=np.zeros(3),
    )
    measured = gyro.samples if fault is None else fault.measured(gyro)
    return FilterInputs(gyro, prior, model, measured)


def referenced(
    measurements: Sequence[AttitudeMeasurement | Snapshot | None], frames: Rotation
) -> list[AttitudeMeasurement | None]:
    """Orbit-frame measurement models (or snapshots, each stacked into one measurement)
    re-expressed for the inertial attitude."""
    out: list[AttitudeMeasurement | None] = []
    for k, item in enumerate(measurements):
        m = item.measurement() if isinstance(item, Snapshot) else item
        out.append(None if m is None else ReferencedMeasurement(m, frames[k]))
    return out
