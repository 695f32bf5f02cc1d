"""Pieces shared by the recursive filters: inputs, options, gyro gaps, gating, results.

Every filter estimates the attitude ``A`` (reference -> body, the reference
being the frame the gyro rates are relative to) and the gyro bias from a
:class:`~attopt.formulations.gyro.GyroSamples` record and one
:class:`~attopt.formulations.attitude_measurement.AttitudeMeasurement` (or ``None``)
per output epoch.  The error state is ``[delta, delta_beta]`` with ``delta``
four times the modified Rodrigues parameters of ``A_true A_est^T`` (seed 000
eq. 28; the generalised Rodrigues parameters with ``a = 1, f = 4`` of
USQUE), equal to the body-frame rotation vector to first order.

Faults (issue 5, sec. 5), all counted in the result's diagnostics:

* gyro gaps (NaN samples): the last valid sample is held and the attitude
  variance grows by ``sigma_hold^2 ((s + dt)^2 - s^2)`` per step, ``s`` the
  time since the gap began, so that after a gap of ``T`` it has grown by
  ``(sigma_hold T)^2`` (a rate error of ``sigma_hold`` held for ``T``);
  before the first valid sample the rate is taken as zero with
  ``unknown_rate_sigma`` instead; epochs in a gap longer than
  ``max_gyro_gap_s`` are flagged invalid;
* measurement rows the model cannot predict, or with NaN values, are left out;
* outliers: each observation block is tested on its normalised innovation
  squared ``nu^T S^-1 nu`` against the chi-square quantile
  ``gate_probability`` with the block's dimension, and left out above it;
* a covariance that loses positive definiteness is symmetrised and its
  eigenvalues are floored (counted as ``covariance_repairs``);
* a non-finite state stops the filter: that epoch and all later ones are
  flagged invalid (never a NaN attitude reported as valid);
* a lost track: after ``max_rejected_epochs`` consecutive measurement epochs
  with at least as many gated observation blocks as used ones, epochs are
  flagged until one is accepted, the attitude covariance is inflated by
  ``recover_sigma^2 I`` and the bias covariance by the prior's bias
  covariance to re-acquire (counted as ``recoveries``): the updates that led
  the attitude astray have corrupted the bias estimate too, and with its
  covariance left small the filter would re-acquire the attitude at the next
  accepted measurement and then drift off again with the wrong bias.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import lru_cache

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.formulations.attitude_model import increment_matrix
from attopt.formulations.errors import ConvergenceError, InvalidObservationError
from attopt.formulations.gyro import (
    GyroModel,
    GyroSamples,
    attitude_increment,
    error_state_transition,
)
from attopt.solvers.results import Track

Array = NDArray[np.float64]

STATE_SIZE = 6
GATE_PROBABILITY = 0.9999
"""Default gate: a Gaussian block is wrongly rejected once in 10,000 (3.9 sigma for a scalar)."""


def error_vector(estimate: Rotation, reference: Rotation) -> Array:
    """Error vector ``4 p`` of ``estimate`` relative to ``reference`` (``p``: MRPs of
    ``estimate * reference.inv()``), body frame."""
    return 4.0 * (estimate * reference.inv()).as_mrp()


def apply_error(delta: Array, reference: Rotation) -> Rotation:
    """The attitude whose :func:`error_vector` relative to ``reference`` is ``delta``."""
    return Rotation.from_mrp(np.asarray(delta) / 4.0) * reference


@lru_cache(maxsize=1)
def _error_jacobian_function() -> ca.Function:
    x = ca.SX.sym("x", 3)
    dx = ca.SX.sym("dx", 3)
    turn = increment_matrix(x + dx) @ increment_matrix(x).T
    body = ca.vertcat(turn[2, 1] - turn[1, 2], turn[0, 2] - turn[2, 0], turn[1, 0] - turn[0, 1])
    jacobian = ca.substitute(ca.jacobian(0.5 * body, dx), dx, ca.DM.zeros(3))
    return ca.Function("error_jacobian", [x], [jacobian])


def error_jacobian(delta: Array) -> Array:
    """``J`` with ``apply_error(delta + d, A) = exp(J d) apply_error(delta, A)`` to first order.

    The derivative of the body-frame perturbation at ``apply_error(delta, A)``
    with respect to the error vector, by CasADi AD of
    :func:`attopt.formulations.attitude_model.increment_matrix` (``I`` at ``delta = 0``).
    """
    return _error_jacobian_function()(np.asarray(delta, dtype=float)).full()


@dataclass(frozen=True)
class FilterPrior:
    """Initial estimate at the first gyro sample time.

    Attributes:
        attitude: reference -> body.
        bias: ``(3,)`` rad/s.
        covariance: ``(6, 6)`` of ``[delta, delta_beta]`` (rad^2, rad^2/s^2).
    """

    attitude: Rotation
    bias: Array
    covariance: Array


@dataclass(frozen=True)
class FilterOptions:
    """Fault handling (module docstring).

    Attributes:
        gate_probability: chi-square probability of the innovation gate; 1 disables gating.
        hold_rate_sigma: rate uncertainty (rad/s) while a gyro sample is missing.
        max_gyro_gap_s: epochs in a longer gap are flagged invalid.
        max_attitude_sigma: epochs whose largest attitude standard deviation
            (rad) exceeds this are flagged invalid (linearisation no longer valid).
        unknown_rate_sigma: rate uncertainty (rad/s) before the first valid gyro sample.
        relinearise_fraction: the MEKF repeats its update while the second-order
            term of the attitude step, ``|s|^2 / 2``, exceeds this fraction of
            the smallest posterior attitude standard deviation
            (:func:`attopt.solvers.filters.mekf.update`).
        max_update_iterations: at most this many passes of that update.
        max_rejected_epochs: after this many consecutive measurement epochs
            with at least as many gated observations as used ones
            (:func:`rejected_epoch`), epochs are flagged as a lost
            track until an observation is accepted again, and the attitude
            covariance is inflated by ``recover_sigma^2 I`` (repeatedly, every
            ``max_rejected_epochs`` such epochs) so that the filter can
            re-acquire (:class:`TrackMonitor`; the bias covariance is inflated by
            the prior's).
        recover_sigma: that inflation (rad).
    """

    gate_probability: float = GATE_PROBABILITY
    hold_rate_sigma: float = np.radians(0.01)
    max_gyro_gap_s: float = 60.0
    max_attitude_sigma: float = np.radians(30.0)
    unknown_rate_sigma: float = np.radians(1.0)
    relinearise_fraction: float = 0.01
    max_update_iterations: int = 10
    max_rejected_epochs: int = 10
    recover_sigma: float = np.radians(20.0)


@dataclass(frozen=True)
class PreparedGyro:
    """Gyro samples with gaps filled by holding (module docstring)."""

    rates: Array
    """``(n - 1, 3)`` rates with NaN rows replaced by the last valid one (zero before any)."""
    hold_variance: Array
    """``(n - 1,)`` extra attitude variance per step (rad^2)."""
    gap_s: Array
    """``(n - 1,)`` time since the current gap began, at the step's end (0 outside gaps)."""


def prepare_gyro(samples: GyroSamples, options: FilterOptions) -> PreparedGyro:
    """Fill gyro gaps causally and compute their variance growth."""
    rates = np.asarray(samples.rates, dtype=float)
    missing = ~np.isfinite(rates).all(axis=1)
    index = np.where(missing, 0, np.arange(rates.shape[0]))
    np.maximum.accumulate(index, out=index)
    filled = np.where(missing[:, None], rates[index], rates)
    filled[missing & ~np.isfinite(filled).all(axis=1)] = 0.0  # a gap at the start
    # steps since the gap began (1 at its first step)
    run = np.zeros(rates.shape[0], dtype=float)
    count = 0
    for j, gap in enumerate(missing):
        count = count + 1 if gap else 0
        run[j] = count
    dt = samples.dt
    leading = np.cumsum(~missing) == 0  # no valid sample yet: the rate is unknown
    sigma = np.where(leading, options.unknown_rate_sigma, options.hold_rate_sigma)
    hold = sigma**2 * ((run * dt) ** 2 - ((run - 1).clip(0) * dt) ** 2)
    return PreparedGyro(filled, np.where(missing, hold, 0.0), run * dt)


def epoch_samples(samples: GyroSamples, t: Array) -> NDArray[np.intp]:
    """Indices of the gyro sample times equal to the epochs ``t`` (must be among them)."""
    t = np.asarray(t, dtype=float)
    index = np.clip(np.searchsorted(samples.t, t - 1e-6 * samples.dt), 0, samples.t.size - 1)
    if t.size == 0 or np.any(np.abs(samples.t[index] - t) > 1e-6 * samples.dt):
        raise InvalidObservationError("every epoch must be a gyro sample time")
    if np.any(np.diff(index) <= 0) or t[0] < samples.t[0]:
        raise InvalidObservationError("epochs must increase and start at or after the gyro")
    return index


def propagate_covariance(
    covariance: Array, rates: Array, hold_variance: Array, model: GyroModel, dt: float
) -> tuple[Array, Array]:
    """``P <- Phi_j P Phi_j^T + Q_j`` over consecutive gyro steps at the estimated
    ``rates``, and the steps' product ``Phi``.

    ``Phi_j`` is :func:`~attopt.formulations.gyro.error_state_transition`, ``Q_j`` the
    step's :func:`step_noise` (with the gap growth ``hold_variance``).
    """
    total = np.eye(STATE_SIZE)
    noise = step_noise(model, dt, hold_variance)
    for phi, q in zip(error_state_transition(rates, dt), noise, strict=True):
        covariance = phi @ covariance @ phi.T + q
        total = phi @ total
    return covariance, total


def step_noise(model: GyroModel, dt: float, hold_variance: Array) -> Array:
    """Process noise ``(k, 6, 6)`` of ``k`` gyro steps including the gap growth."""
    q = np.broadcast_to(model.process_noise(dt), (hold_variance.size, 6, 6)).copy()
    q[:, [0, 1, 2], [0, 1, 2]] += hold_variance[:, None]
    return q


@lru_cache(maxsize=64)
def gate_threshold(probability: float, dof: int) -> float:
    """Chi-square quantile of the innovation gate."""
    return float(chi2.ppf(probability, dof))


def noise_subset(noise: Array, rows: NDArray[np.intp]) -> Array:
    """``R`` restricted to ``rows``: ``(m,)`` variances or an ``(m, m)`` matrix."""
    return noise[rows] if noise.ndim == 1 else noise[np.ix_(rows, rows)]


def solve_noise(noise: Array, x: Array) -> Array:
    """``R^-1 x`` for ``(m,)`` variances (elementwise) or an ``(m, m)`` matrix."""
    if noise.ndim == 1:
        return x / noise.reshape(-1, *([1] * (x.ndim - 1)))
    return np.linalg.solve(noise, x)


def noise_sandwich(gain: Array, noise: Array) -> Array:
    """``K R K^T``."""
    return (gain * noise) @ gain.T if noise.ndim == 1 else gain @ noise @ gain.T


def kalman_gain(
    covariance: Array, h: Array, noise: Array, innovation: Array
) -> tuple[Array, float, Array]:
    """Gain ``K = P H^T S^-1``, ``nu^T S^-1 nu`` and the posterior ``(I - K H) P``,
    ``S = H P H^T + R``, in information form.

    ``P+ = (P^-1 + H^T R^-1 H)^-1``, ``K = P+ H^T R^-1`` and the
    matrix-inversion lemma for the normalised innovation: only ``6 x 6``
    inverses and work linear in the number of rows when ``R`` is given as
    variances (SNRs, unit vectors), however many rows an epoch has.
    """
    weighted = solve_noise(noise, np.column_stack([h, innovation]))
    r_inv_h, r_inv_nu = weighted[:, :-1], weighted[:, -1]
    posterior = np.linalg.inv(np.linalg.inv(covariance) + h.T @ r_inv_h)
    projected = h.T @ r_inv_nu
    nis = float(innovation @ r_inv_nu - projected @ posterior @ projected)
    return posterior @ r_inv_h.T, nis, posterior


def gate(
    innovation: Array,
    factor: Array,
    weight: Array,
    noise: Array,
    blocks: NDArray[np.intp],
    probability: float,
) -> NDArray[np.bool_]:
    """Rows whose block's normalised innovation squared is within the chi-square gate.

    The innovation covariance is ``S = F^T W F + R`` (``F`` ``(k, m)``: for the
    MEKF ``H^T`` with ``W = P``; for USQUE the sigma deviations with ``W`` the
    covariance weights); only its diagonal blocks are formed, blocks of equal
    size tested together, so the cost is linear in the number of blocks.
    """
    keep = np.ones(innovation.shape[0], dtype=bool)
    if probability >= 1.0 or innovation.size == 0:
        return keep
    labels, first, sizes = np.unique(blocks, return_index=True, return_counts=True)
    for size in np.unique(sizes):
        members = labels[sizes == size]
        rows = (
            np.stack([np.flatnonzero(blocks == b) for b in members])
            if size > 1
            else (first[sizes == size][:, None])
        )
        nu = innovation[rows]
        columns = factor[:, rows]  # (k, blocks, size)
        s = np.einsum("kbi,kl,lbj->bij", columns, weight, columns)
        if noise.ndim == 1:
            s += noise[rows][:, :, None] * np.eye(int(size))
        else:
            s += noise[rows[:, :, None], rows[:, None, :]]
        nis = np.einsum("bi,bi->b", nu, np.linalg.solve(s, nu[..., None])[..., 0])
        # not (nis <= threshold): a NaN NIS (non-finite S or innovation) is rejected too
        keep[rows[~(nis <= gate_threshold(probability, int(size)))].ravel()] = False
    return keep


def usable_rows(
    measurement: AttitudeMeasurement, predicted: Array
) -> tuple[NDArray[np.bool_], int, int]:
    """Rows with finite values, predictions and innovations (whole blocks); counts
    of the blocks left out for a NaN value and for an unpredictable one."""
    finite_z = np.isfinite(measurement.z)
    with np.errstate(invalid="ignore"):
        innovation = measurement.innovation(predicted)
    finite_h = np.isfinite(predicted).all(axis=0) & np.isfinite(innovation).all(axis=0)
    blocks = measurement.blocks
    bad_z = np.unique(blocks[~finite_z])
    bad_h = np.setdiff1d(np.unique(blocks[~finite_h]), bad_z)
    keep = ~np.isin(blocks, np.concatenate([bad_z, bad_h]))
    return keep, int(bad_z.size), int(bad_h.size)


def linearised(step: Array, posterior: Array, fraction: float) -> bool:
    """Whether an iterated update's step's second-order term ``|s|^2 / 2`` is within
    ``fraction`` of the smallest posterior attitude standard deviation (no need
    to relinearise; ``FilterOptions.relinearise_fraction``)."""
    smallest = np.sqrt(max(np.linalg.eigvalsh(posterior[:3, :3])[0], 0.0))
    return 0.5 * float(step[:3] @ step[:3]) <= fraction * smallest


def repair_covariance(p: Array) -> tuple[Array, bool]:
    """Symmetrise ``p``; floor its eigenvalues if it is not positive definite."""
    p = 0.5 * (p + p.T)
    try:
        np.linalg.cholesky(p)
        return p, False
    except np.linalg.LinAlgError:
        values, vectors = np.linalg.eigh(p)
        floor = max(values.max(), 0.0) * 1e-12 + 1e-300
        return (vectors * np.maximum(values, floor)) @ vectors.T, True


@dataclass
class EpochRecord:
    """Per-epoch outputs collected while filtering."""

    n: int
    quaternion: Array = field(init=False)
    bias: Array = field(init=False)
    covariance: Array = field(init=False)
    diagnostics: dict[str, Array] = field(init=False)
    reason: NDArray[np.object_] = field(init=False)

    def __post_init__(self) -> None:
        self.quaternion = np.full((self.n, 4), np.nan)
        self.bias = np.full((self.n, 3), np.nan)
        self.covariance = np.full((self.n, 6, 6), np.nan)
        names = ("nis", "n_used", "n_gated", "n_nan", "n_unpredictable", "gyro_gap_s")
        names += ("update_iterations", "recoveries")
        self.diagnostics = {name: np.zeros(self.n) for name in names}
        self.diagnostics["nis"][:] = np.nan
        self.diagnostics["covariance_repairs"] = np.zeros(self.n)
        self.reason = np.full(self.n, "", dtype=object)


NON_FINITE = "filter state became non-finite"


def record_epoch(
    record: EpochRecord,
    k: int,
    attitude: Rotation,
    bias: Array,
    covariance: Array,
    counts: dict[str, float] | None = None,
) -> bool:
    """Store epoch ``k``'s update ``counts`` and estimate; ``False`` if the state is
    not finite, in which case epoch ``k`` and all later ones are flagged (the
    caller stops filtering)."""
    for name, value in (counts or {}).items():
        record.diagnostics[name][k] = value
    quaternion = attitude.as_quat()
    if not (
        np.all(np.isfinite(quaternion))
        and np.all(np.isfinite(bias))
        and np.all(np.isfinite(covariance))
    ):
        record.reason[k:] = NON_FINITE
        return False
    record.quaternion[k], record.bias[k], record.covariance[k] = quaternion, bias, covariance
    return True


def rejected_epoch(n_gated: ArrayLike, n_used: ArrayLike) -> NDArray[np.bool_]:
    """An epoch whose gated observation blocks are at least as many as its used ones.

    With two vectors, a Sun vector rejected while the magnetometer is used
    counts (the filter has lost the rotation about the field); with many SNRs
    a few gated outliers do not.
    """
    n_gated, n_used = np.asarray(n_gated), np.asarray(n_used)
    return (n_gated > 0) & (n_gated >= n_used)


@dataclass
class TrackMonitor:
    """Detects a lost track and inflates the covariance to re-acquire (module docstring).

    Counts consecutive measurement epochs that were :func:`rejected_epoch`;
    at ``options.max_rejected_epochs`` the attitude covariance grows by
    ``options.recover_sigma^2 I`` and the bias covariance by
    ``bias_covariance`` (the prior's), ``recoveries`` is set in the epoch's
    counts and the count restarts.
    """

    options: FilterOptions
    bias_covariance: Array
    run: int = 0

    def check(self, counts: dict[str, float] | None, covariance: Array) -> Array:
        """The covariance to carry on with after an epoch's update ``counts``."""
        if counts is None:
            return covariance
        if rejected_epoch(counts.get("n_gated", 0.0), counts.get("n_used", 0.0)):
            self.run += 1
        elif counts.get("n_used", 0.0) > 0:
            self.run = 0
        if self.run < self.options.max_rejected_epochs:
            return covariance
        self.run = 0
        counts["recoveries"] = 1.0
        inflated = covariance.copy()
        inflated[:3, :3] += self.options.recover_sigma**2 * np.eye(3)
        inflated[3:, 3:] += self.bias_covariance
        return inflated


def _rejected_run(diagnostics: dict[str, Array]) -> Array:
    """Consecutive :func:`rejected_epoch` measurement epochs, up to each epoch.

    Epochs without a measurement neither extend nor reset the run.
    """
    rejected = rejected_epoch(diagnostics["n_gated"], diagnostics["n_used"])
    accepted = (diagnostics["n_used"] > 0) & ~rejected
    run = np.zeros(rejected.size)
    count = 0.0
    for k in range(rejected.size):
        count = count + 1 if rejected[k] else (0.0 if accepted[k] else count)
        run[k] = count
    return run


def filter_result(
    method: str,
    record: EpochRecord,
    options: FilterOptions,
    t: Array,
    history: FilterHistory | None = None,
) -> Track:
    """Assemble a filter's (or smoother's) :class:`~attopt.solvers.results.Track` at the
    epochs ``t``, flagging epochs by the module's rules.

    The track has the ``3 x 3`` attitude covariance; its ``loss`` is the
    normalised innovation squared of the epoch's update (NaN without one);
    diagnostics ``nis``, ``n_used``, ``n_gated``, ``n_nan``,
    ``n_unpredictable`` (observation blocks), ``gyro_gap_s`` and
    ``covariance_repairs``; ``bias`` the gyro bias estimates (rad/s),
    ``state_covariance`` the ``(N, 6, 6)`` covariance of the error state
    ``[delta, delta_beta]`` and ``history`` the inputs of a backward pass
    (MEKF only).
    """
    sigma = np.sqrt(np.max(np.diagonal(record.covariance[:, :3, :3], axis1=1, axis2=2), axis=1))
    reason = record.reason.copy()
    long_gap = (record.diagnostics["gyro_gap_s"] > options.max_gyro_gap_s) & (reason == "")
    reason[long_gap] = f"gyro gap longer than {options.max_gyro_gap_s:g} s"
    with np.errstate(invalid="ignore"):
        wide = (sigma > options.max_attitude_sigma) & (reason == "")
    reason[wide] = (
        f"attitude not determined: 1-sigma above {np.degrees(options.max_attitude_sigma):g} deg"
    )
    lost = _rejected_run(record.diagnostics) >= options.max_rejected_epochs
    reason[lost & (reason == "")] = (
        f"lost track: observations gated for {options.max_rejected_epochs} epochs"
    )
    valid = reason == ""
    error = np.full(record.n, None, dtype=object)
    error[~valid] = ConvergenceError
    quaternion = np.where(valid[:, None], record.quaternion, np.nan)
    covariance = np.where(valid[:, None, None], record.covariance, np.nan)
    return Track(
        method=method,
        quaternion=quaternion,
        covariance=covariance[:, :3, :3],
        loss=np.where(valid, record.diagnostics["nis"], np.nan),
        valid=valid,
        reason=reason,
        error=error,
        diagnostics=record.diagnostics,
        t=np.array(t, dtype=float),
        bias=np.where(valid[:, None], record.bias, np.nan),
        state_covariance=covariance,
        state=("attitude", "bias"),
        history=history,
    )


@dataclass(frozen=True)
class FilterHistory:
    """What a backward (RTS) pass needs, per epoch ``k``.

    ``predicted_*`` is the estimate at epoch ``k`` before its update, and
    ``transition[k]`` the error-state transition from epoch ``k - 1`` (the
    prior for ``k = 0``) to epoch ``k``; ``filtered_*`` the estimate after it.
    """

    predicted_quaternion: Array
    predicted_bias: Array
    predicted_covariance: Array
    transition: Array
    filtered_quaternion: Array
    filtered_bias: Array
    filtered_covariance: Array


def validate_inputs(
    samples: GyroSamples,
    t: Array,
    measurements: Sequence[AttitudeMeasurement | None],
    prior: FilterPrior,
) -> NDArray[np.intp]:
    """Check shapes and the prior; return the epochs' gyro sample indices."""
    if len(measurements) != np.size(t):
        raise InvalidObservationError(f"{len(measurements)} measurements for {np.size(t)} epochs")
    if np.shape(samples.rates) != (samples.t.size - 1, 3):
        raise InvalidObservationError("gyro rates must be (n - 1, 3) for n sample times")
    p = np.asarray(prior.covariance, dtype=float)
    if (
        p.shape != (STATE_SIZE, STATE_SIZE)
        or not np.all(np.isfinite(p))
        or not np.all(np.isfinite(prior.bias))
        or not np.all(np.isfinite(prior.attitude.as_quat()))
    ):
        raise InvalidObservationError("prior must be finite with a (6, 6) covariance")
    if repair_covariance(p)[1]:
        raise InvalidObservationError("prior covariance is not positive definite")
    return epoch_samples(samples, t)


def propagate_attitude(attitude: Rotation, rates: Array, dt: float) -> Rotation:
    """Carry attitudes over consecutive steps at constant rates (seed 000 eq. 25).

    ``rates`` is ``(k, 3)`` for one attitude or ``(K, k, 3)`` for a stack of
    ``K``; step ``j`` applies :func:`attopt.formulations.gyro.attitude_increment`.
    The increments' matrices are multiplied in order (later steps on the
    left) and the product applied once.
    """
    rates = np.asarray(rates, dtype=float)
    k = rates.shape[-2]
    if k == 0:
        return attitude
    steps = attitude_increment(rates.reshape(-1, 3), dt).as_matrix()
    steps = steps.reshape(*rates.shape[:-2], k, 3, 3)
    total = steps[..., 0, :, :]
    for j in range(1, k):
        total = steps[..., j, :, :] @ total
    return Rotation.from_matrix(total) * attitude
