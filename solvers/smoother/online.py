"""Online (causal) factor-graph smoother over attitude and gyro bias (issue 6 sec. 1).

The variables and factors of the batch smoother (:mod:`attopt.solvers.smoother.batch`,
``docs/smoother.md``), added one node at a time to GTSAM's
``IncrementalFixedLagSmoother`` (iSAM2 over the nodes of the last ``lag_s``
seconds; older nodes are marginalised into a linear prior on the window).
The estimate reported at epoch ``k`` is node ``k``'s estimate right after
the update that added it, with its iSAM2 marginal covariance: it uses only the
gyro samples up to ``t_k`` and the measurements of epochs ``0 .. k``.

Per node ``i`` (the epochs, plus a prior node at the first gyro sample when the
first epoch is later, as in the batch):

1. prediction: the previous node's estimate and ``6 x 6`` error-state
   covariance propagated over the gyro steps as the MEKF propagates them
   (:func:`attopt.solvers.filters.mekf.propagate`: held rate across gaps, the
   filters' hold variance);
2. the epoch's measurement factor is prepared at the predicted attitude by
   :func:`~attopt.solvers.smoother.measurement_factors.prepare_factor`: NaN and
   unpredictable rows left out, ``R = noise_covariance_at`` held fixed, every
   block gated once with the filters' chi-square gate against the predicted
   covariance (counted);
3. new factors: ``AHRSFactor`` and ``BetweenFactorVector`` from the previous
   node (:func:`~attopt.solvers.smoother.gyro_factors.gyro_graph`, preintegrated about
   the previous node's causal bias), and one Python ``gtsam.CustomFactor``
   for the epoch's stacked rows, whose callback evaluates the measurement
   interface (:meth:`EpochFactor.evaluate`) and returns ``e = -W nu`` and
   ``de/dxi = -W K`` (:meth:`EpochFactor.whitened_system`, the nonlinear form
   of the batch's linear factor ``A = -W K, b = W nu``); blocks the model
   cannot predict at a relinearisation point give zero rows and a zero
   Jacobian (counted as unpredictable), never NaN; node 0 carries the joint
   prior (:class:`~attopt.solvers.smoother.gyro_factors.JointPrior` in a
   ``CustomFactor``, full ``6 x 6`` with cross terms);
4. ``update`` with the node's timestamp; further empty ``update`` calls (each
   one Gauss-Newton step of iSAM2, relinearising the variables whose step
   exceeds the threshold) while the new node's step is not linearised by the
   MEKF's rule (:func:`~attopt.solvers.filters.common.linearised`,
   ``filter.relinearise_fraction``) and exceeds the relinearisation
   threshold, at most ``filter.max_update_iterations`` in all: the iterated
   update of the MEKF after a large correction;
5. an AHRS factor whose start node's bias estimate has moved by more than
   ``bias_relinearise_angle / T`` from the bias it was preintegrated about is
   removed and added again preintegrated about the current estimate (the
   batch's rule), while that node is in the window;
6. the new node's joint marginal of ``[xi, d]`` from the iSAM2 Bayes tree,
   converted to ``[delta, delta_beta]``
   (:func:`~attopt.solvers.smoother.conventions.error_state_covariance`).

Cost: a ``CustomFactor`` inside GTSAM's C++ code receives a deep copy of the
whole ``Values`` on every callback (``/work/shared/notes/verified-facts.md``);
here ``Values`` holds only the window, so each callback costs a bounded copy
plus one ``predict`` and the pass is linear in its length.  The callback of a
factor at the point where it was prepared reuses that evaluation.

Faults as in the batch and the filters: bad input raises
:class:`~attopt.formulations.errors.InvalidObservationError`; epochs in a gyro gap
longer than ``filter.max_gyro_gap_s``, with a 1-sigma above
``filter.max_attitude_sigma`` or after ``filter.max_rejected_epochs``
consecutive gated epochs (a lost track: the online smoother has no
re-acquisition inflation) are flagged by
:func:`~attopt.solvers.filters.common.filter_result`; a non-finite estimate flags
that epoch and all later ones.  No Huber loss (GTSAM's robust noise models
act on a factor's whole residual, not per block).
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import gtsam
import numpy as np
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.formulations.gyro import GyroModel, GyroSamples
from attopt.solvers.filters.common import (
    STATE_SIZE,
    EpochRecord,
    FilterOptions,
    FilterPrior,
    PreparedGyro,
    filter_result,
    kalman_gain,
    linearised,
    noise_subset,
    prepare_gyro,
    record_epoch,
    repair_covariance,
    validate_inputs,
)
from attopt.solvers.filters.mekf import propagate
from attopt.solvers.results import Track
from attopt.solvers.smoother.conventions import (
    Array,
    attitude,
    attitude_key,
    bias_key,
    error_state_covariance,
    node_marginal,
    rot3,
)
from attopt.solvers.smoother.gyro_factors import (
    GyroIntervals,
    JointPrior,
    check_model,
    gyro_graph,
    gyro_intervals,
)
from attopt.solvers.smoother.measurement_factors import COUNTS, EpochFactor, prepare_factor


@dataclass(frozen=True)
class OnlineOptions:
    """Options of :func:`smooth_online` (module docstring).

    Attributes:
        lag_s: nodes older than the newest by more than this (s) are
            marginalised; the window, and so the cost per epoch, is bounded by it.
        attitude_threshold: iSAM2 relinearises an attitude whose step has a
            component above this (rad); no further update is made for a new
            node's step below it.
        bias_threshold: the same for the bias (rad/s).
        relinearise_skip: iSAM2 checks for relinearisation every this many
            updates (1: every update; the further updates of step 4 rely on it).
        bias_relinearise_angle: an AHRS factor is preintegrated again when
            ``|b - b_hat| T`` exceeds this (rad).
        cross_covariance: joint attitude-bias marginal (else block-diagonal).
        filter: gating, gyro-gap and validity rules shared with the filters;
            ``max_update_iterations`` bounds the iSAM2 updates per epoch.
    """

    lag_s: float = 3.0
    attitude_threshold: float = 1e-3
    bias_threshold: float = 1e-7
    relinearise_skip: int = 1
    bias_relinearise_angle: float = 1e-5
    cross_covariance: bool = True
    filter: FilterOptions = field(default_factory=FilterOptions)

    def __post_init__(self) -> None:
        if not (self.lag_s > 0 and self.attitude_threshold > 0 and self.bias_threshold > 0):
            raise ValueError("lag_s and the relinearisation thresholds must be positive")
        if self.relinearise_skip < 1 or self.filter.max_update_iterations < 1:
            raise ValueError("need relinearise_skip >= 1 and filter.max_update_iterations >= 1")


@dataclass(frozen=True)
class OnlineReport:
    """How the online pass went.

    ``quaternion`` and ``bias`` are the causal estimates even where the result
    flags them.  ``updates`` counts iSAM2 updates (``extra_updates`` of them
    the further ones of step 4), ``evaluations`` the measurement callbacks that
    called ``predict`` (``reused`` those answered from the preparation),
    ``relinearised`` the variables iSAM2 relinearised, ``preintegrations``
    the AHRS factors preintegrated again (step 5), ``n_lost`` the blocks
    zeroed at some relinearisation point (included in ``n_unpredictable``),
    ``max_window`` the most variables in the smoother at once; ``seconds``
    splits the wall time into ``factors`` (prediction, preparation, gating),
    ``update`` (iSAM2 updates with their callbacks, marginals, estimates) and
    ``total``.
    """

    lag_s: float
    updates: int
    extra_updates: int
    evaluations: int
    reused: int
    relinearised: int
    preintegrations: int
    n_gated: int
    n_nan: int
    n_unpredictable: int
    n_lost: int
    measurement_rows: int
    max_window: int
    seconds: dict[str, float]
    quaternion: Array
    bias: Array


class MeasurementCallback:
    """Error function of one epoch's ``CustomFactor`` (module docstring, step 3).

    ``factor`` comes from :func:`~attopt.solvers.smoother.measurement_factors.prepare_factor`
    at the attitude ``prepared_at``, whose evaluation is reused there.  Counts
    the calls that evaluated the model (``evaluations``) or reused
    (``reused``), and collects the blocks zeroed at some point (``lost``).
    """

    def __init__(self, factor: EpochFactor, prepared_at: Rotation) -> None:
        self.factor = factor
        self.prepared = rot3(prepared_at).matrix()
        self.evaluations = 0
        self.reused = 0
        self.lost: set[int] = set()

    def __call__(
        self, _: gtsam.CustomFactor, values: gtsam.Values, jacobians: list[Array] | None
    ) -> Array:
        rotation = values.atRot3(self.factor.key)
        if np.array_equal(rotation.matrix(), self.prepared):
            self.reused += 1
            f = self.factor
            nu, jac, lost = f.innovation, f.jacobian, np.zeros(0, np.intp)
        else:
            self.evaluations += 1
            nu, jac, lost = self.factor.evaluate(attitude(rotation))
            self.lost.update(lost.tolist())
        error, jacobian = self.factor.whitened_system(nu, jac, lost)
        if jacobians is not None:
            jacobians[0] = jacobian
        return error

    def custom_factor(self) -> gtsam.CustomFactor:
        """The ``CustomFactor`` on the epoch's attitude key with this error function."""
        unit = gtsam.noiseModel.Unit.Create(self.factor.rows.size)
        return gtsam.CustomFactor(unit, [self.factor.key], self)


def prior_factor(prior: JointPrior) -> gtsam.CustomFactor:
    """The joint prior on node 0 as a nonlinear factor (its whitened error and Jacobians)."""

    def error(_: gtsam.CustomFactor, values: gtsam.Values, jacobians: list[Array] | None) -> Array:
        a, b = prior.linearize(values).jacobian()  # b = -whitened error
        if jacobians is not None:
            jacobians[0], jacobians[1] = a[:, :3].copy(), a[:, 3:].copy()
        return -b

    unit = gtsam.noiseModel.Unit.Create(STATE_SIZE)
    return gtsam.CustomFactor(unit, [attitude_key(0), bias_key(0)], error)


def interval_factors(
    intervals: GyroIntervals, i: int, gyro: PreparedGyro, dt: float, bias_hat: Array
) -> tuple[gtsam.NonlinearFactor, gtsam.NonlinearFactor]:
    """AHRS and bias random-walk factors between nodes ``i`` and ``i + 1``, the AHRS one
    preintegrated about ``bias_hat`` (:func:`~attopt.solvers.smoother.gyro_factors.gyro_graph`
    on that one interval, rekeyed)."""
    one = GyroIntervals(
        intervals.nodes[i : i + 2],
        intervals.duration[i : i + 1],
        intervals.attitude_variance[i : i + 1],
        intervals.bias_sigma[i : i + 1],
        intervals.broken[i : i + 1],
    )
    graph = gyro_graph(one, gyro, dt, np.asarray(bias_hat, dtype=float)[None])
    keys = {
        attitude_key(0): attitude_key(i),
        attitude_key(1): attitude_key(i + 1),
        bias_key(0): bias_key(i),
        bias_key(1): bias_key(i + 1),
    }
    ahrs, walk = (graph.at(j) for j in range(2))
    return (
        ahrs.rekey([keys[k] for k in ahrs.keys()]),
        walk.rekey([keys[k] for k in walk.keys()]),
    )


class _GyroChain:
    """The AHRS factors of the window and the biases they are preintegrated about (step 5)."""

    def __init__(
        self, intervals: GyroIntervals, gyro: PreparedGyro, dt: float, angle: float
    ) -> None:
        self.intervals, self.gyro, self.dt, self.angle = intervals, gyro, dt, angle
        self.factors: dict[int, tuple[int, Array]] = {}  # interval -> (iSAM2 index, b_hat)
        self.preintegrations = 0

    def extend(
        self, graph: gtsam.NonlinearFactorGraph, estimate: gtsam.Values, node: int, bias: Array
    ) -> tuple[list[int], dict[int, int]]:
        """Add to ``graph`` the factors from ``node - 1`` to ``node`` about ``bias``
        and, preintegrated again about the current ``estimate``, the AHRS factors
        of the window whose start node's bias drifted; return the iSAM2 indices
        of the factors these replace and each new AHRS factor's position in ``graph``."""
        removed, positions = [], {}
        for j, (index, bias_hat) in list(self.factors.items()):
            if not estimate.exists(bias_key(j)):  # marginalised with its start node
                del self.factors[j]
                continue
            current = estimate.atVector(bias_key(j))
            if np.abs(current - bias_hat).max() * self.intervals.duration[j] > self.angle:
                removed.append(index)
                positions[j] = graph.size()
                self.factors[j] = (-1, current)
                graph.add(self._factors(j, current)[0])
                self.preintegrations += 1
        positions[node - 1] = graph.size()
        self.factors[node - 1] = (-1, np.array(bias))
        for f in self._factors(node - 1, bias):
            graph.add(f)
        return removed, positions

    def added(self, positions: dict[int, int], new_indices: list[int]) -> None:
        """Record the iSAM2 indices of the AHRS factors added at ``positions``."""
        for j, position in positions.items():
            self.factors[j] = (new_indices[position], self.factors[j][1])

    def _factors(
        self, i: int, bias_hat: Array
    ) -> tuple[gtsam.NonlinearFactor, gtsam.NonlinearFactor]:
        return interval_factors(self.intervals, i, self.gyro, self.dt, bias_hat)


def _isam2_params(options: OnlineOptions) -> gtsam.ISAM2Params:
    params = gtsam.ISAM2Params()
    thresholds = gtsam.ISAM2ThresholdMap()
    thresholds.insert(("x", np.full(3, options.attitude_threshold)))
    thresholds.insert(("b", np.full(3, options.bias_threshold)))
    params.setRelinearizeThreshold(thresholds)
    params.relinearizeSkip = options.relinearise_skip
    params.setOptimizationParams(gtsam.ISAM2GaussNewtonParams(0.0))  # full back-substitution
    return params


def _node_covariance(isam: gtsam.ISAM2, node: int, cross: bool) -> Array:
    """Error-state covariance ``(6, 6)`` of ``[delta, delta_beta]`` at ``node``."""
    return error_state_covariance(node_marginal(isam, node, cross))


def _settle(
    smoother: gtsam.IncrementalFixedLagSmoother, node: int, options: OnlineOptions
) -> tuple[int, int, Array, bool]:
    """Further updates while the new node's step is not linearised (module docstring, step 4).

    The MEKF's rule (:func:`~attopt.solvers.filters.common.linearised`: the step's
    second-order term against ``filter.relinearise_fraction`` of the smallest
    attitude standard deviation of the node's marginal), for a step iSAM2
    would relinearise (above the thresholds).  Returns the further updates,
    the variables they relinearised, and the node's final error-state
    covariance with whether it was repaired.
    """
    more = relinearised = 0
    while True:
        covariance, repaired = repair_covariance(
            _node_covariance(smoother.getISAM2(), node, options.cross_covariance)
        )
        delta = smoother.getDelta()
        step = np.concatenate([delta.at(attitude_key(node)), delta.at(bias_key(node))])
        above = (
            np.abs(step[:3]).max() > options.attitude_threshold
            or np.abs(step[3:]).max() > options.bias_threshold
        )
        if (
            not above
            or more + 1 >= options.filter.max_update_iterations
            or linearised(step, covariance, options.filter.relinearise_fraction)
        ):
            return more, relinearised, covariance, repaired
        smoother.update()
        relinearised += smoother.getISAM2Result().getVariablesRelinearized()
        more += 1


def _epoch_nis(factor: EpochFactor, covariance: Array) -> float:
    """``nu^T S^-1 nu`` of the epoch against the predicted covariance (the MEKF's loss)."""
    noise = factor.noise if factor.noise_diagonal is None else factor.noise_diagonal
    h = np.zeros((factor.rows.size, STATE_SIZE))
    h[:, :3] = factor.jacobian
    return kalman_gain(covariance, h, noise_subset(noise, factor.rows), factor.innovation)[1]


def smooth_online(
    samples: GyroSamples,
    t: Array,
    measurements: Sequence[AttitudeMeasurement | None],
    prior: FilterPrior,
    model: GyroModel,
    options: OnlineOptions | None = None,
    method: str = "fg_online",
) -> Track:
    """Causal attitudes (reference -> body), biases and ``6 x 6`` covariances at the epochs.

    Inputs as for :func:`attopt.solvers.smoother.smooth` and the filters; the estimate
    at epoch ``k`` uses the gyro up to ``t[k]`` and the measurements of epochs
    ``0 .. k`` only (module docstring).

    The result is a filter's :class:`~attopt.solvers.results.Track`
    (:func:`~attopt.solvers.filters.common.filter_result`) with the pass's
    :class:`OnlineReport` as ``report``.  Its ``loss`` (diagnostic ``nis``) is
    the epoch's normalised innovation squared against the predicted
    covariance, as the MEKF's; diagnostics ``n_used``, ``n_gated``, ``n_nan``,
    ``n_unpredictable`` count observation blocks, ``update_iterations`` the
    iSAM2 updates of the epoch.
    """
    options = options or OnlineOptions()
    begin = time.perf_counter()
    index = validate_inputs(samples, t, measurements, prior)
    check_model(model)
    gyro = prepare_gyro(samples, options.filter)
    offset = int(index[0] > 0)
    nodes = np.concatenate([[0], index]) if offset else index
    dt = samples.dt
    intervals = gyro_intervals(nodes, gyro, model, dt)
    node_time = np.asarray(samples.t, dtype=float)[nodes]

    smoother = gtsam.IncrementalFixedLagSmoother(options.lag_s, _isam2_params(options))
    callbacks: list[MeasurementCallback] = []
    callback_epoch: list[int] = []
    chain = _GyroChain(intervals, gyro, dt, options.bias_relinearise_angle)
    record = EpochRecord(len(measurements))
    seconds = dict.fromkeys(("factors", "update"), 0.0)
    updates = extra = relinearised = max_window = 0
    estimate_attitude, estimate_bias = prior.attitude, np.asarray(prior.bias, dtype=float)
    covariance = np.asarray(prior.covariance, dtype=float)
    values_now = gtsam.Values()

    for i in range(nodes.size):
        start = time.perf_counter()
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        removed: list[int] = []
        positions: dict[int, int] = {}
        if i == 0:
            predicted, predicted_covariance = estimate_attitude, covariance
            graph.add(prior_factor(JointPrior(prior)))
        else:
            predicted, predicted_covariance, _ = propagate(
                estimate_attitude,
                estimate_bias,
                covariance,
                gyro,
                slice(nodes[i - 1], nodes[i]),
                model,
                dt,
            )
            removed, positions = chain.extend(graph, values_now, i, estimate_bias)
        values.insert(attitude_key(i), rot3(predicted))
        values.insert(bias_key(i), np.array(estimate_bias))

        k = i - offset
        counts = dict.fromkeys(COUNTS, 0.0)
        counts["nis"] = np.nan
        measurement = measurements[k] if k >= 0 else None
        if measurement is not None:
            factor, epoch_counts = prepare_factor(
                i,
                measurement,
                predicted,
                predicted_covariance[:3, :3],
                options.filter.gate_probability,
            )
            counts |= epoch_counts
            if factor is not None:
                counts["nis"] = _epoch_nis(factor, predicted_covariance)
                callback = MeasurementCallback(factor, predicted)
                callbacks.append(callback)
                callback_epoch.append(k)
                graph.add(callback.custom_factor())
        seconds["factors"] += time.perf_counter() - start

        start = time.perf_counter()
        stamps = {attitude_key(i): node_time[i], bias_key(i): node_time[i]}
        smoother.update(graph, values, stamps, removed)
        result = smoother.getISAM2Result()
        chain.added(positions, list(result.getNewFactorsIndices()))
        relinearised += result.getVariablesRelinearized()
        more, more_relinearised, covariance, repaired = _settle(smoother, i, options)
        updates += 1 + more
        extra += more
        relinearised += more_relinearised
        values_now = smoother.calculateEstimate()
        max_window = max(max_window, values_now.size())
        estimate_attitude = attitude(values_now.atRot3(attitude_key(i)))
        estimate_bias = values_now.atVector(bias_key(i))
        seconds["update"] += time.perf_counter() - start
        if k < 0:
            continue
        counts["update_iterations"] = float(1 + more)
        counts["covariance_repairs"] = float(repaired)
        if not record_epoch(record, k, estimate_attitude, estimate_bias, covariance, counts):
            break

    for callback, k in zip(callbacks, callback_epoch, strict=True):
        record.diagnostics["n_unpredictable"][k] += len(callback.lost)
    record.diagnostics["gyro_gap_s"] = np.where(index > 0, gyro.gap_s[index - 1], 0.0)
    result = filter_result(method, record, options.filter, t)
    seconds["total"] = time.perf_counter() - begin
    diagnostics = record.diagnostics
    report = OnlineReport(
        lag_s=options.lag_s,
        updates=updates,
        extra_updates=extra,
        evaluations=sum(c.evaluations for c in callbacks),
        reused=sum(c.reused for c in callbacks),
        relinearised=relinearised,
        preintegrations=chain.preintegrations,
        n_gated=int(diagnostics["n_gated"].sum()),
        n_nan=int(diagnostics["n_nan"].sum()),
        n_unpredictable=int(diagnostics["n_unpredictable"].sum()),
        n_lost=int(sum(len(c.lost) for c in callbacks)),
        measurement_rows=int(sum(c.factor.rows.size for c in callbacks)),
        max_window=max_window,
        seconds=seconds,
        quaternion=record.quaternion.copy(),
        bias=record.bias.copy(),
    )
    return replace(result, report=report)
