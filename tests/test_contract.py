"""The contract checks every registered estimator passes (in the spirit of scikit-learn's
``parametrize_with_checks``), on the problems of ``tests/contract_cases.py``:

* every registered estimator has a case, and its declaration is complete;
* noise-free recovery: the truth to near machine precision on every axis the data see;
* bad input: a single solve raises a named error; a sequence flags the epoch with a
  reason and no attitude (snapshots); a pass without what the estimator needs raises;
  no estimate is ever reported valid with a non-finite attitude or covariance;
* a measurement type the estimator does not accept raises ``UnsupportedMeasurementError``;
* determinism: the same input gives the same bits;
* pickling (Dask ships estimators and results between processes);
* the claimed covariance matches Monte Carlo (mean NEES against the axes it bounds).

And one new measurement type, defined here and nowhere else, runs through every estimator
that accepts generic measurements: the proof that a new measurement lives in one file.
"""

from __future__ import annotations

import pickle
from typing import Any

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from attopt import (
    ESTIMATORS,
    AttitudeMeasurement,
    AttoptError,
    Pass,
    PassEstimator,
    Snapshot,
    SnapshotEstimator,
    SymbolicModel,
    Track,
    UnsupportedMeasurementError,
    estimators,
)
from attopt.formulations.symbolic import CASADI
from attopt.solvers.results import attitude_errors, normalised_errors
from tests.contract_cases import CASES, DYNAMICS_VECTORS, GYRO_VECTORS, Case

NAMES = list(ESTIMATORS)


NOISE_FREE_TOLERANCE = {"usque": 1e-6, "usque_offsets": 1e-4}
"""The unscented transform's mean of a nonlinear model is not the model at the mean: from
the truth, noise-free, USQUE keeps an error of order the posterior variance times the
model's curvature (measured 3e-8 rad on unit vectors, 6e-7 rad on the Earth-sensor
angles below; a thousandth of its own sigma; 3.4e-5 rad on the SNR patterns of the
offsets' case, whose sigmas are 0.8-1.1 deg)."""


def _track(name: str, problem: Snapshot | Pass, truth: Rotation | None = None) -> Track:
    estimator = ESTIMATORS[name]
    if isinstance(problem, Snapshot):
        prior = truth if truth is not None and CASES[name].reference_prior else None
        return estimator.solve_sequence([problem], prior)
    return estimator.solve(problem)


def _observable_error(track: Track, truth: Rotation) -> np.ndarray:
    """Errors (rad) of the valid epochs on the axes their covariance bounds."""
    error = attitude_errors(track.quaternion, truth)
    error[~np.isfinite(track.sigma)] = np.nan
    return error[track.valid]


def test_every_registered_estimator_is_declared_and_has_a_case() -> None:
    assert set(CASES) == set(NAMES)
    assert set(estimators("snapshot")) | set(estimators("pass")) == set(NAMES)
    for name, estimator in ESTIMATORS.items():
        assert estimator.name == name and estimator.description
        assert estimator.accepts and all(
            issubclass(a, AttitudeMeasurement) for a in estimator.accepts
        )
        assert isinstance(estimator, SnapshotEstimator | PassEstimator)
        if isinstance(estimator, PassEstimator):
            assert set(estimator.starts_from) <= set(NAMES)


@pytest.mark.parametrize("name", NAMES)
def test_noise_free_input_recovers_the_truth(name: str) -> None:
    case = CASES[name]
    drawn = case.draw(11, False)
    track = _track(name, drawn.problem, drawn.truth)
    assert track.valid.mean() >= 0.9, track.reason[~track.valid][:3]
    error = _observable_error(track, drawn.truth)
    assert np.isfinite(error).any()
    assert np.nanmax(np.abs(error)) < NOISE_FREE_TOLERANCE.get(name, case.tolerance)


@pytest.mark.parametrize("name", NAMES)
def test_bad_input_raises_or_is_flagged_never_a_silent_attitude(name: str) -> None:
    case, estimator = CASES[name], ESTIMATORS[name]
    broken = case.broken(12)
    if isinstance(broken, Snapshot):
        with pytest.raises(AttoptError):
            estimator.solve(broken)
        good = case.draw(13, False).problem
        track = estimator.solve_sequence([good, broken, None, Snapshot(()), good])
        assert track.valid.tolist() == [True, False, False, False, True]
        assert all(track.reason[1:4]) and np.isnan(track.quaternion[1:4]).all()
        assert all(issubclass(e, AttoptError) for e in track.error[1:4])
    else:
        with pytest.raises(AttoptError):
            estimator.solve(broken)
    drawn = case.draw(14, True)
    noisy = _track(name, drawn.problem, drawn.truth)
    assert np.isfinite(noisy.quaternion[noisy.valid]).all()
    assert not np.isnan(noisy.covariance[noisy.valid]).any()
    assert all(noisy.reason[~noisy.valid])


def _generic(name: str) -> bool:
    """Whether estimator ``name`` accepts any measurement type."""
    return any(a is AttitudeMeasurement for a in ESTIMATORS[name].accepts)


@pytest.mark.parametrize("name", [n for n in NAMES if not _generic(n)])
def test_an_unaccepted_measurement_type_raises(name: str) -> None:
    with pytest.raises(UnsupportedMeasurementError):
        _track(name, CASES[name].foreign(15))


@pytest.mark.parametrize("name", NAMES)
def test_deterministic_and_picklable(name: str) -> None:
    problem = CASES[name].draw(16, True).problem
    first = _track(name, problem)
    copy = pickle.loads(pickle.dumps(ESTIMATORS[name]))
    again = copy.solve_sequence([problem]) if isinstance(problem, Snapshot) else copy.solve(problem)
    shipped = pickle.loads(pickle.dumps(first))
    for track in (again, shipped):
        np.testing.assert_array_equal(track.quaternion, first.quaternion)
        np.testing.assert_array_equal(track.covariance, first.covariance)
        np.testing.assert_array_equal(track.valid, first.valid)


MONTE_CARLO_TRIALS = {"snapshot": 60, "pass": 12}


@pytest.mark.slow
@pytest.mark.parametrize("name", NAMES)
def test_claimed_covariance_matches_monte_carlo(name: str) -> None:
    """Mean NEES over the trials' valid epochs against its expectation, the number of axes
    the covariance bounds: within 4 standard errors for independent snapshots, and within
    [0.55, 1.45] of it for passes (their epochs' errors are correlated)."""
    case, estimator = CASES[name], ESTIMATORS[name]
    trials = MONTE_CARLO_TRIALS[estimator.kind]
    nees, dof = [], []
    for seed in range(trials):
        drawn = case.draw(1000 + seed, True)
        track = _track(name, drawn.problem, drawn.truth)
        error = attitude_errors(track.quaternion, drawn.truth)
        values = normalised_errors(error, track.covariance)[track.valid]
        nees.append(values)
        dof.append(np.isfinite(track.sigma[track.valid]).sum(axis=1))
    nees, dof = np.concatenate(nees), np.concatenate(dof)
    ratio = nees.mean() / dof.mean()
    if estimator.kind == "snapshot":
        spread = 4.0 * np.sqrt(2.0 / (nees.size * dof.mean()))
        assert abs(ratio - 1.0) < spread, ratio
    else:
        assert 0.55 < ratio < 1.45, ratio


def test_an_axis_the_data_cannot_see_is_nan_not_a_number() -> None:
    """One unit vector fixes two axes: the MAP NLP reports the estimate with an infinite
    variance about the vector, and every body axis that rotation moves is NaN in its
    sigmas and errors."""
    truth = Rotation.from_euler("xyz", [10.0, -20.0, 30.0], degrees=True)
    reference = np.array([[0.0, 0.6, 0.8]])
    snapshot = Snapshot.from_vectors(truth.apply(reference), reference, sigma=1e-3)
    solution = ESTIMATORS["map_nlp"].solve(snapshot)
    assert np.isinf(np.diagonal(solution.covariance)).all()
    row = solution.to_dataframe(Rotation.concatenate([truth]))
    columns = [f"{kind}_{a}_deg" for kind in ("sigma", "err") for a in "xyz"]
    assert row[columns].isna().all(axis=None)


# --- a new measurement type, written once, here ------------------------------------------------


def earth_sensor_model(attitude: Any, nadir: Any) -> Any:
    """Roll and pitch of the nadir direction ``n = A r`` seen by a body-fixed horizon sensor
    looking along body +z: ``roll = atan2(n_y, n_z)``, ``pitch = atan2(-n_x, n_z)``."""
    n = attitude @ nadir
    return CASADI.matrix([[CASADI.atan2(n[1], n[2])], [CASADI.atan2(-n[0], n[2])]])


class EarthSensor(AttitudeMeasurement):
    """Two angles of one reference direction: the whole new measurement type."""

    def __init__(self, angles: np.ndarray, nadir: np.ndarray, sigma: float) -> None:
        self.z = np.asarray(angles, dtype=float)
        self.nadir = np.asarray(nadir, dtype=float)
        self.noise_covariance = np.full(2, sigma**2)
        self.blocks = np.zeros(2, dtype=np.intp)

    def symbolic(self) -> SymbolicModel:
        return SymbolicModel(earth_sensor_model, (self.nadir,))


DIRECTIONS = np.array([[0.1, -0.2, 0.97], [0.6, 0.3, 0.74]])
"""Two directions the sensors see near their +z axis: together they fix the attitude."""


def _sensors(truth: Rotation, sigma: float = 1e-3) -> Snapshot:
    parts = []
    for direction in DIRECTIONS / np.linalg.norm(DIRECTIONS, axis=1, keepdims=True):
        n = truth.apply(direction)
        angles = np.array([np.arctan2(n[1], n[2]), np.arctan2(-n[0], n[2])])
        parts.append(EarthSensor(angles, direction, sigma))
    return Snapshot(tuple(parts))


GENERIC = [
    name for name in NAMES if any(a is AttitudeMeasurement for a in ESTIMATORS[name].accepts)
]


def test_the_new_type_reaches_every_generic_estimator() -> None:
    assert {"map_nlp", "mekf", "usque", "rts", "fg_online", "ekf_yang2014"} <= set(GENERIC)


@pytest.mark.parametrize("name", GENERIC)
def test_a_new_measurement_type_runs_through_every_generic_estimator(name: str) -> None:
    estimator = ESTIMATORS[name]
    if estimator.kind == "snapshot":
        truth = Rotation.from_euler("xyz", [5.0, -8.0, 30.0], degrees=True)
        track = estimator.solve_sequence([_sensors(truth)])
        truths = Rotation.concatenate([truth])
    else:
        case: Case = DYNAMICS_VECTORS if pass_dynamics(name) else GYRO_VECTORS
        drawn = case.draw(17, False)
        pass_ = drawn.problem
        snapshots = [_sensors(drawn.truth[k]) for k in range(len(pass_))]
        track = estimator.solve(Pass(pass_.t, snapshots, pass_.gyro, pass_.prior, pass_.dynamics))
        truths = drawn.truth
    assert track.valid.all()
    assert np.abs(attitude_errors(track.quaternion, truths)).max() < NOISE_FREE_TOLERANCE.get(
        name, 1e-8
    )


def pass_dynamics(name: str) -> bool:
    """Whether the pass estimator ``name`` runs on rigid-body dynamics (else on a gyro)."""
    return CASES[name] is DYNAMICS_VECTORS
