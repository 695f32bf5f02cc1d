"""Experiment ``wahba-mag-sun``: every Wahba solver on Cilden Guler et al. 2017's scenario.

One trial is one pass of :mod:`attopt.experiments.wahba_mag_sun.scenario` (by
default TIMED, 6000 s at 1 Hz; every choice is a parameter of
:mod:`attopt.experiments.wahba_mag_sun.parameters`) with fresh sensor noise
(:func:`simulate_pass`): each epoch one
:class:`~attopt.formulations.attitude_measurement.VectorMeasurement` of the Sun
and field directions with orbit-frame references (the Sun row dropped in
eclipse).  Every estimator sees the same measurements:

* ``methods``: snapshot estimators of the registry that accept unit vectors,
  labelled by their registry names; the Wahba solvers through their vectorised
  path (:meth:`~attopt.solvers.wahba.WahbaSolver.solve_batch`), any other
  through ``solve_sequence``;
* ``filters``: pass estimators of the registry (default the MEKF, USQUE, the
  RTS smoother over the MEKF and the GTSAM whole-pass smoother ``fg_batch``,
  started from the RTS estimates) run by
  :func:`attopt.solvers.pipeline.run_estimators` on the same vectors plus a
  simulated gyro (``gyro``: a :data:`attopt.formulations.gyro.GYRO_MODELS`
  name or a ``[gyro]`` table of datasheet numbers; Cilden Guler et al. 2017 has
  none, so the default is the MEMS unit) and a prior with ``initial_sigma_deg``
  attitude error per axis (:mod:`attopt.experiments.simulation`), its samples
  corrupted by ``[gyro_fault]`` if given
  (:class:`~attopt.experiments.config.components.GyroFault`).  The gyro and
  the prior draw from a child stream of the trial's seed
  (:func:`attopt.experiments.simulation.child_rng`), so the single-frame rows do
  not depend on the filters.

Rows are per method and epoch: ``t_s`` (seconds from ``start_utc``), the
eclipse ``interval``
(:data:`~attopt.experiments.wahba_mag_sun.scenario.INTERVALS`), the estimated
and true orbit -> body attitudes ``q_est_{x,y,z,w}`` and ``q_true_{x,y,z,w}``
(:func:`attopt.experiments.metrics.attitude_columns`), the metric columns of
:func:`attopt.experiments.metrics.error_columns` (body-axis error, the
method's own sigma and NEES, the 3-2-1 Euler-angle differences the paper's
Table 1 reports) and the Cramer-Rao bound of that epoch (``bound_*``: ``sqrt``
of the diagonal of ``[sum a_i (I - b_i b_i^T)]^-1`` at the true body vectors).
Filter rows add :func:`attopt.experiments.metrics.gyro_columns` (bias
estimates, gyro-bias error and sigma, 6-state NEES ``nees_full``, update
counts) and ``runtime_s``, the wall time of the pass (for ``rts``: the MEKF's
plus the backward pass's; for ``fg_batch`` its start's included); with a
factor-graph smoother among them, every filter row carries
``pbound_{x,y,z}_deg``, the posterior Cramer-Rao bound of the pass
(:func:`attopt.experiments.metrics.posterior_bound_columns`).  Single-frame
rows have NaN there.
"""

from __future__ import annotations

import functools
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
import pandas as pd
from pydantic import Field, ValidationInfo, field_validator

from attopt.experiments.config import Parameters
from attopt.experiments.config.components import (
    CircularOrbit,
    Gyro,
    GyroFault,
    Orbit,
    TleOrbit,
    UtcTime,
    gyro_model,
    repeated,
)
from attopt.experiments.environment.orbit import checked_window
from attopt.experiments.estimators import (
    FACTOR_GRAPH,
    EstimatorOptions,
    configured,
    configured_all,
    label_field,
    registered_labels,
    resolve,
)
from attopt.experiments.experiment import Experiment, Setting
from attopt.experiments.metrics import (
    attitude_columns,
    error_columns,
    gyro_columns,
    in_orbit_frame,
    posterior_bound_columns,
    status_columns,
)
from attopt.experiments.simulation import (
    GYRO_STREAM,
    INITIAL_ATTITUDE_SIGMA_DEG,
    FilterInputs,
    GyroTruth,
    child_rng,
    gyro_truth,
    simulate_filter_inputs,
)
from attopt.experiments.wahba_mag_sun.parameters import (
    TIMED,
    AttitudeProfile,
    Magnetometer,
    SunSensor,
)
from attopt.experiments.wahba_mag_sun.report import report
from attopt.experiments.wahba_mag_sun.scenario import (
    VectorGeometry,
    build_geometry,
    interval_labels,
    simulate_measurements,
    true_attitude,
)
from attopt.formulations.attitude_measurement import VectorMeasurement
from attopt.formulations.conventions import orbit_frame_attitude
from attopt.formulations.passes import Pass
from attopt.formulations.wahba_covariance import quest_covariance
from attopt.solvers import wahba
from attopt.solvers.estimator import SnapshotEstimator
from attopt.solvers.pipeline import run_estimators
from attopt.solvers.results import Track


def method_labels() -> dict[str, str]:
    """Row label -> registry name of the ``methods``: the snapshot estimators that accept
    unit vectors, by name."""
    return registered_labels("snapshot", VectorMeasurement)


def filter_labels() -> dict[str, str]:
    """Row label -> registry name of the ``filters``: the pass estimators that accept unit
    vectors, by name."""
    return registered_labels("pass", VectorMeasurement)


class WahbaMagSunParameters(Parameters):
    """Parameters of ``wahba-mag-sun``: the window, the orbit, the true attitude, the
    sensors and the estimators; the defaults are Cilden Guler et al. 2017 sec. 3's set-up
    (:mod:`attopt.experiments.wahba_mag_sun.parameters`), a 6000 s window at 1 Hz from a
    start chosen so that it holds one eclipse, and the MEMS gyro.

    A config file changes any of it, e.g. another satellite (CBERS-2, one of sgp4's
    verification TLEs)::

        start_utc = "2006-06-26T20:00:00"

        [orbit]
        type = "tle"
        line1 = "1 28057U 03049A   06177.78615833  .00000060  00000-0  35940-4 0  1836"
        line2 = "2 28057  98.4283 247.6961 0000884  88.1964 271.9322 14.35478080140550"

    or a generated orbit (``[orbit] type = "circular"``,
    :class:`~attopt.experiments.config.components.CircularOrbit`).  SGP4 must reach every
    epoch of the window (checked when the config is read); start the window near the
    elements' epoch, where they are accurate.  With ``filters``, the gyro's samples must
    fall on the epochs (``step_s * rate_hz`` a whole number).
    """

    start_utc: UtcTime = Field(
        "2026-05-10T23:23:00",
        description="Start of the pass (the default's eclipse begins 1001 s later).",
    )
    duration_s: float = Field(
        6000.0, gt=0, allow_inf_nan=False, description="Length of the pass from the start."
    )
    step_s: float = Field(1.0, gt=0, allow_inf_nan=False, description="Time between epochs.")
    orbit: Orbit = Field(default_factory=lambda: TIMED, description="The satellite's orbit.")
    attitude: AttitudeProfile = Field(
        default_factory=AttitudeProfile, description="True attitude profile."
    )
    magnetometer: Magnetometer = Field(
        default_factory=Magnetometer, description="Magnetometer (field direction)."
    )
    sun_sensor: SunSensor = Field(
        default_factory=SunSensor, description="Sun sensor (Sun direction, blind in eclipse)."
    )
    methods: list[label_field(method_labels, "methods")] = Field(
        default_factory=lambda: [solver.name for solver in wahba.ESTIMATORS],
        description="Single-frame Wahba solvers (registry names).",
    )
    filters: list[label_field(filter_labels, "filters")] = Field(
        default_factory=lambda: ["mekf", "usque", "rts", "fg_batch"],
        description="Gyro-aided filters and smoothers (registry names).",
    )
    gyro: Gyro = Field("mems", description="The filters' gyro: a preset or a [gyro] table.")
    gyro_fault: GyroFault | None = Field(
        None, description="Faults of the filters' gyro samples; none by default."
    )
    initial_sigma_deg: float = Field(
        INITIAL_ATTITUDE_SIGMA_DEG,
        gt=0,
        le=180.0,
        description="Per-axis sigma of the filters' prior.",
    )
    estimator_options: EstimatorOptions

    @field_validator("step_s")
    @classmethod
    def _two_epochs(cls, step_s: float, info: ValidationInfo) -> float:
        duration_s = info.data.get("duration_s")
        if duration_s is not None and step_s >= duration_s:
            raise ValueError(f"must be shorter than duration_s = {duration_s} (two epochs)")
        return step_s

    @field_validator("orbit")
    @classmethod
    def _propagates_over_the_window(cls, orbit: Orbit, info: ValidationInfo) -> Orbit:
        return checked_window(orbit, info.data)

    @field_validator("filters")
    @classmethod
    def _unique_names(cls, filters: list[str], info: ValidationInfo) -> list[str]:
        names = [*info.data.get("methods", []), *filters]
        if repeated(names):
            raise ValueError(f"names must be unique across methods and filters: {repeated(names)}")
        return filters

    @field_validator("gyro")
    @classmethod
    def _samples_on_the_epochs(cls, gyro: Gyro, info: ValidationInfo) -> Gyro:
        step_s = info.data.get("step_s")
        rate_hz = gyro_model(gyro).rate_hz
        if step_s is not None and info.data.get("filters"):
            samples = step_s * rate_hz
            if abs(samples - round(samples)) > 1e-6:
                raise ValueError(
                    f"a {rate_hz:g} Hz gyro has no samples at the epochs every "
                    f"step_s = {step_s:g} s (step_s * rate_hz must be a whole number)"
                )
        return gyro


def grid(parameters: Mapping[str, Any]) -> list[Setting]:
    """One setting: the parameters validated by :class:`WahbaMagSunParameters` (missing
    ones at their defaults); methods are compared inside each trial.

    Raises:
        pydantic.ValidationError: a ValueError naming each bad value (e.g. a method or
            filter the registry does not have, listing the registered ones).
    """
    return [WahbaMagSunParameters.model_validate(dict(parameters)).model_dump(mode="json")]


def geometry_of(parameters: WahbaMagSunParameters) -> VectorGeometry:
    """The pass's geometry (:func:`~attopt.experiments.wahba_mag_sun.scenario.build_geometry`,
    cached per process)."""
    p = parameters
    return build_geometry(p.orbit, p.start_utc, p.duration_s, p.step_s, p.attitude)


@dataclass(frozen=True)
class VectorPass:
    """One trial's measured Sun and field directions (orbit-frame references).

    Attributes:
        body: ``(N, 2, 3)`` measured body vectors, Sun then field (Sun NaN in eclipse).
        reference: ``(N, 2, 3)`` their orbit-frame references.
        sigma: direction noise (Sun, field).
        present: ``(N, 2)`` which vectors were measured.
        pass_: the same as one snapshot per epoch.
    """

    body: np.ndarray
    reference: np.ndarray
    sigma: tuple[float, float]
    present: np.ndarray
    pass_: Pass

    @property
    def weights(self) -> np.ndarray:
        """``(N, 2)`` Wahba weights ``1 / sigma^2`` (Cilden Guler et al. 2017 eq. 14)."""
        return np.tile([s**-2 for s in self.sigma], (self.body.shape[0], 1))


def simulate_pass(
    geometry: VectorGeometry, seed: np.random.SeedSequence, parameters: WahbaMagSunParameters
) -> VectorPass:
    """The trial's noisy vectors
    (:func:`~attopt.experiments.wahba_mag_sun.scenario.simulate_measurements` with the
    sensors' sigmas, the trial's seed)."""
    sun_sigma = parameters.sun_sensor.sigma_rad
    mag_sigma = parameters.magnetometer.sigma_rad
    sun_body, mag_body = simulate_measurements(
        geometry, np.random.default_rng(seed), mag_sigma_rad=mag_sigma, sun_sigma_rad=sun_sigma
    )
    n = geometry.t.size
    body = np.stack([sun_body, mag_body], axis=1)
    reference = np.stack([geometry.sun_orbit, geometry.mag_orbit], axis=1)
    sigma = (sun_sigma, mag_sigma)
    present = np.stack([~geometry.in_eclipse, np.ones(n, dtype=bool)], axis=1)
    return VectorPass(
        body, reference, sigma, present, Pass.from_vectors(geometry.t, body, reference, sigma)
    )


def trial(setting: Setting, seed: np.random.SeedSequence) -> pd.DataFrame:
    """One noisy pass solved by every method in ``setting["methods"]`` and every filter
    in ``setting["filters"]``."""
    parameters = WahbaMagSunParameters.model_validate(setting)
    geometry = geometry_of(parameters)
    vectors = simulate_pass(geometry, seed, parameters)
    common = epoch_columns(geometry, vectors)
    methods = resolve(parameters.methods, method_labels(), "methods")
    options = parameters.estimator_options
    frames = [
        _method_rows(label, snapshot_track(configured(name, options), vectors), geometry, common)
        for label, name in methods.items()
    ]
    if parameters.filters:
        frames += _filter_rows(parameters, seed, vectors, geometry, common)
    return pd.concat(frames, ignore_index=True)


def epoch_columns(geometry: VectorGeometry, vectors: VectorPass) -> dict[str, np.ndarray]:
    """``t_s``, the eclipse ``interval``
    (:func:`~attopt.experiments.wahba_mag_sun.scenario.interval_labels`) and the
    Cramer-Rao bound ``bound_{x,y,z}_deg`` of each epoch (NaN where the information is
    singular)."""
    true_body = np.stack(
        [geometry.truth.apply(geometry.sun_orbit), geometry.truth.apply(geometry.mag_orbit)], axis=1
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        crb = _safe_inverse_diag(true_body, np.where(vectors.present, vectors.weights, 0.0))
    return {
        "t_s": geometry.t,
        "interval": interval_labels(geometry),
        "bound_x_deg": np.degrees(np.sqrt(crb[:, 0])),
        "bound_y_deg": np.degrees(np.sqrt(crb[:, 1])),
        "bound_z_deg": np.degrees(np.sqrt(crb[:, 2])),
    }


def snapshot_track(method: SnapshotEstimator, vectors: VectorPass) -> Track:
    """The method's track over the pass: a Wahba solver's vectorised path, else
    ``solve_sequence`` over the snapshots."""
    if isinstance(method, wahba.WahbaSolver):
        return method.solve_batch(vectors.body, vectors.reference, vectors.weights, vectors.present)
    return method.solve_sequence(vectors.pass_.snapshots)


def filter_truth(parameters: WahbaMagSunParameters, rate_hz: float) -> GyroTruth:
    """Inertial truth of the pass at the gyro rate (cached per process like the geometry):
    ``A_bi`` at ``rate_hz`` and ``A_oi`` at the epochs."""
    p = parameters
    return _filter_truth(p.orbit, p.start_utc, p.duration_s, p.step_s, p.attitude, rate_hz)


@functools.lru_cache(maxsize=8)
def _filter_truth(
    orbit: TleOrbit | CircularOrbit,
    start_utc: str,
    duration_s: float,
    step_s: float,
    attitude: AttitudeProfile,
    rate_hz: float,
) -> GyroTruth:
    geometry = build_geometry(orbit, start_utc, duration_s, step_s, attitude)
    frames = orbit_frame_attitude(geometry.position_eci_km, geometry.velocity_eci_kms)
    profile = functools.partial(true_attitude, profile=attitude)
    return gyro_truth(geometry.t, frames, profile, rate_hz)


def filter_inputs(
    parameters: WahbaMagSunParameters, seed: np.random.SeedSequence
) -> tuple[GyroTruth, FilterInputs]:
    """The inertial truth at the gyro rate and the trial's gyro record and prior (from the
    trial's gyro stream), as the gyro-aided rows and the pass export use them."""
    model = gyro_model(parameters.gyro)
    truth = filter_truth(parameters, model.rate_hz)
    inputs = simulate_filter_inputs(
        truth,
        model,
        child_rng(seed, GYRO_STREAM),
        parameters.initial_sigma_deg,
        parameters.gyro_fault,
    )
    return truth, inputs


def _filter_rows(
    parameters: WahbaMagSunParameters,
    seed: np.random.SeedSequence,
    vectors: VectorPass,
    geometry: VectorGeometry,
    common: Mapping[str, np.ndarray],
) -> list[pd.DataFrame]:
    truth, inputs = filter_inputs(parameters, seed)
    simulated = inputs.gyro_pass(truth, vectors.pass_.snapshots)
    filters = resolve(parameters.filters, filter_labels(), "filters")
    runs = run_estimators(simulated.pass_, configured_all(filters, parameters.estimator_options))
    bound = posterior_bound_columns(simulated) if FACTOR_GRAPH & set(filters.values()) else {}
    frames = []
    for label, run in runs.items():
        track = in_orbit_frame(run.track, simulated.frames)
        frames.append(
            pd.DataFrame(
                {
                    "method": label,
                    **common,
                    **attitude_columns(track.quaternion, geometry.truth),
                    **error_columns(track, geometry.truth),
                    **status_columns(track),
                    **gyro_columns(run.track, simulated),
                    **bound,
                    "runtime_s": run.seconds,
                }
            )
        )
    return frames


def _safe_inverse_diag(true_body: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Diagonal of the Cramer-Rao bound; NaN where the information is singular."""
    info_rank_ok = (weights > 0).sum(axis=1) >= 2
    out = np.full((weights.shape[0], 3), np.nan)
    if info_rank_ok.any():
        cov = quest_covariance(true_body[info_rank_ok], weights[info_rank_ok])
        out[info_rank_ok] = np.diagonal(cov, axis1=1, axis2=2)
    return out


def _method_rows(
    label: str, track: Track, geometry: VectorGeometry, common: Mapping[str, np.ndarray]
) -> pd.DataFrame:
    return pd.DataFrame(
        {
            "method": label,
            **common,
            **attitude_columns(track.quaternion, geometry.truth),
            **error_columns(track, geometry.truth),
            **status_columns(track),
        }
    )


EXPERIMENT = Experiment(
    name="wahba-mag-sun",
    summary=(
        "Cilden Guler et al. 2017: six Wahba solvers on TIMED with magnetometer + Sun sensor, "
        "vs the CRB"
    ),
    schema=WahbaMagSunParameters,
    grid=grid,
    trial=trial,
    default_trials=20,
    quick_trials=2,
    quick_parameters={"duration_s": 3000.0},
    group_by=("method", "interval"),
    report=report,
    compiled_loops=("wahba", "filters", "vectors", "smoother"),
)
