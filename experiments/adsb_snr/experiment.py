"""Experiment ``adsb-snr``: the SNR attitude solvers over Liu et al. 2023's one-hour pass.

Scenario (Liu et al. 2023 sec. 5.1): :mod:`attopt.experiments.adsb_snr.scenario` gives the
orbit, the true attitude, the antennas and a modelled global aircraft
population for the parameters of :class:`AdsbSnrParameters` (tables of
:mod:`attopt.experiments.adsb_snr.parameters`: ``[orbit]``, ``[attitude]``,
``[[antennas]]``, ``[traffic]``, ``[receiver]``; the defaults are the paper's
two tilted helices on a 600 km Sun-synchronous orbit).  The geometry and the
noise-free SNRs are deterministic scenario inputs, computed once per process
and scenario (:func:`noise_free_pass`); a trial's seed drives only the SNR
noise, the transmitters' power offsets and the gyros.

One trial, epoch by epoch at ``step_s`` over ``duration_s``:

1. *Visible*: the aircraft above the limb inside an antenna's main lobe at the
   TRUE attitude, up to that antenna's pattern's own limit (for Liu et al.
   2023's helix ``G >= 4 dBi``, sec. 5.1).
2. *True SNR*: ``G(alpha) + 10 lg P0 - 10 lg P_n`` (eqs. 1-4, 13) at the true
   attitude with the receiving antenna's pattern, ``P0`` from the
   :class:`~attopt.formulations.link_budget.LinkBudget` of ``[traffic]`` and
   ``[receiver]`` at the slant range.
3. *Measured*: true + ``receiver.snr_sigma_db`` x N(0, 1), one draw per visible
   (epoch, antenna, aircraft) row from ``numpy.random.default_rng(seed)`` in one
   call, rows in the observation table's order (epoch, then antenna 1 before
   antenna 2 and so on, then aircraft id).
4. *Received*: rows with measured SNR >= ``receiver.threshold_db`` (sec. 5.1,
   ``P_SNR^req = 6 dB``); the receiver decodes only those.  This is a selection
   on the noise: near the threshold only positive noise survives, so the kept
   measurements are biased upward and the Gaussian likelihood of eq. 19
   (``deterministic``, ``nlse``, ``nlp``) is misspecified; ``nlp_truncated``
   maximises the likelihood of the truncated measurements instead
   (:mod:`attopt.formulations.snr_truncation`).  The rows record the mean bias of the
   kept measurements (``snr_bias_db``) and a second bound for the truncated
   measurements (``bound_truncated_*``, :func:`epoch_statistics`), the right
   bound for every method on thresholded data.  Measured over the hour (trial 0
   of seed 0, before ``nlp_truncated``): the NLP's RMS / CRLB was 1.33 +/- 0.01
   with mean NEES 11.2 at 6 dB, and 0.99 +/- 0.01 with mean NEES 2.99 with
   ``threshold_db = -100`` (nothing discarded, same noise).
5. Each method (``methods``: the registry's snapshot estimators that accept
   SNRs, labelled by their registry names) runs ``solve_sequence`` over the
   pass's snapshots (one
   :class:`~attopt.formulations.snr_measurement.SnrMeasurement` of the epoch's
   :class:`~attopt.formulations.snr_problem.SnrEpoch` each), warm-started from the previous
   valid estimate as a flight estimator would be (the first epoch has no
   prior: the one-step methods start from the two-step solution, or a
   multi-start, :mod:`attopt.solvers.snr.initialisation`).  The two-step method
   uses antennas with at least ``deterministic_min_per_antenna`` messages
   (Liu et al. 2023 sec. 3.3: 3).

Rows, per method and epoch: ``t_s`` (seconds from the start), ``n_visible``
(before the threshold), ``n_obs`` and ``n_obs_antenna{i}`` for each configured
antenna ``i = 1 .. n`` (their sum), ``snr_bias_db`` (mean over all received
messages); the body-frame error ``err_{x,y,z}_deg`` (rotation vector of
``A_est A_true^T``, ``docs/conventions.md``); ``q_est_{x,y,z,w}`` and
``q_true_{x,y,z,w}``, the estimated and true orbit -> body attitudes
(scalar-last, :func:`attopt.experiments.metrics.attitude_columns`);
``bound_{x,y,z}_deg``, the square root of the diagonal of the Cramer-Rao bound
``(J^T C J)^-1`` (eq. 22) at the TRUE attitude with the received observations
(conditional on which were received), NaN on every body axis that an
unobservable rotation moves (``docs/conventions.md``); ``n_unobservable``, the
dimension of that unobservable rotation space (0 when the bound is finite),
and ``unobservable_{x,y,z}``, its unit direction in the body frame when it is
one-dimensional (NaN otherwise): with every message from one antenna it is
that antenna's boresight, the rotation a symmetric gain pattern cannot see
(Liu et al. 2023 sec. 3.1).  A boresight that is not a body axis makes the
bound NaN on two or three body axes, and the direction columns say which
single rotation it is; the bound's finite axes are exact.
``sigma_{x,y,z}_deg`` and ``nees`` come from the method's own covariance (NaN on
the axes it cannot see); 3-2-1 Euler-angle differences
``euler_{yaw,pitch,roll}_err_deg`` wrapped to [-180, 180) (what Liu et al. 2023
Table 2 tabulates); ``loss`` (the method's own objective: eq. 19 weighted by
``C``, for ``nlp_truncated`` the truncated negative log-likelihood,
:mod:`attopt.solvers.snr.fit`); ``wrong_minimum`` and
``loss_from_truth`` (below); ``valid``, ``reason``; ``runtime_s``.

``runtime_s`` is the wall time (``time.perf_counter``) of the method's whole
``solve_sequence`` over the pass, repeated on each of its rows.  It is the
only column that is not reproducible: every other column is bitwise identical
across engines, workers and reruns (``docs/sweeps.md``).  Before timing, every
method solves one epoch of each padding bucket size of the pass untimed, so
that the one-off construction of CasADi functions and IPOPT problems per
process (:mod:`attopt.solvers.snr.padding`) is not charged to the pass, as flight
code would be compiled beforehand.

Wrong local minima.  Every ``wrong_minimum_every``-th epoch
(0, k, 2k, ...) that the method solved is solved again with the TRUE attitude
as prior.  ``loss_from_truth`` is that solve's loss (of the method's own
objective); ``wrong_minimum`` is 1
when the method's own loss exceeds it by more than
:data:`WRONG_MINIMUM_RTOL` x ``loss_from_truth`` + :data:`WRONG_MINIMUM_ATOL`,
else 0, and NaN where not checked (other epochs, invalid solutions, or a
one-step re-solve that could not start from the truth).  The deterministic
method does not minimise eq. 19: its prior only resolves two-fold boresight
ambiguities, so for it the check tests that choice alone.

Summary columns (:func:`summary_columns`), per method: ``yaw_max_deg``,
``pitch_max_deg``, ``roll_max_deg`` (signed body-axis error of largest
magnitude, z, y, x, as Table 2's "Maximum"), ``runtime_s`` (mean over trials
of the pass time), ``crlb_ratio`` and ``crlb_ratio_10plus`` (RMS error over
RMS of ``sqrt(CRB)``, over valid rows with a finite bound, all of them and
those with at least 10 received observations), ``crlb_ratio_truncated`` (the
same against ``bound_truncated_*``), ``n_unbounded`` (valid rows left out for
a bound that is not finite) and ``wrong_minimum_fraction`` with
``wrong_minimum_checked``.
"""

from __future__ import annotations

import functools
import itertools
import time
from collections.abc import Mapping
from dataclasses import dataclass, replace
from typing import Any, Literal

import numpy as np
import pandas as pd
from numpy.typing import NDArray
from pydantic import Field, model_validator
from scipy.spatial.transform import Rotation

from attopt.experiments.adsb_snr.filters import (
    DEFAULT_FILTERS,
    PAPER_FILTER,
    PAPER_SOURCE,
    SNR_MODELS,
    filter_estimators,
    filter_labels,
    filter_rows,
    gyro_label,
)
from attopt.experiments.adsb_snr.parameters import AdsbScenario
from attopt.experiments.adsb_snr.report import MANY_OBSERVATIONS, report
from attopt.experiments.adsb_snr.scenario import build_adsb_geometry, observation_chunks
from attopt.experiments.adsb_snr.sky import (
    Reception,
    gaussian_measurements,
    model_allowance_db,
    model_common_sigma_db,
    modelled_eirp,
    reception,
    transmitter_offsets,
)
from attopt.experiments.adsb_snr.sky import Rows as SkyRows
from attopt.experiments.adsb_snr.spoofing import Decoded, spoofed_decoding
from attopt.experiments.config.components import Gyro, GyroFault, gyro_model
from attopt.experiments.estimators import (
    EstimatorOptions,
    configured,
    configured_all,
    label_field,
    registered_labels,
    resolve,
)
from attopt.experiments.experiment import Experiment, Setting
from attopt.experiments.metrics import attitude_columns, error_columns
from attopt.experiments.reporting.statistics import (
    bounded_valid_rows,
    rms_ratio_by_group,
    signed_max,
    valid_mask,
)
from attopt.experiments.simulation import INITIAL_ATTITUDE_SIGMA_DEG, child_rng
from attopt.formulations.gain_patterns import AntennaPatterns, GainPattern, shared_pattern
from attopt.formulations.link_budget import LinkBudget
from attopt.formulations.snapshot import Snapshot
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.formulations.snr_model import cramer_rao_bound, predict_snr, unobservable_directions
from attopt.formulations.snr_problem import SnrEpoch
from attopt.formulations.snr_truncation import truncated_information_factor
from attopt.solvers.estimator import SnapshotEstimator
from attopt.solvers.pipeline import Run
from attopt.solvers.results import AXES, Track, observable_sigma
from attopt.solvers.smoother import OFFSET_PRIOR_SIGMA_DB
from attopt.solvers.snr.deterministic import LIU2023_MIN_PER_ANTENNA
from attopt.solvers.snr.driver import SnrSolver, snr_epoch
from attopt.solvers.snr.initialisation import StartSource
from attopt.solvers.snr.padding import bucket_size

NO_GYRO = "none"
"""``gyro`` column of the single-frame rows."""
OFFSET_STREAM = 100
"""Child stream (:func:`~attopt.experiments.simulation.child_rng`) of the power offsets."""
OFFSETS_START = "nlp"
"""The single-frame method ``fg_batch_offsets`` starts from (:func:`offsets_start`)."""
WRONG_MINIMUM_RTOL = 1e-6
"""Relative loss excess over the truth-started solve that counts as a wrong minimum."""
WRONG_MINIMUM_ATOL = 1e-9
"""Absolute loss excess (dB^2 / sigma^2) added to the relative tolerance."""


def method_labels() -> dict[str, str]:
    """Row label -> registry name of the ``methods``: the snapshot estimators that accept
    SNRs, by name."""
    return registered_labels("snapshot", SnrMeasurement)


class AdsbSnrParameters(AdsbScenario):
    """Parameters of ``adsb-snr`` (Liu et al. 2023 sec. 5.1): the scenario's tables
    (:class:`~attopt.experiments.adsb_snr.parameters.AdsbScenario`) and the estimators."""

    wrong_minimum_every: int = Field(
        20, ge=1, description="Every k-th solved epoch is re-solved from the truth."
    )
    methods: list[label_field(method_labels, "methods")] = Field(
        default_factory=lambda: ["deterministic", "nlse", "nlp", "nlp_truncated"],
        description="Single-frame SNR solvers (registry names).",
    )
    deterministic_min_per_antenna: int = Field(
        LIU2023_MIN_PER_ANTENNA,
        ge=2,
        description="Messages an antenna needs to enter the two-step method.",
    )
    filters: list[label_field(filter_labels, "filters")] = Field(
        default_factory=lambda: list(DEFAULT_FILTERS),
        description="Filters and smoothers (row labels).",
    )
    gyros: list[Gyro] = Field(
        default_factory=lambda: ["liu2023", "mems"],
        description="Gyros, each a preset name or a table of its numbers.",
    )
    gyro_fault: GyroFault | None = Field(
        None, description="Faults of every gyro's samples the filters get; none by default."
    )
    initial_sigma_deg: float = Field(
        INITIAL_ATTITUDE_SIGMA_DEG, gt=0, description="Per-axis sigma of the filters' prior."
    )
    paper_sigma_deg: float = Field(
        1.0, gt=0, description="Sigma of the Euler-angle measurements of the paper's MEKF."
    )
    filter_snr_model: Literal[SNR_MODELS] = Field(
        "truncated", description="SNR likelihood of the SNR filters."
    )
    offset_prior_sigma_db: float = Field(
        OFFSET_PRIOR_SIGMA_DB, gt=0, description="Prior sigma of the estimated power offsets."
    )
    estimator_options: EstimatorOptions

    @model_validator(mode="after")
    def _gyros_of_one_pass(self) -> AdsbSnrParameters:
        labels = [gyro_label(g) for g in self.gyros]
        if len(set(labels)) < len(labels):
            raise ValueError(f"gyros need distinct names (row labels), got {labels}")
        rates = {gyro_model(g).rate_hz for g in self.gyros}
        if len(rates) > 1:
            raise ValueError(f"every gyro of a pass must have the same rate, got {sorted(rates)}")
        return self


def grid(parameters: Mapping[str, Any]) -> list[Setting]:
    """One setting, the validated parameters as a document; methods compared inside a trial.

    Raises:
        ValueError: a method or filter the registry does not have (the message lists the
            registered ones), or another bad parameter (pydantic's ValidationError).
    """
    return [AdsbSnrParameters.model_validate(dict(parameters)).model_dump(mode="json")]


@dataclass(frozen=True)
class NoiseFreePass:
    """Visible (epoch, antenna, aircraft) rows of a pass with their noise-free SNRs.

    Rows are in the order of :func:`attopt.experiments.adsb_snr.scenario.observation_chunks`
    (epoch, antenna, aircraft).  Shared per process: do not modify in place.
    """

    t: NDArray[np.float64]
    truth: Rotation
    epoch_index: NDArray[np.intp]
    antenna: NDArray[np.intp]
    aircraft: NDArray[np.intp]
    los_orbit: NDArray[np.float64]
    p0_dbw: NDArray[np.float64]
    aircraft_ecef_km: NDArray[np.float64]
    """The transmitting aircraft's positions, ECEF (ITRS), ``(M, 3)``."""
    true_snr_db: NDArray[np.float64]
    """SNR at the true attitude (eq. 13), ``(M,)``."""
    jacobian: NDArray[np.float64]
    """``d SNR / d delta`` at the true attitude (dB/rad, body-frame error), ``(M, 3)``."""
    boresights_body: NDArray[np.float64]
    """Unit antenna boresights, body frame, ``(n_antennas, 3)``."""
    pattern: GainPattern | AntennaPatterns
    """The antennas' gain pattern (one, or one per antenna)."""
    link_budget: LinkBudget

    @property
    def n_epochs(self) -> int:
        return int(self.t.size)

    @property
    def n_antennas(self) -> int:
        return int(self.boresights_body.shape[0])


def antenna_pattern(scenario: AdsbScenario) -> GainPattern | AntennaPatterns:
    """The antennas' gain patterns: the one pattern when they are all equal, else one per
    antenna (:func:`~attopt.formulations.gain_patterns.shared_pattern`)."""
    return shared_pattern([antenna.gain.pattern() for antenna in scenario.antennas])


def noise_free_pass(scenario: AdsbScenario) -> NoiseFreePass:
    """The scenario's visible rows and true SNRs (cached per process; module docstring, 1-2)."""
    return _noise_free_pass(scenario.key())


@functools.lru_cache(maxsize=2)
def _noise_free_pass(key: str) -> NoiseFreePass:
    scenario = AdsbScenario.model_validate_json(key)
    geometry = build_adsb_geometry(scenario)
    pattern = antenna_pattern(scenario)
    link = scenario.link_budget
    parts: dict[str, list[np.ndarray]] = {
        k: [] for k in ("epoch", "antenna", "aircraft", "los", "p0", "position")
    }
    snr_parts, jac_parts = [], []
    for table in observation_chunks(geometry):
        p0 = link.isotropic_power_dbw(table.range_m)
        per_antenna = isinstance(pattern, AntennaPatterns)
        snr, jac = predict_snr(  # one observation per stacked attitude
            geometry.truth[table.epoch_index],
            table.los_orbit[:, None, :],
            geometry.boresights_body[table.antenna][:, None, :],
            p0[:, None],
            link.noise_power_dbw,
            pattern,
            antenna=table.antenna[:, None] if per_antenna else None,
        )
        for key_, value in zip(
            parts,
            (
                table.epoch_index,
                table.antenna,
                table.aircraft,
                table.los_orbit,
                p0,
                table.aircraft_ecef_km,
            ),
            strict=True,
        ):
            parts[key_].append(value)
        snr_parts.append(snr[:, 0])
        jac_parts.append(jac[:, 0, :])
    return NoiseFreePass(
        t=geometry.t,
        truth=geometry.truth,
        epoch_index=np.concatenate(parts["epoch"]),
        antenna=np.concatenate(parts["antenna"]),
        aircraft=np.concatenate(parts["aircraft"]),
        los_orbit=np.concatenate(parts["los"]),
        p0_dbw=np.concatenate(parts["p0"]),
        aircraft_ecef_km=np.concatenate(parts["position"]),
        true_snr_db=np.concatenate(snr_parts),
        jacobian=np.concatenate(jac_parts),
        boresights_body=geometry.boresights_body,
        pattern=pattern,
        link_budget=link,
    )


@dataclass(frozen=True)
class NoisyPass:
    """One trial's measurements: which rows were received, and the epochs to solve.

    ``true_snr_db`` is the scenario's true SNR plus the transmitters' power
    offsets (equal to it without offsets); ``decoded`` the positions, lines of sight
    and powers the receiver takes from the messages (the true ones without a spoofer,
    :mod:`attopt.experiments.adsb_snr.spoofing`), those of the epochs.
    """

    measured_db: NDArray[np.float64]
    received: NDArray[np.bool_]
    epochs: list[SnrEpoch]
    true_snr_db: NDArray[np.float64]
    decoded: Decoded
    sigma_db: NDArray[np.float64] | float
    """The standard deviation the receiver states, per row or one for all."""
    threshold_db: float
    """The epochs' reception threshold (``-inf`` for the receiver chain)."""
    messages: NDArray[np.int64] | None = None
    """Messages decoded per row, when messages are modelled (:mod:`.sky`)."""


def power_offsets(
    scenario: NoiseFreePass, seed: np.random.SeedSequence, sigma_db: float
) -> NDArray[np.float64]:
    """Each row's transmitter power offset (dB): one ``N(0, sigma_db^2)`` draw per
    aircraft of the fleet from child stream :data:`OFFSET_STREAM` of the trial's seed
    (zeros when ``sigma_db`` is 0)."""
    if sigma_db == 0:
        return np.zeros(scenario.aircraft.size)
    n_fleet = int(scenario.aircraft.max()) + 1 if scenario.aircraft.size else 0
    per_aircraft = sigma_db * child_rng(seed, OFFSET_STREAM).standard_normal(n_fleet)
    return per_aircraft[scenario.aircraft]


def simulate_pass(
    scenario: NoiseFreePass,
    rng: np.random.Generator,
    sigma_db: float,
    threshold_db: float,
    offset_db: NDArray[np.float64] | None = None,
    fault_db: NDArray[np.float64] | None = None,
    decoded: Decoded | None = None,
    reception: Reception | None = None,
) -> NoisyPass:
    """Noisy SNRs, the threshold and one :class:`SnrEpoch` per epoch (module docstring,
    3-4); ``offset_db`` ``(M,)`` adds each row's transmitter power offset, ``fault_db``
    ``(M,)`` an error of the receiver's measurement (``receiver.outliers``), ``decoded``
    replaces the true lines of sight and powers of the epochs by what the receiver
    decodes (``traffic.spoofer``), ``reception`` replaces the Gaussian receiver by
    message collisions and the receiver chain (:mod:`attopt.experiments.adsb_snr.sky`)."""
    decoded = Decoded.of(scenario) if decoded is None else decoded
    true_snr = scenario.true_snr_db if offset_db is None else scenario.true_snr_db + offset_db
    if reception is None:
        reports = gaussian_measurements(true_snr, rng, sigma_db, threshold_db, fault_db)
    else:
        reports = reception.measure(true_snr, rng, sigma_db, threshold_db, fault_db)
    measured, received = reports.measured_db, reports.received
    row_sigma = np.broadcast_to(reports.sigma_db, true_snr.shape)
    rows = np.flatnonzero(received)
    bounds = np.searchsorted(scenario.epoch_index[rows], np.arange(scenario.n_epochs + 1))
    epochs = [
        SnrEpoch(
            snr_db=measured[take],
            los_orbit=decoded.los_orbit[take],
            antenna=scenario.antenna[take],
            boresights_body=scenario.boresights_body,
            p0_dbw=decoded.p0_dbw[take],
            noise_dbw=scenario.link_budget.noise_power_dbw,
            pattern=scenario.pattern,
            sigma_db=reports.sigma_db if np.ndim(reports.sigma_db) == 0 else row_sigma[take],
            threshold_db=reports.threshold_db,
            transmitter=scenario.aircraft[take],
        )
        for take in (rows[start:stop] for start, stop in itertools.pairwise(bounds))
    ]
    return NoisyPass(
        measured,
        received,
        epochs,
        true_snr,
        decoded,
        reports.sigma_db,
        reports.threshold_db,
        reports.messages,
    )


def _per_epoch_sum(values: np.ndarray, epoch: np.ndarray, n_epochs: int) -> np.ndarray:
    """Sum of ``values`` ``(K, ...)`` per epoch -> ``(n_epochs, ...)``."""
    flat = values.reshape(values.shape[0], int(np.prod(values.shape[1:])))
    sums = [
        np.bincount(epoch, weights=flat[:, j], minlength=n_epochs) for j in range(flat.shape[1])
    ]
    return np.stack(sums, axis=-1).reshape(n_epochs, *values.shape[1:])


def antenna_count_columns(n_antennas: int) -> list[str]:
    """``n_obs_antenna1 .. n_obs_antenna{n}``: received messages per antenna and epoch."""
    return [f"n_obs_antenna{i}" for i in range(1, n_antennas + 1)]


def epoch_statistics(
    scenario: NoiseFreePass,
    noisy: NoisyPass,
    sigma_db: float | NDArray[np.float64],
    threshold_db: float,
) -> dict[str, np.ndarray]:
    """Per-epoch columns shared by every method: time, counts, selection bias, CRBs at the
    truth and the rotation the received messages cannot see (module docstring).

    ``bound_*`` is eq. 22 with the received observations (the Gaussian model of
    eq. 19); ``bound_truncated_*`` weights each received observation by
    :func:`~attopt.formulations.snr_truncation.truncated_information_factor` at its
    true SNR, the Fisher information of the threshold-truncated measurement it
    actually is (given which were received): the bound for every method here.
    Both are NaN on the body axes an unobservable rotation moves
    (:func:`~attopt.solvers.results.observable_sigma` of the infinite variances of
    :func:`~attopt.formulations.snr_model.cramer_rao_bound`); the weights are positive,
    so both have the unobservable rotations of ``bound_*``
    (:func:`~attopt.formulations.snr_model.unobservable_directions`).
    """
    n = scenario.n_epochs
    kept = noisy.received
    epoch = scenario.epoch_index[kept]
    counts = np.stack(
        [
            np.bincount(epoch[scenario.antenna[kept] == a], minlength=n)
            for a in range(scenario.n_antennas)
        ],
        axis=1,
    )
    n_obs = counts.sum(axis=1)
    jac = scenario.jacobian[kept]
    sigma = np.broadcast_to(np.asarray(sigma_db, dtype=float), kept.shape)[kept]
    outer = jac[:, :, None] * jac[:, None, :] / sigma[:, None, None] ** 2
    factor = truncated_information_factor(noisy.true_snr_db[kept], sigma, threshold_db)
    fishers = {
        "bound": _per_epoch_sum(outer, epoch, n),
        "bound_truncated": _per_epoch_sum(factor[:, None, None] * outer, epoch, n),
    }
    bias_sum = np.bincount(
        epoch, weights=noisy.measured_db[kept] - noisy.true_snr_db[kept], minlength=n
    )
    with np.errstate(invalid="ignore", divide="ignore"):
        bias = bias_sum / n_obs
    columns = {
        "t_s": scenario.t,
        "n_visible": np.bincount(scenario.epoch_index, minlength=n),
        "n_obs": n_obs,
        **dict(zip(antenna_count_columns(scenario.n_antennas), counts.T, strict=True)),
        "snr_bias_db": bias,
    }
    for label, fisher in fishers.items():
        bound = np.degrees(observable_sigma(cramer_rao_bound(fisher)))
        for axis, column in zip(AXES, bound.T, strict=True):
            columns[f"{label}_{axis}_deg"] = column
    n_unobservable, direction = unobservable_directions(fishers["bound"])
    columns["n_unobservable"] = n_unobservable
    for axis, column in zip(AXES, direction.T, strict=True):
        columns[f"unobservable_{axis}"] = column
    return columns


def snr_snapshots(epochs: list[SnrEpoch]) -> list[Snapshot]:
    """One snapshot per epoch, holding the epoch's SNRs."""
    return [Snapshot.of(SnrMeasurement(epoch)) for epoch in epochs]


def warm_up(solver: SnapshotEstimator, snapshots: list[Snapshot]) -> None:
    """Solve one epoch of each padding bucket size of an SNR solver (untimed), building the
    cached functions; other estimators have none."""
    if not isinstance(solver, SnrSolver):
        return
    seen: set[int] = set()
    for snapshot in snapshots:
        problem = snr_epoch(snapshot)
        size = bucket_size(problem.m)
        if size not in seen and solver.issue(problem) is None:
            seen.add(size)
            solver.solve_sequence([snapshot])


def timed_pass(solver: SnapshotEstimator, snapshots: list[Snapshot]) -> tuple[Track, float]:
    """The method's warm-started pass and its wall time (s)."""
    warm_up(solver, snapshots)
    start = time.perf_counter()
    solution = solver.solve_sequence(snapshots)
    return solution, time.perf_counter() - start


def wrong_minima(
    solver: SnapshotEstimator,
    snapshots: list[Snapshot],
    solution: Track,
    truth: Rotation,
    every: int,
) -> tuple[np.ndarray, np.ndarray]:
    """``wrong_minimum`` (1/0/NaN) and ``loss_from_truth`` per epoch (module docstring)."""
    n = len(snapshots)
    wrong = np.full(n, np.nan)
    loss_from_truth = np.full(n, np.nan)
    for i in range(0, n, every):
        if not solution.valid[i]:
            continue
        again = solver.solve_sequence([snapshots[i]], prior=truth[i])
        source = again.diagnostics.get("start_source")
        if not again.valid[0] or (source is not None and source[0] != StartSource.PRIOR):
            continue
        loss_from_truth[i] = again.loss[0]
        tolerance = WRONG_MINIMUM_RTOL * abs(again.loss[0]) + WRONG_MINIMUM_ATOL
        wrong[i] = float(solution.loss[i] > again.loss[0] + tolerance)
    return wrong, loss_from_truth


def _method_rows(
    label: str,
    solver: SnapshotEstimator,
    snapshots: list[Snapshot],
    truth: Rotation,
    common: Mapping[str, np.ndarray],
    every: int,
) -> tuple[pd.DataFrame, Track]:
    solution, seconds = timed_pass(solver, snapshots)
    wrong, loss_from_truth = wrong_minima(solver, snapshots, solution, truth, every)
    frame = pd.DataFrame(
        {
            "method": label,
            "gyro": NO_GYRO,
            **common,
            **error_columns(solution, truth),
            **attitude_columns(solution.quaternion, truth),
            "loss": solution.loss,
            "wrong_minimum": wrong,
            "loss_from_truth": loss_from_truth,
            "valid": solution.valid,
            "reason": solution.reason.astype(str),
            "runtime_s": seconds,
        }
    )
    return frame, solution


def method_estimators(parameters: AdsbSnrParameters) -> dict[str, SnapshotEstimator]:
    """Row label -> configured estimator of each of ``methods`` (the two-step method's
    ``deterministic_min_per_antenna`` and every method's power prior from the receiver's
    aircraft model, :func:`snapshot_defaults`; then ``estimator_options``)."""
    methods = resolve(parameters.methods, method_labels(), "methods")
    return configured_all(methods, parameters.estimator_options, snapshot_defaults(parameters))


def snapshot_defaults(parameters: AdsbSnrParameters) -> dict[str, dict[str, Any]]:
    """The experiment's defaults of the single-frame methods, by registry name: the
    two-step method's ``deterministic_min_per_antenna``; with ``[receiver.aircraft_model]``
    every method's (and the NLSE's that Liu et al. 2023's MEKF reads) power prior
    ``power_offset_sigma_db``, the model's allowance
    (:func:`~attopt.experiments.adsb_snr.sky.model_allowance_db`; the expected offset
    itself is in each message's ``10 lg P0``), and ``power_offset_common_sigma_db``, the
    part of it an antenna's aircraft share
    (:func:`~attopt.experiments.adsb_snr.sky.model_common_sigma_db`)."""
    defaults: dict[str, dict[str, Any]] = {
        "deterministic": {"min_per_antenna": parameters.deterministic_min_per_antenna}
    }
    allowance = model_allowance_db(parameters)
    if allowance:
        prior = {
            "power_offset_sigma_db": allowance,
            "power_offset_common_sigma_db": model_common_sigma_db(parameters),
        }
        for name in dict.fromkeys([*parameters.methods, PAPER_SOURCE]):
            defaults[name] = {**defaults.get(name, {}), **prior}
    return defaults


def trial_pass(
    parameters: AdsbSnrParameters, seed: np.random.SeedSequence
) -> tuple[NoiseFreePass, NoisyPass]:
    """The scenario's noise-free pass and trial ``seed``'s measurements of it (module
    docstring, 1-4): the SNR noise from ``default_rng(seed)``, the power offsets from
    :func:`power_offsets`, a burst of outliers (``receiver.outliers``) and aircraft
    broadcasting a wrong position
    (``traffic.spoofer``, :func:`~attopt.experiments.adsb_snr.spoofing.spoofed_decoding`)
    if there are."""
    scenario = noise_free_pass(parameters)
    receiver = parameters.receiver
    offsets = power_offsets(scenario, seed, parameters.traffic.power_offset_sigma_db)
    rows = SkyRows(
        scenario.epoch_index, scenario.antenna, scenario.aircraft, scenario.aircraft_ecef_km
    )
    eirp = transmitter_offsets(parameters, rows, seed)
    if eirp is not None:
        offsets = offsets + eirp
    burst = receiver.outliers
    fault = None if burst is None else burst.offsets(scenario.t[scenario.epoch_index])
    decoded = spoofed_decoding(parameters, scenario, seed)
    expected = modelled_eirp(parameters, rows, decoded.aircraft_ecef_km)
    if expected is not None:
        decoded = replace(decoded, p0_dbw=decoded.p0_dbw + expected)
    noisy = simulate_pass(
        scenario,
        np.random.default_rng(seed),
        receiver.snr_sigma_db,
        receiver.threshold_db,
        offsets,
        fault,
        decoded,
        reception(parameters, rows, scenario.true_snr_db + offsets, seed),
    )
    return scenario, noisy


def offsets_start(parameters: AdsbSnrParameters, snapshots: list[Snapshot]) -> Run | None:
    """The single-frame start of ``fg_batch_offsets`` when it is among the filters: the
    NLP's track (orbit frame) with ``power_offset_sigma_db = offset_prior_sigma_db``
    (then ``estimator_options``) and its time (else ``None``).

    A filter that ignores the offsets (the RTS pass ``fg_batch`` starts from) is biased
    by them, and its covariance then gates, or leaves outside the antennas' main lobes,
    much of what the smoother could use: on 300 s of ``adsb-snr`` with 2 dB offsets (MEMS
    gyro, seed 0) 60 % of the SNRs, and the smoother was valid at 76 % of the epochs
    at 0.88 deg RMS; from the NLP, which widens each SNR by the offsets' spread, it
    used 96 % and was valid at 99.7 % at 0.45 deg (``docs/smoother.md``).
    """
    wanted = filter_estimators(parameters)
    if not any(e.name == "fg_batch_offsets" for e in wanted.values()):
        return None
    solver = configured(
        OFFSETS_START,
        parameters.estimator_options,
        power_offset_sigma_db=parameters.offset_prior_sigma_db,
    )
    return Run(*timed_pass(solver, snapshots))


def trial(setting: Setting, seed: np.random.SeedSequence) -> pd.DataFrame:
    """One noisy pass solved by every method in ``setting["methods"]`` and every
    filter in ``setting["filters"]`` (:mod:`attopt.experiments.adsb_snr.filters`)."""
    parameters = AdsbSnrParameters.model_validate(setting)
    scenario, noisy = trial_pass(parameters, seed)
    common = epoch_statistics(scenario, noisy, noisy.sigma_db, noisy.threshold_db)
    snapshots = snr_snapshots(noisy.epochs)
    frames, solutions = [], {}
    for label, solver in method_estimators(parameters).items():
        frame, solutions[label] = _method_rows(
            label, solver, snapshots, scenario.truth, common, parameters.wrong_minimum_every
        )
        frames.append(frame)
    nlse = solutions.get(PAPER_SOURCE)
    if nlse is None and PAPER_FILTER in parameters.filters:
        source = configured(
            PAPER_SOURCE,
            parameters.estimator_options,
            **snapshot_defaults(parameters).get(PAPER_SOURCE, {}),
        )
        nlse = source.solve_sequence(snapshots)
    start = offsets_start(parameters, snapshots)
    frames += filter_rows(parameters, seed, noisy.epochs, nlse, common, scenario.truth, start)
    return pd.concat(frames, ignore_index=True)


def summary_columns(rows: pd.DataFrame, keys: list[str]) -> pd.DataFrame:
    """Per group: signed maxima, mean pass time, CRLB ratios, wrong-minimum fraction."""
    out = rows[keys].drop_duplicates().set_index(keys)
    valid = rows[valid_mask(rows)].groupby(keys)
    for name, axis in (("yaw", "z"), ("pitch", "y"), ("roll", "x")):
        out[f"{name}_max_deg"] = valid[f"err_{axis}_deg"].agg(signed_max)
    per_trial = rows.groupby([*keys, "trial_index"])["runtime_s"].first()
    out["runtime_s"] = per_trial.groupby(keys).mean()
    bounded = bounded_valid_rows(rows)
    for column, subset, bound in (
        ("crlb_ratio", bounded, "bound"),
        ("crlb_ratio_10plus", bounded[bounded["n_obs"] >= MANY_OBSERVATIONS], "bound"),
        ("crlb_ratio_truncated", bounded_valid_rows(rows, "bound_truncated"), "bound_truncated"),
    ):
        out[column] = rms_ratio_by_group(subset, keys, bound)
    n_valid = valid.size().reindex(out.index, fill_value=0)
    out["n_unbounded"] = n_valid - bounded.groupby(keys).size().reindex(out.index, fill_value=0)
    checked = rows.dropna(subset=["wrong_minimum"]).groupby(keys)["wrong_minimum"]
    out["wrong_minimum_fraction"] = checked.mean()
    out["wrong_minimum_checked"] = checked.size().reindex(out.index, fill_value=0).astype(int)
    return out.reset_index()


EXPERIMENT = Experiment(
    name="adsb-snr",
    summary=(
        "Liu et al. 2023: SNR attitude solvers (two-step QUEST, NLSE, NLP, truncated-ML NLP) and "
        "gyro-aided filters (MEKF, USQUE, RTS) and GTSAM smoothers over an hour, vs the CRB"
    ),
    schema=AdsbSnrParameters,
    grid=grid,
    trial=trial,
    default_trials=4,
    quick_trials=1,
    quick_parameters={"duration_s": 600.0},
    group_by=("method", "gyro"),
    report=report,
    summary_columns=summary_columns,
    compiled_loops=("wahba.quest", "filters", "smoother"),
)
