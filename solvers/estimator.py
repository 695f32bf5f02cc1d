"""The contract every registered estimator follows.

Two kinds, as in the problem's nouns (:mod:`attopt.formulations.snapshot`,
:mod:`attopt.formulations.passes`):

* a :class:`SnapshotEstimator` solves one epoch's
  :class:`~attopt.formulations.snapshot.Snapshot` for a
  :class:`~attopt.solvers.results.Solution` (:meth:`~SnapshotEstimator.solve`,
  which raises the specific :mod:`~attopt.formulations.errors` exception for
  bad input or a failed solve), or many epochs at once for a
  :class:`~attopt.solvers.results.Track` whose bad epochs are flagged with
  the reason (:meth:`~SnapshotEstimator.solve_sequence`);
* a :class:`PassEstimator` solves a whole
  :class:`~attopt.formulations.passes.Pass` for a
  :class:`~attopt.solvers.results.Track` (:meth:`~PassEstimator.solve`),
  optionally starting from another estimator's track (``starts_from``).

Each estimator declares the measurement types it ``accepts``; given another
type it raises :class:`~attopt.formulations.errors.UnsupportedMeasurementError`.
Estimators are immutable (frozen dataclasses): options are fields, so
``dataclasses.replace(estimator, field=value)`` (or
:func:`attopt.solvers.registry.estimator` with keywords) makes a configured
copy, and every estimator pickles (Dask sends them to workers).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Iterable, Sequence
from dataclasses import replace
from typing import ClassVar, Literal

from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.formulations.errors import UnsupportedMeasurementError
from attopt.formulations.passes import Pass, Prior
from attopt.formulations.snapshot import Snapshot
from attopt.solvers.results import Solution, Track

Motion = Literal["gyro", "dynamics"]
"""What carries a pass estimator's attitude between epochs (:attr:`PassEstimator.motion`)."""


class Estimator(ABC):
    """What every registered estimator declares.

    Attributes:
        name: registry key, also the ``method`` of its results.
        description: one line naming the method and the equations it implements.
        accepts: the measurement classes it can use;
            ``(AttitudeMeasurement,)`` means any (generic estimators).

    Example::

        >>> from attopt import VectorMeasurement, estimator
        >>> quest = estimator("quest")
        >>> quest.kind, [a.__name__ for a in quest.accepts]
        ('snapshot', ['VectorMeasurement'])
    """

    kind: ClassVar[str]
    name: str
    description: str
    accepts: tuple[type[AttitudeMeasurement], ...]

    def check_types(self, types: Iterable[type[AttitudeMeasurement]]) -> None:
        """Raise :class:`~attopt.formulations.errors.UnsupportedMeasurementError` for a
        measurement class that is not one of :attr:`accepts` (or a subclass)."""
        unsupported = sorted(
            {t.__name__ for t in types if not any(issubclass(t, a) for a in self.accepts)}
        )
        if unsupported:
            accepted = ", ".join(a.__name__ for a in self.accepts)
            raise UnsupportedMeasurementError(
                f"{self.name} accepts {accepted}, not {', '.join(unsupported)}"
            )

    def __repr__(self) -> str:
        accepted = ", ".join(a.__name__ for a in self.accepts)
        return f"<{self.kind} estimator {self.name!r}: {self.description} [{accepted}]>"


class SnapshotEstimator(Estimator):
    """Solves single epochs (module docstring).

    Example::

        >>> import numpy as np
        >>> from attopt import Snapshot, UnobservableError, estimator
        >>> one_vector = Snapshot.from_vectors([[1.0, 0.0, 0.0]], [[1.0, 0.0, 0.0]], 1e-3)
        >>> try:
        ...     estimator("svd").solve(one_vector)
        ... except UnobservableError as error:
        ...     print(error)
        svd: fewer than two vector observations
    """

    kind: ClassVar[str] = "snapshot"

    def solve(self, snapshot: Snapshot, prior: Rotation | Prior | None = None) -> Solution:
        """One epoch's solution; raises the recorded exception if the epoch is not valid.

        ``prior``: an a-priori attitude (a start for iterative methods) or a
        :class:`~attopt.formulations.passes.Prior`, whose covariance only the
        MAP estimators use.
        """
        return self.solve_sequence([snapshot], prior).epoch(0).raise_if_invalid()

    @abstractmethod
    def solve_sequence(
        self, snapshots: Sequence[Snapshot | None], prior: Rotation | Prior | None = None
    ) -> Track:
        """Consecutive epochs (``None``: no measurement), bad ones flagged, never raised.

        ``prior`` applies to the first epoch; iterative methods start each
        later epoch from the most recent valid estimate.
        """

    def solve_pass(self, pass_: Pass) -> Track:
        """:meth:`solve_sequence` over a pass's snapshots, with its epoch times."""
        prior = None if pass_.prior is None else pass_.prior.attitude
        return replace(self.solve_sequence(pass_.snapshots, prior), t=pass_.t.copy())


class PassEstimator(Estimator):
    """Solves whole passes (module docstring).

    Attributes:
        starts_from: registry names of estimators whose track this one can
            start from, in order of preference (the first one run on the same
            pass is used; :func:`attopt.solvers.pipeline.run_estimators`).
        motion: what carries the attitude from epoch to epoch: ``"gyro"``, the
            pass's gyro record (the attitude relative to the gyro's inertial
            frame, with a bias prior), or ``"dynamics"``, the pass's rigid-body
            dynamics (Euler's equation, Yang et al. 2014 eqs. 23-25; the
            attitude relative to the orbit frame, with a rate prior).  A recorded
            pass gives each the pass it needs
            (:func:`attopt.experiments.recorded.estimate.estimate`).

    Example::

        >>> from attopt import estimator
        >>> estimator("rts").starts_from, estimator("fg_batch").starts_from
        (('mekf',), ('fg_online', 'rts'))
        >>> estimator("mekf").motion, estimator("ekf_yang2014").motion
        ('gyro', 'dynamics')
    """

    kind: ClassVar[str] = "pass"
    starts_from: ClassVar[tuple[str, ...]] = ()
    motion: ClassVar[Motion] = "gyro"

    @abstractmethod
    def solve(self, pass_: Pass, initial: Track | None = None) -> Track:
        """The pass's track; ``initial`` is another estimator's track on the same epochs
        to start from (else the estimator computes its own start)."""
