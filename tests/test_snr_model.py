"""SNR model of Liu et al. 2023 (eqs. 1-14): one definition, numpy = CasADi, AD Jacobians, CRB."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from attopt.formulations.conventions import attitude_error
from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.gain_patterns import LIU2023_HELIX
from attopt.formulations.snr_model import (
    cramer_rao_bound,
    fisher_information,
    increment_matrix,
    line_of_sight,
    observation_mask,
    predict_snr,
    snr_db,
    snr_function,
    snr_jacobian_function,
    unobservable_directions,
)
from tests.strategies import attitudes
from tests.test_gain_patterns import PATTERNS

TRUTH = Rotation.from_euler("xyz", [20, -35, 110], degrees=True)
TILT = math.radians(50.77)  # Liu et al. 2023 eq. 64 mounting angle, used here as a tilt from nadir
ANTENNAS = np.array([[math.sin(TILT), 0.0, math.cos(TILT)], [-math.sin(TILT), 0.0, math.cos(TILT)]])


def _directions_at(boresight: np.ndarray, alpha: np.ndarray, azimuth: np.ndarray) -> np.ndarray:
    """Unit vectors at angles ``alpha`` from the unit ``boresight`` rows."""
    helper = np.where(np.abs(boresight[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]])
    u = np.cross(boresight, helper)
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    w = np.cross(boresight, u)
    radial = np.cos(azimuth)[:, None] * u + np.sin(azimuth)[:, None] * w
    return np.cos(alpha)[:, None] * boresight + np.sin(alpha)[:, None] * radial


def _scenario(rng, attitude, pattern, m, antennas=ANTENNAS, max_fraction=0.95):
    """Observations inside the main lobe: (los_orbit, boresight rows, p0, noise)."""
    boresight = antennas[rng.integers(len(antennas), size=m)]
    alpha = rng.uniform(0, max_fraction, m) * pattern.max_off_boresight_rad
    body = _directions_at(boresight, alpha, rng.uniform(0, 2 * np.pi, m))
    los = attitude.inv().apply(body) * rng.uniform(0.5, 3.0, (m, 1))  # not unit on purpose
    return los, boresight, rng.uniform(-140, -120, m), rng.uniform(-139, -136)


def _casadi_snr(pattern, v, attitude_ref, los, boresight, p0, noise):
    f = snr_function(pattern, len(los))
    return f(v, attitude_ref, los, boresight, p0, noise).full().ravel()


def test_line_of_sight_points_from_satellite_to_aircraft():
    # Orbit frame: z_o is nadir.  An aircraft below the satellite is seen along +z_o,
    # on the boresight of a nadir antenna (Liu et al. 2023 eq. 9 with the sign of eq. 3's text).
    los, distance = line_of_sight([0.0, 0.0, 0.0], [0.0, 0.0, 600.0])
    np.testing.assert_array_equal(los, [0.0, 0.0, 1.0])
    assert distance == 600.0
    snr = snr_db(np.eye(3), los[None], [[0.0, 0.0, 1.0]], -130.0, -137.0, LIU2023_HELIX)
    assert snr[0] == pytest.approx(LIU2023_HELIX.peak_gain_dbi + 7.0)
    with pytest.raises(InvalidObservationError):
        line_of_sight([1.0, 2.0, 3.0], [1.0, 2.0, 3.0])


@settings(max_examples=30, deadline=None)
@given(v=st.lists(st.floats(-3.0, 3.0), min_size=3, max_size=3))
def test_increment_matrix_is_scipy_mrp_of_a_quarter(v):
    v = np.asarray(v)
    expected = Rotation.from_mrp(v / 4).as_matrix()
    np.testing.assert_allclose(increment_matrix(v), expected, atol=1e-14)
    symbol = ca.SX.sym("v", 3)
    casadi_matrix = ca.Function("c", [symbol], [increment_matrix(symbol)])(v).full()
    np.testing.assert_allclose(casadi_matrix, expected, atol=1e-14)


@settings(max_examples=30, deadline=None)
@given(reference=attitudes(), v=st.lists(st.floats(-0.1, 0.1), min_size=3, max_size=3))
def test_increment_is_body_frame_error_vector_to_first_order(reference, v):
    # Error of C(v) A_ref relative to A_ref (docs/conventions.md) is the rotation
    # vector 4 arctan(|v|/4) v/|v| = v - |v|^2 v / 48 + ...
    v = np.asarray(v)
    error = attitude_error(
        Rotation.from_matrix(increment_matrix(v) @ reference.as_matrix()), reference
    )
    norm = np.linalg.norm(v)
    exact = 4 * np.arctan(norm / 4) * v / norm if norm > 0 else np.zeros(3)
    np.testing.assert_allclose(error, exact, atol=1e-13)
    assert np.linalg.norm(error - v) <= norm**3 / 48 + 1e-13


@settings(max_examples=40, deadline=None)
@given(
    truth=attitudes(),
    name=st.sampled_from(sorted(PATTERNS)),
    m=st.integers(1, 20),
    seed=st.integers(0, 2**32 - 1),
    v_scale=st.sampled_from([0.0, 0.01]),
)
def test_numpy_and_casadi_evaluations_agree(truth, name, m, seed, v_scale):
    pattern = PATTERNS[name]
    rng = np.random.default_rng(seed)
    los, boresight, p0, noise = _scenario(rng, truth, pattern, m, max_fraction=0.9)
    v = v_scale * rng.normal(size=3)
    attitude = increment_matrix(v) @ truth.as_matrix()
    numeric = snr_db(attitude, los, boresight, p0, noise, pattern)
    symbolic = _casadi_snr(pattern, v, truth.as_matrix(), los, boresight, p0, noise)
    np.testing.assert_allclose(numeric, symbolic, rtol=0, atol=1e-12)


def test_snr_db_accepts_mx_symbols():
    pattern = PATTERNS["tabulated"]
    los, boresight, p0, noise = _scenario(np.random.default_rng(1), TRUTH, pattern, 4)
    a = ca.MX.sym("a", 3, 3)
    f = ca.Function("f", [a], [snr_db(a, ca.DM(los), ca.DM(boresight), p0, noise, pattern)])
    np.testing.assert_allclose(
        f(TRUTH.as_matrix()).full().ravel(),
        snr_db(TRUTH.as_matrix(), los, boresight, p0, noise, pattern),
        atol=1e-12,
    )


def test_vectorised_numpy_matches_epoch_by_epoch():
    rng = np.random.default_rng(2)
    truths = Rotation.random(5, random_state=3)
    pattern = PATTERNS["parabolic"]
    scenes = [_scenario(rng, truths[k], pattern, 7) for k in range(5)]
    los, boresight, p0, noise = (np.stack(x) for x in zip(*scenes, strict=True))
    batch = snr_db(truths.as_matrix(), los, boresight, p0, noise[:, None], pattern)
    assert batch.shape == (5, 7)
    for k in range(5):
        single = snr_db(truths[k].as_matrix(), los[k], boresight[k], p0[k], noise[k], pattern)
        np.testing.assert_array_equal(batch[k], single)


def _central_difference(pattern, v, attitude_ref, los, boresight, p0, noise, h=1e-6):
    columns = []
    for k in range(3):
        step = np.zeros(3)
        step[k] = h
        plus = _casadi_snr(pattern, v + step, attitude_ref, los, boresight, p0, noise)
        minus = _casadi_snr(pattern, v - step, attitude_ref, los, boresight, p0, noise)
        columns.append((plus - minus) / (2 * h))
    return np.stack(columns, axis=1)


def _at_angles(alpha, antennas=ANTENNAS):
    """Observations at given off-boresight angles of alternating antennas (truth attitude)."""
    m = len(alpha)
    boresight = antennas[np.arange(m) % len(antennas)]
    body = _directions_at(boresight, np.asarray(alpha), np.linspace(0.3, 5.0, m))
    return TRUTH.inv().apply(body), boresight, np.full(m, -130.0), -137.0


@pytest.mark.parametrize("name", sorted(PATTERNS))
@pytest.mark.parametrize(
    "where", ["boresight", "1e-8 rad", "generic", "near lobe edge", "away from v=0"]
)
def test_ad_jacobian_matches_central_differences(name, where):
    pattern = PATTERNS[name]
    edge = pattern.max_off_boresight_rad
    alpha = {
        "boresight": [0.0, 0.0],
        "1e-8 rad": [1e-8, 1e-8],
        "generic": [0.1, 0.3, 0.5, 0.2],
        "near lobe edge": [edge - 2e-3, edge - 1e-3],
        "away from v=0": [0.1, 0.3, 0.5, 0.2],
    }[where]
    v = np.array([0.02, -0.03, 0.01]) if where == "away from v=0" else np.zeros(3)
    los, boresight, p0, noise = _at_angles(alpha)
    args = (v, TRUTH.as_matrix(), los, boresight, p0, noise)
    snr, jac = snr_jacobian_function(pattern, len(los))(*args)
    jac = jac.full()
    assert np.all(np.isfinite(jac))
    np.testing.assert_allclose(jac, _central_difference(pattern, *args), rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(snr.full().ravel(), _casadi_snr(pattern, *args), atol=0)
    if where == "boresight":
        # A symmetric main lobe is flat on its axis: the gradient vanishes there.
        np.testing.assert_allclose(jac, 0.0, atol=1e-12)


@pytest.mark.parametrize("name", sorted(PATTERNS))
def test_predict_snr_jacobian_is_with_respect_to_body_rotation_vector(name):
    pattern = PATTERNS[name]
    los, boresight, p0, noise = _scenario(
        np.random.default_rng(4), TRUTH, pattern, 6, max_fraction=0.8
    )
    snr, jac = predict_snr(TRUTH, los, boresight, p0, noise, pattern)
    h = 1e-6
    numeric = np.empty_like(jac)
    for k in range(3):
        delta = np.zeros(3)
        delta[k] = h
        plus = snr_db(
            (Rotation.from_rotvec(delta) * TRUTH).as_matrix(), los, boresight, p0, noise, pattern
        )
        minus = snr_db(
            (Rotation.from_rotvec(-delta) * TRUTH).as_matrix(), los, boresight, p0, noise, pattern
        )
        numeric[:, k] = (plus - minus) / (2 * h)
    np.testing.assert_allclose(jac, numeric, rtol=1e-6, atol=1e-7)
    np.testing.assert_allclose(snr, snr_db(TRUTH.as_matrix(), los, boresight, p0, noise, pattern))


def test_predict_snr_batches_epochs():
    rng = np.random.default_rng(5)
    truths = Rotation.random(4, random_state=6)
    pattern = LIU2023_HELIX
    scenes = [_scenario(rng, truths[k], pattern, 5) for k in range(4)]
    los, boresight, p0, noise = (np.stack(x) for x in zip(*scenes, strict=True))
    snr, jac = predict_snr(truths, los, boresight, p0, noise[:, None], pattern)
    assert snr.shape == (4, 5) and jac.shape == (4, 5, 3)
    empty = predict_snr(truths, los[:, :0], boresight[:, :0], p0[:, :0], 0.0, pattern)
    assert empty[0].shape == (4, 0) and empty[1].shape == (4, 0, 3)
    for k in range(4):
        single = predict_snr(truths[k], los[k], boresight[k], p0[k], noise[k], pattern)
        np.testing.assert_allclose(snr[k], single[0], atol=1e-12)
        np.testing.assert_allclose(jac[k], single[1], atol=1e-12)


@pytest.mark.parametrize("name", sorted(PATTERNS))
def test_noise_free_measurements_have_zero_residual_at_the_truth(name):
    pattern = PATTERNS[name]
    los, boresight, p0, noise = _scenario(np.random.default_rng(7), TRUTH, pattern, 12)
    measured = snr_db(TRUTH.as_matrix(), los, boresight, p0, noise, pattern)
    predicted, _ = predict_snr(TRUTH, los, boresight, p0, noise, pattern)
    np.testing.assert_allclose(measured - predicted, 0.0, atol=1e-12)
    at_truth = _casadi_snr(pattern, np.zeros(3), TRUTH.as_matrix(), los, boresight, p0, noise)
    np.testing.assert_allclose(measured - at_truth, 0.0, atol=1e-12)
    off = _casadi_snr(pattern, [0.0, 0.02, 0.0], TRUTH.as_matrix(), los, boresight, p0, noise)
    assert np.abs(measured - off).max() > 1e-3


def _crb_for(antennas, m=30, seed=8):
    los, boresight, p0, noise = _scenario(
        np.random.default_rng(seed), TRUTH, LIU2023_HELIX, m, antennas=antennas
    )
    _, jac = predict_snr(TRUTH, los, boresight, p0, noise, LIU2023_HELIX)
    fisher = fisher_information(jac, sigma_db=1.0)
    return fisher, cramer_rao_bound(fisher)


def test_crb_is_infinite_about_the_boresight_of_a_single_antenna():
    # Liu et al. 2023 sec. 3.1: the gain is symmetric about the boresight, so one antenna
    # cannot see a rotation about it.  Nadir boresight = body z.
    fisher, crb = _crb_for(np.array([[0.0, 0.0, 1.0]]))
    assert fisher[2, 2] == pytest.approx(0.0, abs=1e-10 * np.trace(fisher))
    assert crb[2, 2] == np.inf
    assert np.all(np.isfinite(crb[:2, :2])) and np.all(np.diag(crb)[:2] > 0)
    # Tilted boresight in the x-z plane: the unobservable rotation moves x and z.
    fisher, crb = _crb_for(ANTENNAS[:1])
    assert ANTENNAS[0] @ fisher @ ANTENNAS[0] == pytest.approx(0.0, abs=1e-10 * np.trace(fisher))
    assert crb[0, 0] == np.inf and crb[2, 2] == np.inf
    assert np.isfinite(crb[1, 1])
    assert np.sign(crb[0, 2]) == np.sign(ANTENNAS[0, 0] * ANTENNAS[0, 2])


def test_unobservable_direction_of_a_single_antenna_is_its_boresight():
    fisher, crb = _crb_for(ANTENNAS[:1])
    count, direction = unobservable_directions(fisher)
    assert count == 1
    np.testing.assert_allclose(abs(direction @ ANTENNAS[0]), 1.0, atol=1e-9)
    # the bound is infinite exactly on the body axes the boresight has a component on
    np.testing.assert_array_equal(np.isinf(np.diag(crb)), np.abs(direction) > 1e-9)
    count, direction = unobservable_directions(_crb_for(ANTENNAS)[0])
    assert count == 0 and np.isnan(direction).all()
    count, direction = unobservable_directions(np.zeros((2, 3, 3)))
    assert count.tolist() == [3, 3] and np.isnan(direction).all()


def test_crb_is_finite_with_two_antennas_and_equals_the_inverse():
    fisher, crb = _crb_for(ANTENNAS)
    assert np.all(np.isfinite(crb))
    np.testing.assert_allclose(crb, np.linalg.inv(fisher), rtol=1e-10)
    print(f"two-antenna CRB sigmas (deg): {np.degrees(np.sqrt(np.diag(crb)))}")


def test_crb_of_no_information_is_infinite_on_the_diagonal():
    crb = cramer_rao_bound(np.zeros((2, 3, 3)))
    assert np.all(np.diagonal(crb, axis1=-2, axis2=-1) == np.inf)


def test_fisher_information_weights_and_mask():
    jac = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0], [np.nan, np.nan, np.nan]])
    fisher = fisher_information(jac, sigma_db=np.array([0.5, 1.0, 1.0]), mask=[True, True, False])
    np.testing.assert_array_equal(fisher, np.diag([4.0, 4.0, 0.0]))


@pytest.mark.parametrize(
    ("corrupt", "message"),
    [
        (lambda los, b: los.__setitem__((1, 0), np.nan), "line of sight"),
        (lambda los, b: los.__setitem__(1, 0.0), "line of sight"),
        (lambda los, b: b.__setitem__(1, np.inf), "boresight"),
        (lambda los, b: los.__setitem__(1, -los[1]), "main lobe"),
    ],
)
def test_invalid_observations_raise_and_are_masked(corrupt, message):
    los, boresight, p0, noise = _scenario(np.random.default_rng(9), TRUTH, LIU2023_HELIX, 4)
    clean = predict_snr(TRUTH, los, boresight, p0, noise, LIU2023_HELIX)
    corrupt(los, boresight)
    with pytest.raises(InvalidObservationError, match=message):
        snr_db(TRUTH.as_matrix(), los, boresight, p0, noise, LIU2023_HELIX)
    with pytest.raises(InvalidObservationError, match=message):
        predict_snr(TRUTH, los, boresight, p0, noise, LIU2023_HELIX)
    mask = observation_mask(TRUTH.as_matrix(), los, boresight, LIU2023_HELIX)
    np.testing.assert_array_equal(mask, [True, False, True, True])
    snr, jac = predict_snr(TRUTH, los, boresight, p0, noise, LIU2023_HELIX, mask=mask)
    assert np.all(np.isnan(snr[1])) and np.all(np.isnan(jac[1]))
    np.testing.assert_allclose(snr[mask], clean[0][mask], atol=1e-12)
    np.testing.assert_allclose(jac[mask], clean[1][mask], atol=1e-12)


def test_invalid_attitude_power_and_shapes_raise():
    los, boresight, p0, noise = _scenario(np.random.default_rng(10), TRUTH, LIU2023_HELIX, 3)
    with pytest.raises(InvalidObservationError, match="attitude"):
        snr_db(2 * np.eye(3), los, boresight, p0, noise, LIU2023_HELIX)
    with pytest.raises(InvalidObservationError, match="attitude"):
        snr_db(-TRUTH.as_matrix(), los, boresight, p0, noise, LIU2023_HELIX)
    with pytest.raises(InvalidObservationError, match="power"):
        snr_db(TRUTH.as_matrix(), los, boresight, p0, np.nan, LIU2023_HELIX)
    with pytest.raises(InvalidObservationError, match="shape"):
        snr_db(TRUTH.as_matrix(), los[:, :2], boresight, p0, noise, LIU2023_HELIX)


def test_observation_mask_at_the_lobe_edge():
    edge = LIU2023_HELIX.max_off_boresight_rad
    los, boresight, _, _ = _at_angles([edge - 1e-9, edge + 1e-9, 0.0], ANTENNAS[:1])
    mask = observation_mask(TRUTH.as_matrix(), los, boresight, LIU2023_HELIX)
    np.testing.assert_array_equal(mask, [True, False, True])
