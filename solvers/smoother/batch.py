"""Batch factor-graph smoother over attitude and gyro bias (issue 6 sec. 1).

Variables: one ``gtsam.Rot3`` (``R = A^T``, :mod:`attopt.solvers.smoother.conventions`)
and one bias 3-vector per node; the nodes are the output epochs (anywhere in the
gyro record, which is cut at them as for the filters) and, when the first
epoch is later than the first gyro sample, one more node there carrying the prior.

Factors: the prior with its full ``6 x 6`` covariance, ``gtsam.AHRSFactor``
and ``BetweenFactorVector`` between consecutive nodes
(:mod:`attopt.solvers.smoother.gyro_factors`), and one stacked measurement factor per
epoch (:mod:`attopt.solvers.smoother.measurement_factors`; SNRs of seed 000 eq. 10 /
seed 004 eq. 7, unit vectors, Euler angles, all through the
:class:`~attopt.formulations.attitude_measurement.AttitudeMeasurement` interface).

Optimiser: Levenberg-Marquardt driven from Python, because a Python
``CustomFactor`` inside GTSAM's optimisers receives a deep copy of the whole
``Values`` on every call and makes a pass quadratic.  Each iteration:

1. linearise the built-in factors (``NonlinearFactorGraph.linearize``, C++),
   add the prior's and every epoch's ``JacobianFactor`` computed in numpy at
   the current estimate (their ``predict`` calls are the dominant cost, one
   per epoch per iteration), and the damping ``sqrt(lambda) I`` on every
   variable;
2. solve (``GaussianFactorGraph.optimize``, multifrontal elimination in
   COLAMD order: linear in the pass for this chain-structured graph), retract
   (``A <- exp(-xi) A``, ``b <- b + d``);
3. accept the step if the total cost (``graph.error`` of the built-in
   factors plus the prior's and the measurements' half squared (or Huber)
   whitened residuals) decreased, and divide ``lambda`` by
   ``lambda_factor``; else multiply it (a rejected step at which some block
   cannot be predicted, outside an antenna's main lobe, drops that block and
   is solved again instead, :mod:`attopt.solvers.smoother.measurement_factors`);
4. stop when the decrease predicted by the undamped linear model, or the
   decrease achieved by an accepted step, is at most ``absolute_tolerance +
   relative_tolerance * cost`` (converged); or when a rejected step changes
   the cost by less than the rounding level (converged); otherwise after
   ``max_iterations`` trial steps or when ``lambda`` exceeds ``max_lambda``
   (not converged: reported in :class:`SmootherReport` with the final cost and
   iterations, and by default every epoch is flagged invalid with that reason;
   the estimates stay in the report).

Initialisation (``SmootherOptions.initialisation``): ``"mekf"`` (default) runs
the forward MEKF and its RTS pass on the same inputs
(:mod:`attopt.solvers.filters`), whose estimates are within the linearisation range
of the batch optimum; ``"gyro"`` integrates the gyro from the prior (cheap;
only for passes short enough, or gyros good enough, that the drift stays
within the measurement models' convergence range).  A caller that has
already run a filter passes its result as ``initial`` and saves that cost.
Epochs the initial estimate leaves undetermined are filled by gyro
integration from the previous node.

Marginal covariances at the solution: the marginals of the final undamped
linear system (built-in factors, prior, measurement factors with their final
IRLS weights) that ``gtsam.Marginals`` computes, from a
``GaussianBayesTree`` eliminated in METIS order (``Marginals`` uses COLAMD,
whose deep tree for this chain makes the joint queries slower and slower
with the pass); per epoch the joint ``6 x 6`` of ``[xi, d]``
(``jointMarginalCovariance``; ``cross_covariance=False`` keeps only the
per-key blocks, block-diagonal, several times cheaper), converted to the
error state ``[delta, delta_beta]`` (cross block negated).  At the truth the inverse of
this information is the posterior Cramer-Rao bound of the pass.

Gyro gaps follow the filters (:func:`attopt.solvers.filters.common.prepare_gyro`):
the last valid sample is held and the AHRS factor's covariance grows by the
filters' hold variance; epochs in a gap longer than
``filter.max_gyro_gap_s`` are flagged invalid as the filters flag them, so
all methods are compared on the same epochs.  The filters' "lost track" rule
does not apply (the smoother bridges gated epochs with the gyro and its
marginal covariance says how well); ``filter.max_attitude_sigma`` does.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace

import gtsam
import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.formulations.errors import ConvergenceError, InvalidObservationError
from attopt.formulations.gyro import GyroModel, GyroSamples
from attopt.formulations.passes import GyroRecord, Pass, Prior, epoch_snapshots
from attopt.solvers.filters.common import (
    STATE_SIZE,
    FilterOptions,
    PreparedGyro,
    gyro_prior,
    prepare_gyro,
    propagate_attitude,
    repair_covariance,
)
from attopt.solvers.filters.estimators import Mekf
from attopt.solvers.filters.rts import rts_smooth
from attopt.solvers.gyro_timeline import gyro_timeline
from attopt.solvers.results import Track
from attopt.solvers.sequential import EpochRecord, filter_result
from attopt.solvers.smoother.chain_marginals import sequential_marginals
from attopt.solvers.smoother.conventions import (
    Array,
    attitude_key,
    bias_key,
    error_state_covariance,
    node_marginal,
    offset_key,
    retract,
    rot3,
    step_arrays,
    to_values,
)
from attopt.solvers.smoother.gyro_factors import JointPrior, check_model, gyro_graph, gyro_intervals
from attopt.solvers.smoother.measurement_factors import COUNTS, EpochFactor, prepare_factor

INITIALISATIONS = ("mekf", "gyro")
UNDETERMINED_SIGMA = np.pi
"""Attitude standard deviation (rad) assumed for gating where the initial estimate has none."""
ROUNDING = 1e-13
"""A rejected step whose cost differs by less than this fraction is at the rounding floor."""


@dataclass(frozen=True)
class SmootherOptions:
    """Options of :func:`smooth` (module docstring).

    Attributes:
        initialisation: ``"mekf"`` or ``"gyro"`` (ignored when ``initial`` is given).
        max_iterations: trial steps (each one ``predict`` per epoch) before giving up.
        relative_tolerance, absolute_tolerance: convergence on the cost decrease
            (predicted or achieved) ``<= absolute + relative * cost``; cost units
            are half chi-square.  The predicted decrease is half the squared
            Newton decrement, ``step^T H step / 2``: at the default 1e-3 the
            remaining step is at most 0.045 posterior standard deviations in
            Mahalanobis norm over the whole pass.
        initial_lambda, lambda_factor, max_lambda: Levenberg damping ``lambda I``.
        huber_threshold: ``k`` of the Huber loss on each block's whitened
            residual norm; ``None`` (default) is plain least squares.
        noise_updates: times ``R`` is re-evaluated at the solution and the
            problem re-solved (attitude-dependent ``R``: truncated SNRs).
        bias_relinearise_angle: the gyro factors are preintegrated again about
            the current bias when ``|b - b_hat| T`` exceeds this (rad).
        cross_covariance: joint attitude-bias marginals (else block-diagonal).
        flag_unconverged: flag every epoch invalid when the optimiser did not converge.
        offset_sigma: estimate one additive offset per transmitter (the
            measurements' ``sources``: an aircraft's power offset, dB) shared by
            every epoch it is seen in, with prior ``N(0, offset_sigma^2)``
            (issue 6 sec. 2); ``None`` (default): offsets not modelled.
        filter: gating, gyro-gap and validity rules shared with the filters
            (and the options of the initialising MEKF).
    """

    initialisation: str = "mekf"
    max_iterations: int = 30
    relative_tolerance: float = 1e-10
    absolute_tolerance: float = 1e-3
    initial_lambda: float = 1e-6
    lambda_factor: float = 10.0
    max_lambda: float = 1e8
    huber_threshold: float | None = None
    noise_updates: int = 0
    bias_relinearise_angle: float = 1e-5
    cross_covariance: bool = True
    flag_unconverged: bool = True
    offset_sigma: float | None = None
    filter: FilterOptions = field(default_factory=FilterOptions)

    def __post_init__(self) -> None:
        if self.initialisation not in INITIALISATIONS:
            raise ValueError(f"initialisation must be one of {INITIALISATIONS}")
        if self.huber_threshold is not None and not self.huber_threshold > 0:
            raise ValueError("huber_threshold must be positive (or None)")
        if self.max_iterations < 0 or self.lambda_factor <= 1 or self.initial_lambda <= 0:
            raise ValueError("need max_iterations >= 0, lambda_factor > 1, initial_lambda > 0")
        if self.offset_sigma is not None and not self.offset_sigma > 0:
            raise ValueError("offset_sigma must be positive (or None)")


@dataclass
class SmootherProblem:
    """The cost the optimiser minimises (exposed for checks, e.g. the brute-force test).

    ``cost = graph.error(values) + prior.cost(values) + sum of the epoch
    factors' costs``, over ``n`` nodes; output epoch ``k`` is node ``k + offset``.
    """

    graph: gtsam.NonlinearFactorGraph
    prior: JointPrior
    factors: list[EpochFactor]
    n: int
    offset: int
    huber_threshold: float | None
    bias_hat: Array
    n_offsets: int = 0
    ordering: gtsam.Ordering | None = None
    """Elimination ordering (with offsets: :func:`_time_ordering`; else GTSAM's default)."""

    def measurement_cost(self) -> float:
        return sum(f.current_cost(self.huber_threshold) for f in self.factors)

    def cost(self, values: gtsam.Values) -> float:
        """Total cost at ``values``, the epoch factors at their current linearisation."""
        return self.graph.error(values) + self.prior.cost(values) + self.measurement_cost()

    def linearize(self, values: gtsam.Values) -> gtsam.GaussianFactorGraph:
        """Undamped whitened linear system at ``values`` (the factors' current linearisation)."""
        linear = self.graph.linearize(values)
        linear.add(self.prior.linearize(values))
        for f in self.factors:
            for factor in f.linear_factors(self.huber_threshold):
                linear.add(factor)
        return linear


@dataclass(frozen=True)
class SmootherReport:
    """How the optimisation went (whole pass).

    ``quaternion`` and ``bias`` are the final estimates at the output epochs
    even where the result flags them (e.g. not converged); ``offsets`` and
    ``offset_sigmas`` the transmitter offsets of ``offset_ids`` with their
    marginal standard deviations (empty unless ``offset_sigma`` is set); ``seconds`` splits
    the wall time into ``initialisation``, ``factors`` (``R`` and gating),
    ``optimisation``, ``marginals`` and ``total``.  ``history`` has one entry per
    trial step: (cost before, cost at the trial, decrease predicted by the
    linear model, lambda, accepted).  ``evaluations`` counts
    passes over all measurements (one ``predict`` per epoch each) after the
    initial one.  ``2 final_cost / measurement_rows`` is of order 1 at a
    correct minimum with consistent noise models (about 1 for SNRs, 2/3 for
    unit vectors, whose three rows carry two degrees of freedom); a wrong
    local minimum leaves it far above.
    """

    converged: bool
    message: str
    iterations: int
    evaluations: int
    initial_cost: float
    final_cost: float
    final_lambda: float
    graph_rebuilds: int
    noise_updates: int
    history: list[tuple[float, float, float, float, bool]]
    n_gated: int
    n_nan: int
    n_unpredictable: int
    n_downweighted: int
    measurement_rows: int
    initialisation: str
    seconds: dict[str, float]
    quaternion: Array
    bias: Array
    offset_ids: NDArray[np.intp]
    offsets: Array
    offset_sigmas: Array
    problem: SmootherProblem


def _initial_estimate(
    gyro: GyroRecord,
    t: Array,
    measurements: Sequence[AttitudeMeasurement | None],
    prior: Prior,
    options: SmootherOptions,
    initial: Track | None,
) -> tuple[Array, Array, Array, str]:
    """Quaternions, biases and ``6 x 6`` covariances at the epochs (NaN where undetermined)."""
    if initial is None:
        filter_ = Mekf(filter=options.filter)
        if options.initialisation == "mekf":
            forward = filter_.solve(Pass(t, epoch_snapshots(measurements, t), gyro, prior))
            initial = rts_smooth(forward, options.filter, "rts")
            label = "mekf+rts"
        else:
            forward = filter_.solve(Pass(t, (None,) * len(measurements), gyro, prior))
            initial = forward
            label = "gyro"
        history = forward.history
    else:
        if len(initial) != len(measurements):
            raise InvalidObservationError(
                f"initial estimate has {len(initial)} epochs, not {len(measurements)}"
            )
        history, label = initial.history, "given"
    q = np.array(initial.quaternion, dtype=float)
    b = np.array(initial.bias, dtype=float)
    p = np.array(initial.state_covariance, dtype=float)
    if history is not None:  # epochs the result flags keep the filter's raw estimate
        missing = ~np.isfinite(q).all(axis=1)
        q[missing] = history.filtered_attitude[missing]
        b[missing] = history.filtered_vector[missing]
        p[missing] = history.filtered_covariance[missing]
    return q, b, p, label


def single_frame_initial(solution: Track, prior: Prior) -> Track:
    """A starting estimate for :func:`smooth` from single-epoch solutions (issue 6
    sec. 1): their attitudes (same reference frame as the smoother's) where valid,
    the prior's bias everywhere; :func:`smooth` fills the other epochs by gyro
    integration from the previous node.  The covariance (used to gate the
    measurements) is the solution's attitude block and the prior's bias block.
    """
    n = len(solution)
    covariance = np.full((n, STATE_SIZE, STATE_SIZE), np.nan)
    covariance[:, :3, :3] = solution.covariance
    covariance[:, :3, 3:] = covariance[:, 3:, :3] = 0.0
    covariance[:, 3:, 3:] = np.asarray(prior.covariance)[3:, 3:]
    quaternion = np.where(solution.valid[:, None], solution.quaternion, np.nan)
    return replace(
        solution,
        quaternion=quaternion,
        bias=np.tile(np.asarray(prior.bias, dtype=float), (n, 1)),
        state_covariance=covariance,
        state=("attitude", "bias"),
    )


def _fill_nodes(
    q: Array, b: Array, p: Array, nodes: Array, gyro: PreparedGyro, prior: Prior
) -> tuple[Rotation, Array, Array]:
    """Node estimates with undetermined ones filled by gyro integration from the previous node."""
    n = nodes.size
    covariance = np.where(np.isfinite(p).all(axis=(1, 2))[:, None, None], p, np.nan)
    attitudes = np.full((n, 4), np.nan)
    bias = np.full((n, 3), np.nan)
    large = np.diag([UNDETERMINED_SIGMA**2] * 3 + [1.0] * 3)
    for k in range(n):
        ok = np.isfinite(q[k]).all() and np.isfinite(b[k]).all()
        if ok:
            attitudes[k], bias[k] = q[k], b[k]
        elif k == 0:
            attitudes[k], bias[k] = prior.attitude.as_quat(), prior.bias
            covariance[k] = prior.covariance
        else:
            start, stop = nodes[k - 1], nodes[k]
            a = propagate_attitude(
                Rotation.from_quat(attitudes[k - 1]),
                gyro.rates[start:stop] - bias[k - 1],
                gyro.dt[start:stop],
            )
            attitudes[k], bias[k] = a.as_quat(), bias[k - 1]
        if not np.isfinite(covariance[k]).all():
            covariance[k] = large
    return Rotation.from_quat(attitudes), bias, covariance


@dataclass
class _Outcome:
    attitudes: Rotation
    bias: Array
    offsets: Array
    values: gtsam.Values
    cost: float
    converged: bool
    message: str
    iterations: int
    evaluations: int
    final_lambda: float
    rebuilds: int
    history: list[tuple[float, float, float, float, bool]]


def _values(attitudes: Rotation, bias: Array, offsets: Array) -> gtsam.Values:
    """``to_values`` plus the transmitter offsets (1-vectors)."""
    values = to_values(attitudes, bias)
    for j, o in enumerate(offsets):
        values.insert(offset_key(j), np.array([o]))
    return values


def _offset_priors(n_offsets: int, sigma: float | None) -> gtsam.NonlinearFactorGraph:
    """``N(0, sigma^2)`` priors on the transmitter offsets (built-in factors)."""
    graph = gtsam.NonlinearFactorGraph()
    if n_offsets:
        model = gtsam.noiseModel.Isotropic.Sigma(1, float(sigma))
        for j in range(n_offsets):
            graph.add(gtsam.PriorFactorVector(offset_key(j), np.zeros(1), model))
    return graph


def _damped(
    linear: gtsam.GaussianFactorGraph, n: int, n_offsets: int, lam: float
) -> gtsam.GaussianFactorGraph:
    damped = linear.clone()
    root = np.sqrt(lam) * np.eye(3)
    zero = np.zeros(3)
    unit = gtsam.noiseModel.Unit.Create(3)
    for k in range(n):
        damped.add(gtsam.JacobianFactor(attitude_key(k), root, zero, unit))
        damped.add(gtsam.JacobianFactor(bias_key(k), root, zero, unit))
    unit1 = gtsam.noiseModel.Unit.Create(1)
    for j in range(n_offsets):
        damped.add(
            gtsam.JacobianFactor(offset_key(j), np.sqrt(lam) * np.eye(1), np.zeros(1), unit1)
        )
    return damped


def _optimise(
    problem: SmootherProblem,
    rebuild: Callable[[Array], None],
    attitudes: Rotation,
    bias: Array,
    offsets: Array,
    durations: Array,
    options: SmootherOptions,
) -> _Outcome:
    """Levenberg-Marquardt on ``problem`` from ``(attitudes, bias, offsets)`` (module docstring)."""
    n, k_huber = problem.n, problem.huber_threshold
    values = _values(attitudes, bias, offsets)
    cost = problem.cost(values)
    lam = options.initial_lambda
    iterations = evaluations = rebuilds = 0
    history: list[tuple[float, float, float, float, bool]] = []
    converged, message = False, f"maximum iterations ({options.max_iterations}) reached"
    while True:
        linear = problem.linearize(values)
        tolerance = options.absolute_tolerance + options.relative_tolerance * abs(cost)
        damped = _damped(linear, n, problem.n_offsets, lam)
        step = damped.optimize(problem.ordering) if problem.ordering else damped.optimize()
        predicted = linear.error(step.scale(0.0)) - linear.error(step)
        if predicted <= tolerance and lam <= options.initial_lambda:
            converged, message = True, "predicted decrease within tolerance"
            break
        if iterations >= options.max_iterations:
            break
        iterations += 1
        xi, d = step_arrays(step, n)
        trial_offsets = offsets + np.array([step.at(offset_key(j))[0] for j in range(offsets.size)])
        trial_attitudes, trial_bias = retract(attitudes, xi), bias + d
        trial_modelled = trial_offsets if problem.n_offsets else None
        evaluations += 1
        evaluated = [f.evaluate(trial_attitudes[f.node], trial_modelled) for f in problem.factors]
        current = cost
        trial = np.inf
        finite = np.all(np.isfinite(xi)) and np.all(np.isfinite(d))
        if finite and np.all(np.isfinite(trial_offsets)):
            trial_values = _values(trial_attitudes, trial_bias, trial_offsets)
            trial = problem.graph.error(trial_values) + problem.prior.cost(trial_values)
            for f, (nu, _, lost) in zip(problem.factors, evaluated, strict=True):
                trial += f.cost(nu, k_huber, lost)
                if lost.size:  # compare on the rows both points can predict
                    current += f.current_cost(k_huber, lost) - f.current_cost(k_huber)
        accepted = bool(np.isfinite(trial) and trial < current)
        history.append((float(current), float(trial), float(predicted), float(lam), accepted))
        if accepted:
            attitudes, bias, values = trial_attitudes, trial_bias, trial_values
            offsets = trial_offsets
            for f, (nu, jac, lost) in zip(problem.factors, evaluated, strict=True):
                f.accept(nu, jac, lost)
            decrease, cost = current - trial, trial
            lam = max(lam / options.lambda_factor, 1e-12)
            drift = np.max(np.abs(bias[:-1] - problem.bias_hat[:-1]), axis=1) * durations
            if drift.size and drift.max() > options.bias_relinearise_angle:
                rebuild(bias)
                rebuilds += 1
                cost = problem.cost(values)
            elif decrease <= tolerance:
                converged, message = True, "decrease within tolerance"
                break
        elif any(lost.size for _, _, lost in evaluated):
            # a block the model cannot predict at the trial point: drop it, solve again
            for f, (_, _, lost) in zip(problem.factors, evaluated, strict=True):
                f.drop(lost)
            cost = problem.cost(values)
        else:
            floor = np.isfinite(trial) and trial - current <= ROUNDING * abs(current)
            if floor and lam <= options.initial_lambda * options.lambda_factor:
                converged, message = True, "no decrease beyond the rounding level"
                break
            lam *= options.lambda_factor
            if lam > options.max_lambda:
                message = f"damping exceeded {options.max_lambda:g} without a decrease"
                break
    return _Outcome(
        attitudes,
        bias,
        offsets,
        values,
        cost,
        converged,
        message,
        iterations,
        evaluations,
        lam,
        rebuilds,
        history,
    )


def _marginals(
    linear: gtsam.GaussianFactorGraph,
    nodes: range,
    cross: bool,
    n_offsets: int = 0,
    ordering: gtsam.Ordering | None = None,
) -> tuple[Array, Array]:
    """Error-state covariances ``(len(nodes), 6, 6)`` (module docstring) and the
    transmitter offsets' variances ``(n_offsets,)``.

    The marginals ``gtsam.Marginals`` computes, from a Bayes tree eliminated
    in a METIS (nested-dissection) ordering: ``Marginals`` eliminates in
    COLAMD order, whose tree for this chain is deep, and its joint queries
    then cost time growing with the pass (45 s for the 6-state joints of
    14,400 epochs, against 4 s here; same values to rounding).  With
    transmitter offsets (``ordering`` given: the time ordering) the Bayes-tree
    queries recompute separator marginals of hundreds of offsets clique by
    clique (47 s for 300 s of ``adsb-snr``); a backward sweep over the
    sequential Bayes net gives the same values (to 1e-11) in about 1 s
    (:func:`~attopt.solvers.smoother.chain_marginals.sequential_marginals`).
    """
    if ordering is not None:
        covariance, variances = sequential_marginals(
            linear,
            ordering,
            [(attitude_key(k), bias_key(k)) for k in nodes],
            [offset_key(j) for j in range(n_offsets)],
        )
        if not cross:  # per-key blocks only, as the Bayes-tree path
            covariance[:, :3, 3:] = 0.0
            covariance[:, 3:, :3] = 0.0
        return error_state_covariance(covariance), variances
    ordering = (
        gtsam.Ordering.ColamdGaussianFactorGraph(linear)
        if _has_isolated_keys(linear)
        else gtsam.Ordering.MetisGaussianFactorGraph(linear)
    )
    tree = linear.eliminateMultifrontal(ordering)
    out = np.zeros((len(nodes), STATE_SIZE, STATE_SIZE))
    for i, k in enumerate(nodes):
        out[i] = node_marginal(tree, k, cross)
    variances = np.array([tree.marginalCovariance(offset_key(j))[0, 0] for j in range(n_offsets)])
    return error_state_covariance(out), variances


def _time_ordering(n: int, factors: list[EpochFactor], n_offsets: int) -> gtsam.Ordering:
    """Nodes in time order, each transmitter offset right after the last node that sees it.

    The separators are then the offsets of the transmitters in view across
    the current time, so elimination cost grows linearly with the pass (GTSAM's
    COLAMD and METIS orderings of this graph were measured to be far slower,
    and METIS aborted in gtsam 4.3.0).
    """
    last = np.zeros(n_offsets, dtype=np.intp)
    for f in factors:
        if f.offset_index is not None:
            seen = f.offset_index[f.rows]
            last[seen] = np.maximum(last[seen], f.node)
    after = np.argsort(last, kind="stable")
    bounds = np.searchsorted(last[after], np.arange(n + 1))
    ordering = gtsam.Ordering()
    for k in range(n):
        ordering.push_back(attitude_key(k))
        ordering.push_back(bias_key(k))
        for j in after[bounds[k] : bounds[k + 1]]:
            ordering.push_back(offset_key(int(j)))
    return ordering


def _has_isolated_keys(linear: gtsam.GaussianFactorGraph) -> bool:
    """Whether some variable shares no factor with another (a node in a long gyro gap
    without measurements): gtsam 4.3.0's METIS ordering crashes on such graphs."""
    keys, linked = set(), set()
    for i in range(linear.size()):
        factor_keys = linear.at(i).keys()
        keys.update(factor_keys)
        if len(factor_keys) > 1:
            linked.update(factor_keys)
    return keys != linked


def _transmitter_offsets(
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


def smooth(
    samples: GyroSamples,
    t: Array,
    measurements: Sequence[AttitudeMeasurement | None],
    prior: Prior,
    model: GyroModel,
    options: SmootherOptions | None = None,
    initial: Track | None = None,
    method: str = "fg_batch",
) -> Track:
    """Smoothed attitudes (reference -> body), biases and ``6 x 6`` covariances at the epochs.

    Inputs: gyro record, epochs ``t`` (in the record, not necessarily sample
    times: :mod:`attopt.solvers.gyro_timeline`), one measurement or ``None`` per
    epoch, the prior at the first gyro sample (attitude, or attitude and bias)
    and the gyro model.  ``initial``: a
    filter's result on the same epochs to start from (else
    ``options.initialisation``).  See the module docstring.

    The result is a filter's :class:`~attopt.solvers.results.Track`
    (:func:`~attopt.solvers.sequential.filter_result`) with the
    optimiser's :class:`SmootherReport` as ``report``.  Its ``loss``
    (diagnostic ``nis``) is the epoch's normalised residual squared at the
    solution, ``nu^T R^-1 nu`` over its used rows; diagnostics ``n_used``,
    ``n_gated``, ``n_nan``, ``n_unpredictable`` count observation blocks,
    ``n_downweighted`` the blocks the Huber loss down-weights,
    ``update_iterations`` the pass's iterations.
    """
    options = options or SmootherOptions()
    begin = time.perf_counter()
    if len(measurements) != np.size(t):
        raise InvalidObservationError(f"{len(measurements)} measurements for {np.size(t)} epochs")
    record = GyroRecord(samples.t, samples.rates, model)  # checks shapes and the sample rate
    prior = gyro_prior(prior, model)
    check_model(model)
    gyro = prepare_gyro(gyro_timeline(samples, t), options.filter)
    index = gyro.timeline.epochs
    offset = int(index[0] > 0)
    nodes = np.concatenate([[0], index]) if offset else index
    n = nodes.size

    q, b, p, label = _initial_estimate(record, t, measurements, prior, options, initial)
    if offset:
        q = np.vstack([prior.attitude.as_quat(), q])
        b = np.vstack([prior.bias, b])
        p = np.concatenate([np.asarray(prior.covariance)[None], p])
    attitudes, bias, covariance = _fill_nodes(q, b, p, nodes, gyro, prior)
    seconds = {"initialisation": time.perf_counter() - begin}

    start = time.perf_counter()
    counts = {name: np.zeros(len(measurements)) for name in COUNTS}
    factors: list[EpochFactor] = []
    offset_ids, offset_index = _transmitter_offsets(measurements, options.offset_sigma)
    offset_variance = 0.0 if options.offset_sigma is None else options.offset_sigma**2
    for k, measurement in enumerate(measurements):
        if measurement is None:
            continue
        node = k + offset
        factor, epoch_counts = prepare_factor(
            node,
            measurement,
            attitudes[node],
            covariance[node, :3, :3],
            options.filter.gate_probability,
            offset_index[k],
            offset_variance,
        )
        for name in COUNTS:
            counts[name][k] = epoch_counts[name]
        if factor is not None:
            factors.append(factor)
    seconds["factors"] = time.perf_counter() - start

    start = time.perf_counter()
    intervals = gyro_intervals(nodes, gyro, model, options.filter.max_gyro_gap_s)
    problem = SmootherProblem(
        gtsam.NonlinearFactorGraph(),
        JointPrior(prior),
        factors,
        n,
        offset,
        options.huber_threshold,
        bias.copy(),
        offset_ids.size,
    )
    fixed_priors = _offset_priors(offset_ids.size, options.offset_sigma)
    diffuse = gtsam.noiseModel.Isotropic.Sigma(3, UNDETERMINED_SIGMA)
    for k in intervals.segment_starts:
        fixed_priors.add(gtsam.PriorFactorRot3(attitude_key(int(k)), rot3(attitudes[k]), diffuse))
    if offset_ids.size:
        problem.ordering = _time_ordering(n, factors, offset_ids.size)

    def rebuild(bias_hat: Array) -> None:
        problem.bias_hat = np.array(bias_hat)
        problem.graph = gyro_graph(intervals, gyro, problem.bias_hat)
        problem.graph.push_back(fixed_priors)

    rebuild(bias)
    offsets = np.zeros(offset_ids.size)
    initial_cost = problem.cost(_values(attitudes, bias, offsets))
    outcome = _optimise(problem, rebuild, attitudes, bias, offsets, intervals.duration, options)
    iterations, evaluations, rebuilds = outcome.iterations, outcome.evaluations, outcome.rebuilds
    history = list(outcome.history)
    updates = 0
    for _ in range(options.noise_updates):
        updates += 1
        for f in problem.factors:
            a = outcome.attitudes[f.node]
            f.set_noise(f.shifted(outcome.offsets).noise_covariance_at(a))
            f.set_rows(f.rows)
        outcome = _optimise(
            problem,
            rebuild,
            outcome.attitudes,
            outcome.bias,
            outcome.offsets,
            intervals.duration,
            options,
        )
        iterations += outcome.iterations
        evaluations += outcome.evaluations
        rebuilds += outcome.rebuilds
        history += outcome.history
    seconds["optimisation"] = time.perf_counter() - start

    start = time.perf_counter()
    linear = problem.linearize(outcome.values)
    marginals_error = ""
    try:
        node_covariance, offset_variances = _marginals(
            linear, range(offset, n), options.cross_covariance, offset_ids.size, problem.ordering
        )
    except RuntimeError as exc:  # an indefinite system (should not happen: prior + gyro chain)
        node_covariance = np.full((len(measurements), STATE_SIZE, STATE_SIZE), np.nan)
        offset_variances = np.full(offset_ids.size, np.nan)
        marginals_error = f"marginal covariance failed: {exc}"
    seconds["marginals"] = time.perf_counter() - start

    record = EpochRecord(len(measurements))
    epoch_attitudes = outcome.attitudes[offset:]
    record.quaternion = epoch_attitudes.as_quat()
    record.vector = outcome.bias[offset:].copy()
    repairs = np.zeros(len(measurements))
    for k in range(len(measurements)):
        if np.isfinite(node_covariance[k]).all():
            node_covariance[k], repaired = repair_covariance(node_covariance[k])
            repairs[k] = float(repaired)
    record.covariance = node_covariance
    for name in COUNTS:
        record.diagnostics[name] = counts[name]
    record.diagnostics["n_downweighted"] = np.zeros(len(measurements))
    for f in problem.factors:
        k = f.node - offset
        record.diagnostics["nis"][k] = f.normalised_residual()
        record.diagnostics["n_used"][k] = f.counts["n_used"]
        record.diagnostics["n_unpredictable"][k] = f.counts["n_unpredictable"]
        record.diagnostics["n_downweighted"][k] = f.n_downweighted(options.huber_threshold)
    record.diagnostics["gyro_gap_s"] = np.where(index > 0, gyro.gap_s[index - 1], 0.0)
    record.diagnostics["update_iterations"][:] = iterations
    record.diagnostics["covariance_repairs"] = repairs
    if marginals_error:
        record.reason[:] = marginals_error
    # no lost-track rule, and a long gyro gap splits the pass instead of being flagged
    own_rules = replace(options.filter, max_gyro_gap_s=np.inf)
    result = filter_result(method, record, own_rules, t)
    message = outcome.message
    if not outcome.converged:
        message = (
            f"smoother did not converge ({outcome.message}): cost {outcome.cost:.6g} "
            f"after {iterations} iterations"
        )
        if options.flag_unconverged:
            reason = np.where(result.valid, message, result.reason)
            error = np.where(result.valid, ConvergenceError, result.error)
            valid = np.zeros_like(result.valid)
            result = replace(
                result,
                quaternion=np.full_like(result.quaternion, np.nan),
                covariance=np.full_like(result.covariance, np.nan),
                loss=np.full_like(result.loss, np.nan),
                valid=valid,
                reason=reason,
                error=error,
            )
    seconds["total"] = time.perf_counter() - begin
    report = SmootherReport(
        converged=outcome.converged,
        message=message,
        iterations=iterations,
        evaluations=evaluations,
        initial_cost=float(initial_cost),
        final_cost=float(outcome.cost),
        final_lambda=float(outcome.final_lambda),
        graph_rebuilds=rebuilds,
        history=history,
        noise_updates=updates,
        n_gated=int(counts["n_gated"].sum()),
        n_nan=int(counts["n_nan"].sum()),
        n_unpredictable=int(record.diagnostics["n_unpredictable"].sum()),
        n_downweighted=int(record.diagnostics["n_downweighted"].sum()),
        measurement_rows=int(sum(f.rows.size for f in problem.factors)),
        initialisation=label,
        seconds=seconds,
        quaternion=record.quaternion.copy(),
        bias=record.vector.copy(),
        offset_ids=offset_ids,
        offsets=outcome.offsets,
        offset_sigmas=np.sqrt(offset_variances),
        problem=problem,
    )
    valid = result.valid
    return replace(
        result,
        bias=np.where(valid[:, None], result.bias, np.nan),
        state_covariance=np.where(valid[:, None, None], result.state_covariance, np.nan),
        report=report,
    )
