"""Bad input raises a specific error (single epoch) or flags the epoch (batch)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from attopt.formulations.errors import InvalidObservationError, UnobservableError
from attopt.formulations.vector_observations import PARALLEL_TOLERANCE
from attopt.solvers.wahba import ESTIMATORS, NUMPY_REFERENCES

SOLVERS = [*ESTIMATORS, *NUMPY_REFERENCES]
"""Every solver, and the numpy reference of each compiled one (``solvers/wahba/compiled.py``)."""
BY_NAME = {s.name: s for s in ESTIMATORS}
TRUTH = Rotation.from_rotvec([0.1, 0.2, -0.3])
REF = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
BODY = TRUTH.apply(REF)
W = np.ones(3)


def _with(array, index, value):
    out = np.array(array, dtype=float)
    out[index] = value
    return out


BAD_SINGLE = {
    "one observation": (BODY[:1], REF[:1], W[:1], UnobservableError, "fewer than two"),
    "no observation": (BODY[:0], REF[:0], W[:0], UnobservableError, "fewer than two"),
    "parallel body": (
        np.array([[1.0, 0, 0], [1.0, 1e-5, 0]]),
        REF[:2],
        W[:2],
        UnobservableError,
        "body vectors are (anti)parallel",
    ),
    "antiparallel": (
        np.array([[1.0, 0, 0], [-1.0, 0, 0]]),
        np.array([[0, 1.0, 0], [0, -1.0, 0]]),
        W[:2],
        UnobservableError,
        "(anti)parallel",
    ),
    "parallel reference": (
        BODY[:2],
        np.array([[0, 0, 1.0], [0, 0, 2.0]]),
        W[:2],
        UnobservableError,
        "reference vectors are (anti)parallel",
    ),
    "NaN component": (_with(BODY, (1, 2), np.nan), REF, W, InvalidObservationError, "NaN, inf"),
    "inf component": (BODY, _with(REF, (0, 0), np.inf), W, InvalidObservationError, "NaN, inf"),
    "zero-length": (_with(BODY, 2, 0.0), REF, W, InvalidObservationError, "zero-length"),
    "zero weight": (BODY, REF, _with(W, 0, 0.0), InvalidObservationError, "weights"),
    "negative weight": (BODY, REF, _with(W, 1, -1.0), InvalidObservationError, "weights"),
    "NaN weight": (BODY, REF, _with(W, 2, np.nan), InvalidObservationError, "weights"),
}


@pytest.mark.parametrize("case", BAD_SINGLE)
@pytest.mark.parametrize("solver", SOLVERS, ids=lambda s: s.label)
def test_bad_single_epoch_raises_specific_error(solver, case):
    body, ref, w, error, text = BAD_SINGLE[case]
    with pytest.raises(error, match=text.replace("(", r"\(").replace(")", r"\)")):
        solver.solve_vectors(body, ref, w)


@pytest.mark.parametrize("solver", SOLVERS, ids=lambda s: s.label)
@pytest.mark.parametrize(
    ("body", "ref", "w", "text"),
    [
        (BODY[:, :2], REF[:, :2], W, "shape"),
        (BODY, REF[:2], W, "must match"),
        (BODY, REF, W[:2], "one entry per observation"),
    ],
)
def test_malformed_shapes_raise(solver, body, ref, w, text):
    with pytest.raises(InvalidObservationError, match=text):
        solver.solve_vectors(body, ref, w)


@pytest.mark.parametrize("solver", SOLVERS, ids=lambda s: s.label)
def test_batch_flags_bad_epochs_and_solves_the_rest(solver):
    body = np.stack([BODY, _with(BODY, (1, 2), np.nan), BODY, BODY])
    ref = np.stack([REF] * 4)
    w = np.stack([W, W, _with(W, 0, 0.0), W])
    present = np.ones((4, 3), dtype=bool)
    present[3, 1:] = False  # only one observation left at epoch 3
    batch = solver.solve_batch(body, ref, w, present)
    assert batch.valid.tolist() == [True, False, False, False]
    assert "NaN" in batch.reason[1] and "weights" in batch.reason[2]
    assert "fewer than two" in batch.reason[3]
    assert np.isnan(batch.quaternion[1:]).all() and np.isnan(batch.covariance[1:]).all()
    assert np.linalg.norm((batch.epoch(0).attitude * TRUTH.inv()).as_rotvec()) < 1e-10
    with pytest.raises(UnobservableError):
        batch.epoch(3).raise_if_invalid()


@pytest.mark.parametrize("solver", SOLVERS, ids=lambda s: s.label)
def test_absent_observation_is_ignored_not_used(solver):
    """A masked-out observation may hold garbage (NaN) without affecting the result."""
    body = _with(BODY, 2, np.nan)
    batch = solver.solve_batch(body[None], REF[None], W[None], np.array([[True, True, False]]))
    assert batch.valid[0]
    assert np.linalg.norm((batch.epoch(0).attitude * TRUTH.inv()).as_rotvec()) < 1e-10


def test_parallel_tolerance_is_the_documented_one():
    angle = 0.5 * PARALLEL_TOLERANCE
    body = np.array([[1.0, 0, 0], [np.cos(angle), np.sin(angle), 0]])
    with pytest.raises(UnobservableError):
        BY_NAME["q_method"].solve_vectors(body, REF[:2], W[:2])
    angle = 2.0 * PARALLEL_TOLERANCE
    body = np.array([[1.0, 0, 0], [np.cos(angle), np.sin(angle), 0]])
    ref = body.copy()
    assert BY_NAME["q_method"].solve_vectors(body, ref, W[:2]).loss < 1e-12


def test_non_unit_vectors_are_normalised():
    solution = BY_NAME["svd"].solve_vectors(BODY * [[50e3], [2.0], [0.1]], REF * 7.0, W)
    assert np.linalg.norm((solution.attitude * TRUTH.inv()).as_rotvec()) < 1e-12
