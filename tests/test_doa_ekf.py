"""The EKF of Yang et al. 2014 (``solvers/doa/ekf.py``, registry ``ekf_yang2014``): step model,
transition matrix, convergence, the CasADi pass against the Python loop, the update against
the textbook Joseph form, gating and the lost-track monitor."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from attopt.experiments.doa_ground.parameters import DoaScenario, FilterPrior, RigidBodyTruth
from attopt.experiments.doa_ground.scenario import build_geometry
from attopt.formulations.attitude_measurement import VectorMeasurement
from attopt.formulations.conventions import attitude_error, attitude_from_euler321
from attopt.formulations.errors import ConvergenceError
from attopt.formulations.passes import Pass, Prior, RigidBody, epoch_snapshots
from attopt.formulations.rigid_body import YANG2014_INERTIA
from attopt.solvers.doa import DoaEkf
from attopt.solvers.doa.ekf import (
    MAX_STEP_ANGLE,
    PRIOR_ORDER,
    step_function,
    update_function,
)
from attopt.solvers.doa.vector_slots import vector_arrays
from attopt.solvers.filters.common import FilterOptions, apply_error
from attopt.solvers.results import Track

UNCHECKED = {"start_hypotheses": "none", "robust_check": False}
"""The EKF alone, without the check against its other runs
(:mod:`attopt.solvers.start_hypotheses`)."""
PASS_S = 1200.0
STEP_S = 1.0
"""Coarser than the paper's 250 ms to keep the test cheap; the model is the same."""
SCENARIO = DoaScenario(duration_s=PASS_S, step_s=STEP_S)
WHEEL_MOMENTUM = RigidBodyTruth().wheel_momentum
PRIOR = FilterPrior()


def _step(omega: np.ndarray, attitude: np.ndarray, turn: np.ndarray):
    function = step_function(STEP_S, tuple(YANG2014_INERTIA.ravel()))
    return [x.full() for x in function(omega, attitude, WHEEL_MOMENTUM, turn)]


def test_step_reproduces_the_rigid_body_truth() -> None:
    """One filter step from the true state lands on the scenario's solve_ivp truth (eqs. 23-24)."""
    geometry = build_geometry(SCENARIO)
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
    geometry = build_geometry(SCENARIO)
    reference = geometry.line_of_sight_km / np.linalg.norm(
        geometry.line_of_sight_km, axis=-1, keepdims=True
    )
    measurements = []
    for k in range(geometry.t.size):
        visible = geometry.visible[k]
        body = geometry.truth[k].apply(reference[k, visible])
        measurements.append(VectorMeasurement(body, reference[k, visible], np.radians(0.3)))
    prior = rate_prior(
        attitude_from_euler321(*np.radians(PRIOR.euler_deg)),
        np.radians(PRIOR.rate_deg_s),
        np.diag(np.radians([0.5] * 3 + [60.0] * 3) ** 2),
    )
    dynamics = RigidBody(YANG2014_INERTIA, geometry.eci_to_orbit, WHEEL_MOMENTUM)
    pass_ = Pass(geometry.t, epoch_snapshots(measurements, geometry.t), None, prior, dynamics)
    result = DoaEkf(compiled=False, **UNCHECKED).solve(pass_)
    error = np.degrees(np.linalg.norm(attitude_error(result.attitude(), geometry.truth), axis=1))
    rate_error = np.degrees(np.linalg.norm(result.rate - geometry.rate, axis=1))
    assert np.degrees(np.linalg.norm(attitude_error(prior.attitude, geometry.truth[0]))) > 50.0
    assert result.valid.all() and result.state == ("rate", "attitude")
    assert error[-1] < 1e-3
    assert rate_error[-1] < 1e-4
    assert result.diagnostics["rows"][-1] == 3 * geometry.visible[-1].sum()


# --- synthetic passes of the filter's own model ---------------------------------------------------

DT = 0.25
RATE0 = np.array([0.02, -0.015, 0.01])
"""Initial true rate (rad/s): the dynamics (Euler's equation with the wheel) matter."""
REFERENCES = np.array([[0.3, 0.1, 0.95], [-0.5, 0.4, 0.77], [0.1, -0.6, 0.8]])
REFERENCES = REFERENCES / np.linalg.norm(REFERENCES, axis=1, keepdims=True)
SIGMA = 0.005
"""Vector noise per axis (rad)."""
ORBIT_TURN = Rotation.from_rotvec([0.0, -1.1e-3 * DT, 0.0])


def rate_prior(attitude: Rotation, rate: np.ndarray, covariance: np.ndarray) -> Prior:
    """The :class:`Prior` of an estimate whose error covariance is given in the filter's
    order ``[delta_omega, delta]`` (the prior's is ``[attitude, rate]``)."""
    return Prior(attitude, covariance[np.ix_(PRIOR_ORDER, PRIOR_ORDER)], rate=rate)


@dataclass
class VectorPass:
    """Truth from the filter's own step map (plus process noise), vectors with NaN rows."""

    truth: Rotation
    rate: np.ndarray
    body: np.ndarray
    reference: np.ndarray
    sigma: np.ndarray
    dynamics: RigidBody

    @property
    def t(self) -> np.ndarray:
        return DT * np.arange(len(self.truth))

    @property
    def arrays(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self.body, self.reference, self.sigma

    def pass_(self, prior: Prior | None = None) -> Pass:
        """The pass of the vectors (one ``VectorMeasurement`` per epoch with any) with the
        dynamics and ``prior``."""
        vectors = Pass.from_vectors(self.t, *self.arrays)
        return Pass(self.t, vectors.snapshots, None, prior, self.dynamics)


def simulate_vectors(
    rng: np.random.Generator,
    n: int,
    process_noise: float = 0.0,
    noisy: bool = True,
    presence: float = 0.6,
) -> VectorPass:
    """``n`` epochs ``DT`` apart; each reference vector seen with probability
    ``presence`` per epoch; truth with ``Q = process_noise E_6`` per step."""
    step = step_function(DT, tuple(YANG2014_INERTIA.ravel()))
    frames = [Rotation.identity()]
    for _ in range(n - 1):
        frames.append(ORBIT_TURN * frames[-1])
    dynamics = RigidBody(YANG2014_INERTIA, Rotation.concatenate(frames), WHEEL_MOMENTUM)
    turns = dynamics.orbit_turns.as_matrix()
    rate, attitude = RATE0.copy(), Rotation.random(random_state=rng)
    rates, attitudes = [], []
    for k in range(n):
        rates.append(rate)
        attitudes.append(attitude)
        if k == n - 1:
            break
        w, a, _ = step(rate, attitude.as_matrix(), WHEEL_MOMENTUM, turns[k])
        noise = rng.normal(0.0, np.sqrt(process_noise), 6)
        rate = w.full().ravel() + noise[:3]
        attitude = apply_error(noise[3:], Rotation.from_matrix(a.full()))
    truth = Rotation.concatenate(attitudes)
    reference = np.broadcast_to(REFERENCES, (n, *REFERENCES.shape)).copy()
    body = np.einsum("nij,nsj->nsi", truth.as_matrix(), reference)
    if noisy:
        body += SIGMA * rng.standard_normal(body.shape)
        body /= np.linalg.norm(body, axis=-1, keepdims=True)
    body[rng.random(body.shape[:2]) > presence] = np.nan
    sigma = np.full(body.shape[:2], SIGMA)
    return VectorPass(truth, np.array(rates), body, reference, sigma, dynamics)


def drawn_prior(rng: np.random.Generator, run: VectorPass, covariance: np.ndarray) -> Prior:
    """Prior whose error ``[delta_omega, delta]`` (``A_true = C(delta) A_est``) is drawn
    from ``covariance`` (in that order)."""
    error = rng.multivariate_normal(np.zeros(6), covariance)
    return rate_prior(apply_error(-error[3:], run.truth[0]), run.rate[0] - error[:3], covariance)


def run_fast(run: VectorPass, prior: Prior, process_noise: float) -> Track:
    """The EKF's compiled pass (unit vectors, no gate), from the prior's start alone."""
    return DoaEkf(process_noise=process_noise, **UNCHECKED).solve(run.pass_(prior))


FAST = {"gate_probability": 1.0, "max_attitude_sigma": np.inf}
"""The EKF's default fault handling (no gate: the compiled path)."""


def run_loop(run: VectorPass, prior: Prior, process_noise: float, **faults) -> Track:
    """The EKF through the sequential loop (Python), with ``faults`` as fault handling."""
    options = FilterOptions(**{**FAST, **faults})
    estimator = DoaEkf(process_noise=process_noise, filter=options, compiled=False, **UNCHECKED)
    return estimator.solve(run.pass_(prior))


def history_rotations(track: Track) -> tuple[Rotation, Rotation]:
    """Filtered and predicted attitudes of an EKF track's history (matrices)."""
    history = track.history
    return (
        Rotation.from_matrix(history.filtered_attitude),
        Rotation.from_matrix(history.predicted_attitude),
    )


def relative_covariance_difference(p: np.ndarray, reference: np.ndarray) -> float:
    """Largest ``|p_ij - r_ij| / sqrt(r_ii r_jj)``."""
    scale = np.sqrt(np.diagonal(reference, axis1=-2, axis2=-1))
    return float(np.max(np.abs(p - reference) / (scale[..., :, None] * scale[..., None, :])))


def test_fast_path_equals_the_generic_loop_on_a_noisy_pass() -> None:
    """The compiled pass (epochs in CasADi, fixed slots) against the sequential loop with
    one ``VectorMeasurement`` per epoch (Python, rows left out), from a 40-deg
    initial error (large geodesic innovations), NaN vectors and empty epochs:
    attitudes within 1e-9 rad, rates, transition matrices and covariances
    within 1e-8 of their scale, the predicted states alike.  (Rounding
    differences of the innovations, 1e-15, grow to about 2e-10 rad/s in the
    rates of the first epochs, whose covariance has a condition number of 2e4.)"""
    rng = np.random.default_rng(7)
    run = simulate_vectors(rng, 240, process_noise=1e-9)
    covariance = np.diag([1e-4] * 3 + [np.radians(40.0) ** 2] * 3)
    prior = rate_prior(
        apply_error(np.radians([25.0, -25.0, 20.0]), run.truth[0]), run.rate[0], covariance
    )
    fast, loop = run_fast(run, prior, 1e-9), run_loop(run, prior, 1e-9)
    start = np.degrees(np.linalg.norm(attitude_error(prior.attitude, run.truth[0])))
    end = np.degrees(np.linalg.norm(attitude_error(fast.attitude()[-1], run.truth[-1])))
    assert start > 35.0 and end < 1.0
    rows = fast.diagnostics["rows"]
    assert (rows == 0).any() and (rows == 9).any()
    for name in ("rows", "n_used", "n_gated", "recoveries", "nis_dof"):
        np.testing.assert_array_equal(fast.diagnostics[name], loop.diagnostics[name])
    # the normalised innovations of both, and so the epochs the consistency test flags
    # while the filter converges from 40 deg (its linearised innovations far off theirs)
    np.testing.assert_allclose(
        fast.diagnostics["nis"], loop.diagnostics["nis"], rtol=1e-8, atol=1e-9
    )
    np.testing.assert_array_equal(fast.valid, loop.valid)
    assert not fast.valid[1] and fast.valid[-100:].all()
    assert all(reason.startswith("inconsistent") for reason in fast.reason[~fast.valid])
    for got, expected in zip(history_rotations(fast), history_rotations(loop), strict=True):
        assert np.radians(np.abs(attitude_error(got, expected)).max()) < 1e-9
    for got, expected in (  # the history's: the track's are NaN where flagged
        (fast.history.filtered_vector, loop.history.filtered_vector),
        (fast.history.predicted_vector, loop.history.predicted_vector),
        (fast.history.transition[1:], loop.history.transition[1:]),
    ):
        np.testing.assert_allclose(got, expected, atol=1e-8 * np.abs(expected).max())
    for got, expected in (
        (fast.history.filtered_covariance, loop.history.filtered_covariance),
        (fast.history.predicted_covariance, loop.history.predicted_covariance),
    ):
        assert relative_covariance_difference(got, expected) < 1e-8


def test_compiled_pass_and_loop_agree_to_rounding() -> None:
    """Noisy vectors with a prior within a few sigma (the linear regime): the compiled
    pass and the sequential loop give the same track to 1e-12 (attitudes in rad,
    rates and covariances relative to their scale), the same diagnostics, validity
    and history."""
    rng = np.random.default_rng(12)
    run = simulate_vectors(rng, 200, process_noise=1e-9)
    prior = drawn_prior(rng, run, np.diag([1e-8] * 3 + [1e-5] * 3))
    fast, loop = run_fast(run, prior, 1e-9), run_loop(run, prior, 1e-9)
    np.testing.assert_array_equal(fast.valid, loop.valid)
    np.testing.assert_array_equal(fast.reason, loop.reason)
    for name in ("rows", "n_used", "n_gated", "recoveries"):
        np.testing.assert_array_equal(fast.diagnostics[name], loop.diagnostics[name])
    np.testing.assert_allclose(
        fast.diagnostics["log_likelihood"], loop.diagnostics["log_likelihood"], rtol=1e-10
    )
    assert np.isnan(fast.diagnostics["log_likelihood"][fast.diagnostics["rows"] == 0]).all()
    assert np.abs(attitude_error(fast.attitude(), loop.attitude())).max() < 1e-12
    np.testing.assert_allclose(fast.rate, loop.rate, rtol=0, atol=1e-12 * np.abs(loop.rate).max())
    assert relative_covariance_difference(fast.state_covariance, loop.state_covariance) < 1e-12
    assert (
        relative_covariance_difference(
            fast.history.predicted_covariance, loop.history.predicted_covariance
        )
        < 1e-12
    )
    np.testing.assert_allclose(fast.history.transition, loop.history.transition, atol=1e-12)


def test_huber_update_down_weights_an_outlier_alike_on_both_paths() -> None:
    """``huber_threshold``: a vector turned 20 deg (an outlier, 70 sigma) is down-weighted on
    both paths (``n_downweighted``), the two agree as without it (attitudes within 1e-9 rad,
    log-likelihoods to 1e-8), and the outlier moves the estimate far less than the
    Gaussian update lets it (its error after the outlier epoch at most a fifth)."""
    rng = np.random.default_rng(21)
    run = simulate_vectors(rng, 120, process_noise=1e-9, presence=1.0)
    run.body[60, 0] = Rotation.from_rotvec([0.0, 0.0, np.radians(20.0)]).apply(run.body[60, 0])
    prior = drawn_prior(rng, run, np.diag([1e-8] * 3 + [1e-5] * 3))
    huber = {"huber_threshold": 3.0}
    fast = DoaEkf(process_noise=1e-9, filter=FilterOptions(**{**FAST, **huber}), **UNCHECKED).solve(
        run.pass_(prior)
    )
    loop = run_loop(run, prior, 1e-9, **huber)
    plain = run_fast(run, prior, 1e-9)
    for track in (fast, loop):
        assert track.diagnostics["n_downweighted"][60] == 1
        assert track.diagnostics["n_downweighted"].sum() <= 3
    assert plain.diagnostics["n_downweighted"].sum() == 0
    assert (
        np.abs(attitude_error(history_rotations(fast)[0], history_rotations(loop)[0])).max() < 1e-9
    )
    np.testing.assert_allclose(
        fast.diagnostics["log_likelihood"], loop.diagnostics["log_likelihood"], rtol=1e-8
    )
    robust, gaussian = (
        np.linalg.norm(attitude_error(history_rotations(t)[0][60], run.truth[60]))
        for t in (fast, plain)
    )
    assert robust < 0.2 * gaussian


def test_lost_track_is_flagged_with_the_gate_on() -> None:
    """A prior 40 deg off that claims 0.1 deg, precise vectors, the gate on: every vector
    is gated, so from the ``max_rejected_epochs``-th epoch on the epochs are flagged
    "lost track" and the covariance is inflated to re-acquire (``recoveries``); the
    filter then converges and is valid again.  Without the gate (the default, as in
    the paper) the monitor never fires."""
    rng = np.random.default_rng(13)
    run = simulate_vectors(rng, 240, process_noise=1e-9, presence=1.0)
    covariance = np.diag([1e-8] * 3 + [np.radians(0.1) ** 2] * 3)
    prior = rate_prior(
        apply_error(np.radians([40.0, 0.0, 0.0]), run.truth[0]), run.rate[0], covariance
    )
    gated = run_loop(run, prior, 1e-9, gate_probability=0.9999)
    lost = np.char.startswith(gated.reason.astype(str), "lost track")
    first = FilterOptions().max_rejected_epochs - 1
    assert lost[first] and not lost[:first].any()
    assert gated.diagnostics["n_gated"][: first + 1].min() == 3
    assert gated.diagnostics["recoveries"].sum() >= 1
    assert gated.valid[-40:].all()
    error = attitude_error(gated.attitude()[-40:], run.truth[-40:])
    assert np.degrees(np.abs(error).max()) < 0.5
    default = run_fast(run, prior, 1e-9)
    assert (
        default.diagnostics["n_gated"].sum() == 0 and default.diagnostics["recoveries"].sum() == 0
    )
    # ... but its consistency test flags the epochs whose innovations contradict the
    # 0.1 deg it claims, until they fit again
    flagged = ~default.valid
    assert flagged[:5].all() and default.valid[-40:].all()
    assert all(reason.startswith("inconsistent") for reason in default.reason[flagged])


def test_update_is_the_textbook_joseph_update() -> None:
    """The information-form update (``M``, ``z``, a 3 x 3 solve) against the batch
    Joseph form ``K = P H^T (H P H^T + R)^-1``, ``H = [0, J]``, with the attitude
    corrected by ``Rotation.from_mrp(K nu / 4)`` (the previous implementation's maths)."""
    rng = np.random.default_rng(11)
    root = rng.normal(size=(6, 6))
    covariance = root @ root.T * 1e-3 + 1e-6 * np.eye(6)
    jacobian, variance = rng.normal(size=(7, 3)), rng.uniform(1e-4, 1e-3, 7)
    innovation, rate = rng.normal(size=7) * 0.01, rng.normal(size=3) * 0.01
    attitude = Rotation.random(random_state=rng)
    h = np.hstack([np.zeros((7, 3)), jacobian])
    gain = np.linalg.solve(h @ covariance @ h.T + np.diag(variance), h @ covariance).T
    keep = np.eye(6) - gain @ h
    expected = keep @ covariance @ keep.T + gain @ np.diag(variance) @ gain.T
    correction = gain @ innovation
    information = jacobian.T @ (jacobian / variance[:, None])
    residual = jacobian.T @ (innovation / variance)
    new_rate, new_attitude, posterior = (
        x.full()
        for x in update_function()(rate, attitude.as_matrix(), covariance, information, residual)
    )
    np.testing.assert_allclose(new_rate.ravel(), rate + correction[:3], rtol=1e-12, atol=1e-16)
    expected_attitude = Rotation.from_mrp(correction[3:] / 4.0) * attitude
    np.testing.assert_allclose(new_attitude, expected_attitude.as_matrix(), rtol=0, atol=1e-14)
    assert relative_covariance_difference(posterior, expected) < 1e-12


def test_an_epoch_without_vectors_is_exactly_no_update() -> None:
    """Absent slots carry zero weight: an epoch without vectors returns its
    predicted state bit for bit, and absent slots beside present ones change nothing
    (the slots are cut to the most vectors at any epoch before the pass)."""
    rng = np.random.default_rng(2)
    run = simulate_vectors(rng, 120, presence=0.4)
    prior = drawn_prior(rng, run, np.diag([1e-6] * 3 + [1e-4] * 3))
    result = run_fast(run, prior, 1e-9)
    history = result.history
    empty = result.diagnostics["rows"] == 0
    assert empty.sum() > 10
    np.testing.assert_array_equal(
        history.filtered_covariance[empty], history.predicted_covariance[empty]
    )
    np.testing.assert_array_equal(result.rate[empty], history.predicted_vector[empty])
    np.testing.assert_array_equal(
        history.filtered_attitude[empty], history.predicted_attitude[empty]
    )
    padded = [np.concatenate([x, np.full_like(x[:, :2], np.nan)], axis=1) for x in run.arrays]
    padded[2][:, -2:] = 1.0
    for got, expected in zip(vector_arrays(*padded), vector_arrays(*run.arrays), strict=True):
        np.testing.assert_array_equal(got, expected)


def test_noise_free_run_from_the_truth_stays_at_the_truth() -> None:
    """Exact vectors of a truth that follows the filter's step map, prior at the
    truth: the estimate stays on it to rounding over 600 epochs."""
    rng = np.random.default_rng(4)
    run = simulate_vectors(rng, 600, noisy=False)
    prior = rate_prior(run.truth[0], run.rate[0], np.diag([1e-6] * 3 + [1e-4] * 3))
    result = run_fast(run, prior, 1e-9)
    assert np.radians(np.abs(attitude_error(result.attitude(), run.truth)).max()) < 1e-12
    np.testing.assert_allclose(result.rate, run.rate, rtol=0, atol=1e-14)


@pytest.mark.parametrize("fast", [True, False], ids=["compiled", "loop"])
def test_a_rate_beyond_the_step_limit_raises(fast: bool) -> None:
    """``MAX_STEP_ANGLE`` per step: reported with the first epoch that exceeds it."""
    rng = np.random.default_rng(5)
    run = simulate_vectors(rng, 20, noisy=False)
    rate = np.array([0.0, 0.0, 1.1 * MAX_STEP_ANGLE / DT])
    prior = rate_prior(run.truth[0], rate, np.diag([1e-12] * 3 + [1e-4] * 3))
    with pytest.raises(ConvergenceError, match="at epoch 0"):
        if fast:
            run_fast(run, prior, 1e-9)
        else:
            run_loop(run, prior, 1e-9)
