"""The one sequential loop (``solvers/sequential.py``) and the registry estimators on it.

* the filters' predict and update steps used by hand equal the estimators' ``solve``;
* epochs between the gyro's sample times (``solvers/gyro_timeline.py``): noise-free
  exact, each epoch propagated to its own time, and the same estimates as a gyro
  sampled so that the epochs are sample times;
* the lost-track monitor against an independent count of its rule (hypothesis);
* bad passes: a gyro at another rate than its model declares, no gyro, a rate prior
  for a gyro filter, no dynamics or a bias prior for Yang et al. 2014's EKF;
* the registries' estimators (names, pickling, configured copies).
"""

from __future__ import annotations

import dataclasses
import pickle

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import VectorMeasurement
from attopt.formulations.conventions import attitude_error
from attopt.formulations.errors import GyroRateMismatchError, InvalidObservationError
from attopt.formulations.gyro import GyroModel, GyroSamples, error_state_transition
from attopt.formulations.passes import GyroRecord, Pass, Prior, RigidBody
from attopt.solvers import doa, filters, smoother
from attopt.solvers.doa import DoaEkf
from attopt.solvers.doa.ekf import EKF_FAULTS, DoaEkfFilter, ekf_dynamics, ekf_monitor, ekf_prior
from attopt.solvers.filters import FilterOptions, Mekf, Rts, Usque
from attopt.solvers.filters.common import gyro_monitor, gyro_pass, step_noise
from attopt.solvers.filters.mekf import MekfFilter
from attopt.solvers.filters.usque import UsqueFilter
from attopt.solvers.sequential import TrackMonitor, rejected_epoch
from attopt.solvers.smoother import (
    BatchSmoother,
    LevenbergMarquardtParams,
    OffsetBatchSmoother,
    OnlineSmoother,
)
from attopt.solvers.smoother.online import OnlineFilter
from tests.filter_passes import (
    GYRO,
    drawn_prior,
    prior_covariance,
    simulate_pass,
)
from tests.filter_passes import (
    gyro_pass as make_pass,
)
from tests.test_doa_ekf import drawn_prior as drawn_rate_prior
from tests.test_doa_ekf import simulate_vectors

# --- the steps by hand --------------------------------------------------------------------


def _vector_pass(seed: int = 3) -> Pass:
    rng = np.random.default_rng(seed)
    run = simulate_pass(rng, duration=30.0)
    run.measurements[7] = None  # an epoch without a measurement
    prior = drawn_prior(rng, run, prior_covariance(np.radians(1.0)))
    return make_pass(run.gyro, run.t, run.measurements, prior)


def _by_hand(step_filter, pass_: Pass):
    """Each epoch's estimate (quaternion, bias or rate, covariance) and update counts from
    ``predict`` and ``update`` called by hand."""
    out = []
    for t, measurement in zip(pass_.t, pass_.measurements(), strict=True):
        step_filter.predict(float(t))
        counts = step_filter.update(measurement)
        out.append(
            (step_filter.attitude.as_quat(), step_filter.vector, step_filter.covariance, counts)
        )
    return out


@pytest.mark.parametrize("kind", ["mekf", "usque", "fg_online"])
def test_gyro_filter_steps_by_hand_equal_solve(kind: str) -> None:
    """``predict(t)`` then ``update(measurement)`` at every epoch, state read from the
    attributes, bit for bit the estimator's track (no gated epoch: the monitor is idle;
    ``recovery = "inflate"``: the start from a single frame is the recovery's,
    tests/test_filter_recovery.py)."""
    pass_ = _vector_pass()
    options = FilterOptions(recovery="inflate")
    estimator = {
        "mekf": Mekf(filter=options),
        "usque": Usque(filter=options),
        "fg_online": OnlineSmoother(filter=options),
    }[kind]
    inputs = gyro_pass(pass_, estimator, options)
    args = (inputs.gyro, inputs.model, inputs.prior)
    step_filter = {
        "mekf": lambda: MekfFilter(*args, options),
        "usque": lambda: UsqueFilter(*args, options),
        "fg_online": lambda: OnlineFilter(*args, inputs.t, estimator.online, options),
    }[kind]()
    track = estimator.solve(pass_)
    assert track.valid.all() and track.diagnostics["n_gated"].sum() == 0
    for k, (quaternion, bias, covariance, counts) in enumerate(_by_hand(step_filter, pass_)):
        np.testing.assert_array_equal(quaternion, track.quaternion[k])
        np.testing.assert_array_equal(bias, track.bias[k])
        np.testing.assert_array_equal(covariance, track.state_covariance[k])
        if counts is None:
            assert k == 7 and kind != "fg_online"
        else:
            assert counts["nis"] == track.loss[k] or np.isnan(track.loss[k])
            assert counts["n_used"] == track.diagnostics["n_used"][k]


def test_ekf_steps_by_hand_equal_solve() -> None:
    """The same for Yang et al. 2014's EKF (its Python path), with the history an RTS
    pass needs: the prediction and the transition recorded at each epoch."""
    rng = np.random.default_rng(4)
    run = simulate_vectors(rng, 60, process_noise=1e-9)
    pass_ = run.pass_(drawn_rate_prior(rng, run, np.diag([1e-6] * 3 + [1e-4] * 3)))
    track = DoaEkf(compiled=False).solve(pass_)
    step_filter = DoaEkfFilter(
        pass_.t, ekf_dynamics(pass_), ekf_prior(pass_.prior), 1e-9, EKF_FAULTS
    )
    for k, (t, measurement) in enumerate(zip(pass_.t, pass_.measurements(), strict=True)):
        step_filter.predict(float(t))
        np.testing.assert_array_equal(
            step_filter.attitude_values(), track.history.predicted_attitude[k]
        )
        np.testing.assert_array_equal(step_filter.transition, track.history.transition[k])
        step_filter.update(measurement)
        np.testing.assert_array_equal(step_filter.attitude.as_quat(), track.quaternion[k])
        np.testing.assert_array_equal(step_filter.rate, track.rate[k])
        np.testing.assert_array_equal(step_filter.covariance, track.state_covariance[k])
    assert track.state == ("rate", "attitude") and track.block("attitude") == slice(3, 6)


def test_predict_rejects_a_time_that_is_no_epoch_nor_sample() -> None:
    pass_ = _vector_pass()
    inputs = gyro_pass(pass_, Mekf(), FilterOptions())
    step_filter = MekfFilter(inputs.gyro, inputs.model, inputs.prior, FilterOptions())
    step_filter.predict(2.5)  # a gyro sample time (2 Hz)
    with pytest.raises(InvalidObservationError, match="neither a gyro sample time nor an epoch"):
        step_filter.predict(2.7)


# --- epochs between gyro samples ------------------------------------------------------------

OFFSET = 0.05
"""Epochs at ``t = 0.05 + k`` s: half-way between samples of a 10 Hz gyro."""
RATE = np.array([0.02, -0.01, 0.015])
BIAS = np.array([1e-3, -2e-3, 5e-4])
START = Rotation.from_euler("xyz", [10.0, -20.0, 30.0], degrees=True)
REFERENCES = np.array([[1.0, 0.0, 0.0], [0.0, 0.6, 0.8]])
MODEL = GyroModel("test-10hz", sigma_v=1e-4, sigma_u=1e-6, initial_bias_sigma=1e-2, rate_hz=10.0)


def _truth(t: np.ndarray) -> Rotation:
    """A body turning at the constant body rate ``RATE``: ``A(t) = exp(-[w x] t) A_0``."""
    return Rotation.from_rotvec(-np.outer(t, RATE)) * START


def _constant_rate_pass(
    gyro_start: float, epochs: np.ndarray, prior: Prior, sigma: float, rng=None
) -> Pass:
    """Exact 10 Hz gyro samples of the constant rate (with ``BIAS``) from ``gyro_start``
    covering ``epochs``, and two vectors per epoch (noisy when ``rng`` is given)."""
    t = gyro_start + MODEL.dt * np.arange(round((epochs[-1] - gyro_start) / MODEL.dt) + 2)
    rates = np.tile(RATE + BIAS, (t.size - 1, 1))
    body = np.stack([_truth(epochs)[k].apply(REFERENCES) for k in range(epochs.size)])
    if rng is not None:
        body = body + sigma * rng.standard_normal(body.shape)
    reference = np.broadcast_to(REFERENCES, body.shape)
    return Pass.from_vectors(epochs, body, reference, sigma, GyroRecord(t, rates, MODEL), prior)


def _exact_prior(t0: float, attitude_sigma: float, error: tuple = (0.0, 0.0, 0.0)) -> Prior:
    covariance = np.diag([attitude_sigma**2] * 3 + [1e-6**2] * 3)
    return Prior(Rotation.from_rotvec(error) * _truth(np.array([t0]))[0], covariance, bias=BIAS)


EXACT_BATCH = BatchSmoother(
    optimiser=LevenbergMarquardtParams(relative_tolerance=1e-15, absolute_tolerance=1e-14)
)
"""The batch smoother iterating to the rounding floor (exactness checks)."""


@pytest.mark.parametrize(
    "estimator", [Mekf(), Usque(), OnlineSmoother(), EXACT_BATCH], ids=lambda e: e.name
)
def test_epochs_between_samples_noise_free_exact(estimator) -> None:
    """Exact gyro and vectors, epochs at 0.05 s past the samples, a 5 deg initial error:
    the estimates are the truth at the epochs' own times to 1e-10 rad after the first
    updates (a filter holding the estimate at the sample before would be 1e-3 rad off)."""
    epochs = OFFSET + np.arange(40.0)
    prior = _exact_prior(0.0, np.radians(5.0), np.radians([5.0, 0.0, 0.0]))
    track = estimator.solve(_constant_rate_pass(0.0, epochs, prior, 1e-6))
    assert track.valid.all()
    np.testing.assert_array_equal(track.t, epochs)
    error = np.linalg.norm(attitude_error(track.attitude(), _truth(epochs)), axis=1)
    assert error[10:].max() < 1e-10, error.max()
    wrong_time = attitude_error(_truth(epochs - OFFSET), _truth(epochs))
    assert np.linalg.norm(wrong_time, axis=1).min() > 1e-3


def test_an_epoch_between_samples_is_propagated_to_its_own_time() -> None:
    """No measurements, an exact prior at the first sample (t = 0): the MEKF's estimate at
    t = 0.05 + k is the truth there, and its covariance after the first 0.05 s is the
    prior's carried by one step of 0.05 s (transition and process noise of that length)."""
    epochs = OFFSET + np.arange(5.0)
    prior = _exact_prior(0.0, 1e-3)
    pass_ = _constant_rate_pass(0.0, epochs, prior, 1e-6)
    silent = Pass(pass_.t, (None,) * len(pass_), pass_.gyro, prior)
    track = Mekf().solve(silent)
    assert np.abs(attitude_error(track.attitude(), _truth(epochs))).max() < 1e-13
    phi = error_state_transition(RATE, OFFSET)
    expected = (
        phi @ prior.covariance @ phi.T + step_noise(MODEL, np.array([OFFSET]), np.zeros(1))[0]
    )
    np.testing.assert_allclose(track.state_covariance[0], expected, rtol=1e-12, atol=0)
    assert track.diagnostics["gyro_gap_s"].max() == 0.0


@pytest.mark.parametrize("estimator", [Mekf(), BatchSmoother()], ids=lambda e: e.name)
def test_epochs_between_samples_match_a_gyro_sampled_at_the_epochs(estimator) -> None:
    """The same truth and the same noisy vectors at t = 0.05 + k, once with the gyro
    sampled at multiples of 0.1 s (each epoch cuts a step in two) and once sampled at
    0.05 + 0.1 j (every epoch a sample time), each prior the truth at its gyro's first
    sample: the MEKF's and the batch smoother's estimates agree to far below their
    sigma (the process noise of two half steps differs from one step's at third
    order in the step)."""
    rng = np.random.default_rng(9)
    epochs = OFFSET + np.arange(60.0)
    sigma = 1e-3
    cut = _constant_rate_pass(0.0, epochs, _exact_prior(0.0, 1e-2), sigma, rng)
    on = _constant_rate_pass(-OFFSET, epochs, _exact_prior(-OFFSET, 1e-2), sigma)
    on = Pass(on.t, cut.snapshots, on.gyro, on.prior)  # the same measured vectors
    a, b = estimator.solve(cut), estimator.solve(on)
    assert a.valid.all() and b.valid.all()
    normalised = attitude_error(a.attitude(), b.attitude()) / a.sigma
    assert np.abs(normalised[5:]).max() < 1e-3, np.abs(normalised).max()
    np.testing.assert_allclose(a.covariance[5:], b.covariance[5:], rtol=1e-3)


# --- the lost-track monitor -----------------------------------------------------------------


@settings(max_examples=60, deadline=None)
@given(
    epochs=st.lists(
        st.one_of(st.none(), st.tuples(st.integers(0, 3), st.integers(0, 3))), max_size=60
    ),
    limit=st.integers(1, 5),
)
def test_monitor_follows_its_rule(epochs, limit) -> None:
    """Random epochs (``None``: no measurement; else gated and used block counts): the
    monitor's lost flags are those of a run count that rejected epochs extend, accepted
    ones reset and others leave (``lost`` from ``limit`` on), and it inflates every
    ``limit``-th epoch of such a run, recording ``recoveries``."""
    monitor = TrackMonitor(limit, np.eye(6))
    run, inflations = 0, 0
    for epoch in epochs:
        covariance = np.zeros((6, 6))
        if epoch is not None:
            gated, used = epoch
            counts = {"n_gated": float(gated), "n_used": float(used)}
            covariance = monitor.check(counts, covariance)
            if gated > 0 and gated >= used:
                run += 1
                expected = run % limit == 0
            else:
                run = 0 if used > 0 else run
                expected = False
            assert (covariance[0, 0] == 1.0) == expected
            assert counts.get("recoveries", 0.0) == float(expected)
            inflations += expected
        assert monitor.lost == (run >= limit)
    assert rejected_epoch(1, 1) and not rejected_epoch(0, 0) and not rejected_epoch(1, 2)
    # SNRs the estimate cannot predict count against it: none usable is a rejection
    assert rejected_epoch(0, 0, 90) and rejected_epoch(2, 4, 2) and not rejected_epoch(0, 150, 3)


def test_epochs_of_unpredictable_observations_keep_a_track_lost() -> None:
    """After a lost track, epochs whose every observation the estimate cannot predict
    (none used, none gated) keep it lost instead of leaving the count where it was, so the
    estimate is not reported valid while the model says none of them could be received."""
    monitor = TrackMonitor(3)
    for _ in range(3):
        monitor.due({"n_used": 1.0, "n_gated": 5.0})
    assert monitor.lost
    monitor.due({"n_used": 5.0, "n_gated": 3.0})  # one accepted epoch ends it
    assert not monitor.lost
    for _ in range(3):
        monitor.due({"n_used": 0.0, "n_gated": 0.0, "n_unpredictable": 90.0})
    assert monitor.lost


def test_monitors_of_the_filters() -> None:
    """The gyro filters inflate the attitude by ``recover_sigma^2`` and the bias by the
    prior's bias covariance; the EKF the attitude (its second block) and the rate by the
    prior's; the online smoother's monitor never inflates."""
    options = FilterOptions()
    prior = Prior(Rotation.identity(), np.diag([1e-4] * 3 + [4e-6] * 3), bias=np.zeros(3))
    inflation = gyro_monitor(options, prior).inflation
    np.testing.assert_array_equal(np.diag(inflation), [options.recover_sigma**2] * 3 + [4e-6] * 3)
    ekf = ekf_monitor(options, np.diag([4e-6] * 3 + [1e-4] * 3)).inflation
    np.testing.assert_array_equal(np.diag(ekf), [4e-6] * 3 + [options.recover_sigma**2] * 3)
    assert TrackMonitor(3).check({"n_gated": 2.0, "n_used": 0.0}, np.eye(6)) is not None


# --- bad passes -----------------------------------------------------------------------------


def test_a_gyro_at_another_rate_than_its_model_raises() -> None:
    """2 Hz samples declared as a 10 Hz gyro: ``GyroRateMismatchError`` (an
    ``InvalidObservationError``) when the gyro record is built, so no estimator
    (every gyro-aided one takes a :class:`~attopt.formulations.passes.Pass`) sees it."""
    rng = np.random.default_rng(5)
    run = simulate_pass(rng, duration=10.0)
    prior = drawn_prior(rng, run, prior_covariance(np.radians(1.0)))
    ten_hz = dataclasses.replace(GYRO, rate_hz=10.0)
    with pytest.raises(GyroRateMismatchError, match="declared at 10 Hz"):
        make_pass(run.gyro, run.t, run.measurements, prior, ten_hz)
    with pytest.raises(GyroRateMismatchError):
        GyroRecord(run.gyro.t, run.gyro.rates, ten_hz)
    assert issubclass(GyroRateMismatchError, InvalidObservationError)


def test_gyro_estimators_need_a_gyro_and_a_gyro_prior() -> None:
    rng = np.random.default_rng(6)
    run = simulate_pass(rng, duration=10.0)
    prior = drawn_prior(rng, run, prior_covariance(np.radians(1.0)))
    pass_ = make_pass(run.gyro, run.t, run.measurements, prior)
    no_gyro = Pass(pass_.t, pass_.snapshots, None, prior)
    for estimator in (Mekf(), Usque(), Rts(), OnlineSmoother(), BatchSmoother()):
        with pytest.raises(InvalidObservationError, match=f"{estimator.name} needs a gyro record"):
            estimator.solve(no_gyro)
    rate_prior = Prior(prior.attitude, prior.covariance, rate=np.zeros(3))
    for estimator in (Mekf(), BatchSmoother()):
        with pytest.raises(InvalidObservationError, match="not a rate"):
            estimator.solve(Pass(pass_.t, pass_.snapshots, pass_.gyro, rate_prior))
    with pytest.raises(InvalidObservationError, match="needs a prior"):
        BatchSmoother().solve(Pass(pass_.t, pass_.snapshots, pass_.gyro))


def test_an_attitude_prior_gets_the_models_bias_sigma() -> None:
    """An attitude-only prior is the ``[attitude, bias]`` prior with zero bias and the
    gyro model's initial bias sigma: the same track bit for bit."""
    rng = np.random.default_rng(7)
    run = simulate_pass(rng, duration=20.0)
    full = drawn_prior(rng, run, prior_covariance(np.radians(1.0)))
    attitude_only = Prior(full.attitude, full.covariance[:3, :3])
    a = Mekf().solve(make_pass(run.gyro, run.t, run.measurements, attitude_only))
    b = Mekf().solve(
        make_pass(
            run.gyro,
            run.t,
            run.measurements,
            attitude_only.with_bias_covariance(GYRO.initial_bias_sigma),
        )
    )
    np.testing.assert_array_equal(a.quaternion, b.quaternion)
    np.testing.assert_array_equal(a.state_covariance, b.state_covariance)


def test_ekf_needs_dynamics_a_rate_prior_and_uniform_epochs() -> None:
    rng = np.random.default_rng(8)
    run = simulate_vectors(rng, 20)
    prior = drawn_rate_prior(rng, run, np.diag([1e-6] * 3 + [1e-4] * 3))
    pass_ = run.pass_(prior)
    with pytest.raises(InvalidObservationError, match="rigid-body dynamics"):
        DoaEkf().solve(Pass(pass_.t, pass_.snapshots, None, prior))
    bias_prior = Prior(prior.attitude, prior.covariance, bias=np.zeros(3))
    with pytest.raises(InvalidObservationError, match="prior with a body rate"):
        DoaEkf().solve(Pass(pass_.t, pass_.snapshots, None, bias_prior, pass_.dynamics))
    uneven = pass_.t.copy()
    uneven[5:] += 0.1
    dynamics = RigidBody(pass_.dynamics.inertia, pass_.dynamics.orbit_frames)
    with pytest.raises(InvalidObservationError, match="uniformly spaced"):
        DoaEkf().solve(Pass(uneven, pass_.snapshots, None, prior, dynamics))


# --- the registries ---------------------------------------------------------------------------


def test_registry_estimators() -> None:
    """The packages' ``ESTIMATORS``: registry names, start orders, pickling, and
    configured copies by ``dataclasses.replace``."""
    names = [e.name for package in (filters, smoother, doa) for e in package.ESTIMATORS]
    assert names == [
        "mekf",
        "usque",
        "rts",
        "mekf_offsets",
        "usque_offsets",
        "fg_online",
        "fg_batch",
        "fg_batch_offsets",
        "ekf_yang2014",
        "rts_yang2014",
        "bls_yang2014",
    ]
    starts = {
        e.name: e.starts_from for package in (filters, smoother, doa) for e in package.ESTIMATORS
    }
    assert starts["rts"] == ("mekf",) and starts["rts_yang2014"] == ("ekf_yang2014",)
    assert starts["bls_yang2014"] == ("rts_yang2014",) and starts["fg_online"] == ()
    assert starts["fg_batch"] == ("fg_online", "rts") and starts["fg_batch_offsets"] == ()
    for package in (filters, smoother, doa):
        for estimator in package.ESTIMATORS:
            assert pickle.loads(pickle.dumps(estimator)) == estimator
            assert estimator.kind == "pass" and repr(estimator).startswith("<pass estimator")
    strict = dataclasses.replace(Mekf(), filter=FilterOptions(gate_probability=0.99))
    assert strict.filter.gate_probability == 0.99 and Mekf().filter.gate_probability > 0.99
    with pytest.raises(dataclasses.FrozenInstanceError):
        strict.filter = FilterOptions()  # type: ignore[misc]
    wide = dataclasses.replace(OffsetBatchSmoother(), offset_sigma=5.0, noise_updates=1)
    assert wide.offset_sigma == 5.0 and wide.noise_updates == 1 and wide.name == "fg_batch_offsets"
    assert pickle.loads(pickle.dumps(wide)) == wide


def test_gyro_samples_and_vector_type_are_what_the_pass_holds() -> None:
    """A pass of ``VectorMeasurement``s with a gyro record: the filters see the record's
    ``GyroSamples`` at the model's step."""
    record = GyroRecord(np.arange(0.0, 2.01, 0.5), np.zeros((4, 3)), GYRO)
    assert isinstance(record.samples, GyroSamples) and record.samples.dt == GYRO.dt
    vector = VectorMeasurement(np.eye(3)[:2], np.eye(3)[:2], 1e-3)
    pass_ = Pass(
        np.array([0.25, 1.0]), (vector, None), record, Prior(Rotation.identity(), np.eye(3))
    )
    assert pass_.types() == {VectorMeasurement}
    assert Mekf().solve(pass_).valid.all()
