"""Pieces shared by the gyro-aided filters: options, the gyro timeline and its gaps, gating.

Every gyro-aided estimator (the MEKF, USQUE, the online and batch smoothers)
estimates the attitude ``A`` (reference -> body, the reference being the
frame the gyro rates are relative to) and the gyro bias from a pass
(:class:`~attopt.formulations.passes.Pass`: a
:class:`~attopt.formulations.passes.GyroRecord`, one
:class:`~attopt.formulations.attitude_measurement.AttitudeMeasurement` or none
per epoch, a prior at the first gyro sample; :func:`gyro_pass`).  The epochs
need not be gyro sample times: the record is cut at them
(:func:`attopt.solvers.gyro_timeline.gyro_timeline`) and every step is
propagated with its own length.  The error state is ``[delta, delta_beta]``
with ``delta`` four times the modified Rodrigues parameters of ``A_true
A_est^T`` (Liu et al. 2023 eq. 28; the generalised Rodrigues parameters with ``a =
1, f = 4`` of USQUE), equal to the body-frame rotation vector to first order.

Faults, all counted in the result's diagnostics:

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
  flagged invalid (never a NaN attitude reported as valid;
  :func:`attopt.solvers.sequential.run_filter`);
* a lost track (:class:`~attopt.solvers.sequential.TrackMonitor`): after
  ``max_rejected_epochs`` consecutive measurement epochs with at least as
  many gated observation blocks as used ones, epochs are flagged until one is
  accepted; by default (``FilterOptions.recovery = "restart"``) the attitude
  restarts from a single-frame solution of the epoch's measurement (counted
  as ``restarts``; :mod:`attopt.solvers.filters.recovery`, which also starts
  a filter without a prior and restarts one whose innovations persistently
  contradict it), and where there is none, or with ``recovery = "inflate"``,
  the attitude covariance is inflated by ``recover_sigma^2 I`` and the bias
  covariance by the prior's bias covariance to re-acquire (counted as
  ``recoveries``; :func:`gyro_monitor`): the updates that led the attitude
  astray have corrupted the bias estimate too, and with its covariance left
  small the filter would re-acquire the attitude at the next accepted
  measurement and then drift off again with the wrong bias.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache
from typing import TYPE_CHECKING, Literal

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.gyro import GyroModel, GyroSamples, error_state_transition
from attopt.formulations.kernels import compiled_loops
from attopt.formulations.passes import GyroRecord, Pass, Prior
from attopt.formulations.quaternion_algebra import (
    compose,
    conjugate,
    from_mrp,
    from_rotation_vector,
    left_matrices,
    to_mrp,
)
from attopt.solvers.blocks import block_structure, count_blocks
from attopt.solvers.estimator import Estimator
from attopt.solvers.filters import compiled, update_kernels
from attopt.solvers.gyro_timeline import (
    COINCIDENCE,
    GyroTimeline,
    gyro_timeline,
    repeated_readings,
)
from attopt.solvers.robust import huber_weights
from attopt.solvers.sequential import SequentialFilter, TrackMonitor

if TYPE_CHECKING:
    from attopt.solvers.filters.offsets import OffsetStates, RowOffsets

Array = NDArray[np.float64]

STATE_SIZE = 6
GATE_PROBABILITY = 0.9999
"""Default gate: a Gaussian block is wrongly rejected once in 10,000 (3.9 sigma for a scalar)."""
CONSISTENCY_WINDOW = 10
"""Updates in the innovation consistency test (:class:`FilterOptions`)."""
CONSISTENCY_FALSE_ALARM = 1e-6
"""The consistency test's false-alarm probability per epoch (:class:`FilterOptions`)."""
RECOVERIES = ("restart", "inflate", "none")
"""The values of ``FilterOptions.recovery``."""


def error_vector(estimate: Rotation, reference: Rotation) -> Array:
    """Error vector ``4 p`` of ``estimate`` relative to ``reference`` (``p``: MRPs of
    ``estimate * reference.inv()``), body frame (:func:`quaternion_error_vector`)."""
    return quaternion_error_vector(estimate.as_quat(), reference.as_quat())


def apply_error(delta: ArrayLike, reference: Rotation) -> Rotation:
    """The attitude whose :func:`error_vector` relative to ``reference`` is ``delta``:
    ``Rotation.from_mrp(delta / 4) * reference`` (:func:`perturb_quaternion`)."""
    return Rotation.from_quat(perturb_quaternion(delta, reference.as_quat()))


def quaternion_error_vector(estimate: ArrayLike, reference: ArrayLike) -> Array:
    """:func:`error_vector` of scalar-last quaternions ``(..., 4)``, by the products of
    :mod:`attopt.formulations.quaternion_algebra`: the filters call it every epoch, and
    scipy's ``Rotation`` costs ten times more per call."""
    return 4.0 * to_mrp(compose(estimate, conjugate(reference)))


def perturb_quaternion(delta: ArrayLike, reference: ArrayLike) -> Array:
    """:func:`apply_error` on scalar-last quaternions (``(..., 4)``; the quaternion
    returned), as :func:`quaternion_error_vector`; compiled
    (:func:`attopt.solvers.filters.update_kernels.perturbed_quaternions`) for one reference or
    as many as errors, unless kernels are interpreted."""
    delta, reference = np.asarray(delta, dtype=float), np.asarray(reference, dtype=float)
    lead = delta.shape[:-1]
    if compiled_loops() and reference.shape[:-1] in (lead, ()):
        flat = update_kernels.perturbed_quaternions(delta.reshape(-1, 3), reference.reshape(-1, 4))
        return flat.reshape(*lead, 4)
    return perturbation_reference(delta, reference)


def perturbation_reference(delta: Array, reference: Array) -> Array:
    """The numpy reference of :func:`perturb_quaternion` (any broadcast shapes)."""
    return compose(from_mrp(delta / 4.0), reference)


def error_jacobian(delta: ArrayLike) -> Array:
    """``J`` with ``apply_error(delta + d, A) = exp(J d) apply_error(delta, A)`` to first order.

    The derivative of the body-frame perturbation at ``apply_error(delta, A)`` with
    respect to the error vector, ``p = delta / 4``::

        J = ((1 - |p|^2) I + 2 [p x] + 2 p p^T) / (1 + |p|^2)^2,

    the inverse of the kinematics matrix ``B(p)`` of the modified Rodrigues parameters
    (Markley and Crassidis 2014, ch. 3; ``B^-1 = 16 B^T / (1 + |p|^2)^2``) for the
    attitude ``C(delta) A`` of :func:`attopt.formulations.attitude_model.increment_matrix`;
    ``I`` at ``delta = 0``.
    Closed form rather than AD, for speed (every update calls it), written out entry by
    entry (a third of the cost of the matrix expression, the same values to the bit); the
    test suite checks it against CasADi's derivative of ``increment_matrix``.
    """
    p = np.asarray(delta, dtype=float) / 4.0
    norm2 = float(p @ p)
    x, y, z = p.tolist()
    a, d = 1.0 - norm2, (1.0 + norm2) ** 2
    xy, xz, yz = 2.0 * x * y, 2.0 * x * z, 2.0 * y * z
    return np.array(
        [
            [(a + 2.0 * x * x) / d, (-2.0 * z + xy) / d, (2.0 * y + xz) / d],
            [(2.0 * z + xy) / d, (a + 2.0 * y * y) / d, (-2.0 * x + yz) / d],
            [(-2.0 * y + xz) / d, (2.0 * x + yz) / d, (a + 2.0 * z * z) / d],
        ]
    )


@dataclass(frozen=True)
class FilterOptions:
    """Fault handling of the recursive estimators (module docstring).

    The gyro filters use every field; Yang et al. 2014's EKF (no gyro, no
    iterated update) the gate, the validity limit and the lost-track ones.

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
            (:func:`~attopt.solvers.sequential.rejected_epoch`), epochs are
            flagged as a lost track until an observation is accepted again,
            and, every ``max_rejected_epochs`` such epochs, the filter is restarted
            or its covariance inflated (``recovery``): the attitude by
            ``recover_sigma^2 I`` and the bias by the prior's
            (:class:`~attopt.solvers.sequential.TrackMonitor`).
        recover_sigma: that inflation (rad).
        consistency_window: updates whose normalised innovations squared are summed in
            the consistency test (:func:`~attopt.solvers.sequential.inconsistent_epochs`): an
            epoch whose window's sum exceeds the chi-square quantile of its degrees of
            freedom at ``consistency_false_alarm`` is flagged ``inconsistent``
            (:func:`~attopt.solvers.sequential.inconsistent_epochs`), since
            the filter's covariance does not describe its errors there (a model that
            does not fit the data, a filter still converging from a wrong start); 0
            turns the test off.
        consistency_false_alarm: the test's probability of flagging an epoch of a
            consistent filter (also the false alarm of the restart's tests,
            :mod:`attopt.solvers.filters.recovery`).
        recovery: what the MEKF and USQUE do to re-acquire
            (:mod:`attopt.solvers.filters.recovery`): ``"restart"``, restart the
            attitude from a single-frame solution of the epoch's measurement when the
            track is lost or the consistency window fails for
            ``max_rejected_epochs`` consecutive updates (and at the first measurement
            epoch when it contradicts the prior), falling back to the inflation by
            ``recover_sigma`` for a lost track where no single frame passes its tests;
            ``"inflate"``, the inflation alone; ``"none"``, flag only.  Without a
            prior the filters start from a single-frame solution whatever this is.
        max_repeated_readings: a gyro whose noise model has white rate noise
            (``sigma_v > 0``) is stuck where one axis reads exactly the same value for
            more than this many consecutive samples while another axis's reading changes
            (:func:`~attopt.solvers.gyro_timeline.repeated_readings`): those samples are
            treated as missing (held, with the variance growth of ``hold_rate_sigma``,
            and flagged beyond ``max_gyro_gap_s``); 0 turns the check off (a quantised
            record whose noise is below its quantum).
        huber_threshold: ``k`` of the Huber loss on each observation block's whitened
            innovation norm at the prior, in the updates of the MEKF, USQUE and Yang et
            al. 2014's EKF (:func:`robust_noise`); the blocks beyond it are down-weighted
            and counted
            in ``n_downweighted``; ``None`` (default): the Gaussian update.  The batch
            smoother has its own (``GraphOptions.huber_threshold``).

    Example::

        >>> import numpy as np
        >>> from attopt import FilterOptions, estimator
        >>> no_gate = FilterOptions(gate_probability=1.0, max_gyro_gap_s=5.0)
        >>> estimator("usque", filter=no_gate).filter.max_gyro_gap_s
        5.0
    """

    gate_probability: float = GATE_PROBABILITY
    hold_rate_sigma: float = np.radians(0.01)
    max_gyro_gap_s: float = 60.0
    max_attitude_sigma: float = np.radians(15.0)
    unknown_rate_sigma: float = np.radians(1.0)
    relinearise_fraction: float = 0.01
    max_update_iterations: int = 10
    max_rejected_epochs: int = 10
    recover_sigma: float = np.radians(20.0)
    consistency_window: int = CONSISTENCY_WINDOW
    consistency_false_alarm: float = CONSISTENCY_FALSE_ALARM
    recovery: Literal["restart", "inflate", "none"] = "restart"
    max_repeated_readings: int = 10
    huber_threshold: float | None = None

    def __post_init__(self) -> None:
        if self.huber_threshold is not None and not self.huber_threshold > 0:
            raise ValueError("huber_threshold must be positive (or None)")
        if self.recovery not in RECOVERIES:
            raise ValueError(
                f"recovery must be one of {', '.join(RECOVERIES)}, not {self.recovery!r}"
            )


@dataclass(frozen=True)
class PreparedGyro:
    """The gyro timeline with gaps filled by holding (module docstring)."""

    timeline: GyroTimeline
    """The steps the filters walk: the gyro record cut at the epochs."""
    rates: Array
    """``(n - 1, 3)`` step rates with NaN rows replaced by the last valid one (zero before any)."""
    hold_variance: Array
    """``(n - 1,)`` extra attitude variance per step (rad^2)."""
    gap_s: Array
    """``(n - 1,)`` time since the current gap began, at the step's end (0 outside gaps)."""

    @property
    def dt(self) -> Array:
        """``(n - 1,)`` step lengths (s)."""
        return self.timeline.dt

    def node(self, t: float) -> int:
        """Index into the timeline's boundaries of time ``t`` (a gyro sample time or an epoch).

        Raises:
            InvalidObservationError: ``t`` is neither.
        """
        boundaries = self.timeline.t
        slack = COINCIDENCE * self.timeline.sample_dt
        i = min(int(np.searchsorted(boundaries, t - slack)), boundaries.size - 1)
        if not abs(boundaries[i] - t) <= slack:
            raise InvalidObservationError(
                f"t = {t:g} s is neither a gyro sample time nor an epoch of the pass"
            )
        return i

    def gap_at(self, node: int) -> float:
        """Time since the current gap began at boundary ``node`` (0 outside gaps)."""
        return float(self.gap_s[node - 1]) if node > 0 else 0.0


def prepare_gyro(timeline: GyroTimeline, options: FilterOptions) -> PreparedGyro:
    """Fill gyro gaps causally and compute their variance growth, step by step.

    On a uniform timeline the time since a gap began is ``steps x dt``; on a
    cut one, the sum of the steps' lengths.
    """
    rates = np.asarray(timeline.rates, dtype=float)
    missing = ~np.isfinite(rates).all(axis=1)
    index = np.where(missing, 0, np.arange(rates.shape[0]))
    np.maximum.accumulate(index, out=index)
    filled = np.where(missing[:, None], rates[index], rates)
    filled[missing & ~np.isfinite(filled).all(axis=1)] = 0.0  # a gap at the start
    leading = np.cumsum(~missing) == 0  # no valid sample yet: the rate is unknown
    sigma = np.where(leading, options.unknown_rate_sigma, options.hold_rate_sigma)
    if timeline.uniform:
        # steps since the gap began (1 at its first step)
        run = np.zeros(rates.shape[0], dtype=float)
        count = 0
        for j, gap in enumerate(missing):
            count = count + 1 if gap else 0
            run[j] = count
        dt = timeline.sample_dt
        hold = sigma**2 * ((run * dt) ** 2 - ((run - 1).clip(0) * dt) ** 2)
        return PreparedGyro(timeline, filled, np.where(missing, hold, 0.0), run * dt)
    end = np.zeros(rates.shape[0])  # time since the gap began at each step's end
    begin = np.zeros(rates.shape[0])
    for j, gap in enumerate(missing):
        if gap:
            begin[j] = end[j - 1] if j > 0 and missing[j - 1] else 0.0
            end[j] = begin[j] + timeline.dt[j]
    hold = sigma**2 * (end**2 - begin**2)
    return PreparedGyro(timeline, filled, np.where(missing, hold, 0.0), end)


@dataclass(frozen=True)
class GyroPass:
    """A :class:`~attopt.formulations.passes.Pass` as the gyro-aided estimators use it.

    Attributes:
        gyro: the prepared timeline of the pass's gyro record cut at its epochs.
        model: the gyro's noise model.
        prior: ``[attitude, bias]`` at the first gyro sample (``None``: the pass has
            none and the estimator allows that).
        t: ``(N,)`` epoch times.
        measurements: one measurement (or ``None``) per epoch.
    """

    gyro: PreparedGyro
    model: GyroModel
    prior: Prior | None
    t: Array
    measurements: list[AttitudeMeasurement | None]


def gyro_prior(prior: Prior, model: GyroModel) -> Prior:
    """The ``[attitude, bias]`` prior of a gyro-aided estimator: ``prior`` itself, or an
    attitude-only one with zero bias and the model's initial bias sigma.

    Raises:
        InvalidObservationError: a prior with a body rate instead of a bias.
    """
    if prior.rate is not None:
        raise InvalidObservationError(
            "a gyro-aided estimator needs an attitude or [attitude, bias] prior, not a rate"
        )
    return prior.with_bias_covariance(model.initial_bias_sigma)


def check_gyro_pass(pass_: Pass, estimator: Estimator, needs_prior: bool = True) -> None:
    """Raise unless ``pass_`` suits a gyro-aided ``estimator``.

    Raises:
        UnsupportedMeasurementError: a measurement type ``estimator`` does not accept.
        InvalidObservationError: no gyro record, or no prior when ``needs_prior``.
    """
    estimator.check_types(pass_.types())
    if pass_.gyro is None:
        raise InvalidObservationError(f"{estimator.name} needs a gyro record: the pass has none")
    if needs_prior and pass_.prior is None:
        raise InvalidObservationError(f"{estimator.name} needs a prior: the pass has none")


def working_samples(record: GyroRecord, options: FilterOptions) -> GyroSamples:
    """The record's samples with those of a stuck axis missing (NaN; ``max_repeated_readings``
    of ``options``, checked only for a gyro model with white rate noise)."""
    samples = record.samples
    if record.model.sigma_v <= 0.0:
        return samples
    stuck = repeated_readings(samples.rates, options.max_repeated_readings)
    if not stuck.any():
        return samples
    return replace(samples, rates=np.where(stuck[:, None], np.nan, samples.rates))


def gyro_pass(
    pass_: Pass, estimator: Estimator, options: FilterOptions, needs_prior: bool = True
) -> GyroPass:
    """Check ``pass_`` for a gyro-aided ``estimator`` (:func:`check_gyro_pass`) and
    prepare its gyro timeline; ``prior`` is ``None`` for a pass without one (allowed
    unless ``needs_prior``)."""
    check_gyro_pass(pass_, estimator, needs_prior)
    model = pass_.gyro.model
    timeline = gyro_timeline(working_samples(pass_.gyro, options), pass_.t)
    return GyroPass(
        prepare_gyro(timeline, options),
        model,
        None if pass_.prior is None else gyro_prior(pass_.prior, model),
        pass_.t,
        pass_.measurements(),
    )


def gyro_monitor(options: FilterOptions, prior: Prior) -> TrackMonitor:
    """The gyro filters' :class:`~attopt.solvers.sequential.TrackMonitor`: re-acquisition
    inflates the attitude covariance by ``recover_sigma^2 I`` and the bias covariance by
    the prior's (module docstring; none with ``recovery = "none"``), and the monitor runs
    the consistency window of ``options`` for the restarts
    (:mod:`attopt.solvers.filters.recovery`)."""
    inflation = np.zeros((STATE_SIZE, STATE_SIZE))
    inflation[:3, :3] = options.recover_sigma**2 * np.eye(3)
    inflation[3:, 3:] = prior.covariance[3:, 3:]
    return TrackMonitor(
        options.max_rejected_epochs,
        None if options.recovery == "none" else inflation,
        options.consistency_window,
        options.consistency_false_alarm,
    )


class GyroStateFilter(SequentialFilter):
    """The state every gyro-aided filter carries: attitude, bias and their ``6 x 6``
    covariance, starting at the first gyro sample with the prior (``[attitude, bias]``),
    and the gyro steps it walks (``node``: the timeline index it has reached).

    ``offsets``, when given, are the transmitters' power offsets carried as augmented
    states (:mod:`attopt.solvers.filters.offsets`): an update works on the joint
    covariance of :meth:`joint` and hands it back to :meth:`absorb`.
    """

    def __init__(
        self,
        gyro: PreparedGyro,
        model: GyroModel,
        prior: Prior,
        options: FilterOptions,
        offsets: OffsetStates | None = None,
    ) -> None:
        self.gyro, self.model, self.options = gyro, model, options
        self.attitude = prior.attitude
        self.bias = np.asarray(prior.bias, dtype=float)
        self.covariance = np.asarray(prior.covariance, dtype=float)
        self.offsets = offsets
        self.node = 0

    def advance(self, transition: Array | None, stop: int) -> None:
        """Move to timeline boundary ``stop`` after a propagation with the error state's
        ``transition``: the offsets' cross-covariance and random walk with it (``None``:
        not formed, there being no offsets)."""
        if self.offsets is not None:
            times = self.gyro.timeline.t
            self.offsets.propagate(transition, float(times[stop] - times[self.node]))
        self.node = stop

    def joint(self, measurement: AttitudeMeasurement) -> tuple[Array, RowOffsets | None]:
        """The covariance an update with ``measurement`` works on and its rows' offsets:
        ``P`` and ``None`` without offsets, else the joint covariance with the offsets of
        the measurement's sources (admitted, or marginalised after their timeout, at the
        filter's time)."""
        if self.offsets is None:
            return self.covariance, None
        time = float(self.gyro.timeline.t[self.node])
        return self.offsets.augment(self.covariance, measurement.sources, measurement.size, time)

    def absorb(self, covariance: Array, increment: Array) -> dict[str, float]:
        """Keep an update's covariance (joint with the offsets: split, and the offsets'
        estimates moved by ``increment``); the counts of the offsets' test against their
        prior (``offset_nis``, ``offset_dof``: ``OffsetStates.prior_test``), none without
        offsets."""
        if self.offsets is None:
            self.covariance = covariance
            return {}
        self.covariance = self.offsets.absorb(covariance, increment)
        statistic, dof = self.offsets.prior_test()
        return {"offset_nis": statistic, "offset_dof": float(dof)}

    def single_frame_view(self, measurement: AttitudeMeasurement) -> AttitudeMeasurement:
        """With offsets, the measurement with its sources' offsets at their prior (each
        row's sigma widened by the prior's, as a start admits them): a single frame that
        assumed known powers would fail its residual test, or pass it wrongly confident."""
        if self.offsets is None or measurement.sources is None:
            return measurement
        return measurement.with_offset_spread(self.offsets.sigma)

    def reset(self, attitude: Rotation, covariance: Array) -> None:
        """Restart at ``attitude`` with ``covariance`` (``6 x 6``), forgetting the offsets."""
        super().reset(attitude, covariance)
        if self.offsets is not None:
            self.offsets.clear()


def propagate_covariance(
    covariance: Array, rates: Array, hold_variance: Array, model: GyroModel, dt: Array
) -> tuple[Array, Array]:
    """``P <- Phi_j P Phi_j^T + Q_j`` over consecutive gyro steps of lengths ``dt`` at the
    estimated ``rates``, and the steps' product ``Phi``.

    ``Phi_j`` is :func:`~attopt.formulations.gyro.error_state_transition`, ``Q_j`` the
    step's :func:`step_noise` (with the gap growth ``hold_variance``).
    """
    noise = step_noise(model, dt, hold_variance)
    if compiled_loops():
        return compiled.covariance_steps(np.ascontiguousarray(covariance), rates, dt, noise)
    return covariance_steps(covariance, rates, dt, noise)


def covariance_steps(
    covariance: Array, rates: Array, dt: Array, noise: Array
) -> tuple[Array, Array]:
    """The numpy reference of :func:`attopt.solvers.filters.compiled.covariance_steps`:
    ``P <- Phi_j P Phi_j^T + Q_j`` over the steps, and the product of the ``Phi_j``."""
    total = np.eye(STATE_SIZE)
    for phi, q in zip(error_state_transition(rates, dt[:, None, None]), noise, strict=True):
        covariance = phi @ covariance @ phi.T + q
        total = phi @ total
    return covariance, total


def step_noise(model: GyroModel, dt: Array, hold_variance: Array) -> Array:
    """Process noise ``(k, 6, 6)`` of ``k`` gyro steps of lengths ``dt`` including the gap
    growth (:meth:`~attopt.formulations.gyro.GyroModel.process_noise` once per length)."""
    if dt.size == 0:
        return np.zeros((0, STATE_SIZE, STATE_SIZE))
    if (dt == dt[0]).all():  # the usual run of whole sampling intervals
        q = np.repeat(_process_noise(model, float(dt[0]))[None], dt.size, axis=0)
    else:
        lengths, index = np.unique(dt, return_inverse=True)
        q = np.stack([_process_noise(model, float(length)) for length in lengths])[index]
    if hold_variance.any():  # a gap: the steps' attitude variance grows
        q[:, [0, 1, 2], [0, 1, 2]] += hold_variance[:, None]
    return q


@lru_cache(maxsize=256)
def _process_noise(model: GyroModel, dt: float) -> Array:
    """:meth:`~attopt.formulations.gyro.GyroModel.process_noise`, once per model and step
    length (read-only: callers copy it)."""
    q = model.process_noise(dt)
    q.flags.writeable = False
    return q


@lru_cache(maxsize=64)
def gate_threshold(probability: float, dof: int) -> float:
    """Chi-square quantile of the innovation gate."""
    return float(chi2.ppf(probability, dof))


def noise_subset(noise: Array, rows: NDArray[np.intp]) -> Array:
    """``R`` restricted to ``rows``: ``(m,)`` variances or an ``(m, m)`` matrix."""
    return noise[rows] if noise.ndim == 1 else noise[np.ix_(rows, rows)]


def log_det_noise(noise: Array) -> float:
    """``log det R`` for ``(m,)`` variances or an ``(m, m)`` matrix."""
    if noise.ndim == 1:
        return float(np.sum(np.log(noise)))
    return float(np.linalg.slogdet(noise)[1])


def solve_noise(noise: Array, x: Array) -> Array:
    """``R^-1 x`` for ``(m,)`` variances (elementwise) or an ``(m, m)`` matrix."""
    if noise.ndim == 1:
        return x / noise.reshape(-1, *([1] * (x.ndim - 1)))
    return np.linalg.solve(noise, x)


def noise_sandwich(gain: Array, noise: Array) -> Array:
    """``K R K^T``."""
    return (gain * noise) @ gain.T if noise.ndim == 1 else gain @ noise @ gain.T


def kalman_gain(
    covariance: Array,
    h: Array,
    noise: Array,
    innovation: Array,
    information: Array | None = None,
) -> tuple[Array, float, Array]:
    """Gain ``K = P H^T S^-1``, ``nu^T S^-1 nu`` and the posterior ``(I - K H) P``,
    ``S = H P H^T + R``, in information form.

    ``P+ = (P^-1 + H^T R^-1 H)^-1``, ``K = P+ H^T R^-1`` and the
    matrix-inversion lemma for the normalised innovation: only ``6 x 6``
    inverses and work linear in the number of rows when ``R`` is given as
    variances (SNRs, unit vectors), however many rows an epoch has.
    ``information``: ``P^-1`` when the caller has it (an iterated update's prior).
    Compiled (:func:`attopt.solvers.filters.update_kernels.information_gain`) for
    variances unless kernels are interpreted; :func:`gain_reference` is the numpy
    reference.
    """
    if information is None:
        information = np.linalg.inv(covariance)
    if noise.ndim == 1 and compiled_loops():
        gain, nis, posterior = update_kernels.information_gain(information, h, noise, innovation)
        return gain, float(nis), posterior
    return gain_reference(information, h, noise, innovation)


def gain_reference(
    information: Array, h: Array, noise: Array, innovation: Array
) -> tuple[Array, float, Array]:
    """The numpy reference of :func:`kalman_gain` from the prior information ``P^-1``
    (any ``R``)."""
    weighted = solve_noise(noise, np.column_stack([h, innovation]))
    r_inv_h, r_inv_nu = weighted[:, :-1], weighted[:, -1]
    posterior = np.linalg.inv(information + h.T @ r_inv_h)
    projected = h.T @ r_inv_nu
    nis = float(innovation @ r_inv_nu - projected @ posterior @ projected)
    return posterior @ r_inv_h.T, nis, posterior


def block_nis(
    innovation: Array,
    factor: Array,
    weight: Array,
    noise: Array,
    blocks: NDArray[np.intp],
) -> tuple[Array, NDArray[np.intp]]:
    """Per row, its block's normalised innovation squared ``nu_b^T S_b^-1 nu_b`` and the
    block's size.

    The innovation covariance is ``S = F^T W F + R`` (``F`` ``(k, m)``: for the
    MEKF ``H^T`` with ``W = P``; for USQUE the sigma deviations with ``W`` the
    covariance weights); only its diagonal blocks are formed, blocks of equal
    size tested together, so the cost is linear in the number of blocks.  NaN where
    ``S`` or the innovation is not finite.  Compiled
    (:func:`attopt.solvers.filters.update_kernels.block_nis`) unless kernels are interpreted
    (:func:`~attopt.formulations.kernels.compiled_loops`); :func:`block_nis_reference` is the
    numpy reference.
    """
    if compiled_loops():
        members = block_structure(blocks).members.members
        return update_kernels.block_nis(innovation, factor, weight, noise, members)
    return block_nis_reference(innovation, factor, weight, noise, blocks)


def block_nis_reference(
    innovation: Array,
    factor: Array,
    weight: Array,
    noise: Array,
    blocks: NDArray[np.intp],
) -> tuple[Array, NDArray[np.intp]]:
    """The numpy reference of :func:`block_nis` (same arguments and results): the blocks
    of each size in one set of array calls."""
    nis_rows = np.full(innovation.shape[0], np.nan)
    size_rows = np.zeros(innovation.shape[0], dtype=np.intp)
    for size, rows in block_structure(blocks).layout:
        nu = innovation[rows]
        columns = factor[:, rows]  # (k, blocks, size)
        weighted = (weight @ columns.reshape(columns.shape[0], -1)).reshape(columns.shape)
        s = np.einsum("kbi,kbj->bij", columns, weighted)  # F^T W F, one matrix product
        if noise.ndim == 1:
            s += noise[rows][:, :, None] * np.eye(int(size))
        else:
            s += noise[rows[:, :, None], rows[:, None, :]]
        nis = np.einsum("bi,bi->b", nu, np.linalg.solve(s, nu[..., None])[..., 0])
        nis_rows[rows] = nis[:, None]
        size_rows[rows] = size
    return nis_rows, size_rows


def gate(
    innovation: Array,
    factor: Array,
    weight: Array,
    noise: Array,
    blocks: NDArray[np.intp],
    probability: float,
) -> NDArray[np.bool_]:
    """Rows whose block's normalised innovation squared (:func:`block_nis`) is within the
    chi-square gate of its size at ``probability`` (1: every row)."""
    keep = np.ones(innovation.shape[0], dtype=bool)
    if probability >= 1.0 or innovation.size == 0:
        return keep
    nis, size = block_nis(innovation, factor, weight, noise, blocks)
    # not (nis <= threshold): a NaN NIS (non-finite S or innovation) is rejected too
    if (size == size[0]).all():  # the usual epoch: blocks of one size
        return nis <= gate_threshold(probability, int(size[0]))
    sizes, index = np.unique(size, return_inverse=True)
    threshold = np.array([gate_threshold(probability, int(n)) for n in sizes])
    return nis <= threshold[index]


def robust_noise(
    noise: Array,
    rows: NDArray[np.intp],
    nis: Array,
    threshold: float | None,
) -> tuple[Array, NDArray[np.bool_]]:
    """``R`` with the blocks of ``rows`` down-weighted by the Huber loss on their whitened
    innovation norms ``sqrt(nis)`` (:func:`block_nis` at the prior), and which rows were.

    The weight ``w = min(1, k / sqrt(nis))`` (:func:`attopt.solvers.robust.huber_weights`)
    divides the rows' noise covariance (the rows and columns of a full ``R`` by
    ``sqrt(w)``): the update of a Huber M-estimate linearised at the prior (Karlgaard and
    Schaub 2007).  ``threshold`` ``None``: ``R`` unchanged.
    """
    down = np.zeros(rows.size, dtype=bool)
    if threshold is None or rows.size == 0:
        return noise, down
    weights = huber_weights(np.sqrt(nis), threshold)
    down = weights < 1.0
    if not down.any():
        return noise, down
    scale = np.ones(noise.shape[0])
    scale[rows[down]] = 1.0 / weights[down]
    if noise.ndim == 1:
        return noise * scale, down
    root = np.sqrt(scale)
    return root[:, None] * noise * root[None, :], down


def huber_noise(
    noise: Array,
    rows: NDArray[np.intp],
    innovation: Array,
    factor: Array,
    weight: Array,
    blocks: NDArray[np.intp],
    options: FilterOptions,
    counts: dict[str, float],
) -> Array:
    """``R`` (all rows) with the used ``rows`` Huber-weighted at the prior
    (:func:`robust_noise` of their :func:`block_nis`), the down-weighted blocks counted in
    ``counts["n_downweighted"]``; ``R`` itself without ``options.huber_threshold``.

    ``innovation``, ``factor`` (``(k, len(rows))``, with its ``weight``, as in
    :func:`block_nis`) and ``blocks`` are those of ``rows``."""
    if options.huber_threshold is None:
        return noise
    nis, _ = block_nis(innovation, factor, weight, noise_subset(noise, rows), blocks)
    weighted, down = robust_noise(noise, rows, nis, options.huber_threshold)
    counts["n_downweighted"] = float(count_blocks(blocks[down]))
    return weighted


def usable_rows(
    measurement: AttitudeMeasurement, predicted: Array, innovation: Array
) -> tuple[NDArray[np.bool_], int, int]:
    """Rows with finite values, predictions ``(N, m)`` and their innovations ``(N, m)``
    (whole blocks); counts of the blocks left out for a NaN value and for an
    unpredictable one."""
    if np.isfinite(measurement.z).all() and np.isfinite(predicted).all():
        if np.isfinite(innovation).all():  # the usual epoch, in the fewest calls
            return np.ones(measurement.z.size, dtype=bool), 0, 0
    finite_z = np.isfinite(measurement.z)
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
    variance = (
        update_kernels.smallest_attitude_variance(posterior)
        if compiled_loops()
        else np.linalg.eigvalsh(posterior[:3, :3])[0]
    )
    smallest = np.sqrt(max(variance, 0.0))
    return 0.5 * float(step[:3] @ step[:3]) <= fraction * smallest


def repair_covariance(p: Array) -> tuple[Array, bool]:
    """Symmetrise ``p``; floor its eigenvalues if it is not positive definite (tested by a
    Cholesky factorisation, compiled unless kernels are interpreted:
    :func:`attopt.solvers.filters.update_kernels.symmetric_positive`)."""
    if compiled_loops():
        p, positive = update_kernels.symmetric_positive(p)
    else:
        p = 0.5 * (p + p.T)
        try:
            np.linalg.cholesky(p)
            positive = True
        except np.linalg.LinAlgError:
            positive = False
    if positive:
        return p, False
    values, vectors = np.linalg.eigh(p)
    floor = max(values.max(), 0.0) * 1e-12 + 1e-300
    return (vectors * np.maximum(values, floor)) @ vectors.T, True


def propagate_attitude(attitude: Rotation, rates: Array, dt: ArrayLike) -> Rotation:
    """Carry attitudes over consecutive steps at constant rates (Liu et al. 2023 eq. 25).

    ``rates`` is ``(k, 3)`` for one attitude or ``(K, k, 3)`` for a stack of
    ``K``; ``dt`` the step (s) or ``(k,)`` steps.  Step ``j`` applies the increment
    ``exp(-[w_j x] dt_j)`` of :func:`attopt.formulations.gyro.attitude_increment`
    (:func:`propagate_quaternion`).
    """
    if np.shape(rates)[-2] == 0:
        return attitude
    return Rotation.from_quat(propagate_quaternion(attitude.as_quat(), rates, dt))


def propagate_quaternion(quaternion: Array, rates: Array, dt: ArrayLike) -> Array:
    """:func:`propagate_attitude` on scalar-last quaternions (``(4,)`` or ``(K, 4)``), as
    quaternion products (:mod:`attopt.formulations.quaternion_algebra`, for speed: one
    ``4 x 4`` matrix product per step, later steps on the left)."""
    rates = np.asarray(rates, dtype=float)
    dt = np.asarray(dt, dtype=float)
    if compiled_loops():
        quaternions = np.atleast_2d(np.asarray(quaternion, dtype=float))
        stacked = np.broadcast_to(rates, (quaternions.shape[0], *rates.shape[-2:]))
        steps = np.broadcast_to(dt, rates.shape[-2:-1])
        out = compiled.quaternion_steps(quaternions, np.ascontiguousarray(stacked), steps.copy())
        return out.reshape(np.shape(quaternion))
    return quaternion_steps(quaternion, rates, dt)


def quaternion_steps(quaternion: Array, rates: Array, dt: Array) -> Array:
    """The numpy reference of :func:`attopt.solvers.filters.compiled.quaternion_steps`
    (:func:`propagate_quaternion`'s arguments)."""
    steps = left_matrices(from_rotation_vector(-rates * (dt[..., None] if dt.ndim else dt)))
    total = np.asarray(quaternion, dtype=float)[..., None]
    for j in range(rates.shape[-2]):
        total = steps[..., j, :, :] @ total
    return total[..., 0]
