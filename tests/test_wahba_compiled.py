"""The compiled Wahba methods against their numpy references (``solvers/wahba/compiled.py``).

Both paths solve the same equations; they differ by round-off, which the problem's
conditioning amplifies: a Wahba attitude is determined to about ``eps lambda_0 / gap``
(``gap`` the eigen-gap of Davenport's ``K``), so the paths are held to
``ANGLE_FACTOR * eps * lambda_0 / gap`` (at most ``1e-14`` rad on well-conditioned epochs).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from attopt.formulations.conventions import attitude_error
from attopt.formulations.errors import ConvergenceError
from attopt.formulations.kernels import compiled_loops
from attopt.solvers.wahba import ESTIMATORS, Q_METHOD, compiled
from attopt.solvers.wahba.driver import solve_compiled

COMPILED = [s for s in ESTIMATORS if s.has_kernel]
EPS = np.finfo(float).eps
ANGLE_FACTOR = 200.0
"""Largest measured: 83 (FOAM) over 100,000 random two-vector epochs."""
CONDITION_POWER = {"quest": 2}
"""QUEST's quaternion (eqs. 30-31) is accurate only to ``eps (lambda_0 / gap)^2`` before
its Rayleigh refinement, so either path of it can be that far from the optimum (2e-5 and
1e-3 rad on an epoch with ``lambda_0 / gap = 2.4e7``, where the SVD agrees with the numpy
q-method to 1e-9 rad)."""
pytestmark = pytest.mark.skipif(
    not compiled_loops(), reason="ATTOPT_KERNELS=interpreted: the compiled path is off"
)
SETTINGS = settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.too_slow])


@st.composite
def batches(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Noisy epochs of 2-5 observations, some absent, some spoilt (each check's case)."""
    n_epochs = draw(st.integers(1, 12))
    n_obs = draw(st.integers(2, 5))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    truth = Rotation.random(n_epochs, random_state=rng)
    reference = rng.normal(size=(n_epochs, n_obs, 3))
    sigma = 10.0 ** rng.uniform(-4, -1, size=(n_epochs, n_obs))
    body = np.einsum("eij,enj->eni", truth.as_matrix(), reference)
    body += sigma[..., None] * rng.normal(size=body.shape)
    body *= rng.uniform(0.5, 2.0, size=(n_epochs, n_obs, 1))  # not unit: normalised
    weights = sigma**-2
    present = rng.random((n_epochs, n_obs)) > 0.15
    for e in range(n_epochs):
        spoil = draw(st.sampled_from(["", "", "nan", "zero", "weight", "parallel"]))
        i = draw(st.integers(0, n_obs - 1))
        if spoil == "nan":
            body[e, i, 1] = np.nan
        elif spoil == "zero":
            reference[e, i] = 0.0
        elif spoil == "weight":
            weights[e, i] = -1.0
        elif spoil == "parallel":
            body[e] = body[e, :1] * rng.uniform(0.5, 2.0, size=(n_obs, 1))
    return body, reference, weights, present


def _gap(body, reference, weights, present) -> np.ndarray:
    """``lambda_0 / gap`` per epoch (the numpy q-method's eigenvalues)."""
    track = Q_METHOD.numpy_reference().solve_batch(body, reference, weights, present)
    lambda_0 = np.where(present, weights, 0.0).sum(axis=1)
    if not track.valid.any():
        return np.full(len(track), np.nan)
    return lambda_0 / track.diagnostics["eigen_gap"]


@pytest.mark.parametrize("solver", COMPILED, ids=lambda s: s.name)
@SETTINGS
@given(batch=batches())
def test_compiled_batches_equal_the_numpy_methods(solver, batch):
    fast = solver.solve_batch(*batch)
    slow = solver.numpy_reference().solve_batch(*batch)
    np.testing.assert_array_equal(fast.valid, slow.valid)
    assert fast.reason.tolist() == slow.reason.tolist()
    assert fast.error.tolist() == slow.error.tolist()
    assert sorted(fast.diagnostics) == sorted(slow.diagnostics)
    v = fast.valid
    assert np.isnan(fast.quaternion[~v]).all() and np.isnan(fast.covariance[~v]).all()
    assert np.isnan(fast.loss[~v]).all()
    if not v.any():
        return
    condition = _gap(*batch)[v]
    angle = np.linalg.norm(
        attitude_error(
            Rotation.from_quat(fast.quaternion[v]), Rotation.from_quat(slow.quaternion[v])
        ),
        axis=1,
    )
    power = CONDITION_POWER.get(solver.name, 1)
    assert np.all(angle <= ANGLE_FACTOR * EPS * condition**power + 1e-15)
    # Both are scipy's canonical quaternion (w >= 0), so they are close as vectors too.
    close = angle < 1e-9
    np.testing.assert_allclose(fast.quaternion[v][close], slow.quaternion[v][close], atol=1e-9)
    scale = np.abs(slow.covariance[v]).max(axis=(1, 2))
    cov_error = np.abs(fast.covariance[v] - slow.covariance[v]).max(axis=(1, 2)) / scale
    assert np.all(cov_error <= 1e3 * ANGLE_FACTOR * EPS * condition ** (power + 1) + 1e-12)
    lambda_0 = np.where(batch[3], batch[2], 0.0).sum(axis=1)[v]
    assert np.all(np.abs(fast.loss[v] - slow.loss[v]) <= 1e-12 * lambda_0)
    for name in ("anchor", "partner", "sequential_rotation"):
        if name in slow.diagnostics:
            np.testing.assert_array_equal(fast.diagnostics[name][v], slow.diagnostics[name][v])
    if "lambda_max" in slow.diagnostics:  # to eps lambda_0 / gap (FOAM's quartic)
        gap = np.abs(fast.diagnostics["lambda_max"][v] - slow.diagnostics["lambda_max"][v])
        assert np.all(gap <= ANGLE_FACTOR * EPS * lambda_0 * condition**power), gap / lambda_0
    for name in ("s3", "eigen_gap"):  # differences of the eigenvalues of K: to eps lambda_0
        if name in slow.diagnostics:
            gap = np.abs(fast.diagnostics[name][v] - slow.diagnostics[name][v])
            assert np.all(gap <= 1e3 * EPS * lambda_0), (name, gap / (EPS * lambda_0))
    if "iterations" in slow.diagnostics:  # the stopping rule meets round-off: a step or two
        steps = np.abs(fast.diagnostics["iterations"][v] - slow.diagnostics["iterations"][v])
        assert steps.max() <= 3


@pytest.mark.parametrize("solver", COMPILED, ids=lambda s: s.name)
@SETTINGS
@given(batch=batches())
def test_single_calls_equal_the_batch_or_raise_its_error(solver, batch):
    body, reference, weights, present = batch
    track = solver.solve_batch(*batch)
    for e in range(len(track)):
        keep = present[e]
        args = body[e][keep], reference[e][keep], weights[e][keep]
        if not track.valid[e]:
            with pytest.raises(track.error[e], match=f"^{solver.name}: "):
                solver.solve_vectors(*args)
            continue
        solution = solver.solve_vectors(*args)
        np.testing.assert_array_equal(solution.quaternion, track.quaternion[e])
        np.testing.assert_array_equal(solution.covariance, track.covariance[e])
        assert solution.loss == track.loss[e]
        expected = {k: float(v[e]) for k, v in track.diagnostics.items()}
        for index in ("anchor", "partner"):  # TRIAD's: indices among the present vectors
            if index in solution.diagnostics:
                solution.diagnostics[index] = float(
                    np.flatnonzero(keep)[int(solution.diagnostics[index])]
                )
        assert solution.diagnostics == expected
        assert solution.attitude.approx_equal(Rotation.from_quat(track.quaternion[e]), 1e-15)


def test_an_unconverged_epoch_is_flagged_with_the_method_reason(monkeypatch):
    """The buffer's convergence column becomes the method's reason and ConvergenceError."""
    real = compiled.solve_epochs

    def unconverged(*args):
        out = real(*args)
        out[1, compiled.CONVERGED] = 0.0
        out[1, compiled.QUATERNION :] = np.nan
        return out

    monkeypatch.setattr(compiled, "solve_epochs", unconverged)
    vectors = np.tile(np.eye(3)[:2], (3, 1, 1))
    track = solve_compiled(
        "quest",
        compiled.QUEST,
        "did not converge",
        (vectors, vectors, np.ones((3, 2)), np.ones((3, 2), bool)),
        1e-3,
    )
    assert track.valid.tolist() == [True, False, True]
    assert track.reason.tolist() == ["", "did not converge", ""]
    assert track.error[1] is ConvergenceError


def test_the_quaternion_is_canonical_at_180_degrees():
    """Near 180 deg the sequential rotations and the sign rule keep ``w >= 0``."""
    reference = np.eye(3)
    for axis in np.eye(3):
        truth = Rotation.from_rotvec(np.pi * axis)
        for solver in COMPILED:
            q = solver.solve_vectors(truth.apply(reference), reference, np.ones(3)).quaternion
            assert q[3] >= 0.0
            assert Rotation.from_quat(q).approx_equal(truth, atol=1e-12)


def test_the_numpy_path_is_an_option():
    """``compiled = false`` (a configuration's options table) selects the numpy reference."""
    from attopt.solvers.registry import estimator, with_options

    numpy_quest = with_options(estimator("quest"), {"compiled": False})
    assert numpy_quest.label == "quest (numpy)" and numpy_quest.kernel is None
    assert estimator("quest").kernel == compiled.QUEST and estimator("sdp").kernel is None


def test_a_compiling_first_call_prints_its_cost(capsys):
    """A loop compiled on first use says so on standard error, one loaded from the cache
    does not (numba's statistics: cache misses and hits)."""
    from collections import Counter
    from types import SimpleNamespace

    from attopt.formulations.kernels import report_compilation

    compiled_now = SimpleNamespace(cache_misses=Counter({"sig": 1}), cache_path="/cache")
    loaded = SimpleNamespace(cache_misses=Counter(), cache_path="/cache")
    assert report_compilation("the quest Wahba loop", 7.5, compiled_now)
    assert "compiled the quest Wahba loop in 7.50 s" in capsys.readouterr().err
    assert not report_compilation("the quest Wahba loop", 0.01, loaded)
    assert capsys.readouterr().err == ""
