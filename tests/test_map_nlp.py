"""The generic MAP NLP (``solvers/map_nlp.py``): noise-free recovery for every measurement
type and a mix, agreement with QUEST and with the SNR NLP, the covariance against Monte
Carlo, the prior term, and bad input."""

from __future__ import annotations

import pickle
from dataclasses import replace

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import (
    AttitudeMeasurement,
    EulerAngleMeasurement,
    VectorMeasurement,
)
from attopt.formulations.doa_crb import stochastic_crb
from attopt.formulations.doa_measurement import DoaMeasurement
from attopt.formulations.errors import (
    ConvergenceError,
    InvalidObservationError,
    UnobservableError,
    UnsupportedMeasurementError,
)
from attopt.formulations.map_problem import MapTerm, map_loss, parameter_vector, prior_error
from attopt.formulations.passes import Pass, Prior
from attopt.formulations.snapshot import Snapshot, StackedMeasurement
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.solvers.bounds import crb, snapshot_information
from attopt.solvers.map_nlp import ESTIMATORS, MAP_NLP, map_solver
from attopt.solvers.nlpsol import NlpOptions
from attopt.solvers.snapshot_sequence import WarmStart
from attopt.solvers.snr import NLP
from attopt.solvers.snr.initialisation import StartSource
from attopt.solvers.wahba import QUEST
from tests.strategies import attitudes, noisy_body
from tests.test_doa_measurement import ARRAY_DOAS, geometry
from tests.test_measurement_model import direction_cosines
from tests.test_snr_solvers import TRUTH, _epoch, _geometry

SIGMA = np.array([1e-3, 2e-3, 5e-3, 3e-3])


def angle(a: Rotation, b: Rotation) -> float:
    return float((a * b.inv()).magnitude())


def _references(seed: int, k: int = 4) -> np.ndarray:
    r = np.random.default_rng(seed).normal(size=(k, 3))
    return r / np.linalg.norm(r, axis=1, keepdims=True)


def _vectors(
    truth: Rotation, seed: int = 0, noise: bool = False, sigma: np.ndarray = SIGMA
) -> VectorMeasurement:
    reference = _references(seed)
    rng = np.random.default_rng(seed + 100)
    body = noisy_body(truth, reference, sigma, rng) if noise else truth.apply(reference)
    return VectorMeasurement(body, reference, sigma)


def _euler(truth: Rotation, sigma: float = 1e-2) -> EulerAngleMeasurement:
    return EulerAngleMeasurement(truth.inv().as_euler("ZYX"), sigma**2 * np.eye(3))


def _doa(truth: Rotation) -> DoaMeasurement:
    los = geometry(truth, Rotation.identity(), np.zeros(3))
    measurement = DoaMeasurement(ARRAY_DOAS, np.tile(np.eye(2), (4, 1, 1)), los)
    angles = measurement.predict(truth)[0].reshape(-1, 2)
    # The near-axis station is measured in direction cosines; give every station its CRB.
    far = ~measurement.near_axis
    covariance = np.tile(np.diag(np.radians([0.05, 0.05]) ** 2), (4, 1, 1))
    covariance[far] = stochastic_crb(angles[far, 0], angles[far, 1], 10.0, 100)
    doas = ARRAY_DOAS.copy()
    return DoaMeasurement(doas, covariance, los)


def test_registry_entry():
    assert ESTIMATORS == (MAP_NLP,) and MAP_NLP.name == "map_nlp"
    assert pickle.loads(pickle.dumps(MAP_NLP)) == MAP_NLP


@settings(max_examples=10, deadline=None)
@given(attitudes())
def test_noise_free_vectors_are_recovered_without_a_prior(truth):
    solution = MAP_NLP.solve(Snapshot.of(_vectors(truth)))
    assert angle(solution.attitude, truth) < 1e-9
    assert solution.loss < 1e-12
    assert solution.diagnostics["start_source"] == StartSource.MULTISTART
    np.testing.assert_allclose(
        solution.covariance, crb(Snapshot.of(_vectors(truth)), truth), rtol=1e-6
    )


@pytest.mark.parametrize("count", [2, 3])
def test_axis_aligned_vectors_are_not_matched_by_a_half_turn(count):
    """The multi-start includes half turns about the axes, which reverse some of these
    vectors exactly: a reversed vector must cost (pi / sigma)^2, not nothing."""
    reference = np.eye(3)[:count]
    solution = MAP_NLP.solve(Snapshot.from_vectors(reference, reference, sigma=1e-3))
    assert solution.attitude.magnitude() < 1e-9 and solution.loss < 1e-12
    half_turn = Rotation.from_rotvec([np.pi, 0.0, 0.0])
    flipped = MAP_NLP.solve(
        Snapshot.from_vectors(half_turn.apply(reference), reference, sigma=1e-3)
    )
    assert angle(flipped.attitude, half_turn) < 1e-9


SOLVERS = pytest.mark.parametrize(
    "options", [NlpOptions(), NlpOptions(solver="sqpmethod")], ids=["ipopt", "sqpmethod"]
)
"""Both ``nlpsol`` plugins (:mod:`attopt.solvers.nlpsol`; more in tests/test_nlp_solvers.py)."""


@SOLVERS
@settings(max_examples=8, deadline=None)
@given(attitudes())
def test_noise_free_vectors_euler_angles_and_doas_are_recovered(options, truth):
    solver = replace(MAP_NLP, options=options)
    for measurement in (_vectors(truth), _euler(truth), _doa(truth)):
        solution = solver.solve(Snapshot.of(measurement))
        assert angle(solution.attitude, truth) < 1e-8, type(measurement).__name__


@SOLVERS
def test_noise_free_snrs_are_recovered_with_and_without_a_start(options):
    problem = _epoch(_geometry(np.random.default_rng(40), TRUTH, (9, 9)))
    snapshot = Snapshot.of(SnrMeasurement(problem))
    start = Rotation.from_rotvec([0.05, -0.04, 0.06]) * TRUTH
    for solver in (replace(NLP, options=options), replace(MAP_NLP, options=options)):
        for prior in (start, None):
            assert angle(solver.solve(snapshot, prior).attitude, TRUTH) < 1e-8


def test_noise_free_mix_of_every_type_is_recovered():
    """Vectors, Euler angles, DOAs, SNRs and a type written only as its symbolic model, all
    of the same attitude (the SNR and DOA geometry is in its reference frame)."""
    measurements = (
        _vectors(TRUTH),
        _euler(TRUTH, 0.05),
        _doa(TRUTH),
        SnrMeasurement(_epoch(_geometry(np.random.default_rng(41), TRUTH, (5, 5)))),
        direction_cosines(TRUTH, _references(7, 1)[0]),
    )
    solution = MAP_NLP.solve(Snapshot.of(*measurements))
    assert angle(solution.attitude, TRUTH) < 1e-9
    bound = crb(Snapshot.of(*measurements), TRUTH)
    np.testing.assert_allclose(solution.covariance, bound, rtol=1e-6)
    # A stacked measurement of the same parts is split into them.
    stacked = MAP_NLP.solve(Snapshot.of(StackedMeasurement(measurements)))
    assert angle(stacked.attitude, solution.attitude) < 1e-12


@settings(max_examples=10, deadline=None)
@given(attitudes())
def test_vectors_agree_with_quest(truth):
    """Geodesic residuals (``theta^2``) versus Wahba's ``2 (1 - cos theta)``: the minimisers
    differ by ``O(sigma^3)``, below 1e-9 rad at sigma <= 1e-3."""
    measurement = _vectors(truth, seed=3, noise=True, sigma=SIGMA / 5.0)
    solution = MAP_NLP.solve(Snapshot.of(measurement), prior=truth)
    quest = QUEST.solve(Snapshot.of(measurement))
    assert angle(solution.attitude, quest.attitude) < 1e-9
    assert angle(quest.attitude, truth) > 1e-5  # noise moved it: the comparison is not trivial
    # Jacobians at the estimate (predicted vectors) versus QUEST's at the measured ones: O(sigma).
    scale = np.abs(quest.covariance).max()
    np.testing.assert_allclose(solution.covariance, quest.covariance, rtol=1e-2, atol=1e-2 * scale)


def test_snrs_agree_with_the_snr_nlp():
    """The same attitude, loss and eq. 22 covariance (the SNR NLP's widening by the
    threshold's selection bias left out: the MAP NLP does not model the threshold)."""
    rng = np.random.default_rng(42)
    geometry = _geometry(rng, TRUTH, (10, 10))
    snapshot = Snapshot.of(SnrMeasurement(_epoch(geometry, geometry[3] + rng.normal(size=20))))
    ours = MAP_NLP.solve(snapshot, prior=TRUTH)
    theirs = replace(NLP, selection_bias=False).solve(snapshot, prior=TRUTH)
    assert angle(ours.attitude, theirs.attitude) < 1e-8
    assert angle(theirs.attitude, TRUTH) > 1e-3
    assert ours.loss == pytest.approx(theirs.loss, rel=1e-9)
    np.testing.assert_allclose(ours.covariance, theirs.covariance, rtol=1e-6)


@pytest.mark.slow
def test_covariance_matches_monte_carlo():
    """Vectors and Euler angles of comparable accuracy: the reported covariance (inverse
    Gauss-Newton Hessian at the estimate) describes the scatter and is the CRB."""
    truth = Rotation.from_rotvec([0.4, -0.7, 1.1])
    reference = _references(5, 2)
    sigma = np.array([2e-3, 4e-3])
    euler_sigma = np.radians([0.2, 0.1, 0.3])
    rng = np.random.default_rng(43)
    trials = 300
    errors = np.empty((trials, 3))
    reported = np.zeros((3, 3))
    for i in range(trials):
        vectors = VectorMeasurement(noisy_body(truth, reference, sigma, rng), reference, sigma)
        angles = truth.inv().as_euler("ZYX") + euler_sigma * rng.standard_normal(3)
        euler = EulerAngleMeasurement(angles, np.diag(euler_sigma**2))
        solution = MAP_NLP.solve(Snapshot.of(vectors, euler), prior=truth)
        errors[i] = (solution.attitude * truth.inv()).as_rotvec()
        reported += solution.covariance / trials
    scatter = errors.T @ errors / trials
    euler = EulerAngleMeasurement(truth.inv().as_euler("ZYX"), np.diag(euler_sigma**2))
    vectors = VectorMeasurement(truth.apply(reference), reference, sigma)
    bound = crb(Snapshot.of(vectors, euler), truth)
    np.testing.assert_allclose(reported, bound, rtol=0.02, atol=0.02 * np.trace(bound))
    assert np.trace(scatter) == pytest.approx(np.trace(reported), rel=0.15)
    assert np.linalg.norm(scatter - reported) < 0.2 * np.trace(reported)
    standard_error = np.sqrt(np.diag(scatter) / trials)
    assert np.all(np.abs(errors.mean(axis=0)) < 4 * standard_error)


def test_prior_term_adds_its_information_and_pulls_towards_the_prior():
    truth = Rotation.from_rotvec([0.1, 0.2, 0.3])
    reference = np.array([[0.0, 0.6, 0.8]])
    body = truth.apply(reference)
    snapshot = Snapshot.of(VectorMeasurement(body, reference, 1e-3))
    alone = MAP_NLP.solve(snapshot, prior=truth)
    assert np.isinf(np.diag(alone.covariance)).all()  # the rotation about A r: unobservable
    covariance = np.diag([1e-4, 2e-4, 3e-4])
    # 0.6 deg about the measured vector: only the prior sees it, so the MAP is the prior.
    prior = Prior(Rotation.from_rotvec(0.01 * body[0]) * truth, covariance)
    solution = MAP_NLP.solve(snapshot, prior=prior)
    assert angle(solution.attitude, prior.attitude) < 1e-8
    assert solution.loss == pytest.approx(0.0, abs=1e-12)
    information = snapshot_information(snapshot, solution.attitude) + np.linalg.inv(covariance)
    np.testing.assert_allclose(solution.covariance, np.linalg.inv(information), rtol=1e-9)
    # Half-way between two priors of equal weight along an observed axis.
    tilt = np.cross(body[0], [1.0, 0.0, 0.0])
    tilt *= 1e-3 / np.linalg.norm(tilt)
    pulled = MAP_NLP.solve(
        snapshot, prior=Prior(Rotation.from_rotvec(tilt) * truth, 1e-6 * np.eye(3))
    )
    error = (pulled.attitude * truth.inv()).as_rotvec()
    np.testing.assert_allclose(error, tilt / 2.0, atol=1e-8)


def test_a_pass_prior_gives_its_covariance():
    truth = Rotation.from_rotvec([0.1, 0.2, 0.3])
    reference = np.array([[0.0, 0.6, 0.8]])
    snapshot = Snapshot.of(VectorMeasurement(truth.apply(reference), reference, 1e-3))
    pass_ = Pass(np.array([0.0, 1.0]), (snapshot, snapshot), prior=Prior(truth, 1e-4 * np.eye(3)))
    track = MAP_NLP.solve_pass(pass_)
    np.testing.assert_array_equal(track.t, [0.0, 1.0])
    assert np.all(np.isfinite(track.covariance[0]))  # the prior term at the first epoch
    assert np.isinf(np.diag(track.covariance[1])).all()  # a start only at the second


def test_prior_error_is_the_mrp_error_relative_to_the_prior():
    v, q = ca.SX.sym("v", 3), ca.SX.sym("q", 4)
    error = ca.Function("e", [v, q], [prior_error(v, q)])
    increment = np.array([0.1, -0.2, 0.05])
    offset = Rotation.from_rotvec([0.2, 0.1, -0.3])
    expected = 4.0 * (Rotation.from_mrp(increment / 4.0) * offset).as_mrp()
    np.testing.assert_allclose(error(increment, offset.as_quat()).full().ravel(), expected)
    np.testing.assert_allclose(error(increment, [0, 0, 0, 1]).full().ravel(), increment)


def test_the_loss_is_the_weighted_innovations_and_the_prior_term():
    """The compiled loss at a point equals ``1/2 sum nu^T R^-1 nu + 1/2 e^T P^-1 e`` from the
    measurements' own numpy innovations."""
    vectors, euler = _vectors(TRUTH, noise=True), _euler(TRUTH)
    start = Rotation.from_rotvec([0.02, 0.01, -0.03]) * TRUTH
    prior = (Rotation.from_rotvec([0.01, 0.0, 0.0]) * TRUTH, np.diag([1e4, 2e4, 3e4]))
    terms = [MapTerm.of(m, start) for m in (vectors, euler)]
    v, p, loss = map_loss(tuple(t.structure for t in terms), True)
    value = float(
        ca.Function("loss", [v, p], [loss])(np.zeros(3), parameter_vector(start, terms, prior))
    )
    expected = 0.0
    for m in (vectors, euler):
        nu = m.innovation(m.predict(start)[0][0])
        expected += (
            0.5
            * nu
            @ np.linalg.solve(
                np.diag(m.noise_covariance) if m.noise_covariance.ndim == 1 else m.noise_covariance,
                nu,
            )
        )
    e = 4.0 * (start * prior[0].inv()).as_mrp()  # the rotation vector to second order
    expected += 0.5 * e @ prior[1] @ e
    assert value == pytest.approx(expected, rel=1e-6)


def test_solver_is_built_once_per_structure_and_pickles():
    terms = (MapTerm.of(_vectors(TRUTH), TRUTH).structure,)
    solver = map_solver(terms, False, NlpOptions())
    assert map_solver(terms, False, NlpOptions()) is solver
    other = MapTerm.of(_vectors(TRUTH, seed=9), TRUTH).structure
    assert map_solver((other,), False, NlpOptions()) is solver  # same types and sizes
    copy = pickle.loads(pickle.dumps(solver))
    p = parameter_vector(TRUTH, [MapTerm.of(_vectors(TRUTH), TRUTH)])
    np.testing.assert_allclose(
        copy(x0=np.zeros(3), p=p)["x"].full(), solver(x0=np.zeros(3), p=p)["x"].full()
    )


def test_sequence_warm_starts_and_flags_bad_epochs():
    truth = [Rotation.from_rotvec([0.1, 0.2, 0.3 + 0.01 * k]) for k in range(3)]
    nan = VectorMeasurement([[np.nan, 0.0, 1.0]] * 2, np.eye(3)[:2], 1e-3)  # NaN rows dropped
    snapshots = [
        Snapshot.of(_vectors(truth[0])),
        None,
        Snapshot.of(nan),
        Snapshot.of(_vectors(truth[2])),
    ]
    track = MAP_NLP.solve_sequence(snapshots)
    np.testing.assert_array_equal(track.valid, [True, False, False, True])
    assert track.error[1] is UnobservableError and track.error[2] is UnobservableError
    assert "no measurement rows" in track.reason[2]
    np.testing.assert_array_equal(track.diagnostics["warm_started"][[0, 3]], [0.0, 1.0])
    assert track.diagnostics["start_source"][3] == StartSource.PRIOR
    assert angle(track.epoch(3).attitude, truth[2]) < 1e-9
    cold = replace(MAP_NLP, warm_start=WarmStart(enabled=False)).solve_sequence(snapshots)
    assert cold.diagnostics["start_source"][3] == StartSource.MULTISTART


def test_ipopt_failure_is_raised_single_and_flagged_in_a_sequence():
    snapshot = Snapshot.of(_vectors(TRUTH, noise=True))
    failing = replace(MAP_NLP, options=NlpOptions(max_iter=1))
    start = Rotation.from_rotvec([0.3, 0.0, 0.0]) * TRUTH
    with pytest.raises(ConvergenceError, match="IPOPT: Maximum_Iterations_Exceeded"):
        failing.solve(snapshot, prior=start)
    track = failing.solve_sequence([snapshot, snapshot], prior=start)
    assert not track.valid.any() and np.isnan(track.quaternion).all()
    assert all(e is ConvergenceError for e in track.error)
    assert (track.diagnostics["local_solves"] == 25).all()  # the start, then 24 multi-starts


class PredictOnly(AttitudeMeasurement):
    """A type with ``predict`` but no symbolic model."""

    def __init__(self) -> None:
        self.z, self.noise_covariance, self.blocks = np.zeros(1), np.ones(1), np.zeros(1, int)

    def predict(self, attitude, jacobian=True):
        return np.zeros((1, 1)), (np.zeros((1, 1, 3)) if jacobian else None)


def test_bad_input_raises_or_is_flagged():
    with pytest.raises(UnsupportedMeasurementError, match="PredictOnly"):
        MAP_NLP.solve(Snapshot.of(_vectors(TRUTH), PredictOnly()))
    with pytest.raises(UnsupportedMeasurementError):
        MAP_NLP.solve_sequence([Snapshot.of(_vectors(TRUTH)), Snapshot.of(PredictOnly())])
    problem = _epoch(_geometry(np.random.default_rng(44), TRUTH, (5, 5)))
    corrupt = SnrMeasurement(problem)
    corrupt.z = corrupt.z.copy()
    corrupt.z[3] = np.nan
    with pytest.raises(InvalidObservationError, match="finite"):
        MAP_NLP.solve(Snapshot.of(corrupt), prior=TRUTH)
