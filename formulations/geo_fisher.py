"""Attitude information in a GEO broadcaster's SNRs (Pimienta-Penalver and Crassidis sec. V).

With SNRs ``y = h(A) + n``, ``n ~ N(0, sigma^2 I)``, the Fisher information of
the attitude error is ``F = H^T H / sigma^2`` (eqs. 13-14), ``H = dh / d delta``.
Pimienta-Penalver and Crassidis derive ``H`` by hand (eqs. 15-24); here it is CasADi's
automatic derivative of the one SNR model (:func:`attopt.formulations.geo_link.geo_snr_db` in
the form of :func:`attopt.formulations.snr_model.predict_snr`), with respect to
attopt's body-frame error ``delta`` of ``exp(delta) A``.  The paper's ``delta alpha``
(eq. 17, ``A_hat = exp(-[delta alpha x]) A``) is ``-delta``:
``F`` and its nullspace are the same.

A single SNR depends on the attitude only through ``theta_b``, the angle
between the boresight ``z_B`` and the line of sight ``l_B``.  Rotations about
``z_B`` (the pattern's symmetry axis) and about ``l_B`` (which keeps the line
of sight) leave it unchanged, so the nullspace of one SNR's ``F`` is
``span{z_B, l_B}`` = ``span{[0 0 1], [l_x l_y 0]}``: the boresight and the
line of sight projected on the body x-y plane, Pimienta-Penalver and Crassidis eq. 25
(whose second vector ``[l_x / l_y, 1, 0]`` is the same direction).  The only non-zero
eigenvalue, ``|H|^2 / sigma^2``, is the "information magnitude" of Fig. 8.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.geo_link import (
    BORESIGHT_BODY,
    GARUDA1,
    GeoLink,
    attitude_pointing,
    station_terms,
)
from attopt.formulations.snr_model import fisher_information, predict_snr

Array = NDArray[np.float64]


def snr_attitude_jacobian(
    attitude: Rotation, satellite_km: ArrayLike, stations_km: ArrayLike, link: GeoLink = GARUDA1
) -> tuple[Array, Array]:
    """SNRs ``(m,)`` (eq. 7) and ``dSNR / d delta`` ``(m, 3)`` (dB/rad) by CasADi AD."""
    los, p0 = station_terms(satellite_km, stations_km, link)
    return predict_snr(attitude, los, BORESIGHT_BODY, p0, link.noise_dbw, link.pattern)


def snr_fisher_information(
    attitude: Rotation,
    satellite_km: ArrayLike,
    stations_km: ArrayLike,
    sigma_db: ArrayLike,
    link: GeoLink = GARUDA1,
) -> Array:
    """``F = sum_k H_k^T H_k / sigma_k^2`` (rad^-2, body frame), eq. 14 for every station."""
    _, jacobian = snr_attitude_jacobian(attitude, satellite_km, stations_km, link)
    return fisher_information(jacobian, sigma_db)


def information_magnitude(jacobian: ArrayLike, sigma_db: ArrayLike) -> Array:
    """``|H_k|^2 / sigma_k^2``: the non-zero eigenvalue of each single SNR's ``F`` (Fig. 8)."""
    h = np.asarray(jacobian, dtype=float)
    return np.sum(h * h, axis=-1) / np.asarray(sigma_db, dtype=float) ** 2


def single_snr_nullspace(
    attitude: Rotation, satellite_km: ArrayLike, station_km: ArrayLike
) -> Array:
    """Pimienta-Penalver and Crassidis eq. 25: ``(2, 3)`` unit rows ``[0 0 1]`` and
    ``[l_x l_y 0] / |.|`` (body frame).

    ``l = A (r_GS - r_RSO)``; eq. 25 writes ``r_RSO - r_GS``, the opposite
    sign, which spans the same line.
    """
    los_body = attitude.apply(np.asarray(station_km, float) - np.asarray(satellite_km, float))
    projected = np.array([los_body[0], los_body[1], 0.0])
    return np.stack([BORESIGHT_BODY, projected / np.linalg.norm(projected)])


def information_map(
    satellite_km: ArrayLike,
    station_km: ArrayLike,
    roll_rad: ArrayLike,
    pitch_rad: ArrayLike,
    sigma_db: float,
    link: GeoLink = GARUDA1,
) -> Array:
    """Information magnitude ``(n_roll, n_pitch)`` about the attitude pointing at the station.

    Pimienta-Penalver and Crassidis Fig. 8: the base attitude has its boresight on the line
    of sight to ``station_km`` (``theta_b = 0``,
    :func:`attopt.formulations.geo_link.attitude_pointing`);
    each grid point is ``exp([roll, pitch, 0]) A_base`` (body-frame rotations).
    """
    los = np.asarray(station_km, float) - np.asarray(satellite_km, float)
    base = attitude_pointing(los)
    roll, pitch = np.meshgrid(np.asarray(roll_rad, float), np.asarray(pitch_rad, float))
    offsets = np.stack([roll.T.ravel(), pitch.T.ravel(), np.zeros(roll.size)], axis=-1)
    attitudes = Rotation.from_rotvec(offsets) * base
    los_unit, p0 = station_terms(satellite_km, np.asarray(station_km, float)[None], link)
    _, jacobian = predict_snr(
        attitudes, los_unit[None], BORESIGHT_BODY, p0[None], link.noise_dbw, link.pattern
    )
    return information_magnitude(jacobian[:, 0], sigma_db).reshape(roll.T.shape)
