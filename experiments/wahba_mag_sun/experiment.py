"""Experiment ``wahba-mag-sun``: every Wahba solver on seed 002's scenario.

One trial is one pass of :mod:`attopt.experiments.wahba_mag_sun.scenario` (6000 s
at 1 Hz) with fresh sensor noise; every solver sees the same measurements.
Rows are per method and epoch: the body-axis attitude error, the Cramer-Rao
bound of that epoch (``sqrt`` of the diagonal of ``[sum a_i (I - b_i b_i^T)]^-1``
at the true body vectors) and the method's own covariance (as ``sigma_*`` and
the normalised estimation error squared ``nees``), and the 3-2-1 Euler-angle
differences the seed's Table 1 reports.

Gyro-aided filters (``filters``: the MEKF, USQUE and the RTS smoother over
the MEKF, :mod:`attopt.experiments.filtering`) see the same vector measurements
(each epoch one :class:`~attopt.formulations.attitude_measurement.VectorMeasurement`
of the Sun and field directions, orbit-frame references; the Sun row is
dropped in eclipse) plus a simulated gyro (``gyro``, a
:data:`attopt.formulations.gyro.GYRO_MODELS` name; seed 002 has none, so the default
is the MEMS unit) and a prior with ``initial_sigma_deg`` attitude error per
axis.  The gyro and the prior draw from a child stream of the trial's seed
(:func:`attopt.experiments.filtering.child_rng`), so the single-frame rows do not
depend on the filters.  Filter rows carry the single-frame columns plus
:func:`attopt.experiments.filtering.filter_columns` (gyro-bias error and sigma,
6-state NEES ``nees_full``, update counts), the bias estimates
``bias_{x,y,z}_deg_h`` and ``runtime_s``, the wall time of the pass (for
``rts``: the MEKF's plus the backward pass's); single-frame rows have NaN
there.  ``fg_batch`` is the GTSAM whole-pass smoother (:mod:`attopt.solvers.smoother`)
started from the RTS estimates (its ``runtime_s`` includes them); with it,
the gyro-aided rows carry ``pbound_{x,y,z}_deg``, the posterior Cramer-Rao
bound of the pass (:func:`attopt.solvers.bounds.posterior_bound`).
"""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from typing import Any

import numpy as np
import pandas as pd

from attopt.experiments.experiment import Experiment, Setting
from attopt.experiments.filtering import (
    GYRO_STREAM,
    INITIAL_ATTITUDE_SIGMA_DEG,
    VECTOR_FILTERS,
    GyroTruth,
    bound_columns,
    child_rng,
    filter_columns,
    gyro_truth,
    in_orbit_frame,
    run_filters,
    simulate_filter_inputs,
)
from attopt.experiments.metrics import error_columns
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
from attopt.formulations.wahba_covariance import quest_covariance
from attopt.solvers.wahba import ESTIMATORS

INTERVALS = ("before_eclipse", "eclipse", "after_eclipse")
SOLVERS = {solver.name: solver for solver in ESTIMATORS}
"""The Wahba solvers by registry name."""


PARAMETERS: dict[str, Any] = {
    "duration_s": 6000.0,
    "step_s": 1.0,
    "mag_sigma": MAG_SIGMA,
    "sun_sigma": SUN_SIGMA,
    "methods": list(SOLVERS),
    "filters": ["mekf", "usque", "rts", "fg_batch"],
    "gyro": "mems",
    "initial_sigma_deg": INITIAL_ATTITUDE_SIGMA_DEG,
}


def grid(parameters: Mapping[str, Any]) -> list[Setting]:
    """One setting: the seed's sensor noise; methods are compared inside each trial.

    Raises:
        ValueError: for an unknown method, filter or gyro model, a name used
            twice across ``methods`` and ``filters``, or a non-positive
            ``initial_sigma_deg``.
    """
    unknown = sorted(set(parameters["methods"]) - set(SOLVERS))
    if unknown:
        raise ValueError(f"unknown methods {unknown}; registered: {sorted(SOLVERS)}")
    filters = list(parameters.get("filters", []))
    unknown = sorted(set(filters) - set(VECTOR_FILTERS))
    if unknown:
        raise ValueError(f"unknown filters {unknown}; known: {list(VECTOR_FILTERS)}")
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


def trial(setting: Setting, seed: np.random.SeedSequence) -> pd.DataFrame:
    """One noisy pass solved by every method in ``setting["methods"]``."""
    geometry = build_geometry(setting["duration_s"], setting["step_s"])
    sun_body, mag_body = simulate_measurements(
        geometry,
        np.random.default_rng(seed),
        mag_sigma=setting["mag_sigma"],
        sun_sigma=setting["sun_sigma"],
    )
    n = geometry.t.size
    body = np.stack([sun_body, mag_body], axis=1)
    reference = np.stack([geometry.sun_orbit, geometry.mag_orbit], axis=1)
    weights = np.tile([setting["sun_sigma"] ** -2, setting["mag_sigma"] ** -2], (n, 1))
    present = np.stack([~geometry.in_eclipse, np.ones(n, dtype=bool)], axis=1)

    true_body = np.stack(
        [geometry.truth.apply(geometry.sun_orbit), geometry.truth.apply(geometry.mag_orbit)], axis=1
    )
    with np.errstate(divide="ignore", invalid="ignore"):
        crb = _safe_inverse_diag(true_body, np.where(present, weights, 0.0))
    common = {
        "t": geometry.t,
        "interval": interval_labels(geometry),
        "bound_x_deg": np.degrees(np.sqrt(crb[:, 0])),
        "bound_y_deg": np.degrees(np.sqrt(crb[:, 1])),
        "bound_z_deg": np.degrees(np.sqrt(crb[:, 2])),
    }
    frames = [
        _method_rows(name, body, reference, weights, present, geometry, common)
        for name in setting["methods"]
    ]
    if setting.get("filters"):
        frames += _filter_rows(setting, seed, geometry, sun_body, mag_body, common)
    return pd.concat(frames, ignore_index=True)


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
    geometry: VectorGeometry,
    sun_body: np.ndarray,
    mag_body: np.ndarray,
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
    sigma = [setting["sun_sigma"], setting["mag_sigma"]]
    measurements = [
        VectorMeasurement(
            np.stack([sun_body[k], mag_body[k]]),
            np.stack([geometry.sun_orbit[k], geometry.mag_orbit[k]]),
            sigma,
        )
        for k in range(geometry.t.size)
    ]
    frames = []
    runs = run_filters(setting["filters"], inputs, truth, measurements)
    bound = bound_columns(runs, inputs, truth, measurements)
    for name, (result, seconds) in runs.items():
        solution = in_orbit_frame(result, truth.epoch_frames)
        frames.append(
            pd.DataFrame(
                {
                    "method": name,
                    **common,
                    **error_columns(solution, geometry.truth),
                    "valid": solution.valid,
                    "reason": solution.reason.astype(str),
                    **filter_columns(result, inputs, truth),
                    **bound,
                    "runtime_s": seconds,
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
    name: str,
    body: np.ndarray,
    reference: np.ndarray,
    weights: np.ndarray,
    present: np.ndarray,
    geometry: VectorGeometry,
    common: Mapping[str, np.ndarray],
) -> pd.DataFrame:
    solution = SOLVERS[name].solve_batch(body, reference, weights, present)
    return pd.DataFrame(
        {
            "method": name,
            **common,
            **error_columns(solution, geometry.truth),
            "valid": solution.valid,
            "reason": solution.reason.astype(str),
        }
    )


EXPERIMENT = Experiment(
    name="wahba-mag-sun",
    summary=(
        "Cilden Guler et al. 2017: six Wahba solvers on TIMED with magnetometer + Sun sensor, "
        "vs the CRB"
    ),
    parameters=PARAMETERS,
    grid=grid,
    trial=trial,
    default_trials=20,
    quick_trials=2,
    quick_parameters={"duration_s": 3000.0},
    group_by=("method", "interval"),
    report=report,
)
