"""The reception threshold in the SNR model: log Phi, the truncated likelihood and its
information (formulations/snr_truncation.py), and the ``"nlp_truncated"`` solver.

Geometry from ``tests/test_snr_solvers.py`` (two antennas tilted 50.77 deg,
Liu et al. 2023 eq. 64); for the threshold to matter the isotropic powers are shifted
so that the true SNRs lie within a few dB of the 6 dB threshold (Liu et al. 2023
sec. 5.1), where a 1 dB noise decides whether a message is received.
"""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
import scipy.special
from scipy.spatial.transform import Rotation
from scipy.stats import truncnorm

from attopt.formulations.conventions import attitude_error
from attopt.formulations.gain_patterns import LIU2023_HELIX
from attopt.formulations.snr_model import cramer_rao_bound
from attopt.formulations.snr_problem import RECEPTION_THRESHOLD_DB, SnrEpoch
from attopt.formulations.snr_truncation import (
    inverse_mills_ratio,
    log_normal_cdf,
    truncated_fisher_information,
    truncated_information_factor,
    truncated_nll,
)
from attopt.formulations.symbolic import CASADI
from attopt.solvers.nlpsol import NlpOptions
from attopt.solvers.snr.fit import fit_at, model_at
from attopt.solvers.snr.nlp import nlp_solver, parameter_vector
from attopt.solvers.snr.padding import pad_epoch
from tests.test_snr_solvers import BORESIGHTS, BUDGET, SOLVERS, TRUTH, _geometry, _snapshot

TAU = RECEPTION_THRESHOLD_DB


def _casadi_elementwise(build, *arrays):
    """Evaluate the CasADi expression ``build(*symbols)`` elementwise on numpy ``arrays``."""
    symbols = [ca.SX.sym(f"a{i}") for i in range(len(arrays))]
    function = ca.Function("f", symbols, [build(*symbols)])
    stacked = [np.broadcast_to(a, np.shape(arrays[0])).reshape(1, -1) for a in arrays]
    return np.asarray(function.map(stacked[0].size)(*stacked)).reshape(np.shape(arrays[0]))


def _near_threshold_epoch(rng, true_snr, per_antenna=(20, 20), **kwargs):
    """An epoch whose true SNRs are ``true_snr`` (isotropic powers shifted), with its truth data.

    Returns ``(make, jacobian)``: ``make(snr)`` builds the epoch with measured ``snr``.
    """
    los, antenna, ranges, snr, jac = _geometry(rng, TRUTH, per_antenna, inner=0.5)
    p0 = BUDGET.isotropic_power_dbw(ranges) + (true_snr - snr)

    def make(measured):
        return SnrEpoch(
            snr_db=measured,
            los_orbit=los,
            antenna=antenna,
            boresights_body=BORESIGHTS,
            p0_dbw=p0,
            noise_dbw=BUDGET.noise_power_dbw,
            pattern=LIU2023_HELIX,
            **kwargs,
        )

    return make, jac


def _received(rng, true_snr, sigma, tau):
    """One received measurement per row: draw until ``y >= tau`` (rejection sampling)."""
    sigma = np.broadcast_to(sigma, true_snr.shape)
    y = true_snr + sigma * rng.standard_normal(true_snr.shape)
    while np.any(low := y < tau):
        y[low] = true_snr[low] + sigma[low] * rng.standard_normal(int(low.sum()))
    return y


# --- log Phi ------------------------------------------------------------------------------


def test_log_normal_cdf_matches_scipy_log_ndtr_on_both_backends():
    # The grid, the branch points x = +-sqrt 2 and Cephes' switch at |x| = 8 sqrt 2.
    edges = np.array([-1e-9, 0.0, 1e-9])
    branch_points = (-math.sqrt(2), math.sqrt(2), -8 * math.sqrt(2), 8 * math.sqrt(2))
    x = np.concatenate([np.linspace(-30.0, 30.0, 6001), *(c + edges for c in branch_points)])
    expected = scipy.special.log_ndtr(x)
    numpy_path = log_normal_cdf(x)
    casadi_path = _casadi_elementwise(log_normal_cdf, x)
    # log Phi(30) = -4.9e-198 and log Phi(-30) = -454.3: relative accuracy on the whole range.
    np.testing.assert_allclose(numpy_path, expected, rtol=1e-12, atol=0)
    np.testing.assert_allclose(casadi_path, numpy_path, rtol=1e-12, atol=0)


def test_log_normal_cdf_derivatives_are_finite_and_match_the_inverse_mills_ratio():
    x = np.linspace(-30.0, 30.0, 601)
    s = ca.SX.sym("x")
    first, second = ca.Function(
        "d", [s], [ca.gradient(log_normal_cdf(s), s), ca.hessian(log_normal_cdf(s), s)[0]]
    ).map(x.size)(x.reshape(1, -1))
    first, second = np.asarray(first).ravel(), np.asarray(second).ravel()
    mills = np.exp(-0.5 * x**2 - 0.5 * math.log(2 * math.pi) - scipy.special.log_ndtr(x))
    np.testing.assert_allclose(first, mills, rtol=1e-11, atol=0)
    # d lambda / dx = -lambda (x + lambda); evaluated where it does not cancel badly.
    moderate = x > -5.0
    expected = -mills * (x + mills)
    np.testing.assert_allclose(second[moderate], expected[moderate], rtol=1e-8, atol=1e-300)
    assert np.isfinite(second).all()


# --- the truncated likelihood and its information ------------------------------------------


def test_truncated_nll_is_the_truncated_normal_density():
    rng = np.random.default_rng(1)
    f = rng.uniform(2.0, 12.0, 50)
    sigma = rng.uniform(0.5, 2.0, 50)
    y = TAU + rng.exponential(1.5, 50)
    density = truncnorm((TAU - f) / sigma, np.inf, loc=f, scale=sigma).logpdf(y)
    constant = np.log(sigma * math.sqrt(2 * math.pi))
    np.testing.assert_allclose(truncated_nll(y, f, sigma, TAU) + constant, -density, rtol=1e-12)


def test_truncated_nll_score_vanishes_at_the_truncated_mean():
    # The sign of the log Phi term: E[d l / d f] = 0 under the truncated normal.
    f = np.array([3.0, 5.5, 6.0, 7.0, 9.0, 15.0])
    sigma = np.array([1.0, 0.7, 1.0, 1.3, 1.0, 2.0])
    mean = truncnorm((TAU - f) / sigma, np.inf, loc=f, scale=sigma).mean()
    y, fs = ca.SX.sym("y"), ca.SX.sym("f")
    for k in range(f.size):
        score = ca.Function(
            "score", [y, fs], [ca.gradient(truncated_nll(y, fs, float(sigma[k]), TAU), fs)]
        )
        assert abs(float(score(mean[k], f[k]))) < 1e-10


def test_truncated_information_factor_is_the_truncated_normal_variance():
    x = np.linspace(-10.0, 30.0, 161)  # x = (f - tau) / sigma
    sigma = 1.7
    factor = truncated_information_factor(TAU + sigma * x, sigma, TAU)
    expected = [truncnorm(-v, np.inf).var() for v in x]
    # 1 - x lambda - lambda^2 cancels for x << 0 (about 1e-10 relative at x = -10).
    np.testing.assert_allclose(factor, expected, rtol=1e-9)
    casadi_path = _casadi_elementwise(
        lambda f: truncated_information_factor(f, sigma, TAU, CASADI), TAU + sigma * x
    )
    # Same cancellation, so the two back-ends (erf of CasADi and scipy) agree to ~1e-12 only.
    np.testing.assert_allclose(casadi_path, factor, rtol=1e-10)


def test_truncated_information_is_the_variance_of_the_score():
    # Monte Carlo of the score (y - f) / sigma^2 - lambda / sigma over received messages.
    rng = np.random.default_rng(2)
    f, sigma = 6.3, 1.0
    y = _received(rng, np.full(200_000, f), sigma, TAU)
    # d log p / d f by CasADi AD of truncated_nll, evaluated at every received y.
    ys, fs = ca.SX.sym("y"), ca.SX.sym("f")
    score = ca.Function("score", [ys, fs], [-ca.gradient(truncated_nll(ys, fs, sigma, TAU), fs)])
    scores = np.asarray(score.map(y.size)(y.reshape(1, -1), f)).ravel()
    factor = float(truncated_information_factor(f, sigma, TAU))
    assert scores.mean() == pytest.approx(0.0, abs=4 * scores.std() / math.sqrt(y.size))
    assert scores.var() * sigma**2 == pytest.approx(factor, rel=0.01)


# --- the NLP of the truncated likelihood ----------------------------------------------------


def test_truncated_nlp_objective_gradient_matches_finite_differences():
    rng = np.random.default_rng(3)
    # True SNRs from 4.5 to 12 dB: the three branches of log Phi are all in use.
    true_snr = rng.uniform(4.5, 12.0, 22)
    sigma = rng.uniform(0.6, 1.5, 22)
    make, _ = _near_threshold_epoch(rng, true_snr, (11, 11), sigma_db=sigma)
    problem = make(_received(rng, true_snr, sigma, TAU))
    start = Rotation.from_rotvec([0.02, -0.01, 0.03]) * TRUTH
    a_ref = start.as_matrix()
    padded = pad_epoch(problem, a_ref)
    assert padded.size == 32  # 10 padding rows, which must add nothing
    solver = nlp_solver(LIU2023_HELIX, padded.size, NlpOptions(), "truncated_ml")
    p = parameter_vector(padded, a_ref, problem.threshold_db)
    loss, gradient = solver.get_function("nlp_grad_f")(np.zeros(3), p)
    predicted, _ = model_at(problem, start)
    expected = np.sum(truncated_nll(problem.snr_db, predicted, problem.sigma_db, TAU))
    assert float(loss) == pytest.approx(expected, rel=1e-12)
    assert fit_at(problem, start, "truncated_ml").loss == pytest.approx(expected, rel=1e-12)

    def numpy_loss(v):
        return fit_at(problem, Rotation.from_mrp(v / 4.0) * start, "truncated_ml").loss

    h = 1e-6
    central = [(numpy_loss(h * e) - numpy_loss(-h * e)) / (2 * h) for e in np.eye(3)]
    np.testing.assert_allclose(np.asarray(gradient).ravel(), central, rtol=1e-6, atol=1e-6)
    assert np.linalg.norm(central) > 1.0  # away from the optimum: a non-trivial gradient


def test_truncated_nlp_equals_the_nlp_when_nothing_is_cut():
    rng = np.random.default_rng(4)
    true_snr = rng.uniform(4.5, 12.0, 30)
    make, _ = _near_threshold_epoch(rng, true_snr, (15, 15), threshold_db=-100.0)
    problem = make(true_snr + rng.standard_normal(30))
    nlp = SOLVERS["nlp"].solve(_snapshot(problem), prior=TRUTH)
    truncated = SOLVERS["nlp_truncated"].solve(_snapshot(problem), prior=TRUTH)
    assert np.linalg.norm(attitude_error(truncated.attitude, nlp.attitude)) < 1e-8
    assert truncated.loss == pytest.approx(nlp.loss, rel=1e-12)
    np.testing.assert_allclose(truncated.covariance, nlp.covariance, rtol=1e-9)
    assert np.linalg.norm(attitude_error(nlp.attitude, TRUTH)) > 1e-3  # noise moved it


@pytest.mark.slow
def test_monte_carlo_truncated_ml_is_unbiased_and_reaches_the_truncated_bound():
    # 40 messages, true SNRs 4.5-8 dB: about a third of the draws fall below the 6 dB
    # threshold and are redrawn, so every received SNR is a truncated normal.
    rng = np.random.default_rng(10)
    true_snr = rng.uniform(4.5, 8.0, 40)
    make, jac = _near_threshold_epoch(rng, true_snr)
    crb = cramer_rao_bound(truncated_fisher_information(jac, true_snr, 1.0, TAU))
    trials = 300
    names = ("nlp", "nlp_truncated")
    errors = {name: np.empty((trials, 3)) for name in names}
    reported = np.zeros((3, 3))
    for k in range(trials):
        problem = make(_received(rng, true_snr, 1.0, TAU))
        for name in names:
            solution = SOLVERS[name].solve(_snapshot(problem), prior=TRUTH)
            errors[name][k] = attitude_error(solution.attitude, TRUTH)
            if name == "nlp_truncated":
                reported += solution.covariance / trials
    scatter = {name: np.cov(e.T) for name, e in errors.items()}
    bias_in_standard_errors = {
        name: errors[name].mean(axis=0) / np.sqrt(np.diag(scatter[name]) / trials) for name in names
    }
    ratio = {name: np.trace(s) / np.trace(crb) for name, s in scatter.items()}
    mse = {name: np.mean(np.sum(e**2, axis=1)) / np.trace(crb) for name, e in errors.items()}
    explained = np.trace(reported) / np.trace(scatter["nlp_truncated"])
    print("bias / standard error:", {n: np.round(b, 2) for n, b in bias_in_standard_errors.items()})
    print("tr(scatter) / tr(truncated CRB):", {n: round(float(r), 3) for n, r in ratio.items()})
    print("mean |e|^2 / tr(truncated CRB):", {n: round(float(r), 3) for n, r in mse.items()})
    print("nlp_truncated tr(reported) / tr(scatter):", round(float(explained), 3))
    # Least squares (eq. 19) is biased by the selection; the truncated ML is not.
    assert np.max(np.abs(bias_in_standard_errors["nlp"])) > 4.0
    assert np.all(np.abs(bias_in_standard_errors["nlp_truncated"]) < 3.0)
    # 300 trials: the standard error of tr(scatter) is ~5%; 15% is three of them.
    assert ratio["nlp_truncated"] == pytest.approx(1.0, abs=0.15)
    assert explained == pytest.approx(1.0, abs=0.15)


def test_without_a_threshold_the_truncated_model_is_the_gaussian_one():
    """``tau = -inf`` (no reception threshold, as at a GEO ground station): no NaN, the
    limits exactly: ``log Phi = 0``, ``lambda = 0``, information factor 1."""
    f = np.array([-20.0, 0.0, 10.0, 60.0])
    assert np.array_equal(truncated_information_factor(f, 1.0, -np.inf), np.ones(4))
    assert np.array_equal(truncated_nll(f + 0.5, f, 1.0, -np.inf), np.full(4, 0.125))
    assert inverse_mills_ratio(np.array([np.inf]))[0] == 0.0
    assert log_normal_cdf(np.array([np.inf]))[0] == 0.0
