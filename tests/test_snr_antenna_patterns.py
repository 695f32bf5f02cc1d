"""Antennas with different gain patterns (one pattern per antenna) through the SNR model,
the single-frame solvers, the filters and the smoothers (Liu et al. 2023 eqs. 4, 13, 19, 22).

The reference is each antenna evaluated alone with its own pattern, the single-pattern
path the rest of the SNR tests pin; the per-antenna path must agree with it, stay finite
where another antenna's pattern is undefined, and reduce to it exactly when the antennas
share one pattern.
"""

from __future__ import annotations

import math
from dataclasses import replace

import casadi as ca
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from attopt.formulations.conventions import attitude_error, attitude_from_euler321
from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.gain_patterns import (
    LIU2023_HELIX,
    AntennaPatterns,
    ParabolicPattern,
    shared_pattern,
)
from attopt.formulations.link_budget import LinkBudget
from attopt.formulations.passes import Pass
from attopt.formulations.snapshot import Snapshot
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.formulations.snr_model import (
    observation_mask,
    predict_snr,
    snr_db,
    snr_function,
    snr_jacobian_function,
)
from attopt.formulations.snr_problem import SnrEpoch
from attopt.solvers.registry import estimator
from attopt.solvers.snr.fit import fit_at
from tests.contract_cases import _gyro_draw
from tests.test_gain_patterns import PARABOLIC, TABULATED
from tests.test_snr_model import _directions_at

TILT = math.radians(50.77)
BORESIGHTS = np.array(
    [
        [0.0, math.sin(TILT), math.cos(TILT)],
        [0.0, -math.sin(TILT), math.cos(TILT)],
        [math.sin(TILT), 0.0, math.cos(TILT)],
    ]
)
"""Two cross-track antennas (Liu et al. 2023 Fig. 7) and a third tilted along-track."""
PATTERNS = (LIU2023_HELIX, PARABOLIC, TABULATED)
"""Antenna ``i`` has ``PATTERNS[i]``."""
BUDGET = LinkBudget()
TRUTH = attitude_from_euler321(*np.radians([25.0, -6.0, 8.0]))
SNAPSHOT_METHODS = ("deterministic", "nlse", "nlp", "nlp_truncated", "map_nlp")
PASS_METHODS = ("mekf", "usque", "rts", "fg_online", "fg_batch", "fg_batch_offsets")
PASS_TOLERANCE_RAD = {"usque": 1e-3}
"""USQUE's sigma points spread the 1 deg prior through the nonlinear SNR model, so even a
noise-free update is not exact: 2.1e-4 rad with three helices, 2.0e-4 with three patterns."""


def _geometry(rng, truth, per_antenna=(8, 8, 8), patterns=PATTERNS, fraction=0.9):
    """Observations inside each antenna's own main lobe: los, antenna, range (m), and the
    true SNR computed antenna by antenna with that antenna's pattern alone."""
    los, antenna, ranges, snr = [], [], [], []
    for a, count in enumerate(per_antenna):
        alpha = fraction * patterns[a].max_off_boresight_rad * np.sqrt(rng.uniform(0, 1, count))
        body = _directions_at(
            np.tile(BORESIGHTS[a], (count, 1)), alpha, rng.uniform(0, 2 * np.pi, count)
        )
        r = rng.uniform(1.0e6, 2.0e6, count)
        snr.append(
            snr_db(
                np.eye(3),
                body,
                BORESIGHTS[a],
                BUDGET.isotropic_power_dbw(r),
                BUDGET.noise_power_dbw,
                patterns[a],
            )
        )
        los.append(truth.inv().apply(body))
        antenna.append(np.full(count, a))
        ranges.append(r)
    return (np.concatenate(x) for x in (los, antenna, ranges, snr))


def _epoch(rng, truth=TRUTH, per_antenna=(8, 8, 8), patterns=PATTERNS, **kwargs) -> SnrEpoch:
    los, antenna, ranges, snr = _geometry(rng, truth, per_antenna, patterns)
    kwargs.setdefault("threshold_db", -np.inf)
    return SnrEpoch.from_ranges(snr, los, antenna, BORESIGHTS, ranges, patterns, BUDGET, **kwargs)


def _each_antenna_alone(epoch: SnrEpoch, attitude: Rotation) -> tuple[np.ndarray, np.ndarray]:
    """SNR and Jacobian of every observation from the single-pattern path, antenna by antenna."""
    snr, jac = np.empty(epoch.m), np.empty((epoch.m, 3))
    for a in range(epoch.n_antennas):
        rows = epoch.antenna == a
        snr[rows], jac[rows] = predict_snr(
            attitude,
            epoch.unit_los[rows],
            epoch.boresight_rows[rows],
            epoch.p0_dbw[rows],
            epoch.noise_dbw,
            epoch.pattern_of(a),
        )
    return snr, jac


def test_antenna_patterns_give_each_observation_its_antennas_gain():
    epoch = _epoch(np.random.default_rng(1))
    assert isinstance(epoch.pattern, AntennaPatterns)
    expected, expected_jac = _each_antenna_alone(epoch, TRUTH)
    np.testing.assert_allclose(expected, epoch.snr_db, atol=1e-12)  # noise-free epoch
    numpy = snr_db(
        TRUTH.as_matrix(),
        epoch.unit_los,
        epoch.boresight_rows,
        epoch.p0_dbw,
        epoch.noise_dbw,
        epoch.pattern,
        epoch.antenna,
    )
    np.testing.assert_allclose(numpy, expected, atol=1e-12)
    v = np.array([0.01, -0.02, 0.005])
    casadi = snr_function(epoch.pattern, epoch.m)(
        v,
        TRUTH.as_matrix(),
        epoch.unit_los,
        epoch.boresight_rows,
        epoch.p0_dbw,
        epoch.noise_dbw,
        epoch.antenna.astype(float),
    )
    moved = Rotation.from_mrp(v / 4.0) * TRUTH  # C(v) of increment_matrix
    np.testing.assert_allclose(
        casadi.full().ravel(), _each_antenna_alone(epoch, moved)[0], atol=1e-11
    )
    snr, jac = predict_snr(
        TRUTH,
        epoch.unit_los,
        epoch.boresight_rows,
        epoch.p0_dbw,
        epoch.noise_dbw,
        epoch.pattern,
        antenna=epoch.antenna,
    )
    np.testing.assert_allclose(snr, expected, atol=1e-12)
    np.testing.assert_allclose(jac, expected_jac, atol=1e-10)


def test_per_antenna_jacobian_is_finite_where_another_pattern_is_undefined():
    """A wide lobe sees an aircraft 91 deg off its boresight, where ``lg cos(alpha)`` of the
    cos^6 helix on the other antenna is NaN: values and AD Jacobian stay finite and match
    central differences."""
    wide = ParabolicPattern(10.0, math.radians(100.0), min_gain_dbi=0.0)  # lobe to 91.3 deg
    patterns = AntennaPatterns((LIU2023_HELIX, wide))
    boresight = BORESIGHTS[[0, 1, 1, 0]]
    alpha = np.radians([10.0, 91.0, 30.0, 35.0])
    los = TRUTH.inv().apply(_directions_at(boresight, alpha, np.linspace(0.4, 4.0, 4)))
    antenna = np.array([0.0, 1.0, 1.0, 0.0])
    args = (TRUTH.as_matrix(), los, boresight, np.full(4, -130.0), -137.0, antenna)
    snr, jac = snr_jacobian_function(patterns, 4)(np.zeros(3), *args)
    snr, jac = snr.full().ravel(), jac.full()
    assert np.isfinite(snr).all() and np.isfinite(jac).all()
    function = snr_function(patterns, 4)
    h = 1e-6
    numeric = np.stack(
        [
            (function(h * e, *args).full().ravel() - function(-h * e, *args).full().ravel())
            / (2 * h)
            for e in np.eye(3)
        ],
        axis=1,
    )
    np.testing.assert_allclose(jac, numeric, rtol=1e-6, atol=1e-7)
    alone = snr_db(TRUTH.as_matrix(), los[1:3], boresight[1:3], -130.0, -137.0, wide)
    np.testing.assert_allclose(snr[1:3], alone, atol=1e-12)
    with np.errstate(all="raise"):  # no pattern is evaluated outside its domain
        numpy = snr_db(*args[:-1], patterns, antenna.astype(int))
    np.testing.assert_allclose(numpy, snr, atol=1e-12)


def test_each_observation_is_masked_at_its_own_antennas_lobe_edge():
    patterns = AntennaPatterns((LIU2023_HELIX, PARABOLIC))
    helix_edge, parabolic_edge = (
        LIU2023_HELIX.max_off_boresight_rad,
        PARABOLIC.max_off_boresight_rad,
    )
    assert parabolic_edge < helix_edge
    # Between the two edges: inside the helix's lobe, outside the parabolic one's.
    between = 0.5 * (helix_edge + parabolic_edge)
    antenna = np.array([0, 1, 1, 0])
    alpha = np.array([between, between, parabolic_edge - 1e-9, helix_edge + 1e-9])
    boresight = BORESIGHTS[antenna]
    los = TRUTH.inv().apply(_directions_at(boresight, alpha, np.linspace(0.3, 5.0, 4)))
    mask = observation_mask(TRUTH.as_matrix(), los, boresight, patterns, antenna)
    np.testing.assert_array_equal(mask, [True, False, True, False])
    with pytest.raises(InvalidObservationError, match="main lobe of the receiving antenna"):
        snr_db(TRUTH.as_matrix(), los, boresight, 0.0, 0.0, patterns, antenna)


def test_antennas_that_share_a_pattern_are_the_single_pattern_epoch_bitwise():
    rng = np.random.default_rng(2)
    los, antenna, ranges, snr = _geometry(rng, TRUTH, (6, 6, 6), (LIU2023_HELIX,) * 3)
    noisy = snr + rng.standard_normal(snr.size)
    single, shared = (
        SnrEpoch.from_ranges(noisy, los, antenna, BORESIGHTS, ranges, pattern, BUDGET)
        for pattern in (LIU2023_HELIX, [LIU2023_HELIX] * 3)
    )
    assert shared.pattern is LIU2023_HELIX and shared.pattern_antenna is None
    assert shared_pattern([PARABOLIC, replace(PARABOLIC)]) == PARABOLIC
    for name in ("deterministic", "nlse", "nlp", "nlp_truncated"):
        one, other = (
            estimator(name).solve(Snapshot.of(SnrMeasurement(e))) for e in (single, shared)
        )
        np.testing.assert_array_equal(one.attitude.as_quat(), other.attitude.as_quat())
        np.testing.assert_array_equal(one.covariance, other.covariance)


def test_a_pattern_count_other_than_the_antenna_count_is_rejected():
    los, antenna, ranges, snr = _geometry(np.random.default_rng(3), TRUTH, (4, 4, 4))
    with pytest.raises(InvalidObservationError, match="one per antenna \\(3\\), got 2"):
        SnrEpoch.from_ranges(snr, los, antenna, BORESIGHTS, ranges, PATTERNS[:2], BUDGET)


@pytest.mark.parametrize("name", SNAPSHOT_METHODS)
def test_noise_free_recovery_with_a_pattern_per_antenna(name):
    epoch = _epoch(np.random.default_rng(4))
    prior = Rotation.from_rotvec(np.radians([2.0, -1.5, 2.5])) * TRUTH
    solution = estimator(name).solve(Snapshot.of(SnrMeasurement(epoch)), prior=prior)
    assert np.linalg.norm(attitude_error(solution.attitude, TRUTH)) < 1e-8


def test_covariance_is_eq22_of_the_antennas_evaluated_alone():
    epoch = _epoch(np.random.default_rng(5))
    _, jac = _each_antenna_alone(epoch, TRUTH)
    expected = np.linalg.inv(jac.T @ jac)  # sigma = 1 dB
    np.testing.assert_allclose(fit_at(epoch, TRUTH).covariance, expected, rtol=1e-9)


@pytest.mark.parametrize("truncated", [False, True])
def test_snr_measurement_predictions_agree_with_its_symbolic_model(truncated):
    epoch = _epoch(np.random.default_rng(6), threshold_db=6.0)
    measurement = SnrMeasurement(epoch, truncated=truncated)
    attitudes = Rotation.concatenate([TRUTH, Rotation.from_rotvec([0.01, 0.0, -0.02]) * TRUTH])
    values, jac = measurement.predict(attitudes)
    quick, _ = measurement.predict(attitudes, jacobian=False)
    symbolic, symbolic_jac = measurement.symbolic().evaluate(attitudes)
    np.testing.assert_allclose(values, symbolic, atol=1e-12)
    np.testing.assert_allclose(jac, symbolic_jac, atol=1e-10)
    np.testing.assert_allclose(quick, values, atol=1e-12)
    if not truncated:
        np.testing.assert_allclose(values[0], _each_antenna_alone(epoch, TRUTH)[0], atol=1e-12)


def _mixed_pass(seed: int) -> tuple[Pass, Rotation]:
    """The contract checks' noise-free gyro pass with SNR snapshots of three antennas with
    three patterns (transmitters numbered for the power-offset smoother)."""
    drawn = _gyro_draw(seed, False)
    rng = np.random.default_rng(seed)
    snapshots = []
    for k in range(len(drawn.problem)):
        epoch = _epoch(rng, drawn.truth[k], (5, 5, 5))
        snapshots.append(
            Snapshot.of(SnrMeasurement(replace(epoch, transmitter=np.arange(epoch.m))))
        )
    pass_ = drawn.problem
    return Pass(pass_.t, snapshots, pass_.gyro, pass_.prior), drawn.truth


@pytest.mark.parametrize("name", PASS_METHODS)
def test_filters_and_smoothers_recover_the_truth_with_a_pattern_per_antenna(name):
    pass_, truth = _mixed_pass(11)
    track = estimator(name).solve(pass_)
    assert track.valid.all()
    error = np.linalg.norm(attitude_error(track.attitude(), truth), axis=1)
    assert error.max() < PASS_TOLERANCE_RAD.get(name, 1e-6)


def test_symbolic_antenna_input_accepts_mx():
    patterns = AntennaPatterns(PATTERNS)
    epoch = _epoch(np.random.default_rng(7), per_antenna=(2, 2, 2))
    a = ca.MX.sym("a", 3, 3)
    expression = snr_db(
        a,
        ca.DM(epoch.unit_los),
        ca.DM(epoch.boresight_rows),
        epoch.p0_dbw,
        epoch.noise_dbw,
        patterns,
        ca.DM(epoch.antenna.astype(float)),
    )
    value = ca.Function("f", [a], [expression])(TRUTH.as_matrix()).full().ravel()
    np.testing.assert_allclose(value, _each_antenna_alone(epoch, TRUTH)[0], atol=1e-12)
