"""Cramer-Rao bounds of the attitude: of one snapshot, and of a pass.

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

The pass bounds (posterior Cramer-Rao bounds, Tichavsky, Muravchik and Nehorai
1998: the inverse of the whole pass's information, measurements, dynamics and
prior, evaluated at the truth):

* :func:`posterior_bound`, of a gyro-aided pass: the attitude block of the batch
  smoother's marginal covariance (:mod:`attopt.solvers.smoother.marginals`) with
  its factors linearised at the true attitudes and biases: every measurement
  used (no gating), no optimisation step, transmitter offsets not modelled;
* :func:`posterior_bound_ekf`, of Yang et al. 2014's rigid-body dynamics model
  (:mod:`attopt.solvers.doa.eks`): filter and smoother bounds.
"""

from __future__ import annotations

from dataclasses import fields

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import AttitudeMeasurement
from attopt.formulations.passes import Pass
from attopt.formulations.snapshot import Snapshot
from attopt.formulations.snr_model import cramer_rao_bound
from attopt.solvers.doa.eks import posterior_bound_ekf
from attopt.solvers.filters.common import FilterOptions
from attopt.solvers.smoother.estimators import BatchSmoother, OffsetBatchSmoother
from attopt.solvers.smoother.initial import fixed_start
from attopt.solvers.smoother.marginals import MarginalOptions
from attopt.solvers.smoother.optimiser_params import LevenbergMarquardtParams

__all__ = [
    "crb",
    "measurement_information",
    "posterior_bound",
    "posterior_bound_ekf",
    "snapshot_information",
]

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
    on the axes the snapshot cannot see (module docstring).

    Example::

        >>> import numpy as np
        >>> from scipy.spatial.transform import Rotation
        >>> from attopt import Snapshot, crb
        >>> one_vector = Snapshot.from_vectors([[0.0, 0.0, 1.0]], [[0.0, 0.0, 1.0]], 1e-3)
        >>> np.sqrt(np.diag(crb(one_vector, Rotation.identity()))).tolist()  # z is not seen
        [0.001, 0.001, inf]
    """
    return cramer_rao_bound(snapshot_information(snapshot, truth))


AT_THE_TRUTH = BatchSmoother(
    optimiser=LevenbergMarquardtParams(max_iterations=0),
    marginals=MarginalOptions(cross_covariance=False),
    filter=FilterOptions(gate_probability=1.0, consistency_window=0),
    flag_unconverged=False,
    gyro_exclusions=0,
    max_variance_factor=1.0,
)
"""The batch smoother that :func:`posterior_bound` evaluates at the truth: no step, no
gate, no consistency test, variance factor nor gyro fault test (the bound does not depend
on the noise drawn), per-key marginals."""


def posterior_bound(
    pass_: Pass,
    truth_attitude: Rotation,
    truth_bias: ArrayLike,
    offset_sigma: float | None = None,
) -> Array:
    """Per-epoch posterior Cramer-Rao bound ``(N, 3)`` of the attitude of a gyro-aided pass
    (rad, body axes; module docstring).

    The square roots of the diagonal of the attitude block of the batch smoother's
    marginal covariance with its factors at ``truth_attitude`` (``N`` attitudes at the
    epochs) and ``truth_bias`` (``(N, 3)`` rad/s): every measurement of the pass used
    (no gate).  Without ``offset_sigma`` the transmitters' powers are known; with it,
    each transmitter (the measurements' ``sources``) has an unknown constant power
    offset with prior ``N(0, offset_sigma^2)``, linearised at 0
    (``fg_batch_offsets``' problem): the bound of an estimator that must learn the
    powers.  The prior node at the first gyro sample (when the
    first epoch is later) stays at the prior's estimate.  NaN at epochs the
    smoother's validity rules flag (an attitude sigma above
    ``FilterOptions.max_attitude_sigma``).

    Raises:
        InvalidObservationError: the pass has no gyro record or prior, or the truth
            has another number of epochs.

    Example::

        >>> import numpy as np
        >>> from scipy.spatial.transform import Rotation
        >>> from attopt import MEMS_GYRO, GyroRecord, Pass, Prior, posterior_bound
        >>> gyro = GyroRecord(np.arange(51) / 10.0, np.zeros((50, 3)), MEMS_GYRO)
        >>> v = np.eye(3)[:2]
        >>> prior = Prior(Rotation.identity(), 1e-4 * np.eye(3))
        >>> pass_ = Pass.from_vectors(np.arange(5.0), np.tile(v, (5, 1, 1)), v, 1e-3, gyro, prior)
        >>> sigma = posterior_bound(pass_, Rotation.identity(5), np.zeros((5, 3)))
        >>> sigma.shape, bool((sigma < 1e-3).all())
        ((5, 3), True)
    """
    smoother = (
        AT_THE_TRUTH
        if offset_sigma is None
        else OffsetBatchSmoother(
            **{f.name: getattr(AT_THE_TRUTH, f.name) for f in fields(AT_THE_TRUTH)},
            offset_sigma=offset_sigma,
        )
    )
    track = smoother.solve(pass_, fixed_start(truth_attitude, truth_bias))
    return np.sqrt(np.diagonal(track.state_covariance[:, :3, :3], axis1=1, axis2=2))
