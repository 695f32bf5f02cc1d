"""Whole-pass batch least squares over Yang et al. 2014's dynamics (``solvers/doa/batch_ls.py``,
registry ``bls_yang2014``): noise-free recovery, its covariance against the ``Q = 0``
posterior bound, Monte Carlo consistency, the estimator from its RTS start, flagged
non-convergence and bad input."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from attopt.formulations.attitude_measurement import EulerAngleMeasurement
from attopt.formulations.conventions import attitude_error
from attopt.formulations.errors import (
    ConvergenceError,
    ModelMismatchError,
    UnobservableError,
    UnsupportedMeasurementError,
)
from attopt.formulations.passes import Pass
from attopt.formulations.snapshot import Snapshot
from attopt.solvers.doa import DoaBatchLs, DoaRts
from attopt.solvers.doa.batch_ls import BatchLsOptions, batch_least_squares
from attopt.solvers.doa.ekf import ekf_dynamics
from attopt.solvers.filters.common import apply_error, error_vector
from attopt.solvers.results import Track
from attopt.solvers.sequential import stored_rotations
from tests.test_doa_ekf import (
    VectorPass,
    rate_prior,
    relative_covariance_difference,
    simulate_vectors,
)
from tests.test_doa_eks import bound

EPOCHS = 400
RUNS = 20
START = np.diag([1e-6] * 3 + [1e-4] * 3)
"""Covariance of the start's error ``[delta_omega, delta]`` in the Monte Carlo runs
(1e-3 rad/s and 0.6 deg): inside the basin of the minimum."""


def solve(run: VectorPass, attitude: Rotation, rate: np.ndarray, **options) -> Track:
    return batch_least_squares(
        attitude,
        rate,
        run.arrays,
        ekf_dynamics(run.pass_()),
        run.t,
        BatchLsOptions(**options),
        "bls_yang2014",
    )


def drawn_start(rng: np.random.Generator, run: VectorPass) -> tuple[Rotation, np.ndarray]:
    """A start whose error ``[delta_omega, delta]`` (``A_true = C(delta) A``) is drawn
    from :data:`START`."""
    error = rng.multivariate_normal(np.zeros(6), START)
    return apply_error(-error[3:], run.truth[0]), run.rate[0] - error[:3]


@settings(max_examples=10, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    angle=st.floats(0.0, np.radians(10.0)),
    rate_error=st.floats(0.0, 2e-3),
)
def test_noise_free_recovers_the_truth(seed: int, angle: float, rate_error: float) -> None:
    """Exact vectors of a truth that follows the step map: from a start up to 10 deg and
    2e-3 rad/s off, the whole trajectory is recovered to 1e-9 rad (rate 1e-11 rad/s)
    and the cost is zero to rounding."""
    rng = np.random.default_rng(seed)
    run = simulate_vectors(rng, EPOCHS, noisy=False)
    axis = rng.normal(size=3)
    direction = rng.normal(size=3)
    start = Rotation.from_rotvec(angle * axis / np.linalg.norm(axis)) * run.truth[0]
    rate = run.rate[0] + rate_error * direction / np.linalg.norm(direction)
    result = solve(run, start, rate)
    assert result.report.converged, result.report.reason
    assert result.valid.all() and result.state == ("rate", "attitude")
    assert np.abs(attitude_error(result.attitude(), run.truth)).max() < 1e-9
    assert np.abs(result.rate - run.rate).max() < 1e-11
    assert result.report.cost < 1e-16


def test_covariance_is_the_zero_process_noise_smoother_bound() -> None:
    """At the truth (noise-free vectors) ``S_k N^-1 S_k^T`` is the posterior bound of the
    EKF's model with ``Q = 0``, computed by the filter-and-RTS recursion
    (:func:`~attopt.solvers.doa.eks.posterior_bound_ekf`): two independent computations of the
    same Cramer-Rao bound.  The recursion needs a prior: with a wide one (1e-2 rad^2/s^2,
    1 rad^2; measured difference 3e-7, its own weight) at every epoch, and at epoch 0
    (``S_0 = I``) exactly, ``(N + P_0^-1)^-1``, with a tighter one (measured 1.5e-9)."""
    rng = np.random.default_rng(3)
    run = simulate_vectors(rng, EPOCHS, noisy=False)
    result = solve(run, run.truth[0], run.rate[0])

    def smoother_bound(prior: np.ndarray) -> np.ndarray:
        return bound(run, prior, 0.0)[1]

    wide = np.diag([1e-2] * 3 + [1.0] * 3)
    covariance = result.state_covariance
    assert relative_covariance_difference(covariance, smoother_bound(wide)) < 1e-6
    tight = np.diag([1e-4] * 3 + [1e-2] * 3)
    with_prior = np.linalg.inv(np.linalg.inv(covariance[0]) + np.linalg.inv(tight))
    difference = relative_covariance_difference(with_prior, smoother_bound(tight)[0])
    assert difference < 1e-8


@pytest.fixture(scope="module")
def monte_carlo() -> tuple[np.ndarray, np.ndarray, list[Track]]:
    """20 seeded noisy passes: errors ``(runs, epochs, 6)``, covariances and results."""
    errors, covariances, results = [], [], []
    for seed in range(RUNS):
        rng = np.random.default_rng(200 + seed)
        run = simulate_vectors(rng, EPOCHS)
        result = solve(run, *drawn_start(rng, run))
        errors.append(
            np.concatenate(
                [run.rate - result.rate, error_vector(run.truth, result.attitude())], axis=1
            )
        )
        covariances.append(result.state_covariance)
        results.append(result)
    return np.array(errors), np.array(covariances), results


def test_monte_carlo_nees_is_consistent(monte_carlo) -> None:
    """The estimate's 6-state NEES at epoch 0 over the 20 runs, a ``chi2(6 M) / M`` mean
    for an efficient estimator, is inside its two-sided 99% interval; so is the
    attitude's (3 states) at the middle and the last epoch."""
    errors, covariances, results = monte_carlo
    assert all(r.report.converged for r in results)
    low, high = chi2.ppf([0.005, 0.995], 6 * RUNS) / RUNS
    nees = np.einsum("ri,rij,rj->r", errors[:, 0], np.linalg.inv(covariances[:, 0]), errors[:, 0])
    assert low < nees.mean() < high, (nees.mean(), low, high)
    low, high = chi2.ppf([0.005, 0.995], 3 * RUNS) / RUNS
    for k in (EPOCHS // 2, EPOCHS - 1):
        e, p = errors[:, k, 3:], covariances[:, k, 3:, 3:]
        nees = np.einsum("ri,rij,rj->r", e, np.linalg.inv(p), e)
        assert low < nees.mean() < high, (k, nees.mean(), low, high)


def test_cost_per_row_is_two_thirds(monte_carlo) -> None:
    """Each unit vector's geodesic innovation lies in the plane normal to it: two of its
    three rows carry noise, so the minimised cost per row is about 2/3 (minus the six
    fitted states)."""
    _, _, results = monte_carlo
    per_row = np.array([r.report.cost / r.report.rows for r in results])
    assert np.all(np.abs(per_row - 2.0 / 3.0) < 0.1), per_row


def test_not_converged_is_flagged() -> None:
    """One pass allowed: the result says so instead of passing for a solution."""
    rng = np.random.default_rng(4)
    run = simulate_vectors(rng, EPOCHS)
    result = solve(run, *drawn_start(rng, run), max_iterations=1)
    assert not result.report.converged
    assert result.report.reason == "not converged in 1 passes"
    assert not result.valid.any() and set(result.reason) == {"not converged in 1 passes"}
    assert np.isnan(result.quaternion).all()
    with pytest.raises(ConvergenceError, match="not converged"):
        result.epoch(0).raise_if_invalid()
    kept = solve(
        run, *drawn_start(np.random.default_rng(4), run), max_iterations=1, flag_unconverged=False
    )
    assert kept.valid.all() and not kept.report.converged


def test_no_vectors_is_unobservable() -> None:
    run = simulate_vectors(np.random.default_rng(5), 50)
    run.body[:] = np.nan
    with pytest.raises(UnobservableError):
        solve(run, run.truth[0], run.rate[0])


def test_a_start_spinning_beyond_the_step_limit_raises() -> None:
    run = simulate_vectors(np.random.default_rng(6), 50)
    with pytest.raises(ConvergenceError):
        solve(run, run.truth[0], np.array([1.0, 0.0, 0.0]))


def test_estimator_starts_from_the_rts_track() -> None:
    """``bls_yang2014`` on a noise-free pass: without a start track it runs ``rts_yang2014``
    and starts from its first epoch, exactly as when given that track; the truth is
    recovered."""
    rng = np.random.default_rng(7)
    run = simulate_vectors(rng, EPOCHS, noisy=False)
    prior = rate_prior(
        apply_error(np.radians([2.0, -1.0, 1.0]), run.truth[0]), run.rate[0] + 1e-4, START * 4
    )
    pass_ = run.pass_(prior)
    rts = DoaRts().solve(pass_)
    own, given = DoaBatchLs().solve(pass_), DoaBatchLs().solve(pass_, initial=rts)
    np.testing.assert_array_equal(own.quaternion, given.quaternion)
    np.testing.assert_array_equal(own.rate, given.rate)
    expected = solve(run, stored_rotations(rts.quaternion[0]), rts.rate[0])
    np.testing.assert_array_equal(own.quaternion, expected.quaternion)
    assert own.method == "bls_yang2014" and own.report.converged
    assert np.abs(attitude_error(own.attitude(), run.truth)).max() < 1e-9


def test_estimator_accepts_unit_vectors_only() -> None:
    """Another measurement type raises ``UnsupportedMeasurementError``."""
    run = simulate_vectors(np.random.default_rng(8), 20)
    pass_ = run.pass_(rate_prior(run.truth[0], run.rate[0], START))
    snapshots = list(pass_.snapshots)
    snapshots[3] = Snapshot.of(EulerAngleMeasurement([0.1, 0.2, 0.3], 1e-4 * np.eye(3)))
    mixed = Pass(pass_.t, tuple(snapshots), None, pass_.prior, pass_.dynamics)
    with pytest.raises(UnsupportedMeasurementError, match="bls_yang2014 accepts VectorMeasurement"):
        DoaBatchLs().solve(mixed)


def test_consistent_passes_pass_both_residual_tests(monte_carlo) -> None:
    """The 20 consistent passes: no epoch flagged by the windowed residual test, every
    pass consistent as a whole, and the per-epoch residuals sum to the cost."""
    _, _, results = monte_carlo
    for result in results:
        assert result.valid.all(), set(result.reason)
        assert result.report.consistent, result.report.chi_square_p
        np.testing.assert_allclose(result.diagnostics["nis"].sum(), result.report.cost)
        assert result.diagnostics["nis_dof"].sum() == result.report.rows


def test_a_truth_off_the_dynamics_fails_the_residual_tests() -> None:
    """A truth with process noise (``Q = 1e-7 E_6`` per step) that the batch least
    squares' exact dynamics cannot follow: the whole pass fails its chi-square test and
    the windowed test flags epochs (``inconsistent``, ``ModelMismatchError``); with the
    test off (``consistency_window = 0``) none is flagged."""
    rng = np.random.default_rng(8)
    run = simulate_vectors(rng, EPOCHS, process_noise=1e-7)
    start = drawn_start(rng, run)
    result = solve(run, *start)
    assert result.report.converged and not result.report.consistent
    flagged = ~result.valid
    assert flagged.mean() > 0.5, flagged.mean()
    assert all(r.startswith("inconsistent: the residuals") for r in result.reason[flagged])
    assert set(result.error[flagged]) == {ModelMismatchError}
    assert solve(run, *start, consistency_window=0).valid.all()
