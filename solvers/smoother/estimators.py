"""The factor-graph smoothers as registry estimators: ``fg_online``, ``fg_batch`` and
``fg_batch_offsets``.

Each takes a :class:`~attopt.formulations.passes.Pass` with a gyro record (epochs
anywhere in it) and a prior (an attitude-only prior gets zero bias with the gyro
model's initial bias sigma), and returns a filter's
:class:`~attopt.solvers.results.Track` (state ``("attitude", "bias")``) with the
smoother's report.

* ``fg_online`` is the causal fixed-lag smoother of
  :mod:`attopt.solvers.smoother.online`, run by the sequential loop
  (:func:`attopt.solvers.sequential.run_filter`) like the filters;
* ``fg_batch`` is the whole-pass maximum a posteriori estimate
  (:mod:`attopt.solvers.smoother.batch`), started from the online smoother's track
  if that was run on the same pass, else from the RTS pass's (``starts_from``);
* ``fg_batch_offsets`` is ``fg_batch`` with one power-offset variable per
  transmitter (the measurements' ``sources``: SNRs).

Example::

    >>> import numpy as np
    >>> import attopt
    >>> record = attopt.GyroRecord(np.arange(101) / 10.0, np.zeros((100, 3)), attopt.MEMS_GYRO)
    >>> still = attopt.Prior(attopt.attitude_from_euler321(0.1, 0.0, 0.0), 1e-4 * np.eye(3))
    >>> directions = [[1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    >>> pass_ = attopt.Pass.from_vectors(
    ...     np.arange(0.0, 10.0, 0.5), still.attitude.apply(directions)[None].repeat(20, 0),
    ...     directions, 2e-3, record, still,
    ... )
    >>> runs = attopt.run_estimators(pass_, ["fg_online", "fg_batch"])
    >>> runs["fg_batch"].track.report.initialisation  # started from fg_online's track
    'given'
    >>> bool(runs["fg_batch"].track.valid.all())
    True
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from attopt.formulations.attitude_measurement import AttitudeMeasurement, ReferencedMeasurement
from attopt.formulations.passes import Pass
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.solvers.estimator import PassEstimator
from attopt.solvers.filters.common import FilterOptions, gyro_pass
from attopt.solvers.filters.offsets import OFFSET_PRIOR_SIGMA_DB
from attopt.solvers.filters.recovery import SingleFrameStart
from attopt.solvers.results import Track
from attopt.solvers.sequential import TrackMonitor, run_filter
from attopt.solvers.smoother.batch import Stopwatch, batch_track, gyro_faults
from attopt.solvers.smoother.gyro_factors import check_model
from attopt.solvers.smoother.initial import (
    INITIALISATIONS,
    filter_start,
    given_start,
    node_values,
)
from attopt.solvers.smoother.marginals import MarginalOptions, problem_marginals
from attopt.solvers.smoother.online import OnlineFilter, OnlineOptions
from attopt.solvers.smoother.optimiser import LevenbergMarquardtResult, levenberg_marquardt
from attopt.solvers.smoother.optimiser_params import LevenbergMarquardtParams
from attopt.solvers.smoother.problem import GraphOptions, SmootherProblem, build_problem


@dataclass(frozen=True, repr=False)
class OnlineSmoother(PassEstimator):
    """The online (causal) factor-graph smoother (:mod:`attopt.solvers.smoother.online`).

    Attributes:
        online: the iSAM2 window (lag, relinearisation).
        filter: gating, gyro-gap and validity rules shared with the filters;
            ``max_update_iterations`` bounds the iSAM2 updates per epoch.
            Lost tracks are flagged, never re-acquired (no inflation); with
            ``recovery = "restart"`` the first measured node is linearised at its single
            frame (:class:`~attopt.solvers.filters.recovery.SingleFrameStart`).
    """

    online: OnlineOptions = field(default_factory=OnlineOptions)
    filter: FilterOptions = field(default_factory=FilterOptions)

    name: ClassVar[str] = "fg_online"
    description: ClassVar[str] = (
        "causal fixed-lag factor-graph smoother over attitude and gyro bias (GTSAM iSAM2)"
    )
    accepts: ClassVar[tuple[type[AttitudeMeasurement], ...]] = (AttitudeMeasurement,)

    def __post_init__(self) -> None:
        if self.filter.max_update_iterations < 1:
            raise ValueError("need filter.max_update_iterations >= 1")

    def solve(self, pass_: Pass, initial: Track | None = None) -> Track:
        """The causal track with its :class:`~attopt.solvers.smoother.online.OnlineReport`
        (``initial`` unused).

        Its ``loss`` (diagnostic ``nis``) is the epoch's normalised innovation
        squared against the predicted covariance, as the MEKF's; diagnostics
        ``n_used``, ``n_gated``, ``n_nan``, ``n_unpredictable`` count
        observation blocks, ``update_iterations`` the iSAM2 updates of the epoch.
        """
        inputs = gyro_pass(pass_, self, self.filter)
        online = OnlineFilter(
            inputs.gyro, inputs.model, inputs.prior, inputs.t, self.online, self.filter
        )
        track = run_filter(
            online,
            inputs.t,
            inputs.measurements,
            TrackMonitor(self.filter.max_rejected_epochs),
            self.filter,
            self.name,
            SingleFrameStart(self.filter),
        )
        return online.report(track)


@dataclass(frozen=True, repr=False)
class BatchSmoother(PassEstimator):
    """The whole-pass factor-graph smoother (:mod:`attopt.solvers.smoother.batch`).

    Attributes:
        graph: the problem's model: Huber loss, bias relinearisation
            (:class:`~attopt.solvers.smoother.problem.GraphOptions`).
        optimiser: Levenberg-Marquardt's stopping rules and damping
            (:class:`~attopt.solvers.smoother.optimiser_params.LevenbergMarquardtParams`).
        noise_updates: times ``R`` is re-evaluated at the solution and the
            problem re-solved (attitude-dependent ``R``: truncated SNRs).
        marginals: joint or block-diagonal marginals
            (:class:`~attopt.solvers.smoother.marginals.MarginalOptions`).
        filter: gating, gyro-gap and validity rules shared with the filters (and
            the options of the MEKF it starts from when given no start).
        flag_unconverged: flag every epoch invalid when the optimiser did not converge.
        initialisation: the start when none is given
            (:func:`~attopt.solvers.smoother.initial.filter_start`): ``"mekf"``
            (the MEKF and its RTS pass) or ``"gyro"`` (gyro integration from the prior).
        gyro_exclusions: rounds of the gyro fault test at the solution
            (:func:`~attopt.solvers.smoother.batch.gyro_faults`): the interval whose AHRS
            factor fails its chi-square test worst is removed, with the rest of its
            stretch between measured nodes, the pass split there and the problem
            re-solved; the epochs after the removed intervals are flagged
            ``inconsistent`` (a manoeuvre or turn the gyro record misses); 0 turns it off.
        max_variance_factor: a pass whose residuals fail the whole-pass chi-square
            test by at most this variance factor has its covariances scaled by it
            (:func:`~attopt.solvers.smoother.batch.variance_factor`; 1: never).  Measured
            on a 90 s ``adsb-snr`` pass with 2 dB power offsets: 1.3 with the offsets
            modelled, 5.6 without.
    """

    graph: GraphOptions = field(default_factory=GraphOptions)
    optimiser: LevenbergMarquardtParams = field(default_factory=LevenbergMarquardtParams)
    noise_updates: int = 0
    marginals: MarginalOptions = field(default_factory=MarginalOptions)
    filter: FilterOptions = field(default_factory=FilterOptions)
    flag_unconverged: bool = True
    initialisation: str = "mekf"
    gyro_exclusions: int = 10
    max_variance_factor: float = 2.0

    name: ClassVar[str] = "fg_batch"
    description: ClassVar[str] = (
        "whole-pass factor-graph smoother over attitude and gyro bias (GTSAM AHRS and "
        "bias random-walk factors, Liu et al. 2023 eq. 24; Levenberg-Marquardt)"
    )
    accepts: ClassVar[tuple[type[AttitudeMeasurement], ...]] = (AttitudeMeasurement,)
    starts_from: ClassVar[tuple[str, ...]] = ("fg_online", "rts")

    def __post_init__(self) -> None:
        if self.initialisation not in INITIALISATIONS:
            raise ValueError(f"initialisation must be one of {INITIALISATIONS}")
        if self.noise_updates < 0:
            raise ValueError("need noise_updates >= 0")
        if self.gyro_exclusions < 0:
            raise ValueError("need gyro_exclusions >= 0")
        if not self.max_variance_factor >= 1.0:
            raise ValueError("need max_variance_factor >= 1")

    def modelled_offsets(self) -> float | None:
        """Prior sigma of the transmitter offsets the problem models (``None``: none)."""
        return None

    def offsets_from_start(self, given: bool) -> bool:
        """Whether the factors get the offsets' columns at the start (``given``: the start
        is a track passed as ``initial``); without offsets, never."""
        return False

    def _resolved(
        self, problem: SmootherProblem, outcome: LevenbergMarquardtResult
    ) -> LevenbergMarquardtResult:
        """Levenberg-Marquardt on ``problem`` (changed since) from ``outcome``'s estimate."""
        return levenberg_marquardt(
            problem, outcome.attitudes, outcome.bias, outcome.offsets, self.optimiser
        )

    def solve(self, pass_: Pass, initial: Track | None = None) -> Track:
        """The smoothed track with its :class:`~attopt.solvers.smoother.batch.SmootherReport`
        (:func:`~attopt.solvers.smoother.batch.batch_track`).

        ``initial``: another estimator's track on the pass's epochs to start from
        (else the start of ``initialisation``).

        Raises:
            InvalidObservationError: no gyro record or prior, a gyro model without
                noise, ``initial`` on other epochs, or offsets modelled and no
                measurement with sources.
            UnsupportedMeasurementError: a measurement type it does not accept.
        """
        clock = Stopwatch()
        with clock.stage("initialisation"):
            inputs = gyro_pass(pass_, self, self.filter)
            check_model(inputs.model)
            start = (
                filter_start(pass_, self.initialisation, self.filter)
                if initial is None
                else given_start(initial, pass_)
            )
            values = node_values(start, inputs)
        with clock.stage("factors"):
            problem = build_problem(
                inputs, values, self.graph, self.filter, self.modelled_offsets()
            )
        with clock.stage("optimisation"):
            offsets = np.zeros(problem.n_offsets)
            from_start = self.offsets_from_start(given=initial is not None)
            if from_start:
                problem.linearise_offsets(values.attitudes, offsets)
            outcome = levenberg_marquardt(
                problem, values.attitudes, values.bias, offsets, self.optimiser
            )
            for _ in range(self.noise_updates):
                problem.update_noise(outcome.attitudes, outcome.offsets)
                outcome = outcome.then(self._resolved(problem, outcome))
            for _ in range(self.gyro_exclusions):
                faults = gyro_faults(problem, outcome, self.filter.consistency_false_alarm)
                if not faults.size:
                    break
                problem.exclude_intervals(faults, outcome.attitudes)
                outcome = outcome.then(self._resolved(problem, outcome))
        with clock.stage("marginals"):
            stepped = any(accepted for *_, accepted in outcome.history)
            held = outcome.system
            if problem.n_offsets and not (from_start or stepped):  # no offsets' columns yet
                problem.linearise_offsets(outcome.attitudes, outcome.offsets)
                held = None  # the factors changed since the optimiser linearised them
            marginals = problem_marginals(problem, outcome.values, self.marginals, held)
        return batch_track(
            self.name,
            inputs,
            problem,
            outcome,
            marginals,
            self.filter,
            self.flag_unconverged,
            self.noise_updates,
            start.label,
            clock,
            self.max_variance_factor,
        )


@dataclass(frozen=True, repr=False)
class OffsetBatchSmoother(BatchSmoother):
    """:class:`BatchSmoother` with one additive offset per transmitter (the measurements'
    ``sources``: an aircraft's power offset, dB) shared by every epoch it is seen in,
    with prior ``N(0, offset_sigma^2)`` (:mod:`attopt.solvers.smoother.problem`).

    It accepts the measurements that carry ``sources``: SNRs
    (:class:`~attopt.formulations.snr_measurement.SnrMeasurement`), also re-expressed
    for another frame (:class:`~attopt.formulations.attitude_measurement.ReferencedMeasurement`);
    a pass in which none has sources raises ``InvalidObservationError``.

    Its start.  A start that ignores the offsets is biased by them: its covariance
    gates, or its attitudes leave outside the antennas' main lobes, much of what the
    smoother could use.  So it starts from no other estimator's track on its own
    (``starts_from`` is empty), and a track given as ``initial`` is taken to allow for
    the offsets, for example single-frame solutions whose SNRs are widened by the
    offsets' spread (:func:`~attopt.solvers.smoother.initial.single_frame_initial`;
    ``adsb-snr`` gives the NLP's): the factors are linearised with the offsets'
    columns from the first step.  Without ``initial`` it starts from its own MEKF and
    RTS pass, which ignore the offsets, and the factors gain the columns at the first
    accepted step (with them from the start it was measured not to converge from that
    start).  Measured on 300 s of ``adsb-snr`` with 2 dB offsets (MEMS gyro, seed 0):
    from the NLP, 5 iterations, valid at every epoch, 0.31 deg RMS, mean NEES 2.3;
    from its own start, 22 iterations, valid at 76 %, 0.88 deg (docs/smoother.md).

    Attributes:
        offset_sigma: prior standard deviation of each offset (dB).
    """

    offset_sigma: float = OFFSET_PRIOR_SIGMA_DB

    name: ClassVar[str] = "fg_batch_offsets"
    starts_from: ClassVar[tuple[str, ...]] = ()
    description: ClassVar[str] = (
        "whole-pass factor-graph smoother with one power offset per transmitter "
        "(Liu et al. 2023 eq. 13's 10 lg P0 per aircraft)"
    )
    accepts: ClassVar[tuple[type[AttitudeMeasurement], ...]] = (
        SnrMeasurement,
        ReferencedMeasurement,
    )

    def __post_init__(self) -> None:
        super().__post_init__()
        if not self.offset_sigma > 0:
            raise ValueError("offset_sigma must be positive")

    def modelled_offsets(self) -> float | None:
        return self.offset_sigma

    def offsets_from_start(self, given: bool) -> bool:
        """A given start is taken to allow for the offsets (class docstring)."""
        return given
