"""The batch smoother's result: the track, its validity rules and the optimiser's report.

The batch smoother (registry ``fg_batch`` and ``fg_batch_offsets``,
:class:`~attopt.solvers.smoother.estimators.BatchSmoother`) is the composition, as
GTSAM splits it, of

1. the start (:mod:`attopt.solvers.smoother.initial`) at every node;
2. the problem (:mod:`attopt.solvers.smoother.problem`: the factor graph and its
   values, ``NonlinearFactorGraph`` and ``Values``);
3. Levenberg-Marquardt (:mod:`attopt.solvers.smoother.optimiser`, parameters
   :class:`~attopt.solvers.smoother.optimiser_params.LevenbergMarquardtParams`),
   repeated ``noise_updates`` times with ``R`` re-evaluated at the solution
   (:meth:`~attopt.solvers.smoother.problem.SmootherProblem.update_noise`);
4. the marginals at the solution (:mod:`attopt.solvers.smoother.marginals`);
5. the track (:func:`batch_track`, here).

Validity rules of the track.  Gyro gaps follow the filters
(:func:`attopt.solvers.filters.common.prepare_gyro`): the last valid sample is held
and the AHRS factor's covariance grows by the filters' hold variance; a gap longer
than ``filter.max_gyro_gap_s`` splits the pass
(:class:`~attopt.solvers.smoother.gyro_factors.GyroIntervals`) instead of flagging
its epochs, whose marginal covariance then says how well each is determined.  The
filters' "lost track" rule does not apply as such (the smoother bridges a few gated
epochs with the gyro), but its test does, at the solution: a run of
``filter.max_rejected_epochs`` epochs with measurements in a row that each gated, or
cannot predict at the solution, at least as many received blocks as they use
(:func:`~attopt.solvers.sequential.rejected_epoch`; :func:`unpredictable_at_solution`:
SNRs that the solved attitude puts outside every main lobe, where the model says
they could not have been received) is flagged ``inconsistent``
(:class:`~attopt.formulations.errors.ModelMismatchError`), with the epochs without
measurements after it (:func:`rejected_stretches`).  Without it, the last 30 s of a
300 s ``adsb-snr`` pass with unmodelled transmitter powers were reported valid 40-50
deg off: at the solution they used 1-2 of about 120 received SNRs each, which the
residual test below passed.  ``filter.max_attitude_sigma`` applies, and so does the
filters' consistency test (:func:`~attopt.solvers.sequential.inconsistent_epochs`) on
the residuals at the solution: each epoch's ``nu^T R^-1 nu`` over its used rows, summed
over the last ``filter.consistency_window`` epochs with measurements and tested against
chi-square with their rows (conservative: the smoothed estimate absorbs part of each
epoch's noise, so the residuals' expected sum is below the rows) when the optimiser
converged.  So is each gyro interval (:func:`gyro_faults`): the worst AHRS factor whose
residual at the solution fails chi-square(3) is removed, with the rest of its stretch
between measured nodes, the pass split there as at a long gyro gap and the problem
re-solved, up to ``gyro_exclusions`` rounds, and the epoch after each removed interval
is flagged
``inconsistent`` (:class:`~attopt.formulations.errors.ModelMismatchError`; counted in
the report's ``excluded_intervals``).  The whole pass is tested too
(:func:`pass_chi_square`), and the report
says whether it is consistent.  A pass that fails it by a variance factor ``s = 2 J /
dof`` of at most ``max_variance_factor`` has its noise model taken as ``s R`` (the a
posteriori variance factor of least-squares adjustment, Teunissen 2003 ch. 4): every
covariance is scaled by ``s`` and the epochs are tested on residuals normalised by ``s
R``, so a small excess spread over the pass (a noise model slightly off) widens the
covariances while a local one (a manoeuvre, an outlier burst) is still flagged; a larger
factor scales nothing, and the windows flag the epochs.  When the optimiser did not converge
the report says so (final cost, iterations) and, by default (``flag_unconverged``),
every epoch is flagged invalid with that reason and
:class:`~attopt.formulations.errors.ConvergenceError`; the estimates stay in the
report.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import predict_each
from attopt.formulations.errors import ModelMismatchError
from attopt.solvers.chi_square import chi_square_tail
from attopt.solvers.filters.common import FilterOptions, GyroPass, repair_covariance, usable_rows
from attopt.solvers.results import Track
from attopt.solvers.sequential import EpochRecord, filter_result, rejected_epoch
from attopt.solvers.smoother.conventions import Array
from attopt.solvers.smoother.marginals import PassMarginals
from attopt.solvers.smoother.measurement_factors import COUNTS
from attopt.solvers.smoother.optimiser import LevenbergMarquardtResult, Step
from attopt.solvers.smoother.problem import SmootherProblem


@dataclass(frozen=True)
class SmootherReport:
    """How the optimisation went (whole pass).

    ``quaternion`` and ``bias`` are the final estimates at the output epochs
    even where the result flags them (e.g. not converged); ``offsets`` and
    ``offset_sigmas`` the transmitter offsets of ``offset_ids`` with their
    marginal standard deviations (empty unless offsets are modelled); ``seconds``
    splits the wall time into ``initialisation``, ``factors`` (the problem's
    set-up: ``R``, gating, graph), ``optimisation``, ``marginals`` and ``total``.
    ``history`` has one entry per trial step (cost before, cost at the trial,
    decrease predicted by the linear model, lambda, accepted).  ``evaluations``
    counts passes over all measurements (one ``predict`` per epoch each) after the
    initial one.  ``2 final_cost / measurement_rows`` is of order 1 at a correct
    minimum with consistent noise models (about 1 for SNRs, 2/3 for unit vectors,
    whose three rows carry two degrees of freedom); a wrong local minimum leaves it
    far above.  ``chi_square`` (``2 final_cost``), ``chi_square_dof`` and
    ``chi_square_p`` are the whole-pass test of :func:`pass_chi_square`;
    ``consistent`` is ``chi_square_p >= filter.consistency_false_alarm``;
    ``variance_factor`` the factor the covariances were scaled by
    (:func:`variance_factor`; 1: none); ``excluded_intervals`` the gyro intervals
    removed after failing their test (:func:`gyro_faults`).
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
    history: list[Step]
    n_gated: int
    n_nan: int
    n_unpredictable: int
    n_downweighted: int
    measurement_rows: int
    chi_square: float
    chi_square_dof: int
    chi_square_p: float
    consistent: bool
    variance_factor: float
    excluded_intervals: int
    initialisation: str
    seconds: dict[str, float]
    quaternion: Array
    bias: Array
    offset_ids: NDArray[np.intp]
    offsets: Array
    offset_sigmas: Array
    problem: SmootherProblem


class Stopwatch:
    """Wall time of a solve split into stages (the report's ``seconds``)."""

    def __init__(self) -> None:
        self.begin = time.perf_counter()
        self.seconds: dict[str, float] = {}

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        start = time.perf_counter()
        yield
        self.seconds[name] = time.perf_counter() - start

    def split(self) -> dict[str, float]:
        """The stages so far and the ``total`` since the watch was made."""
        return self.seconds | {"total": time.perf_counter() - self.begin}


def pass_chi_square(problem: SmootherProblem, final_cost: float) -> tuple[float, int, float]:
    """The whole-pass consistency test: ``(2 J, dof, P(chi2(dof) >= 2 J))``.

    At the minimum of a linear least-squares problem with correct noise models, twice
    the cost ``J`` is chi-square with (residual rows - parameters) degrees of freedom
    (Bar-Shalom, Li and Kirubarajan 2001, ch. 3).  Each node adds six parameters and
    the six rows of its gyro and bias factors, and the prior's six rows match the first
    node's, so the measurements' rows are left, less three for each attitude segment
    that a long gyro gap starts (its diffuse prior constrains nothing); an offset adds
    one parameter and its prior's row.  The rows of a unit vector count three, of which
    two carry noise, so for vector passes the test is conservative.  With the Huber loss
    ``J`` is not quadratic and the test is approximate.
    """
    dof = sum(f.rows.size for f in problem.factors) - 3 * problem.intervals.segment_starts.size
    statistic = 2.0 * final_cost
    p = float(chi_square_tail(statistic, dof)) if dof > 0 else np.nan
    return statistic, int(dof), p


def gyro_faults(
    problem: SmootherProblem, outcome: LevenbergMarquardtResult, false_alarm: float
) -> NDArray[np.intp]:
    """The intervals whose gyro the converged solution contradicts most: the interval
    with the largest AHRS-factor whitened squared residual ``r``
    (:meth:`SmootherProblem.gyro_chi_square`) if ``P(chi2(3) >= r) < false_alarm``, with
    every interval between the nearest measured nodes
    (:meth:`SmootherProblem.measured_nodes`) on either side of it;
    none when no interval fails or the optimiser did not converge.

    At the minimum each residual is below chi-square(3) (the solution absorbs part of
    it), so the test is conservative for a consistent gyro.  An unmodelled rotation (a
    manoeuvre the record misses, a saturated axis) is spread by the least squares over
    its neighbours through the bias, so only the worst interval is taken at a time, and
    the problem re-solved without it, until none fails (the exclusion of fault
    detection and exclusion, one measurement at a time as in RAIM).  Between nodes
    without measurements (gated, missing) nothing locates the fault, and a node left
    hanging from a faulty interval would take its word: every interval of that stretch
    is taken.
    """
    none = np.zeros(0, dtype=np.intp)
    if not outcome.converged:
        return none
    statistic = problem.gyro_chi_square(outcome.values)
    if not np.isfinite(statistic).any():
        return none
    worst = int(np.nanargmax(statistic))
    if not chi_square_tail(statistic[worst], 3) < false_alarm:
        return none
    measured = np.flatnonzero(problem.measured_nodes())
    before, after = measured[measured <= worst], measured[measured > worst]
    first = before[-1] if before.size else 0
    stop = after[0] if after.size else problem.n - 1
    stretch = np.arange(first, stop)
    return stretch[~problem.intervals.broken[stretch]]


def unpredictable_at_solution(inputs: GyroPass, attitudes: Rotation) -> Array:
    """``(N,)`` each epoch's received observation blocks (finite values) that the model
    cannot predict at the solution's attitude ``attitudes`` ``(N,)`` (an SNR from an
    aircraft outside every main lobe there), all measurements evaluated together."""
    out = np.zeros(len(inputs.measurements))
    epochs = [k for k, m in enumerate(inputs.measurements) if m is not None and m.size]
    measurements = [inputs.measurements[k] for k in epochs]
    for k, m, (h, _) in zip(
        epochs, measurements, predict_each(measurements, attitudes[epochs]), strict=True
    ):
        with np.errstate(invalid="ignore"):
            innovation = m.innovation(h[0])
        out[k] = usable_rows(m, h, innovation[None])[2]
    return out


def rejected_stretches(
    rejected: NDArray[np.bool_], measured: NDArray[np.bool_], length: int
) -> NDArray[np.bool_]:
    """The epochs of each run of at least ``length`` consecutive ``measured`` epochs that
    are all ``rejected``, with the epochs without measurements after each of them up to
    the next measured epoch (bridged by the gyro from a rejected one).

    Example::

        >>> import numpy as np
        >>> from attopt.solvers.smoother.batch import rejected_stretches
        >>> rejected = np.array([0, 1, 1, 0, 1, 0, 0, 1], dtype=bool)
        >>> measured = np.array([1, 1, 1, 0, 1, 1, 0, 1], dtype=bool)
        >>> rejected_stretches(rejected, measured, 3).astype(int).tolist()
        [0, 1, 1, 1, 1, 0, 0, 0]
    """
    index = np.flatnonzero(measured)
    edges = np.diff(np.concatenate([[0], rejected[index].astype(np.int8), [0]]))
    out = np.zeros(rejected.size, dtype=bool)
    for begin, end in zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1), strict=True):
        if end - begin >= length:
            out[index[begin] : index[end] if end < index.size else rejected.size] = True
    return out


def variance_factor(
    chi_square: float, dof: int, p: float, false_alarm: float, max_factor: float
) -> float:
    """The factor ``s`` the pass's noise model is scaled by (module docstring): ``2 J /
    dof`` when the whole-pass test fails (``p < false_alarm``) and that is at most
    ``max_factor``, else 1.

    Example::

        >>> from attopt.solvers.smoother.batch import variance_factor
        >>> variance_factor(1300.0, 1000, 1e-19, 1e-6, 2.0)  # 30% excess over the pass
        1.3
        >>> variance_factor(5600.0, 1000, 0.0, 1e-6, 2.0)  # too large: the windows flag
        1.0
        >>> variance_factor(980.0, 1000, 0.7, 1e-6, 2.0)  # consistent
        1.0
    """
    if not p < false_alarm:
        return 1.0
    factor = chi_square / dof
    return factor if factor <= max_factor else 1.0


def batch_track(
    method: str,
    inputs: GyroPass,
    problem: SmootherProblem,
    outcome: LevenbergMarquardtResult,
    marginals: PassMarginals,
    rules: FilterOptions,
    flag_unconverged: bool,
    noise_updates: int,
    label: str,
    clock: Stopwatch,
    max_variance_factor: float = 1.0,
) -> Track:
    """The smoothed attitudes (reference -> body), biases and ``6 x 6`` covariances at the
    epochs as a filter's :class:`~attopt.solvers.results.Track`
    (:func:`~attopt.solvers.sequential.filter_result` with ``rules``, module docstring),
    with the :class:`SmootherReport` as ``report``.

    Its ``loss`` (diagnostic ``nis``) is the epoch's normalised residual squared at
    the solution, ``nu^T (s R)^-1 nu`` over its used rows (``nis_dof``; ``s`` the
    variance factor, usually 1); diagnostics ``n_used``,
    ``n_gated``, ``n_nan``, ``n_unpredictable`` count observation blocks,
    ``n_downweighted`` the blocks the Huber loss down-weights, ``update_iterations``
    the pass's iterations, ``covariance_repairs`` the marginals that were not
    positive definite.

    Args:
        method: the track's ``method`` (registry name).
        inputs, problem, outcome, marginals: the pass, its problem, the optimiser's
            result (all runs) and the marginals at it.
        rules: the filters' validity rules (the gyro-gap rule excepted, module docstring).
        flag_unconverged: flag every epoch when the optimiser did not converge.
        noise_updates, label: for the report (the re-solves with ``R`` updated, the start).
        clock: the solve's stage times.
        max_variance_factor: the largest whole-pass variance factor taken as the noise
            model's scale (module docstring; 1: none).
    """
    n, offset, threshold = len(inputs.measurements), problem.offset, problem.huber_threshold
    record = EpochRecord(n)
    record.quaternion = outcome.attitudes[offset:].as_quat()
    record.vector = outcome.bias[offset:].copy()
    chi_square, dof, p = pass_chi_square(problem, float(outcome.cost))
    factor = variance_factor(chi_square, dof, p, rules.consistency_false_alarm, max_variance_factor)
    covariance = factor * marginals.covariance
    repairs = np.zeros(n)
    for k in range(n):
        if np.isfinite(covariance[k]).all():
            covariance[k], repaired = repair_covariance(covariance[k])
            repairs[k] = float(repaired)
    record.covariance = covariance
    for name in COUNTS:
        record.diagnostics[name] = problem.counts[name].copy()
    record.diagnostics["n_downweighted"] = np.zeros(n)
    record.diagnostics["nis_dof"] = np.zeros(n)
    for f in problem.factors:
        k = f.node - offset
        record.diagnostics["nis"][k] = f.normalised_residual() / factor
        record.diagnostics["nis_dof"][k] = float(f.rows.size)
        record.diagnostics["n_used"][k] = f.counts["n_used"]
        record.diagnostics["n_unpredictable"][k] = f.counts["n_unpredictable"]
        record.diagnostics["n_downweighted"][k] = f.n_downweighted(threshold)
    index = inputs.gyro.timeline.epochs
    record.diagnostics["gyro_gap_s"] = np.where(index > 0, inputs.gyro.gap_s[index - 1], 0.0)
    record.diagnostics["update_iterations"][:] = outcome.iterations
    record.diagnostics["covariance_repairs"] = repairs
    if marginals.error:
        record.reason[:] = marginals.error
    excluded = np.flatnonzero(problem.excluded) + 1 - offset
    excluded = excluded[(excluded >= 0) & (record.reason[excluded] == "")]
    record.reason[excluded] = (
        f"inconsistent: the gyro up to this epoch contradicts the measurements around it "
        f"(chi-square test at {rules.consistency_false_alarm:g}); the pass is split there"
    )
    counts = record.diagnostics
    unpredictable = unpredictable_at_solution(inputs, outcome.attitudes[offset:])
    gated, used = counts["n_gated"], counts["n_used"]
    rejected = np.array(
        [rejected_epoch(*c) for c in zip(gated, used, unpredictable, strict=True)], dtype=bool
    )
    measured = (counts["n_used"] + counts["n_gated"] + unpredictable) > 0
    stretch = rejected_stretches(rejected, measured, rules.max_rejected_epochs)
    stretch &= record.reason == ""
    record.reason[stretch] = (
        f"inconsistent: at least as many received blocks gated or unpredictable at the "
        f"solution as used, {rules.max_rejected_epochs} epochs with measurements in a row"
    )
    # no lost-track rule, and a long gyro gap splits the pass instead of being flagged
    result = filter_result(
        method,
        record,
        # no residual test of a solution that is not a minimum (flagged below instead)
        replace(
            rules,
            max_gyro_gap_s=np.inf,
            consistency_window=rules.consistency_window if outcome.converged else 0,
        ),
        inputs.t,
        tested="residuals at the solution of the last {window} epochs with measurements",
    )
    result.error[excluded] = ModelMismatchError
    result.error[stretch] = ModelMismatchError
    message = outcome.message
    if not outcome.converged:
        message = (
            f"smoother did not converge ({outcome.message}): cost {outcome.cost:.6g} "
            f"after {outcome.iterations} iterations"
        )
        if flag_unconverged:
            result = result.flagged(np.ones(len(result), dtype=bool), message)
    report = SmootherReport(
        converged=outcome.converged,
        message=message,
        iterations=outcome.iterations,
        evaluations=outcome.evaluations,
        initial_cost=outcome.initial_cost,
        final_cost=float(outcome.cost),
        final_lambda=float(outcome.final_lambda),
        graph_rebuilds=outcome.rebuilds,
        history=outcome.history,
        noise_updates=noise_updates,
        n_gated=int(problem.counts["n_gated"].sum()),
        n_nan=int(problem.counts["n_nan"].sum()),
        n_unpredictable=int(record.diagnostics["n_unpredictable"].sum()),
        n_downweighted=int(record.diagnostics["n_downweighted"].sum()),
        measurement_rows=int(sum(f.rows.size for f in problem.factors)),
        chi_square=chi_square,
        chi_square_dof=dof,
        chi_square_p=p,
        consistent=bool(p >= rules.consistency_false_alarm),
        variance_factor=factor,
        excluded_intervals=int(problem.excluded.sum()),
        initialisation=label,
        seconds=clock.split(),
        quaternion=record.quaternion.copy(),
        bias=record.vector.copy(),
        offset_ids=problem.offset_ids,
        offsets=outcome.offsets,
        offset_sigmas=np.sqrt(marginals.offset_variances),
        problem=problem,
    )
    valid = result.valid
    return replace(
        result,
        bias=np.where(valid[:, None], result.bias, np.nan),
        state_covariance=np.where(valid[:, None, None], result.state_covariance, np.nan),
        report=report,
    )
