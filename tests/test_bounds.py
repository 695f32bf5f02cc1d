"""The snapshot Cramer-Rao bound (``solvers/bounds.py``) against the special cases the
formulations derive: Wahba's covariance for unit vectors (Cilden Guler et al. 2017
eq. 32), Liu et al. 2023's eq. 22 for SNRs with and without the reception threshold,
and the DOA stochastic bound mapped through the DOA model (by finite differences)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import EulerAngleMeasurement, VectorMeasurement
from attopt.formulations.doa_array import doa_from_unit_vector
from attopt.formulations.doa_crb import stochastic_crb
from attopt.formulations.doa_measurement import DoaMeasurement
from attopt.formulations.snapshot import Snapshot
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.formulations.snr_model import cramer_rao_bound, fisher_information
from attopt.formulations.snr_problem import RECEPTION_THRESHOLD_DB
from attopt.formulations.snr_truncation import truncated_fisher_information
from attopt.formulations.wahba_covariance import quest_covariance
from attopt.solvers.bounds import crb, snapshot_information
from tests.strategies import attitudes, wahba_problems
from tests.test_doa_measurement import ARRAY_DOAS, geometry
from tests.test_snr_solvers import TRUTH, _epoch, _geometry
from tests.test_snr_truncation import _near_threshold_epoch


@settings(max_examples=40, deadline=None)
@given(wahba_problems(max_vectors=10))
def test_vector_bound_is_wahbas_covariance(problem):
    truth, body, reference, weights = problem
    bound = crb(Snapshot.from_vectors(body, reference, weights**-0.5), truth)
    expected = quest_covariance(body[None], weights[None])[0]
    np.testing.assert_allclose(bound, expected, rtol=1e-8, atol=1e-8 * np.abs(expected).max())


def test_one_vector_leaves_the_rotation_about_it_unbounded():
    truth = Rotation.from_rotvec([0.2, -0.4, 1.0])
    reference = np.array([[0.0, 0.6, 0.8]])
    bound = crb(Snapshot.from_vectors(truth.apply(reference), reference, 1e-3), truth)
    assert np.all(np.isinf(np.diag(bound)))  # the axis A r is oblique: every body axis moves
    euler = EulerAngleMeasurement(truth.inv().as_euler("ZYX"), 1e-4 * np.eye(3))
    mixed = Snapshot.of(VectorMeasurement(truth.apply(reference), reference, 1e-3), euler)
    assert np.all(np.isfinite(crb(mixed, truth)))


def test_snr_bound_is_eq22():
    geometry = _geometry(np.random.default_rng(30), TRUTH, (8, 7))
    snapshot = Snapshot.of(SnrMeasurement(_epoch(geometry, sigma_db=1.3)))
    expected = cramer_rao_bound(fisher_information(geometry[4], 1.3))
    np.testing.assert_allclose(crb(snapshot, TRUTH), expected, rtol=1e-9)


def test_truncated_snr_bound_is_the_truncated_information():
    """The truncated model's AD Jacobian (the mean's slope, ``c_k f'``) and variance
    (``c_k sigma^2``) give ``c_k f' f'^T / sigma^2``: the truncated Fisher information."""
    rng = np.random.default_rng(31)
    true_snr = rng.uniform(4.5, 9.0, 24)
    make, jacobian = _near_threshold_epoch(rng, true_snr, (12, 12))
    snapshot = Snapshot.of(SnrMeasurement(make(true_snr), truncated=True))
    information = truncated_fisher_information(jacobian, true_snr, 1.0, RECEPTION_THRESHOLD_DB)
    np.testing.assert_allclose(crb(snapshot, TRUTH), cramer_rao_bound(information), rtol=1e-8)
    untruncated = crb(Snapshot.of(SnrMeasurement(make(true_snr))), TRUTH)
    assert np.trace(crb(snapshot, TRUTH)) > 1.1 * np.trace(untruncated)


def test_unpredictable_rows_carry_no_information():
    """An observation outside the main lobe at the attitude is left out (NaN row)."""
    geometry = _geometry(np.random.default_rng(32), TRUTH, (6, 6))
    measurement = SnrMeasurement(_epoch(geometry))
    tilted = Rotation.from_rotvec([0.5, 0.0, 0.0]) * TRUTH
    h, _ = measurement.predict(tilted)
    assert np.isnan(h).any() and np.isfinite(h).any()
    information = snapshot_information(Snapshot.of(measurement), tilted)
    assert np.all(np.isfinite(information)) and np.linalg.matrix_rank(information) == 3


def _doa_angles(truth: Rotation, line_of_sight: np.ndarray) -> np.ndarray:
    theta, phi = doa_from_unit_vector(truth.apply(line_of_sight))
    return np.column_stack([theta, phi])


@settings(max_examples=15, deadline=None)
@given(attitudes(), st.floats(-14.0, 0.0), st.integers(10, 200))
def test_doa_bound_is_the_stochastic_crb_mapped_through_the_doa_model(truth, snr_db, snapshots):
    """``F = sum_s G_s^T CRB_s^-1 G_s`` with ``G_s = d(theta, phi) / d delta`` by central
    differences of the angles of the rotated lines of sight (far field, no lever arm)."""
    los = geometry(truth, Rotation.identity(), np.zeros(3))
    far = ARRAY_DOAS[:, 0] > np.radians(5.0)  # stations measured as angles
    los = los[far]
    angles = _doa_angles(truth, los)
    covariance = stochastic_crb(angles[:, 0], angles[:, 1], 10.0 ** (snr_db / 10.0), snapshots)
    bound = crb(Snapshot.of(DoaMeasurement(angles, covariance, los)), truth)
    step = 1e-6
    g = np.stack(
        [
            (
                _doa_angles(Rotation.from_rotvec(step * e) * truth, los)
                - _doa_angles(Rotation.from_rotvec(-step * e) * truth, los)
            )
            / (2 * step)
            for e in np.eye(3)
        ],
        axis=-1,
    )  # (stations, 2, 3)
    information = np.einsum("sai,sab,sbj->ij", g, np.linalg.inv(covariance), g)
    np.testing.assert_allclose(bound, np.linalg.inv(information), rtol=1e-5)
