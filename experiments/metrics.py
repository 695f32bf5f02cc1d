"""Per-epoch metric columns of a track against the truth, shared by the experiments.

Columns (``docs/conventions.md``), from the helpers of
:mod:`attopt.solvers.results` that :meth:`~attopt.solvers.results.Track.to_dataframe`
uses:

* ``err_{x,y,z}_deg``: the body-axis components of the rotation vector of
  ``estimate * truth.inv()`` (:func:`~attopt.solvers.results.attitude_errors`);
* ``sigma_{x,y,z}_deg``: the square roots of the diagonal of the estimator's
  own covariance (:func:`~attopt.solvers.results.observable_sigma`);
* ``nees``: ``e^T P^-1 e`` over the axes the covariance bounds
  (:func:`~attopt.solvers.results.normalised_errors`);
* ``euler_{yaw,pitch,roll}_err_deg``: the 3-2-1 Euler-angle differences
  (Liu et al. 2023 eq. 8) wrapped to [-180, 180), which the papers' tables report.

Invalid epochs are NaN throughout; an axis the estimator cannot see (infinite
variance) has NaN error and sigma.  Gyro-aided tracks add the bias columns
(:func:`gyro_columns`) and, with a factor-graph smoother among the
estimators, the posterior Cramer-Rao bound of the pass
(:func:`posterior_bound_columns`).  A boresight estimate's error is the
pointing error (:func:`pointing_error`), which has no component about the
boresight.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.experiments.simulation import GyroPass
from attopt.formulations.conventions import euler321_from_attitude
from attopt.solvers.bounds import posterior_bound
from attopt.solvers.results import (
    AXES,
    TO_DEG_H,
    Track,
    attitude_errors,
    normalised_errors,
    observable_sigma,
)

Array = NDArray[np.float64]

QUATERNION_COMPONENTS = ("x", "y", "z", "w")
"""Scalar-last components of the ``q_est_*`` and ``q_true_*`` columns."""
UPDATE_COUNTS = ("n_used", "n_gated", "n_unpredictable", "update_iterations")
"""Diagnostics of the sequential filters' updates that their rows carry."""


def unobservable(covariance: Array) -> NDArray[np.bool_]:
    """``(N, 3)``: the axes whose variance is infinite (the data cannot see them)."""
    return np.isinf(np.diagonal(np.asarray(covariance, dtype=float), axis1=-2, axis2=-1))


def error_columns(track: Track, truth: Rotation) -> dict[str, Array]:
    """Error, own-sigma, NEES and Euler-difference columns for every epoch (deg; module
    docstring); ``truth``: one attitude per epoch."""
    valid = track.valid
    quaternion = np.where(valid[:, None], track.quaternion, np.nan)
    error = attitude_errors(quaternion, truth)
    nees = normalised_errors(error, track.covariance)
    error[unobservable(track.covariance)] = np.nan
    euler = np.full((len(track), 3), np.nan)
    if valid.any():
        estimate = Rotation.from_quat(quaternion[valid])
        diff = np.degrees(euler321_from_attitude(estimate) - euler321_from_attitude(truth[valid]))
        euler[valid] = (diff + 180.0) % 360.0 - 180.0
    sigma = np.degrees(observable_sigma(track.covariance))
    columns = {f"err_{a}_deg": np.degrees(error[:, i]) for i, a in enumerate(AXES)}
    columns |= {f"sigma_{a}_deg": sigma[:, i] for i, a in enumerate(AXES)}
    columns["nees"] = nees
    for i, name in enumerate(("yaw", "pitch", "roll")):
        columns[f"euler_{name}_err_deg"] = euler[:, i]
    return columns


def attitude_columns(quaternion: Array, truth: Rotation | None = None) -> dict[str, Array]:
    """``q_est_{x,y,z,w}`` (NaN where invalid) and, with ``truth``, ``q_true_{x,y,z,w}``:
    the estimated and true attitudes per epoch, scipy's scalar-last quaternions
    (``docs/conventions.md``), so the attitudes of a sweep can be read back from its rows.

    Example::

        >>> import numpy as np
        >>> from scipy.spatial.transform import Rotation
        >>> columns = attitude_columns(np.array([[0.0, 0.0, 0.0, 1.0]]), Rotation.identity(1))
        >>> list(columns)[:4], float(columns["q_true_w"][0])
        (['q_est_x', 'q_est_y', 'q_est_z', 'q_est_w'], 1.0)
    """
    quaternion = np.asarray(quaternion, dtype=float)
    columns = {f"q_est_{c}": quaternion[:, i] for i, c in enumerate(QUATERNION_COMPONENTS)}
    if truth is not None:
        true = truth.as_quat()
        columns |= {f"q_true_{c}": true[:, i] for i, c in enumerate(QUATERNION_COMPONENTS)}
    return columns


def status_columns(track: Track) -> dict[str, Array]:
    """``valid`` and ``reason`` (empty where valid)."""
    return {"valid": track.valid, "reason": track.reason.astype(str)}


def in_orbit_frame(track: Track, eci_to_orbit: Rotation) -> Track:
    """``A_bo = A_bi A_oi^T`` of a gyro-aided estimator's track (covariance unchanged: body
    frame)."""
    return _reframed(track, eci_to_orbit.inv())


def in_inertial_frame(track: Track, eci_to_orbit: Rotation) -> Track:
    """``A_bi = A_bo A_oi`` of a single-frame track in the orbit frame (covariance unchanged:
    body frame), e.g. to start a gyro-aided estimator from it."""
    return _reframed(track, eci_to_orbit)


def _reframed(track: Track, frame: Rotation) -> Track:
    """``track`` with each valid attitude ``A`` replaced by ``A F`` (``frame`` per epoch)."""
    quaternion = track.quaternion.copy()
    valid = track.valid
    if valid.any():
        quaternion[valid] = (track.attitude() * frame[valid]).as_quat()
    return replace(track, quaternion=quaternion)


def gyro_columns(track: Track, truth: GyroPass) -> dict[str, Array]:
    """Bias estimate, error and sigma (deg/h, per axis), the 6-state NEES ``nees_full`` of
    ``[attitude, bias]`` and the update counts (:data:`UPDATE_COUNTS`), per epoch."""
    bias_error = track.bias - truth.bias
    attitude_error = (
        Rotation.from_quat(np.where(track.valid[:, None], track.quaternion, [0, 0, 0, 1]))
        * truth.attitude.inv()
    ).as_rotvec()
    error = np.concatenate([attitude_error, bias_error], axis=1)
    valid = track.valid
    nees = np.full(valid.size, np.nan)
    if valid.any():
        nees[valid] = np.einsum(
            "ei,eij,ej->e",
            error[valid],
            np.linalg.inv(track.state_covariance[valid]),
            error[valid],
        )
    sigma = np.sqrt(np.diagonal(track.state_covariance[:, 3:, 3:], axis1=1, axis2=2))
    columns = {f"bias_{a}_deg_h": TO_DEG_H * track.bias[:, i] for i, a in enumerate(AXES)}
    columns |= {f"bias_err_{a}_deg_h": TO_DEG_H * bias_error[:, i] for i, a in enumerate(AXES)}
    columns |= {f"bias_sigma_{a}_deg_h": TO_DEG_H * sigma[:, i] for i, a in enumerate(AXES)}
    columns["nees_full"] = nees
    for name in UPDATE_COUNTS:
        columns[name] = track.diagnostics[name]
    return columns


def posterior_bound_columns(truth: GyroPass, offset_sigma: float | None = None) -> dict[str, Array]:
    """``pbound_{x,y,z}_deg`` per epoch: the posterior Cramer-Rao bound of the pass at the
    true attitudes and biases (:func:`attopt.solvers.bounds.posterior_bound`; with
    ``offset_sigma``, each transmitter's power unknown with that prior)."""
    sigma = np.degrees(posterior_bound(truth.pass_, truth.attitude, truth.bias, offset_sigma))
    return {f"pbound_{a}_deg": sigma[:, i] for i, a in enumerate(AXES)}


def pointing_error(truth: Rotation, boresight: Array) -> Array:
    """``(N, 3)`` rad: the smallest rotation carrying the true boresight (body ``z``) to the
    estimated one ``boresight`` (the truth's reference frame), in the true body frame; its
    component about the boresight (``z``, yaw) is NaN: a boresight does not determine it.

    With ``A_est = exp(delta) A_true`` and no yaw, ``A_true B_est = exp(-delta) z``:
    ``delta = angle (b_y, -b_x, 0) / |(b_x, b_y)|``, ``b = A_true B_est``.
    """
    b = truth.apply(boresight)
    across = np.hypot(b[:, 0], b[:, 1])
    angle = np.arctan2(across, b[:, 2])
    scale = np.divide(angle, across, out=np.zeros_like(angle), where=across > 0)
    return np.stack([scale * b[:, 1], -scale * b[:, 0], np.full_like(angle, np.nan)], axis=1)
