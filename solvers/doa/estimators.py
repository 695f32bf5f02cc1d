"""Yang et al. 2014's estimators as registry estimators: ``ekf_yang2014``, ``rts_yang2014``,
``bls_yang2014``.

Each takes a :class:`~attopt.formulations.passes.Pass` with uniformly spaced
epochs, the :class:`~attopt.formulations.passes.RigidBody` dynamics and a
:class:`~attopt.formulations.passes.Prior` with a rate (``Prior(attitude,
covariance of [attitude, rate], rate=...)``, at epoch 0), no gyro (their ``motion`` is
``"dynamics"``), and returns a
:class:`~attopt.solvers.results.Track` with state ``("rate", "attitude")``:
``rate`` the ``omega_bi`` estimates and ``state_covariance`` that of
``[delta_omega, delta]``.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import ClassVar, Literal

import numpy as np
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import AttitudeMeasurement, VectorMeasurement
from attopt.formulations.errors import ConvergenceError, InvalidObservationError
from attopt.formulations.passes import Pass
from attopt.solvers.doa.batch_ls import BatchLsOptions, batch_least_squares
from attopt.solvers.doa.ekf import (
    EKF_FAULTS,
    PROCESS_NOISE,
    ROBUST_CHECK,
    DoaEkfFilter,
    EkfDynamics,
    ekf_dynamics,
    ekf_monitor,
    ekf_prior,
    run_vectors,
)
from attopt.solvers.doa.vector_slots import unit_vectors_only, vector_arrays, vector_slots
from attopt.solvers.estimator import Motion, PassEstimator
from attopt.solvers.filters.common import FilterOptions
from attopt.solvers.filters.rts import rts_smooth
from attopt.solvers.results import Track
from attopt.solvers.sequential import run_filter, stored_rotations
from attopt.solvers.start_hypotheses import (
    GROUPS,
    StartCheck,
    checked,
    start_attitudes,
    unchecked,
)


def _same_epochs(initial: Track, pass_: Pass) -> None:
    if len(initial) != len(pass_):
        raise InvalidObservationError(
            f"the track to start from has {len(initial)} epochs, the pass {len(pass_)}"
        )


@dataclass(frozen=True, repr=False)
class DoaEkf(PassEstimator):
    """The EKF on rigid-body dynamics (:mod:`attopt.solvers.doa.ekf`; Yang et al. 2014 sec. 5).

    Attributes:
        process_noise: ``q`` of ``Q = q E_6`` per step (sec. 5.2).
        filter: fault handling: by default no gate (as in the paper) and no
            attitude-sigma limit; with a gate, the lost-track monitor
            re-acquires as the gyro filters do.
        compiled: run the epochs in CasADi where that applies (unit vectors
            with sigmas and no gate), else the Python loop.
        start_hypotheses: the rotation group whose turns of the prior's attitude the
            filter also starts from, to check that the reported run (the prior's) has
            settled where the measurements say (:mod:`attopt.solvers.start_hypotheses`:
            ``"T"``, ``"O"``, ``"I"``, or ``"none"`` for no check). Epochs it fails are
            flagged ``converging``; the runs are the track's ``report``
            (:class:`~attopt.solvers.start_hypotheses.StartCheck`).
        robust_check: the check also compares with the run from the prior's start with
            Huber-weighted updates (threshold
            :data:`~attopt.solvers.doa.ekf.ROBUST_CHECK`): epochs where it lies outside the
            reported covariance are flagged ``inconsistent`` (an outlier the Gaussian
            update absorbed).  Not with a ``filter`` that has its own ``huber_threshold``.
    """

    process_noise: float = PROCESS_NOISE
    filter: FilterOptions = EKF_FAULTS
    compiled: bool = True
    start_hypotheses: Literal["none", "T", "O", "I"] = "O"
    robust_check: bool = True

    def __post_init__(self) -> None:
        if self.start_hypotheses not in GROUPS:
            raise ValueError(
                f"start_hypotheses must be one of {GROUPS}, not {self.start_hypotheses!r}"
            )

    name: ClassVar[str] = "ekf_yang2014"
    description: ClassVar[str] = (
        "EKF on Euler's equation with wheels, no gyro (Yang et al. 2014 sec. 5, eqs. 23-33)"
    )
    accepts: ClassVar[tuple[type[AttitudeMeasurement], ...]] = (AttitudeMeasurement,)
    motion: ClassVar[Motion] = "dynamics"

    def solve(self, pass_: Pass, initial: Track | None = None) -> Track:
        """The filtered track with its history, checked against the other starts
        (``initial`` unused).

        Raises:
            InvalidObservationError: no dynamics, no rate prior, epochs not uniform.
            ConvergenceError: an estimated rate of the prior's own run turns more than
                :data:`~attopt.solvers.doa.ekf.MAX_STEP_ANGLE` per step (another start's
                run that does is left out of the check).
        """
        self.check_types(pass_.types())
        dynamics = ekf_dynamics(pass_)
        prior = ekf_prior(pass_.prior)
        attitude, rate, covariance = prior
        gated = self.filter.gate_probability < 1.0
        vectors = None
        if self.compiled and not gated and unit_vectors_only(pass_.snapshots):
            vectors = vector_arrays(*vector_slots(pass_.snapshots))
        starts = start_attitudes(attitude, self.start_hypotheses)
        runs = [self._run(pass_, dynamics, prior, vectors)]
        for start in starts[1:]:
            try:
                runs.append(self._run(pass_, dynamics, (start, rate, covariance), vectors))
            except ConvergenceError:
                continue
        options = self.filter
        robust = None
        if self.robust_check and options.huber_threshold is None:
            huber = replace(options, huber_threshold=ROBUST_CHECK)
            robust = replace(self, filter=huber)._run(pass_, dynamics, prior, vectors)
        check = StartCheck(
            tuple(runs),
            options.consistency_false_alarm,
            options.consistency_window,
            diverged=len(starts) - len(runs),
            robust=robust,
        )
        return checked(check)

    def _run(
        self,
        pass_: Pass,
        dynamics: EkfDynamics,
        prior: tuple[Rotation, np.ndarray, np.ndarray],
        vectors: tuple[np.ndarray, np.ndarray, np.ndarray] | None,
    ) -> Track:
        """The filter from ``prior`` (``(attitude, rate, covariance)``): in CasADi over the
        pass's unit ``vectors`` in slots when given, else the Python loop."""
        if vectors is not None:
            return run_vectors(
                pass_.t, vectors, dynamics, prior, self.process_noise, self.filter, self.name
            )
        return run_filter(
            DoaEkfFilter(pass_.t, dynamics, prior, self.process_noise, self.filter),
            pass_.t,
            pass_.measurements(),
            ekf_monitor(self.filter, prior[2]),
            self.filter,
            self.name,
        )


@dataclass(frozen=True, repr=False)
class DoaRts(PassEstimator):
    """The RTS backward pass over the EKF (:func:`attopt.solvers.filters.rts.rts_smooth`).

    Attributes:
        forward: the EKF it runs when not given one's track; its fault handling
            is also the smoothed track's validity rules.
    """

    forward: DoaEkf = field(default_factory=DoaEkf)

    name: ClassVar[str] = "rts_yang2014"
    description: ClassVar[str] = (
        "multiplicative RTS smoother over Yang et al. 2014's EKF (attitude block last)"
    )
    accepts: ClassVar[tuple[type[AttitudeMeasurement], ...]] = (AttitudeMeasurement,)
    motion: ClassVar[Motion] = "dynamics"
    starts_from: ClassVar[tuple[str, ...]] = ("ekf_yang2014",)

    def solve(self, pass_: Pass, initial: Track | None = None) -> Track:
        """The smoothed track of ``initial`` (an EKF's on this pass), else of the EKF run here.

        With the EKF's start check (its ``report``), the checked track is smoothed over
        each of its valid stretches (as any flagged stretch: the backward pass corrects
        the forward estimates linearly about them, so it does not mend a forward
        estimate the starts contradict; measured without this, at 0 dB and L = 100,
        ``Q = 1e-9``: 8-10 % of the valid epochs beyond the integrity quantile), and then
        checked against the other runs plausible over the whole pass, smoothed
        (:func:`~attopt.solvers.start_hypotheses.checked` with ``whole_pass``); the
        report's first run is the unchecked EKF run smoothed (a start for other
        estimators)."""
        if initial is None:
            initial = self.forward.solve(pass_)
        else:
            self.check_types(pass_.types())
            _same_epochs(initial, pass_)
        check = initial.report
        if not isinstance(check, StartCheck):
            return rts_smooth(initial, self.forward.filter, self.name)
        options = self.forward.filter
        smoothed = replace(
            check,
            runs=tuple(rts_smooth(run, options, self.name) for run in check.plausible()),
            robust=None if check.robust is None else rts_smooth(check.robust, options, self.name),
        )
        reported = rts_smooth(initial, options, self.name)
        return checked(smoothed, whole_pass=True, reported=reported)


@dataclass(frozen=True, repr=False)
class DoaBatchLs(PassEstimator):
    """Whole-pass batch least squares over the deterministic dynamics
    (:mod:`attopt.solvers.doa.batch_ls`), from a smoothed track's first epoch.

    Attributes:
        batch: Gauss-Newton settings.
        start: the RTS pass it starts from when not given one's track.
    """

    batch: BatchLsOptions = field(default_factory=BatchLsOptions)
    start: DoaRts = field(default_factory=DoaRts)

    name: ClassVar[str] = "bls_yang2014"
    description: ClassVar[str] = (
        "whole-pass batch least squares over Yang et al. 2014's torque-free dynamics (Q = 0)"
    )
    accepts: ClassVar[tuple[type[AttitudeMeasurement], ...]] = (VectorMeasurement,)
    motion: ClassVar[Motion] = "dynamics"
    starts_from: ClassVar[tuple[str, ...]] = ("rts_yang2014",)

    def solve(self, pass_: Pass, initial: Track | None = None) -> Track:
        """The whole-pass track with its :class:`~attopt.solvers.doa.batch_ls.BatchLsReport`.

        Raises:
            UnsupportedMeasurementError: measurements other than unit vectors.
            InvalidObservationError: vectors without per-vector sigmas, no
                dynamics, or a start track whose first epoch is not valid.
            UnobservableError: the vectors do not determine the initial state.
            ConvergenceError: the start's trajectory turns faster than the step limit.
        """
        self.check_types(pass_.types())
        if not unit_vectors_only(pass_.snapshots):
            raise InvalidObservationError(f"{self.name} needs unit vectors with sigmas")
        dynamics = ekf_dynamics(pass_)
        if initial is None:
            initial = self.start.solve(pass_)
        _same_epochs(initial, pass_)
        initial = unchecked(initial)  # a start, not a result
        if initial.rate is None or not initial.valid[0]:
            raise InvalidObservationError(
                f"{self.name} starts from a valid first epoch with a rate"
            )
        return batch_least_squares(
            stored_rotations(initial.quaternion[0]),
            np.asarray(initial.rate[0], dtype=float),
            vector_slots(pass_.snapshots),
            dynamics,
            pass_.t,
            self.batch,
            self.name,
        )
