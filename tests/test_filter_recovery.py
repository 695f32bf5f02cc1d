"""Start and re-acquisition of the gyro filters from single-frame solutions
(:mod:`attopt.solvers.filters.recovery`).

Scenario: the vector passes of :mod:`tests.filter_passes` (a body turning at a
constant rate, a 2 Hz MEMS-class gyro, two unit vectors at 1 s epochs with 1 mrad
noise).  Integrity is the share of valid epochs whose attitude NEES exceeds the
chi-square(3) 1 - 1e-4 quantile.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation
from scipy.stats import chi2

from attopt.formulations.attitude_measurement import VectorMeasurement
from attopt.formulations.conventions import attitude_error
from attopt.formulations.passes import GyroRecord, Pass, Prior, epoch_snapshots
from attopt.solvers.filters import FilterOptions, Mekf, Usque
from attopt.solvers.filters.recovery import SingleFrame, single_frame
from attopt.solvers.sequential import INCONSISTENT, LOST, WAIT, TrackMonitor
from tests.filter_passes import (
    GYRO,
    REFERENCES,
    SIGMA,
    SimulatedPass,
    prior_covariance,
    simulate_pass,
    solve_with,
)

QUANTILE = chi2.ppf(1.0 - 1e-4, 3)
FILTERS = pytest.mark.parametrize("estimator", [Mekf, Usque], ids=["mekf", "usque"])
WINDOW = FilterOptions().consistency_window


def integrity_share(track, run: SimulatedPass) -> float:
    """Share of the valid epochs whose attitude NEES exceeds :data:`QUANTILE`."""
    valid = track.valid
    estimate = Rotation.from_quat(track.quaternion[valid])
    error = attitude_error(estimate, run.truth_at_epochs[valid])
    nees = np.einsum("ei,eij,ej->e", error, np.linalg.inv(track.covariance[valid]), error)
    return float(np.mean(nees > QUANTILE))


def outliers(run: SimulatedPass, start: int, stop: int) -> list:
    """The pass's measurements with the Sun vector of epochs ``[start, stop)`` turned by
    20 deg: no attitude fits both vectors there."""
    turn = Rotation.from_rotvec(np.radians(20.0) * np.array([0.0, 0.0, 1.0]))
    measurements = list(run.measurements)
    for k in range(start, stop):
        body = measurements[k].z.reshape(-1, 3).copy()
        body[0] = turn.apply(body[0])
        measurements[k] = VectorMeasurement(body, REFERENCES, SIGMA)
    return measurements


@FILTERS
def test_restart_reacquires_after_an_outlier_burst(estimator):
    """30 s of outlier vectors from 50 s, and from 60 s (the track already lost) a gyro
    rate 1 deg/s off until the burst ends (the attitude drifts 20 deg): the vectors are
    gated, the track is lost after ``max_rejected_epochs`` epochs, the outliers' single
    frames fail their residual test (no restart, no inflation), and at the first clean
    epoch the filter, 20 deg off, restarts from its single frame.  It is valid again
    ``consistency_window + 1`` epochs after the burst, with no valid epoch beyond the
    quantile."""
    run = simulate_pass(np.random.default_rng(31), duration=150.0)
    start, stop = 50, 80
    rates = run.gyro.rates.copy()
    rates[(start + 10) * 2 : stop * 2] += np.radians(1.0) * np.array([1.0, 0.0, 0.0])
    gyro = dataclasses.replace(run.gyro, rates=rates)
    prior = Prior(run.truth[0], prior_covariance(np.radians(1.0)), bias=run.bias[0])
    track = solve_with(estimator(), gyro, run.t, outliers(run, start, stop), prior)
    assert np.flatnonzero(track.diagnostics["restarts"]).tolist() == [stop]
    assert track.diagnostics["recoveries"].sum() == 0
    back = stop + WINDOW + 1
    assert track.valid[: start + 9].all()
    assert not track.valid[start + 9 : back].any()
    assert track.valid[back:].all()
    assert integrity_share(track, run) <= 0.001


@settings(max_examples=3, deadline=None)
@given(seed=st.integers(0, 2**16))
def test_a_pass_without_a_prior_starts_from_a_single_frame(seed):
    """No prior: the filters start at the first epoch from its single-frame solution
    and covariance (``restarts`` there), flag the first window of updates as
    converging, and are valid after it, with no more valid epochs beyond the quantile
    than the same filter started from the truth with a consistent 1 deg prior."""
    run = simulate_pass(np.random.default_rng(seed), duration=40.0)
    gyro = GyroRecord(run.gyro.t, run.gyro.rates, GYRO)
    pass_ = Pass(run.t, epoch_snapshots(run.measurements, run.t), gyro)
    truth = Prior(run.truth[0], prior_covariance(np.radians(1.0)), bias=np.zeros(3))
    for estimator in (Mekf(), Usque()):
        track = estimator.solve(pass_)
        assert track.diagnostics["restarts"].tolist() == [1.0] + [0.0] * (len(run.t) - 1)
        assert all(r.startswith("converging") for r in track.reason[: WINDOW + 1])
        assert track.valid[WINDOW + 1 :].all()
        reference = solve_with(estimator, run.gyro, run.t, run.measurements, truth)
        assert integrity_share(track, run) <= integrity_share(reference, run) + 0.001


@settings(max_examples=3, deadline=None)
@given(
    angle=st.floats(60.0, 90.0),
    axis=st.tuples(*[st.floats(-1.0, 1.0)] * 3).filter(lambda a: np.linalg.norm(a) > 0.1),
)
def test_a_wrong_basin_prior_is_detected_and_restarted(angle, axis):
    """A prior 60-90 deg off that claims 10 deg: its prediction contradicts the first
    epoch's single frame, so the filters restart from it at epoch 0 and are valid and
    consistent after the first window of updates."""
    run = simulate_pass(np.random.default_rng(41), duration=40.0)
    axis = np.asarray(axis) / np.linalg.norm(axis)
    wrong = Rotation.from_rotvec(np.radians(angle) * axis) * run.truth[0]
    prior = Prior(wrong, prior_covariance(np.radians(10.0)), bias=np.zeros(3))
    for estimator in (Mekf(), Usque()):
        track = solve_with(estimator, run.gyro, run.t, run.measurements, prior)
        assert track.diagnostics["restarts"][0] == 1.0
        assert track.valid[WINDOW + 1 :].all()
        assert integrity_share(track, run) <= 0.001


@FILTERS
def test_restart_changes_a_run_where_nothing_fails_only_by_its_first_update(estimator):
    """A clean pass from a consistent prior: ``inflate`` and ``none`` give the same track
    bit for bit; ``restart`` updates the first epoch with its single frame instead of the
    filter's own update, and its track agrees with theirs to a small fraction of sigma,
    with no restart and no recovery."""
    run = simulate_pass(np.random.default_rng(51), duration=120.0)
    error = Rotation.from_rotvec(np.radians([2.0, -3.0, 1.0]))
    prior = Prior(error * run.truth[0], prior_covariance(np.radians(5.0)), bias=np.zeros(3))
    tracks = [
        solve_with(
            estimator(filter=FilterOptions(recovery=mode)), run.gyro, run.t, run.measurements, prior
        )
        for mode in ("restart", "inflate", "none")
    ]
    np.testing.assert_array_equal(tracks[1].quaternion, tracks[2].quaternion)
    np.testing.assert_array_equal(tracks[1].state_covariance, tracks[2].state_covariance)
    restarted, plain = tracks[0], tracks[1]
    assert restarted.diagnostics["nis_dof"][0] == 3
    difference = attitude_error(restarted.attitude(), plain.attitude())
    assert np.abs(difference / plain.sigma).max() < 0.05
    np.testing.assert_allclose(restarted.covariance, plain.covariance, rtol=0.05)
    for track in tracks:
        assert track.valid.all()
        assert track.diagnostics["restarts"].sum() == 0
        assert track.diagnostics["recoveries"].sum() == 0


def test_a_prior_inside_its_sigma_but_in_another_basin_starts_from_the_single_frame():
    """Trial 0 of five minutes of ``adsb-snr`` with Liu et al. 2023's gyro: the MEKF's
    prior is 29 deg off against 10 deg sigmas, which the contradiction test passes.  Its
    own update from that prior lands in another basin of the SNR cost, and the filter is
    then reported valid 25-83 deg off (NEES up to 24: its covariance grows with the
    error) until its innovations fail;
    updated by the first epoch's single frame it starts 1.2 deg off and stays within its
    covariance (measured in ``adsb-sky``'s quick run)."""
    from attopt.experiments.adsb_snr import experiment as adsb

    def rows(options: dict):
        document = {"duration_s": 300.0, "methods": [], "filters": ["mekf_snr"]}
        document |= {"gyros": ["liu2023"], "estimator_options": options}
        setting = adsb.AdsbSnrParameters.model_validate(document).model_dump(mode="json")
        return adsb.trial(setting, np.random.SeedSequence(0, spawn_key=(0, 0)))

    def largest_error(frame) -> float:
        return float(np.nanmax(np.linalg.norm(frame[[f"err_{a}_deg" for a in "xyz"]], axis=1)))

    own_update = rows({"mekf": {"filter": {"recovery": "inflate"}}})
    assert largest_error(own_update.iloc[:1]) > 20.0
    assert own_update["valid"].iloc[:30].all() and largest_error(own_update.iloc[:30]) > 25.0
    started = rows({})
    assert largest_error(started.iloc[:1]) < 3.0 and largest_error(started) < 3.0
    assert started["valid"].all() and started["nees"].max() < QUANTILE


def test_single_frame_fails_on_outliers_and_is_the_map_solution_otherwise():
    """The single frame of a clean epoch is within 5 sigma of the truth; an epoch whose
    vectors no attitude fits fails the residual test (wait for a later epoch)."""
    run = simulate_pass(np.random.default_rng(61), duration=2.0)
    frame = single_frame(run.measurements[0], FilterOptions())
    assert isinstance(frame, SingleFrame)
    error = attitude_error(frame.attitude, run.truth_at_epochs[0])
    assert error @ np.linalg.solve(frame.covariance, error) < QUANTILE
    assert single_frame(outliers(run, 0, 1)[0], FilterOptions()) == WAIT


@settings(max_examples=40, deadline=None)
@given(nis=st.lists(st.one_of(st.none(), st.floats(0.0, 200.0)), max_size=40))
def test_monitor_gives_inconsistent_after_a_persistently_failing_window(nis):
    """Updates with ``nis`` (3 rows each; ``None``: no update): the monitor's verdict is
    ``inconsistent`` at each ``max_rejected_epochs``-th consecutive update whose window
    (the last ``window`` updates) fails the chi-square test, and never ``lost``."""
    limit, window, false_alarm = 3, 2, 1e-6
    monitor = TrackMonitor(limit, None, window, false_alarm)
    updates: list[float] = []
    failing = 0
    for value in nis:
        if value is None:
            assert monitor.due({}) is None
            continue
        updates = [*updates[-(window - 1) :], value]
        failed = chi2.sf(sum(updates), 3 * len(updates)) < false_alarm
        failing = failing + 1 if failed else 0
        expected = INCONSISTENT if failing == limit else None
        failing = 0 if failing == limit else failing
        verdict = monitor.due({"n_used": 1.0, "nis": value, "nis_dof": 3.0})
        assert verdict == expected
        assert verdict != LOST


@FILTERS
def test_a_start_wider_than_the_limit_waits_for_a_single_frame(estimator):
    """A prior 98 deg off with 60 deg sigmas (the start of Yang et al. 2014) and, for the
    first 60 s, one vector per epoch: no epoch determines every axis, so no single frame
    can check the filter, and its epochs are flagged (``attitude not determined``, then
    ``converging``: not yet confirmed) however small its covariance has become.  At 60 s
    the second vector appears: the filter restarts from its single frame (the updates so
    far were linearised far from the truth; fused instead, they left the bias estimate
    and its shrunken covariance, and ``doa-ground``'s MEKF 1-2 deg off at NEES up to 63
    for 200-700 s), and from a window of updates later it is valid and consistent.  With
    both vectors from the start the check is at the first epoch, as for any prior."""
    run = simulate_pass(np.random.default_rng(43), duration=120.0)
    first = 60
    measurements = [
        VectorMeasurement(m.z.reshape(-1, 3)[:1], REFERENCES[:1], SIGMA) if k < first else m
        for k, m in enumerate(run.measurements)
    ]
    axis = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
    wrong = Rotation.from_rotvec(np.radians(98.0) * axis) * run.truth[0]
    prior = Prior(wrong, prior_covariance(np.radians(60.0)), bias=np.zeros(3))
    track = solve_with(estimator(), run.gyro, run.t, measurements, prior)
    reasons = set(track.reason[:first])
    assert not track.valid[:first].any()
    assert any(r.startswith("converging: started from a prior wider than") for r in reasons)
    assert track.diagnostics["restarts"][first] == 1.0
    assert track.valid[first + WINDOW + 1 :].all()
    assert integrity_share(track, run) <= 0.001
    both = solve_with(estimator(), run.gyro, run.t, run.measurements, prior)
    assert both.diagnostics["restarts"][0] == 1.0 or both.diagnostics["nis_dof"][0] == 3.0
    assert not any(r.startswith("converging: started") for r in both.reason)


@FILTERS
def test_a_track_regained_without_a_restart_is_converging_for_a_window(estimator):
    """30 s of outlier vectors from 50 s with no recovery (``recovery = "none"``): the
    vectors are gated, the track is lost after ``max_rejected_epochs`` epochs, and at
    80 s the clean vectors are accepted again by the filter as it drifted.  Those first
    updates are linearised wherever the filter drifted to, so that epoch and those to the
    ``consistency_window``-th update after it are flagged ``converging`` (as after a
    restart), and valid after."""
    run = simulate_pass(np.random.default_rng(31), duration=150.0)
    start, stop = 50, 80
    prior = Prior(run.truth[0], prior_covariance(np.radians(1.0)), bias=run.bias[0])
    options = FilterOptions(recovery="none")
    track = solve_with(
        estimator(filter=options), run.gyro, run.t, outliers(run, start, stop), prior
    )
    lost = np.flatnonzero(np.char.startswith(track.reason.astype(str), "lost track"))
    assert lost[0] == start + options.max_rejected_epochs - 1 and lost[-1] == stop - 1
    regained = np.char.startswith(track.reason.astype(str), "converging: re-acquired")
    assert np.flatnonzero(regained).tolist() == list(range(stop, stop + WINDOW + 1))
    assert track.valid[stop + WINDOW + 1 :].all()
    assert integrity_share(track, run) <= 0.001


@FILTERS
def test_a_prior_its_first_update_contradicts_waits_for_a_single_frame(estimator):
    """A prior 80 deg off at 10 deg sigmas (inside the limit) and one vector per epoch for
    the first 60 s: the first epoch has no single frame (one vector leaves the rotation
    about it free), so nothing checks the prior, and its update there gates the vector
    (rejects as many observations as it uses: the lost-track monitor's rule for an
    epoch).  The filter then waits for a single frame as from a wide prior: no epoch
    until the first with two vectors is valid (flagging only the window
    of updates after the first left epochs valid beyond the quantile), that epoch
    restarts the filter, and no valid epoch after it lies beyond the quantile (Liu et al.
    2023's sky under real aircraft antennas: USQUE's first epoch was reported valid 40 deg
    off, NEES 40, its update using 1 of 87 SNRs).  From the true attitude the same start
    is not flagged."""
    run = simulate_pass(np.random.default_rng(47), duration=120.0)
    first = 60
    measurements = [
        VectorMeasurement(m.z.reshape(-1, 3)[:1], REFERENCES[:1], SIGMA) if k < first else m
        for k, m in enumerate(run.measurements)
    ]
    axis = np.array([0.3, 1.0, -0.4]) / np.linalg.norm([0.3, 1.0, -0.4])
    wrong = Rotation.from_rotvec(np.radians(80.0) * axis) * run.truth[0]
    reason = "converging: a prior no single frame confirmed, contradicted by its first update"
    prior = Prior(wrong, prior_covariance(np.radians(10.0)), bias=np.zeros(3))
    track = solve_with(estimator(), run.gyro, run.t, measurements, prior)
    assert track.reason[0] == reason
    assert not track.valid[:first].any()
    assert track.diagnostics["restarts"][first] == 1
    assert track.valid[first:].any()
    assert integrity_share(track, run) == 0.0
    right = solve_with(
        estimator(),
        run.gyro,
        run.t,
        measurements,
        dataclasses.replace(prior, attitude=run.truth[0]),
    )
    assert not any(str(r) == reason for r in right.reason)
