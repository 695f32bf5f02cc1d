"""Gyro model of Liu et al. 2023 eqs. 23-25 (``formulations/gyro.py``): discretisation,
error-state convention and the simulator's statistics.

The error state is ``[delta, delta_beta]`` with ``A_true = exp(delta) A_est``
(body frame) and ``delta_beta = beta - beta_hat``; its continuous model is
``F = [[-[w x], I], [0, 0]]``, ``G = I6`` on the noises ``[eta_v, eta_u]`` of
power spectral density ``Qc = diag(sigma_v^2 I3, sigma_u^2 I3)``.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st
from scipy.linalg import expm
from scipy.spatial.transform import Rotation

from attopt.formulations.gyro import (
    GYRO_MODELS,
    LIU2023_GYRO,
    MEMS_GYRO,
    GyroModel,
    attitude_increment,
    error_state_transition,
    mean_rates,
    simulate_gyro,
)

TEST_GYRO = GyroModel("test", sigma_v=3e-4, sigma_u=2e-5, initial_bias_sigma=1e-3, rate_hz=10.0)


def cross(w: np.ndarray) -> np.ndarray:
    return np.array([[0.0, -w[2], w[1]], [w[2], 0.0, -w[0]], [-w[1], w[0], 0.0]])


def continuous_model(rate: np.ndarray) -> np.ndarray:
    """``F`` of the error state at estimated rate ``rate``."""
    f = np.zeros((6, 6))
    f[:3, :3] = -cross(rate)
    f[:3, 3:] = np.eye(3)
    return f


def van_loan(model: GyroModel, rate: np.ndarray, dt: float) -> np.ndarray:
    """Discrete process noise by Van Loan's method (Van Loan 1978).

    ``expm([[-F, G Qc G^T], [0, F^T]] dt) = [[., M12], [0, M22]]`` gives
    ``Phi = M22^T`` and ``Q = int_0^dt Phi(s) G Qc G^T Phi(s)^T ds = Phi M12``.
    """
    f = continuous_model(rate)
    qc = np.diag([model.sigma_v**2] * 3 + [model.sigma_u**2] * 3)
    block = np.block([[-f, qc], [np.zeros((6, 6)), f.T]]) * dt
    m = expm(block)
    q = m[6:, 6:].T @ m[:6, 6:]
    return 0.5 * (q + q.T)


def blockwise_relative_error(q: np.ndarray, reference: np.ndarray) -> list[float]:
    """Largest entry difference of each 3x3 block over the block's largest entry
    (the blocks differ in scale by many orders of magnitude)."""
    errors = []
    for rows in (slice(0, 3), slice(3, 6)):
        for cols in (slice(0, 3), slice(3, 6)):
            ref = reference[rows, cols]
            errors.append(float(np.abs(q[rows, cols] - ref).max() / np.abs(ref).max()))
    return errors


# --- discretisation -------------------------------------------------------------------


@pytest.mark.parametrize("model", [LIU2023_GYRO, MEMS_GYRO, TEST_GYRO], ids=lambda m: m.name)
@pytest.mark.parametrize("dt", [0.1, 1.0, 10.0])
def test_process_noise_is_van_loan_at_zero_rate(model, dt):
    """Exact for a non-rotating body: Q11 = sigma_v^2 dt + sigma_u^2 dt^3/3,
    Q12 = +sigma_u^2 dt^2/2, Q22 = sigma_u^2 dt (all three times I3)."""
    reference = van_loan(model, np.zeros(3), dt)
    q = model.process_noise(dt)
    assert max(blockwise_relative_error(q, reference)) < 1e-12
    np.testing.assert_array_equal(q, q.T)
    # the sign of Q12 is + in this error convention (a positive bias error
    # makes the attitude error grow positively, d delta/dt = ... + delta_beta)
    assert np.all(np.diag(q[:3, 3:]) > 0)


def test_process_noise_is_first_order_in_rate():
    """At a rate ``w`` the exact ``Q`` differs from the zero-rate formula at first
    order in ``|w| dt``: ``Q12`` gains ``-sigma_u^2 dt^3/6 [w x]``, a relative
    change of ``|w| dt / 3`` (entrywise ``max|w_i| dt / 3``); ``Q11`` and
    ``Q22`` change at second order or not at all (rotations leave the
    isotropic parts invariant).  The tolerance
    is therefore ``|w| dt`` (= 1e-3 here, 0.01 rad/s over 0.1 s), and the
    error must halve with the rate."""
    model, dt = TEST_GYRO, 0.1
    direction = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
    q = model.process_noise(dt)
    errors = {}
    for magnitude in (0.01, 0.005):
        errors[magnitude] = blockwise_relative_error(q, van_loan(model, magnitude * direction, dt))
        assert max(errors[magnitude]) < magnitude * dt
    q11, q12, _, q22 = errors[0.01]
    # the largest entry of sigma_u^2 dt^3/6 [w x] over that of sigma_u^2 dt^2/2 I
    assert q12 == pytest.approx(np.abs(0.01 * direction).max() * dt / 3.0, rel=0.01)
    assert q11 < 1e-6 and q22 < 1e-12
    assert errors[0.01][1] / errors[0.005][1] == pytest.approx(2.0, rel=1e-3)


@st.composite
def rates_and_steps(draw):
    """A rate of log-uniform magnitude (``|w dt|`` from 1e-9 to 3 rad, so the
    Taylor branch below 1e-3 rad is exercised) and a step."""
    direction = np.array(draw(st.lists(st.floats(-1, 1), min_size=3, max_size=3)))
    if np.linalg.norm(direction) < 1e-3:
        direction = np.array([0.3, -0.5, 0.8])
    dt = draw(st.sampled_from([0.01, 0.1, 1.0]))
    angle = 10.0 ** draw(st.floats(-9.0, math.log10(3.0)))
    return direction / np.linalg.norm(direction) * angle / dt, dt


@settings(max_examples=200, deadline=None)
@given(rates_and_steps())
@example((np.zeros(3), 0.1))
@example((np.array([0.0, 0.0, 0.999e-3]), 1.0))  # just below the series limit
@example((np.array([0.0, 1.001e-3, 0.0]), 1.0))  # just above it
def test_error_state_transition_is_expm(case):
    rate, dt = case
    phi = error_state_transition(rate, dt)
    expected = expm(continuous_model(rate) * dt)
    np.testing.assert_allclose(phi[:3, :3], expected[:3, :3], rtol=0, atol=1e-12)
    np.testing.assert_allclose(phi[:3, 3:], expected[:3, 3:], rtol=0, atol=1e-12 * dt)
    np.testing.assert_array_equal(phi[3:, :3], 0.0)
    np.testing.assert_array_equal(phi[3:, 3:], np.eye(3))
    # Phi11 is the rotation matrix of the attitude increment
    np.testing.assert_allclose(
        phi[:3, :3], attitude_increment(rate, dt).as_matrix(), rtol=0, atol=1e-13
    )


def test_error_state_transition_exactly_zero_rate():
    phi = error_state_transition(np.zeros(3), 0.5)
    expected = np.eye(6)
    expected[:3, 3:] = 0.5 * np.eye(3)
    np.testing.assert_array_equal(phi, expected)


def test_error_state_transition_is_vectorised():
    rng = np.random.default_rng(3)
    rates = rng.normal(scale=[[0.1], [1e-5], [3.0], [0.0]], size=(4, 3))
    stacked = error_state_transition(rates.reshape(2, 2, 3), 0.2)
    assert stacked.shape == (2, 2, 6, 6)
    for i, rate in enumerate(rates):
        np.testing.assert_array_equal(
            stacked.reshape(4, 6, 6)[i], error_state_transition(rate, 0.2)
        )


# --- the error convention ---------------------------------------------------------------


def test_linearised_error_propagation_matches_two_nonlinear_attitudes():
    """Pins ``d delta/dt = -[w_hat x] delta + delta_beta`` (the ``+`` sign).

    The truth and the estimate are carried by the same noise-free gyro samples,
    the truth with the true bias and the estimate with a wrong one; the error
    ``delta = rotvec(A_true A_est^T)`` after 20 s must be the product of the
    transitions applied to the initial ``[delta, delta_beta]``, to second
    order in the error (here ~2e-4 rad, so ~1e-7).  The opposite sign of
    ``delta_beta`` would be off by ``2 delta_beta T`` = 4e-4 rad.
    """
    dt, steps = 0.1, 200
    t = np.arange(steps) * dt
    true_rates = np.stack(
        [0.05 * np.sin(0.3 * t), 0.02 + 0.01 * np.cos(0.2 * t), -0.03 * np.ones_like(t)], axis=1
    )
    bias = np.array([2e-3, -1e-3, 5e-4])
    delta_beta = np.array([1e-5, -6e-6, 8e-6])  # beta - beta_hat
    delta0 = np.array([5e-5, -4e-5, 3e-5])
    measured = true_rates + bias
    estimated_rates = measured - (bias - delta_beta)

    truth = Rotation.from_euler("xyz", [30.0, -20.0, 100.0], degrees=True)
    estimate = Rotation.from_rotvec(-delta0) * truth  # A_true = exp(delta0) A_est
    phi = np.eye(6)
    for j in range(steps):
        truth = attitude_increment(true_rates[j], dt) * truth
        estimate = attitude_increment(estimated_rates[j], dt) * estimate
        phi = error_state_transition(estimated_rates[j], dt) @ phi

    nonlinear = (truth * estimate.inv()).as_rotvec()
    linear = (phi @ np.concatenate([delta0, delta_beta]))[:3]
    assert np.linalg.norm(nonlinear) > 1e-4
    np.testing.assert_allclose(linear, nonlinear, rtol=0, atol=1e-7)
    wrong_sign = (phi @ np.concatenate([delta0, -delta_beta]))[:3]
    assert np.linalg.norm(wrong_sign - nonlinear) > 1e-4


# --- simulator ---------------------------------------------------------------------------


def _spinning_truth(t: np.ndarray, rate: np.ndarray) -> Rotation:
    start = Rotation.from_euler("xyz", [10.0, 20.0, 30.0], degrees=True)
    return Rotation.from_rotvec(-np.outer(t, rate)) * start


def test_simulated_rate_noise_has_the_documented_variance():
    """``measured - true rate - bias midpoint`` is white with variance
    ``sigma_v^2/dt + sigma_u^2 dt/12`` per axis (the two terms comparable here:
    9.0e-7 and 8.3e-7, so dropping the Brownian-bridge term would fail), and
    the bias increments have variance ``sigma_u^2 dt``, independent of it.
    Tolerances: 5 standard errors of a sample variance, ``5 sqrt(2/n)``."""
    model = GyroModel("stats", sigma_v=3e-4, sigma_u=1e-2, initial_bias_sigma=0.05, rate_hz=10.0)
    n = 40_001
    t = np.arange(n) * model.dt
    rate = np.array([0.01, -0.02, 0.015])
    simulated = simulate_gyro(t, _spinning_truth(t, rate), model, np.random.default_rng(11))
    assert simulated.samples.rates.shape == (n - 1, 3)
    np.testing.assert_allclose(simulated.true_rates, np.broadcast_to(rate, (n - 1, 3)), atol=1e-12)

    bias = simulated.bias
    residual = simulated.samples.rates - simulated.true_rates - 0.5 * (bias[:-1] + bias[1:])
    variance = model.sigma_v**2 / model.dt + model.sigma_u**2 * model.dt / 12.0
    tolerance = 5.0 * math.sqrt(2.0 / (n - 1))
    np.testing.assert_allclose(np.abs(residual.mean(axis=0)), 0.0, atol=5 * math.sqrt(variance / n))
    sample = np.cov(residual.T)
    np.testing.assert_allclose(np.diag(sample) / variance, 1.0, atol=tolerance)
    off_diagonal = sample[~np.eye(3, dtype=bool)] / variance
    assert np.abs(off_diagonal).max() < 5.0 / math.sqrt(n)

    increments = np.diff(bias, axis=0)
    step_variance = model.sigma_u**2 * model.dt
    np.testing.assert_allclose(increments.var(axis=0) / step_variance, 1.0, atol=tolerance)
    correlation = np.corrcoef(residual[:, 0], increments[:, 0])[0, 1]
    assert abs(correlation) < 5.0 / math.sqrt(n)


def test_documented_sample_variance_is_the_continuous_models():
    """Independent check of the formula ``simulate_gyro`` uses: a rate-integrating
    gyro averaging the continuous model (simulated on 100 sub-steps) has, about
    the bias midpoint, variance ``sigma_v^2/dt + sigma_u^2 dt/12``."""
    sigma_v, sigma_u, dt, substeps, n = 3e-4, 1e-2, 0.1, 100, 20_000
    rng = np.random.default_rng(5)
    h = dt / substeps
    walk = np.cumsum(sigma_u * math.sqrt(h) * rng.standard_normal((n, substeps)), axis=1)
    start = np.zeros((n, 1))
    edges = np.concatenate([start, walk], axis=1)  # bias at the sub-step edges
    # exact mean of a Brownian path over a sub-step is its edge mean plus an
    # independent N(0, sigma_u^2 h / 12); the white noise averages to N(0, sigma_v^2 / dt)
    bias_mean = (0.5 * (edges[:, :-1] + edges[:, 1:])).mean(axis=1)
    bias_mean += sigma_u * math.sqrt(h / 12.0 / substeps) * rng.standard_normal(n)
    white = sigma_v / math.sqrt(dt) * rng.standard_normal(n)
    residual = bias_mean + white - 0.5 * (edges[:, 0] + edges[:, -1])
    expected = sigma_v**2 / dt + sigma_u**2 * dt / 12.0
    assert residual.var() / expected == pytest.approx(1.0, abs=5.0 * math.sqrt(2.0 / n))


def test_noise_free_gyro_reproduces_the_truth():
    model = GyroModel("perfect", sigma_v=0.0, sigma_u=0.0, initial_bias_sigma=0.0, rate_hz=10.0)
    t = 5.0 + np.arange(1001) * model.dt
    spin = Rotation.from_rotvec(-np.outer(t, [0.02, -0.01, 0.03]))
    wobble = Rotation.from_rotvec(0.3 * np.stack([np.sin(0.1 * t), np.cos(0.07 * t), 0 * t], 1))
    truth = wobble * spin * Rotation.from_euler("zyx", [40.0, -10.0, 170.0], degrees=True)
    simulated = simulate_gyro(t, truth, model, np.random.default_rng(0))
    np.testing.assert_array_equal(simulated.samples.rates, simulated.true_rates)
    np.testing.assert_array_equal(simulated.bias, 0.0)
    np.testing.assert_array_equal(simulated.true_rates, mean_rates(truth, model.dt))
    attitude = truth[0]
    propagated = [attitude]
    for rate in simulated.samples.rates:
        attitude = attitude_increment(rate, model.dt) * attitude
        propagated.append(attitude)
    error = (Rotation.concatenate(propagated) * truth.inv()).magnitude()
    assert error.max() < 1e-12


def test_simulate_gyro_draw_order_is_reproducible():
    t = np.arange(101) * TEST_GYRO.dt
    truth = _spinning_truth(t, np.array([0.01, 0.0, -0.02]))
    a = simulate_gyro(t, truth, TEST_GYRO, np.random.default_rng(7))
    b = simulate_gyro(t, truth, TEST_GYRO, np.random.default_rng(7))
    np.testing.assert_array_equal(a.samples.rates, b.samples.rates)
    # initial bias is the first draw
    first = TEST_GYRO.initial_bias_sigma * np.random.default_rng(7).standard_normal(3)
    np.testing.assert_array_equal(a.bias[0], first)


@pytest.mark.parametrize(
    "times",
    [
        np.array([0.0, 0.1, 0.2, 0.35, 0.4]),  # non-uniform
        np.arange(10) * 0.2,  # uniform, wrong step for 10 Hz
        np.array([0.0]),  # a single time
        np.arange(12).reshape(3, 4) * 0.1,  # not one-dimensional
    ],
    ids=["non-uniform", "wrong-step", "single", "2d"],
)
def test_simulate_gyro_rejects_bad_times(times):
    truth = Rotation.identity(times.size)
    with pytest.raises(ValueError, match="uniform"):
        simulate_gyro(times, truth, TEST_GYRO, np.random.default_rng(0))


@pytest.mark.parametrize(
    "kwargs",
    [
        {"sigma_v": -1e-4},
        {"sigma_u": np.nan},
        {"initial_bias_sigma": np.inf},
        {"rate_hz": 0.0},
    ],
)
def test_gyro_model_rejects_bad_statistics(kwargs):
    values = {"sigma_v": 1e-4, "sigma_u": 1e-6, "initial_bias_sigma": 1e-3} | kwargs
    with pytest.raises(ValueError):
        GyroModel("bad", **values)


# --- the documented models -----------------------------------------------------------------


def test_liu2023_gyro_is_the_papers_numbers_in_si_units():
    """Liu et al. 2023 sec. 5.1: sigma_v = sigma_u = 0.05 deg/s read as 0.05 deg/s^(1/2)
    and 0.05 deg/s^(3/2); 0.1 deg/s initial bias; 10 Hz."""
    assert LIU2023_GYRO.sigma_v == pytest.approx(8.726646259971648e-4, rel=1e-15)
    assert LIU2023_GYRO.sigma_u == pytest.approx(8.726646259971648e-4, rel=1e-15)
    assert LIU2023_GYRO.initial_bias_sigma == pytest.approx(1.7453292519943296e-3, rel=1e-15)
    assert LIU2023_GYRO.rate_hz == 10.0 and LIU2023_GYRO.dt == pytest.approx(0.1)
    # "the bias wanders by 0.05 sqrt(3600) = 3 deg/s per axis in an hour"
    assert math.degrees(LIU2023_GYRO.sigma_u * math.sqrt(3600.0)) == pytest.approx(3.0, rel=1e-12)


def test_mems_gyro_is_the_documented_mems_class():
    """0.3 deg/h^(1/2) angle random walk, 10 deg/h per h^(1/2) rate random walk,
    0.1 deg/s (360 deg/h) turn-on bias."""
    hour = 3600.0
    assert MEMS_GYRO.sigma_v == pytest.approx(8.726646259971648e-5, rel=1e-15)
    assert MEMS_GYRO.sigma_u == pytest.approx(8.080228018492266e-7, rel=1e-14)
    assert MEMS_GYRO.initial_bias_sigma == pytest.approx(1.7453292519943296e-3, rel=1e-15)
    # the same numbers in the datasheet units: angle random walk gives 0.3 deg of
    # attitude spread after an hour, the rate random walk 10 deg/h of bias
    # change after an hour, the turn-on bias 360 deg/h
    assert math.degrees(MEMS_GYRO.sigma_v * math.sqrt(hour)) == pytest.approx(0.3, rel=1e-12)
    assert math.degrees(MEMS_GYRO.sigma_u * math.sqrt(hour)) * hour == pytest.approx(10, rel=1e-12)
    assert math.degrees(MEMS_GYRO.initial_bias_sigma) * hour == pytest.approx(360.0, rel=1e-12)
    assert MEMS_GYRO.rate_hz == 10.0


def test_gyro_registry():
    assert GYRO_MODELS == {"liu2023": LIU2023_GYRO, "mems": MEMS_GYRO}


@given(
    st.integers(0, 2**32 - 1),
    st.integers(1, 12),
    st.integers(1, 20),
    st.integers(0, 2),
    st.integers(0, 30),
)
def test_repeated_readings_are_the_runs_longer_than_the_limit(seed, limit, length, axis, at):
    """Noisy readings never repeat; a run of one axis's reading is stuck exactly when it is
    longer than the limit, and then every sample of it is."""
    from attopt.solvers.gyro_timeline import repeated_readings

    rates = np.random.default_rng(seed).normal(size=(60, 3))
    assert not repeated_readings(rates, limit).any()
    rates[at : at + length, axis] = 0.125
    stuck = repeated_readings(rates, limit)
    expected = np.zeros(60, dtype=bool)
    expected[at : at + length] = length > limit
    np.testing.assert_array_equal(stuck, expected)
    assert not repeated_readings(rates, 0).any()
