"""The batch smoother's residual tests: per epoch (windowed, as the filters' innovation
test) and over the whole pass (``SmootherReport.chi_square``).

Scenario: :mod:`tests.filter_passes` (two unit vectors at 1 Hz, a 2 Hz MEMS-class
gyro, 30 s passes).
"""

from __future__ import annotations

import numpy as np

from attopt.formulations.attitude_measurement import VectorMeasurement
from attopt.solvers.filters import FilterOptions
from attopt.solvers.smoother import BatchSmoother
from tests.filter_passes import SIGMA, drawn_prior, prior_covariance, simulate_pass, solve_with

TRIALS = 20


def _pass(seed: int):
    rng = np.random.default_rng(seed)
    run = simulate_pass(rng, duration=30.0)
    return run, drawn_prior(rng, run, prior_covariance(np.radians(1.0)))


def test_whole_pass_chi_square_follows_its_distribution():
    """Consistent passes: twice the final cost averages two per unit vector (its
    geodesic residual has two components; three rows are declared, so the reported
    test is conservative), every pass is consistent and no epoch is flagged."""
    statistics, dof, effective = [], [], []
    for seed in range(TRIALS):
        run, prior = _pass(seed)
        result = solve_with(BatchSmoother(), run.gyro, run.t, run.measurements, prior)
        report = result.report
        assert result.valid.all() and report.consistent, (seed, set(result.reason))
        statistics.append(report.chi_square)
        dof.append(report.chi_square_dof)
        effective.append(2.0 * report.measurement_rows / 3.0)
    assert dof == [report.measurement_rows] * TRIALS  # no gyro gap: every row counts
    ratio = np.sum(statistics) / np.sum(effective)
    # the sum over the trials is chi-square(sum of 2 per vector): ~2,480 +/- 70
    assert abs(ratio - 1.0) < 0.1, ratio


def _noisier(run, epochs: range, factor: float) -> list:
    """The pass's measurements with ``epochs`` drawn ``factor`` times noisier than the
    declared ``SIGMA``."""
    rng = np.random.default_rng(99)
    measurements = list(run.measurements)
    for k in epochs:
        truth = run.truth_at_epochs[k].apply(measurements[k].reference)
        body = truth + factor * SIGMA * rng.standard_normal(truth.shape)
        measurements[k] = VectorMeasurement(body, measurements[k].reference, SIGMA)
    return measurements


def test_under_declared_noise_is_flagged_and_the_pass_inconsistent():
    """Epochs 10-19 with six times the declared noise, the gate off: the windowed
    residual test flags the epochs whose window holds enough of them (not the first
    ten), the whole pass fails its test, and with the test turned off
    (``consistency_window = 0``) nothing is flagged and the estimates stay."""
    run, prior = _pass(3)
    measurements = _noisier(run, range(10, 20), 6.0)
    ungated = FilterOptions(gate_probability=1.0)  # the gate would reject most of them
    result = solve_with(BatchSmoother(filter=ungated), run.gyro, run.t, measurements, prior)
    flagged = ~result.valid
    assert not flagged[:10].any() and flagged[12:20].all(), flagged.astype(int)
    assert {r for r in result.reason[flagged]} == {
        "inconsistent: the residuals at the solution of the last 10 epochs with measurements "
        "fail the chi-square test at 1e-06"
    }
    assert not result.report.consistent and result.report.chi_square_p < 1e-6
    off = BatchSmoother(filter=FilterOptions(gate_probability=1.0, consistency_window=0))
    untested = solve_with(off, run.gyro, run.t, measurements, prior)
    assert untested.valid.all()
    # the same optimum to the optimiser's tolerance (its MEKF start differs: the
    # filter's own test is off too)
    np.testing.assert_allclose(
        untested.quaternion[~flagged], result.quaternion[~flagged], atol=1e-5
    )
