"""The RTS smoother over Yang et al. 2014's EKF (``rts_yang2014``) and the EKF's posterior bound
(``solvers/doa/eks.py``): the one backward pass (``solvers/filters/rts.py``) against the
textbook recursion for the EKF and the gyro MEKF, covariance order, errors, Monte Carlo
NEES, and the bound against the EKF run at the truth."""

from __future__ import annotations

import casadi as ca
import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from attopt.formulations.conventions import attitude_error
from attopt.solvers.doa import DoaRts
from attopt.solvers.doa.ekf import PRIOR_ORDER
from attopt.solvers.doa.eks import posterior_bound_ekf
from attopt.solvers.filters import Mekf, Rts
from attopt.solvers.filters.common import apply_error, error_vector
from attopt.solvers.filters.rts import composed_error
from attopt.solvers.results import Track
from tests.filter_passes import GYRO, gyro_pass, prior_covariance, simulate_pass
from tests.filter_passes import drawn_prior as drawn_gyro_prior
from tests.test_doa_ekf import (
    VectorPass,
    drawn_prior,
    rate_prior,
    relative_covariance_difference,
    run_fast,
    simulate_vectors,
)

PROCESS_NOISE = 1e-7
"""``Q = q E_6`` per step, large enough that smoothing gains: ``sqrt(q)`` = 3e-4 rad
of attitude noise per step against 5e-3 rad vectors."""
PRIOR = np.diag([1e-6] * 3 + [1e-4] * 3)
RUNS = 20
EPOCHS = 400


def state_errors(result: Track, run: VectorPass) -> np.ndarray:
    """``(N, 6)`` errors ``[omega_true - omega, delta]``, ``A_true = C(delta) A``."""
    return np.concatenate(
        [run.rate - result.rate, error_vector(run.truth, result.attitude())], axis=1
    )


def smooth(run: VectorPass, filtered: Track) -> Track:
    """``rts_yang2014`` over the EKF track ``filtered`` of ``run``."""
    return DoaRts().solve(run.pass_(), initial=filtered)


def nees(errors: np.ndarray, covariance: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...ij,...j->...", errors, np.linalg.inv(covariance), errors)


def textbook_rts(
    after: Rotation,
    before: Rotation,
    rest: np.ndarray,
    rest_before: np.ndarray,
    covariance: np.ndarray,
    predicted_covariance: np.ndarray,
    transition: np.ndarray,
    attitude: slice,
) -> tuple[Rotation, np.ndarray, np.ndarray]:
    """The RTS equations one epoch at a time with scipy rotations: ``C_k = P_k Phi_k^T
    (P^-_{k+1})^-1``, ``x_k = C_k [x^s_{k+1} (-) x^-_{k+1}]``, ``P^s_k = P_k + C_k
    (P^s_{k+1} - P^-_{k+1}) C_k^T``, ``(-)`` the attitude error vector in the
    ``attitude`` block and the difference of the other components (``rest``)."""
    others = np.delete(np.arange(covariance.shape[1]), attitude)
    quaternion, rest, smoothed = after.as_quat(), rest.copy(), covariance.copy()
    for k in range(len(after) - 2, -1, -1):
        gain = covariance[k] @ transition[k].T @ np.linalg.inv(predicted_covariance[k + 1])
        difference = np.empty(covariance.shape[1])
        difference[attitude] = error_vector(Rotation.from_quat(quaternion[k + 1]), before[k + 1])
        difference[others] = rest[k + 1] - rest_before[k + 1]
        offset = gain @ difference
        quaternion[k] = apply_error(offset[attitude], after[k]).as_quat()
        rest[k] = rest[k] + offset[others]
        smoothed[k] = (
            covariance[k] + gain @ (smoothed[k + 1] - predicted_covariance[k + 1]) @ gain.T
        )
    return Rotation.from_quat(quaternion), rest, smoothed


def mekf_smoother() -> tuple[tuple, tuple, Rotation]:
    """``rts`` on a gyro MEKF pass (attitude block first) and the textbook recursion on
    the filter's history; also the filtered attitudes."""
    rng = np.random.default_rng(5)
    run = simulate_pass(rng, duration=60.0)
    prior = drawn_gyro_prior(rng, run, prior_covariance(np.radians(1.0)))
    pass_ = gyro_pass(run.gyro, run.t, run.measurements, prior, GYRO)
    filtered = Mekf().solve(pass_)
    smoothed = Rts().solve(pass_, initial=filtered)
    history = filtered.history
    after = Rotation.from_quat(history.filtered_attitude)
    expected = textbook_rts(
        after,
        Rotation.from_quat(history.predicted_attitude),
        history.filtered_vector,
        history.predicted_vector,
        history.filtered_covariance,
        history.predicted_covariance,
        history.transition[1:],
        slice(0, 3),
    )
    return (smoothed.attitude(), smoothed.bias, smoothed.state_covariance), expected, after


def ekf_smoother() -> tuple[tuple, tuple, Rotation]:
    """``rts_yang2014`` on an EKF pass (attitude block last) and the textbook recursion on
    the filter's history; also the filtered attitudes."""
    rng = np.random.default_rng(8)
    run = simulate_vectors(rng, 200, process_noise=PROCESS_NOISE)
    filtered = run_fast(run, drawn_prior(rng, run, PRIOR), PROCESS_NOISE)
    smoothed = smooth(run, filtered)
    history = filtered.history
    after = Rotation.from_matrix(history.filtered_attitude)
    expected = textbook_rts(
        after,
        Rotation.from_matrix(history.predicted_attitude),
        history.filtered_vector,
        history.predicted_vector,
        history.filtered_covariance,
        history.predicted_covariance,
        history.transition[1:],
        slice(3, 6),
    )
    return (smoothed.attitude(), smoothed.rate, smoothed.state_covariance), expected, after


@pytest.mark.parametrize("smoother", [mekf_smoother, ekf_smoother], ids=["mekf", "ekf"])
def test_rts_backward_is_the_textbook_recursion(smoother) -> None:
    """The one RTS smoother (``attopt.solvers.filters.rts.rts_smooth``) on the gyro MEKF's
    track (state ``[delta, delta_beta]``, ``rts``) and on the EKF's
    (``[delta_omega, delta]``, ``rts_yang2014``) equals the textbook recursion: one
    backward pass serves both filters."""
    (attitude, rest, covariance), expected, filtered = smoother()
    assert np.abs(attitude_error(attitude, expected[0])).max() < 1e-12
    np.testing.assert_allclose(rest, expected[1], rtol=0, atol=1e-15)
    assert relative_covariance_difference(covariance, expected[2]) < 1e-10
    assert np.abs(attitude_error(attitude[:-1], filtered[:-1])).max() > 1e-5


def test_composed_error_matches_scipy() -> None:
    """``composed_error(x, c)`` is ``error_vector(apply_error(x, apply_error(c, A)), A)``,
    also past 180 deg (the shadow MRPs)."""
    outer, inner = ca.SX.sym("outer", 3), ca.SX.sym("inner", 3)
    function = ca.Function("f", [outer, inner], [composed_error(outer, inner)])
    rng = np.random.default_rng(3)
    attitude = Rotation.random(random_state=rng)
    for scale in (1e-6, 1e-2, 1.0, 4.0, 10.0):
        x, c = rng.normal(size=(2, 50, 3)) * scale
        got = function.map(50)(x.T, c.T).full().T
        expected = error_vector(apply_error(x, apply_error(c, attitude)), attitude)
        np.testing.assert_allclose(got, expected, rtol=1e-12, atol=4e-15)


@pytest.fixture(scope="module")
def monte_carlo() -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """20 seeded passes of 400 epochs (100 s) with process noise ``Q``, filtered and
    smoothed; errors ``(runs, epochs, 6)`` and covariances ``(runs, epochs, 6, 6)``."""
    out: dict[str, tuple[list, list]] = {"filter": ([], []), "smoother": ([], [])}
    for seed in range(RUNS):
        rng = np.random.default_rng(100 + seed)
        run = simulate_vectors(rng, EPOCHS, process_noise=PROCESS_NOISE)
        filtered = run_fast(run, drawn_prior(rng, run, PRIOR), PROCESS_NOISE)
        for name, result in (("filter", filtered), ("smoother", smooth(run, filtered))):
            out[name][0].append(state_errors(result, run))
            out[name][1].append(result.state_covariance)
    return {name: (np.array(e), np.array(p)) for name, (e, p) in out.items()}


@pytest.mark.parametrize("name", ["filter", "smoother"])
def test_nees_is_consistent(monte_carlo, name: str) -> None:
    """At each epoch the NEES averaged over the M = 20 runs, ``chi2(6 M) / M`` for a
    consistent estimator: its time average must lie inside the two-sided 99%
    interval (a conservative test: the epochs are correlated, so the average
    spreads less than one epoch's), and so must at least 90% of the epochs
    (99% expected).  Returning the filter's covariance with the smoothed
    estimates, or the reverse, fails it."""
    errors, covariance = monte_carlo[name]
    averaged = nees(errors, covariance).mean(axis=0)
    low, high = chi2.ppf([0.005, 0.995], 6 * RUNS) / RUNS
    assert low < averaged.mean() < high, (averaged.mean(), low, high)
    inside = np.mean((averaged > low) & (averaged < high))
    assert inside > 0.9, inside


def test_smoothed_covariance_never_exceeds_the_filtered(monte_carlo) -> None:
    """``P^s_k <= P_k`` at every epoch (eigenvalues of the difference, scaled by the
    filter's standard deviations, >= -1e-12), well below it inside the pass, and
    equal at the last epoch."""
    _, filtered = monte_carlo["filter"]
    _, smoothed = monte_carlo["smoother"]
    scale = np.sqrt(np.diagonal(filtered, axis1=-2, axis2=-1))
    difference = (filtered - smoothed) / (scale[..., :, None] * scale[..., None, :])
    assert np.linalg.eigvalsh(difference).min() > -1e-12
    np.testing.assert_array_equal(filtered[:, -1], smoothed[:, -1])
    trace = np.trace(smoothed[:, 50:-50, 3:, 3:], axis1=-2, axis2=-1)
    assert np.all(trace < 0.8 * np.trace(filtered[:, 50:-50, 3:, 3:], axis1=-2, axis2=-1))


def test_smoothed_error_is_below_the_filters(monte_carlo) -> None:
    """RMS attitude and rate errors over runs and the epochs inside the pass."""
    rms = {
        name: np.sqrt(np.mean(errors[:, 50:-50] ** 2, axis=(0, 1)))
        for name, (errors, _) in monte_carlo.items()
    }
    assert np.all(rms["smoother"][3:] < 0.85 * rms["filter"][3:]), rms
    assert np.all(rms["smoother"][:3] < rms["filter"][:3]), rms


def test_smoother_keeps_the_last_epoch_and_moves_the_others() -> None:
    """The last smoothed estimate is the filter's; earlier ones differ."""
    rng = np.random.default_rng(8)
    run = simulate_vectors(rng, 200, process_noise=PROCESS_NOISE)
    filtered = run_fast(run, drawn_prior(rng, run, PRIOR), PROCESS_NOISE)
    smoothed = smooth(run, filtered)
    np.testing.assert_array_equal(smoothed.quaternion[-1], filtered.quaternion[-1])
    np.testing.assert_array_equal(smoothed.rate[-1], filtered.rate[-1])
    moved = np.linalg.norm(
        attitude_error(smoothed.attitude()[:-1], filtered.attitude()[:-1]), axis=1
    )
    assert np.all(moved > 0) and moved.max() > 1e-4


def bound(
    run: VectorPass, covariance: np.ndarray, process_noise: float
) -> tuple[np.ndarray, np.ndarray]:
    """The posterior bounds of ``run``'s vectors with the prior ``covariance`` (of
    ``[delta_omega, delta]``)."""
    prior = rate_prior(run.truth[0], run.rate[0], covariance)
    return posterior_bound_ekf(run.pass_(prior), run.truth, run.rate, process_noise)


def test_bound_prior_order_is_the_filters() -> None:
    """The bound's first filtered covariance without a measurement is the prior's,
    permuted to ``[delta_omega, delta]``."""
    run = simulate_vectors(np.random.default_rng(10), 20)
    run.body[0] = np.nan
    covariance = np.diag([1e-6, 2e-6, 3e-6, 1e-4, 2e-4, 3e-4])
    filtered, _ = bound(run, covariance, PROCESS_NOISE)
    np.testing.assert_array_equal(filtered[0], covariance)
    assert np.array_equal(PRIOR_ORDER[PRIOR_ORDER], np.arange(6))


def test_filter_bound_is_the_ekf_covariance_at_the_truth() -> None:
    """Noise-free vectors of a truth that follows the step map, prior at the truth:
    the EKF stays on the truth, so its covariances are the recursion the bound
    runs (Phi and H at the truth), filter and smoother alike."""
    rng = np.random.default_rng(6)
    run = simulate_vectors(rng, 500, noisy=False)
    result = run_fast(run, rate_prior(run.truth[0], run.rate[0], PRIOR), PROCESS_NOISE)
    assert np.abs(attitude_error(result.attitude(), run.truth)).max() < 1e-12
    filter_bound, smoother_bound = bound(run, PRIOR, PROCESS_NOISE)
    assert relative_covariance_difference(filter_bound, result.state_covariance) < 1e-9
    smoothed = smooth(run, result).state_covariance
    assert relative_covariance_difference(smoother_bound, smoothed) < 1e-9


def test_smoother_bound_is_below_the_filter_bound() -> None:
    """On a noisy pass's geometry: smoother bound <= filter bound at every epoch,
    clearly below inside the pass, equal at the end."""
    rng = np.random.default_rng(9)
    run = simulate_vectors(rng, 400, process_noise=PROCESS_NOISE)
    filter_bound, smoother_bound = bound(run, PRIOR, PROCESS_NOISE)
    scale = np.sqrt(np.diagonal(filter_bound, axis1=-2, axis2=-1))
    difference = (filter_bound - smoother_bound) / (scale[..., :, None] * scale[..., None, :])
    assert np.linalg.eigvalsh(difference).min() > -1e-12
    np.testing.assert_array_equal(filter_bound[-1], smoother_bound[-1])
    inside = slice(50, -50)
    ratio = np.trace(smoother_bound[inside, 3:, 3:], axis1=-2, axis2=-1) / np.trace(
        filter_bound[inside, 3:, 3:], axis1=-2, axis2=-1
    )
    assert ratio.max() < 0.8
