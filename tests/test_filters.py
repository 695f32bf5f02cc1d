"""MEKF and multiplicative RTS smoother (``solvers/filters``): convergence,
statistical consistency on a seeded Monte Carlo, fault handling and bad input.

Scenario (unless a test says otherwise): a body turning at a constant
``(0.01, -0.02, 0.015)`` rad/s relative to the inertial frame, a gyro with
:data:`~attopt.formulations.gyro.MEMS_GYRO`'s noise statistics sampled at 2 Hz (the
filter cost is dominated by the updates, so the rate barely matters), and at
1 Hz two inertial unit vectors measured in the body with ``sigma`` per axis.

Error convention: the filter's state error is ``delta = rotvec(A_true
A_est^T) = -attitude_error(A_est, A_true)`` and ``delta_beta = beta -
beta_hat``; the sign matters for the 6-state NEES through the
attitude-bias cross-covariance.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from attopt.formulations.attitude_measurement import (
    AttitudeMeasurement,
    EulerAngleMeasurement,
    VectorMeasurement,
)
from attopt.formulations.conventions import attitude_error
from attopt.formulations.errors import ConvergenceError, InvalidObservationError
from attopt.formulations.gain_patterns import LIU2023_HELIX
from attopt.formulations.gyro import GyroModel, GyroSamples, simulate_gyro
from attopt.formulations.passes import Prior
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.formulations.snr_problem import SnrEpoch
from attopt.solvers.filters import FilterOptions, Mekf, Usque
from attopt.solvers.filters.rts import rts_smooth
from attopt.solvers.sequential import NON_FINITE
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


def state_errors(result, run: SimulatedPass) -> np.ndarray:
    """``(N, 6)`` filter-convention errors ``[delta, beta - beta_hat]`` at the epochs."""
    valid = result.valid
    assert valid.all()
    delta = -attitude_error(result.attitude(), run.truth_at_epochs)
    return np.concatenate([delta, run.bias_at_epochs - result.bias], axis=1)


def nees(errors: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...ij,...j->...", errors, np.linalg.inv(covariance), errors)


def assert_valid_and_finite(result) -> None:
    assert result.valid.all(), set(result.reason)
    assert np.all(np.isfinite(result.quaternion))
    assert np.all(np.isfinite(result.state_covariance)) and np.all(np.isfinite(result.bias))


# --- convergence -------------------------------------------------------------------------------


def test_mekf_converges_from_20_degrees_noise_free():
    """Noise-free gyro (constant unknown bias) and vectors, declared precise
    (``sigma = 1e-6`` rad), a 20 deg initial error and a 0.1 deg/s-class bias.

    Bounds (measured: about 1e-11 rad and 6e-7 rad/s at 300 s): attitude
    error below 1e-9 rad over the last 100 s; bias error below 1e-6 rad/s
    (0.2 deg/h) at the end, a 1000-fold reduction, and decreasing.

    The iterated update (exact state Jacobian, stopped on the step's
    second-order term) removes the 20 deg in the first epoch; no vector is
    gated."""
    rng = np.random.default_rng(1)
    bias_only = GyroModel("bias-only", 0.0, 0.0, GYRO.initial_bias_sigma, GYRO.rate_hz)
    run = simulate_pass(rng, sigma=1e-6, noisy=False, simulated_gyro=bias_only)
    axis = np.array([1.0, 1.0, -1.0]) / math.sqrt(3.0)
    prior = Prior(
        Rotation.from_rotvec(np.radians(20.0) * axis) * run.truth[0],
        prior_covariance(np.radians(20.0)),
        bias=np.zeros(3),
    )
    result = solve_with(Mekf(), run.gyro, run.t, run.measurements, prior, GYRO)
    assert_valid_and_finite(result)
    error = np.linalg.norm(state_errors(result, run)[:, :3], axis=1)
    bias_error = np.linalg.norm(run.bias_at_epochs - result.bias, axis=1)
    assert error[-100:].max() < 1e-9
    assert bias_error[-1] < 1e-6 and bias_error[-1] < 1e-3 * bias_error[0]
    assert bias_error[300] < bias_error[100] < bias_error[30] < bias_error[10]


def test_mekf_converges_from_20_degrees_with_precise_sensors():
    """Star-tracker-class vectors (1e-5 rad) and a quiet gyro model (1e-5 rad/s^(1/2),
    1e-7 rad/s^(3/2)); noise-free data, default options, 20 deg initial error."""
    rng = np.random.default_rng(1)
    quiet = GyroModel("quiet", 1e-5, 1e-7, GYRO.initial_bias_sigma, GYRO.rate_hz)
    bias_only = GyroModel("bias-only", 0.0, 0.0, GYRO.initial_bias_sigma, GYRO.rate_hz)
    run = simulate_pass(rng, duration=60.0, sigma=1e-5, noisy=False, simulated_gyro=bias_only)
    axis = np.array([1.0, 1.0, -1.0]) / math.sqrt(3.0)
    prior = Prior(
        Rotation.from_rotvec(np.radians(20.0) * axis) * run.truth[0],
        prior_covariance(np.radians(20.0), quiet),
        bias=np.zeros(3),
    )
    result = solve_with(Mekf(), run.gyro, run.t, run.measurements, prior, quiet)
    error = np.linalg.norm(state_errors(result, run)[:, :3], axis=1)
    assert error[-10:].max() < 1e-7
    assert result.diagnostics["n_gated"].sum() == 0


# --- Monte Carlo consistency ---------------------------------------------------------------------

RUNS = 20
BURN_IN = 50
"""Epochs (s) left out of the time averages: the prior's 1 deg error is gone by then."""


@pytest.fixture(scope="module")
def monte_carlo():
    """20 seeded passes of 300 s, filtered and smoothed; errors and covariances
    ``(runs, epochs, 6[, 6])``.  Initial errors are drawn from the prior."""
    out = {"filter": ([], []), "smoother": ([], [])}
    for seed in range(RUNS):
        rng = np.random.default_rng(1000 + seed)
        run = simulate_pass(rng)
        filtered = solve_with(
            Mekf(),
            run.gyro,
            run.t,
            run.measurements,
            drawn_prior(rng, run, prior_covariance(np.radians(1.0))),
            GYRO,
        )
        smoothed = rts_smooth(filtered, FilterOptions(), "rts")
        for name, result in (("filter", filtered), ("smoother", smoothed)):
            out[name][0].append(state_errors(result, run))
            out[name][1].append(result.state_covariance)
    return {name: (np.array(e), np.array(p)) for name, (e, p) in out.items()}


def chi2_interval(dof_per_run: int, runs: int = RUNS) -> tuple[float, float]:
    """Two-sided 95% interval of the run-averaged NEES, ``chi2(dof * M) / M``."""
    low, high = chi2.ppf([0.025, 0.975], dof_per_run * runs) / runs
    return float(low), float(high)


@pytest.mark.parametrize("name", ["filter", "smoother"])
@pytest.mark.parametrize("states", [3, 6], ids=["attitude", "full"])
def test_nees_is_consistent(monte_carlo, name, states):
    """Statistic: at each epoch the NEES averaged over the M = 20 runs, which for
    a consistent estimator is ``chi2(n M) / M`` (n = 3 attitude, 6 full state).
    Its time average after the burn-in has the same mean n and a smaller spread
    (the epochs are correlated, so no tighter interval is claimed); it must lie
    inside the two-sided 95% interval of ``chi2(n M) / M``, and so must at
    least 85% of the epochs individually (95% expected)."""
    errors, covariance = monte_carlo[name]
    values = nees(errors[..., :states], covariance[..., :states, :states])
    averaged = values.mean(axis=0)[BURN_IN:]
    low, high = chi2_interval(states)
    assert low < averaged.mean() < high, (averaged.mean(), low, high)
    inside = np.mean((averaged > low) & (averaged < high))
    assert inside > 0.85, inside


def test_filter_covariance_matches_monte_carlo_scatter(monte_carlo):
    """Steady state (after the burn-in): the mean filter attitude covariance
    against the sample covariance of the errors over runs and epochs, each axis
    within 20% (the errors are correlated in time, so the effective sample is
    a few hundred, a standard error of about 6%)."""
    errors, covariance = monte_carlo["filter"]
    e = errors[:, BURN_IN:, :3].reshape(-1, 3)
    sample = e.T @ e / e.shape[0]
    predicted = covariance[:, BURN_IN:, :3, :3].mean(axis=(0, 1))
    np.testing.assert_allclose(np.diag(sample) / np.diag(predicted), 1.0, atol=0.2)
    assert np.all(np.abs(e.mean(axis=0)) < 0.2 * np.sqrt(np.diag(predicted)))


def test_rts_covariance_never_exceeds_the_filters(monte_carlo):
    """``P^s_k <= P_k`` in the positive semi-definite order at every epoch of
    every run (checked after scaling by the filtered standard deviations, the
    blocks differ by ten orders of magnitude; to 1e-6: the update's covariance
    reset ``T P T^T`` to the reset attitude's body frame can raise a filtered
    covariance above its prediction by the square of the correction, here
    ~1e-8 relative); traces accordingly; equal at the last epoch."""
    _, filtered = monte_carlo["filter"]
    _, smoothed = monte_carlo["smoother"]
    scale = 1.0 / np.sqrt(np.diagonal(filtered, axis1=-2, axis2=-1))
    difference = (filtered - smoothed) * scale[..., :, None] * scale[..., None, :]
    assert np.linalg.eigvalsh(difference).min() > -1e-6
    for block in (slice(0, 3), slice(3, 6)):
        trace_f = np.trace(filtered[..., block, block], axis1=-2, axis2=-1)
        trace_s = np.trace(smoothed[..., block, block], axis1=-2, axis2=-1)
        assert np.all(trace_s <= trace_f * (1.0 + 1e-12))
    np.testing.assert_array_equal(filtered[:, -1], smoothed[:, -1])


def test_rts_error_is_below_the_filters(monte_carlo):
    """Smoothed attitude RMS below the filtered one, by a margin (measured: about
    0.011 deg against 0.017 deg per axis), over all runs after the burn-in."""
    rms = {
        name: np.sqrt(np.mean(monte_carlo[name][0][:, BURN_IN:, :3] ** 2, axis=(0, 1)))
        for name in ("filter", "smoother")
    }
    assert np.all(rms["smoother"] < 0.85 * rms["filter"]), rms
    bias_rms = {
        name: np.sqrt(np.mean(monte_carlo[name][0][:, BURN_IN:, 3:] ** 2))
        for name in ("filter", "smoother")
    }
    assert bias_rms["smoother"] < bias_rms["filter"]


def test_rts_needs_the_filter_history():
    run = simulate_pass(np.random.default_rng(2), duration=5.0)
    filtered = solve_with(
        Mekf(),
        run.gyro,
        run.t,
        run.measurements,
        drawn_prior(np.random.default_rng(3), run, prior_covariance(0.01)),
        GYRO,
    )
    with pytest.raises(ValueError, match="history"):
        rts_smooth(dataclasses.replace(filtered, history=None), FilterOptions(), "rts")


# --- outliers, unpredictable and missing values ------------------------------


def _short_vector_pass(seed: int = 5, duration: float = 60.0) -> tuple[SimulatedPass, Prior]:
    rng = np.random.default_rng(seed)
    run = simulate_pass(rng, duration=duration)
    return run, drawn_prior(rng, run, prior_covariance(np.radians(1.0)))


def _vector_outlier_runs(wrong_vector):
    """Runs with vector 1 of epoch 30 replaced by ``wrong_vector(body)`` and without it."""
    run, prior = _short_vector_pass()
    k = 30
    body = run.measurements[k].z.reshape(-1, 3).copy()
    wrong, without = body.copy(), body.copy()
    wrong[1] = wrong_vector(body)
    without[1] = np.nan  # dropped
    results = {}
    for name, replaced in (("outlier", wrong), ("without", without)):
        measurements = list(run.measurements)
        measurements[k] = VectorMeasurement(replaced, REFERENCES, SIGMA)
        results[name] = solve_with(Mekf(), run.gyro, run.t, measurements, prior, GYRO)
    return results["outlier"], results["without"]


def test_gated_vector_outlier_leaves_the_estimate_unchanged():
    """Vector 1 of epoch 30 replaced by one 90 deg away from it."""

    def perpendicular(body):
        wrong = np.cross(body[1], body[0])
        return wrong / np.linalg.norm(wrong)

    outlier, reference = _vector_outlier_runs(perpendicular)
    k = 30
    assert np.array_equal(outlier.quaternion, reference.quaternion)
    assert np.array_equal(outlier.state_covariance, reference.state_covariance)
    diagnostics = outlier.diagnostics
    assert diagnostics["n_gated"][k] == 1 and diagnostics["n_used"][k] == 1
    assert diagnostics["n_gated"].sum() == 1
    assert reference.diagnostics["n_gated"].sum() == 0


def test_reversed_vector_is_gated():
    outlier, reference = _vector_outlier_runs(lambda body: -body[1])
    assert outlier.diagnostics["n_gated"][30] == 1
    assert np.array_equal(outlier.quaternion, reference.quaternion)


def _snr_pass(extra=None, replace=None, drop: int | None = None, epochs: int = 20):
    """A static attitude ``TRUTH`` (orbit -> body; the filter's reference frame is
    the orbit frame here) seen by SNRs of 12 aircraft per epoch with 1 dB noise.

    ``replace(k, snr)`` may alter epoch ``k``'s measured SNRs, ``drop`` removes
    that observation index at epoch 10, ``extra`` appends an observation to it.
    """
    rng = np.random.default_rng(21)
    gyro_model = GYRO
    t_gyro = np.arange(2 * epochs - 1) * gyro_model.dt
    truth = Rotation.concatenate([TRUTH] * t_gyro.size)
    gyro = simulate_gyro(t_gyro, truth, gyro_model, rng)
    t = np.arange(epochs, dtype=float)
    measurements = []
    for k in range(epochs):
        los, antenna, ranges, snr, _ = _geometry(rng, TRUTH, (6, 6))
        snr = snr + rng.standard_normal(snr.shape)
        if replace is not None:
            snr = replace(k, snr)
        if k == 10 and drop is not None:
            keep = np.arange(snr.size) != drop
            los, antenna, ranges, snr = los[keep], antenna[keep], ranges[keep], snr[keep]
        if k == 10 and extra is not None:
            los = np.vstack([los, extra[0]])
            antenna = np.append(antenna, extra[1])
            ranges = np.append(ranges, extra[2])
            snr = np.append(snr, extra[3])
        epoch = SnrEpoch.from_ranges(snr, los, antenna, BORESIGHTS, ranges, LIU2023_HELIX, BUDGET)
        measurements.append(SnrMeasurement(epoch))
    prior = Prior(
        Rotation.from_rotvec(np.radians([1.0, -0.5, 0.8])) * TRUTH,
        prior_covariance(np.radians(2.0)),
        bias=gyro.bias[0] + 1e-4,
    )
    return solve_with(Mekf(), gyro.samples, t, measurements, prior, gyro_model)


def test_gated_snr_outlier_leaves_the_estimate_unchanged():
    def off_by_20_db(k, snr):
        snr = snr.copy()
        if k == 10:
            snr[3] += 20.0
        return snr

    outlier = _snr_pass(replace=off_by_20_db)
    reference = _snr_pass(drop=3)
    assert_valid_and_finite(outlier)
    assert np.array_equal(outlier.quaternion, reference.quaternion)
    assert outlier.diagnostics["n_gated"][10] == 1
    assert outlier.diagnostics["n_used"][10] == 11
    assert outlier.diagnostics["n_gated"].sum() == 1


def test_unpredictable_snr_is_left_out_and_counted():
    """An observation behind the antenna (outside the main lobe at any attitude
    near the truth) has NaN predictions: counted in ``n_unpredictable`` and
    left out, the estimate as without it."""
    backwards = (-TRUTH.inv().apply(BORESIGHTS[0]), 0, 1.5e6, 12.0)
    with_it = _snr_pass(extra=backwards)
    reference = _snr_pass()
    assert_valid_and_finite(with_it)
    diagnostics = with_it.diagnostics
    assert diagnostics["n_unpredictable"][10] == 1 and diagnostics["n_unpredictable"].sum() == 1
    assert diagnostics["n_used"][10] == 12 and diagnostics["n_nan"].sum() == 0
    assert np.array_equal(with_it.quaternion, reference.quaternion)


def test_nan_measured_values_are_left_out_and_counted():
    def nan_at_10(k, snr):
        snr = snr.copy()
        if k == 10:
            snr[3] = np.nan
        return snr

    with_nan = _snr_pass(replace=nan_at_10)
    reference = _snr_pass(drop=3)
    diagnostics = with_nan.diagnostics
    assert diagnostics["n_nan"][10] == 1 and diagnostics["n_nan"].sum() == 1
    assert diagnostics["n_used"][10] == 11 and diagnostics["n_unpredictable"].sum() == 0
    assert np.array_equal(with_nan.quaternion, reference.quaternion)


def test_all_nan_euler_measurement_is_a_propagation():
    run, prior = _short_vector_pass(duration=10.0)
    measurements = list(run.measurements)
    measurements[5] = EulerAngleMeasurement([np.nan, 0.1, 0.2], np.eye(3) * 1e-4)
    with_nan = solve_with(Mekf(), run.gyro, run.t, measurements, prior, GYRO)
    measurements[5] = None
    reference = solve_with(Mekf(), run.gyro, run.t, measurements, prior, GYRO)
    assert with_nan.diagnostics["n_nan"][5] == 1
    assert with_nan.diagnostics["n_used"][5] == 0
    assert np.array_equal(with_nan.quaternion, reference.quaternion)
    assert np.isnan(with_nan.loss[5])


# --- gyro gaps and measurement outages ------------------------------------------------------------


def _with_gyro_gap(run: SimulatedPass, start_s: float, length_s: float) -> GyroSamples:
    rates = run.gyro.rates.copy()
    first = round(start_s / run.gyro.dt)
    rates[first : first + round(length_s / run.gyro.dt)] = np.nan
    return GyroSamples(run.gyro.t, rates, run.gyro.dt)


def test_short_gyro_gap_grows_the_attitude_covariance_by_the_hold_variance():
    """A 5 s gap (no measurements during it): estimates finite and valid, and the
    attitude covariance at its end exceeds the run without the gap by at least
    ``(hold_rate_sigma T)^2`` in every direction (to 1%: the held rate differs
    from the sampled ones by the gyro noise only) and grows over the gap by at
    least that much on each axis."""
    run, prior = _short_vector_pass(duration=40.0)
    start, length = 20.0, 5.0
    measurements = [
        None if start < t <= start + length + 1 else m
        for t, m in zip(run.t, run.measurements, strict=True)
    ]
    gapped = solve_with(
        Mekf(), _with_gyro_gap(run, start, length), run.t, measurements, prior, GYRO
    )
    reference = solve_with(Mekf(), run.gyro, run.t, measurements, prior, GYRO)
    assert_valid_and_finite(gapped)
    end = int(start + length)
    hold = (FilterOptions().hold_rate_sigma * length) ** 2
    np.testing.assert_allclose(gapped.diagnostics["gyro_gap_s"][end], length)
    assert gapped.diagnostics["gyro_gap_s"][end + 1] == 0.0
    extra = gapped.state_covariance[end, :3, :3] - reference.state_covariance[end, :3, :3]
    assert np.linalg.eigvalsh(extra).min() > 0.99 * hold
    growth = np.diag(gapped.state_covariance[end, :3, :3]) - np.diag(
        gapped.state_covariance[int(start), :3, :3]
    )
    assert np.all(growth >= hold)


def test_filter_tracks_carry_the_epochs_and_the_error_state():
    """MEKF, RTS and USQUE tracks: the epoch times, the ``[attitude, bias]`` error state
    and its ``6 x 6`` covariance, whose attitude block is the ``3 x 3`` covariance."""
    run, prior = _short_vector_pass(duration=10.0)
    filtered = solve_with(Mekf(), run.gyro, run.t, run.measurements, prior, GYRO)
    unscented = solve_with(Usque(), run.gyro, run.t, run.measurements, prior, GYRO)
    for track in (filtered, rts_smooth(filtered, FilterOptions(), "rts"), unscented):
        np.testing.assert_array_equal(track.t, run.t)
        assert track.state == ("attitude", "bias") and track.block("bias") == slice(3, 6)
        np.testing.assert_array_equal(track.state_covariance[:, :3, :3], track.covariance)


def test_long_gyro_gap_flags_its_epochs():
    run, prior = _short_vector_pass(duration=40.0)
    options = FilterOptions(max_gyro_gap_s=5.0)
    gyro = _with_gyro_gap(run, 20.0, 10.0)
    result = solve_with(Mekf(filter=options), gyro, run.t, run.measurements, prior, GYRO)
    invalid = np.flatnonzero(~result.valid)
    np.testing.assert_array_equal(invalid, np.arange(26, 31))  # 6..10 s into the gap
    assert set(result.reason[invalid]) == {"gyro gap longer than 5 s"}
    assert np.all(np.isnan(result.quaternion[invalid]))
    assert np.all(np.isfinite(result.quaternion[result.valid]))
    assert result.epoch(25).covariance.shape == (3, 3)
    with pytest.raises(ConvergenceError, match="gyro gap"):
        result.epoch(26).raise_if_invalid()
    errors = np.linalg.norm(state_errors_valid(result, run)[31:, :3], axis=1)
    assert errors.max() < np.radians(0.2)  # recovered after the gap


def state_errors_valid(result, run: SimulatedPass) -> np.ndarray:
    """Errors at every epoch, NaN where invalid."""
    out = np.full((run.t.size, 3), np.nan)
    valid = result.valid
    out[valid] = -attitude_error(result.attitude(), run.truth_at_epochs[valid])
    return out


def test_minutes_without_measurements():
    """Five minutes with no measurements after one of measurements: the attitude
    covariance grows at every epoch, the estimate stays finite and valid, and
    the error stays within its covariance (NEES below the 99.9% chi-square(3)
    point at the end)."""
    run, prior = _short_vector_pass(duration=360.0)
    measurements = [m if t <= 60 else None for t, m in zip(run.t, run.measurements, strict=True)]
    result = solve_with(Mekf(), run.gyro, run.t, measurements, prior, GYRO)
    assert_valid_and_finite(result)
    trace = np.trace(result.state_covariance[:, :3, :3], axis1=1, axis2=2)
    assert np.all(np.diff(trace[60:]) > 0)
    assert trace[-1] > 10 * trace[60]
    errors = state_errors(result, run)
    assert nees(errors[-1, :3], result.state_covariance[-1, :3, :3]) < chi2.ppf(0.999, 3)


def _missing_start(rate: np.ndarray):
    """The first 3 s of gyro samples NaN (filled with a zero rate: there is no
    sample to hold yet), a 5 deg prior, vectors every second."""
    rng = np.random.default_rng(8)
    run = simulate_pass(rng, duration=60.0, rate=rate)
    gyro = _with_gyro_gap(run, 0.0, 3.0)
    prior = drawn_prior(rng, run, prior_covariance(np.radians(5.0)))
    return run, solve_with(Mekf(), gyro, run.t, run.measurements, prior, GYRO)


def test_pass_starting_with_missing_gyro_samples_runs():
    """Estimates finite and valid, the gap reported at the epochs it covers."""
    _, result = _missing_start(RATE)
    assert_valid_and_finite(result)
    np.testing.assert_allclose(result.diagnostics["gyro_gap_s"][:5], [0, 1, 2, 3, 0])


@pytest.mark.parametrize("rate", [np.zeros(3), RATE], ids=["static", "turning"])
def test_pass_starting_with_missing_gyro_samples_converges(rate):
    run, result = _missing_start(rate)
    errors = np.linalg.norm(state_errors_valid(result, run)[-20:], axis=1)
    # either the filter recovers or it stops reporting the epochs as valid
    assert np.all(~result.valid[-20:] | (errors < np.radians(0.1)))


# --- bad input and divergence ----------------------------------------


def _tiny_pass():
    run = simulate_pass(np.random.default_rng(4), duration=5.0)
    prior = Prior(run.truth[0], prior_covariance(0.01), bias=np.zeros(3))
    return run, prior


def test_wrong_number_of_measurements():
    run, prior = _tiny_pass()
    with pytest.raises(InvalidObservationError, match="5 snapshots for 6 epochs"):
        solve_with(Mekf(), run.gyro, run.t, run.measurements[:-1], prior, GYRO)


@pytest.mark.parametrize(
    "t",
    [
        np.array([0.0, 2.0, 1.0]),  # not increasing
        np.array([0.0, 1.0, 1.0]),  # repeated
        np.array([-0.5, 1.0, 2.0]),  # before the gyro
        np.array([0.0, 1.0, 7.0]),  # after the gyro
    ],
    ids=["decreasing", "repeated", "before", "after"],
)
def test_epochs_must_be_increasing_inside_the_gyro_record(t):
    run, prior = _tiny_pass()
    with pytest.raises(InvalidObservationError):
        solve_with(Mekf(), run.gyro, t, [None] * t.size, prior, GYRO)


@pytest.mark.parametrize(
    "covariance",
    [
        np.diag([1e-4, 1e-4, -1e-4, 1e-6, 1e-6, 1e-6]),  # negative variance
        np.diag([1e-4, 1e-4, 0.0, 1e-6, 1e-6, 1e-6]),  # singular
        np.full((6, 6), 1e-4) + np.diag([0, 0, 0, 0, 0, -1e-4]),  # indefinite
        np.diag([np.nan, 1e-4, 1e-4, 1e-6, 1e-6, 1e-6]),
        np.eye(3) * 1e-4,  # wrong shape
    ],
    ids=["negative", "singular", "indefinite", "nan", "3x3"],
)
def test_prior_covariance_must_be_positive_definite(covariance):
    run, _ = _tiny_pass()
    with pytest.raises(InvalidObservationError):
        prior = Prior(run.truth[0], covariance, bias=np.zeros(3))
        solve_with(Mekf(), run.gyro, run.t, run.measurements, prior, GYRO)


def test_prior_must_be_finite_and_gyro_rates_shaped():
    run, prior = _tiny_pass()
    with pytest.raises(InvalidObservationError):
        solve_with(
            Mekf(),
            run.gyro,
            run.t,
            run.measurements,
            dataclasses.replace(prior, bias=np.full(3, np.nan)),
            GYRO,
        )
    wrong = GyroSamples(run.gyro.t, np.vstack([run.gyro.rates, run.gyro.rates[-1:]]), run.gyro.dt)
    with pytest.raises(InvalidObservationError):
        solve_with(Mekf(), wrong, run.t, run.measurements, prior, GYRO)


class Pathological(AttitudeMeasurement):
    """Three rows with finite predictions and a Jacobian ``jacobian * I`` (may be
    inf), or infinite predictions."""

    def __init__(self, prediction: float = 0.0, jacobian: float = 1.0) -> None:
        self.z = np.zeros(3)
        self.noise_covariance = np.eye(3) * 1e-4
        self.blocks = np.zeros(3, dtype=np.intp)
        self.prediction, self.jacobian = prediction, jacobian

    def predict(self, attitude: Rotation, jacobian: bool = True):
        n = 1 if attitude.single else len(attitude)
        values = np.full((n, 3), self.prediction)
        with np.errstate(invalid="ignore"):
            matrix = np.broadcast_to(self.jacobian * np.eye(3), (n, 3, 3)).copy()
        return values, matrix if jacobian else None


def _run_with(measurement, options=None):
    run, prior = _short_vector_pass(duration=10.0)
    measurements = list(run.measurements)
    measurements[5] = measurement
    estimator = Mekf(filter=options or FilterOptions())
    return run, solve_with(estimator, run.gyro, run.t, measurements, prior, GYRO)


def test_infinite_predictions_are_unpredictable():
    _, result = _run_with(Pathological(prediction=np.inf))
    _, reference = _run_with(None)
    assert_valid_and_finite(result)
    assert result.diagnostics["n_unpredictable"][5] == 1
    assert np.array_equal(result.quaternion, reference.quaternion)


@pytest.mark.filterwarnings("ignore:invalid value encountered")
def test_infinite_jacobian_is_gated():
    _, result = _run_with(Pathological(jacobian=np.inf))
    _, reference = _run_with(None)
    assert_valid_and_finite(result)
    assert result.diagnostics["n_gated"][5] == 1
    assert np.array_equal(result.quaternion, reference.quaternion)


def test_covariance_overflow_is_flagged_not_reported():
    """A rate random walk whose variance overflows makes the covariance infinite
    at the first propagation: that epoch and all later ones are flagged, no NaN
    attitude is reported valid, and the smoother keeps them invalid."""
    run, prior = _short_vector_pass(duration=10.0)
    huge = np.float64(1e200)  # its square overflows to inf (a Python float would raise)
    wild = GyroModel("wild", GYRO.sigma_v, huge, GYRO.initial_bias_sigma, GYRO.rate_hz)
    with np.errstate(over="ignore", invalid="ignore"):
        result = solve_with(Mekf(), run.gyro, run.t, run.measurements, prior, wild)
        smoothed = rts_smooth(result, FilterOptions(), "rts")
    for track in (result, smoothed):
        assert track.valid[0] and not track.valid[1:].any()
        assert set(track.reason[1:]) == {NON_FINITE}
        assert np.all(np.isfinite(track.quaternion[track.valid]))
        assert np.all(np.isnan(track.quaternion[~track.valid]))
        with pytest.raises(ConvergenceError):
            track.epoch(3).raise_if_invalid()


@pytest.mark.filterwarnings("ignore:invalid value encountered")
@pytest.mark.filterwarnings("ignore:overflow encountered")
def test_non_finite_update_is_flagged_not_raised():
    """Gating off (``gate_probability=1``) and an infinite Jacobian: the gain and
    the state become NaN.  Documented behaviour (``solvers/filters/common.py``):
    the epoch and all later ones flagged."""
    _, result = _run_with(Pathological(jacobian=np.inf), FilterOptions(gate_probability=1.0))
    assert result.valid[:5].all() and not result.valid[5:].any()
    assert set(result.reason[5:]) == {NON_FINITE}
    assert np.all(np.isfinite(result.quaternion[:5]))


@pytest.mark.parametrize("estimator", [Mekf, Usque], ids=["mekf", "usque"])
def test_lost_track_is_flagged_and_recovered(estimator):
    """A prior 60 deg off that claims 0.1 deg, with the inflation alone (``recovery =
    "inflate"``; the restart is in ``tests/test_filter_recovery.py``): every vector is
    gated, so after ``max_rejected_epochs`` epochs they are flagged "lost track" and the
    attitude covariance is inflated by ``recover_sigma`` (repeatedly) until the
    vectors are accepted; the filter then converges and is valid again."""
    run = simulate_pass(np.random.default_rng(11), duration=120.0)
    axis = np.array([0.0, 1.0, 1.0]) / math.sqrt(2.0)
    prior = Prior(
        Rotation.from_rotvec(np.radians(60.0) * axis) * run.truth[0],
        prior_covariance(np.radians(0.1)),
        bias=np.zeros(3),
    )
    options = FilterOptions(recovery="inflate")
    result = solve_with(estimator(filter=options), run.gyro, run.t, run.measurements, prior)
    lost = np.char.startswith(result.reason.astype(str), "lost track")
    first = options.max_rejected_epochs - 1
    assert lost[first] and not lost[:first].any()
    assert result.diagnostics["recoveries"].sum() >= 1
    assert result.valid[-60:].all()
    error = np.linalg.norm(
        attitude_error(result.attitude()[-60:], run.truth_at_epochs[-60:]), axis=1
    )
    assert error.max() < 5.0 * SIGMA


@pytest.mark.parametrize("estimator", [Mekf, Usque], ids=["mekf", "usque"])
def test_lost_track_recovery_reacquires_the_bias(estimator):
    """For the first 150 s the vectors come from a false attitude turning 0.2
    deg/s faster about z than the gyro says (a misidentified source): the
    filter settles on a bias about 0.2 deg/s wrong with a small covariance.
    From 150 s (the false attitude is 30 deg off) the true vectors are gated,
    the track is lost, and the recovery inflates the bias covariance by the
    prior's as well as the attitude's (``recovery = "inflate"``), so the filter
    re-estimates the bias and converges.  With the attitude inflated alone it
    re-acquires the attitude at each recovery and drifts off again with the wrong bias (measured: 30
    recoveries, valid epochs up to 2 deg off in the last 60 s, the bias still
    0.2 deg/s wrong; with the bias inflated too: 4 recoveries, 0.04 deg)."""
    run = simulate_pass(np.random.default_rng(12), duration=400.0)
    extra = np.radians(0.2) * np.array([0.0, 0.0, 1.0])
    switch = 150
    false_truth = (
        Rotation.from_rotvec(-np.outer(run.t[:switch], extra)) * run.truth_at_epochs[:switch]
    )
    measurements = [
        VectorMeasurement(attitude.apply(REFERENCES), REFERENCES, SIGMA) for attitude in false_truth
    ] + run.measurements[switch:]
    prior = Prior(run.truth[0], prior_covariance(np.radians(1.0)), bias=run.bias[0])
    options = FilterOptions(recovery="inflate")
    result = solve_with(estimator(filter=options), run.gyro, run.t, measurements, prior)
    assert result.diagnostics["recoveries"][switch:].sum() >= 1
    assert result.valid[-60:].all()
    error = np.linalg.norm(
        attitude_error(result.attitude()[-60:], run.truth_at_epochs[-60:]), axis=1
    )
    assert error.max() < 5.0 * SIGMA
    bias_error = np.linalg.norm(result.bias[-1] - run.bias_at_epochs[-1])
    assert bias_error < np.radians(0.01)


def test_rts_smooths_each_valid_stretch_on_its_own():
    """Vectors 30 deg off for 20 s that the ungated MEKF takes in: its consistency test
    flags that stretch, and the RTS pass over the whole pass gives the epochs before it
    exactly what it gives a pass that ends before it: the flagged states never reach the
    smoothed estimates before them."""
    run = simulate_pass(np.random.default_rng(21), duration=200.0)
    prior = Prior(run.truth[0], prior_covariance(np.radians(1.0)), bias=run.bias[0])
    turn = Rotation.from_rotvec(np.radians(30.0) * np.array([0.0, 0.0, 1.0]))
    measurements = list(run.measurements)
    for k in range(100, 120):
        false = (turn * run.truth_at_epochs[k]).apply(REFERENCES)
        measurements[k] = VectorMeasurement(false, REFERENCES, SIGMA)
    options = FilterOptions(gate_probability=1.0)
    forward = solve_with(Mekf(filter=options), run.gyro, run.t, measurements, prior)
    flagged = np.flatnonzero(~forward.valid)
    assert flagged.size and flagged[0] >= 100
    # flagged inconsistent, then (once the restart from a single frame follows) converging
    assert all(r.startswith(("inconsistent", "converging")) for r in forward.reason[flagged])
    assert forward.reason[flagged[0]].startswith("inconsistent")
    first = int(flagged[0])
    whole = rts_smooth(forward, options, "rts")
    before = solve_with(Mekf(filter=options), run.gyro, run.t[:first], measurements[:first], prior)
    short = rts_smooth(before, options, "rts")
    np.testing.assert_allclose(whole.quaternion[:first], short.quaternion, rtol=0, atol=1e-12)
    assert not whole.valid[flagged].any()
