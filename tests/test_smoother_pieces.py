"""The batch smoother's pieces on their own, its registry estimators and the pass bound.

* the problem (``solvers/smoother/problem.py``): zero cost and a zero Gauss-Newton
  step at the truth of a noise-free pass whose epochs lie between the gyro's samples
  (prior node, cut gyro steps);
* the marginals (``solvers/smoother/marginals.py``) against ``gtsam.Marginals`` on
  small problems, with and without transmitter offsets;
* the optimiser's parameters validate (hypothesis); the loop's damping and
  bias-relinearisation rules, read from its history; a rejected step reuses the
  linearisation;
* ``fg_batch`` and ``fg_batch_offsets`` in the pipeline: started from ``fg_online``
  when that is run, else from an unreported RTS pass, which is what it starts from
  when given none;
* :func:`attopt.solvers.bounds.posterior_bound` of a one-epoch pass against the
  closed form ``(P0^-1 + F)^-1``.
"""

from __future__ import annotations

import dataclasses
import itertools

import gtsam
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from attopt.formulations.errors import InvalidObservationError, ModelMismatchError
from attopt.formulations.gyro import GyroModel
from attopt.formulations.passes import GyroRecord, Pass, Prior
from attopt.formulations.snapshot import Snapshot
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.solvers.bounds import posterior_bound, posterior_bound_ekf, snapshot_information
from attopt.solvers.doa.eks import posterior_bound_ekf as eks_bound
from attopt.solvers.filters import FilterOptions, Rts
from attopt.solvers.filters.common import gyro_pass
from attopt.solvers.pipeline import run_estimators
from attopt.solvers.smoother import (
    BatchSmoother,
    GraphOptions,
    LevenbergMarquardtParams,
    OffsetBatchSmoother,
    OnlineSmoother,
    optimiser,
)
from attopt.solvers.smoother import estimators as smoother_estimators
from attopt.solvers.smoother.conventions import (
    SIGN,
    attitude_key,
    bias_key,
    offset_key,
    step_arrays,
    to_values,
)
from attopt.solvers.smoother.initial import Start, fixed_start, node_values
from attopt.solvers.smoother.marginals import MarginalOptions, problem_marginals
from attopt.solvers.smoother.optimiser import levenberg_marquardt
from attopt.solvers.smoother.problem import SmootherProblem, build_problem, pass_nodes
from tests.filter_passes import drawn_prior, prior_covariance, simulate_pass, solve_with
from tests.filter_passes import gyro_pass as make_pass
from tests.test_sequential import BIAS, MODEL, OFFSET, _constant_rate_pass, _exact_prior, _truth
from tests.test_smoother_offsets import OFFSET_SIGMA, _offset_pass


def _problem(pass_: Pass, attitudes: Rotation, bias: np.ndarray, offset_sigma=None):
    """The problem of ``pass_`` with its factors prepared at ``attitudes`` and ``bias`` at
    the epochs (no gate)."""
    rules = FilterOptions(gate_probability=1.0)
    inputs = gyro_pass(pass_, BatchSmoother(), rules)
    start = Start(fixed_start(attitudes, bias), None, "given")
    values = node_values(start, inputs)
    problem = build_problem(inputs, values, GraphOptions(), rules, offset_sigma)
    offsets = np.zeros(problem.n_offsets)
    return problem, values, to_values(values.attitudes, values.bias, offsets)


# --- the problem ----------------------------------------------------------------------------


def test_cost_at_the_truth_of_a_noise_free_pass_is_zero():
    """Exact gyro samples of a constant rate with a known bias, exact vectors declared at
    1e-6 rad, epochs 0.05 s after the samples and the exact prior at the first sample
    (a prior node): the cost at the true nodes is zero to rounding and so is the
    Gauss-Newton step there; one attitude moved by ``delta = 1e-5`` rad costs the two
    AHRS factors' ``|delta|^2 / (2 var)`` each (``var = sigma_v^2 T + sigma_u^2 T^3 /
    3``) and its measurement ``|J delta|^2 / (2 sigma^2)`` (at its own linearisation,
    which the problem's cost holds until the optimiser moves it)."""
    epochs = OFFSET + np.arange(20.0)
    pass_ = _constant_rate_pass(0.0, epochs, _exact_prior(0.0, 1e-3), 1e-6)
    truth, bias = _truth(epochs), np.tile(BIAS, (epochs.size, 1))
    problem, values, at_truth = _problem(pass_, truth, bias)
    gyro = gyro_pass(pass_, BatchSmoother(), FilterOptions()).gyro
    nodes, offset = pass_nodes(gyro)
    assert offset == 1 and nodes.size == epochs.size + 1 and problem.n == nodes.size
    assert not gyro.timeline.uniform
    np.testing.assert_allclose(values.attitudes[0].as_quat(), _truth(np.zeros(1)).as_quat()[0])
    assert problem.cost(at_truth) < 1e-12
    xi, d = step_arrays(problem.linearize(at_truth).optimize(), problem.n)
    assert np.abs(xi).max() < 1e-10 and np.abs(d).max() < 1e-10
    delta = np.array([1e-5, 0.0, 0.0])
    moved = Rotation.concatenate([values.attitudes[:5], Rotation.from_rotvec(delta) * truth[4]])
    moved = Rotation.concatenate([moved, values.attitudes[6:]])
    # the gyro factors' share: two AHRS factors of variance sigma_v^2 T + sigma_u^2 T^3 / 3
    variance = MODEL.sigma_v**2 + MODEL.sigma_u**2 / 3.0
    gyro_cost = problem.cost(to_values(moved, values.bias))
    np.testing.assert_allclose(gyro_cost, delta @ delta / variance, rtol=1e-6)
    # the measurements' share at the moved attitude: |J delta|^2 / (2 sigma^2)
    factor = problem.factors[4]
    assert factor.node == 5
    nu, _, lost = factor.evaluate(moved[5])
    information = snapshot_information(pass_.snapshots[4], truth[4])
    expected = 0.5 * delta @ information @ delta
    np.testing.assert_allclose(factor.cost(nu, None, lost), expected, rtol=1e-4)


# --- the marginals --------------------------------------------------------------------------


def _gtsam_marginals(problem, values) -> tuple[np.ndarray, np.ndarray]:
    """Joint 6 x 6 of each output epoch in ``[delta, delta_beta]`` and the offsets'
    variances, from ``gtsam.Marginals`` of the linear system at ``values``."""
    linear = problem.linearize(values)
    marginals = gtsam.Marginals(linear, values)
    out = []
    for k in range(problem.offset, problem.n):
        x, b = attitude_key(k), bias_key(k)
        joint = marginals.jointMarginalCovariance([x, b])
        c = np.block([[joint.at(x, x), joint.at(x, b)], [joint.at(b, x), joint.at(b, b)]])
        out.append(SIGN @ c @ SIGN)
    variances = [
        marginals.marginalCovariance(offset_key(j))[0, 0] for j in range(problem.n_offsets)
    ]
    return np.array(out), np.array(variances)


@pytest.mark.parametrize("kind", ["vectors", "offsets"])
def test_marginals_equal_gtsam_marginals(kind):
    """The smoother's marginals (a METIS Bayes tree without offsets, the normal
    equations eliminated in time order and swept back with them) equal
    ``gtsam.Marginals`` (Cholesky of the Hessian in COLAMD order) of the same linear
    system: to 1e-7 in units of the standard deviations (measured 7e-9 with offsets,
    the Hessian squaring their conditioning;
    3e-11 without); without cross covariance the blocks are the same
    and the cross block zero."""
    rng = np.random.default_rng(21)
    if kind == "vectors":
        run = simulate_pass(rng, duration=12.0)
        prior = drawn_prior(rng, run, prior_covariance(np.radians(1.0)))
        offset_sigma = None
    else:
        run, prior, _ = _offset_pass(7, epochs=6)
        offset_sigma = OFFSET_SIGMA
    pass_ = make_pass(run.gyro, run.t, run.measurements, prior)
    problem, _, values = _problem(pass_, run.truth_at_epochs, run.bias_at_epochs, offset_sigma)
    expected, expected_variances = _gtsam_marginals(problem, values)
    marginals = problem_marginals(problem, values, MarginalOptions())
    covariance, variances = marginals.covariance, marginals.offset_variances
    scale = np.sqrt(np.einsum("kii->ki", expected))
    scale = scale[:, :, None] * scale[:, None, :]
    assert np.abs((covariance - expected) / scale).max() < 1e-7
    if kind == "offsets":
        assert variances.size == 12
        np.testing.assert_allclose(variances, expected_variances, rtol=1e-7)
    blocks = problem_marginals(problem, values, MarginalOptions(cross_covariance=False)).covariance
    np.testing.assert_allclose(blocks[:, :3, :3], expected[:, :3, :3], rtol=1e-7)
    np.testing.assert_allclose(blocks[:, 3:, 3:], expected[:, 3:, 3:], rtol=1e-7)
    assert np.all(blocks[:, :3, 3:] == 0.0) and np.abs(expected[:, :3, 3:]).max() > 0.0


# --- the optimiser --------------------------------------------------------------------------


@settings(max_examples=80, deadline=None)
@given(
    max_iterations=st.integers(-2, 40),
    tolerance=st.floats(-1.0, 1.0),
    initial_lambda=st.floats(-1.0, 1.0),
    lambda_factor=st.floats(0.0, 20.0),
    max_lambda=st.floats(1e-9, 1e9),
)
def test_optimiser_params_validate(
    max_iterations, tolerance, initial_lambda, lambda_factor, max_lambda
):
    """Parameters outside their ranges raise ``ValueError``; valid ones are frozen."""
    args = {
        "max_iterations": max_iterations,
        "relative_tolerance": tolerance,
        "absolute_tolerance": abs(tolerance),
        "initial_lambda": initial_lambda,
        "lambda_factor": lambda_factor,
        "max_lambda": max_lambda,
    }
    valid = (
        max_iterations >= 0
        and tolerance >= 0
        and lambda_factor > 1
        and 1e-12 <= initial_lambda <= max_lambda
    )
    if not valid:
        with pytest.raises(ValueError):
            LevenbergMarquardtParams(**args)
        return
    params = LevenbergMarquardtParams(**args)
    with pytest.raises(dataclasses.FrozenInstanceError):
        params.max_iterations = 1  # type: ignore[misc]


def test_damping_and_bias_relinearisation_follow_their_rules():
    """From gyro integration 10 deg off with a zero bias estimate (the true bias is of
    the MEMS class), the loop's history obeys its rules: the cost falls at every
    accepted step, lambda is divided by the factor after one (not below the floor) and
    multiplied after a rejected one; the gyro factors were preintegrated again and end
    within ``bias_relinearise_angle`` of the final bias."""
    rng = np.random.default_rng(29)
    run = simulate_pass(rng, duration=30.0)
    axis = np.array([1.0, -1.0, 1.0]) / np.sqrt(3.0)
    prior = Prior(
        Rotation.from_rotvec(np.radians(10.0) * axis) * run.truth[0],
        prior_covariance(np.radians(10.0)),
        bias=np.zeros(3),
    )
    pass_ = make_pass(run.gyro, run.t, run.measurements, prior)
    params = LevenbergMarquardtParams(initial_lambda=1e-3, lambda_factor=4.0, min_lambda=1e-4)
    track = BatchSmoother(optimiser=params, initialisation="gyro").solve(pass_)
    report = track.report
    assert report.converged and report.graph_rebuilds > 0, report.message
    history = report.history
    assert len(history) == report.iterations == report.evaluations
    for (current, trial, _, lam, accepted), following in itertools.pairwise(history):
        assert accepted == (trial < current)
        expected = max(lam / 4.0, 1e-4) if accepted else lam * 4.0
        assert following[3] == expected
    assert report.final_cost < report.initial_cost
    problem = report.problem
    assert problem.offset == 0 and not problem.bias_drifted(report.bias)


def test_a_rejected_step_damps_the_same_linearisation(monkeypatch):
    """After a rejected step the loop damps the linear system it has more and solves it
    again; it linearises only at the start and after accepted steps.  The first trial
    point is made to look worse (its innovations scaled up), so that step is rejected."""
    linearised, evaluated = [], []
    linear_system, evaluate_factors = optimiser.linear_system, optimiser.evaluate_factors

    def counted(problem, values):
        linearised.append(values)
        return linear_system(problem, values)

    def first_worse(factors, attitudes, offsets):
        out = evaluate_factors(factors, attitudes, offsets)
        evaluated.append(attitudes)
        return [(1e3 * nu, j, lost) for nu, j, lost in out] if len(evaluated) == 1 else out

    monkeypatch.setattr(optimiser, "linear_system", counted)
    monkeypatch.setattr(optimiser, "evaluate_factors", first_worse)
    rng = np.random.default_rng(29)
    run = simulate_pass(rng, duration=30.0)
    prior = drawn_prior(rng, run, prior_covariance(np.radians(3.0)))
    pass_ = make_pass(run.gyro, run.t, run.measurements, prior)
    history = BatchSmoother(initialisation="gyro").solve(pass_).report.history
    assert not history[0][4] and history[1][4]  # rejected, then accepted
    accepted = sum(step[4] for step in history)
    assert len(linearised) <= accepted + 1 < len(history) + 1


def test_the_marginals_use_the_optimisers_last_linearisation(monkeypatch):
    """A run that stops on the decrease its last linearisation predicts hands that
    linearisation on: the marginals do not linearise the problem again, and their
    covariances are those of a fresh linearisation at the solution."""
    calls = []
    linearize = SmootherProblem.linearize

    def counted(problem, values):
        calls.append(values)
        return linearize(problem, values)

    monkeypatch.setattr(SmootherProblem, "linearize", counted)
    rng = np.random.default_rng(29)
    run = simulate_pass(rng, duration=30.0)
    prior = drawn_prior(rng, run, prior_covariance(np.radians(3.0)))
    pass_ = make_pass(run.gyro, run.t, run.measurements, prior)
    track = BatchSmoother(initialisation="gyro").solve(pass_)
    report = track.report
    assert report.history and report.history[-1][4]  # it stepped, then converged
    accepted = sum(step[4] for step in report.history)
    assert len(calls) == accepted + 1  # at the start and after each accepted step, no more
    fresh = problem_marginals(report.problem, calls[-1], MarginalOptions()).covariance
    np.testing.assert_array_equal(track.state_covariance, fresh)


def test_with_offsets_the_marginals_use_the_optimisers_last_normal_equations(monkeypatch):
    """The same with transmitter offsets: the normal equations the optimiser stopped on
    give the marginals, without building them again."""
    calls = []
    normal_equations = SmootherProblem.normal_equations

    def counted(problem, values):
        calls.append(values)
        return normal_equations(problem, values)

    given = []

    def recorded(*args):
        given.append(problem_marginals(*args))
        return given[-1]

    monkeypatch.setattr(SmootherProblem, "normal_equations", counted)
    monkeypatch.setattr(smoother_estimators, "problem_marginals", recorded)
    run, prior, _ = _offset_pass(5)
    smoother = OffsetBatchSmoother(offset_sigma=OFFSET_SIGMA)
    report = solve_with(smoother, run.gyro, run.t, run.measurements, prior).report
    assert report.converged and report.history[-1][4]
    accepted = sum(step[4] for step in report.history)
    assert len(calls) == accepted + 1
    fresh = problem_marginals(report.problem, calls[-1], MarginalOptions())
    np.testing.assert_array_equal(given[0].covariance, fresh.covariance)
    np.testing.assert_array_equal(given[0].offset_variances, fresh.offset_variances)


def test_optimiser_from_the_truth_of_a_noise_free_pass_takes_no_step():
    """At the truth the predicted decrease is zero: converged before any trial step."""
    epochs = OFFSET + np.arange(10.0)
    pass_ = _constant_rate_pass(0.0, epochs, _exact_prior(0.0, 1e-3), 1e-6)
    problem, values, _ = _problem(pass_, _truth(epochs), np.tile(BIAS, (epochs.size, 1)))
    result = levenberg_marquardt(
        problem, values.attitudes, values.bias, np.zeros(0), LevenbergMarquardtParams()
    )
    assert result.converged and result.iterations == 0 and result.history == []
    assert result.message == "predicted decrease within tolerance"


def test_a_stretch_of_snrs_the_solution_cannot_predict_is_flagged():
    """Twelve epochs in a row whose SNRs come from behind the antennas (finite values that no
    attitude near the truth can predict: left out as unpredictable), then epochs without
    measurements: the smoother bridges them with the gyro, and its residual test sees
    nothing there; the rejected-stretch rule flags them with the measurement-free epochs
    after them (``batch.rejected_stretches``), and no other epoch."""
    run, prior, _ = _offset_pass(4, epochs=40)
    measurements = list(run.measurements)
    behind = range(20, 32)
    for k in behind:
        epoch = measurements[k].epoch
        measurements[k] = SnrMeasurement(dataclasses.replace(epoch, los_orbit=-epoch.los_orbit))
    for k in range(32, 35):
        measurements[k] = None
    smoother = OffsetBatchSmoother(offset_sigma=OFFSET_SIGMA)  # the pass's 2 dB offsets
    start = fixed_start(run.truth_at_epochs, run.bias_at_epochs)  # a start that is not lost
    result = solve_with(smoother, run.gyro, run.t, measurements, prior, initial=start)
    flagged = np.flatnonzero(~result.valid)
    assert flagged.tolist() == list(range(20, 35))
    assert all(
        r.startswith("inconsistent: at least as many received blocks")
        for r in result.reason[flagged]
    )
    assert all(e is ModelMismatchError for e in result.error[flagged])
    assert result.diagnostics["n_unpredictable"][20] == measurements[20].size


# --- registry estimators in the pipeline ----------------------------------------------------


def test_batch_starts_from_the_online_smoother_else_from_the_rts_pass():
    """``run_estimators`` hands ``fg_batch`` the ``fg_online`` track when both are asked
    for (the same result as solving from it by hand) and otherwise an unreported RTS
    pass; without any start the estimator runs the MEKF and its RTS pass itself and
    reaches the same estimate."""
    rng = np.random.default_rng(43)
    run = simulate_pass(rng, duration=20.0)
    pass_ = make_pass(
        run.gyro, run.t, run.measurements, drawn_prior(rng, run, prior_covariance(0.02))
    )
    both = run_estimators(pass_, ["fg_online", "fg_batch"])
    by_hand = BatchSmoother().solve(pass_, OnlineSmoother().solve(pass_))
    np.testing.assert_array_equal(both["fg_batch"].track.quaternion, by_hand.quaternion)
    assert both["fg_batch"].seconds >= both["fg_online"].seconds
    alone = run_estimators(pass_, {"smoothed": "fg_batch"})
    assert list(alone) == ["smoothed"] and alone["smoothed"].track.report.initialisation == "given"
    from_rts = BatchSmoother().solve(pass_, Rts().solve(pass_))
    np.testing.assert_array_equal(alone["smoothed"].track.quaternion, from_rts.quaternion)
    own = BatchSmoother().solve(pass_)
    assert own.report.initialisation == "mekf+rts"
    np.testing.assert_array_equal(own.quaternion, from_rts.quaternion)


def test_offset_smoother_in_the_pipeline():
    """``fg_batch_offsets`` configured through the registry's keywords estimates the
    transmitters' offsets on an SNR pass, started from the RTS pass."""
    run, prior, offsets = _offset_pass(5, epochs=12)
    pass_ = make_pass(run.gyro, run.t, run.measurements, prior)
    estimator = dataclasses.replace(OffsetBatchSmoother(), offset_sigma=OFFSET_SIGMA)
    track = run_estimators(pass_, {"offsets": estimator})["offsets"].track
    assert track.method == "fg_batch_offsets" and track.report.converged
    z = (track.report.offsets - offsets) / track.report.offset_sigmas
    assert np.mean(z**2) < 3.0


# --- the pass bound -------------------------------------------------------------------------


def test_posterior_bound_of_one_epoch_is_prior_plus_snapshot_information():
    """One epoch at the first gyro sample with exact vectors: the bound is the attitude
    block of ``(P0^-1 + diag(F, 0))^-1`` with ``F`` the snapshot's Fisher information
    (:func:`attopt.solvers.bounds.snapshot_information`), i.e. ``(P0_a^-1 + F)^-1`` for
    a prior without attitude-bias correlation."""
    truth = Rotation.from_euler("xyz", [20.0, -10.0, 40.0], degrees=True)
    references = np.array([[1.0, 0.0, 0.0], [0.0, 0.6, 0.8]])
    snapshot = Snapshot.from_vectors(truth.apply(references), references, [1e-3, 3e-3], t=0.0)
    model = GyroModel("bound", 1e-4, 1e-6, 1e-3, rate_hz=2.0)
    record = GyroRecord(np.array([0.0, 0.5]), np.zeros((1, 3)), model)
    p0 = np.radians(0.1) ** 2
    prior = Prior(truth, np.diag([p0] * 3 + [1e-6] * 3), bias=np.zeros(3))
    pass_ = Pass(np.zeros(1), (snapshot,), record, prior)
    bound = posterior_bound(pass_, Rotation.concatenate([truth]), np.zeros((1, 3)))
    expected = np.linalg.inv(np.eye(3) / p0 + snapshot_information(snapshot, truth))
    np.testing.assert_allclose(bound[0] ** 2, np.diagonal(expected), rtol=1e-6)
    with pytest.raises(InvalidObservationError, match="initial estimate has 2 epochs"):
        posterior_bound(pass_, Rotation.concatenate([truth, truth]), np.zeros((2, 3)))


def test_the_bounds_module_has_every_bound():
    assert posterior_bound_ekf is eks_bound
