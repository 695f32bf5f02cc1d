"""Online (causal) factor-graph smoother over attitude and gyro bias.

The variables and factors of the batch smoother (:mod:`attopt.solvers.smoother.problem`,
``docs/smoother.md``), added one node at a time to GTSAM's
``IncrementalFixedLagSmoother`` (iSAM2 over the nodes of the last ``lag_s``
seconds; older nodes are marginalised into a linear prior on the window).
The estimate reported at epoch ``k`` is node ``k``'s estimate right after
the update that added it, with its iSAM2 marginal covariance: it uses only the
gyro samples up to ``t_k`` and the measurements of epochs ``0 .. k``.

The smoother is a :class:`~attopt.solvers.sequential.SequentialFilter`
(:class:`OnlineFilter`) run by :func:`attopt.solvers.sequential.run_filter`:
its :meth:`~OnlineFilter.predict` is step 1 below and its
:meth:`~OnlineFilter.update` steps 2-6 (with or without a measurement: every
epoch is a node).  Per node ``i`` (the epochs, plus a prior node at the first
gyro sample when the first epoch is later, as in the batch, added when the
filter is made):

1. prediction: the previous node's estimate and ``6 x 6`` error-state
   covariance propagated over the steps of the gyro timeline (the record cut
   at the epochs, which need not be sample times) as the MEKF propagates them
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
   ``FilterOptions.relinearise_fraction``) and exceeds the relinearisation
   threshold, at most ``FilterOptions.max_update_iterations`` in all: the
   iterated update of the MEKF after a large correction;
5. an AHRS factor whose start node's bias estimate has moved by more than
   ``bias_relinearise_angle / T`` from the bias it was preintegrated about is
   removed and added again preintegrated about the current estimate (the
   batch's rule), while that node is in the window;
6. the new node's joint marginal of ``[xi, d]`` from the iSAM2 Bayes tree,
   converted to ``[delta, delta_beta]``
   (:func:`~attopt.solvers.smoother.conventions.error_state_covariance`).

Cost: a ``CustomFactor`` inside GTSAM's C++ code receives a deep copy of the
whole ``Values`` on every callback (measured with gtsam 4.3.0); here ``Values``
holds only the window, so each callback costs a bounded copy plus one
``predict`` and the pass is linear in its length.  The callback of a factor at
the point where it was prepared reuses that evaluation.

Faults as in the batch and the filters: bad input raises
:class:`~attopt.formulations.errors.InvalidObservationError`; epochs in a gyro gap
longer than ``max_gyro_gap_s``, with a 1-sigma above ``max_attitude_sigma``
or after ``max_rejected_epochs`` consecutive gated epochs (a lost track,
detected by the loop's :class:`~attopt.solvers.sequential.TrackMonitor`; the
online smoother has no re-acquisition: its monitor never inflates) are
flagged by :func:`~attopt.solvers.sequential.filter_result`; a non-finite
estimate flags that epoch and all later ones.  No Huber loss (GTSAM's robust noise models
act on a factor's whole residual, not per block).
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import gtsam
import numpy as np
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.formulations.gyro import GyroModel
from attopt.formulations.passes import Prior
from attopt.solvers.filters.common import (
    STATE_SIZE,
    FilterOptions,
    PreparedGyro,
    error_jacobian,
    error_vector,
    kalman_gain,
    linearised,
    noise_subset,
    repair_covariance,
)
from attopt.solvers.filters.mekf import propagate
from attopt.solvers.results import Track
from attopt.solvers.sequential import SequentialFilter
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
from attopt.solvers.smoother.measurement_factors import (
    COUNTS,
    NO_BLOCKS,
    EpochFactor,
    prepare_factor,
)


@dataclass(frozen=True)
class OnlineOptions:
    """The iSAM2 window of the online smoother (module docstring).

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
    """

    lag_s: float = 3.0
    attitude_threshold: float = 1e-3
    bias_threshold: float = 1e-7
    relinearise_skip: int = 1
    bias_relinearise_angle: float = 1e-5
    cross_covariance: bool = True

    def __post_init__(self) -> None:
        if not (self.lag_s > 0 and self.attitude_threshold > 0 and self.bias_threshold > 0):
            raise ValueError("lag_s and the relinearisation thresholds must be positive")
        if self.relinearise_skip < 1:
            raise ValueError("need relinearise_skip >= 1")


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
            nu, jac, lost = f.innovation, f.jacobian, NO_BLOCKS
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
    intervals: GyroIntervals, i: int, gyro: PreparedGyro, bias_hat: Array
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
    graph = gyro_graph(one, gyro, np.asarray(bias_hat, dtype=float)[None])
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

    def __init__(self, intervals: GyroIntervals, gyro: PreparedGyro, angle: float) -> None:
        self.intervals, self.gyro, self.angle = intervals, gyro, angle
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
        return interval_factors(self.intervals, i, self.gyro, bias_hat)


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
    smoother: gtsam.IncrementalFixedLagSmoother,
    node: int,
    options: OnlineOptions,
    faults: FilterOptions,
) -> tuple[int, int, Array, bool]:
    """Further updates while the new node's step is not linearised (module docstring, step 4).

    The MEKF's rule (:func:`~attopt.solvers.filters.common.linearised`: the step's
    second-order term against ``faults.relinearise_fraction`` of the smallest
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
            or more + 1 >= faults.max_update_iterations
            or linearised(step, covariance, faults.relinearise_fraction)
        ):
            return more, relinearised, covariance, repaired
        smoother.update()
        relinearised += smoother.getISAM2Result().getVariablesRelinearized()
        more += 1


def _epoch_nis(
    factor: EpochFactor, covariance: Array, predicted: Rotation, updated: Rotation
) -> tuple[float, float]:
    """``nu~^T S^-1 nu~`` of the epoch against the predicted covariance and its rows: the
    MEKF's statistic (:func:`attopt.solvers.filters.mekf.update`), with ``nu~ = nu(x+) +
    H(x+) x+`` the innovation relinearised at the update ``x+`` (the error of ``updated``
    relative to ``predicted``), so a large correction does not inflate it.  Blocks the
    model cannot predict at ``updated`` are left out."""
    state = error_vector(updated, predicted)
    nu, jac, lost = factor.evaluate(updated)
    keep = ~np.isin(factor.measurement.blocks[factor.rows], lost)
    rows = factor.rows[keep]
    if not rows.size:
        return np.nan, 0.0
    h = np.zeros((rows.size, STATE_SIZE))
    h[:, :3] = jac[keep] @ error_jacobian(state)
    relinearised = nu[keep] + h[:, :3] @ state
    noise = factor.noise if factor.noise_diagonal is None else factor.noise_diagonal
    return kalman_gain(covariance, h, noise_subset(noise, rows), relinearised)[1], float(rows.size)


class OnlineFilter(SequentialFilter):
    """The online smoother's state and steps (module docstring).

    Starts at the first gyro sample with ``prior`` (``[attitude, bias]``;
    the prior node is added here when the first epoch ``t[0]`` is later).
    :meth:`predict` is the MEKF prediction to an epoch of the timeline and
    stages its node with the gyro factors from the previous one;
    :meth:`update` adds the epoch's measurement factor (if any), runs iSAM2 and
    reads the new node's estimate and marginal.  :meth:`report` summarises
    the pass.
    """

    def __init__(
        self,
        gyro: PreparedGyro,
        model: GyroModel,
        prior: Prior,
        t: Array,
        online: OnlineOptions,
        faults: FilterOptions,
    ) -> None:
        check_model(model)
        self.begin = time.perf_counter()
        self.gyro, self.model, self.prior = gyro, model, prior
        self.online, self.faults = online, faults
        index = np.array([gyro.node(float(epoch)) for epoch in t], dtype=np.intp)
        self.offset = int(index[0] > 0)
        self.nodes = np.concatenate([[0], index]) if self.offset else index
        self.node_time = gyro.timeline.t[self.nodes]
        self.smoother = gtsam.IncrementalFixedLagSmoother(online.lag_s, _isam2_params(online))
        self.callbacks: list[MeasurementCallback] = []
        self.callback_epoch: list[int] = []
        self.chain = _GyroChain(
            gyro_intervals(self.nodes, gyro, model), gyro, online.bias_relinearise_angle
        )
        self.seconds = dict.fromkeys(("factors", "update"), 0.0)
        self.updates = self.extra = self.relinearised = self.max_window = 0
        self.attitude = prior.attitude
        self.bias = np.asarray(prior.bias, dtype=float)
        self.covariance = np.asarray(prior.covariance, dtype=float)
        self.values = gtsam.Values()
        self.estimates = (np.full((index.size, 4), np.nan), np.full((index.size, 3), np.nan))
        self.i = -1
        if self.offset:  # the prior node at the first gyro sample
            self.predict(float(self.node_time[0]))
            self.update(None)

    def predict(self, t: float) -> dict[str, float]:
        start = time.perf_counter()
        self.i += 1
        i = self.i
        if self.gyro.node(t) != self.nodes[i]:
            raise ValueError(f"the online smoother's next node is at t = {self.node_time[i]:g} s")
        self.graph, self.new_values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        self.removed: list[int] = []
        self.positions: dict[int, int] = {}
        if i == 0:
            self.graph.add(prior_factor(JointPrior(self.prior)))
        else:
            self.attitude, self.covariance, _ = propagate(
                self.attitude,
                self.bias,
                self.covariance,
                self.gyro,
                slice(self.nodes[i - 1], self.nodes[i]),
                self.model,
            )
            self.removed, self.positions = self.chain.extend(self.graph, self.values, i, self.bias)
        self.new_values.insert(attitude_key(i), rot3(self.attitude))
        self.new_values.insert(bias_key(i), np.array(self.bias))
        self.seconds["factors"] += time.perf_counter() - start
        return {"gyro_gap_s": self.gyro.gap_at(int(self.nodes[i]))}

    def start_at(self, attitude: Rotation) -> None:
        """Linearise the current node at ``attitude`` instead of its prediction: its initial
        value and the point its measurement factor is prepared at
        (:class:`~attopt.solvers.filters.recovery.SingleFrameStart`)."""
        self.attitude = attitude
        self.new_values.update(attitude_key(self.i), rot3(attitude))

    def update(self, measurement: AttitudeMeasurement | None) -> dict[str, float]:
        start = time.perf_counter()
        i, predicted, predicted_covariance = self.i, self.attitude, self.covariance
        counts = dict.fromkeys(COUNTS, 0.0)
        counts["nis"], counts["nis_dof"] = np.nan, 0.0
        factor = None
        if measurement is not None:
            factor, epoch_counts = prepare_factor(
                i,
                measurement,
                predicted,
                predicted_covariance[:3, :3],
                self.faults.gate_probability,
            )
            counts |= epoch_counts
            if factor is not None:
                callback = MeasurementCallback(factor, predicted)
                self.callbacks.append(callback)
                self.callback_epoch.append(i - self.offset)
                self.graph.add(callback.custom_factor())
        self.seconds["factors"] += time.perf_counter() - start

        start = time.perf_counter()
        stamps = {attitude_key(i): self.node_time[i], bias_key(i): self.node_time[i]}
        self.smoother.update(self.graph, self.new_values, stamps, self.removed)
        result = self.smoother.getISAM2Result()
        self.chain.added(self.positions, list(result.getNewFactorsIndices()))
        self.relinearised += result.getVariablesRelinearized()
        more, more_relinearised, self.covariance, repaired = _settle(
            self.smoother, i, self.online, self.faults
        )
        self.updates += 1 + more
        self.extra += more
        self.relinearised += more_relinearised
        self.values = self.smoother.calculateEstimate()
        self.max_window = max(self.max_window, self.values.size())
        self.attitude = attitude(self.values.atRot3(attitude_key(i)))
        self.bias = self.values.atVector(bias_key(i))
        if factor is not None:
            counts["nis"], counts["nis_dof"] = _epoch_nis(
                factor, predicted_covariance, predicted, self.attitude
            )
        self.seconds["update"] += time.perf_counter() - start
        k = i - self.offset
        if k >= 0:
            quaternion = self.attitude.as_quat()
            if all(np.all(np.isfinite(x)) for x in (quaternion, self.bias, self.covariance)):
                self.estimates[0][k], self.estimates[1][k] = quaternion, self.bias
        counts["update_iterations"] = float(1 + more)
        counts["covariance_repairs"] = float(repaired)
        return counts

    def report(self, track: Track) -> Track:
        """``track`` (this filter's) with the blocks zeroed at some relinearisation point
        counted as unpredictable and the pass's :class:`OnlineReport`."""
        diagnostics = dict(track.diagnostics)
        unpredictable = diagnostics["n_unpredictable"].copy()
        for callback, k in zip(self.callbacks, self.callback_epoch, strict=True):
            unpredictable[k] += len(callback.lost)
        diagnostics["n_unpredictable"] = unpredictable
        seconds = {**self.seconds, "total": time.perf_counter() - self.begin}
        report = OnlineReport(
            lag_s=self.online.lag_s,
            updates=self.updates,
            extra_updates=self.extra,
            evaluations=sum(c.evaluations for c in self.callbacks),
            reused=sum(c.reused for c in self.callbacks),
            relinearised=self.relinearised,
            preintegrations=self.chain.preintegrations,
            n_gated=int(diagnostics["n_gated"].sum()),
            n_nan=int(diagnostics["n_nan"].sum()),
            n_unpredictable=int(unpredictable.sum()),
            n_lost=int(sum(len(c.lost) for c in self.callbacks)),
            measurement_rows=int(sum(c.factor.rows.size for c in self.callbacks)),
            max_window=self.max_window,
            seconds=seconds,
            quaternion=self.estimates[0],
            bias=self.estimates[1],
        )
        return replace(track, diagnostics=diagnostics, report=report)
