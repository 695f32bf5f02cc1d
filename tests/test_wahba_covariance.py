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
