"""Experiment ``wahba-mag-sun``: every Wahba solver on Cilden Guler et al. 2017's scenario.

One trial is one pass of :mod:`attopt.experiments.wahba_mag_sun.scenario` (6000 s
at 1 Hz) with fresh sensor noise (:func:`simulate_pass`): each epoch one
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
  simulated gyro (``gyro``, a :data:`attopt.formulations.gyro.GYRO_MODELS`
  name; Cilden Guler et al. 2017 has none, so the default is the MEMS unit)
  and a prior with ``initial_sigma_deg`` attitude error per axis
  (:mod:`attopt.experiments.simulation`).  The gyro and the prior draw from a
  child stream of the trial's seed (:func:`attopt.experiments.simulation.child_rng`),
  so the single-frame rows do not depend on the filters.

Rows are per method and epoch: the metric columns of
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
import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
import pandas as pd
from pydantic import Field

from attopt.experiments.config import Parameters
from attopt.experiments.estimators import FACTOR_GRAPH, label_field, registered_labels, resolve
from attopt.experiments.experiment import Experiment, Setting
from attopt.experiments.metrics import (
    error_columns,
    gyro_columns,
    in_orbit_frame,
    posterior_bound_columns,
    status_columns,
)
from attopt.experiments.simulation import (
    GYRO_STREAM,
    INITIAL_ATTITUDE_SIGMA_DEG,
    GyroTruth,
    child_rng,
    gyro_truth,
    simulate_filter_inputs,
)
from attopt.experiments.wahba_mag_sun.report import report
from attopt.experiments.wahba_mag_sun.scenario import (
    MAG_SIGMA,
    SUN_SIGMA,
    VectorGeometry,
    build_geometry,
    simulate_measurements,
    true_attitude,
)
from attopt.formulations.attitude_measurement import VectorMeasurement
from attopt.formulations.conventions import orbit_frame_attitude
from attopt.formulations.gyro import GYRO_MODELS
from attopt.formulations.passes import Pass
from attopt.formulations.wahba_covariance import quest_covariance
from attopt.solvers import wahba
from attopt.solvers.estimator import SnapshotEstimator
from attopt.solvers.pipeline import run_estimators
from attopt.solvers.registry import estimator
from attopt.solvers.results import Track

INTERVALS = ("before_eclipse", "eclipse", "after_eclipse")


def method_labels() -> dict[str, str]:
    """Row label -> registry name of the ``methods``: the snapshot estimators that accept
    unit vectors, by name."""
    return registered_labels("snapshot", VectorMeasurement)


def filter_labels() -> dict[str, str]:
    """Row label -> registry name of the ``filters``: the pass estimators that accept unit
    vectors, by name."""
    return registered_labels("pass", VectorMeasurement)


class WahbaMagSunParameters(Parameters):
    """Parameters of ``wahba-mag-sun`` (Cilden Guler et al. 2017 sec. 3)."""

    duration_s: float = Field(6000.0, gt=0, description="Length of the pass from the start.")
    step_s: float = Field(1.0, gt=0, description="Time between epochs.")
    mag_sigma: float = Field(
        MAG_SIGMA, gt=0, description="Magnetometer direction-cosine noise standard deviation."
    )
    sun_sigma: float = Field(
        SUN_SIGMA, gt=0, description="Sun-sensor direction-cosine noise standard deviation."
    )
    methods: list[label_field(method_labels, "methods")] = Field(
        default_factory=lambda: [solver.name for solver in wahba.ESTIMATORS],
        description="Single-frame Wahba solvers (registry names).",
    )
    filters: list[label_field(filter_labels, "filters")] = Field(
        default_factory=lambda: ["mekf", "usque", "rts", "fg_batch"],
        description="Gyro-aided filters and smoothers (registry names).",
    )
    gyro: Literal[tuple(GYRO_MODELS)] = Field("mems", description="Gyro model preset.")
    initial_sigma_deg: float = Field(
        INITIAL_ATTITUDE_SIGMA_DEG, gt=0, description="Per-axis sigma of the filters' prior."
    )


def grid(parameters: Mapping[str, Any]) -> list[Setting]:
    """One setting: the paper's sensor noise; methods are compared inside each trial.

    Raises:
        ValueError: for a method or filter the registry does not have (the message
            lists the registered ones), an unknown gyro model, a name used twice
            across ``methods`` and ``filters``, or a non-positive ``initial_sigma_deg``.
    """
    resolve(parameters["methods"], method_labels(), "methods")
    filters = list(parameters.get("filters", []))
    resolve(filters, filter_labels(), "filters")
    names = [*parameters["methods"], *filters]
    repeated = sorted({name for name in names if names.count(name) > 1})
    if repeated:
        raise ValueError(f"method names must be unique across methods and filters: {repeated}")
    if parameters.get("gyro", "mems") not in GYRO_MODELS:
        raise ValueError(f"unknown gyro {parameters['gyro']!r}; known: {sorted(GYRO_MODELS)}")
    sigma = parameters.get("initial_sigma_deg", INITIAL_ATTITUDE_SIGMA_DEG)
    if isinstance(sigma, bool) or not (
        isinstance(sigma, int | float) and math.isfinite(sigma) and sigma > 0
    ):
        raise ValueError(f"initial_sigma_deg must be a positive number, got {sigma!r}")
    return [dict(parameters)]


def interval_labels(geometry: VectorGeometry) -> np.ndarray:
    """``before_eclipse``, ``eclipse`` or ``after_eclipse`` per epoch."""
    labels = np.full(geometry.t.shape, INTERVALS[0], dtype=object)
    if geometry.eclipse_interval is not None:
        start, end = geometry.eclipse_interval
        labels[geometry.t >= start] = INTERVALS[1]
        labels[geometry.t >= end] = INTERVALS[2]
    return labels


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
    geometry: VectorGeometry, seed: np.random.SeedSequence, setting: Setting
) -> VectorPass:
    """The trial's noisy vectors
    (:func:`~attopt.experiments.wahba_mag_sun.scenario.simulate_measurements`, the
    trial's seed)."""
    sun_body, mag_body = simulate_measurements(
        geometry,
        np.random.default_rng(seed),
        mag_sigma=setting["mag_sigma"],
        sun_sigma=setting["sun_sigma"],
    )
    n = geometry.t.size
    body = np.stack([sun_body, mag_body], axis=1)
    reference = np.stack([geometry.sun_orbit, geometry.mag_orbit], axis=1)
    sigma = (setting["sun_sigma"], setting["mag_sigma"])
    present = np.stack([~geometry.in_eclipse, np.ones(n, dtype=bool)], axis=1)
    return VectorPass(
        body, reference, sigma, present, Pass.from_vectors(geometry.t, body, reference, sigma)
    )


def trial(setting: Setting, seed: np.random.SeedSequence) -> pd.DataFrame:
    """One noisy pass solved by every method in ``setting["methods"]`` and every filter
    in ``setting["filters"]``."""
    geometry = build_geometry(setting["duration_s"], setting["step_s"])
    vectors = simulate_pass(geometry, seed, setting)
    common = epoch_columns(geometry, vectors)
    methods = resolve(setting["methods"], method_labels(), "methods")
    frames = [
        _method_rows(label, snapshot_track(estimator(name), vectors), geometry, common)
        for label, name in methods.items()
    ]
    if setting.get("filters"):
        frames += _filter_rows(setting, seed, vectors, geometry, common)
    return pd.concat(frames, ignore_index=True)


def epoch_columns(geometry: VectorGeometry, vectors: VectorPass) -> dict[str, np.ndarray]:
    """``t``, the eclipse ``interval`` and the Cramer-Rao bound ``bound_{x,y,z}_deg`` of
    each epoch (NaN where the information is singular)."""
    true_body = np.stack(
        [geometry.truth.apply(geometry.sun_orbit), geometry.truth.apply(geometry.mag_orbit)], axis=1
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        crb = _safe_inverse_diag(true_body, np.where(vectors.present, vectors.weights, 0.0))
    return {
        "t": geometry.t,
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


def filter_truth(duration_s: float, step_s: float, rate_hz: float) -> GyroTruth:
    """Inertial truth of :func:`build_geometry`'s pass at the gyro rate (cached per
    process like the geometry): ``A_bi`` at ``rate_hz`` and ``A_oi`` at the epochs."""
    return _filter_truth(float(duration_s), float(step_s), float(rate_hz))


@functools.lru_cache(maxsize=8)
def _filter_truth(duration_s: float, step_s: float, rate_hz: float) -> GyroTruth:
    geometry = build_geometry(duration_s, step_s)
    frames = orbit_frame_attitude(geometry.position_eci_km, geometry.velocity_eci_kms)
    return gyro_truth(geometry.t, frames, true_attitude, rate_hz)


def _filter_rows(
    setting: Setting,
    seed: np.random.SeedSequence,
    vectors: VectorPass,
    geometry: VectorGeometry,
    common: Mapping[str, np.ndarray],
) -> list[pd.DataFrame]:
    model = GYRO_MODELS[setting.get("gyro", "mems")]
    truth = filter_truth(setting["duration_s"], setting["step_s"], model.rate_hz)
    inputs = simulate_filter_inputs(
        truth,
        model,
        child_rng(seed, GYRO_STREAM),
        setting.get("initial_sigma_deg", INITIAL_ATTITUDE_SIGMA_DEG),
    )
    simulated = inputs.gyro_pass(truth, vectors.pass_.snapshots)
    filters = resolve(setting["filters"], filter_labels(), "filters")
    runs = run_estimators(simulated.pass_, filters)
    bound = posterior_bound_columns(simulated) if FACTOR_GRAPH & set(filters.values()) else {}
    frames = []
    for label, run in runs.items():
        track = in_orbit_frame(run.track, simulated.frames)
        frames.append(
            pd.DataFrame(
                {
                    "method": label,
                    **common,
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
        {"method": label, **common, **error_columns(track, geometry.truth), **status_columns(track)}
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
)
