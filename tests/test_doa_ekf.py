"""The EKF of seed 003 (``solvers/doa/ekf.py``): step model, transition matrix, convergence,
the CasADi pass against the Python loop, the update against the textbook Joseph form."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from attopt.experiments.doa_ground.scenario import (
    FILTER_INITIAL_EULER_DEG,
    FILTER_INITIAL_RATE_DEG_S,
    WHEEL_MOMENTUM,
    build_geometry,
)
from attopt.formulations.attitude_measurement import VectorMeasurement
from attopt.formulations.conventions import attitude_error, attitude_from_euler321
from attopt.formulations.errors import ConvergenceError
from attopt.solvers.doa.ekf import (
    INERTIA_SEED003,
    MAX_STEP_ANGLE,
    EkfPrior,
    EkfResult,
    run_ekf,
    run_ekf_vectors,
    step_function,
    update_function,
)
from attopt.solvers.filters.common import apply_error

PASS_S = 1200.0
STEP_S = 1.0
"""Coarser than the seed's 250 ms to keep the test cheap; the model is the same."""


def _step(omega: np.ndarray, attitude: np.ndarray, turn: np.ndarray):
    function = step_function(STEP_S, tuple(INERTIA_SEED003.ravel()))
    return [x.full() for x in function(omega, attitude, WHEEL_MOMENTUM, turn)]


def test_step_reproduces_the_rigid_body_truth() -> None:
    """One filter step from the true state lands on the scenario's solve_ivp truth (eqs. 23-24)."""
    geometry = build_geometry(PASS_S, STEP_S)
    turns = geometry.orbit_turns().as_matrix()
    for k in (0, 300, 1000):
        omega, attitude, _ = _step(geometry.rate[k], geometry.truth[k].as_matrix(), turns[k])
        error = attitude_error(Rotation.from_matrix(attitude), geometry.truth[k + 1])
        assert np.linalg.norm(error) < 1e-9
        np.testing.assert_allclose(omega.ravel(), geometry.rate[k + 1], atol=1e-12)


def test_transition_matrix_matches_finite_differences() -> None:
    """The AD transition matrix is the derivative of the step map in the error state (eq. 28)."""
    rng = np.random.default_rng(3)
    omega = np.radians([0.5, -0.3, 0.4])
    attitude = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    turn = Rotation.from_rotvec([0.0, -2.7e-4, 0.0]).as_matrix()
    omega1, attitude1, transition = _step(omega, attitude, turn)
    eps = 1e-6
    numeric = np.empty((6, 6))
    for i in range(6):
        d = np.zeros(6)
        d[i] = eps
        start = Rotation.from_rotvec(d[3:]).as_matrix() @ attitude
        w, a, _ = _step(omega + d[:3], start, turn)
        numeric[:3, i] = (w - omega1).ravel() / eps
        numeric[3:, i] = Rotation.from_matrix(a @ attitude1.T).as_rotvec() / eps
    np.testing.assert_allclose(transition, numeric, atol=1e-6)


def test_converges_from_the_paper_initial_condition_noise_free() -> None:
    """From yaw = pitch = roll = 50 deg and 0.5 deg/s per axis (sec. 6) to the truth."""
    geometry = build_geometry(PASS_S, STEP_S)
    reference = geometry.line_of_sight_km / np.linalg.norm(
        geometry.line_of_sight_km, axis=-1, keepdims=True
    )
    measurements = []
    for k in range(geometry.t.size):
        visible = geometry.visible[k]
        body = geometry.truth[k].apply(reference[k, visible])
        measurements.append(VectorMeasurement(body, reference[k, visible], np.radians(0.3)))
    prior = EkfPrior(
        attitude_from_euler321(*np.radians(FILTER_INITIAL_EULER_DEG)),
        np.radians(FILTER_INITIAL_RATE_DEG_S),
        np.diag(np.radians([0.5] * 3 + [60.0] * 3) ** 2),
    )
    result = run_ekf(prior, measurements, geometry.orbit_turns(), WHEEL_MOMENTUM, STEP_S)
    error = np.degrees(np.linalg.norm(attitude_error(result.attitude, geometry.truth), axis=1))
    rate_error = np.degrees(np.linalg.norm(result.rate - geometry.rate, axis=1))
    assert np.degrees(np.linalg.norm(attitude_error(prior.attitude, geometry.truth[0]))) > 50.0
    assert error[-1] < 1e-3
    assert rate_error[-1] < 1e-4
    assert result.updates[-1] == 3 * geometry.visible[-1].sum()


# --- synthetic passes of the filter's own model ---------------------------------------------------

DT = 0.25
RATE0 = np.array([0.02, -0.015, 0.01])
"""Initial true rate (rad/s): the dynamics (Euler's equation with the wheel) matter."""
REFERENCES = np.array([[0.3, 0.1, 0.95], [-0.5, 0.4, 0.77], [0.1, -0.6, 0.8]])
REFERENCES = REFERENCES / np.linalg.norm(REFERENCES, axis=1, keepdims=True)
SIGMA = 0.005
"""Vector noise per axis (rad)."""
ORBIT_TURN = Rotation.from_rotvec([0.0, -1.1e-3 * DT, 0.0])


@dataclass
class VectorPass:
    """Truth from the filter's own step map (plus process noise), vectors with NaN rows."""

    truth: Rotation
    rate: np.ndarray
    body: np.ndarray
    reference: np.ndarray
    sigma: np.ndarray
    turns: Rotation

    def measurements(self) -> list[VectorMeasurement]:
        return [VectorMeasurement(*(x[k] for x in self.arrays)) for k in range(len(self.truth))]

    @property
    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.body, self.reference, self.sigma


def simulate_vectors(
    rng: np.random.Generator,
    n: int,
    process_noise: float = 0.0,
    noisy: bool = True,
    presence: float = 0.6,
) -> VectorPass:
    """``n`` epochs ``DT`` apart; each reference vector seen with probability
    ``presence`` per epoch; truth with ``Q = process_noise E_6`` per step."""
    step = step_function(DT, tuple(INERTIA_SEED003.ravel()))
    turn = ORBIT_TURN.as_matrix()
    rate, attitude = RATE0.copy(), Rotation.random(random_state=rng)
    rates, attitudes = [], []
    for _ in range(n):
        rates.append(rate)
        attitudes.append(attitude)
        w, a, _ = step(rate, attitude.as_matrix(), WHEEL_MOMENTUM, turn)
        noise = rng.normal(0.0, np.sqrt(process_noise), 6)
        rate = w.full().ravel() + noise[:3]
        attitude = apply_error(noise[3:], Rotation.from_matrix(a.full()))
    truth = Rotation.concatenate(attitudes)
    reference = np.broadcast_to(REFERENCES, (n, *REFERENCES.shape)).copy()
    body = np.einsum("nij,nsj->nsi", truth.as_matrix(), reference)
    if noisy:
        body += SIGMA * rng.standard_normal(body.shape)
        body /= np.linalg.norm(body, axis=-1, keepdims=True)
    body[rng.random(body.shape[:2]) > presence] = np.nan
    sigma = np.full(body.shape[:2], SIGMA)
    return VectorPass(
        truth, np.array(rates), body, reference, sigma, Rotation.concatenate([ORBIT_TURN] * (n - 1))
    )


def drawn_prior(rng: np.random.Generator, run: VectorPass, covariance: np.ndarray) -> EkfPrior:
    """Prior whose error ``[delta_omega, delta]`` (``A_true = C(delta) A_est``) is drawn
    from ``covariance``."""
    error = rng.multivariate_normal(np.zeros(6), covariance)
    return EkfPrior(apply_error(-error[3:], run.truth[0]), run.rate[0] - error[:3], covariance)


def run_fast(run: VectorPass, prior: EkfPrior, process_noise: float) -> EkfResult:
    return run_ekf_vectors(
        prior, *run.arrays, run.turns, WHEEL_MOMENTUM, DT, process_noise=process_noise
    )


def relative_covariance_difference(p: np.ndarray, reference: np.ndarray) -> float:
    """Largest ``|p_ij - r_ij| / sqrt(r_ii r_jj)``."""
    scale = np.sqrt(np.diagonal(reference, axis1=-2, axis2=-1))
    return float(np.max(np.abs(p - reference) / (scale[..., :, None] * scale[..., None, :])))


def test_fast_path_equals_the_generic_loop_on_a_noisy_pass() -> None:
    """``run_ekf_vectors`` (epochs in CasADi, fixed slots) against ``run_ekf`` with one
    ``VectorMeasurement`` per epoch (Python loop, rows left out), from a 40-deg
    initial error (large geodesic innovations), NaN vectors and empty epochs:
    attitudes within 1e-9 rad, rates, transition matrices and covariances
    within 1e-8 of their scale, the predicted states alike.  (Rounding
    differences of the innovations, 1e-15, grow to about 2e-10 rad/s in the
    rates of the first epochs, whose covariance has a condition number of 2e4.)"""
    rng = np.random.default_rng(7)
    run = simulate_vectors(rng, 240, process_noise=1e-9)
    covariance = np.diag([1e-4] * 3 + [np.radians(40.0) ** 2] * 3)
    prior = EkfPrior(
        apply_error(np.radians([25.0, -25.0, 20.0]), run.truth[0]), run.rate[0], covariance
    )
    fast = run_fast(run, prior, 1e-9)
    loop = run_ekf(prior, run.measurements(), run.turns, WHEEL_MOMENTUM, DT, process_noise=1e-9)
    start = np.degrees(np.linalg.norm(attitude_error(prior.attitude, run.truth[0])))
    end = np.degrees(np.linalg.norm(attitude_error(fast.attitude[-1], run.truth[-1])))
    assert start > 35.0 and end < 1.0
    assert (fast.updates == 0).any() and (fast.updates == 9).any()
    np.testing.assert_array_equal(fast.updates, loop.updates)
    for name in ("attitude", "predicted_attitude"):
        error = attitude_error(getattr(fast, name), getattr(loop, name))
        assert np.radians(np.abs(error).max()) < 1e-9, name
    for name in ("rate", "predicted_rate", "transition"):
        expected = getattr(loop, name)
        np.testing.assert_allclose(
            getattr(fast, name), expected, atol=1e-8 * np.abs(expected).max()
        )
    for name in ("covariance", "predicted_covariance"):
        assert relative_covariance_difference(getattr(fast, name), getattr(loop, name)) < 1e-8


def test_update_is_the_textbook_joseph_update() -> None:
    """The information-form update (``M``, ``z``, a 3 x 3 solve) against the batch
    Joseph form ``K = P H^T (H P H^T + R)^-1``, ``H = [0, J]``, with the attitude
    corrected by ``Rotation.from_mrp(K nu / 4)`` (the previous implementation's maths)."""
    rng = np.random.default_rng(11)
    root = rng.normal(size=(6, 6))
    covariance = root @ root.T * 1e-3 + 1e-6 * np.eye(6)
    jacobian, variance = rng.normal(size=(7, 3)), rng.uniform(1e-4, 1e-3, 7)
    innovation, rate = rng.normal(size=7) * 0.01, rng.normal(size=3) * 0.01
    attitude = Rotation.random(random_state=rng)
    h = np.hstack([np.zeros((7, 3)), jacobian])
    gain = np.linalg.solve(h @ covariance @ h.T + np.diag(variance), h @ covariance).T
    keep = np.eye(6) - gain @ h
    expected = keep @ covariance @ keep.T + gain @ np.diag(variance) @ gain.T
    correction = gain @ innovation
    information = jacobian.T @ (jacobian / variance[:, None])
    residual = jacobian.T @ (innovation / variance)
    new_rate, new_attitude, posterior = (
        x.full()
        for x in update_function()(rate, attitude.as_matrix(), covariance, information, residual)
    )
    np.testing.assert_allclose(new_rate.ravel(), rate + correction[:3], rtol=1e-12, atol=1e-16)
    expected_attitude = Rotation.from_mrp(correction[3:] / 4.0) * attitude
    np.testing.assert_allclose(new_attitude, expected_attitude.as_matrix(), rtol=0, atol=1e-14)
    assert relative_covariance_difference(posterior, expected) < 1e-12


def test_an_epoch_without_vectors_is_exactly_no_update() -> None:
    """Absent slots carry zero weight: an epoch without vectors returns its
    predicted state bit for bit, and absent slots beside present ones change nothing."""
    rng = np.random.default_rng(2)
    run = simulate_vectors(rng, 120, presence=0.4)
    prior = drawn_prior(rng, run, np.diag([1e-6] * 3 + [1e-4] * 3))
    result = run_fast(run, prior, 1e-9)
    empty = result.updates == 0
    assert empty.sum() > 10
    np.testing.assert_array_equal(result.covariance[empty], result.predicted_covariance[empty])
    np.testing.assert_array_equal(result.rate[empty], result.predicted_rate[empty])
    np.testing.assert_array_equal(
        result.attitude[empty].as_matrix(), result.predicted_attitude[empty].as_matrix()
    )
    padded = [np.concatenate([x, np.full_like(x[:, :2], np.nan)], axis=1) for x in run.arrays]
    padded[2][:, -2:] = 1.0
    again = run_ekf_vectors(prior, *padded, run.turns, WHEEL_MOMENTUM, DT, process_noise=1e-9)
    np.testing.assert_array_equal(again.covariance, result.covariance)


def test_noise_free_run_from_the_truth_stays_at_the_truth() -> None:
    """Exact vectors of a truth that follows the filter's step map, prior at the
    truth: the estimate stays on it to rounding over 600 epochs."""
    rng = np.random.default_rng(4)
    run = simulate_vectors(rng, 600, noisy=False)
    prior = EkfPrior(run.truth[0], run.rate[0], np.diag([1e-6] * 3 + [1e-4] * 3))
    result = run_fast(run, prior, 1e-9)
    assert np.radians(np.abs(attitude_error(result.attitude, run.truth)).max()) < 1e-12
    np.testing.assert_allclose(result.rate, run.rate, rtol=0, atol=1e-14)


@pytest.mark.parametrize("fast", [True, False], ids=["run_ekf_vectors", "run_ekf"])
def test_a_rate_beyond_the_step_limit_raises(fast: bool) -> None:
    """``MAX_STEP_ANGLE`` per step: reported with the first epoch that exceeds it."""
    rng = np.random.default_rng(5)
    run = simulate_vectors(rng, 20, noisy=False)
    rate = np.array([0.0, 0.0, 1.1 * MAX_STEP_ANGLE / DT])
    prior = EkfPrior(run.truth[0], rate, np.diag([1e-12] * 3 + [1e-4] * 3))
    with pytest.raises(ConvergenceError, match="at epoch 0"):
        if fast:
            run_fast(run, prior, 1e-9)
        else:
            run_ekf(prior, run.measurements(), run.turns, WHEEL_MOMENTUM, DT)
