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

from dataclasses import dataclass, field
from typing import ClassVar

import numpy as np

from attopt.formulations.attitude_measurement import AttitudeMeasurement, VectorMeasurement
from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.passes import Pass
from attopt.solvers.doa.batch_ls import BatchLsOptions, batch_least_squares
from attopt.solvers.doa.ekf import (
    EKF_FAULTS,
    PROCESS_NOISE,
    DoaEkfFilter,
    ekf_dynamics,
    ekf_monitor,
    ekf_prior,
    run_vectors,
)
from attopt.solvers.doa.vector_slots import unit_vectors_only, vector_slots
from attopt.solvers.estimator import Motion, PassEstimator
from attopt.solvers.filters.common import FilterOptions
from attopt.solvers.filters.rts import rts_smooth
from attopt.solvers.results import Track
from attopt.solvers.sequential import run_filter, stored_rotations


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
    """

    process_noise: float = PROCESS_NOISE
    filter: FilterOptions = EKF_FAULTS
    compiled: bool = True

    name: ClassVar[str] = "ekf_yang2014"
    description: ClassVar[str] = (
        "EKF on Euler's equation with wheels, no gyro (Yang et al. 2014 sec. 5, eqs. 23-33)"
    )
    accepts: ClassVar[tuple[type[AttitudeMeasurement], ...]] = (AttitudeMeasurement,)
    motion: ClassVar[Motion] = "dynamics"

    def solve(self, pass_: Pass, initial: Track | None = None) -> Track:
        """The filtered track with its history (``initial`` unused).

        Raises:
            InvalidObservationError: no dynamics, no rate prior, epochs not uniform.
            ConvergenceError: an estimated rate turns more than
                :data:`~attopt.solvers.doa.ekf.MAX_STEP_ANGLE` per step.
        """
        self.check_types(pass_.types())
        dynamics = ekf_dynamics(pass_)
        prior = ekf_prior(pass_.prior)
        gated = self.filter.gate_probability < 1.0
        if self.compiled and not gated and unit_vectors_only(pass_.snapshots):
            return run_vectors(pass_, dynamics, prior, self.process_noise, self.filter, self.name)
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
        """The smoothed track of ``initial`` (an EKF's on this pass), else of the EKF run here."""
        if initial is None:
            initial = self.forward.solve(pass_)
        else:
            self.check_types(pass_.types())
            _same_epochs(initial, pass_)
        return rts_smooth(initial, self.forward.filter, self.name)


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
