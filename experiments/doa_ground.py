"""Experiment ``doa-ground``: attitude from MUSIC DOAs of ground stations (seed 003 sec. 6).

Settings are seed 003's Tables 1 and 2: input SNR -14..14 dB at ``L = 100``
snapshots and ``L = 1..1000`` at 0 dB (the shared setting 0 dB, ``L = 100``
once).  One trial is one pass of :mod:`experiments.scenarios.doa_ground`:

1. snapshots (eqs. 8-10) of every visible station at every epoch, drawn from
   ``numpy.random.default_rng(seed)``, and MUSIC DOAs with refinement
   (:class:`~solvers.doa.music.MusicEstimator`, eq. 11), all sets of a trial
   batched (in chunks of at most :data:`CHUNK_ELEMENTS` complex samples, so
   ``L = 1000`` fits in memory).  MUSIC is given the input SNR for its
   covariance (the link budget's value; it also makes ``L = 1`` usable).
   Rejected estimates (ambiguous peak, horizon) give no measurement.
2. ``ekf_seed003``: the EKF of seed 003 (:mod:`solvers.doa.ekf`) over all
   epochs from the paper's initial condition (50 deg Euler angles, 0.5 deg/s
   rates; :mod:`experiments.scenarios.doa_ground` explains that reading) with
   prior sigmas ``initial_sigma_deg`` and ``initial_rate_sigma_deg_s`` and
   ``Q = process_noise E_6`` per step (default the seed's 1e-9).  Its
   measurement is the seed's unit-vector form (eqs. 18, 30): a
   :class:`~formulations.attitude_measurement.VectorMeasurement` per epoch of
   the accepted ``S_dr`` (eq. 12) against ``S_o`` (eq. 17, far field), with
   ``R_W = sigma^2 E``, ``sigma^2 = tr(J Sigma J^T) / 2`` from MUSIC's
   covariance ``Sigma`` (:func:`unit_vector_observations`; why not the angle
   form: :mod:`solvers.doa.ekf`).
3. ``wahba``: the single-epoch SVD solution of Wahba's problem
   (:data:`solvers.wahba.WAHBA_SOLVERS`) wherever at least two accepted DOAs
   exist, on the same unit vectors with weights ``1 / sigma^2``.

Rows.  Attitude rows every ``row_step_s`` (not every epoch: a 5000 s pass has
20 000 epochs) per method with :func:`experiments.metrics.error_columns`, the
``phase`` (``converging`` before ``settle_s``, then ``settled``: seed 003's
RMSEs of about 0.1 deg can only be post-convergence values, its Fig. 6 shows
convergence within 1500 s), the rate error of the EKF (``rate_err_{x,y,z}_deg_s``)
and, for the single-epoch rows, the single-epoch Cramer-Rao bound
``bound_{x,y,z}_deg`` from the DOA CRBs of the visible stations (NaN with
fewer than two).  One ``music`` row per trial carries the DOA statistics over
all estimates: counts, acceptance and mean squared errors of ``theta`` and
``phi`` and of their CRBs at the true DOAs (``doa_*`` columns, deg^2).

4. ``filters`` (default ``mekf`` and ``fg_batch``): the gyro-aided MEKF and
   the GTSAM whole-pass smoother (:func:`experiments.filtering.run_filters`)
   on the same unit vectors plus a MEMS-class gyro sampled at the epochs
   (``GYRO``; seed 003 has none: its EKF propagates the dynamics), started
   from a prior drawn with ``gyro_initial_sigma_deg`` per axis around the
   truth (child stream :data:`experiments.filtering.GYRO_STREAM` of the
   trial's seed; not the EKF's 98 deg start, which the vector measurements'
   linearisation does not survive in a gyro-driven filter).  Their rows
   carry ``pbound_{x,y,z}_deg``, the posterior Cramer-Rao bound of the pass
   (:func:`experiments.filtering.posterior_bound`), and ``runtime_s``.

Not implemented: the attitude bound of the seed's EKF itself, and DOA
factors in angle form (the smoother uses the unit vectors, like the EKF).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from typing import Any

import numpy as np
import pandas as pd
from scipy.spatial.transform import Rotation

from experiments.doa_report import report
from experiments.experiment import Experiment, Setting
from experiments.filtering import (
    GYRO_STREAM,
    INITIAL_ATTITUDE_SIGMA_DEG,
    VECTOR_FILTERS,
    GyroTruth,
    bound_columns,
    child_rng,
    in_orbit_frame,
    run_filters,
    simulate_filter_inputs,
)
from experiments.metrics import error_columns
from experiments.scenarios.doa_ground import (
    DURATION_S,
    FILTER_INITIAL_EULER_DEG,
    FILTER_INITIAL_RATE_DEG_S,
    STEP_S,
    WHEEL_MOMENTUM,
    DoaGroundGeometry,
    build_geometry,
)
from formulations.attitude_measurement import VectorMeasurement
from formulations.conventions import attitude_from_euler321
from formulations.doa_array import (
    SEED003_UCA,
    doa_unit_vector,
    simulate_snapshots,
    unit_vector_covariance,
)
from formulations.doa_crb import stochastic_crb
from formulations.doa_measurement import DoaMeasurement
from formulations.gyro import MEMS_GYRO
from solvers.doa.ekf import PROCESS_NOISE, EkfPrior, EkfResult, run_ekf
from solvers.doa.music import DoaEstimates, MusicEstimator
from solvers.result import BatchSolution
from solvers.wahba import WAHBA_SOLVERS

TABLE1_SNR_DB = (-14.0, -12.0, -10.0, -8.0, -6.0, -2.0, 0.0, 14.0)
TABLE2_SNAPSHOTS = (1, 10, 20, 50, 100, 1000)
WAHBA_SOLVER = "svd"
CHUNK_ELEMENTS = 1 << 22
"""Complex snapshot samples simulated and estimated at once (64 MB)."""
RAD2_TO_DEG2 = np.degrees(1.0) ** 2
DOA_ROW_REASON = "DOA statistics row (no attitude)"
"""``reason`` of the per-trial ``music`` row, which the attitude summaries count as invalid."""

PARAMETERS: dict[str, Any] = {
    "duration_s": DURATION_S,
    "step_s": STEP_S,
    "table1_snr_db": list(TABLE1_SNR_DB),
    "table1_snapshots": 100,
    "table2_snapshots": list(TABLE2_SNAPSHOTS),
    "table2_snr_db": 0.0,
    "settle_s": 1500.0,
    "row_step_s": 10.0,
    "initial_sigma_deg": 60.0,
    "initial_rate_sigma_deg_s": 0.5,
    "process_noise": PROCESS_NOISE,
    "filters": ["mekf", "fg_batch"],
    "gyro_initial_sigma_deg": INITIAL_ATTITUDE_SIGMA_DEG,
}
GYRO = MEMS_GYRO
"""The gyro of the gyro-aided rows, sampled at the epochs (``rate_hz = 1 / step_s``)."""


def grid(parameters: Mapping[str, Any]) -> list[Setting]:
    """One setting per distinct ``(snr_db, snapshots)`` of Tables 1 and 2."""
    pairs = [(float(s), int(parameters["table1_snapshots"])) for s in parameters["table1_snr_db"]]
    pairs += [(float(parameters["table2_snr_db"]), int(n)) for n in parameters["table2_snapshots"]]
    unknown = sorted(set(parameters["filters"]) - set(VECTOR_FILTERS))
    if unknown:
        raise ValueError(f"unknown filters {unknown}; known: {list(VECTOR_FILTERS)}")
    if any(n < 1 for _, n in pairs):
        raise ValueError("numbers of snapshots must be >= 1")
    if parameters["row_step_s"] < parameters["step_s"]:
        raise ValueError("row_step_s must be at least step_s")
    common = {k: v for k, v in parameters.items() if not k.startswith(("table1_", "table2_"))}
    return [{**common, "snr_db": s, "snapshots": n} for s, n in dict.fromkeys(pairs)]


def estimate_doas(
    geometry: DoaGroundGeometry, snr_db: float, snapshots: int, rng: np.random.Generator
) -> tuple[tuple[np.ndarray, np.ndarray], DoaEstimates]:
    """MUSIC estimates of every visible ``(epoch, station)`` pair, in epoch-major order."""
    epochs, stations = np.nonzero(geometry.visible)
    truth = geometry.doa[epochs, stations]
    per_chunk = max(1, CHUNK_ELEMENTS // (SEED003_UCA.n_elements * snapshots))
    estimator = MusicEstimator()
    parts = []
    for start in range(0, epochs.size, per_chunk):
        chunk = truth[start : start + per_chunk]
        x = simulate_snapshots(chunk[:, 0], chunk[:, 1], snr_db, snapshots, rng)
        parts.append(estimator.estimate(x, snr_db=snr_db))
    return (epochs, stations), _concatenate(parts)


def _concatenate(parts: list[DoaEstimates]) -> DoaEstimates:
    return DoaEstimates(
        theta=np.concatenate([p.theta for p in parts]),
        phi=np.concatenate([p.phi for p in parts]),
        covariance=np.concatenate([p.covariance for p in parts]),
        valid=np.concatenate([p.valid for p in parts]),
        reason=np.concatenate([p.reason for p in parts]),
        error=np.concatenate([p.error for p in parts]),
        diagnostics={
            k: np.concatenate([p.diagnostics[k] for p in parts]) for k in parts[0].diagnostics
        },
    )


def trial(setting: Setting, seed: np.random.SeedSequence) -> pd.DataFrame:
    """One pass at ``setting``'s SNR and ``L``: MUSIC, the EKF and Wahba (module docstring)."""
    geometry = build_geometry(setting["duration_s"], setting["step_s"])
    (epochs, stations), doas = estimate_doas(
        geometry, setting["snr_db"], setting["snapshots"], np.random.default_rng(seed)
    )
    vectors = unit_vector_observations(geometry, epochs, stations, doas)
    row_epochs = np.arange(0, geometry.t.size, round(setting["row_step_s"] / setting["step_s"]))
    common = {
        "t": geometry.t[row_epochs],
        "phase": np.where(geometry.t[row_epochs] < setting["settle_s"], "converging", "settled"),
    }
    ekf = run_ekf(
        _prior(setting),
        [VectorMeasurement(*(v[k] for v in vectors)) for k in range(geometry.t.size)],
        geometry.orbit_turns(),
        WHEEL_MOMENTUM,
        setting["step_s"],
        process_noise=setting["process_noise"],
    )
    frames = [
        _ekf_rows(ekf, geometry, row_epochs, common),
        _wahba_rows(geometry, vectors, row_epochs, common, setting),
        *_gyro_rows(setting, seed, geometry, vectors, row_epochs, common),
        pd.DataFrame([_doa_row(geometry, epochs, stations, doas, setting)]),
    ]
    return pd.concat(frames, ignore_index=True)


def _gyro_rows(
    setting: Setting,
    seed: np.random.SeedSequence,
    geometry: DoaGroundGeometry,
    vectors: tuple[np.ndarray, np.ndarray, np.ndarray],
    rows: np.ndarray,
    common: Mapping[str, Any],
) -> list[pd.DataFrame]:
    """Rows of the gyro-aided filters and smoothers (module docstring, 4)."""
    if not setting["filters"]:
        return []
    model = replace(GYRO, rate_hz=1.0 / setting["step_s"])
    truth = GyroTruth(
        t=geometry.t,
        attitude=geometry.truth * geometry.eci_to_orbit,
        epoch_frames=geometry.eci_to_orbit,
        epoch_samples=np.arange(geometry.t.size),
    )
    inputs = simulate_filter_inputs(
        truth, model, child_rng(seed, GYRO_STREAM), setting["gyro_initial_sigma_deg"]
    )
    accepted = np.isfinite(vectors[0]).all(axis=-1).any(axis=-1)
    measurements = [
        VectorMeasurement(*(v[k] for v in vectors)) if accepted[k] else None
        for k in range(geometry.t.size)
    ]
    runs = run_filters(setting["filters"], inputs, truth, measurements)
    bound = {k: v[rows] for k, v in bound_columns(runs, inputs, truth, measurements).items()}
    frames = []
    for method, (result, seconds) in runs.items():
        solution = in_orbit_frame(result.solution, truth.epoch_frames)
        errors = error_columns(solution, geometry.truth)
        frames.append(
            pd.DataFrame(
                {
                    "method": method,
                    **common,
                    **{name: column[rows] for name, column in errors.items()},
                    **bound,
                    "valid": solution.valid[rows],
                    "reason": solution.reason[rows].astype(str),
                    "runtime_s": seconds,
                }
            )
        )
    return frames


def unit_vector_observations(
    geometry: DoaGroundGeometry, epochs: np.ndarray, stations: np.ndarray, doas: DoaEstimates
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Body vectors ``S_dr`` (eq. 12), reference vectors ``S_o`` (eq. 17), sigmas; ``(N, S, .)``.

    ``sigma^2 = tr(R_W) / 2`` with ``R_W`` the unit-vector covariance of
    MUSIC's ``(theta, phi)`` covariance (isotropic form of eq. 22).  Body
    vectors are NaN (and sigmas 1) where a station is not visible or MUSIC
    rejected it; measurements leave those out.
    """
    n, count = geometry.visible.shape
    body = np.full((n, count, 3), np.nan)
    sigma = np.ones((n, count))
    body[epochs, stations] = doa_unit_vector(doas.theta, doas.phi)
    unit_covariance = unit_vector_covariance(doas.theta, doas.phi, doas.covariance)
    variance = 0.5 * np.trace(unit_covariance, axis1=-2, axis2=-1)
    sigma[epochs, stations] = np.sqrt(np.nan_to_num(variance, nan=1.0))
    reference = geometry.line_of_sight_km / np.linalg.norm(
        geometry.line_of_sight_km, axis=-1, keepdims=True
    )
    return body, reference, sigma


def _prior(setting: Setting) -> EkfPrior:
    """Seed 003 sec. 6's initial estimate with the experiment's prior sigmas."""
    sigma = np.radians(
        [setting["initial_rate_sigma_deg_s"]] * 3 + [setting["initial_sigma_deg"]] * 3
    )
    return EkfPrior(
        attitude=attitude_from_euler321(*np.radians(FILTER_INITIAL_EULER_DEG)),
        rate=np.radians(FILTER_INITIAL_RATE_DEG_S),
        covariance=np.diag(sigma**2),
    )


def _solution(method: str, attitude: Rotation, covariance: np.ndarray) -> BatchSolution:
    n = len(attitude)
    return BatchSolution(
        method=method,
        quaternion=attitude.as_quat(),
        covariance=covariance,
        loss=np.full(n, np.nan),
        valid=np.ones(n, dtype=bool),
        reason=np.full(n, "", dtype=object),
        error=np.full(n, None, dtype=object),
        diagnostics={},
    )


def _ekf_rows(
    ekf: EkfResult, geometry: DoaGroundGeometry, rows: np.ndarray, common: Mapping[str, Any]
) -> pd.DataFrame:
    solution = _solution("ekf_seed003", ekf.attitude[rows], ekf.covariance[rows, 3:, 3:])
    rate_error = np.degrees(ekf.rate[rows] - geometry.rate[rows])
    return pd.DataFrame(
        {
            "method": "ekf_seed003",
            **common,
            **error_columns(solution, geometry.truth[rows]),
            **{f"rate_err_{a}_deg_s": rate_error[:, i] for i, a in enumerate("xyz")},
            "valid": True,
            "reason": "",
        }
    )


def _wahba_rows(
    geometry: DoaGroundGeometry,
    vectors: tuple[np.ndarray, np.ndarray, np.ndarray],
    rows: np.ndarray,
    common: Mapping[str, Any],
    setting: Setting,
) -> pd.DataFrame:
    """Single-epoch SVD solutions at the row epochs, with the single-epoch CRB."""
    body, reference, sigma = (v[rows] for v in vectors)
    present = np.isfinite(body).all(axis=-1)
    solution = WAHBA_SOLVERS[WAHBA_SOLVER].solve_batch(
        np.where(present[..., None], body, reference), reference, sigma**-2.0, present
    )
    bound = np.array([_single_epoch_bound(geometry, k, setting) for k in rows])
    return pd.DataFrame(
        {
            "method": "wahba",
            **common,
            **error_columns(solution, geometry.truth[rows]),
            **{f"bound_{a}_deg": bound[:, i] for i, a in enumerate("xyz")},
            "valid": solution.valid,
            "reason": solution.reason.astype(str),
        }
    )


def _single_epoch_bound(geometry: DoaGroundGeometry, k: int, setting: Setting) -> np.ndarray:
    """Standard deviations (deg) of the CRB of ``C_bo`` from epoch ``k``'s stations alone."""
    visible = geometry.visible[k]
    if visible.sum() < 2:
        return np.full(3, np.nan)
    doa = geometry.doa[k, visible]
    crb = stochastic_crb(
        doa[:, 0], doa[:, 1], 10.0 ** (setting["snr_db"] / 10.0), setting["snapshots"]
    )
    measurement = DoaMeasurement(doa, crb, geometry.line_of_sight_km[k, visible])
    _, jacobian = measurement.predict(geometry.truth[k])
    information = jacobian[0].T @ np.linalg.solve(measurement.noise_covariance, jacobian[0])
    return np.degrees(np.sqrt(np.diag(np.linalg.inv(information))))


def _doa_row(
    geometry: DoaGroundGeometry,
    epochs: np.ndarray,
    stations: np.ndarray,
    doas: DoaEstimates,
    setting: Setting,
) -> dict[str, Any]:
    """Counts and mean squared DOA errors (deg^2) of the trial, and of the CRB at the truth."""
    truth = geometry.doa[epochs, stations]
    crb = stochastic_crb(
        truth[:, 0], truth[:, 1], 10.0 ** (setting["snr_db"] / 10.0), setting["snapshots"]
    )
    valid = doas.valid
    theta_error = np.degrees(doas.theta[valid] - truth[valid, 0])
    phi_error = np.degrees((doas.phi[valid] - truth[valid, 1] + np.pi) % (2.0 * np.pi) - np.pi)
    return {
        "method": "music",
        "phase": "all",
        "valid": False,
        "reason": DOA_ROW_REASON,
        "doa_count": int(valid.size),
        "doa_accepted": int(valid.sum()),
        "doa_theta_mse_deg2": float(np.mean(theta_error**2)) if valid.any() else np.nan,
        "doa_phi_mse_deg2": float(np.mean(phi_error**2)) if valid.any() else np.nan,
        "doa_crb_theta_deg2": float(np.mean(crb[:, 0, 0]) * RAD2_TO_DEG2),
        "doa_crb_phi_deg2": float(np.mean(crb[:, 1, 1]) * RAD2_TO_DEG2),
    }


EXPERIMENT = Experiment(
    name="doa-ground",
    summary=(
        "Seed 003: attitude from MUSIC DOAs of ground stations, EKF, Wahba, gyro-aided MEKF "
        "and GTSAM smoother, Tables 1-2"
    ),
    parameters=PARAMETERS,
    grid=grid,
    trial=trial,
    default_trials=200,
    quick_trials=2,
    quick_parameters={
        "duration_s": 1500.0,
        "table1_snr_db": [-10.0, 0.0],
        "table2_snapshots": [10],
        "settle_s": 1000.0,
    },
    group_by=("method", "phase"),
    report=report,
)
