"""Solvers of Wahba's problem (Cilden Guler et al. 2017) as snapshot estimators.

Every solver is a :class:`WahbaSolver` in :data:`ESTIMATORS` (registry names
``triad``, ``svd``, ``q_method``, ``quest``, ``foam``, ``sdp``).  Each accepts
:class:`~attopt.formulations.attitude_measurement.VectorMeasurement` s
(:meth:`~attopt.solvers.estimator.SnapshotEstimator.solve`,
:meth:`WahbaSolver.solve_sequence`) and keeps the array-level interface the
experiments use for speed (:meth:`WahbaSolver.solve_batch`,
:meth:`WahbaSolver.solve_vectors`).

Weights.  The weight of vector ``i`` is ``a_i = 1 / sigma_i^2`` (eq. 14) and
each covariance (eqs. 11, 19, 32, 37) is that of the attitude error under the
QUEST measurement model with isotropic direction noise of standard deviation
``sigma_i`` per axis.  Weights given directly are read the same way, as
inverse variances: weights scaled by ``c`` give the same attitude and a
covariance scaled by ``1 / c``, so the covariance is a covariance in rad^2
only for ``a_i = 1 / sigma_i^2``.  A
:class:`~attopt.formulations.attitude_measurement.VectorMeasurement` given
full ``3 x 3`` covariances ``C_i`` contributes its isotropic equivalent
:attr:`~attopt.formulations.attitude_measurement.VectorMeasurement.sigma`
(``sigma_i^2 = tr(P_i C_i P_i) / 2``, the mean variance across the measured
direction): the covariance is then that of the isotropic model with those
variances, an approximation when ``C_i`` is not isotropic across the
direction.
"""

from __future__ import annotations

from abc import abstractmethod
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import AttitudeMeasurement, VectorMeasurement
from attopt.formulations.kernels import compiled_loops
from attopt.formulations.passes import Prior
from attopt.formulations.snapshot import Snapshot
from attopt.formulations.vector_observations import (
    PARALLEL_TOLERANCE,
    ObservationBatch,
    as_batch,
    prepare_observations,
)
from attopt.formulations.wahba_covariance import anisotropic_covariance
from attopt.solvers.estimator import SnapshotEstimator
from attopt.solvers.results import Solution, Track
from attopt.solvers.wahba import compiled as compiled_path
from attopt.solvers.wahba import foam, qmethod, quest, sdp, svd, triad
from attopt.solvers.wahba.driver import (
    Estimate,
    Method,
    solve_compiled,
    solve_one_compiled,
    solve_prepared,
)
from attopt.solvers.wahba.sdp import SdpOptions

Array = NDArray[np.float64]

_FAILURES = {"quest": quest.FAILURE, "foam": foam.FAILURE}
"""The methods that iterate: their reason for an unconverged epoch."""


@dataclass(frozen=True, repr=False, kw_only=True)
class WahbaSolver(SnapshotEstimator):
    """A solver of Wahba's problem (module docstring).

    Attributes:
        name: registry key, also the ``method`` of its results.
        description: one line with the equations it implements.
        optimal: whether it minimises Wahba's loss exactly (TRIAD does not).
        vectorised: whether a batch is solved without a Python loop per epoch.
        parallel_tolerance: ``|b_i x b_j|`` below which every pair of
            directions counts as (anti)parallel (an unobservable epoch).
        compiled: solve with the method's compiled loop
            (:mod:`attopt.solvers.wahba.compiled`), where it has one and
            ``ATTOPT_KERNELS=interpreted`` does not turn them off; ``False``: the numpy
            method :meth:`estimate` (the reference), e.g. ``compiled = false`` in a
            configuration's ``[estimator_options.quest]``.
    """

    name: str
    description: str
    optimal: bool
    vectorised: bool
    parallel_tolerance: float = PARALLEL_TOLERANCE
    compiled: bool = True
    accepts: ClassVar[tuple[type[AttitudeMeasurement], ...]] = (VectorMeasurement,)

    @property
    def kernel(self) -> int | None:
        """The method's code in :mod:`attopt.solvers.wahba.compiled` when :attr:`compiled`
        (``None``: it has none, or it is off)."""
        return compiled_path.NAMES.index(self.name) if self.has_kernel and self.compiled else None

    @property
    def failure(self) -> str:
        """The reason of an epoch whose compiled iteration did not converge."""
        return _FAILURES.get(self.name, f"{self.name} did not converge")

    @property
    def has_kernel(self) -> bool:
        """Whether the method has a compiled loop."""
        return self.name in compiled_path.NAMES

    @property
    def label(self) -> str:
        """``name``, or ``"name (numpy)"`` for the numpy reference of a compiled method."""
        return f"{self.name} (numpy)" if self.has_kernel and not self.compiled else self.name

    def numpy_reference(self) -> WahbaSolver:
        """This solver on its numpy method alone (the compiled path's reference).

        Example::

            >>> from attopt.solvers.wahba import QUEST
            >>> QUEST.numpy_reference().label
            'quest (numpy)'
        """
        return replace(self, compiled=False)

    @abstractmethod
    def estimate(self, obs: ObservationBatch) -> Estimate:
        """The method itself on validated observations (:mod:`attopt.solvers.wahba.driver`)."""

    def solve_batch(
        self,
        body: ArrayLike,
        reference: ArrayLike,
        weights: ArrayLike,
        present: ArrayLike | None = None,
        vector_covariance: ArrayLike | None = None,
    ) -> Track:
        """Solve ``N`` epochs of ``(N, n, 3)`` vectors with weights ``(N, n)``; ``present``
        ``(N, n)`` masks absent vectors.  Invalid epochs are flagged, not raised.

        The weights are read as inverse variances ``a_i = 1 / sigma_i^2`` (rad^-2)
        of isotropic direction noise: the covariance is the attitude error's (rad^2)
        for those, and scales by ``1 / c`` when every weight is scaled by ``c``
        (the attitude does not change).  With ``vector_covariance`` ``(N, n, 3, 3)``,
        each body vector's noise covariance (rad^2), the covariance of an optimal
        solver is that of the weighted solution under that noise instead
        (:func:`~attopt.formulations.wahba_covariance.anisotropic_covariance`); TRIAD's
        stays eq. 11's with the weights' isotropic variances.
        """
        batch = None
        if self.kernel is not None and compiled_loops():
            batch = as_batch(body, reference, weights, present)
            track = solve_compiled(
                self.name, self.kernel, self.failure, batch, self.parallel_tolerance
            )
        else:
            obs = prepare_observations(
                body, reference, weights, present, parallel_tolerance=self.parallel_tolerance
            )
            track = solve_prepared(self.name, self.estimate, obs)
        if vector_covariance is None or not self.optimal or not track.valid.any():
            return track
        if batch is None:
            batch = as_batch(body, reference, weights, present)
        return _with_vector_covariance(track, batch, vector_covariance)

    def solve_vectors(self, body: ArrayLike, reference: ArrayLike, weights: ArrayLike) -> Solution:
        """Solve one epoch (``(n, 3)`` vectors, weights as in :meth:`solve_batch`); raises a
        specific error on bad input."""
        if self.kernel is not None and compiled_loops():
            epoch = as_batch(body, reference, weights, None)
            _check_one_epoch(epoch[0].shape[0])
            return solve_one_compiled(
                self.name, self.kernel, self.failure, epoch, self.parallel_tolerance
            )
        obs = prepare_observations(
            body, reference, weights, parallel_tolerance=self.parallel_tolerance
        )
        _check_one_epoch(obs.n_epochs)
        return solve_prepared(self.name, self.estimate, obs).epoch(0).raise_if_invalid()

    def solve_sequence(
        self, snapshots: Sequence[Snapshot | None], prior: Rotation | Prior | None = None
    ) -> Track:
        """Every epoch's vector measurements, padded to a common count, by :meth:`solve_batch`.

        Weights ``1 / sigma_i^2`` from each measurement's ``sigma``; where a
        measurement gives full ``3 x 3`` covariances, the covariance is the weighted
        solution's under them (:meth:`solve_batch`'s ``vector_covariance``).  An epoch
        without measurement (``None``) is flagged as having fewer than two
        vectors.  ``prior`` is not used: the solution is closed-form.
        """
        vectors = [self._vectors(snapshot) for snapshot in snapshots]
        n = max((v[2].size for v in vectors), default=0)
        body = np.zeros((len(vectors), n, 3))
        reference = np.zeros((len(vectors), n, 3))
        weights = np.zeros((len(vectors), n))
        present = np.zeros((len(vectors), n), dtype=bool)
        covariance = np.zeros((len(vectors), n, 3, 3))
        for i, (b, r, sigma, c, _) in enumerate(vectors):
            k = sigma.size
            body[i, :k], reference[i, :k], weights[i, :k] = b, r, sigma**-2.0
            present[i, :k], covariance[i, :k] = True, c
        full = any(v[4] for v in vectors)
        return self.solve_batch(body, reference, weights, present, covariance if full else None)

    def _vectors(self, snapshot: Snapshot | None) -> tuple[Array, Array, Array, Array, bool]:
        """The snapshot's body vectors, references, sigmas and ``3 x 3`` noise covariances,
        stacked (empty if none), and whether any measurement gave full covariances."""
        parts = []
        if snapshot is not None:
            self.check_types(snapshot.types)
            parts = snapshot.of_type(VectorMeasurement)
        if not parts:
            return np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3, 3)), False
        return (
            np.concatenate([m.z.reshape(-1, 3) for m in parts]),
            np.concatenate([m.reference for m in parts]),
            np.concatenate([m.sigma for m in parts]),
            np.concatenate([_vector_blocks(m) for m in parts]),
            any(m.noise_covariance.ndim == 2 for m in parts),
        )


def _vector_blocks(measurement: VectorMeasurement) -> Array:
    """``(k, 3, 3)`` noise covariance of each of the measurement's ``k`` vectors."""
    noise = measurement.noise_covariance
    k = measurement.reference.shape[0]
    if noise.ndim == 1:
        return noise.reshape(k, 3)[:, :, None] * np.eye(3)
    return np.stack([noise[3 * i : 3 * i + 3, 3 * i : 3 * i + 3] for i in range(k)])


def _with_vector_covariance(
    track: Track,
    batch: tuple[Array, Array, Array, NDArray[np.bool_]],
    vector_covariance: ArrayLike,
) -> Track:
    """``track`` with the covariances of its valid epochs under the vectors' noise
    covariances (:func:`~attopt.formulations.wahba_covariance.anisotropic_covariance`);
    ``batch`` the observations as :func:`as_batch` gives them."""
    body, _, weights, present = batch
    c = np.asarray(vector_covariance, dtype=float).reshape(*weights.shape, 3, 3)
    valid = track.valid
    covariance = track.covariance.copy()
    covariance[valid] = anisotropic_covariance(
        body[valid], np.where(present, weights, 0.0)[valid], c[valid]
    )
    return replace(track, covariance=covariance)


def _check_one_epoch(n_epochs: int) -> None:
    if n_epochs != 1:
        raise ValueError("solve_vectors() takes one epoch of (n, 3) vectors; use solve_batch()")


@dataclass(frozen=True, repr=False, kw_only=True)
class ClosedFormSolver(WahbaSolver):
    """A closed-form or eigenvalue method: ``method`` maps the observations to an estimate."""

    method: Method

    def estimate(self, obs: ObservationBatch) -> Estimate:
        return self.method(obs)


@dataclass(frozen=True, repr=False, kw_only=True)
class SdpSolver(WahbaSolver):
    """Registry entry ``sdp``: the semidefinite relaxation, :class:`SdpOptions` its solver."""

    name: str = "sdp"
    description: str = (
        "SDP relaxation (cvxpy: Clarabel or SCS), Cilden Guler et al. 2017 eqs. 22-26"
    )
    optimal: bool = True
    vectorised: bool = False
    options: SdpOptions = field(default_factory=SdpOptions)

    def estimate(self, obs: ObservationBatch) -> Estimate:
        return sdp.estimate(obs, self.options)


TRIAD = ClosedFormSolver(
    name="triad",
    method=triad.estimate,
    optimal=False,
    vectorised=True,
    description="TRIAD/algebraic, Cilden Guler et al. 2017 eqs. 5-11",
)
SVD = ClosedFormSolver(
    name="svd",
    method=svd.estimate,
    optimal=True,
    vectorised=True,
    description="SVD, Cilden Guler et al. 2017 eqs. 17-19",
)
Q_METHOD = ClosedFormSolver(
    name="q_method",
    method=qmethod.estimate,
    optimal=True,
    vectorised=True,
    description="Davenport q-method, Cilden Guler et al. 2017 eqs. 20-26",
)
QUEST = ClosedFormSolver(
    name="quest",
    method=quest.estimate,
    optimal=True,
    vectorised=True,
    description="QUEST, Cilden Guler et al. 2017 eqs. 27-32",
)
FOAM = ClosedFormSolver(
    name="foam",
    method=foam.estimate,
    optimal=True,
    vectorised=True,
    description="FOAM, Cilden Guler et al. 2017 eqs. 33-37",
)
SDP = SdpSolver()

ESTIMATORS: tuple[WahbaSolver, ...] = (TRIAD, SVD, Q_METHOD, QUEST, FOAM, SDP)
"""The six solvers, in the order of Cilden Guler et al. 2017's sections."""
NUMPY_REFERENCES: tuple[WahbaSolver, ...] = tuple(
    s.numpy_reference() for s in ESTIMATORS if s.has_kernel
)
"""The numpy method of each compiled solver (``compiled = false``): the compiled path's
reference, which tests and benchmarks run beside it."""
