"""Batch factor-graph smoother (``solvers/smoother``): conventions, exactness, consistency, faults.

Scenario (unless a test says otherwise): a body turning at a constant
``(0.01, -0.02, 0.015)`` rad/s relative to the inertial frame, a gyro sampled
at 2 Hz, and at 1 Hz two inertial unit vectors measured in the body with
``sigma`` per axis (:class:`~attopt.formulations.attitude_measurement.VectorMeasurement`).

Error convention: ``delta = rotvec(A_true A_est^T) = -attitude_error(A_est,
A_true)`` and ``delta_beta = beta - beta_hat`` (``docs/filters.md``); GTSAM's
``Rot3`` is ``R = A^T`` with ``R.retract(xi) = R Exp(xi)``, so ``delta =
-xi`` (:mod:`attopt.solvers.smoother.conventions`).
"""

from __future__ import annotations

import dataclasses
import math

import gtsam
import numpy as np
import pytest
from gtsam.utils.numerical_derivative import (
    numericalDerivative11,
    numericalDerivative21,
    numericalDerivative22,
)
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import EulerAngleMeasurement, VectorMeasurement
from attopt.formulations.conventions import attitude_error
from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.gain_patterns import LIU2023_HELIX
from attopt.formulations.gyro import GyroModel, GyroSamples, attitude_increment, simulate_gyro
from attopt.formulations.passes import Prior
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.formulations.snr_problem import SnrEpoch
from attopt.solvers.filters import FilterOptions, Mekf
from attopt.solvers.filters.common import prepare_gyro
from attopt.solvers.filters.rts import rts_smooth
from attopt.solvers.gyro_timeline import gyro_timeline
from attopt.solvers.results import Track
from attopt.solvers.smoother import (
    BatchSmoother,
    GraphOptions,
    LevenbergMarquardtParams,
    single_frame_initial,
)
from attopt.solvers.smoother.conventions import (
    attitude_key,
    bias_key,
    retract,
    rot3,
    to_values,
)
from attopt.solvers.smoother.gyro_factors import JointPrior, gyro_graph, gyro_intervals
from attopt.solvers.smoother.measurement_factors import prepare_factor
from tests.filter_passes import (
    GYRO,
    RATE,
    REFERENCES,
    SIGMA,
    SimulatedPass,
    drawn_prior,
    prior_covariance,
    simulate_pass,
    solve_with,
)
from tests.test_snr_solvers import BORESIGHTS, BUDGET, TRUTH, _geometry

COARSE = GyroModel("coarse-2hz", 2e-3, 2e-4, 0.01, rate_hz=2.0)
"""A poor gyro: the measurements and the gyro both matter (well-conditioned brute force)."""
TIGHT = BatchSmoother(
    optimiser=LevenbergMarquardtParams(relative_tolerance=1e-15, absolute_tolerance=1e-14)
)
"""Tolerances for comparisons at 1e-8: stop only at the rounding floor."""


def state_errors(result, run: SimulatedPass) -> np.ndarray:
    """``(N, 6)`` errors ``[delta, beta - beta_hat]`` at the epochs."""
    assert result.valid.all(), set(result.reason)
    delta = -attitude_error(result.attitude(), run.truth_at_epochs)
    return np.concatenate([delta, run.bias_at_epochs - result.bias], axis=1)


def rms_deg(result, run: SimulatedPass, skip: int = 0) -> float:
    error = attitude_error(result.attitude(), run.truth_at_epochs)[skip:]
    return float(np.degrees(np.sqrt(np.mean(np.sum(error**2, axis=1)))))


# --- conventions -------------------------------------------------------------------------------


def test_noise_free_pass_recovers_truth_and_bias():
    """Noise-free gyro (constant unknown bias of 0.1 deg/s class) and vectors declared
    precise (``sigma = 1e-6`` rad), a 20 deg prior error: the attitude comes back
    to 1e-10 rad and the bias to 1e-10 rad/s at every epoch (measured: about
    1e-12 rad and 1e-13 rad/s; the residual pull of the priors is of that order)."""
    rng = np.random.default_rng(1)
    bias_only = GyroModel("bias-only", 0.0, 0.0, GYRO.initial_bias_sigma, GYRO.rate_hz)
    declared = GyroModel("declared", 1e-7, 1e-9, GYRO.initial_bias_sigma, GYRO.rate_hz)
    run = simulate_pass(rng, duration=60.0, sigma=1e-6, noisy=False, simulated_gyro=bias_only)
    axis = np.array([1.0, 1.0, -1.0]) / math.sqrt(3.0)
    prior = Prior(
        Rotation.from_rotvec(np.radians(20.0) * axis) * run.truth[0],
        prior_covariance(np.radians(20.0), declared),
        bias=np.zeros(3),
    )
    result = solve_with(TIGHT, run.gyro, run.t, run.measurements, prior, declared)
    assert result.report.converged, result.report.message
    errors = state_errors(result, run)
    assert np.abs(errors[:, :3]).max() < 1e-10
    assert np.abs(errors[:, 3:]).max() < 1e-10


def _ahrs_pass(rng: np.random.Generator):
    """Noise-free gyro samples of a known motion with a known bias at 10 Hz over 3 s."""
    dt, bias = 0.1, np.array([2e-3, -1e-3, 3e-3])
    rates = 0.2 * rng.standard_normal((30, 3))
    attitudes = [Rotation.random(random_state=rng)]
    for w in rates:
        attitudes.append(attitude_increment(w, dt) * attitudes[-1])
    samples = GyroSamples(np.arange(31) * dt, rates + bias, dt)
    return samples, Rotation.concatenate(attitudes), bias


def test_ahrs_factor_follows_attitude_increment():
    """The AHRS factor built from gyro samples has zero error exactly where
    :func:`attopt.formulations.gyro.attitude_increment` carries ``A_i`` to ``A_j``
    (with ``R = A^T``, a nonzero bias removed).  A body-frame error ``delta`` at
    ``A_j``, i.e. ``R_j Exp(xi)`` with ``xi = -delta``, gives the error ``+delta``:
    GTSAM's AHRS error is ``Log(R_j^T R_i Delta R) = -xi`` (measured)."""
    rng = np.random.default_rng(3)
    samples, truth, bias = _ahrs_pass(rng)
    model = GyroModel("ahrs", 1e-3, 1e-4, 0.01, rate_hz=10.0)
    nodes = np.array([0, 10, 30])
    gyro = prepare_gyro(gyro_timeline(samples, samples.t[nodes]), FilterOptions())
    intervals = gyro_intervals(nodes, gyro, model)
    graph = gyro_graph(intervals, gyro, np.tile(bias, (3, 1)))
    values = to_values(truth[nodes], np.tile(bias, (3, 1)))
    for i in range(graph.size()):
        assert np.abs(graph.at(i).unwhitenedError(values)).max() < 1e-12
    # preintegrated about a zero bias, GTSAM's first-order bias correction is
    # accurate to second order in (b - b_hat) T (measured 9e-8 rad here)
    about_zero = gyro_graph(intervals, gyro, np.zeros((3, 3)))
    assert np.abs(about_zero.at(0).unwhitenedError(values)).max() < 1e-6
    delta = np.array([2e-6, -1e-6, 3e-6])
    moved = to_values(
        Rotation.concatenate([truth[0], Rotation.from_rotvec(delta) * truth[10], truth[30]]),
        np.tile(bias, (3, 1)),
    )
    assert np.allclose(graph.at(0).unwhitenedError(moved), delta, rtol=0, atol=1e-11)
    # the preintegrated covariance is (sigma_v^2 T + sigma_u^2 T^3 / 3) I
    t = 2.0
    expected = model.sigma_v**2 * t + model.sigma_u**2 * t**3 / 3.0
    information = graph.at(2).noiseModel().R()
    assert np.allclose(np.linalg.inv(information.T @ information), expected * np.eye(3))


def _whitened_residual(factor, measurement, rotation: gtsam.Rot3) -> np.ndarray:
    """``e = W (h - z)`` at the attitude ``A = R^T`` (the smoother's factor, nonlinear)."""
    a = Rotation.from_matrix(rotation.matrix().T)
    predicted, _ = measurement.predict(a)
    return -factor.whiten(measurement.innovation(predicted[0])[factor.rows])


def _snr_measurement(rng: np.random.Generator, truth: Rotation = TRUTH) -> SnrMeasurement:
    los, antenna, ranges, snr, _ = _geometry(rng, truth, (6, 6))
    epoch = SnrEpoch.from_ranges(
        snr + rng.standard_normal(snr.shape),
        los,
        antenna,
        BORESIGHTS,
        ranges,
        LIU2023_HELIX,
        BUDGET,
    )
    return SnrMeasurement(epoch, truncated=True)


@pytest.mark.parametrize("kind", ["vector", "snr"])
def test_measurement_factor_jacobian_is_minus_interface_jacobian(kind):
    """The stacked factor's Jacobian ``-W K`` equals GTSAM's numerical derivative of
    the whitened residual ``-W innovation(h)`` with respect to ``R.retract(xi)``;
    ``K`` is the interface's ``J`` for SNRs (``z - h``: the ``-J`` sign) and
    differs from it for unit vectors only by the tangent-plane projection's
    terms of the order of the residual; the QR-compressed ``JacobianFactor``
    carries the same information and gradient."""
    rng = np.random.default_rng(5)
    if kind == "vector":
        attitude = Rotation.random(random_state=rng)
        body = attitude.apply(REFERENCES) + SIGMA * rng.standard_normal((2, 3))
        measurement = VectorMeasurement(body, REFERENCES, SIGMA)
    else:
        attitude = Rotation.from_rotvec(np.radians([0.5, -0.3, 0.4])) * TRUTH
        measurement = _snr_measurement(rng)
    factor, counts = prepare_factor(0, measurement, attitude, 1e-4 * np.eye(3), 0.9999)
    assert counts["n_gated"] == 0 and factor.rows.size == measurement.size
    analytic = -factor.whiten(factor.jacobian)
    numeric = numericalDerivative11(
        lambda r: _whitened_residual(factor, measurement, r), rot3(attitude), 1e-6
    )
    scale = np.abs(analytic).max()
    assert np.abs(numeric - analytic).max() < 1e-6 * scale
    interface = -factor.whiten(measurement.predict(attitude)[1][0])
    if kind == "snr":
        assert np.abs(analytic - interface).max() < 1e-9 * scale
    else:  # the projection's terms, relative size of the residual (sigma = 1e-3)
        assert 1e-5 * scale < np.abs(analytic - interface).max() < 1e-2 * scale
    (compressed,) = factor.linear_factors(None)
    a, b = compressed.getA().copy(), compressed.getb().copy()
    residual = factor.whiten(factor.innovation)
    assert np.allclose(a.T @ a, analytic.T @ analytic, rtol=1e-10, atol=0)
    assert np.allclose(a.T @ b, analytic.T @ residual, rtol=1e-10, atol=1e-12 * scale)


def test_prior_factor_matches_numerical_derivative_and_filter_sign():
    """The joint prior's whitened error is ``L^-1 [-delta, b - b_prior]`` with ``L L^T``
    the prior covariance with its cross block negated, and its linearisation
    matches GTSAM's numerical derivative in both variables."""
    rng = np.random.default_rng(7)
    root = rng.standard_normal((6, 6)) * np.array([1e-2] * 3 + [1e-4] * 3)
    covariance = root @ root.T + 1e-8 * np.eye(6)
    prior = Prior(Rotation.random(random_state=rng), covariance, bias=1e-3 * np.ones(3))
    joint = JointPrior(prior)
    estimate = Rotation.from_rotvec([0.01, -0.02, 0.005]) * prior.attitude
    bias = prior.bias + np.array([1e-4, 2e-4, -1e-4])
    values = to_values(Rotation.concatenate([estimate]), bias[None])
    delta = (estimate * prior.attitude.inv()).as_rotvec()  # A = exp(delta) A_prior
    expected = np.concatenate([delta, bias - prior.bias])
    cost = 0.5 * expected @ np.linalg.solve(covariance, expected)
    assert math.isclose(joint.cost(values), cost, rel_tol=1e-7)
    linear = joint.linearize(values)
    a = linear.jacobian()[0].copy()

    def whitened(rotation, vector):
        v = gtsam.Values()
        v.insert(attitude_key(0), rotation)
        v.insert(bias_key(0), vector)
        return joint.whitened_error(v)

    numeric = np.hstack(
        [
            numericalDerivative21(whitened, rot3(estimate), bias, 1e-7),
            numericalDerivative22(whitened, rot3(estimate), bias, 1e-7),
        ]
    )
    assert np.allclose(a, numeric, rtol=1e-5, atol=1e-5 * np.abs(numeric).max())


# --- exactness and consistency -----------------------------------------------------------------


def test_smoother_equals_brute_force_least_squares():
    """On a 25-epoch pass (vectors + the coarse gyro, a correlated prior) the
    smoother's solution equals scipy's ``least_squares`` minimum of the same
    cost to 1e-8 (rad and rad/s).  The brute force parameterises each
    attitude by ``xi`` about the smoother's solution (``A = exp(-xi) A*``) and
    each bias directly, and its residuals are: the AHRS and bias random-walk
    factors' ``whitenedError`` (GTSAM), the prior written out here with the
    filters' ``delta`` and the full covariance, and each vector's whitened
    innovation from the measurement interface."""
    rng = np.random.default_rng(11)
    run = simulate_pass(rng, duration=24.0, sigma=1e-2, simulated_gyro=COARSE)
    root = np.diag([0.05] * 3 + [0.01] * 3)
    root[3, 0] = root[4, 1] = 0.005
    covariance = root @ root.T
    prior = drawn_prior(rng, run, covariance)
    result = solve_with(TIGHT, run.gyro, run.t, run.measurements, prior, COARSE)
    report = result.report
    assert report.converged and report.n_gated == 0, report.message
    problem = report.problem
    solution = Rotation.from_quat(report.quaternion)
    n = len(run.t)
    factors = [problem.graph.at(i) for i in range(problem.graph.size())]
    prior_root = np.linalg.cholesky(covariance)
    whiteners = [
        np.linalg.cholesky(np.linalg.inv(np.diag(r) if r.ndim == 1 else r)).T
        for r in (np.asarray(m.noise_covariance) for m in run.measurements)
    ]

    def residuals(x: np.ndarray) -> np.ndarray:
        xi, bias = x[: 3 * n].reshape(n, 3), x[3 * n :].reshape(n, 3)
        attitudes = retract(solution, xi)
        values = to_values(attitudes, bias)
        parts = [f.whitenedError(values) for f in factors]
        delta = (attitudes[0] * prior.attitude.inv()).as_rotvec()
        parts.append(np.linalg.solve(prior_root, np.concatenate([delta, bias[0] - prior.bias])))
        for k, m in enumerate(run.measurements):
            predicted, _ = m.predict(attitudes[k], jacobian=False)
            parts.append(whiteners[k] @ m.innovation(predicted[0]))
        return np.concatenate(parts)

    # central differences, columns that share no residual row perturbed together
    columns = {attitude_key(k): 3 * k for k in range(n)}
    columns |= {bias_key(k): 3 * (n + k) for k in range(n)}
    blocks = [[columns[key] for key in f.keys()] for f in factors]
    blocks += [[columns[attitude_key(0)], columns[bias_key(0)]]]
    blocks += [[columns[attitude_key(k)]] for k in range(n)]
    sizes = [3] * len(factors) + [6] + [m.size for m in run.measurements]
    sparsity = np.zeros((sum(sizes), 6 * n), dtype=bool)
    row = 0
    for size, block in zip(sizes, blocks, strict=True):
        for column in block:
            sparsity[row : row + size, column : column + 3] = True
        row += size
    groups: list[list[int]] = []
    for column in range(6 * n):
        for group in groups:
            if not (sparsity[:, group].any(axis=1) & sparsity[:, column]).any():
                group.append(column)
                break
        else:
            groups.append([column])

    def jacobian(x: np.ndarray) -> np.ndarray:
        out = np.zeros(sparsity.shape)
        for group in groups:
            step = np.zeros_like(x)
            step[group] = 1e-7
            difference = (residuals(x + step) - residuals(x - step)) / 2e-7
            for column in group:
                out[sparsity[:, column], column] = difference[sparsity[:, column]]
        return out

    start = np.concatenate([1e-3 * rng.standard_normal(3 * n), report.bias.ravel() + 1e-4])
    brute = least_squares(
        residuals, start, jac=jacobian, method="lm", xtol=1e-15, ftol=1e-15, gtol=1e-15
    )
    xi, bias = brute.x[: 3 * n].reshape(n, 3), brute.x[3 * n :].reshape(n, 3)
    assert np.abs(xi).max() < 1e-8
    assert np.abs(bias - report.bias).max() < 1e-8
    assert math.isclose(0.5 * brute.fun @ brute.fun, report.final_cost, rel_tol=1e-9)


NOISY = GyroModel("noisy-2hz", 1e-2, 1e-3, 0.01, rate_hz=2.0)
"""A gyro so poor that the smoothing window is a few epochs: nearly independent errors."""


def test_marginal_covariance_matches_monte_carlo_scatter():
    """30 passes of 30 epochs (two vectors, ``sigma = 0.02``, :data:`NOISY` gyro,
    prior drawn from its covariance): the mean squared attitude error per axis
    is within 15 % of the mean marginal variance and the mean 6-state NEES
    within 15 % of 6.  Measured: ratios 1.02 / 0.98 / 1.06, NEES 6.26."""
    rng = np.random.default_rng(13)
    errors, covariances = [], []
    covariance = prior_covariance(np.radians(5.0), NOISY)
    for _ in range(30):
        run = simulate_pass(rng, duration=29.0, sigma=2e-2, simulated_gyro=NOISY)
        prior = drawn_prior(rng, run, covariance)
        result = solve_with(BatchSmoother(), run.gyro, run.t, run.measurements, prior, NOISY)
        assert result.report.converged, result.report.message
        errors.append(state_errors(result, run))
        covariances.append(result.state_covariance)
    errors, covariances = np.array(errors), np.array(covariances)
    variance = np.diagonal(covariances[..., :3, :3], axis1=-2, axis2=-1).mean(axis=(0, 1))
    ratio = (errors[..., :3] ** 2).mean(axis=(0, 1)) / variance
    assert np.all(np.abs(ratio - 1.0) < 0.15), ratio
    nees = np.einsum("rki,rkij,rkj->rk", errors, np.linalg.inv(covariances), errors).mean()
    assert abs(nees / 6.0 - 1.0) < 0.15, nees


def test_marginal_covariance_equals_rts_covariance_on_a_near_linear_pass():
    """With the MEMS gyro the attitude and bias errors are strongly correlated
    (up to 0.85), and on this near-linear pass the smoother's joint ``6 x 6``
    marginals equal the RTS smoother's (the exact smoother of the linearised
    system, in the filters' pinned ``[delta, delta_beta]`` convention):
    correlations within 0.01 and variances within 1 % (measured 0.004 and
    0.3 %); a wrong sign of the cross block would differ by up to 1.7."""
    rng = np.random.default_rng(3)
    run = simulate_pass(rng, duration=29.0, sigma=2e-2)
    prior = drawn_prior(rng, run, prior_covariance(np.radians(5.0)))
    rts = rts_smooth(
        solve_with(Mekf(), run.gyro, run.t, run.measurements, prior, GYRO), FilterOptions(), "rts"
    )
    result = solve_with(BatchSmoother(), run.gyro, run.t, run.measurements, prior, GYRO, rts)
    sigma = np.sqrt(np.einsum("kii->ki", rts.state_covariance))
    scale = sigma[:, :, None] * sigma[:, None, :]
    correlation = rts.state_covariance / scale
    assert np.abs(correlation[:, :3, 3:]).max() > 0.8
    assert np.abs(result.state_covariance / scale - correlation).max() < 0.01
    ratio = np.einsum("kii->ki", result.state_covariance) / sigma**2
    assert np.abs(ratio - 1.0).max() < 0.01


def test_smoother_at_least_as_good_as_the_filters():
    """Three 90 s vector passes with the :data:`NOISY` gyro: the smoother's RMS is
    below the MEKF's and equal to the RTS smoother's within 0.5 % (the two
    smoothers coincide for a linear system; measured: MEKF 1.23 deg, RTS and
    smoother 0.93 deg, relative difference 5e-4), and its cost is at most the
    cost at the RTS estimate it starts from (it is the minimiser)."""
    rms = np.zeros((3, 3))
    for seed in range(3):
        rng = np.random.default_rng(100 + seed)
        run = simulate_pass(rng, duration=90.0, sigma=2e-2, simulated_gyro=NOISY)
        prior = drawn_prior(rng, run, prior_covariance(np.radians(5.0), NOISY))
        forward = solve_with(Mekf(), run.gyro, run.t, run.measurements, prior, NOISY)
        backward = rts_smooth(forward, FilterOptions(), "rts")
        result = solve_with(
            BatchSmoother(), run.gyro, run.t, run.measurements, prior, NOISY, backward
        )
        assert result.report.converged, result.report.message
        assert result.report.final_cost <= result.report.initial_cost
        rms[seed] = [rms_deg(forward, run), rms_deg(backward, run), rms_deg(result, run)]
    mekf_rms, rts_rms, smoother_rms = rms.mean(axis=0)
    assert smoother_rms < 0.9 * mekf_rms
    assert abs(smoother_rms / rts_rms - 1.0) < 5e-3


def _snr_pass(rng: np.random.Generator, epochs: int = 40) -> tuple[SimulatedPass, Prior]:
    """A slowly turning body seen by the SNRs of 12 aircraft per epoch (1 dB noise,
    true SNRs at least 10 dB), the MEMS gyro at 2 Hz, a prior drawn with 5 deg per axis."""
    t_gyro = np.arange(round((epochs - 1) / GYRO.dt) + 1) * GYRO.dt
    truth = Rotation.from_rotvec(-np.outer(t_gyro, 0.1 * RATE)) * TRUTH
    gyro = simulate_gyro(t_gyro, truth, GYRO, rng)
    t = np.arange(epochs, dtype=float)
    index = np.round(t / GYRO.dt).astype(int)
    measurements = []
    for i in index:
        measurements.append(_snr_measurement(rng, truth[i]))
    run = SimulatedPass(truth, gyro.samples, gyro.bias, t, index, measurements)
    return run, drawn_prior(rng, run, prior_covariance(np.radians(5.0)))


def test_snr_pass_end_to_end():
    """SNRs through the interface (truncated model, attitude-dependent ``R``
    re-evaluated once at the solution): the smoother converges from the RTS
    estimate to a lower cost, beats the MEKF and matches the RTS smoother
    (measured RMS: MEKF 1.44 deg, RTS 1.00, smoother 1.02; one 40 s pass, the
    difference is within its noise)."""
    run, prior = _snr_pass(np.random.default_rng(0))
    forward = solve_with(Mekf(), run.gyro, run.t, run.measurements, prior, GYRO)
    backward = rts_smooth(forward, FilterOptions(), "rts")
    options = BatchSmoother(noise_updates=1)
    result = solve_with(options, run.gyro, run.t, run.measurements, prior, GYRO, backward)
    report = result.report
    assert report.converged and report.noise_updates == 1, report.message
    assert report.final_cost < report.initial_cost
    assert 0.5 < 2.0 * report.final_cost / report.measurement_rows < 1.5
    assert rms_deg(result, run) < rms_deg(forward, run)
    assert abs(rms_deg(result, run) / rms_deg(backward, run) - 1.0) < 0.05


# --- bad input and faults ----------------------------------------------------------------------


def test_bad_input_is_rejected():
    rng = np.random.default_rng(17)
    run = simulate_pass(rng, duration=10.0)
    prior = drawn_prior(rng, run, prior_covariance(np.radians(1.0)))
    with pytest.raises(InvalidObservationError, match="snapshots for"):
        solve_with(BatchSmoother(), run.gyro, run.t, run.measurements[:-1], prior, GYRO)
    rigid = dataclasses.replace(GYRO, sigma_u=0.0)
    with pytest.raises(InvalidObservationError, match="sigma_u > 0"):
        solve_with(BatchSmoother(), run.gyro, run.t, run.measurements, prior, rigid)
    short = solve_with(Mekf(), run.gyro, run.t[:-1], run.measurements[:-1], prior, GYRO)
    with pytest.raises(InvalidObservationError, match="initial estimate has"):
        solve_with(BatchSmoother(), run.gyro, run.t, run.measurements, prior, GYRO, short)
    with pytest.raises(ValueError, match="initialisation"):
        BatchSmoother(initialisation="magic")
    with pytest.raises(ValueError, match="noise_updates"):
        BatchSmoother(noise_updates=-1)
    with pytest.raises(ValueError, match="huber_threshold"):
        GraphOptions(huber_threshold=0.0)


def test_nan_measurement_is_counted_and_left_out():
    """An Euler-angle measurement with a NaN angle (one block) at epoch 5 is left
    out and counted; the epoch is still estimated from the gyro and its neighbours."""
    rng = np.random.default_rng(19)
    run = simulate_pass(rng, duration=20.0)
    run.measurements[5] = EulerAngleMeasurement([0.1, np.nan, 0.2], 1e-4 * np.eye(3))
    prior = drawn_prior(rng, run, prior_covariance(np.radians(1.0)))
    result = solve_with(BatchSmoother(), run.gyro, run.t, run.measurements, prior, GYRO)
    diagnostics = result.diagnostics
    assert diagnostics["n_nan"][5] == 1 and diagnostics["n_used"][5] == 0
    assert result.report.n_nan == 1
    assert np.isnan(result.loss[5]) and result.valid.all()
    assert np.degrees(np.abs(state_errors(result, run)[5, :3])).max() < 0.5


def _outlier_pass(seed: int = 23):
    """Epoch 10's second vector turned by 30 deg (an outlier); the same pass without it."""
    rng = np.random.default_rng(seed)
    run = simulate_pass(rng, duration=30.0, sigma=2e-3)
    prior = drawn_prior(rng, run, prior_covariance(np.radians(2.0)))
    clean = list(run.measurements)
    good = run.measurements[10]
    body = good.z.reshape(-1, 3)
    clean[10] = VectorMeasurement(body[:1], good.reference[:1], 2e-3)
    turned = Rotation.from_rotvec(np.radians(30.0) * body[0]).apply(body[1])
    run.measurements[10] = VectorMeasurement(np.vstack([body[0], turned]), good.reference, 2e-3)
    return run, prior, clean


def test_outlier_is_gated_once_and_counted():
    """The turned vector is gated at the initial estimate: the solution equals
    the one of the pass without it (to 1e-9 rad) and the block is counted."""
    run, prior, clean = _outlier_pass()
    result = solve_with(TIGHT, run.gyro, run.t, run.measurements, prior, GYRO)
    reference = solve_with(TIGHT, run.gyro, run.t, clean, prior, GYRO)
    assert result.diagnostics["n_gated"][10] == 1 and result.report.n_gated == 1
    assert result.diagnostics["n_used"][10] == 1
    difference = attitude_error(result.attitude(), reference.attitude())
    assert np.abs(difference).max() < 1e-9


def test_huber_loss_downweights_an_ungated_outlier():
    """With gating off, the turned vector pulls the least-squares estimate at epoch
    10 by degrees, and the residual test flags the window of epochs it is in; with the
    gyro fault test on, the gyro factors on either side of epoch 10 fail instead, are
    removed, and epoch 10 is split off: only it and the next are flagged and the pass is
    consistent.  The Huber loss (switchable, reported) down-weights the vector and
    keeps the error near the clean solution's."""
    run, prior, clean = _outlier_pass()
    ungated = FilterOptions(gate_probability=1.0)
    tested = solve_with(
        BatchSmoother(filter=ungated, gyro_exclusions=0), run.gyro, run.t, run.measurements, prior
    )
    # the residual test sees the outlier; the least-squares fit spreads it over the pass
    window = FilterOptions().consistency_window
    assert not tested.valid[10 : 10 + window].any()
    assert all(r.startswith("inconsistent: the residuals") for r in tested.reason[10:20])
    assert not tested.report.consistent and tested.report.chi_square_p < 1e-6
    split = solve_with(BatchSmoother(filter=ungated), run.gyro, run.t, run.measurements, prior)
    assert np.flatnonzero(~split.valid).tolist() == [10, 11]
    assert all(r.startswith("inconsistent: the gyro up to") for r in split.reason[10:12])
    assert split.report.excluded_intervals == 2 and split.report.consistent
    no_gate = FilterOptions(gate_probability=1.0, consistency_window=0)  # accuracy alone
    plain = solve_with(
        BatchSmoother(filter=no_gate, gyro_exclusions=0), run.gyro, run.t, run.measurements, prior
    )
    huber = BatchSmoother(
        graph=GraphOptions(huber_threshold=1.345), filter=no_gate, gyro_exclusions=0
    )
    robust = solve_with(huber, run.gyro, run.t, run.measurements, prior)
    reference = solve_with(BatchSmoother(), run.gyro, run.t, clean, prior)
    assert reference.valid.all() and reference.report.consistent
    assert plain.report.n_gated == 0 and plain.report.n_downweighted == 0
    assert robust.diagnostics["n_downweighted"][10] == 1
    assert robust.report.converged, robust.report.message

    def error_deg(result) -> float:
        return float(np.degrees(np.abs(state_errors(result, run)[10, :3]).max()))

    assert error_deg(plain) > 10.0 * error_deg(reference)
    assert error_deg(robust) < 3.0 * error_deg(reference)


def test_non_convergence_is_reported_not_silent():
    """From gyro integration 20 deg off and a 0.1 deg/s-class bias, one iteration is
    not enough: the report says so (final cost, iterations), every epoch is
    flagged with that reason, and the estimates stay in the report."""
    rng = np.random.default_rng(29)
    run = simulate_pass(rng, duration=30.0)
    axis = np.array([1.0, -1.0, 1.0]) / math.sqrt(3.0)
    prior = Prior(
        Rotation.from_rotvec(np.radians(20.0) * axis) * run.truth[0],
        prior_covariance(np.radians(20.0)),
        bias=np.zeros(3),
    )
    options = BatchSmoother(
        optimiser=LevenbergMarquardtParams(max_iterations=1), initialisation="gyro"
    )
    result = solve_with(options, run.gyro, run.t, run.measurements, prior, GYRO)
    report = result.report
    assert not report.converged and report.iterations == 1
    assert "did not converge" in report.message and "after 1 iterations" in report.message
    assert np.isfinite(report.final_cost) and report.final_cost < report.initial_cost
    assert not result.valid.any()
    assert all("did not converge" in reason for reason in result.reason)
    assert np.all(np.isfinite(report.quaternion)) and np.all(np.isfinite(report.bias))
    enough = dataclasses.replace(options, optimiser=LevenbergMarquardtParams(max_iterations=30))
    converged = solve_with(enough, run.gyro, run.t, run.measurements, prior, GYRO)
    assert converged.report.converged and converged.valid.all()


def _gap_pass(seed: int = 31):
    """Gyro samples missing from 20 s to 40 s and no measurement from 25 s to 35 s."""
    rng = np.random.default_rng(seed)
    run = simulate_pass(rng, duration=60.0)
    rates = run.gyro.rates.copy()
    rates[(run.gyro.t[:-1] >= 20.0) & (run.gyro.t[:-1] < 40.0)] = np.nan
    gyro = dataclasses.replace(run.gyro, rates=rates)
    for k in range(25, 36):
        run.measurements[k] = None
    prior = drawn_prior(rng, run, prior_covariance(np.radians(1.0)))
    return run, gyro, prior


def test_gyro_gap_is_bridged_below_the_limit():
    """A 20 s gap below ``max_gyro_gap_s``: the held rate (the true one is
    constant) bridges it with a growing covariance (sigma at 30 s above that at
    10 s), errors stay within 4 sigma, every epoch valid."""
    run, gyro, prior = _gap_pass()
    result = solve_with(BatchSmoother(), gyro, run.t, run.measurements, prior, GYRO)
    assert result.report.converged and result.valid.all()
    errors = state_errors(result, run)[:, :3]
    sigma = np.sqrt(np.einsum("kii->ki", result.covariance))
    assert np.all(np.abs(errors) < 4.0 * sigma)
    assert sigma[30].min() > 2.0 * sigma[10].max()
    assert result.diagnostics["gyro_gap_s"].max() == pytest.approx(20.0)


def test_long_gyro_gap_splits_the_pass_into_segments():
    """The same gap above ``max_gyro_gap_s = 5``: no AHRS factor spans it (the
    attitude segments are not linked, the bias walk still is); the epochs in the
    gap with measurements are determined by them alone and valid, those without
    (25-35 s) are undetermined (diffuse prior only) and flagged by the
    ``max_attitude_sigma`` rule; no motion is invented."""
    run, gyro, prior = _gap_pass()
    strict = BatchSmoother(filter=FilterOptions(max_gyro_gap_s=5.0))
    result = solve_with(strict, gyro, run.t, run.measurements, prior, GYRO)
    assert result.report.converged, result.report.message
    prepared = prepare_gyro(gyro_timeline(gyro, run.t), strict.filter)
    intervals = gyro_intervals(np.round(run.t / GYRO.dt).astype(int), prepared, GYRO, 5.0)
    np.testing.assert_array_equal(np.flatnonzero(intervals.broken), np.arange(20, 40))
    graph = result.report.problem.graph
    ahrs = [graph.at(i) for i in range(graph.size()) if isinstance(graph.at(i), gtsam.AHRSFactor)]
    assert len(ahrs) == run.t.size - 1 - 20
    # each segment's diffuse start takes three degrees of freedom from the pass's test
    assert result.report.chi_square_dof == result.report.measurement_rows - 3 * 20
    blind = np.zeros(run.t.size, dtype=bool)
    blind[25:36] = True
    assert np.array_equal(~result.valid, blind)
    limit = np.degrees(strict.filter.max_attitude_sigma)
    assert set(result.reason[blind]) == {f"attitude not determined: 1-sigma above {limit:g} deg"}
    valid = result.valid
    delta = attitude_error(Rotation.from_quat(result.quaternion[valid]), run.truth_at_epochs[valid])
    sigma = np.sqrt(np.einsum("kii->ki", result.covariance[valid]))
    assert np.all(np.abs(delta) < 4.0 * sigma)
    # inside the gap with measurements: one epoch's vectors only (no gyro link)
    covariance = result.covariance
    assert np.trace(covariance[22]) > 4.0 * np.trace(covariance[10])


def test_single_frame_initialisation_reaches_the_same_optimum():
    """Starting from single-epoch solutions (1 deg noise, a third of the epochs
    invalid and filled by gyro integration) the smoother converges to the
    optimum it reaches from the RTS estimate."""
    rng = np.random.default_rng(41)
    run = simulate_pass(rng, duration=90.0)
    prior = drawn_prior(rng, run, prior_covariance(np.radians(5.0)))
    n = run.t.size
    sigma = np.radians(1.0)
    noisy = Rotation.from_rotvec(sigma * rng.standard_normal((n, 3))) * run.truth_at_epochs
    valid = rng.uniform(size=n) > 1.0 / 3.0
    snapshots = Track(
        method="snapshot",
        quaternion=np.where(valid[:, None], noisy.as_quat(), np.nan),
        covariance=np.where(valid[:, None, None], sigma**2 * np.eye(3), np.nan),
        loss=np.zeros(n),
        valid=valid,
        reason=np.where(valid, "", "invalid").astype(object),
        error=np.full(n, None, dtype=object),
        diagnostics={},
    )
    start = single_frame_initial(snapshots, prior)
    from_snapshots = solve_with(TIGHT, run.gyro, run.t, run.measurements, prior, GYRO, start)
    from_rts = solve_with(TIGHT, run.gyro, run.t, run.measurements, prior, GYRO)
    assert from_snapshots.report.converged, from_snapshots.report.message
    assert from_snapshots.report.initialisation == "given"
    difference = attitude_error(from_snapshots.attitude(), from_rts.attitude())
    assert np.abs(difference).max() < 1e-8
    np.testing.assert_allclose(from_snapshots.bias, from_rts.bias, atol=1e-10)


def test_first_epoch_after_the_gyro_start_gets_a_prior_node():
    """Epochs from 1 s on: the prior (at the first gyro sample) sits on an extra node
    that is not reported; the estimates match the run with an epoch at 0 s."""
    rng = np.random.default_rng(37)
    run = simulate_pass(rng, duration=20.0)
    prior = drawn_prior(rng, run, prior_covariance(np.radians(1.0)))
    full = solve_with(TIGHT, run.gyro, run.t, run.measurements, prior, GYRO)
    without_zero = list(run.measurements)
    without_zero[0] = None
    reference = solve_with(TIGHT, run.gyro, run.t, without_zero, prior, GYRO)
    later = solve_with(TIGHT, run.gyro, run.t[1:], run.measurements[1:], prior, GYRO)
    assert len(later) == len(run.t) - 1 and later.report.problem.offset == 1
    difference = attitude_error(later.attitude(), reference.attitude()[1:])
    assert np.abs(difference).max() < 1e-9
    assert np.allclose(later.state_covariance, reference.state_covariance[1:], rtol=1e-6)
    assert full.valid.all()


def test_the_native_gtsam_reference_solves_the_same_pass():
    """The benchmark's reference graph (``experiments/benchmarks/native_graph.py``): GTSAM's
    own factors and optimiser on the smoother's nodes reach the smoother's solution (the
    residuals differ only by the geodesic angle against its sine)."""
    from attopt.experiments.benchmarks.native_graph import STAGES, format_table, run

    ours, native, difference_deg = run(runs=1, duration_s=300.0)
    assert difference_deg < 1e-3
    assert set(ours[0].seconds) == set(native[0].seconds) == set(STAGES)
    assert len(native[0].attitudes) >= len(ours[0].attitudes) == 300
    assert "| total |" in format_table(ours, native, difference_deg)
