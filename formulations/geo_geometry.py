"""Geometry of a geostationary broadcaster seen from ground stations (Pimienta-Penalver
and Crassidis, assumption 1 and sec. IV.A).

The satellite sits on the geostationary belt: equatorial, at radius
:data:`GEO_RADIUS_KM` from the Earth's centre, at longitude ``lambda`` (ECEF,
:func:`belt_position`).  A line of sight runs from a station to the
satellite; :func:`line_of_sight_errors` is the angle between an estimated and
the true one.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

GEO_RADIUS_KM = 42_164.17
"""Radius of the geostationary orbit (km)."""


def belt_position(longitude_rad: ArrayLike, radius_km: float = GEO_RADIUS_KM) -> Array:
    """ECEF positions ``(..., 3)`` on the equatorial belt at ``longitude_rad``."""
    lon = np.asarray(longitude_rad, dtype=float)
    return radius_km * np.stack([np.cos(lon), np.sin(lon), np.zeros_like(lon)], axis=-1)


def line_of_sight_errors(
    estimate_km: ArrayLike, truth_km: ArrayLike, stations_km: ArrayLike
) -> Array:
    """Angle (rad) between estimated and true lines of sight station -> satellite, ``(m,)``."""
    stations = np.asarray(stations_km, dtype=float)
    a = np.asarray(estimate_km, dtype=float) - stations
    b = np.asarray(truth_km, dtype=float) - stations
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))
