"""USQUE (``attopt.solvers.filters.usque``) on small simulated passes.

Scenario: a body turning at a constant rate, gyro samples of
:func:`attopt.formulations.gyro.simulate_gyro`, and two body-frame unit vectors
(reference x and y axes) measured at every epoch.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from attopt.formulations.attitude_measurement import AttitudeMeasurement, VectorMeasurement
from attopt.formulations.conventions import attitude_error
from attopt.formulations.errors import ModelMismatchError
from attopt.formulations.gyro import GyroModel, GyroSamples, SimulatedGyro, simulate_gyro
from attopt.formulations.passes import Prior
from attopt.solvers.filters import FilterOptions, Mekf, Usque
from attopt.solvers.filters.common import propagate_attitude
from attopt.solvers.results import Track
from attopt.solvers.sequential import NON_FINITE
from tests.filter_passes import solve_with

REFERENCES = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
RATE = np.array([0.01, -0.02, 0.015])
"""True body rate (rad/s)."""
START = Rotation.from_euler("xyz", [10.0, 20.0, 30.0], degrees=True)
MODEL = GyroModel("test", sigma_v=1e-4, sigma_u=1e-6, initial_bias_sigma=0.01)
VECTOR_SIGMA = 1e-3


@dataclass
class UsquePass:
    """Simulated data of one pass."""

    gyro: SimulatedGyro
    truth: Rotation
    """True attitudes at the gyro sample times."""
    epochs: np.ndarray
    """Gyro sample index of each output epoch."""
    bodies: np.ndarray
    """``(N, 2, 3)`` measured unit vectors."""

    @property
    def t(self) -> np.ndarray:
        return self.gyro.samples.t[self.epochs]

    def measurements(self) -> list[AttitudeMeasurement | None]:
        return [VectorMeasurement(b, REFERENCES, VECTOR_SIGMA) for b in self.bodies]

    def errors(self, result: Track) -> np.ndarray:
        """``(N, 3)`` attitude errors (rad)."""
        return attitude_error(result.attitude(), self.truth[self.epochs])


def simulate(
    rng: np.random.Generator,
    duration: float,
    model: GyroModel = MODEL,
    every: int = 10,
    noise_free: bool = False,
) -> UsquePass:
    """A pass of ``duration`` s with a measurement every ``every`` gyro samples."""
    t = np.arange(0.0, duration + 1e-9, model.dt)
    truth = Rotation.from_rotvec(-np.outer(t, RATE)) * START
    if noise_free:
        clean = GyroModel("clean", 0.0, 0.0, 0.0, model.rate_hz)
        gyro = simulate_gyro(t, truth, clean, rng)
        bias = np.array([0.004, -0.003, 0.002])
        samples = GyroSamples(t, gyro.samples.rates + bias, model.dt)
        gyro = SimulatedGyro(samples, gyro.true_rates, np.broadcast_to(bias, (t.size, 3)))
    else:
        gyro = simulate_gyro(t, truth, model, rng)
    epochs = np.arange(0, t.size, every)
    bodies = np.stack([truth[i].apply(REFERENCES) for i in epochs])
    if not noise_free:
        bodies = bodies + VECTOR_SIGMA * rng.standard_normal(bodies.shape)
        bodies /= np.linalg.norm(bodies, axis=-1, keepdims=True)
    return UsquePass(gyro, truth, epochs, bodies)


def prior_at(data: UsquePass, error: np.ndarray, covariance: np.ndarray) -> Prior:
    """Prior whose attitude is ``exp(error) A_true`` and bias zero."""
    return Prior(Rotation.from_rotvec(error) * data.truth[0], covariance, bias=np.zeros(3))


def wide_covariance(attitude_sigma_deg: float) -> np.ndarray:
    return np.diag([np.radians(attitude_sigma_deg) ** 2] * 3 + [MODEL.initial_bias_sigma**2] * 3)


def run(
    data: UsquePass,
    prior: Prior,
    measurements: list[AttitudeMeasurement | None] | None = None,
    options: FilterOptions | None = None,
    model: GyroModel = MODEL,
    estimator: type[Mekf | Usque] = Usque,
) -> Track:
    measurements = data.measurements() if measurements is None else measurements
    filter_ = estimator(filter=options or FilterOptions())
    return solve_with(filter_, data.gyro.samples, data.t, measurements, prior, model)


def test_noise_free_data_converge_to_the_truth_from_20_degrees() -> None:
    """Exact gyro rates (constant bias) and exact vectors: the estimate converges to the truth.

    The filter's noise model is the realistic one; with exact data nothing
    but the initial error drives its error, which after the first update (the
    prior updated by that epoch's single frame, a 3-row attitude observation)
    is 3e-6 rad, stays below 1e-4 rad while the bias is learnt (the second
    update iterates) and then decays with the bias estimate's error (about as
    ``1 / t``: 2e-9 rad and 2e-10 rad/s after 400 s).  Asserted with margins of
    at least 20: attitude within 1e-7 rad, bias within 1e-8 rad/s (true bias
    5e-3 rad/s).
    """
    rng = np.random.default_rng(np.random.SeedSequence(101))
    data = simulate(rng, 400.0, noise_free=True)
    result = run(data, prior_at(data, np.radians([20.0, 0.0, 0.0]), wide_covariance(20.0)))
    assert result.valid.all()
    diagnostics = result.diagnostics
    assert diagnostics["n_gated"].sum() == 0
    assert diagnostics["nis_dof"][0] == 3 and diagnostics["update_iterations"][0] == 0
    assert np.linalg.norm(data.errors(result)[0]) < 1e-5  # the single frame's update
    assert diagnostics["update_iterations"][1] > 1
    assert np.all(diagnostics["update_iterations"][1:] >= 1)
    errors = data.errors(result)
    assert np.linalg.norm(errors, axis=1).max() < 1e-4
    assert np.abs(errors[-1]).max() < 1e-7
    np.testing.assert_allclose(result.bias[-1], data.gyro.bias[-1], rtol=0, atol=1e-8)


def test_agrees_with_the_mekf_on_noisy_data() -> None:
    """Same data and prior: after the transient the USQUE and MEKF estimates differ
    by a small fraction of the filter sigma and their covariances agree."""
    rng = np.random.default_rng(np.random.SeedSequence(202))
    data = simulate(rng, 300.0)
    prior = prior_at(data, np.radians([5.0, -3.0, 2.0]), wide_covariance(5.0))
    unscented, extended = run(data, prior), run(data, prior, estimator=Mekf)
    assert unscented.valid.all() and extended.valid.all()
    steady = slice(50, None)
    sigma = np.sqrt(np.diagonal(unscented.covariance, axis1=1, axis2=2))[steady]
    difference = attitude_error(unscented.attitude(), extended.attitude())
    assert np.sqrt(np.mean((difference[steady] / sigma) ** 2, axis=0)).max() < 0.02
    assert np.abs(difference[steady] / sigma).max() < 0.1
    bias_sigma = np.sqrt(np.diagonal(unscented.state_covariance[steady, 3:, 3:], axis1=1, axis2=2))
    bias_difference = (unscented.bias - extended.bias)[steady] / bias_sigma
    assert np.abs(bias_difference).max() < 0.1
    # covariances: difference in units of the standard deviations, (P1 - P2)_ij / (s_i s_j)
    scale = np.sqrt(np.diagonal(extended.state_covariance[steady], axis1=1, axis2=2))
    normalised = (unscented.state_covariance - extended.state_covariance)[steady] / (
        scale[:, :, None] * scale[:, None, :]
    )
    assert np.abs(normalised).max() < 0.01


def test_nees_is_consistent_over_a_monte_carlo() -> None:
    """Run-averaged NEES over ``M = 20`` seeded runs of 300 s, time-averaged.

    Each run draws its initial error from the prior covariance, so every epoch
    is a valid sample.  At epoch ``k``, ``eps_k = (1 / M) sum_runs e^T P^-1
    e`` (attitude error ``e``, filter attitude covariance ``P``) and, for a
    consistent filter, ``M eps_k ~ chi2(3 M)``.  The test statistic is the
    time average of ``eps_k`` over the epochs; it must lie in the two-sided
    95% interval ``[chi2.ppf(0.025, 3 M), chi2.ppf(0.975, 3 M)] / M`` =
    [2.02, 4.17].  That interval is the one of a single epoch: averaging over
    (correlated) epochs only narrows the statistic's spread, so the test is
    conservative.  The same for the 6-state NEES (attitude and bias,
    ``chi2(6 M) / M`` = [4.81, 7.39]): ``attitude_error`` is ``-delta``
    (``A_est = exp(e) A_true``), so the bias error paired with it is
    ``beta_hat - beta = -delta_beta``.  Seeded, so deterministic (the
    statistics are 3.23 and 6.21).
    """
    runs, duration = 20, 300.0
    model = GyroModel("mc", sigma_v=1e-4, sigma_u=1e-6, initial_bias_sigma=1e-3, rate_hz=2.0)
    covariance = np.diag([np.radians(2.0) ** 2] * 3 + [1e-3**2] * 3)
    root = np.linalg.cholesky(covariance)
    attitude_nees, full_nees = [], []
    for seed in np.random.SeedSequence(303).spawn(runs):
        rng = np.random.default_rng(seed)
        data = simulate(rng, duration, model=model, every=10)
        draw = root @ rng.standard_normal(6)
        start = Rotation.from_rotvec(-draw[:3]) * data.truth[0]
        prior = Prior(start, covariance, bias=data.gyro.bias[0] - draw[3:])
        result = run(data, prior, model=model)
        assert result.valid.all()
        errors = data.errors(result)
        attitude_nees.append(
            np.einsum("ni,nij,nj->n", errors, np.linalg.inv(result.covariance), errors)
        )
        errors = np.concatenate([errors, result.bias - data.gyro.bias[data.epochs]], axis=1)
        inverse = np.linalg.inv(result.state_covariance)
        full_nees.append(np.einsum("ni,nij,nj->n", errors, inverse, errors))
    for nees, size in ((attitude_nees, 3), (full_nees, 6)):
        statistic = np.mean(nees)
        low, high = chi2.ppf([0.025, 0.975], size * runs) / runs
        assert low < statistic < high, (size, low, statistic, high)


def test_gated_outlier_leaves_the_estimate_as_without_it() -> None:
    """One vector replaced by one 30 deg (500 sigma) away is gated; every estimate
    equals that of the run where the epoch has only the other vector."""
    rng = np.random.default_rng(np.random.SeedSequence(404))
    data = simulate(rng, 120.0)
    prior = prior_at(data, np.radians([1.0, 1.0, -1.0]), wide_covariance(2.0))
    k = 60
    measurements = data.measurements()
    wrong = data.bodies[k].copy()
    axis = np.cross(np.cross(wrong[0], wrong[1]), wrong[1])  # perpendicular to the vector
    wrong[1] = Rotation.from_rotvec(np.radians(30.0) * axis / np.linalg.norm(axis)).apply(wrong[1])
    with_outlier = list(measurements)
    with_outlier[k] = VectorMeasurement(wrong, REFERENCES, VECTOR_SIGMA)
    without = list(measurements)
    without[k] = VectorMeasurement(data.bodies[k][:1], REFERENCES[:1], VECTOR_SIGMA)
    gated, reference = run(data, prior, with_outlier), run(data, prior, without)
    diagnostics = gated.diagnostics
    assert diagnostics["n_gated"][k] == 1 and diagnostics["n_used"][k] == 1
    assert diagnostics["n_gated"].sum() == 1
    np.testing.assert_allclose(gated.quaternion, reference.quaternion, atol=1e-13)
    np.testing.assert_allclose(gated.bias, reference.bias, rtol=0, atol=1e-16)
    np.testing.assert_allclose(
        gated.state_covariance, reference.state_covariance, rtol=1e-10, atol=0
    )
    np.testing.assert_allclose(diagnostics["nis"], reference.diagnostics["nis"])
    unmonitored = FilterOptions(gate_probability=1.0, consistency_window=0)
    ungated = run(data, prior, with_outlier, unmonitored)
    assert np.degrees(np.abs(data.errors(ungated)[k])).max() > 1.0  # the outlier does harm
    # ... and, ungated, the innovation test flags the epoch it enters
    monitored = run(data, prior, with_outlier, FilterOptions(gate_probability=1.0))
    assert not monitored.valid[k] and monitored.reason[k].startswith("inconsistent")
    assert monitored.error[k] is ModelMismatchError
    assert monitored.valid[:k].all()


def test_gyro_gap_grows_the_covariance_and_is_flagged_only_when_long() -> None:
    """5 s of NaN gyro samples with no measurements around them: the estimate stays
    finite, the attitude variance grows by the hold variance ``(sigma_hold T)^2``
    per axis more than without the gap, and the gap's epochs are flagged only
    when ``max_gyro_gap_s`` is shorter than the gap."""
    rng = np.random.default_rng(np.random.SeedSequence(505))
    data = simulate(rng, 120.0)
    prior = prior_at(data, np.radians([1.0, -1.0, 1.0]), wide_covariance(2.0))
    first, last = 600, 650  # gyro steps of the gap: t = 60 s to 65 s
    rates = data.gyro.samples.rates.copy()
    rates[first:last] = np.nan
    gapped = UsquePass(
        SimulatedGyro(
            GyroSamples(data.gyro.samples.t, rates, MODEL.dt), data.gyro.true_rates, data.gyro.bias
        ),
        data.truth,
        data.epochs,
        data.bodies,
    )
    measurements = data.measurements()
    quiet = range(58, 68)  # epochs (t = k s) without measurements
    for k in quiet:
        measurements[k] = None
    options = FilterOptions()
    result = run(gapped, prior, measurements, options)
    no_gap = run(data, prior, measurements, options)
    assert result.valid.all()
    assert np.all(np.isfinite(result.quaternion)) and np.all(np.isfinite(result.state_covariance))
    gap_s = result.diagnostics["gyro_gap_s"]
    np.testing.assert_allclose(gap_s[61:66], [1.0, 2.0, 3.0, 4.0, 5.0], atol=1e-9)
    assert gap_s[:61].max() == 0 and gap_s[66:].max() == 0
    variance = np.trace(result.state_covariance[:, :3, :3], axis1=1, axis2=2)
    baseline = np.trace(no_gap.state_covariance[:, :3, :3], axis1=1, axis2=2)
    growth = 3.0 * (options.hold_rate_sigma * 5.0) ** 2
    assert np.all(np.diff(variance[58:68]) > 0)
    np.testing.assert_allclose(variance[67] - baseline[67], growth, rtol=0.05)
    assert np.degrees(np.abs(data.errors(result)).max()) < 0.5

    short = FilterOptions(max_gyro_gap_s=2.5)
    flagged = run(gapped, prior, measurements, short)
    invalid = np.flatnonzero(~flagged.valid)
    np.testing.assert_array_equal(invalid, [63, 64, 65])
    assert all("gyro gap" in reason for reason in flagged.reason[invalid])
    valid = flagged.valid
    np.testing.assert_array_equal(flagged.quaternion[valid], result.quaternion[valid])


def test_epoch_without_measurement_only_propagates() -> None:
    """A ``None`` epoch: no update is recorded, the bias is unchanged, the attitude
    is the previous estimate carried by the bias-corrected gyro rates (to
    second order in the error covariance), and the covariance grows."""
    rng = np.random.default_rng(np.random.SeedSequence(606))
    data = simulate(rng, 60.0)
    prior = prior_at(data, np.radians([1.0, 1.0, 1.0]), wide_covariance(2.0))
    k = 40
    measurements = data.measurements()
    measurements[k] = None
    result = run(data, prior, measurements)
    assert result.valid.all()
    diagnostics = result.diagnostics
    assert np.isnan(diagnostics["nis"][k]) and np.isnan(result.loss[k])
    assert diagnostics["n_used"][k] == 0 and diagnostics["update_iterations"][k] == 0
    assert diagnostics["n_used"][k - 1] == 2 and diagnostics["n_used"][k + 1] == 2
    np.testing.assert_allclose(result.bias[k], result.bias[k - 1], rtol=0, atol=1e-18)
    rates = data.gyro.samples.rates[data.epochs[k - 1] : data.epochs[k]] - result.bias[k - 1]
    carried = propagate_attitude(result.attitude()[k - 1], rates, MODEL.dt)
    assert np.abs(attitude_error(result.attitude()[k], carried)).max() < 1e-9
    p = result.state_covariance
    assert np.trace(p[k, :3, :3]) > np.trace(p[k - 1, :3, :3])
    assert np.trace(p[k + 1, :3, :3]) < np.trace(p[k, :3, :3])


@pytest.mark.parametrize("steps", [0, 10])
def test_first_epoch_at_or_after_the_first_gyro_sample(steps: int) -> None:
    """The first epoch may be the first gyro sample (no propagation) or a later one."""
    rng = np.random.default_rng(np.random.SeedSequence(707))
    data = simulate(rng, 30.0)
    data.epochs = data.epochs + steps
    data.epochs = data.epochs[data.epochs < len(data.truth)]
    data.bodies = np.stack([data.truth[i].apply(REFERENCES) for i in data.epochs])
    result = run(data, prior_at(data, np.zeros(3), wide_covariance(1.0)))
    assert result.valid.all()
    assert np.degrees(np.abs(data.errors(result)[-1]).max()) < 0.05


class WithoutJacobian(VectorMeasurement):
    """A vector measurement that refuses to give Jacobians."""

    def predict(self, attitude: Rotation, jacobian: bool = True):
        if jacobian:
            raise AssertionError("USQUE asked for a Jacobian")
        return super().predict(attitude, jacobian=False)


def test_needs_no_jacobian() -> None:
    """USQUE's updates use no Jacobian (the single-frame check of a restart does, so it is
    left out here): a measurement that refuses to give one is estimated as the plain
    vectors are (those by the compiled update, whose kernel evaluates the Jacobian beside
    the prediction; equal to round-off)."""
    rng = np.random.default_rng(np.random.SeedSequence(808))
    data = simulate(rng, 20.0)
    prior = prior_at(data, np.radians([1.0, 1.0, 1.0]), wide_covariance(2.0))
    measurements = [WithoutJacobian(b, REFERENCES, VECTOR_SIGMA) for b in data.bodies]
    options = FilterOptions(recovery="inflate")
    result = run(data, prior, measurements, options)
    reference = run(data, prior, options=options)
    assert result.valid.all()
    np.testing.assert_allclose(result.quaternion, reference.quaternion, rtol=0, atol=1e-12)


def test_covariance_overflow_is_flagged_not_raised() -> None:
    """A rate random walk whose variance overflows makes the covariance infinite at
    the first propagation: that epoch and all later ones are flagged, and no
    NaN attitude is reported valid."""
    rng = np.random.default_rng(np.random.SeedSequence(909))
    data = simulate(rng, 10.0)
    prior = prior_at(data, np.zeros(3), wide_covariance(1.0))
    huge = np.float64(1e200)  # its square overflows to inf
    wild = GyroModel("wild", MODEL.sigma_v, huge, MODEL.initial_bias_sigma, MODEL.rate_hz)
    with np.errstate(over="ignore", invalid="ignore"):
        result = run(data, prior, model=wild)
    assert result.valid[0] and not result.valid[1:].any()
    assert set(result.reason[1:]) == {NON_FINITE}
    assert np.all(np.isnan(result.quaternion[1:]))
