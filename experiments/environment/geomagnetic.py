"""Geomagnetic field at the satellite: IGRF (Cilden Guler et al. 2017 eq. 1) via ppigrf.

``ppigrf.igrf(lon, lat, h, dates)`` evaluates every date at every position
(output shape ``(n_dates, n_positions)``), so calling it once with ``N`` epochs
would cost ``N^2``.  The IGRF Gauss coefficients are linear in time between
the five-yearly model epochs and the field is linear in the coefficients, so
within one five-year segment the field at a fixed position is linear in time.
:func:`igrf_enu` therefore evaluates each segment's positions at only its
earliest and latest epochs and interpolates linearly: exact, and linear in
``N``.  The model is ppigrf's default coefficient file (IGRF-14).
"""

from __future__ import annotations

import numpy as np
import ppigrf
from astropy.time import Time
from numpy.typing import ArrayLike, NDArray

from attopt.experiments.environment.orbit import ecef_to_eci_matrices


def igrf_enu(
    times: Time, longitude_deg: ArrayLike, latitude_deg: ArrayLike, height_km: ArrayLike
) -> NDArray[np.float64]:
    """IGRF field (east, north, up) in nT at geodetic positions, shape ``(N, 3)``.

    Args:
        times: 1-D array of ``N`` epochs.
        longitude_deg, latitude_deg, height_km: WGS84 geodetic coordinates of
            the ``N`` positions, each broadcastable to ``(N,)``.
    """
    stamps = times.utc.to_value("datetime64").astype("datetime64[ns]")
    lon, lat, height = np.broadcast_arrays(longitude_deg, latitude_deg, height_km, stamps)[:3]
    model_epochs = ppigrf.ppigrf.read_shc()[0].index.to_numpy().astype("datetime64[ns]")
    segment = np.searchsorted(model_epochs, stamps, side="right")
    field = np.empty((stamps.size, 3))
    for index in np.unique(segment):
        rows = np.flatnonzero(segment == index)
        first, last = stamps[rows].min(), stamps[rows].max()
        east, north, up = ppigrf.igrf(lon[rows], lat[rows], height[rows], np.array([first, last]))
        at_ends = np.stack([east, north, up], axis=-1)  # (2, rows, 3)
        elapsed = (stamps[rows] - first) / np.timedelta64(1, "ns")
        span = (last - first) / np.timedelta64(1, "ns")
        weight = elapsed / span if span > 0 else np.zeros(rows.size)
        field[rows] = at_ends[0] + weight[:, None] * (at_ends[1] - at_ends[0])
    return field


def enu_to_ecef_matrices(longitude_deg: ArrayLike, latitude_deg: ArrayLike) -> NDArray[np.float64]:
    """Matrices ``E`` with ``v_ecef = E @ [east, north, up]``, shape ``(..., 3, 3)``.

    The columns are the local east, north and up unit vectors of the WGS84
    ellipsoid (up is the ellipsoid normal) at geodetic longitude and latitude.
    """
    lon = np.radians(np.asarray(longitude_deg, dtype=float))
    lat = np.radians(np.asarray(latitude_deg, dtype=float))
    lon, lat = np.broadcast_arrays(lon, lat)
    zero = np.zeros_like(lon)
    east = np.stack([-np.sin(lon), np.cos(lon), zero], axis=-1)
    north = np.stack([-np.sin(lat) * np.cos(lon), -np.sin(lat) * np.sin(lon), np.cos(lat)], -1)
    up = np.stack([np.cos(lat) * np.cos(lon), np.cos(lat) * np.sin(lon), np.sin(lat)], axis=-1)
    return np.stack([east, north, up], axis=-1)


def geomagnetic_field_eci(
    times: Time, longitude_deg: ArrayLike, latitude_deg: ArrayLike, height_km: ArrayLike
) -> NDArray[np.float64]:
    """IGRF field vectors in ECI (GCRS) in nT, shape ``(N, 3)`` (Cilden Guler et al. 2017 eq. 1).

    The ENU field of :func:`igrf_enu` is rotated to ECEF with
    :func:`enu_to_ecef_matrices` and to ECI with
    :func:`~attopt.experiments.environment.orbit.ecef_to_eci_matrices`.
    """
    enu = igrf_enu(times, longitude_deg, latitude_deg, height_km)
    ecef = (enu_to_ecef_matrices(longitude_deg, latitude_deg) @ enu[..., None])[..., 0]
    return (ecef_to_eci_matrices(times) @ ecef[..., None])[..., 0]
