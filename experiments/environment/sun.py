"""Sun direction from the satellite (Cilden Guler et al. 2017 eq. 3, via astropy).

The direction is *apparent*: :func:`astropy.coordinates.get_sun` returns the
geocentric Sun in GCRS corrected for the annual aberration of an observer at
the Earth's centre (about 20 arcsec from the geometric direction).  The
satellite's own orbital velocity would add up to about 5 arcsec more and is
neglected; both are far below the 0.002 Sun-sensor noise of Cilden Guler et al. 2017 sec. 3.
The analytic VSOP2000-based ephemeris needs no data file.
"""

from __future__ import annotations

import astropy.units as u
import numpy as np
from astropy.coordinates import get_sun
from astropy.time import Time
from numpy.typing import ArrayLike, NDArray


def sun_direction_eci(times: Time, position_eci_km: ArrayLike) -> NDArray[np.float64]:
    """Unit vectors from the satellite to the Sun in ECI (GCRS), shape ``(N, 3)``.

    The satellite position is subtracted from the geocentric Sun vector
    (parallax, up to about 10 arcsec in low Earth orbit).

    Args:
        times: 1-D array of epochs.
        position_eci_km: satellite GCRS positions, shape ``(N, 3)`` in km.
    """
    sun_km = get_sun(times).cartesian.xyz.to_value(u.km).T
    line_of_sight = sun_km - np.asarray(position_eci_km, dtype=float)
    return line_of_sight / np.linalg.norm(line_of_sight, axis=-1, keepdims=True)
