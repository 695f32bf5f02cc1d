"""Gyro truth, simulated gyro, priors and filter runs shared by the experiments.

The scenarios define the true attitude relative to the orbit frame (``A_bo``)
at the measurement epochs.  A gyro measures the body rate relative to the
inertial frame (ECI, GCRS), so the filters estimate ``A_bi = A_bo A_oi``
(:mod:`attopt.solvers.filters`) and their measurements are wrapped in
:class:`~attopt.formulations.attitude_measurement.ReferencedMeasurement` with the
epoch's ``A_oi``.  Between epochs the orbit frame is interpolated by
spherical linear interpolation (``scipy.spatial.transform.Slerp``: the orbit
frame turns at the nearly constant orbit rate, so the interpolation error is
far below a microradian for 1 s epochs) and ``A_bo`` is the scenario's
analytic profile, giving the truth at the gyro rate.  At the epochs the truth
is exactly the scenario's.

Estimates are reported relative to the orbit frame again
(:func:`in_orbit_frame`); the body-frame attitude error and its covariance
are the same in both frames.

Random streams of a trial: the scenario's measurement noise uses the trial's
seed as before; the gyro and the prior draw from a child stream
(:func:`child_rng`), so adding filters does not change the single-frame
methods' data.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation, Slerp

from attopt.formulations.attitude_measurement import AttitudeMeasurement, ReferencedMeasurement
from attopt.formulations.gyro import GyroModel, SimulatedGyro, simulate_gyro
from attopt.formulations.passes import GyroRecord, Pass, Prior, epoch_snapshots
from attopt.solvers.bounds import posterior_bound
from attopt.solvers.estimator import PassEstimator
from attopt.solvers.filters import Mekf, Rts, Usque
from attopt.solvers.results import Track
from attopt.solvers.smoother import (
    OFFSET_PRIOR_SIGMA_DB,
    BatchSmoother,
    OffsetBatchSmoother,
    OnlineSmoother,
)

Array = NDArray[np.float64]

GYRO_STREAM = 1
"""Spawn-key suffix of the gyro-and-prior stream of a trial."""
TO_DEG_H = np.degrees(1.0) * 3600.0
"""rad/s -> deg/h (bias columns)."""
INITIAL_ATTITUDE_SIGMA_DEG = 10.0
"""Default per-axis standard deviation of the filters' initial attitude error."""


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
class FilterInputs:
    """One trial's gyro record and prior (drawn from :func:`child_rng`)."""

    gyro: SimulatedGyro
    prior: Prior
    model: GyroModel

    def filter_pass(
        self, truth: GyroTruth, measurements: Sequence[AttitudeMeasurement | None]
    ) -> Pass:
        """The :class:`~attopt.formulations.passes.Pass` the filters solve: the epochs'
        orbit-frame ``measurements`` re-expressed for the inertial attitude
        (:func:`referenced`), the gyro record and the prior."""
        t = truth.t[truth.epoch_samples]
        inertial = referenced(measurements, truth.epoch_frames)
        samples = self.gyro.samples
        gyro = GyroRecord(samples.t, samples.rates, self.model)
        return Pass(t, epoch_snapshots(inertial, t), gyro, self.prior)


def simulate_filter_inputs(
    truth: GyroTruth,
    model: GyroModel,
    rng: np.random.Generator,
    initial_sigma_deg: float = INITIAL_ATTITUDE_SIGMA_DEG,
) -> FilterInputs:
    """Gyro samples, then the prior: attitude error ``~ N(0, sigma0^2 I3)``, bias estimate 0.

    The prior covariance is ``diag(sigma0^2 I3, initial_bias_sigma^2 I3)``, the
    statistics the truth was drawn from, so the filters start consistent.
    """
    gyro = simulate_gyro(truth.t, truth.attitude, model, rng)
    sigma0 = np.radians(initial_sigma_deg)
    error = sigma0 * rng.standard_normal(3)
    prior = Prior(
        attitude=Rotation.from_rotvec(error) * truth.attitude[0],
        covariance=np.diag([sigma0**2] * 3 + [model.initial_bias_sigma**2] * 3),
        bias=np.zeros(3),
    )
    return FilterInputs(gyro, prior, model)


def referenced(
    measurements: Sequence[AttitudeMeasurement | None], frames: Rotation
) -> list[AttitudeMeasurement | None]:
    """Orbit-frame measurement models re-expressed for the inertial attitude."""
    return [
        None if m is None else ReferencedMeasurement(m, frames[k])
        for k, m in enumerate(measurements)
    ]


FILTERS = ("mekf", "usque", "rts", "fg_online", "fg_batch", "fg_batch_offsets")
"""Filter kinds: the MEKF, USQUE, the RTS pass over the MEKF, and the factor-graph
smoother (:mod:`attopt.solvers.smoother`): causal fixed-lag (``fg_online``), batch over the
whole pass (``fg_batch``), and batch with one power offset per transmitter
(``fg_batch_offsets``, SNR measurements only).  The smoother rows keep their
names; the others take the caller's suffix."""
SMOOTHER_KINDS = ("fg_online", "fg_batch", "fg_batch_offsets")
VECTOR_FILTERS = tuple(k for k in FILTERS if k != "fg_batch_offsets")
"""Filter kinds for measurements without transmitter offsets to estimate."""


FILTER_ESTIMATORS: dict[str, PassEstimator] = {
    "mekf": Mekf(),
    "usque": Usque(),
    "rts": Rts(),
    "fg_online": OnlineSmoother(),
    "fg_batch": BatchSmoother(),
    "fg_batch_offsets": OffsetBatchSmoother(),
}
"""The registry estimators :func:`run_filter` runs, by filter kind."""


def run_filter(
    kind: str,
    inputs: FilterInputs,
    truth: GyroTruth,
    measurements: Sequence[AttitudeMeasurement | None],
    method: str,
    initial: Track | None = None,
    offset_sigma: float = OFFSET_PRIOR_SIGMA_DB,
) -> tuple[Track, float]:
    """Run filter ``kind`` on orbit-frame ``measurements``; the result and its wall time (s).

    ``initial``: the track it starts from (the RTS pass's MEKF, the batch
    smoothers' start; else its own: ``rts`` runs the MEKF and smooths it);
    ``fg_batch_offsets`` estimates one offset per transmitter with prior ``N(0,
    offset_sigma^2)``.
    """
    if kind not in FILTER_ESTIMATORS:
        raise ValueError(f"run_filter runs {', '.join(FILTER_ESTIMATORS)}, not {kind!r}")
    estimator = FILTER_ESTIMATORS[kind]
    if isinstance(estimator, OffsetBatchSmoother):
        estimator = replace(estimator, offset_sigma=offset_sigma)
    pass_ = inputs.filter_pass(truth, measurements)
    start = time.perf_counter()
    result = estimator.solve(pass_, initial)
    return replace(result, method=method), time.perf_counter() - start


def method_name(kind: str, suffix: str) -> str:
    """The row name of filter ``kind``: ``kind + suffix``; smoother kinds keep their names."""
    return kind if kind in SMOOTHER_KINDS else kind + suffix


def run_filters(
    kinds: Sequence[str],
    inputs: FilterInputs,
    truth: GyroTruth,
    measurements: Sequence[AttitudeMeasurement | None],
    suffix: str = "",
    offset_sigma: float = OFFSET_PRIOR_SIGMA_DB,
    initial: tuple[Track, float] | None = None,
) -> dict[str, tuple[Track, float]]:
    """Each filter kind's result and wall time (s), methods named ``kind + suffix``
    (smoother kinds keep their names).

    The RTS pass smooths the MEKF run (run once even when both are asked for);
    its time includes the MEKF's.  The batch smoothers start from ``initial`` (a
    result and the seconds it took) if given, else from the online smoother's
    causal estimates when ``fg_online`` is asked for (an online pass followed
    by a batch solve), else from the MEKF and RTS passes (their
    ``starts_from``); their times include that start's.  ``fg_batch_offsets``
    estimates one offset per transmitter with prior ``N(0, offset_sigma^2)``.
    """
    unknown = sorted(set(kinds) - set(FILTERS))
    if unknown:
        raise ValueError(f"unknown filter kinds {unknown}; known: {FILTERS}")
    wanted = set(kinds)
    batch = {"fg_batch", "fg_batch_offsets"} & wanted
    from_rts = bool(batch) and initial is None and "fg_online" not in wanted
    out: dict[str, tuple[Track, float]] = {}
    if {"mekf", "rts"} & wanted or from_rts:
        out["mekf"] = run_filter("mekf", inputs, truth, measurements, method_name("mekf", suffix))
    if "rts" in wanted or from_rts:
        filtered, seconds = out["mekf"]
        smoothed, rts_seconds = run_filter(
            "rts", inputs, truth, measurements, method_name("rts", suffix), filtered
        )
        out["rts"] = (smoothed, seconds + rts_seconds)
    if "usque" in wanted:
        out["usque"] = run_filter(
            "usque", inputs, truth, measurements, method_name("usque", suffix)
        )
    if "fg_online" in wanted:
        out["fg_online"] = run_filter("fg_online", inputs, truth, measurements, "fg_online")
    for kind in sorted(batch):
        start, seconds = initial or out["fg_online" if "fg_online" in wanted else "rts"]
        result, own = run_filter(kind, inputs, truth, measurements, kind, start, offset_sigma)
        out[kind] = (result, seconds + own)
    return {kind: out[kind] for kind in kinds}


def bound_columns(
    runs: Mapping[str, tuple[Track, float]],
    inputs: FilterInputs,
    truth: GyroTruth,
    measurements: Sequence[AttitudeMeasurement | None],
) -> dict[str, Array]:
    """``pbound_{x,y,z}_deg`` per epoch when ``runs`` has a factor-graph smoother, else
    nothing: the posterior Cramer-Rao bound of the pass
    (:func:`attopt.solvers.bounds.posterior_bound`) at the true attitudes and biases."""
    if not set(SMOOTHER_KINDS) & set(runs):
        return {}
    sigma = posterior_bound(
        inputs.filter_pass(truth, measurements),
        truth.attitude[truth.epoch_samples],
        inputs.gyro.bias[truth.epoch_samples],
    )
    return {f"pbound_{a}_deg": np.degrees(sigma)[:, i] for i, a in enumerate("xyz")}


def in_orbit_frame(track: Track, eci_to_orbit: Rotation) -> Track:
    """``A_bo = A_bi A_oi^T`` of a filter's track (covariance unchanged: body frame)."""
    quaternion = track.quaternion.copy()
    valid = track.valid
    if valid.any():
        quaternion[valid] = (track.attitude() * eci_to_orbit[valid].inv()).as_quat()
    return replace(track, quaternion=quaternion)


def filter_columns(result: Track, inputs: FilterInputs, truth: GyroTruth) -> dict[str, Array]:
    """Bias estimate, error and sigma (deg/h, per axis), the 6-state NEES ``nees_full``
    and the update counts, per epoch.

    The attitude columns come from :func:`attopt.experiments.metrics.error_columns`
    applied to :func:`in_orbit_frame` of the track.
    """
    true_bias = inputs.gyro.bias[truth.epoch_samples]
    bias_error = result.bias - true_bias
    attitude_error = (
        Rotation.from_quat(np.where(result.valid[:, None], result.quaternion, [0, 0, 0, 1]))
        * truth.attitude[truth.epoch_samples].inv()
    ).as_rotvec()
    error = np.concatenate([attitude_error, bias_error], axis=1)
    valid = result.valid
    nees = np.full(valid.size, np.nan)
    if valid.any():
        nees[valid] = np.einsum(
            "ei,eij,ej->e",
            error[valid],
            np.linalg.inv(result.state_covariance[valid]),
            error[valid],
        )
    sigma = np.sqrt(np.diagonal(result.state_covariance[:, 3:, 3:], axis1=1, axis2=2))
    columns = {f"bias_{a}_deg_h": TO_DEG_H * result.bias[:, i] for i, a in enumerate("xyz")}
    columns |= {f"bias_err_{a}_deg_h": TO_DEG_H * bias_error[:, i] for i, a in enumerate("xyz")}
    columns |= {f"bias_sigma_{a}_deg_h": TO_DEG_H * sigma[:, i] for i, a in enumerate("xyz")}
    columns["nees_full"] = nees
    for name in ("n_used", "n_gated", "n_unpredictable", "update_iterations"):
        columns[name] = result.diagnostics[name]
    return columns
