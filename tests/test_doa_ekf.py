"""The EKF of seed 003 (``solvers/doa/ekf.py``): step model, transition matrix, convergence."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from experiments.scenarios.doa_ground import (
    FILTER_INITIAL_EULER_DEG,
    FILTER_INITIAL_RATE_DEG_S,
    WHEEL_MOMENTUM,
    build_geometry,
)
from formulations.attitude_measurement import VectorMeasurement
from formulations.conventions import attitude_error, attitude_from_euler321
from solvers.doa.ekf import INERTIA_SEED003, EkfPrior, run_ekf, step_function

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
