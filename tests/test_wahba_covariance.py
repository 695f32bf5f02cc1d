"""Each method's covariance formula against Monte Carlo scatter (Cilden Guler et al. 2017
eqs. 11, 19, 32, 37)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from attopt.formulations.conventions import attitude_error
from attopt.solvers.wahba import ESTIMATORS, NUMPY_REFERENCES, SDP, TRIAD
from tests.strategies import noisy_body

TRUTH = Rotation.from_euler("xyz", [20, -35, 110], degrees=True)


def _unit(v):
    v = np.asarray(v, dtype=float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


# (reference vectors, sigmas): Cilden Guler et al. 2017's Sun + magnetometer pair at 90 and
# 30 degrees, and five vectors of mixed accuracy.
GEOMETRIES = {
    "sun-mag-90deg": (_unit([[1, 0, 0], [0, 1, 0]]), np.array([0.002, 0.008])),
    "sun-mag-30deg": (
        _unit([[1, 0, 0], [np.cos(np.pi / 6), np.sin(np.pi / 6), 0]]),
        np.array([0.002, 0.008]),
    ),
    "five-vectors": (
        _unit([[1, 0.2, 0], [0, 1, 0.3], [0.1, 0, 1], [1, 1, 1], [-1, 0.5, 0.2]]),
        np.array([0.002, 0.008, 0.004, 0.01, 0.003]),
    ),
}


def _monte_carlo(solver, reference, sigmas, trials, seed):
    rng = np.random.default_rng(seed)
    body = np.stack([noisy_body(TRUTH, reference, sigmas, rng) for _ in range(trials)])
    batch = solver.solve_batch(
        body, np.broadcast_to(reference, body.shape), np.tile(sigmas**-2, (trials, 1))
    )
    assert batch.valid.all()
    errors = attitude_error(batch.attitude(), TRUTH)
    scatter = errors.T @ errors / trials
    return scatter, batch.covariance.mean(axis=0)


@pytest.mark.parametrize("geometry", GEOMETRIES)
@pytest.mark.parametrize(
    "solver",
    [
        *(s for s in ESTIMATORS if s.vectorised),
        *NUMPY_REFERENCES,
    ],
    ids=lambda s: s.label,
)
def test_covariance_matches_monte_carlo(solver, geometry):
    reference, sigmas = GEOMETRIES[geometry]
    scatter, predicted = _monte_carlo(solver, reference, sigmas, trials=4000, seed=11)
    assert np.linalg.norm(scatter - predicted) < 0.1 * np.trace(predicted)


def test_sdp_covariance_matches_monte_carlo():
    reference, sigmas = GEOMETRIES["five-vectors"]
    scatter, predicted = _monte_carlo(SDP, reference, sigmas, trials=1000, seed=12)
    assert np.linalg.norm(scatter - predicted) < 0.1 * np.trace(predicted)


def test_triad_variance_belongs_to_the_anchor():
    """Cilden Guler et al. 2017 eq. 11 labels s1 the magnetometer; the anchor's variance is
    the right one.

    With the swapped labels the formula misses the scatter by far more than 10%.
    """
    from attopt.formulations.wahba_covariance import triad_covariance

    reference, sigmas = GEOMETRIES["sun-mag-30deg"]
    scatter, _ = _monte_carlo(TRIAD, reference, sigmas, trials=4000, seed=13)
    u = TRUTH.apply(reference)
    swapped = triad_covariance(u[:1], u[1:], sigmas[1:] ** 2, sigmas[:1] ** 2)[0]
    assert np.linalg.norm(scatter - swapped) > 0.5 * np.trace(scatter)


def test_svd_covariance_equals_seed_eq19_form():
    """[tr(B A^T) I - B A^T]^-1 at the optimum equals U diag[(s2+s3)^-1, ...] U^T (eq. 19)."""
    from attopt.formulations.wahba import attitude_profile_matrix, proper_svd
    from attopt.formulations.wahba_covariance import svd_covariance

    reference, sigmas = GEOMETRIES["five-vectors"]
    body = noisy_body(TRUTH, reference, sigmas, np.random.default_rng(3))
    b = attitude_profile_matrix(body[None], reference[None], sigmas[None] ** -2)
    u, s, vt, d = proper_svd(b)
    optimal = u @ np.diag([1.0, 1.0, d[0]]) @ vt
    s1, s2, s3 = s[0, 0], s[0, 1], d[0] * s[0, 2]
    eq19 = u[0] @ np.diag([1 / (s2 + s3), 1 / (s3 + s1), 1 / (s1 + s2)]) @ u[0].T
    np.testing.assert_allclose(svd_covariance(b, optimal)[0], eq19, rtol=1e-10)


def _anisotropic_noise(truth, reference, stretch, sigma, trials, rng):
    """Body vectors whose noise across each direction has standard deviations ``sigma`` and
    ``stretch * sigma`` (rad), and their ``3 x 3`` covariances."""
    h = truth.apply(reference)
    first = np.cross(h, [0.3, 0.5, 0.8])
    first /= np.linalg.norm(first, axis=-1, keepdims=True)
    second = np.cross(h, first)
    covariance = sigma**2 * (
        np.einsum("ni,nj->nij", first, first) + stretch**2 * np.einsum("ni,nj->nij", second, second)
    )
    draws = rng.normal(size=(trials, len(h), 2)) * sigma * np.array([1.0, stretch])
    body = h + draws[..., :1] * first + draws[..., 1:] * second
    return body / np.linalg.norm(body, axis=-1, keepdims=True), covariance


@pytest.mark.parametrize(
    "solver", [s for s in ESTIMATORS if s.vectorised and s.optimal], ids=lambda s: s.label
)
def test_anisotropic_vector_covariance_matches_monte_carlo(solver):
    """With noise three times larger along one axis across each direction than the other,
    the covariance given the vectors' covariances matches the scatter; the isotropic
    weights' own covariance, which assumes the mean variance, misses it by far."""
    reference = _unit([[1, 0, 0], [0.2, 1, 0], [0, 0.3, 1]])
    trials = 4000
    body, covariance = _anisotropic_noise(
        TRUTH, reference, 3.0, 0.002, trials, np.random.default_rng(21)
    )
    isotropic = np.einsum("nii->n", covariance) / 2.0
    weights = np.tile(1.0 / isotropic, (trials, 1))
    references = np.broadcast_to(reference, body.shape)
    given = solver.solve_batch(
        body, references, weights, None, np.broadcast_to(covariance, (trials, *covariance.shape))
    )
    plain = solver.solve_batch(body, references, weights)
    errors = attitude_error(given.attitude(), TRUTH)
    scatter = errors.T @ errors / trials
    np.testing.assert_allclose(given.quaternion, plain.quaternion)
    predicted = given.covariance.mean(axis=0)
    assert np.linalg.norm(scatter - predicted) < 0.1 * np.trace(predicted)
    assert np.linalg.norm(scatter - plain.covariance.mean(axis=0)) > 0.2 * np.trace(scatter)


def test_isotropic_vector_covariances_give_the_solvers_own_covariance():
    """``C_i = sigma_i^2 I`` with weights ``1 / sigma_i^2``: the sandwich is eq. 32's inverse."""
    from attopt.solvers.wahba import QUEST

    reference, sigmas = GEOMETRIES["five-vectors"]
    body = noisy_body(TRUTH, reference, sigmas, np.random.default_rng(5))[None]
    covariance = sigmas[None, :, None, None] ** 2 * np.eye(3)
    args = (body, reference[None], sigmas[None] ** -2.0)
    np.testing.assert_allclose(
        QUEST.solve_batch(*args, None, covariance).covariance,
        QUEST.solve_batch(*args).covariance,
        rtol=1e-9,
    )


def test_a_sequence_of_full_covariance_measurements_gets_their_covariance():
    """``solve_sequence`` passes measurements' ``3 x 3`` covariances on as ``solve_batch``'s
    ``vector_covariance``; their isotropic equivalents are the weights."""
    from attopt.formulations.attitude_measurement import VectorMeasurement
    from attopt.formulations.snapshot import Snapshot
    from attopt.solvers.wahba import QUEST

    reference = _unit([[1, 0, 0], [0.2, 1, 0], [0, 0.3, 1]])
    body, covariance = _anisotropic_noise(TRUTH, reference, 3.0, 0.002, 2, np.random.default_rng(4))
    covariance = covariance + 1e-10 * np.eye(3)  # positive definite, as measurements need
    snapshots = [Snapshot((VectorMeasurement(b, reference, covariance=covariance),)) for b in body]
    track = QUEST.solve_sequence(snapshots)
    weights = np.stack([m.sigma**-2.0 for s in snapshots for m in s.measurements])
    expected = QUEST.solve_batch(
        body,
        np.broadcast_to(reference, body.shape),
        weights,
        None,
        np.broadcast_to(covariance, (2, *covariance.shape)),
    )
    np.testing.assert_allclose(track.covariance, expected.covariance, rtol=1e-12)
    assert not np.allclose(
        track.covariance,
        QUEST.solve_batch(body, np.broadcast_to(reference, body.shape), weights).covariance,
        rtol=0.05,
    )
