"""The batch smoother's residual tests: per epoch (windowed, as the filters' innovation
test) and over the whole pass (``SmootherReport.chi_square``).

Scenario: :mod:`tests.filter_passes` (two unit vectors at 1 Hz, a 2 Hz MEMS-class
gyro, 30 s passes).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.stats import chi2

from attopt.formulations.attitude_measurement import VectorMeasurement
from attopt.formulations.conventions import attitude_error
from attopt.formulations.errors import ModelMismatchError
from attopt.solvers.filters import FilterOptions
from attopt.solvers.smoother import BatchSmoother
from tests.filter_passes import SIGMA, drawn_prior, prior_covariance, simulate_pass, solve_with

TRIALS = 20
QUANTILE = chi2.ppf(1.0 - 1e-4, 3)


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


def _nees(result, run) -> np.ndarray:
    """Each valid epoch's attitude NEES against the smoother's own covariance."""
    valid = result.valid
    error = attitude_error(result.attitude(), run.truth_at_epochs[valid])
    return np.einsum("ei,eij,ej->e", error, np.linalg.inv(result.covariance[valid]), error)


def test_a_gyro_fault_is_excluded_and_its_epoch_flagged():
    """The gyro misses a 10 deg turn about x between 60 and 61 s (a manoeuvre the record
    does not have), the gate off: the AHRS factor over that interval fails its
    chi-square(3) test at the solution, so it is removed, the pass split there and
    re-solved; epoch 61 alone is flagged ``inconsistent`` (``ModelMismatchError``), the
    pass is consistent and no valid epoch is beyond the chi-square(3) 1 - 1e-4 quantile.
    Without the test (``gyro_exclusions = 0``) the least squares spread the turn over its
    neighbours through the bias and the windows flag about half the pass."""
    rng = np.random.default_rng(5)
    run = simulate_pass(rng, duration=120.0)
    prior = drawn_prior(rng, run, prior_covariance(np.radians(1.0)))
    rates = run.gyro.rates.copy()
    rates[(run.gyro.t[:-1] >= 60.0) & (run.gyro.t[:-1] < 61.0)] -= np.radians([10.0, 0.0, 0.0])
    gyro = dataclasses.replace(run.gyro, rates=rates)
    ungated = FilterOptions(gate_probability=1.0)
    result = solve_with(BatchSmoother(filter=ungated), gyro, run.t, run.measurements, prior)
    assert np.flatnonzero(~result.valid).tolist() == [61]
    assert result.reason[61] == (
        "inconsistent: the gyro up to this epoch contradicts the measurements around it "
        "(chi-square test at 1e-06); the pass is split there"
    )
    assert result.error[61] is ModelMismatchError
    assert result.report.excluded_intervals == 1 and result.report.consistent
    assert np.max(_nees(result, run)) < QUANTILE
    blind = BatchSmoother(filter=ungated, gyro_exclusions=0)
    spread = solve_with(blind, gyro, run.t, run.measurements, prior)
    assert spread.report.excluded_intervals == 0 and not spread.report.consistent
    assert np.mean(~spread.valid) > 0.3


@pytest.mark.parametrize(
    ("seed", "stop", "rate_deg_s"), [(7, 61.0, 10.0), (5, 70.0, 0.5)], ids=["1s", "10s"]
)
def test_a_gyro_fault_behind_gated_epochs_excludes_the_whole_stretch(seed, stop, rate_deg_s):
    """A turn the gyro misses from 60 s (10 deg in 1 s; 5 deg in 10 s), the gate on: the
    MEKF start follows the gyro, gates the vectors of epochs 61-69 (at some epochs one
    vector of two) and restarts at 70, so the smoother has no full measurement between
    epochs 60 and 70 and the least squares share the turn among those ten intervals.
    Nothing locates it there, and an epoch left hanging from a faulty interval would
    take its word: all ten are removed, epochs 61-70 are flagged, and no valid epoch is
    beyond the quantile (before: the gyro bridge was reported valid with NEES above
    3e5; with the epochs that kept one vector counted as measured, 779)."""
    rng = np.random.default_rng(seed)
    run = simulate_pass(rng, duration=120.0)
    prior = drawn_prior(rng, run, prior_covariance(np.radians(1.0)))
    rates = run.gyro.rates.copy()
    turning = (run.gyro.t[:-1] >= 60.0) & (run.gyro.t[:-1] < stop)
    rates[turning] += np.radians([rate_deg_s, 0.0, 0.0])
    gyro = dataclasses.replace(run.gyro, rates=rates)
    result = solve_with(BatchSmoother(), gyro, run.t, run.measurements, prior)
    assert np.flatnonzero(result.diagnostics["n_gated"]).tolist() == list(range(61, 70))
    assert np.flatnonzero(~result.valid).tolist() == list(range(61, 71))
    assert all(r.startswith("inconsistent: the gyro up to") for r in result.reason[61:71])
    assert result.report.excluded_intervals == 10 and result.report.consistent
    assert np.max(_nees(result, run)) < QUANTILE
