"""The batch smoother's problem: its factor graph and its values (GTSAM's
``NonlinearFactorGraph`` and ``Values``).

Variables (:mod:`attopt.solvers.smoother.conventions`): one ``gtsam.Rot3`` (``R =
A^T``) and one bias 3-vector per node, and with transmitter offsets modelled one
1-vector per transmitter.  The nodes are the output epochs (anywhere in the gyro
record, which is cut at them as for the filters: :func:`pass_nodes`) and, when the
first epoch is later than the first gyro sample, one more node there carrying the
prior (output epoch ``k`` is node ``k + offset``).

Factors (:func:`build_problem`):

* the prior with its full ``6 x 6`` covariance
  (:class:`~attopt.solvers.smoother.gyro_factors.JointPrior`);
* ``gtsam.AHRSFactor`` and ``BetweenFactorVector`` between consecutive nodes
  (:mod:`attopt.solvers.smoother.gyro_factors`; Liu et al. 2023 eq. 24 for the
  bias walk), preintegrated about the bias estimate ``b_hat`` of each interval's
  first node and rebuilt about the current estimate when ``|b - b_hat| T`` exceeds
  ``GraphOptions.bias_relinearise_angle`` (:meth:`SmootherProblem.bias_drifted`);
* segment priors: a node after a gyro gap longer than ``max_gyro_gap_s`` (no AHRS
  factor spans it), or after an interval whose gyro the solution contradicts
  (:meth:`SmootherProblem.exclude_intervals`), gets a diffuse attitude prior, ``sigma
  = UNDETERMINED_SIGMA`` about its estimate then, which keeps a node without
  measurements from making the system singular;
* offset priors ``N(0, offset_sigma^2)`` on the transmitter offsets;
* one stacked measurement factor per epoch
  (:mod:`attopt.solvers.smoother.measurement_factors`: SNRs of Liu et al. 2023 eq. 10
  and Pimienta-Penalver and Crassidis eq. 7, unit vectors, Euler angles, all
  through the :class:`~attopt.formulations.attitude_measurement.AttitudeMeasurement`
  interface), prepared once at the initial values (rows, ``R``, gating).

The cost, in half chi-square units, is ``graph.error`` of the built-in factors plus
the prior's and the epochs' half squared (or Huber, ``GraphOptions.huber_threshold``)
whitened residuals (:meth:`SmootherProblem.cost`); :meth:`SmootherProblem.linearize`
is its undamped whitened linear system, the epoch factors at their current
linearisation (what the optimiser, :mod:`attopt.solvers.smoother.optimiser`, and the
marginals, :mod:`attopt.solvers.smoother.marginals`, work on).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import gtsam
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import (
    AttitudeMeasurement,
    noise_covariance_each,
    predict_each,
)
from attopt.formulations.errors import InvalidObservationError
from attopt.solvers.filters.common import FilterOptions, GyroPass, PreparedGyro
from attopt.solvers.sequential import rejected_epoch
from attopt.solvers.smoother.conventions import (
    Array,
    attitude_key,
    offset_key,
    rot3,
)
from attopt.solvers.smoother.gyro_factors import (
    GyroIntervals,
    JointPrior,
    gyro_graph,
    gyro_intervals,
)
from attopt.solvers.smoother.measurement_factors import (
    COUNTS,
    EpochFactor,
    evaluate_factors,
    linear_factors,
    prepare_factor,
)
from attopt.solvers.smoother.offset_elimination import NormalEquations, structure_keys

UNDETERMINED_SIGMA = np.pi
"""Attitude standard deviation (rad) of a node the initial values leave undetermined
(for gating) and of the diffuse prior that starts a segment after a long gyro gap."""


@dataclass(frozen=True)
class GraphOptions:
    """How the problem models the pass (module docstring).

    Attributes:
        huber_threshold: ``k`` of the Huber loss on each block's whitened
            residual norm; ``None`` (default) is plain least squares.
        bias_relinearise_angle: the gyro factors are preintegrated again about
            the current bias when ``|b - b_hat| T`` exceeds this (rad).
    """

    huber_threshold: float | None = None
    bias_relinearise_angle: float = 1e-5

    def __post_init__(self) -> None:
        if self.huber_threshold is not None and not self.huber_threshold > 0:
            raise ValueError("huber_threshold must be positive (or None)")
        if not self.bias_relinearise_angle > 0:
            raise ValueError("bias_relinearise_angle must be positive")


@dataclass(frozen=True)
class NodeValues:
    """Estimates at the nodes: attitudes ``(n,)``, biases ``(n, 3)`` and the ``6 x 6``
    error-state covariances the measurements are gated with."""

    attitudes: Rotation
    bias: Array
    covariance: Array


def pass_nodes(gyro: PreparedGyro) -> tuple[NDArray[np.intp], int]:
    """Indices into the gyro timeline's boundaries of the nodes, and ``offset``: 1 when
    a prior node at the first gyro sample precedes the epochs, else 0."""
    index = gyro.timeline.epochs
    offset = int(index[0] > 0)
    return (np.concatenate([[0], index]) if offset else index), offset


@dataclass
class SmootherProblem:
    """The cost the optimiser minimises (module docstring; exposed for checks, e.g. the
    brute-force test).

    ``cost = graph.error(values) + prior.cost(values) + sum of the epoch factors'
    costs`` over ``n`` nodes; output epoch ``k`` is node ``k + offset``.
    ``graph`` holds the gyro factors about ``bias_hat`` and the ``fixed`` priors
    (segments, offsets); ``counts`` the blocks of each epoch left out when the
    factors were prepared (:data:`~attopt.solvers.smoother.measurement_factors.COUNTS`).
    """

    prior: JointPrior
    factors: list[EpochFactor]
    n: int
    offset: int
    options: GraphOptions
    gyro: PreparedGyro
    intervals: GyroIntervals
    fixed: gtsam.NonlinearFactorGraph
    counts: dict[str, Array]
    offset_ids: NDArray[np.intp]
    excluded: NDArray[np.bool_]
    """``(n - 1,)`` intervals whose AHRS factor :meth:`exclude_intervals` removed."""
    graph: gtsam.NonlinearFactorGraph | None = None
    bias_hat: Array | None = None

    @property
    def n_offsets(self) -> int:
        return int(self.offset_ids.size)

    @property
    def huber_threshold(self) -> float | None:
        return self.options.huber_threshold

    def linearise_offsets(self, attitudes: Rotation, offsets: Array) -> None:
        """Linearise the epoch factors at ``attitudes`` and ``offsets`` with the offsets'
        column.  The factors are prepared without it and gain it at the first accepted
        optimiser step; a solve without an accepted step (the posterior bound at the
        truth) needs it set here, else its marginals are those of known powers."""
        evaluated = evaluate_factors(self.factors, attitudes, offsets)
        for f, (nu, jacobian, lost) in zip(self.factors, evaluated, strict=True):
            f.accept(nu, jacobian, lost)

    def modelled(self, offsets: Array) -> Array | None:
        """``offsets`` when the problem models them, else ``None`` (for the factors)."""
        return offsets if self.n_offsets else None

    def relinearise_bias(self, bias: Array) -> None:
        """Preintegrate the gyro factors about ``bias`` ``(n, 3)`` (rebuilds :attr:`graph`)."""
        self.bias_hat = np.array(bias)
        self.graph = gyro_graph(self.intervals, self.gyro, self.bias_hat)
        self.graph.push_back(self.fixed)

    def bias_drifted(self, bias: Array) -> bool:
        """Whether some interval's ``|b - b_hat| T`` exceeds ``bias_relinearise_angle``."""
        drift = np.max(np.abs(bias[:-1] - self.bias_hat[:-1]), axis=1) * self.intervals.duration
        return bool(drift.size and drift.max() > self.options.bias_relinearise_angle)

    def gyro_chi_square(self, values: gtsam.Values) -> Array:
        """``(n - 1,)`` each interval's AHRS factor residual at ``values``, whitened and
        squared (``2 x`` its cost: chi-square with 3 degrees of freedom when the gyro and
        its noise model are right); NaN where no AHRS factor spans the interval."""
        statistic = np.full(self.n - 1, np.nan)
        for i in range(self.graph.size()):
            factor = self.graph.at(i)
            if isinstance(factor, gtsam.AHRSFactor):
                statistic[gtsam.Symbol(factor.keys()[0]).index()] = 2.0 * factor.error(values)
        return statistic

    def measured_nodes(self) -> NDArray[np.bool_]:
        """``(n,)`` the nodes whose epoch has used rows and is not a rejected epoch (at
        least as many blocks gated as used, :func:`~attopt.solvers.sequential.rejected_epoch`:
        with two vectors, one gated leaves the rotation about the other unmeasured)."""
        measured = np.zeros(self.n, dtype=bool)
        gated = self.counts["n_gated"]
        for f in self.factors:
            k = f.node - self.offset
            measured[f.node] = f.rows.size > 0 and not rejected_epoch(gated[k], f.counts["n_used"])
        return measured

    def exclude_intervals(self, intervals: NDArray[np.intp], attitudes: Rotation) -> None:
        """Remove the AHRS factors of ``intervals`` (interval ``i`` joins nodes ``i`` and
        ``i + 1``): the pass is split there as at a long gyro gap, each new segment
        starting with a diffuse prior about ``attitudes[i + 1]`` (its node's estimate);
        the bias walk still links the segments."""
        self.excluded[intervals] = True
        broken = self.intervals.broken.copy()
        broken[intervals] = True
        self.intervals = replace(self.intervals, broken=broken)
        for i in intervals:
            self.fixed.add(segment_prior(int(i) + 1, attitudes[int(i) + 1]))
        self.relinearise_bias(self.bias_hat)

    def measurement_cost(self) -> float:
        return sum(f.current_cost(self.huber_threshold) for f in self.factors)

    def cost(self, values: gtsam.Values) -> float:
        """Total cost at ``values``, the epoch factors at their current linearisation."""
        return self.graph.error(values) + self.prior.cost(values) + self.measurement_cost()

    def linearize(self, values: gtsam.Values) -> gtsam.GaussianFactorGraph:
        """Undamped whitened linear system at ``values`` (the factors' current linearisation)."""
        linear = self.graph.linearize(values)
        linear.add(self.prior.linearize(values))
        for factor in linear_factors(self.factors, self.huber_threshold):
            linear.add(factor)
        return linear

    def normal_equations(self, values: gtsam.Values) -> NormalEquations:
        """The undamped normal equations at ``values`` by blocks (the factors' current
        linearisation), for a problem with offsets: the built-in factors and the prior
        linearised by GTSAM, the epochs' rows added from numpy."""
        linear = self.graph.linearize(values)
        linear.add(self.prior.linearize(values))
        equations = NormalEquations.empty(self.n, self.n_offsets)
        equations.add_linear(linear, structure_keys(self.n, self.n_offsets))
        for f in self.factors:
            if f.rows.size:
                system, column = f.whitened_rows(self.huber_threshold)
                equations.add_rows(f.node, system, column, f.offset_index[f.rows])
        return equations

    def update_noise(self, attitudes: Rotation, offsets: Array) -> None:
        """Re-evaluate every epoch's ``R`` at ``attitudes`` (and ``offsets``), keeping its rows
        (attitude-dependent ``R``: truncated SNRs)."""
        for f in self.factors:
            f.set_noise(f.shifted(offsets).noise_covariance_at(attitudes[f.node]))
            f.set_rows(f.rows)


def build_problem(
    inputs: GyroPass,
    start: NodeValues,
    options: GraphOptions,
    rules: FilterOptions,
    offset_sigma: float | None = None,
) -> SmootherProblem:
    """The problem of a pass (module docstring) with its factors prepared at ``start``.

    ``rules``: the gate (``gate_probability``) and the gyro gap that splits the pass
    (``max_gyro_gap_s``); ``offset_sigma``: model one offset per transmitter with
    prior ``N(0, offset_sigma^2)`` (``None``: not modelled).

    Raises:
        InvalidObservationError: offsets modelled but no measurement has ``sources``.
    """
    nodes, offset = pass_nodes(inputs.gyro)
    measurements = inputs.measurements
    counts = {name: np.zeros(len(measurements)) for name in COUNTS}
    factors: list[EpochFactor] = []
    offset_ids, offset_index = transmitter_offsets(measurements, offset_sigma)
    offset_variance = 0.0 if offset_sigma is None else offset_sigma**2
    epochs = [k for k, m in enumerate(measurements) if m is not None and m.size > 0]
    node_of = np.array(epochs, dtype=np.intp) + offset
    used, at = [measurements[k] for k in epochs], start.attitudes[node_of]
    predictions, noises = predict_each(used, at), noise_covariance_each(used, at)
    for k, node, prediction, noise in zip(epochs, node_of, predictions, noises, strict=True):
        factor, epoch_counts = prepare_factor(
            int(node),
            measurements[k],
            None,  # predicted and noise already evaluated at start.attitudes[node]
            start.covariance[node, :3, :3],
            rules.gate_probability,
            offset_index[k],
            offset_variance,
            prediction,
            noise,
        )
        for name in COUNTS:
            counts[name][k] = epoch_counts[name]
        if factor is not None:
            factors.append(factor)

    intervals = gyro_intervals(nodes, inputs.gyro, inputs.model, rules.max_gyro_gap_s)
    fixed = offset_priors(offset_ids.size, offset_sigma)
    for k in intervals.segment_starts:
        fixed.add(segment_prior(int(k), start.attitudes[k]))
    problem = SmootherProblem(
        prior=JointPrior(inputs.prior),
        factors=factors,
        n=nodes.size,
        offset=offset,
        options=options,
        gyro=inputs.gyro,
        intervals=intervals,
        fixed=fixed,
        counts=counts,
        offset_ids=offset_ids,
        excluded=np.zeros(nodes.size - 1, dtype=bool),
    )
    problem.relinearise_bias(start.bias)
    return problem


def segment_prior(k: int, attitude: Rotation) -> gtsam.PriorFactorRot3:
    """The diffuse prior (``sigma = UNDETERMINED_SIGMA``) on node ``k``'s attitude about
    ``attitude``, which starts a segment (module docstring)."""
    diffuse = gtsam.noiseModel.Isotropic.Sigma(3, UNDETERMINED_SIGMA)
    return gtsam.PriorFactorRot3(attitude_key(k), rot3(attitude), diffuse)


def offset_priors(n_offsets: int, sigma: float | None) -> gtsam.NonlinearFactorGraph:
    """``N(0, sigma^2)`` priors on the transmitter offsets (built-in factors)."""
    graph = gtsam.NonlinearFactorGraph()
    if n_offsets:
        model = gtsam.noiseModel.Isotropic.Sigma(1, float(sigma))
        for j in range(n_offsets):
            graph.add(gtsam.PriorFactorVector(offset_key(j), np.zeros(1), model))
    return graph


def transmitter_offsets(
    measurements: Sequence[AttitudeMeasurement | None], sigma: float | None
) -> tuple[NDArray[np.intp], list[NDArray[np.intp] | None]]:
    """The transmitters of the pass (sorted ids) and, per measurement, each row's
    index among them (``None`` where offsets are not modelled)."""
    none: list[NDArray[np.intp] | None] = [None] * len(measurements)
    if sigma is None:
        return np.zeros(0, np.intp), none
    sources = [m.sources for m in measurements if m is not None and m.sources is not None]
    if not sources:
        raise InvalidObservationError("offset_sigma is set but no measurement has sources")
    ids = np.unique(np.concatenate(sources))
    index = [
        None if m is None or m.sources is None else np.searchsorted(ids, m.sources)
        for m in measurements
    ]
    return ids, index
