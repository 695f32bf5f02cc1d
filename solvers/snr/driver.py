"""The part every SNR solver shares: read the snapshot, validate, warm-start, estimate.

A solver (:class:`SnrSolver` subclass) is a
:class:`~attopt.solvers.estimator.SnapshotEstimator` that accepts
:class:`~attopt.formulations.snr_measurement.SnrMeasurement` s, one per
snapshot (its :attr:`~attopt.formulations.snr_measurement.SnrMeasurement.epoch`
is the :class:`~attopt.formulations.snr_problem.SnrEpoch` solved; the
objective, Gaussian or threshold-truncated, is the solver's, not the
measurement's ``truncated`` flag).  It supplies its validation rule
(:meth:`SnrSolver.issue`, :func:`attopt.formulations.snr_problem.epoch_issue`)
and :meth:`SnrSolver.estimate_epoch` for one validated epoch with an optional
a-priori attitude.  :func:`attopt.solvers.snapshot_sequence.solve_in_sequence`
turns that into the project's result types:

* ``solve(snapshot, prior)`` solves one epoch and raises the specific
  exception of bad input (:class:`~attopt.formulations.errors.InvalidObservationError`,
  :class:`~attopt.formulations.errors.UnobservableError`) or of a failed solve
  (:class:`~attopt.formulations.errors.ConvergenceError`, with the solver status as
  message);
* :meth:`SnrSolver.solve_sequence` solves consecutive epochs, flags invalid or
  failed ones with the reason (never an attitude) and, with
  :attr:`SnrSolver.warm_start`, starts each epoch from the most recent valid
  estimate (Liu et al. 2023 sec. 5.1 solves one epoch per second of a slowly moving
  Earth-pointing attitude);
* :meth:`SnrSolver.solve_epochs` is the same on the epochs themselves.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import ClassVar

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.passes import Prior
from attopt.formulations.snapshot import Snapshot
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.formulations.snr_problem import EpochIssue, SnrEpoch, epoch_issue
from attopt.solvers.estimator import Estimator, SnapshotEstimator
from attopt.solvers.results import Track
from attopt.solvers.snapshot_sequence import (
    MISMATCH_FALSE_ALARM,
    EpochEstimate,
    WarmStart,
    mismatched,
    residual_test,
    solve_in_sequence,
)
from attopt.solvers.snr.exclusion import Tested, exclude_one_transmitter
from attopt.solvers.snr.fit import (
    SELECTION_BIAS_DIAGNOSTICS,
    Residuals,
    common_offsets,
    least_squares_shifts,
    model_at,
    standardised_residuals,
    threshold_bias,
    widened,
)

DEFAULT_FAULT_EXCLUSION = True
"""Whether the SNR solvers exclude a faulty transmitter by default (``docs/filters.md``)."""


def snr_epoch(snapshot: Snapshot) -> SnrEpoch | EpochIssue:
    """The epoch of a snapshot's one SNR measurement, or why it has none."""
    measurements = snapshot.of_type(SnrMeasurement)
    if len(measurements) != 1:
        return EpochIssue(
            f"an SNR snapshot holds one SnrMeasurement, not {len(measurements)}",
            InvalidObservationError,
        )
    return measurements[0].epoch


def snr_epochs(
    estimator: Estimator, snapshots: Sequence[Snapshot | None]
) -> list[SnrEpoch | EpochIssue | None]:
    """Each snapshot's :func:`snr_epoch` (``None``: no measurement), after ``estimator``
    checked the snapshot's measurement types."""
    epochs: list[SnrEpoch | EpochIssue | None] = []
    for snapshot in snapshots:
        if snapshot is not None:
            estimator.check_types(snapshot.types)
        epochs.append(None if snapshot is None else snr_epoch(snapshot))
    return epochs


def start_attitude(prior: Rotation | Prior | None) -> Rotation | None:
    """The attitude of a prior (the SNR solvers use no prior covariance)."""
    return prior.attitude if isinstance(prior, Prior) else prior


@dataclass(frozen=True, repr=False)
class SnrSolver(SnapshotEstimator):
    """A solver of the SNR attitude problem (Liu et al. 2023 secs. 3.2-3.3).

    Subclasses set ``name``, ``description`` and :attr:`diagnostic_names`
    and implement :meth:`estimate_epoch`.

    Attributes:
        warm_start: how a sequence starts its epochs
            (:class:`~attopt.solvers.snapshot_sequence.WarmStart`).
        mismatch_false_alarm: the residual test's false-alarm probability
            (:func:`~attopt.solvers.snapshot_sequence.residual_test`: an estimate whose
            eq. 19 loss is beyond the chi-square quantile of ``m - 3`` degrees of freedom
            is flagged ``model mismatch``, :class:`~attopt.formulations.errors.ModelMismatchError`;
            the truncated likelihood's residuals are standardised by the truncated
            moments, :func:`~attopt.solvers.snr.fit.truncated_chi_square`; 0: no test).
        fault_exclusion: an epoch that fails the residual test is solved again without
            the one transmitter whose exclusion restores the fit, valid if that is the
            only one (:mod:`attopt.solvers.snr.exclusion`, RAIM-style fault detection and
            exclusion); off: the epoch is flagged.
        selection_bias: an estimate's covariance is widened by the reception
            threshold's selection bias propagated through the method's own gain
            (:meth:`SnrSolver.attitude_bias`; ``P + d d^T``,
            :func:`~attopt.solvers.snr.fit.widened`), which eq. 19 does not model; off:
            the method's covariance alone (for the least squares eq. 22, Liu et al.
            2023's). The truncated likelihood models the threshold and is never
            widened.
        power_offset_mean_db, power_offset_sigma_db: the distribution of the
            transmitters' unknown power offsets from the epoch's ``10 lg P0`` (dB): every
            epoch is solved with ``P0`` raised by the mean and each SNR's sigma widened
            to ``sqrt(sigma^2 + s^2)`` (:meth:`SnrSolver.with_power_prior`).  Exact for
            offsets drawn independently per transmitter from a normal distribution, one
            SNR per transmitter and epoch: the offset is then another independent
            Gaussian error of the SNR (Liu et al. 2023 eq. 13's ``10 lg P0`` known only in
            distribution).  Both 0 (default): the powers are known.
        power_offset_common_sigma_db: the part of the power offsets that every
            transmitter an antenna hears in an epoch shares (dB, standard deviation; 0,
            the default: none).  Offsets independent from row to row average out over an
            epoch's ``m`` SNRs; a shared part does not, so the estimate's covariance is
            widened by it through the method's own gain: ``P + sum_a u_a u_a^T``, ``u_a``
            the attitude error an offset of ``s_c`` on antenna ``a``'s SNRs causes
            (:meth:`SnrSolver.attitude_shifts`, :func:`~attopt.solvers.snr.fit.common_offsets`),
            the covariance of the estimate when the SNR errors' covariance is
            ``diag(sigma_k^2) + s_c^2 sum_a 1_a 1_a^T`` (to first order).  The estimate
            itself is unchanged.
    """

    warm_start: WarmStart = field(default_factory=WarmStart)
    mismatch_false_alarm: float = MISMATCH_FALSE_ALARM
    fault_exclusion: bool = DEFAULT_FAULT_EXCLUSION
    selection_bias: bool = True
    power_offset_mean_db: float = 0.0
    power_offset_sigma_db: float = 0.0
    power_offset_common_sigma_db: float = 0.0
    accepts: ClassVar[tuple[type[AttitudeMeasurement], ...]] = (SnrMeasurement,)
    diagnostic_names: ClassVar[tuple[str, ...]]

    def __post_init__(self) -> None:
        if not (
            np.isfinite(self.power_offset_mean_db)
            and self.power_offset_sigma_db >= 0.0
            and self.power_offset_common_sigma_db >= 0.0
        ):
            raise ValueError(
                "power_offset_mean_db must be finite, power_offset_sigma_db and "
                "power_offset_common_sigma_db non-negative"
            )

    def with_power_prior(self, problem: SnrEpoch) -> SnrEpoch:
        """``problem`` with the transmitters' power prior (class docstring,
        :meth:`~attopt.formulations.snr_problem.SnrEpoch.with_power_prior`): ``10 lg P0 +
        mean`` and ``sigma_k = sqrt(sigma_k^2 + s^2)``; unchanged without a prior.

        Example::

            >>> from attopt import CosinePowerPattern, LinkBudget, SnrEpoch
            >>> from attopt.solvers.snr.nlp import NlpSolver
            >>> helix = CosinePowerPattern(peak_gain=14.46, exponent=6.0, min_gain_dbi=4.0)
            >>> epoch = SnrEpoch.from_ranges(
            ...     [12.0, 10.0], [[0, 0, 1.0], [0.1, 0, 0.995]], [0, 0], [[0.0, 0.0, 1.0]],
            ...     [1.2e6, 1.5e6], helix, LinkBudget(),
            ... )
            >>> solver = NlpSolver(power_offset_mean_db=0.5, power_offset_sigma_db=0.75)
            >>> solver.with_power_prior(epoch).sigma_db.tolist()  # sqrt(1 + 0.75^2)
            [1.25, 1.25]
        """
        return problem.with_power_prior(self.power_offset_mean_db, self.power_offset_sigma_db)

    def issue(self, problem: SnrEpoch) -> EpochIssue | None:
        """Why ``problem`` cannot be solved by this method, or ``None`` (the one-step rule)."""
        return epoch_issue(problem)

    @abstractmethod
    def estimate_epoch(self, problem: SnrEpoch, prior: Rotation | None) -> EpochEstimate:
        """Estimate one validated epoch; ``prior`` is an a-priori attitude or ``None``."""

    @property
    def models_the_threshold(self) -> bool:
        """Whether the method's objective models the reception threshold (then its
        covariance is not widened by :attr:`selection_bias`)."""
        return False

    def attitude_shifts(
        self,
        problem: SnrEpoch,
        estimate: EpochEstimate,
        errors: NDArray[np.float64],
        jacobian: NDArray[np.float64],
    ) -> NDArray[np.float64]:
        """``(k, 3)``: the attitude error that each row of the SNR errors ``errors``
        (``(k, m)`` or ``(m,)``, dB) causes in this method's estimate: through the
        least-squares gain (:func:`~attopt.solvers.snr.fit.least_squares_shifts`;
        ``jacobian`` the SNRs' at the estimate, :func:`~attopt.solvers.snr.fit.model_at`),
        for the least-squares methods."""
        return least_squares_shifts(jacobian, problem.sigma_db, estimate.covariance, errors)

    def attitude_bias(
        self,
        problem: SnrEpoch,
        estimate: EpochEstimate,
        predicted: NDArray[np.float64],
        jacobian: NDArray[np.float64],
    ) -> NDArray[np.float64]:
        """The attitude bias ``d`` that the reception threshold's selection of the SNRs
        (:func:`~attopt.solvers.snr.fit.threshold_bias` at the predicted SNRs) causes in
        this method's estimate (:meth:`attitude_shifts`); 0 without a selection."""
        bias = threshold_bias(problem, predicted)
        if not np.any(bias):
            return np.zeros(3)
        return self.attitude_shifts(problem, estimate, bias, jacobian)[0]

    def residual_chi_square(self, problem: SnrEpoch, estimate: EpochEstimate) -> float:
        """The residuals' chi-square at ``estimate`` (``m - 3`` degrees of freedom):
        twice its eq. 19 loss, ``sum_k (y_k - f_k)^2 / sigma_k^2``."""
        return 2.0 * estimate.loss

    def residuals(self, problem: SnrEpoch, estimate: EpochEstimate) -> Residuals:
        """The standardised residuals whose squares :meth:`residual_chi_square` sums
        (eq. 19's) and their whitened Jacobian
        (:func:`~attopt.solvers.snr.fit.standardised_residuals`)."""
        return standardised_residuals(problem, estimate.attitude)

    def tested(self, problem: SnrEpoch, prior: Rotation | None) -> Tested:
        """:meth:`estimate_epoch` and its residual test's reason (``None``: passed or not
        solved), with ``n_excluded = 0`` in the diagnostics of a solved epoch."""
        estimate = self.estimate_epoch(problem, prior)
        if estimate.failure is not None or estimate.attitude is None:
            return estimate, None
        diagnostics = {**estimate.diagnostics, "n_excluded": 0.0}
        covariance = estimate.covariance
        selection = self.selection_bias and not self.models_the_threshold
        if selection or self.power_offset_common_sigma_db:
            predicted, jacobian = model_at(problem, estimate.attitude)
        if selection:
            bias = self.attitude_bias(problem, estimate, predicted, jacobian)
            diagnostics.update(zip(SELECTION_BIAS_DIAGNOSTICS, bias, strict=True))
            covariance = widened(covariance, bias)
        if self.power_offset_common_sigma_db:
            offsets = common_offsets(problem, self.power_offset_common_sigma_db)
            shifts = self.attitude_shifts(problem, estimate, offsets, jacobian)
            covariance = widened(covariance, shifts)
        estimate = replace(estimate, covariance=covariance, diagnostics=diagnostics)
        chi_square = self.residual_chi_square(problem, estimate)
        return estimate, residual_test(chi_square, problem.m - 3, self.mismatch_false_alarm)

    def tested_estimate(self, problem: SnrEpoch, prior: Rotation | None) -> EpochEstimate:
        """:meth:`estimate_epoch`, unchanged when its residuals pass the test; else, with
        :attr:`fault_exclusion`, repaired by excluding one transmitter or flagged
        (:func:`~attopt.solvers.snr.exclusion.exclude_one_transmitter`), without it
        flagged ``model mismatch`` (class docstring)."""
        estimate, reason = self.tested(problem, prior)
        if reason is None or not self.fault_exclusion:
            return mismatched(estimate, reason)
        return exclude_one_transmitter(
            problem,
            estimate,
            reason,
            self.residuals(problem, estimate),
            lambda epoch: self.issue(epoch) is None,
            lambda epoch: self.tested(epoch, prior),
        )

    def solve_sequence(
        self, snapshots: Sequence[Snapshot | None], prior: Rotation | Prior | None = None
    ) -> Track:
        """Consecutive epochs (module docstring); ``prior`` is the first epoch's a-priori
        attitude (of a :class:`~attopt.formulations.passes.Prior`, its attitude)."""
        return self.solve_epochs(snr_epochs(self, snapshots), start_attitude(prior))

    def solve_epochs(
        self, problems: Sequence[SnrEpoch | EpochIssue | None], prior: Rotation | None = None
    ) -> Track:
        """:meth:`solve_sequence` on the epochs themselves (``None``: no measurement), each
        with the transmitters' power prior (:meth:`with_power_prior`)."""
        problems = [self.with_power_prior(p) if isinstance(p, SnrEpoch) else p for p in problems]
        return solve_in_sequence(
            self.name,
            problems,
            prior,
            self.warm_start,
            self.diagnostic_names,
            self.issue,
            self.tested_estimate,
        )
