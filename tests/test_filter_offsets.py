"""Transmitter power offsets as augmented states of the MEKF and USQUE
(``mekf_offsets``, ``usque_offsets``; :mod:`attopt.solvers.filters.offsets`)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.stats import chi2

from attopt.experiments.metrics import attitude_errors
from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.passes import GyroRecord, Pass
from attopt.formulations.snapshot import Snapshot
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.solvers.bounds import posterior_bound
from attopt.solvers.filters import Mekf, MekfOffsets, Rts, Usque
from attopt.solvers.filters.common import gyro_monitor, gyro_pass
from attopt.solvers.filters.estimators import UsqueOffsets
from attopt.solvers.filters.offsets import OffsetStates
from attopt.solvers.filters.recovery import SingleFrameRecovery
from attopt.solvers.sequential import run_filter
from tests.filter_passes import GYRO, drawn_prior, prior_covariance, simulate_pass
from tests.test_snr_solvers import _epoch, _geometry

OFFSET_SIGMA_DB = 2.0
IN_VIEW = 12
"""Transmitters heard per epoch: every 4 s three set and three rise, so each is heard
for 16 epochs and the filters admit and marginalise offsets throughout."""


def _offset_pass(
    seed: int,
    duration: float = 30.0,
    offset_sigma: float = OFFSET_SIGMA_DB,
    sources: bool = True,
):
    """A gyro pass with SNRs of transmitters whose powers are off by ``N(0, sigma^2)`` dB
    (1 dB SNR noise), its truth and the true offsets (``sources``: the SNRs say which
    transmitter sent them)."""
    rng = np.random.default_rng(seed)
    run = simulate_pass(rng, duration=duration, simulated_gyro=GYRO)
    prior = drawn_prior(rng, run, prior_covariance(np.radians(1.0)))
    offsets = offset_sigma * rng.standard_normal(200)
    snapshots = []
    for k in range(run.t.size):
        geometry = _geometry(rng, run.truth_at_epochs[k], per_antenna=(6, 6))
        ids = 3 * (k // 4) + np.arange(IN_VIEW)
        snr = geometry[3] + offsets[ids] + rng.standard_normal(IN_VIEW)
        epoch = _epoch(geometry, snr, threshold_db=-np.inf, transmitter=ids if sources else None)
        snapshots.append(Snapshot.of(SnrMeasurement(epoch)))
    gyro = GyroRecord(run.gyro.t, run.gyro.rates, GYRO)
    return Pass(run.t, snapshots, gyro, prior), run.truth_at_epochs, offsets


def _nees(track, truth) -> np.ndarray:
    error = attitude_errors(track.quaternion, truth)
    return np.einsum("ni,nij,nj->n", error, np.linalg.inv(track.covariance), error)


@pytest.fixture(scope="module")
def monte_carlo() -> dict[str, np.ndarray]:
    """Final-epoch NEES of each filter over 40 seeded passes (independent across passes;
    NaN where the filter flags that epoch); the plain MEKF over the first 10 (it flagged
    the last epoch of all 40)."""
    estimators = {
        "mekf_offsets": MekfOffsets(offset_timeout_s=3.0),
        "usque_offsets": UsqueOffsets(offset_timeout_s=3.0),
        "mekf": Mekf(),
    }
    nees: dict[str, list[float]] = {name: [] for name in estimators}
    for seed in range(40):
        pass_, truth, _ = _offset_pass(seed)
        for name, estimator in estimators.items():
            if name == "mekf" and seed >= 10:
                continue
            track = estimator.solve(pass_)
            nees[name].append(float(_nees(track, truth)[-1]) if track.valid[-1] else np.nan)
    return {name: np.array(values) for name, values in nees.items()}


def test_offsets_filters_are_nees_consistent_over_a_seeded_monte_carlo(monte_carlo) -> None:
    """The sum of 40 independent final-epoch NEES is chi-square(120) for a consistent
    filter: inside its two-sided 0.999 interval for both offsets filters, every pass
    valid at its end.  The plain MEKF on the same data, told nothing of the offsets,
    flags most of them as inconsistent (the data do contradict a filter without them)."""
    low, high = chi2.ppf([0.0005, 0.9995], 3 * 40)
    for name in ("mekf_offsets", "usque_offsets"):
        assert np.isfinite(monte_carlo[name]).all(), name
        assert low <= monte_carlo[name].sum() <= high, (name, monte_carlo[name].mean())
    assert np.isnan(monte_carlo["mekf"]).mean() > 0.5


def test_offsets_are_estimated_within_their_covariance() -> None:
    """The offsets of the transmitters still in view at the end of a pass are estimated
    with normalised errors of a consistent filter, and much better than their prior."""
    pass_, _, truth = _offset_pass(3, duration=60.0)
    states = OffsetStates(OFFSET_SIGMA_DB, 3.0)
    estimator = MekfOffsets(offset_timeout_s=3.0)
    options = estimator.filter
    inputs = gyro_pass(pass_, estimator, options)
    steps = estimator.steps(inputs.gyro, inputs.model, inputs.prior, options, states)
    recovery = SingleFrameRecovery.of(options, inputs.prior, started=True)
    monitor = gyro_monitor(options, inputs.prior)
    track = run_filter(steps, inputs.t, inputs.measurements, monitor, options, "x", recovery)
    assert track.valid.all()
    last = 3 * (60 // 4) + np.arange(IN_VIEW)  # heard at the last epoch; 3 more within 3 s
    assert set(last) < set(states.ids) and states.size == IN_VIEW + 3
    error = states.value - truth[states.ids]
    normalised = error / np.sqrt(np.diag(states.own))
    assert np.all(np.abs(normalised) < 4.0)
    assert np.sqrt(np.mean(error**2)) < 0.5 * OFFSET_SIGMA_DB


@pytest.mark.parametrize(("plain", "offsets"), [(Mekf(), MekfOffsets), (Usque(), UsqueOffsets)])
def test_offsets_with_a_tiny_prior_are_the_plain_filter(plain, offsets) -> None:
    """Offsets whose prior allows (almost) nothing leave the filter as it is without them:
    admission, the joint update and marginalisation change nothing else."""
    pass_, _, _ = _offset_pass(5, duration=20.0, offset_sigma=0.0)
    reference = plain.solve(pass_)
    track = offsets(offset_sigma=1e-9, offset_timeout_s=3.0).solve(pass_)
    np.testing.assert_allclose(track.quaternion, reference.quaternion, atol=1e-9)
    np.testing.assert_allclose(track.covariance, reference.covariance, rtol=1e-6, atol=1e-18)


def test_mekf_and_usque_with_offsets_agree() -> None:
    """Independent filters (linearised and unscented) on one pass agree to a small
    fraction of their sigma."""
    pass_, _, _ = _offset_pass(7)
    mekf, usque = MekfOffsets().solve(pass_), UsqueOffsets().solve(pass_)
    difference = attitude_errors(mekf.quaternion, usque.attitude())
    assert np.all(np.abs(difference) < 0.1 * mekf.sigma)


def test_an_offsets_pass_without_sources_raises_and_rts_cannot_smooth_it() -> None:
    anonymous, _, _ = _offset_pass(2, duration=5.0, sources=False)
    with pytest.raises(InvalidObservationError, match="no measurement has sources"):
        MekfOffsets().solve(anonymous)
    pass_, _, _ = _offset_pass(2, duration=5.0)
    track = MekfOffsets().solve(pass_)
    with pytest.raises(InvalidObservationError):
        Rts().solve(pass_, track)


@settings(max_examples=40, deadline=None)
@given(
    heard=st.lists(st.lists(st.integers(0, 30), min_size=1, max_size=8), min_size=1, max_size=12),
    timeout=st.floats(0.5, 5.0),
)
def test_offset_bookkeeping_admits_marginalises_and_keeps_the_joint_covariance(
    heard, timeout
) -> None:
    """Sources are admitted at their prior and kept sorted; one not heard for longer than
    the timeout is dropped with its row and column (the others' marginal unchanged)."""
    states = OffsetStates(2.0, timeout)
    rng = np.random.default_rng(len(heard))
    covariance = np.eye(6)
    for k, sources in enumerate(heard):
        sources = np.array(sources)
        before = {  # the variances of the sources kept: heard within the timeout
            source: variance
            for source, variance, last in zip(
                states.ids.tolist(), np.diag(states.own), states.last_heard, strict=True
            )
            if last >= k - timeout
        }
        joint, rows = states.augment(covariance, sources, sources.size, float(k))
        assert np.all(np.diff(states.ids) > 0)
        np.testing.assert_array_equal(states.ids[rows.index], sources)
        for i, source in enumerate(states.ids):
            assert states.own[i, i] == before.get(source, 4.0)
        expected = {s for j in range(k + 1) if k - j <= timeout for s in heard[j]}
        assert set(states.ids.tolist()) == expected
        # a Kalman update of the joint state by random rows, absorbed back
        h = rng.standard_normal((3, joint.shape[0]))
        gain = np.linalg.solve(h @ joint @ h.T + np.eye(3), h @ joint).T
        joint = joint - gain @ h @ joint
        covariance = states.absorb(0.5 * (joint + joint.T), np.zeros(states.size))
        rebuilt = np.block([[covariance, states.cross], [states.cross.T, states.own]])
        np.testing.assert_allclose(rebuilt, 0.5 * (joint + joint.T))
        assert np.linalg.eigvalsh(rebuilt)[0] > -1e-12
    states.clear()
    assert states.size == 0 and states.cross.shape == (6, 0)


def test_offsets_propagate_their_cross_covariance_and_random_walk() -> None:
    """``C <- Phi C`` and, with a random walk, ``O <- O + q dt I``; constants by default."""
    constant, walking = OffsetStates(2.0, 30.0), OffsetStates(2.0, 30.0, rate_sigma=0.1)
    transition = np.diag([2.0, 1, 1, 1, 1, 1])
    for states in (constant, walking):
        states.augment(np.eye(6), np.array([4, 9]), 2, t=0.0)
        states.cross[0] = 1.0
        states.propagate(transition, 5.0)
        np.testing.assert_array_equal(states.cross[0], [2.0, 2.0])
    np.testing.assert_array_equal(constant.own, 4.0 * np.eye(2))
    np.testing.assert_allclose(walking.own, (4.0 + 0.01 * 5.0) * np.eye(2))
    with pytest.raises(ValueError, match="random-walk"):
        OffsetStates(2.0, 30.0, rate_sigma=-1.0)


def test_the_offsets_prior_test_is_chi_square_and_skips_what_the_data_did_not_inform() -> None:
    """Estimates drawn from ``N(0, D - O)`` give a statistic with mean ``k``; an offset the
    data have not informed is left out; estimates far off their prior fail."""
    rng = np.random.default_rng(0)
    states = OffsetStates(2.0, 30.0)
    states.augment(np.eye(6), np.arange(5), 5, t=0.0)
    root = rng.standard_normal((5, 5)) * 0.3
    states.own = 4.0 * np.eye(5) - root @ root.T  # the data removed root root^T
    states.own[4, :] = states.own[:, 4] = 0.0
    states.own[4, 4] = 4.0  # offset 4 not informed at all
    statistics = []
    for _ in range(2000):
        states.value = root @ rng.standard_normal(5)
        statistic, dof = states.prior_test()
        statistics.append(statistic)
    assert dof == 4
    assert abs(np.mean(statistics) - 4.0) < 0.25
    states.value = 3.0 * np.ones(5)
    statistic, dof = states.prior_test()
    assert chi2.sf(statistic, dof) < 1e-6


def test_a_start_or_restart_sees_the_offsets_at_their_prior() -> None:
    """The single frame a filter with offsets starts or restarts from solves the epoch with
    each SNR's sigma widened by the offsets' prior; the plain filter's sees it as it is."""
    pass_, _, _ = _offset_pass(4, duration=3.0)
    estimator = MekfOffsets(offset_sigma=3.0)
    inputs = gyro_pass(pass_, estimator, estimator.filter)
    measurement = inputs.measurements[0]
    with_offsets = estimator.steps(
        inputs.gyro, inputs.model, inputs.prior, estimator.filter, estimator.empty_offsets()
    )
    view = with_offsets.single_frame_view(measurement)
    np.testing.assert_allclose(view.epoch.sigma_db, np.hypot(measurement.epoch.sigma_db, 3.0))
    np.testing.assert_array_equal(view.z, measurement.z)
    plain = Mekf.steps(inputs.gyro, inputs.model, inputs.prior, estimator.filter)
    assert plain.single_frame_view(measurement) is measurement


def test_the_posterior_bound_with_unknown_powers_is_looser_and_tends_to_the_known_one() -> None:
    """Unknown transmitter powers can only loosen the posterior bound; with a vanishing
    prior on them it is the bound of known powers."""
    pass_, truth, _ = _offset_pass(6, duration=20.0)
    # the pass's gyro run is the first draw of its generator: drawn again for its bias
    run = simulate_pass(np.random.default_rng(6), duration=20.0, simulated_gyro=GYRO)
    bias = run.bias[run.index]
    known = posterior_bound(pass_, truth, bias)
    unknown = posterior_bound(pass_, truth, bias, offset_sigma=OFFSET_SIGMA_DB)
    almost = posterior_bound(pass_, truth, bias, offset_sigma=1e-6)
    assert np.all(unknown >= known * (1 - 1e-9)) and np.any(unknown > 1.05 * known)
    np.testing.assert_allclose(almost, known, rtol=1e-6)
