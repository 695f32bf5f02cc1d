"""The DOA attitude measurement of Yang et al. 2014 (eqs. 13-18) for filters and smoothers.

For each visible ground station: ``D_o = G_o - S_do`` (eq. 13) is the vector
from the satellite's centre of mass to the station in the reference (orbit)
frame, ``R_b`` the lever arm from the centre of mass to the array centre in
the body frame (eq. 14, ``R_o = A^T R_b``), and the unit line of sight from
the array centre (eq. 15) in the array frame (eq. 16) is

``S_r = C_rb (A D_o - R_b) / |A D_o - R_b|``

with ``A = C_bo`` the attitude and ``C_rb`` the antenna mounting (body ->
array; Yang et al. 2014's array is parallel to the body, ``C_rb = I``, eq. 2).  The
measurement is the DOA of ``S_r`` (eq. 12), ``h = (theta, phi)``, with a
``2 x 2`` covariance per station (one gating block each).  The far-field
approximation (eq. 17, ``far_field=True``) drops ``R_b``: the line of sight
then turns by at most ``asin(|R_b| / |D_o|)`` (``docs/doa.md``).

The model is written once in CasADi and differentiated by AD
(:func:`~attopt.formulations.attitude_model.attitude_model_function`).  Two
directions get a special treatment:

* near the array axis (measured ``theta < axis_threshold``) ``phi`` is
  undefined and ``(theta, phi)`` is singular, so the station is measured by
  its direction cosines ``(x, y)`` of ``S_r`` in the array plane instead,
  ``sin theta (cos phi, sin phi)``, smooth through the axis, with the
  covariance mapped by eq. 12's Jacobian (finite: ``Var phi ~ 1 / sin^2
  theta`` is multiplied by ``sin^2 theta``);
* at or behind the array horizon (``theta >= pi / 2``) the planar array
  cannot measure ``theta`` (``theta`` and ``pi - theta`` give the same
  phases): a measured ``theta`` there is an error, and a station predicted
  there is unpredictable (NaN, filters leave it out).

The innovation wraps ``phi`` differences into ``(-pi, pi]``.
"""

from __future__ import annotations

from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike
from scipy.linalg import block_diag
from scipy.spatial.transform import Rotation

from attopt.formulations.attitude_measurement import Array, AttitudeMeasurement
from attopt.formulations.doa_array import doa_from_unit_vector, doa_jacobian, doa_unit_vector
from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.measurement_model import SymbolicModel, wrapped_difference

AXIS_THRESHOLD = float(np.radians(5.0))
"""Measured polar angle below which a station is measured by direction cosines (rad)."""

_ROWS_PER_STATION = 4
"""Model outputs per station: ``theta, phi, x, y``."""


def doa_model(attitude: Any, line_of_sight: Any, lever_arm: Any, mounting: Any) -> Any:
    """``[theta, phi, x, y]`` per station of ``S_r`` (Yang et al. 2014 eqs. 12-16; CasADi).

    ``line_of_sight`` ``k x 3`` rows ``D_o`` (km), ``lever_arm`` ``3 x 1``
    ``R_b`` (km), ``mounting`` ``C_rb``; stacked station by station.
    """
    k = line_of_sight.size1()
    body = attitude @ line_of_sight.T - lever_arm @ ca.DM.ones(1, k)
    array = (mounting @ body).T
    theta, phi = doa_from_unit_vector(array)
    norm = ca.sqrt(ca.sum2(array**2))
    return ca.vec(ca.horzcat(theta, phi, array[:, 0] / norm, array[:, 1] / norm).T)


class DoaMeasurement(AttitudeMeasurement):
    """Measured DOAs of ground stations as a model of ``A = C_bo`` (module docstring).

    Args:
        angles: ``(k, 2)`` measured ``(theta, phi)`` (rad) per station.
        covariance: ``(k, 2, 2)`` covariances of the angles (rad^2).
        line_of_sight: ``(k, 3)`` ``D_o``, centre of mass -> station, in the
            reference frame (km).
        lever_arm: ``R_b``, centre of mass -> array centre, body frame (km).
        mounting: ``C_rb``, body -> array frame (default identity, eq. 2).
        far_field: use eq. 17 (ignore ``lever_arm``).
        axis_threshold: polar angle below which direction cosines are used.

    Stations with a non-finite angle, covariance or line of sight are left
    out; ``z`` holds the others.

    Example::

        >>> import numpy as np
        >>> from scipy.spatial.transform import Rotation
        >>> from attopt import DoaMeasurement
        >>> stations = np.array([[300.0, 100.0, 800.0], [-200.0, 400.0, 900.0]])  # km, orbit frame
        >>> doas = np.array([[0.4, 0.3], [0.5, 2.0]])  # theta, phi (rad); replaced below
        >>> m = DoaMeasurement(doas, np.tile(1e-6 * np.eye(2), (2, 1, 1)), stations)
        >>> m.predict(Rotation.identity())[0].round(3).tolist()  # the true DOAs at A = I
        [[0.376, 0.322, 0.461, 2.034]]
    """

    def __init__(
        self,
        angles: ArrayLike,
        covariance: ArrayLike,
        line_of_sight: ArrayLike,
        lever_arm: ArrayLike = (0.0, 0.0, 0.0),
        mounting: Rotation | None = None,
        far_field: bool = False,
        axis_threshold: float = AXIS_THRESHOLD,
    ) -> None:
        try:
            z = np.array(angles, dtype=float).reshape(-1, 2)
            k = z.shape[0]
            sigma = np.array(covariance, dtype=float).reshape(k, 2, 2)
            los = np.array(line_of_sight, dtype=float).reshape(k, 3)
            arm = np.array(lever_arm, dtype=float).reshape(3)
        except ValueError as exc:
            raise InvalidObservationError(
                f"DOAs must be (k, 2) with (k, 2, 2) covariances, (k, 3) lines of sight "
                f"and a (3,) lever arm: {exc}"
            ) from None
        if not np.all(np.isfinite(arm)):
            raise InvalidObservationError("lever arm must be finite")
        keep = (
            np.isfinite(z).all(axis=1)
            & np.isfinite(sigma).all(axis=(1, 2))
            & np.isfinite(los).all(axis=1)
        )
        z, sigma, los = z[keep], sigma[keep], los[keep]
        _check_stations(z, sigma, los)
        self.line_of_sight = los
        self.lever_arm = np.zeros(3) if far_field else arm
        self.mounting = Rotation.identity() if mounting is None else mounting
        self.near_axis = z[:, 0] < axis_threshold
        cosines = doa_unit_vector(z[:, 0], z[:, 1])[:, :2]
        jacobian = doa_jacobian(z[:, 0], z[:, 1])[:, :2, :]
        mapped = jacobian @ sigma @ jacobian.transpose(0, 2, 1)
        mapped = 0.5 * (mapped + mapped.transpose(0, 2, 1))
        sigma = np.where(self.near_axis[:, None, None], mapped, sigma)
        if np.any(np.linalg.eigvalsh(sigma) <= 0.0):
            raise InvalidObservationError(
                "DOA covariances must be positive definite (near the axis: in direction cosines)"
            )
        self.z = np.where(self.near_axis[:, None], cosines, z).ravel()
        self.noise_covariance = block_diag(*sigma) if len(z) else np.zeros((0, 0))
        self.blocks = np.repeat(np.arange(len(z)), 2)
        first = _ROWS_PER_STATION * np.arange(len(z)) + 2 * self.near_axis
        self._rows = np.column_stack([first, first + 1]).ravel()
        self._wrapped = np.column_stack([np.zeros(len(z), bool), ~self.near_axis]).ravel()

    def symbolic(self) -> SymbolicModel:
        """:func:`doa_model`'s measured rows (angles, or direction cosines near the axis);
        azimuth differences wrapped."""
        return SymbolicModel(
            doa_model,
            (self.line_of_sight, self.lever_arm, self.mounting.as_matrix()),
            rows=tuple(self._rows),
            innovation=wrapped_difference,
            innovation_parameters=(self._wrapped.astype(float),),
        )

    def predict(self, attitude: Rotation, jacobian: bool = True) -> tuple[Array, Array | None]:
        k = self.line_of_sight.shape[0]
        if k == 0:
            n = attitude.as_matrix().reshape(-1, 3, 3).shape[0]
            return np.empty((n, 0)), (np.empty((n, 0, 3)) if jacobian else None)
        h, jac = self.symbolic_model().evaluate_outputs(attitude)
        behind = np.repeat(~(h[:, 0::_ROWS_PER_STATION] < np.pi / 2).all(axis=0), 2)
        h, jac = h[:, self._rows], jac[:, self._rows]
        h[:, behind] = np.nan
        jac[:, behind] = np.nan
        return h, (jac if jacobian else None)

    def innovation(self, predicted: Array) -> Array:
        difference = self.z - predicted
        wrapped = (difference + np.pi) % (2.0 * np.pi) - np.pi
        return np.where(self._wrapped, wrapped, difference)


def _check_stations(angles: Array, covariance: Array, line_of_sight: Array) -> None:
    """Raise for a DOA outside the array's hemisphere, an asymmetric covariance or a null LOS."""
    theta = angles[:, 0]
    if np.any((theta < 0.0) | (theta >= np.pi / 2)):
        raise InvalidObservationError(
            "measured theta must lie in [0, pi/2): at or behind the array horizon "
            "a planar array cannot measure it"
        )
    if not np.allclose(covariance, covariance.transpose(0, 2, 1)):
        raise InvalidObservationError("DOA covariances must be symmetric")
    if np.any(np.linalg.norm(line_of_sight, axis=1) == 0.0):
        raise InvalidObservationError("a station's line of sight has zero length")
