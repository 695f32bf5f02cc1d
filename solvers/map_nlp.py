"""The MAP attitude of a snapshot of any mix of measurements: a CasADi NLP solved by IPOPT
(or by CasADi's SQP method: ``NlpOptions(solver="sqpmethod")``, :mod:`attopt.solvers.nlpsol`).

Registry name ``map_nlp``.  The loss is
:func:`attopt.formulations.map_problem.map_loss`: each measurement's own
innovation of its own symbolic model, weighted by its inverse noise
covariance, plus with a :class:`~attopt.formulations.passes.Prior` its
``1/2 e^T P^-1 e`` (the attitude block of ``P``).  Every measurement type with
the symbolic hook
(:meth:`~attopt.formulations.attitude_measurement.AttitudeMeasurement.symbolic`)
is accepted, the very definitions the filters and smoothers use; a type
without one raises :class:`~attopt.formulations.errors.UnsupportedMeasurementError`.

Compilation.  The NLP is built once per structure (measurement types, sizes
and noise layout) and per process (``functools.lru_cache``; ``nlpsol``
objects pickle, but each process builds its own and uses it from one
thread), with every value a parameter.  Epochs whose sizes vary build one NLP
per size (no padding: the loss is generic, and padding rows would need a
harmless value of each type's parameters).  The noise covariance of a
measurement whose noise depends on the attitude (the truncated SNR model) is
that at the start of each local solve.

Start.  From the prior (a :class:`~scipy.spatial.transform.Rotation` is a
start only, a ``Prior`` adds its term to the epochs that start from it: the
first of a sequence), in a sequence from the most recent valid estimate
(:class:`~attopt.solvers.snapshot_sequence.WarmStart`, a start only); without
one, or if that solve fails, by the multi-start of
:func:`~attopt.solvers.snr.initialisation.initialise` from the elements of a
rotation group (:class:`StartOptions`: the 24 rotations of the octahedral
group by default, no attitude farther than 62.8 deg from one of them), the
converged solve of lowest loss winning.  Diagnostics are those of
:data:`~attopt.solvers.snr.initialisation.INITIALISATION_DIAGNOSTICS`.

Status.  IPOPT's ``Solve_Succeeded`` and ``Solved_To_Acceptable_Level``
(flagged ``acceptable = 1``), or the SQP method's ``Solve_Succeeded``, are accepted;
anything else flags the epoch with
:class:`~attopt.formulations.errors.ConvergenceError` and the solver and status
(``IPOPT: ...`` or ``SQP: ...``).

Covariance.  The inverse Gauss-Newton Hessian at the estimate: the Fisher
information of the measurements' AD Jacobians
(:func:`attopt.solvers.bounds.snapshot_information`) plus the prior's ``P^-1``,
inverted by :func:`attopt.formulations.snr_model.cramer_rao_bound` (infinite
on the axes neither the data nor the prior see).  The loss is the MAP loss
at the estimate.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from functools import lru_cache
from typing import Any, ClassVar, Literal

import casadi as ca
import numpy as np
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.formulations.errors import (
    InvalidObservationError,
    UnobservableError,
    UnsupportedMeasurementError,
)
from attopt.formulations.map_problem import MapTerm, map_loss, parameter_vector
from attopt.formulations.passes import Pass, Prior
from attopt.formulations.snapshot import Snapshot, StackedMeasurement
from attopt.formulations.snr_model import cramer_rao_bound
from attopt.formulations.snr_problem import EpochIssue
from attopt.solvers.bounds import snapshot_information
from attopt.solvers.estimator import SnapshotEstimator
from attopt.solvers.nlpsol import NlpOptions
from attopt.solvers.results import Track
from attopt.solvers.snapshot_sequence import EpochEstimate, WarmStart, solve_in_sequence
from attopt.solvers.snr.initialisation import (
    INITIALISATION_DIAGNOSTICS,
    LocalResult,
    increment_solve,
    initialise,
    rival_minimum,
)
from attopt.solvers.start_hypotheses import rotation_group


@dataclass(frozen=True)
class StartOptions:
    """Multi-start attitudes: the elements of a rotation group (scipy ``create_group``).

    ``"T"`` (12, tetrahedral), ``"O"`` (24, octahedral) or ``"I"`` (60, icosahedral).
    """

    group: Literal["T", "O", "I"] = "O"

    @property
    def attitudes(self) -> Rotation:
        return rotation_group(self.group)


@lru_cache(maxsize=64)
def map_solver(
    structure: tuple[tuple[Any, ...], ...], with_prior: bool, options: NlpOptions
) -> ca.Function:
    """The ``nlpsol`` of the MAP loss of ``structure`` by ``options.solver`` (built once per
    process)."""
    v, parameters, loss = map_loss(structure, with_prior)
    problem = {"x": v, "p": parameters, "f": loss}
    return ca.nlpsol(f"map_nlp_{len(structure)}", options.solver, problem, options.nlpsol_options())


def has_symbolic_model(kind: type[AttitudeMeasurement]) -> bool:
    """Whether measurements of class ``kind`` implement the symbolic hook."""
    return kind.symbolic is not AttitudeMeasurement.symbolic


def _leaves(measurements: Iterable[AttitudeMeasurement]) -> list[AttitudeMeasurement]:
    """The measurements with stacked ones split into their parts."""
    out: list[AttitudeMeasurement] = []
    for m in measurements:
        out += _leaves(m.parts) if isinstance(m, StackedMeasurement) else [m]
    return out


def _parts(measurements: Iterable[AttitudeMeasurement]) -> list[AttitudeMeasurement]:
    """:func:`_leaves` with rows (the loss's terms)."""
    return [m for m in _leaves(measurements) if m.size]


@dataclass(frozen=True, eq=False)
class _Epoch:
    """A validated snapshot's measurements and, for the prior term, ``(A_p, P^-1)``."""

    measurements: list[AttitudeMeasurement]
    prior: tuple[Rotation, np.ndarray] | None


@dataclass(frozen=True, repr=False)
class MapNlp(SnapshotEstimator):
    """Registry entry ``map_nlp`` (module docstring)."""

    options: NlpOptions = field(default_factory=NlpOptions)
    starts: StartOptions = field(default_factory=StartOptions)
    warm_start: WarmStart = field(default_factory=WarmStart)
    name: str = "map_nlp"
    description: str = (
        "MAP NLP of any measurement mix on the MRP increment, CasADi + IPOPT, covariance the "
        "inverse Gauss-Newton Hessian"
    )
    accepts: ClassVar[tuple[type[AttitudeMeasurement], ...]] = (AttitudeMeasurement,)

    def check_types(self, types: Iterable[type[AttitudeMeasurement]]) -> None:
        """Also raise for a type without the symbolic hook (module docstring)."""
        types = list(types)
        super().check_types(types)
        missing = sorted({t.__name__ for t in types if not has_symbolic_model(t)})
        if missing:
            raise UnsupportedMeasurementError(
                f"{self.name} needs measurement types with a symbolic model "
                f"(AttitudeMeasurement.symbolic), not {', '.join(missing)}"
            )

    def solve_sequence(
        self, snapshots: Sequence[Snapshot | None], prior: Rotation | Prior | None = None
    ) -> Track:
        for snapshot in snapshots:
            if snapshot is not None:
                self.check_types(type(m) for m in _leaves(snapshot.measurements))
        return solve_in_sequence(
            self.name,
            snapshots,
            prior,
            self.warm_start,
            INITIALISATION_DIAGNOSTICS,
            _issue,
            self._estimate,
        )

    def solve_pass(self, pass_: Pass) -> Track:
        """:meth:`solve_sequence` over a pass's snapshots with its whole
        :class:`~attopt.formulations.passes.Prior` (attitude and covariance)."""
        return replace(self.solve_sequence(pass_.snapshots, pass_.prior), t=pass_.t.copy())

    def _estimate(self, snapshot: Snapshot, start: Rotation | Prior | None) -> EpochEstimate:
        prior = None
        if isinstance(start, Prior):
            prior = (start.attitude, np.linalg.inv(start.covariance[:3, :3]))
            start = start.attitude
        epoch = _Epoch(_parts(snapshot.measurements), prior)
        init = initialise(epoch, self._local_solve, start, None, self.starts.attitudes)
        diagnostics = init.diagnostics()
        if not init.result.converged:
            return EpochEstimate.failed(f"{self.options.label}: {init.result.status}", diagnostics)
        attitude = init.result.attitude
        information = snapshot_information(snapshot, attitude)
        if prior is not None:
            information = information + prior[1]
        return EpochEstimate(attitude, cramer_rao_bound(information), init.result.loss, diagnostics)

    def rival(
        self, snapshot: Snapshot, attitude: Rotation, loss: float, covariance: np.ndarray
    ) -> tuple[float, float] | None:
        """A second minimum of ``snapshot``'s loss (no prior) that fits about as well as the
        solution ``attitude`` (loss ``loss``, covariance ``covariance``): ``(angle in
        degrees, 2 dL)`` or ``None`` (:func:`~attopt.solvers.snr.initialisation.rival_minimum`
        from this solver's multi-start attitudes)."""
        epoch = _Epoch(_parts(snapshot.measurements), None)
        return rival_minimum(
            epoch, self._local_solve, attitude, loss, covariance, self.starts.attitudes
        )

    def _local_solve(self, epoch: _Epoch, start: Rotation) -> LocalResult:
        """One solve with ``A_ref = start`` and ``v_0 = 0`` by ``options.solver``
        (:func:`~attopt.solvers.snr.initialisation.increment_solve`)."""
        terms = [MapTerm.of(m, start) for m in epoch.measurements]
        structure = tuple(term.structure for term in terms)
        return increment_solve(
            lambda o: map_solver(structure, epoch.prior is not None, o),
            self.options,
            parameter_vector(start, terms, epoch.prior),
            start,
        )


def _issue(snapshot: Snapshot) -> EpochIssue | None:
    """No rows, or non-finite values or noise (the types validate the rest on construction)."""
    measurements = _parts(snapshot.measurements)
    if not measurements:
        return EpochIssue("the snapshot has no measurement rows", UnobservableError)
    for m in measurements:
        noise = np.asarray(m.noise_covariance, dtype=float)
        if not (np.all(np.isfinite(m.z)) and np.all(np.isfinite(noise))):
            return EpochIssue(
                f"{type(m).__name__}: measured values and noise must be finite",
                InvalidObservationError,
            )
    return None


MAP_NLP = MapNlp()
ESTIMATORS = (MAP_NLP,)
