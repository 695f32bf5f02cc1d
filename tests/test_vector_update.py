"""The MEKF's and USQUE's compiled updates for unit vectors against their numpy paths, the
references."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from attopt import EulerAngleMeasurement, FilterOptions, ReferencedMeasurement, VectorMeasurement
from attopt.formulations.conventions import euler321_from_attitude
from attopt.formulations.kernels import compiled_kernels
from attopt.solvers.filters import mekf, usque, vector_unscented_update, vector_update
from attopt.solvers.filters.common import usable_rows

pytestmark = pytest.mark.skipif(not compiled_kernels(), reason="needs compiled kernels")

TOLERANCE = 1e-6
"""Differences between the two paths in units of what the update started from: the
attitude and bias differences whitened by the prior covariance, each posterior
covariance entry relative to the prior's ``sqrt(P_ii P_jj)``, and the NIS relative to
the sum it cancels, ``c = 1 + nu^T R^-1 nu`` at the prior; the first two are allowed
``TOLERANCE + AMPLIFICATION * c``.  The two paths sum in other orders (BLAS against
loops, scipy's quaternion product against CasADi's matrix product), and an update
amplifies that round-off with the size of its innovation in sigmas: in steady state
they agree to 1e-14 rad; over 1,500 random updates of the property test's kinds the
MEKF's largest whitened difference was 7e-8 and USQUE's 1.8e-5, the latter with the gate
off and a vector 170 deg from its prediction against a 0.1 deg prior (``c`` near 1e9);
covariance entries 9e-8 of the prior's scale; the NIS, the difference of two terms as
large as ``c``, by up to 4e-8 of ``c``."""
AMPLIFICATION = 1e-13
"""Round-off allowed per unit of ``c`` (module docstring of the tolerance): about 500
machine epsilons."""


USQUE_WEIGHTS = (usque.WEIGHTS, usque.COVARIANCE_WEIGHTS, usque.LAMBDA)


def _problem(seed: int, k: int, error_deg: float, sigma: float, flip: bool, referenced: bool):
    rng = np.random.default_rng(seed)
    truth = Rotation.random(random_state=rng)
    reference = rng.normal(size=(k, 3))
    reference /= np.linalg.norm(reference, axis=1, keepdims=True)
    body = truth.apply(reference) + sigma * rng.normal(size=(k, 3))
    axis = rng.normal(size=3)
    estimate = Rotation.from_rotvec(np.radians(error_deg) * axis / np.linalg.norm(axis)) * truth
    if flip:  # a measured vector nearly opposite its prediction (an exact opposite has no
        # defined geodesic: its direction is round-off, different in the two paths)
        opposite = -estimate.apply(reference[0])
        turn = np.cross(opposite, axis)
        body[0] = Rotation.from_rotvec(0.3 * turn / np.linalg.norm(turn)).apply(opposite)
    measurement = VectorMeasurement(body, reference, sigma * rng.uniform(0.5, 2.0, size=k))
    if referenced:
        frame = Rotation.random(random_state=rng)
        measurement = ReferencedMeasurement(measurement, frame)
        estimate = estimate * frame
    a = rng.normal(size=(6, 6))
    covariance = a @ a.T * rng.uniform(1e-8, 1e-5) + np.diag(
        np.r_[np.full(3, np.radians(max(error_deg, 0.1)) ** 2), np.full(3, 1e-8)]
    )
    bias = rng.normal(size=3) * 1e-4
    return estimate, bias, covariance, measurement


def _compare(compiled, reference, measurement, prior, prior_covariance) -> None:
    attitude, bias, covariance, counts, increment = compiled
    attitude_ref, bias_ref, covariance_ref, counts_ref, increment_ref = reference
    assert list(counts) == list(counts_ref)
    nis, nis_ref = counts.pop("nis"), counts_ref.pop("nis")
    assert counts == counts_ref
    nu = measurement.innovation(measurement.predict(prior, jacobian=False)[0][0])
    cancelled = 1.0 + nu @ (nu / measurement.noise_covariance)
    allowed = TOLERANCE + AMPLIFICATION * cancelled
    difference = np.r_[(attitude * attitude_ref.inv()).as_rotvec(), bias - bias_ref]
    assert difference @ np.linalg.solve(prior_covariance, difference) < allowed**2
    scale = np.sqrt(np.outer(np.diag(prior_covariance), np.diag(prior_covariance)))
    assert (np.abs(covariance - covariance_ref) <= allowed * scale).all()
    both_nan = np.isnan(nis) and np.isnan(nis_ref)
    assert both_nan or abs(nis - nis_ref) <= TOLERANCE * cancelled
    assert increment.shape == increment_ref.shape == (0,)


@settings(max_examples=80, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    k=st.integers(1, 4),
    error_deg=st.sampled_from([0.0, 0.05, 1.0, 20.0, 60.0, 150.0]),
    sigma=st.sampled_from([1e-4, 1e-3, 3e-2]),
    flip=st.booleans(),
    referenced=st.booleans(),
    gate_probability=st.sampled_from([0.9999, 0.5, 1.0]),
    iterations=st.sampled_from([1, 3, 10]),
)
def test_the_compiled_update_equals_the_numpy_path(
    seed, k, error_deg, sigma, flip, referenced, gate_probability, iterations
) -> None:
    """Updates that gate, iterate, backtrack, lose a vector or keep the prior: the same
    attitude, bias, covariance and counts, for the MEKF and for USQUE."""
    estimate, bias, covariance, measurement = _problem(seed, k, error_deg, sigma, flip, referenced)
    options = FilterOptions(gate_probability=gate_probability, max_update_iterations=iterations)
    arguments = (estimate, bias, covariance, measurement, options)
    compiled = vector_update.compiled_update(*arguments, max_halvings=mekf.MAX_HALVINGS)
    assert compiled is not None
    _compare(compiled, mekf.update_reference(*arguments), measurement, estimate, covariance)
    compiled = vector_unscented_update.compiled_update(*arguments, USQUE_WEIGHTS)
    assert compiled is not None
    _compare(compiled, usque.update_reference(*arguments), measurement, estimate, covariance)


def test_the_paths_cover_gating_iterations_and_kept_priors() -> None:
    """The cases of the property test happen: a gated vector, an iterated update, and an
    update with no vector left."""
    seen = {"n_gated": 0.0, "update_iterations": 0.0, "kept": 0}
    for seed in range(60):
        estimate, bias, covariance, measurement = _problem(
            seed, 1 + seed % 3, [0.05, 20.0, 60.0][seed % 3], 1e-3, seed % 4 == 0, True
        )
        arguments = (estimate, bias, covariance, measurement, FilterOptions())
        compiled = vector_update.compiled_update(*arguments, max_halvings=mekf.MAX_HALVINGS)
        _compare(compiled, mekf.update_reference(*arguments), measurement, estimate, covariance)
        counts = compiled[3]
        for key in ("n_gated", "update_iterations"):
            seen[key] = max(seen[key], counts[key])
        seen["kept"] += counts["n_used"] == 0
    assert seen["n_gated"] >= 1 and seen["update_iterations"] >= 3 and seen["kept"] >= 1


@pytest.mark.parametrize(
    ("z", "predicted", "innovation"),
    [
        ([1.0, 0.0, 0.0, np.nan, 0.0, 1.0], np.ones(6), np.zeros(6)),
        (np.ones(6), [1.0, np.nan, 0.0, 0.0, 0.0, 1.0], np.zeros(6)),
        (np.ones(6), np.ones(6), [0.0, 0.0, 0.0, np.inf, 0.0, 0.0]),
        ([np.nan, 0.0, 0.0, 0.0, 0.0, 1.0], np.ones(6), [0.0, 0.0, 0.0, np.nan, 0.0, 0.0]),
        (np.ones(6), np.ones(6), np.zeros(6)),
    ],
)
def test_usable_rows_drop_whole_blocks_and_count_them(z, predicted, innovation) -> None:
    """The loop's row selection against the numpy path's
    (:func:`attopt.solvers.filters.common.usable_rows`); a vector whose prediction or
    innovation is not finite is also the relinearised update's lost block."""
    blocks = np.arange(2).repeat(3)
    z, predicted, innovation = (np.asarray(x, dtype=float) for x in (z, predicted, innovation))
    measurement = SimpleNamespace(z=z, blocks=blocks)
    keep, n_nan, n_unpredictable = usable_rows(measurement, predicted[None], innovation[None])
    got = vector_update._usable_rows(z, predicted[None], innovation[None], blocks)
    assert got[0].tolist() == keep.tolist() and got[1:] == (n_nan, n_unpredictable)
    lost = vector_update._lost_rows(innovation[None], blocks)
    assert lost.tolist() == np.isin(blocks, blocks[~np.isfinite(innovation)]).tolist()


def test_what_the_compiled_update_does_not_serve_runs_the_numpy_path() -> None:
    """Full vector covariances, other measurement types, the Huber weights and interpreted
    kernels: no compiled result, and the MEKF's update is its numpy path's."""
    truth = Rotation.from_rotvec([0.1, 0.2, -0.3])
    reference = np.array([[1.0, 0.0, 0.0], [0.0, 0.6, 0.8]])
    body = truth.apply(reference)
    args = (Rotation.identity(), np.zeros(3), 0.01 * np.eye(6))
    cases = [
        (VectorMeasurement(body, reference, covariance=1e-6 * np.eye(3)), FilterOptions()),
        (EulerAngleMeasurement(euler321_from_attitude(truth), 1e-4 * np.eye(3)), FilterOptions()),
        (VectorMeasurement(body, reference, 1e-3), FilterOptions(huber_threshold=2.0)),
    ]
    for measurement, options in cases:
        assert vector_update.compiled_update(*args, measurement, options, 8) is None
        assert (
            vector_unscented_update.compiled_update(*args, measurement, options, USQUE_WEIGHTS)
            is None
        )
        out, ref = (
            mekf.update(*args, measurement, options),
            mekf.update_reference(*args, measurement, options),
        )
        np.testing.assert_array_equal(out[2], ref[2])


def test_interpreted_loops_run_the_numpy_path(monkeypatch) -> None:
    monkeypatch.setattr(vector_update, "compiled_loops", lambda: False)
    reference = np.array([[1.0, 0.0, 0.0], [0.0, 0.6, 0.8]])
    measurement = VectorMeasurement(reference, reference, 1e-3)
    args = (Rotation.identity(), np.zeros(3), 0.01 * np.eye(6), measurement, FilterOptions())
    assert vector_update.compiled_update(*args, 8) is None
    assert vector_unscented_update.compiled_update(*args, USQUE_WEIGHTS) is None
