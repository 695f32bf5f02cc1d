"""Experiment ``doa-ground``: attitude from MUSIC DOAs of ground stations (Yang et al. 2014
sec. 6).

Settings are Yang et al. 2014's Tables 1 and 2: input SNR -14..14 dB at ``L = 100``
snapshots and ``L = 1..1000`` at 0 dB (the shared setting 0 dB, ``L = 100``
once).  One trial is one pass of :mod:`attopt.experiments.doa_ground.scenario`
(geometry and truth are the same in every trial, as in the paper; only the
noise is drawn).  Every physical choice is a parameter
(:class:`DoaGroundParameters`: the scenario's orbit, stations and rigid body, the
``[array]``, ``[music]``, the ``gyro``, the ``[prior]``), and every estimator sees
the same DOAs (each row label names a registry estimator with its options,
:mod:`attopt.experiments.doa_ground.methods`; the pass estimators run by
:func:`attopt.solvers.pipeline.run_estimators`):

1. MUSIC (:class:`~attopt.solvers.doa.music.MusicEstimator`, eq. 11, with the
   ``[music]`` grid and thresholds) on the ``[array]`` for every
   visible ``(epoch, station)`` pair, from a sample covariance drawn from
   ``numpy.random.default_rng(seed)`` with the exact distribution of eqs.
   8-10's ``X X^H / L`` (:func:`estimate_doas`).  MUSIC is given the input SNR
   for its covariance (the link budget's value; it also makes ``L = 1``
   usable).  Rejected estimates (ambiguous peak, source at the horizon) give
   no measurement: that epoch has one station fewer, and with none the
   filters propagate.  Unit vectors ``S_dr`` (eq. 12) against ``S_o`` (eq.
   17, far field) with ``R_W = sigma^2 E``, ``sigma^2 = tr(J Sigma J^T) / 2``
   from MUSIC's covariance ``Sigma`` (:func:`unit_vector_observations`).
2. ``ekf_yang2014_q<Q>``: the EKF of Yang et al. 2014 (:mod:`attopt.solvers.doa.ekf`,
   rigid-body dynamics of the ``[attitude]`` table, no gyro) over all epochs from the
   ``[prior]``'s initial estimate (default the paper's initial condition, 50 deg Euler
   angles, 0.5 deg/s rates; :mod:`attopt.experiments.doa_ground.scenario` explains that
   reading) with its sigmas ``sigma_deg`` and ``rate_sigma_deg_s``, once per
   ``Q = q E_6`` in ``process_noise``: the paper's printed 1e-9 and
   :data:`LOW_PROCESS_NOISE` (1e-12), with which our EKF reproduces the paper's
   attitude RMSEs (docs/doa.md).
3. ``rts_yang2014_q<Q>``: the Rauch-Tung-Striebel smoother over that EKF (same
   model, same data; :func:`attopt.solvers.filters.rts.rts_smooth`).  The EKF
   and RTS rows carry ``pbound_{x,y,z}_deg``, the posterior Cramer-Rao bound of that model
   (filter and smoother) linearised along the truth, with the DOA CRB at the
   true DOAs of every visible station, and ``crb_{x,y,z}_deg``, the same with
   ``Q = 0``: the bound of the paper's problem itself, whose torque-free
   dynamics the filter knows exactly (the truth has no process noise, so
   errors below ``pbound`` are possible).  Both are the same for every trial
   of a setting and computed once per worker.
4. ``wahba``: the single-epoch SVD solution of Wahba's problem
   (registry ``svd``) wherever at least two accepted DOAs
   exist (about 5 % of the pass), with the single-epoch CRB ``bound_*``.
5. ``bls_yang2014`` (:func:`~attopt.experiments.doa_ground.methods.batch_ls_estimator`),
   in the first ``filter_trials`` trials of each setting
   (:func:`attopt.experiments.sweep.seeding.trial_index`): the whole-pass batch
   least squares over the paper's deterministic dynamics
   (:mod:`attopt.solvers.doa.batch_ls`, ``Q = 0``), started from the lowest-``Q``
   RTS pass at epoch 0; its ``pbound_*`` and ``crb_*`` are both the ``Q = 0``
   smoother bound, its time includes the EKF and RTS passes it starts from.
6. ``filters`` (registry pass estimators that accept unit vectors; default
   ``mekf`` and ``fg_batch``), in the first ``filter_trials`` trials of each
   setting only (they cost about 25x the rest): the gyro-aided MEKF and the
   GTSAM whole-pass smoother on the same unit vectors plus the ``gyro`` (default
   the MEMS-class preset; Yang et al. 2014 has none) sampled at the epochs, from the
   EKF's initial estimate and sigma (the same prior information as the EKF).
   The estimators that can start from an RTS pass (the smoothers) start their
   iterations from the lowest-``Q`` RTS pass (their result does not depend on
   the start once they converge; their time includes that pass).  With a
   factor-graph smoother among them, their rows carry the posterior bound of
   the pass with the gyro
   (:func:`attopt.experiments.metrics.posterior_bound_columns`).

Rows.  Attitude rows every ``row_step_s`` (a 5000 s pass has 20 000 epochs)
per method at ``t_s`` with :func:`attopt.experiments.metrics.error_columns`, the
estimated and true ``C_bo`` (``q_est_*``, ``q_true_*``:
:func:`attopt.experiments.metrics.attitude_columns`), the ``phase``
(``converging`` before ``settle_s``, then ``settled``: Yang et al. 2014's RMSEs of
about 0.1 deg can only be post-convergence values, its Fig. 6 shows
convergence within 1500 s), rate errors (``rate_err_{x,y,z}_deg_s``) of the
EKF and RTS rows, and ``runtime_s`` (wall time of the pass).  One ``music``
row per trial carries the DOA statistics over all estimates: counts,
acceptance, rejections by reason, and mean squared errors of ``theta`` and
``phi`` and of their CRBs at the true DOAs (``doa_*`` columns, deg^2), and the same
per configured station ``k`` (1-based, ``doa_count_station<k>``,
``doa_accepted_station<k>``, ``doa_theta_mse_station<k>_deg2``, ...).

Export.  :func:`simulate_pass` and :func:`gyro_inputs` are what a trial simulates
before its estimators run; :mod:`attopt.experiments.doa_ground.export` writes them as
a recorded pass (``attopt export doa-ground``).
"""

from __future__ import annotations

import functools
import math
import time
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Annotated, Any

import numpy as np
import pandas as pd
from pydantic import Field, ValidationInfo, field_validator

from attopt.experiments.config.components import Gyro, GyroNumbers, gyro_model
from attopt.experiments.doa_ground.methods import (
    BATCH_LS,
    GYRO_FILTERS,
    WAHBA,
    batch_ls_estimator,
    dynamics_estimators,
    filter_labels,
    rts_method,
)
from attopt.experiments.doa_ground.parameters import (
    DoaArray,
    DoaScenario,
    FilterPrior,
    MusicGrid,
)
from attopt.experiments.doa_ground.report import report
from attopt.experiments.doa_ground.scenario import DoaGroundGeometry, build_geometry
from attopt.experiments.estimators import (
    FACTOR_GRAPH,
    EstimatorOptions,
    Options,
    configured,
    configured_all,
    label_field,
    resolve,
)
from attopt.experiments.experiment import Experiment, Setting
from attopt.experiments.metrics import (
    attitude_columns,
    error_columns,
    in_orbit_frame,
    posterior_bound_columns,
    status_columns,
)
from attopt.experiments.simulation import (
    GYRO_STREAM,
    FilterInputs,
    GyroTruth,
    child_rng,
    simulate_filter_inputs,
)
from attopt.experiments.sweep.seeding import trial_index
from attopt.formulations.conventions import attitude_from_euler321
from attopt.formulations.doa_array import (
    UniformCircularArray,
    doa_unit_vector,
    simulate_sample_covariance,
    unit_vector_covariance,
)
from attopt.formulations.doa_crb import stochastic_crb
from attopt.formulations.doa_measurement import DoaMeasurement
from attopt.formulations.errors import ConvergenceError, ModelMismatchError, UnobservableError
from attopt.formulations.gyro import GyroModel
from attopt.formulations.passes import Pass, Prior
from attopt.solvers.bounds import posterior_bound_ekf
from attopt.solvers.doa.ekf import PROCESS_NOISE
from attopt.solvers.doa.music import DoaEstimates, MusicEstimator
from attopt.solvers.pipeline import Run, run_estimators
from attopt.solvers.registry import estimator
from attopt.solvers.results import Track
from attopt.solvers.sequential import stored_rotations
from attopt.solvers.smoother import single_frame_initial
from attopt.solvers.start_hypotheses import unchecked

TABLE1_SNR_DB = (-14.0, -12.0, -10.0, -8.0, -6.0, -2.0, 0.0, 14.0)
TABLE2_SNAPSHOTS = (1, 10, 20, 50, 100, 1000)
RAD2_TO_DEG2 = np.degrees(1.0) ** 2
DOA_ROW_REASON = "DOA statistics row (no attitude)"
"""``reason`` of the per-trial ``music`` row, which the attitude summaries count as invalid."""
SETTING_KEYS = ("snr_db", "snapshots")
"""The keys :func:`grid` adds to the parameters to make a setting."""

REJECTIONS = {"ambiguous": "ambiguous peak", "horizon": "source at the array horizon"}
"""Counted MUSIC rejections (``doa_rejected_<name>``) by the start of their reason."""
LOW_PROCESS_NOISE = 1.0e-12
"""The ``Q`` per step with which our EKF reproduces Yang et al. 2014's attitude RMSEs
(docs/doa.md)."""
FILTER_TRIALS = 4
"""Trials per setting that also run the batch least squares and the gyro-aided rows (about
25x the cost of the rest)."""

Snapshots = Annotated[int, Field(ge=1)]
ProcessNoise = Annotated[float, Field(gt=0.0)]


class DoaGroundParameters(DoaScenario):
    """Parameters of ``doa-ground`` (Yang et al. 2014 secs. 4-6): the scenario's
    (:class:`~attopt.experiments.doa_ground.parameters.DoaScenario`), the array, MUSIC, the
    gyro of the gyro-aided rows, the filters' prior, Tables 1 and 2 and the rows."""

    array: DoaArray = Field(
        default_factory=DoaArray, description="The DOA array (Yang et al. 2014 sec. 4.1)."
    )
    music: MusicGrid = Field(default_factory=MusicGrid, description="MUSIC's grid and thresholds.")
    gyro: Gyro = Field(
        "mems",
        description="Gyro of the gyro-aided rows, sampled at the epochs (rate 1 / step_s).",
    )
    prior: FilterPrior = Field(
        default_factory=FilterPrior, description="The filters' initial estimate (sec. 6)."
    )
    table1_snr_db: list[float] = Field(
        default_factory=lambda: list(TABLE1_SNR_DB),
        description="Input SNRs of Table 1 (at table1_snapshots).",
    )
    table1_snapshots: int = Field(100, ge=1, description="Snapshots L of Table 1.")
    table2_snapshots: list[Snapshots] = Field(
        default_factory=lambda: list(TABLE2_SNAPSHOTS),
        description="Snapshot counts L of Table 2 (at table2_snr_db).",
    )
    table2_snr_db: float = Field(0.0, description="Input SNR of Table 2.")
    settle_s: float = Field(1500.0, ge=0, description="Time after which rows count as settled.")
    row_step_s: float = Field(10.0, gt=0, description="Time between stored rows (>= step_s).")
    process_noise: list[ProcessNoise] = Field(
        default_factory=lambda: [PROCESS_NOISE, LOW_PROCESS_NOISE],
        min_length=1,
        description="Diagonals of the EKF's Q per step (one EKF/RTS row per value).",
    )
    filters: list[label_field(filter_labels, "filters")] = Field(
        default_factory=lambda: list(GYRO_FILTERS),
        description="Gyro-aided filters and smoothers (registry names).",
    )
    filter_trials: int = Field(
        FILTER_TRIALS, ge=0, description="Trials per setting that also run the costly rows."
    )
    estimator_options: EstimatorOptions

    @field_validator("music")
    @classmethod
    def _grid_resolves_the_main_lobe(cls, value: MusicGrid, info: ValidationInfo) -> MusicGrid:
        array = info.data.get("array")
        if array is not None and value.grid_step >= array.array().first_null_radius:
            raise ValueError(
                f"grid_step must be below the array's first-null radius "
                f"{array.array().first_null_radius:.4g} (2.405 / (k r))"
            )
        return value

    @field_validator("gyro", mode="before")
    @classmethod
    def _rate_of_the_epochs(cls, value: Any, info: ValidationInfo) -> Any:
        step = info.data.get("step_s")
        if isinstance(value, dict) and "rate_hz" not in value and step:
            return {**value, "rate_hz": 1.0 / step}
        return value

    @field_validator("gyro")
    @classmethod
    def _sampled_at_the_epochs(cls, value: Any, info: ValidationInfo) -> Any:
        step = info.data.get("step_s")
        if isinstance(value, GyroNumbers) and step and not math.isclose(value.rate_hz * step, 1.0):
            raise ValueError(
                f"the gyro is sampled at the epochs: rate_hz must be 1 / step_s = {1.0 / step:g}"
            )
        return value

    @field_validator("row_step_s")
    @classmethod
    def _at_least_a_step(cls, value: float, info: ValidationInfo) -> float:
        step = info.data.get("step_s")
        if step and value < step:
            raise ValueError(f"row_step_s must be at least step_s = {step:g}")
        return value


def grid(parameters: Mapping[str, Any]) -> list[Setting]:
    """One setting per distinct ``(snr_db, snapshots)`` of Tables 1 and 2 (the validated
    parameters without the tables' keys, plus ``snr_db`` and ``snapshots``).

    Raises:
        ValueError: a filter the registry does not have (the message lists the
            registered ones).
    """
    resolve(parameters["filters"], filter_labels(), "filters")
    pairs = [(float(s), int(parameters["table1_snapshots"])) for s in parameters["table1_snr_db"]]
    pairs += [(float(parameters["table2_snr_db"]), int(n)) for n in parameters["table2_snapshots"]]
    common = {k: v for k, v in parameters.items() if not k.startswith(("table1_", "table2_"))}
    return [{**common, "snr_db": s, "snapshots": n} for s, n in dict.fromkeys(pairs)]


def setting_parameters(setting: Setting) -> DoaGroundParameters:
    """The parameters of a setting (validated again: the workers receive plain documents)."""
    return DoaGroundParameters.model_validate(
        {k: v for k, v in setting.items() if k not in SETTING_KEYS}
    )


def estimate_doas(
    geometry: DoaGroundGeometry,
    snr_db: float,
    snapshots: int,
    rng: np.random.Generator,
    array: DoaArray,
    music: MusicGrid,
) -> tuple[tuple[np.ndarray, np.ndarray], DoaEstimates]:
    """MUSIC estimates of every visible ``(epoch, station)`` pair, in epoch-major order.

    Each pair's sample covariance is drawn directly
    (:func:`~attopt.formulations.doa_array.simulate_sample_covariance`: the exact
    distribution of ``X X^H / L`` of eqs. 8-10, at a cost independent of ``L``).
    """
    epochs, stations = np.nonzero(geometry.visible)
    truth = geometry.doa[epochs, stations]
    uca = array.array()
    covariance = simulate_sample_covariance(truth[:, 0], truth[:, 1], snr_db, snapshots, rng, uca)
    estimates = music_estimator(music, uca).estimate_covariance(
        covariance, snapshots, snr_db=snr_db
    )
    return (epochs, stations), estimates


def music_estimator(music: MusicGrid, array: UniformCircularArray) -> MusicEstimator:
    """MUSIC on ``array`` with the ``[music]`` options (one per process and set-up: its grid
    is built once)."""
    return _music(
        array,
        music.grid_step,
        music.cone_half_angle_deg,
        music.peak_ratio_threshold,
        music.horizon_angle_deg,
        music.threshold_output_snr,
        music.threshold_variance_factor,
    )


@functools.lru_cache(maxsize=4)
def _music(
    array: UniformCircularArray,
    grid_step: float,
    cone_half_angle_deg: float,
    peak_ratio_threshold: float,
    horizon_angle_deg: float,
    threshold_output_snr: float,
    threshold_variance_factor: float,
) -> MusicEstimator:
    return MusicEstimator(
        array=array,
        cone_half_angle=float(np.radians(cone_half_angle_deg)),
        grid_step=grid_step,
        peak_ratio_threshold=peak_ratio_threshold,
        horizon_angle=float(np.radians(horizon_angle_deg)),
        threshold_output_snr=threshold_output_snr,
        threshold_variance_factor=threshold_variance_factor,
    )


@dataclass(frozen=True)
class SimulatedPass:
    """What :func:`trial` simulates before its estimators run (module docstring, 1).

    Attributes:
        parameters: the setting's validated parameters.
        geometry: the scenario's true geometry and attitude (cached: do not modify).
        epochs, stations: the visible ``(epoch, station)`` pairs MUSIC estimated,
            epoch-major.
        doas: MUSIC's estimates of those pairs.
        vector_covariance: each ``(epoch, station)``'s unit-vector covariance ``(N, S, 3,
            3)`` (eq. 12; zero where MUSIC gave no DOA).
        below_threshold: ``(N, S)``, whether that DOA is below MUSIC's threshold output
            SNR.
        vectors: body vectors, reference vectors and sigmas, ``(N, S, .)``
            (:func:`unit_vector_observations`).
        pass_: the pass of the unit vectors with the scenario's rigid-body dynamics and
            the ``[prior]``'s orbit-frame estimate with its body rate: what Yang et al.
            2014's EKF, its RTS pass and the batch least squares solve.
    """

    parameters: DoaGroundParameters
    geometry: DoaGroundGeometry
    epochs: np.ndarray
    stations: np.ndarray
    doas: DoaEstimates
    vector_covariance: np.ndarray
    below_threshold: np.ndarray
    vectors: tuple[np.ndarray, np.ndarray, np.ndarray]
    pass_: Pass


def simulate_pass(setting: Setting, seed: np.random.SeedSequence) -> SimulatedPass:
    """The DOAs, unit vectors and dynamics pass of trial ``seed`` of ``setting``: MUSIC's
    noise from ``numpy.random.default_rng(seed)`` (module docstring, 1)."""
    parameters = setting_parameters(setting)
    geometry = build_geometry(parameters)
    (epochs, stations), doas = estimate_doas(
        geometry,
        setting["snr_db"],
        setting["snapshots"],
        np.random.default_rng(seed),
        parameters.array,
        parameters.music,
    )
    covariance, below = _doa_vector_statistics(geometry.visible.shape, epochs, stations, doas)
    vectors = unit_vector_observations(geometry, epochs, stations, doas, covariance)
    doa_pass = _vector_pass(geometry, vectors, _prior(parameters.prior))
    return SimulatedPass(
        parameters, geometry, epochs, stations, doas, covariance, below, vectors, doa_pass
    )


def trial(setting: Setting, seed: np.random.SeedSequence) -> pd.DataFrame:
    """One pass at the setting's SNR and ``L``: every estimator on the same DOAs (docstring)."""
    simulated = simulate_pass(setting, seed)
    parameters, geometry = simulated.parameters, simulated.geometry
    epochs, stations, doas, doa_pass = (
        simulated.epochs,
        simulated.stations,
        simulated.doas,
        simulated.pass_,
    )
    row_epochs = np.arange(0, geometry.t.size, round(parameters.row_step_s / parameters.step_s))
    common = {
        "t_s": geometry.t[row_epochs],
        "phase": np.where(geometry.t[row_epochs] < parameters.settle_s, "converging", "settled"),
    }
    passes = {
        q: _dynamics_passes(setting, parameters, doa_pass, q) for q in parameters.process_noise
    }
    frames = [
        _dynamics_rows(label, run, geometry, row_epochs, common)
        for runs in passes.values()
        for label, run in runs.items()
    ]
    frames += [
        _wahba_rows(label, name, simulated, row_epochs, common, setting)
        for label, name in WAHBA.items()
    ]
    if trial_index(seed) < parameters.filter_trials:
        lowest = passes[min(passes)][rts_method(min(passes))]
        frames.append(
            _batch_ls_rows(
                doa_pass, geometry, row_epochs, common, lowest, parameters.estimator_options
            )
        )
        frames += _gyro_rows(parameters, seed, geometry, doa_pass, row_epochs, common, lowest)
    frames.append(
        pd.DataFrame([_doa_row(geometry, epochs, stations, doas, setting, parameters.array)])
    )
    return pd.concat(frames, ignore_index=True)


def _vector_pass(
    geometry: DoaGroundGeometry,
    vectors: tuple[np.ndarray, np.ndarray, np.ndarray],
    prior: Prior,
) -> Pass:
    """The pass of the unit vectors (NaN body rows: absent) with the scenario's rigid-body
    dynamics (inertia, wheel momentum, orbit frames) and ``prior``."""
    return replace(Pass.from_vectors(geometry.t, *vectors), dynamics=geometry.dynamics, prior=prior)


def _dynamics_passes(
    setting: Setting, parameters: DoaGroundParameters, doa_pass: Pass, process_noise: float
) -> dict[str, DynamicsPass]:
    """The paper's EKF and its RTS pass with ``Q = process_noise E_6``, by row label: each
    run (the RTS's time includes the EKF's), the model's bound and the ``Q = 0`` bound."""
    runs = run_estimators(
        doa_pass, dynamics_estimators(process_noise, parameters.estimator_options)
    )
    keys = (
        parameters.scenario().model_dump_json(),
        parameters.array.array(),
        setting["snr_db"],
        setting["snapshots"],
    )
    prior_sigmas = parameters.prior.sigma_deg, parameters.prior.rate_sigma_deg_s
    bounds = zip(
        *(_model_bound(*keys, q, *prior_sigmas) for q in (process_noise, 0.0)), strict=True
    )
    return {
        label: DynamicsPass(run, bound, crb)
        for (label, run), (bound, crb) in zip(runs.items(), bounds, strict=True)
    }


@dataclass(frozen=True)
class DynamicsPass:
    """An EKF, RTS or batch run with the posterior bound of its model and the bound with
    ``Q = 0`` (the truth's dynamics are deterministic), deg ``(N, 3)`` each."""

    run: Run
    bound: np.ndarray
    crb: np.ndarray


@functools.lru_cache(maxsize=16)
def _model_bound(
    scenario: str,
    array: UniformCircularArray,
    snr_db: float,
    snapshots: int,
    process_noise: float,
    prior_sigma_deg: float,
    prior_rate_sigma_deg_s: float,
) -> tuple[np.ndarray, np.ndarray]:
    """Attitude standard deviations (deg, ``(N, 3)``) of the posterior Cramer-Rao bound of
    the EKF's model (filter, smoother), :func:`attopt.solvers.bounds.posterior_bound_ekf` with
    the DOA CRB of every visible station at the truth: the same for every trial of a
    setting, so cached (``scenario``: the scenario's JSON document).  With
    ``process_noise = 0`` it is the Cramer-Rao bound of Yang et al. 2014's problem itself
    (known, torque-free dynamics)."""
    geometry = build_geometry(DoaScenario.model_validate_json(scenario))
    truth_doa = geometry.doa[geometry.visible]
    crb = stochastic_crb(
        truth_doa[:, 0], truth_doa[:, 1], 10.0 ** (snr_db / 10.0), snapshots, array
    )
    sigma = np.ones(geometry.visible.shape)
    sigma[geometry.visible] = _isotropic_sigma(
        unit_vector_covariance(truth_doa[:, 0], truth_doa[:, 1], crb)
    )
    covariance = np.diag(np.radians([prior_sigma_deg] * 3 + [prior_rate_sigma_deg_s] * 3) ** 2)
    reference = _unit(geometry.line_of_sight_km)
    body = np.einsum("nij,nsj->nsi", geometry.truth.as_matrix(), reference)
    body[~geometry.visible] = np.nan
    prior = Prior(geometry.truth[0], covariance, rate=geometry.rate[0])
    bound_pass = _vector_pass(geometry, (body, reference, sigma), prior)
    bounds = posterior_bound_ekf(bound_pass, geometry.truth, geometry.rate, process_noise)
    return tuple(np.degrees(np.sqrt(np.diagonal(b, axis1=1, axis2=2)[:, 3:])) for b in bounds)


def _batch_ls_rows(
    doa_pass: Pass,
    geometry: DoaGroundGeometry,
    rows: np.ndarray,
    common: Mapping[str, Any],
    start: DynamicsPass,
    options: Options,
) -> pd.DataFrame:
    """Rows of the whole-pass batch least squares (module docstring, 5), started from the
    lowest-``Q`` RTS pass at epoch 0; its bound is the ``Q = 0`` CRB, its time includes the
    start's.  A pass that raises or does not converge gives invalid rows with the reason."""
    began = time.perf_counter()
    try:
        runs = run_estimators(
            doa_pass,
            {BATCH_LS: batch_ls_estimator(options)},
            starts={BATCH_LS: start.run},
        )
    except (UnobservableError, ConvergenceError) as error:
        return pd.DataFrame(
            {
                "method": BATCH_LS,
                **common,
                **attitude_columns(np.full((rows.size, 4), np.nan), geometry.truth[rows]),
                "valid": False,
                "reason": f"{type(error).__name__}: {error}",
                "runtime_s": start.run.seconds + time.perf_counter() - began,
            }
        )
    run = DynamicsPass(runs[BATCH_LS], start.crb, start.crb)
    return _dynamics_rows(BATCH_LS, run, geometry, rows, common, run.run.track.report.reason)


def _dynamics_rows(
    label: str,
    run: DynamicsPass,
    geometry: DoaGroundGeometry,
    rows: np.ndarray,
    common: Mapping[str, Any],
    reason: str = "",
) -> pd.DataFrame:
    """Rows of an EKF, RTS or batch pass: the estimates at the row epochs, rate errors,
    both bounds, wall time.  Rows are valid where the track is and ``reason`` is empty;
    errors are shown also where ``reason`` or the start check
    (:mod:`attopt.solvers.start_hypotheses`: the unchecked run's estimates, so that the
    convergence from the paper's start can be drawn) flags the rows, and nowhere else
    the track flags them (e.g. a filter whose innovations fail its consistency test)."""
    track = run.run.track
    shown = unchecked(track)
    tracked = track.valid[rows]
    estimates = _estimates(label, shown.quaternion[rows], shown.covariance[rows], shown.valid[rows])
    rate_error = np.degrees(shown.rate[rows] - geometry.rate[rows])
    return pd.DataFrame(
        {
            "method": label,
            **common,
            **error_columns(estimates, geometry.truth[rows]),
            **_attitudes(estimates, geometry.truth[rows]),
            **{f"rate_err_{a}_deg_s": rate_error[:, i] for i, a in enumerate("xyz")},
            **{f"pbound_{a}_deg": run.bound[rows, i] for i, a in enumerate("xyz")},
            **{f"crb_{a}_deg": run.crb[rows, i] for i, a in enumerate("xyz")},
            "valid": tracked & (not reason),
            "reason": np.where(tracked, reason, track.reason[rows]),
            "runtime_s": run.run.seconds,
        }
    )


def _attitudes(track: Track, truth: Any) -> dict[str, np.ndarray]:
    """``q_est_*`` (NaN where the track is invalid) and ``q_true_*`` (``C_bo``, orbit frame)."""
    quaternion = np.where(track.valid[:, None], track.quaternion, np.nan)
    return attitude_columns(quaternion, truth)


def epoch_gyro(parameters: DoaGroundParameters) -> GyroModel:
    """The gyro of the gyro-aided rows at the epochs' rate ``1 / step_s`` (a preset's own rate
    replaced; a table's is validated to be that rate)."""
    return replace(gyro_model(parameters.gyro), rate_hz=1.0 / parameters.step_s)


def _gyro_prior(
    parameters: DoaGroundParameters, geometry: DoaGroundGeometry, bias_sigma: float
) -> Prior:
    """The EKF's initial attitude estimate and sigma (Yang et al. 2014 sec. 6) for the
    gyro-aided rows, in the inertial frame, with the gyro's initial bias sigma."""
    ekf = _prior(parameters.prior)
    return Prior(
        attitude=ekf.attitude * geometry.eci_to_orbit[0],
        covariance=np.diag([ekf.covariance[0, 0]] * 3 + [bias_sigma**2] * 3),
        bias=np.zeros(3),
    )


def gyro_inputs(
    parameters: DoaGroundParameters, seed: np.random.SeedSequence, geometry: DoaGroundGeometry
) -> tuple[GyroTruth, FilterInputs]:
    """The truth at the gyro's samples (the epochs) and the gyro-aided rows' inputs: the
    :func:`epoch_gyro` record drawn from the trial's gyro stream
    (``child_rng(seed, GYRO_STREAM)``) and the EKF's initial estimate in the inertial
    frame with the gyro's bias sigma (:func:`_gyro_prior`) as the prior."""
    model = epoch_gyro(parameters)
    truth = GyroTruth(
        t=geometry.t,
        attitude=geometry.truth * geometry.eci_to_orbit,
        epoch_frames=geometry.eci_to_orbit,
        epoch_samples=np.arange(geometry.t.size),
    )
    inputs = replace(
        simulate_filter_inputs(truth, model, child_rng(seed, GYRO_STREAM)),
        prior=_gyro_prior(parameters, geometry, model.initial_bias_sigma),
    )
    return truth, inputs


def _gyro_rows(
    parameters: DoaGroundParameters,
    seed: np.random.SeedSequence,
    geometry: DoaGroundGeometry,
    doa_pass: Pass,
    rows: np.ndarray,
    common: Mapping[str, Any],
    start: DynamicsPass,
) -> list[pd.DataFrame]:
    """Rows of the gyro-aided filters and smoothers (module docstring, 6)."""
    filters = resolve(parameters.filters, filter_labels(), "filters")
    if not filters:
        return []
    truth, inputs = gyro_inputs(parameters, seed, geometry)
    simulated = inputs.gyro_pass(truth, doa_pass.snapshots)
    smoothed = unchecked(start.run.track)  # a start: the start check's flags do not apply
    valid = smoothed.valid  # (the epochs it flags start by gyro integration)
    inertial = np.full_like(smoothed.quaternion, np.nan)
    inertial[valid] = (
        stored_rotations(smoothed.quaternion[valid]) * geometry.eci_to_orbit[valid]
    ).as_quat()
    first = Run(
        single_frame_initial(
            _estimates("rts", inertial, smoothed.covariance, valid),
            inputs.prior,
        ),
        start.run.seconds,
    )
    starts = {
        label: first for label, name in filters.items() if "rts" in estimator(name).starts_from
    }
    chosen = configured_all(filters, parameters.estimator_options)
    runs = run_estimators(simulated.pass_, chosen, starts=starts)
    bound = {}
    if FACTOR_GRAPH & set(filters.values()):
        bound = {k: v[rows] for k, v in posterior_bound_columns(simulated).items()}
    frames = []
    for label, run in runs.items():
        track = in_orbit_frame(run.track, simulated.frames)
        errors = error_columns(track, geometry.truth)
        attitudes = _attitudes(track, geometry.truth)
        status = status_columns(track)
        frames.append(
            pd.DataFrame(
                {
                    "method": label,
                    **common,
                    **{name: column[rows] for name, column in errors.items()},
                    **{name: column[rows] for name, column in attitudes.items()},
                    **bound,
                    **{name: column[rows] for name, column in status.items()},
                    "runtime_s": run.seconds,
                }
            )
        )
    return frames


def unit_vector_observations(
    geometry: DoaGroundGeometry,
    epochs: np.ndarray,
    stations: np.ndarray,
    doas: DoaEstimates,
    covariance: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Body vectors ``S_dr`` (eq. 12), reference vectors ``S_o`` (eq. 17), sigmas; ``(N, S, .)``.

    Sigmas by :func:`_isotropic_sigma` of each DOA's unit-vector ``covariance`` ``(N, S,
    3, 3)`` (:func:`_doa_vector_statistics`).  Body vectors are NaN (and sigmas 1) where
    a station is not visible or MUSIC rejected it; measurements leave those out.
    """
    n, count = geometry.visible.shape
    body = np.full((n, count, 3), np.nan)
    body[epochs, stations] = doa_unit_vector(doas.theta, doas.phi)
    present = np.isfinite(body).all(axis=-1)
    sigma = np.where(present, _isotropic_sigma(covariance), 1.0)
    return body, _unit(geometry.line_of_sight_km), sigma


def _isotropic_sigma(unit_covariance: np.ndarray) -> np.ndarray:
    """``sigma`` of ``R_W = sigma^2 E`` (isotropic form of eq. 22): ``sigma^2 = tr(R_W) / 2``
    with ``R_W`` a DOA's unit-vector covariance (eq. 12)."""
    return np.sqrt(0.5 * np.trace(unit_covariance, axis1=-2, axis2=-1))


def _unit(vectors: np.ndarray) -> np.ndarray:
    return vectors / np.linalg.norm(vectors, axis=-1, keepdims=True)


def _prior(prior: FilterPrior) -> Prior:
    """The filters' initial estimate (Yang et al. 2014 sec. 6 by default) with its sigmas
    (covariance of ``[attitude, rate]``)."""
    sigma = np.radians([prior.sigma_deg] * 3 + [prior.rate_sigma_deg_s] * 3)
    return Prior(
        attitude=attitude_from_euler321(*np.radians(prior.euler_deg)),
        covariance=np.diag(sigma**2),
        rate=np.radians(prior.rate_deg_s),
    )


def _estimates(
    method: str,
    quaternion: np.ndarray,
    covariance: np.ndarray,
    valid: np.ndarray | None = None,
) -> Track:
    """A track of the estimates ``quaternion`` with their attitude covariances, valid where
    ``valid`` (default: everywhere)."""
    n = len(quaternion)
    return Track(
        method=method,
        quaternion=quaternion,
        covariance=covariance,
        loss=np.full(n, np.nan),
        valid=np.ones(n, dtype=bool) if valid is None else np.asarray(valid, dtype=bool),
        reason=np.full(n, "", dtype=object),
        error=np.full(n, None, dtype=object),
        diagnostics={},
    )


def _wahba_rows(
    label: str,
    name: str,
    simulated: SimulatedPass,
    rows: np.ndarray,
    common: Mapping[str, Any],
    setting: Setting,
) -> pd.DataFrame:
    """Single-epoch solutions of Wahba solver ``name`` (its vectorised path) at the row
    epochs, with the single-epoch CRB.

    Weighted by the DOAs' isotropic ``1 / sigma^2`` (:func:`unit_vector_observations`),
    with the covariance of that solution under each DOA's full unit-vector covariance
    (:func:`~attopt.formulations.wahba_covariance.anisotropic_covariance`: at 60 deg from the array
    axis a DOA's elevation error is twice its azimuth's).  An epoch with a DOA below
    MUSIC's threshold SNR is flagged (its error's tail is not Gaussian there:
    :mod:`attopt.solvers.doa.music`, Threshold region).
    """
    parameters, geometry = simulated.parameters, simulated.geometry
    body, reference, sigma = (v[rows] for v in simulated.vectors)
    present = np.isfinite(body).all(axis=-1)
    covariance, below = simulated.vector_covariance[rows], simulated.below_threshold[rows]
    track = configured(name, parameters.estimator_options).solve_batch(
        np.where(present[..., None], body, reference), reference, sigma**-2.0, present, covariance
    )
    threshold = parameters.music.threshold_output_snr
    track = track.flagged(
        (below & present).any(axis=1),
        f"below MUSIC's threshold: a DOA's output SNR L M SNR is below {threshold:g}, where "
        "its covariance does not describe its error's tail",
        ModelMismatchError,
    )
    array = parameters.array.array()
    bound = np.array([_single_epoch_bound(geometry, k, setting, array) for k in rows])
    return pd.DataFrame(
        {
            "method": label,
            **common,
            **error_columns(track, geometry.truth[rows]),
            **_attitudes(track, geometry.truth[rows]),
            **{f"bound_{a}_deg": bound[:, i] for i, a in enumerate("xyz")},
            **status_columns(track),
        }
    )


def _doa_vector_statistics(
    shape: tuple[int, int], epochs: np.ndarray, stations: np.ndarray, doas: DoaEstimates
) -> tuple[np.ndarray, np.ndarray]:
    """Each ``(epoch, station)``'s unit-vector covariance ``(*shape, 3, 3)`` (eq. 12, zero
    where absent) and whether its DOA is below MUSIC's threshold ``shape``, from the DOAs
    ``doas`` of the pairs ``(epochs, stations)``."""
    covariance = np.zeros((*shape, 3, 3))
    below = np.zeros(shape, dtype=bool)
    index = epochs[doas.valid], stations[doas.valid]
    covariance[index] = unit_vector_covariance(
        doas.theta[doas.valid], doas.phi[doas.valid], doas.covariance[doas.valid]
    )
    below[index] = doas.diagnostics["below_threshold"][doas.valid]
    return covariance, below


def _single_epoch_bound(
    geometry: DoaGroundGeometry, k: int, setting: Setting, array: UniformCircularArray
) -> np.ndarray:
    """Standard deviations (deg) of the CRB of ``C_bo`` from epoch ``k``'s stations alone."""
    visible = geometry.visible[k]
    if visible.sum() < 2:
        return np.full(3, np.nan)
    doa = geometry.doa[k, visible]
    crb = stochastic_crb(
        doa[:, 0], doa[:, 1], 10.0 ** (setting["snr_db"] / 10.0), setting["snapshots"], array
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
    array: DoaArray,
) -> dict[str, Any]:
    """Counts and mean squared DOA errors (deg^2) of the trial, and of the CRB at the truth,
    over all stations and per station (``..._station<k>``, ``k`` the 1-based index in
    ``stations``)."""
    truth = geometry.doa[epochs, stations]
    crb = stochastic_crb(
        truth[:, 0],
        truth[:, 1],
        10.0 ** (setting["snr_db"] / 10.0),
        setting["snapshots"],
        array.array(),
    )
    valid = doas.valid
    theta_error = np.degrees(doas.theta[valid] - truth[valid, 0])
    phi_error = np.degrees((doas.phi[valid] - truth[valid, 1] + np.pi) % (2.0 * np.pi) - np.pi)
    row = {
        "method": "music",
        "phase": "all",
        "valid": False,
        "reason": DOA_ROW_REASON,
        "doa_count": int(valid.size),
        "doa_accepted": int(valid.sum()),
        **{
            f"doa_rejected_{name}": int(np.char.startswith(doas.reason.astype(str), prefix).sum())
            for name, prefix in REJECTIONS.items()
        },
        "doa_theta_mse_deg2": _mean(theta_error**2),
        "doa_phi_mse_deg2": _mean(phi_error**2),
        "doa_crb_theta_deg2": _mean(crb[:, 0, 0]) * RAD2_TO_DEG2,
        "doa_crb_phi_deg2": _mean(crb[:, 1, 1]) * RAD2_TO_DEG2,
    }
    accepted = stations[valid]
    for k in range(geometry.visible.shape[1]):
        here, good = stations == k, accepted == k
        label = f"station{k + 1}"
        row |= {
            f"doa_count_{label}": int(here.sum()),
            f"doa_accepted_{label}": int(good.sum()),
            f"doa_theta_mse_{label}_deg2": _mean(theta_error[good] ** 2),
            f"doa_phi_mse_{label}_deg2": _mean(phi_error[good] ** 2),
            f"doa_crb_theta_{label}_deg2": _mean(crb[here, 0, 0]) * RAD2_TO_DEG2,
            f"doa_crb_phi_{label}_deg2": _mean(crb[here, 1, 1]) * RAD2_TO_DEG2,
        }
    return row


def _mean(values: np.ndarray) -> float:
    """The mean, NaN for no values."""
    return float(np.mean(values)) if values.size else np.nan


EXPERIMENT = Experiment(
    name="doa-ground",
    summary=(
        "Yang et al. 2014: attitude from MUSIC DOAs of ground stations, EKF, Wahba, "
        "gyro-aided MEKF and GTSAM smoother, Tables 1-2"
    ),
    schema=DoaGroundParameters,
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
    compiled_loops=("wahba.svd", "filters", "vectors", "smoother"),
)
