"""Cylindrical Earth shadow (the eclipse of Cilden Guler et al. 2017 sec. 3)."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

EARTH_RADIUS_KM = 6378.137
"""WGS84 equatorial radius, the radius of the shadow cylinder."""


def in_cylindrical_shadow(position_km: ArrayLike, sun_direction: ArrayLike) -> NDArray[np.bool_]:
    """Whether each position lies in the Earth's cylindrical shadow.

    With ``s`` the unit Sun direction, a position ``r`` is in shadow iff
    ``r . s < 0`` and ``|r - (r . s) s| < R_E``.

    Args:
        position_km: geocentric positions, shape ``(..., 3)`` in km.
        sun_direction: unit Sun directions in the same frame, shape ``(..., 3)``.
    """
    r = np.asarray(position_km, dtype=float)
    s = np.asarray(sun_direction, dtype=float)
    along = np.sum(r * s, axis=-1)
    across = np.linalg.norm(r - along[..., None] * s, axis=-1)
    return (along < 0.0) & (across < EARTH_RADIUS_KM)
