"""Cramer-Rao bounds of the attitude.

The snapshot bound (:func:`crb`): one epoch's measurements ``z_k = h_k(A) +
nu_k``, ``nu_k ~ N(0, R_k(A))``, independent across measurements, carry the
Fisher information

    ``F(A) = sum_k J_k^T R_k(A)^-1 J_k``

about the body-frame attitude error, ``J_k = dh_k / d delta`` the
measurement's AD Jacobian (``predict``, the one the filters use).  Its inverse
(:func:`attopt.formulations.snr_model.cramer_rao_bound`: infinite on the axes
the data cannot see) at the truth bounds the covariance of any unbiased
estimator of that epoch.  It is the general form of the special cases the
formulations derive: Wahba's ``[sum_i a_i (I - b_i b_i^T)]^-1`` for unit
vectors (Cilden Guler et al. 2017 eq. 32), Liu et al. 2023's eq. 22 for SNRs
(with the reception threshold's truncated information,
:mod:`attopt.formulations.snr_truncation`, for a ``truncated`` SNR
measurement), and the DOA stochastic bound of
:mod:`attopt.formulations.doa_crb` mapped through the DOA measurement.

Rows a model cannot predict at the attitude (NaN) carry no information and
are left out.  :func:`snapshot_information` is the information itself, which
the MAP estimator adds to its prior's (:mod:`attopt.solvers.map_nlp`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.formulations.snapshot import Snapshot
from attopt.formulations.snr_model import cramer_rao_bound

Array = NDArray[np.float64]


def measurement_information(measurement: AttitudeMeasurement, attitude: Rotation) -> Array:
    """``J^T R^-1 J`` ``(3, 3)`` (rad^-2, body frame) of one measurement at one attitude."""
    if measurement.size == 0:
        return np.zeros((3, 3))
    attitude = Rotation.from_quat(attitude.as_quat().reshape(-1, 4)[:1])
    h, jacobian = measurement.predict(attitude)
    jacobian = jacobian[0]
    keep = np.isfinite(h[0]) & np.isfinite(jacobian).all(axis=1)
    noise = np.asarray(measurement.noise_covariance_at(attitude), dtype=float)
    j = jacobian[keep]
    if noise.ndim == 1:
        return j.T @ (j / noise[keep, None])
    return j.T @ np.linalg.solve(noise[np.ix_(keep, keep)], j)


def snapshot_information(snapshot: Snapshot, attitude: Rotation) -> Array:
    """``F(A) = sum_k J_k^T R_k^-1 J_k`` ``(3, 3)`` of a snapshot's measurements (module
    docstring)."""
    return sum(
        (measurement_information(m, attitude) for m in snapshot.measurements), np.zeros((3, 3))
    )


def crb(snapshot: Snapshot, truth: Rotation) -> Array:
    """The snapshot Cramer-Rao bound ``F(truth)^-1`` ``(3, 3)`` (rad^2, body frame), infinite
    on the axes the snapshot cannot see (module docstring)."""
    return cramer_rao_bound(snapshot_information(snapshot, truth))
