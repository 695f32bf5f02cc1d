"""Orbit propagation from a TLE (seed 002 sec. 2: TIMED orbit from its TLE).

SGP4 (:mod:`sgp4`) gives TEME states; astropy moves them to the frame attopt
calls ECI (GCRS: geocentric, axes of the ICRS) and to ECEF (ITRS), and gives
the WGS84 geodetic coordinates.  Positions are in km, velocities in km/s.
"""

from __future__ import annotations

from dataclasses import dataclass

import astropy.units as u
import numpy as np
from astropy.coordinates import GCRS, ITRS, TEME, CartesianDifferential, CartesianRepresentation
from astropy.time import Time
from numpy.typing import NDArray
from sgp4.api import SGP4_ERRORS, Satrec


@dataclass(frozen=True)
class OrbitStates:
    """Satellite states at ``N`` epochs (arrays of shape ``(N, 3)`` or ``(N,)``)."""

    times: Time
    position_eci_km: NDArray[np.float64]
    velocity_eci_kms: NDArray[np.float64]
    position_ecef_km: NDArray[np.float64]
    velocity_ecef_kms: NDArray[np.float64]
    longitude_deg: NDArray[np.float64]
    latitude_deg: NDArray[np.float64]
    """Geodetic (WGS84) latitude."""
    height_km: NDArray[np.float64]
    """Height above the WGS84 ellipsoid."""


def satellite_from_tle(line1: str, line2: str) -> Satrec:
    """SGP4 satellite record of a two-line element set."""
    return Satrec.twoline2rv(line1, line2)


def propagate(satellite: Satrec, times: Time) -> OrbitStates:
    """Propagate ``satellite`` to the 1-D array of UTC epochs ``times``.

    Raises:
        RuntimeError: if SGP4 reports an error at any epoch.
    """
    utc = times.utc
    error, position_teme, velocity_teme = satellite.sgp4_array(
        np.ascontiguousarray(utc.jd1, dtype=float), np.ascontiguousarray(utc.jd2, dtype=float)
    )
    if np.any(error):
        first = int(np.flatnonzero(error)[0])
        code = int(error[first])
        raise RuntimeError(
            f"SGP4 error {code} ({SGP4_ERRORS.get(code, 'unknown')}) at {utc[first].isot} "
            f"for satellite {satellite.satnum}"
        )
    teme = TEME(
        CartesianRepresentation(position_teme.T * u.km).with_differentials(
            CartesianDifferential(velocity_teme.T * (u.km / u.s))
        ),
        obstime=times,
    )
    eci = teme.transform_to(GCRS(obstime=times))
    ecef = teme.transform_to(ITRS(obstime=times))
    geodetic = ecef.earth_location.to_geodetic("WGS84")
    return OrbitStates(
        times=times,
        position_eci_km=eci.cartesian.xyz.to_value(u.km).T,
        velocity_eci_kms=eci.velocity.d_xyz.to_value(u.km / u.s).T,
        position_ecef_km=ecef.cartesian.xyz.to_value(u.km).T,
        velocity_ecef_kms=ecef.velocity.d_xyz.to_value(u.km / u.s).T,
        longitude_deg=geodetic.lon.to_value(u.deg),
        latitude_deg=geodetic.lat.to_value(u.deg),
        height_km=geodetic.height.to_value(u.km),
    )


def ecef_to_eci_matrices(times: Time) -> NDArray[np.float64]:
    """Rotation matrices ``M`` with ``v_eci = M @ v_ecef``, shape ``(N, 3, 3)``.

    Obtained by transforming the three ITRS unit axes to GCRS with astropy; for
    geocentric vectors this transformation is a pure rotation, so ``M`` moves
    direction vectors (Sun, magnetic field) between the frames.
    """
    n = times.size
    axes = np.repeat(np.eye(3), n, axis=0)  # ITRS x axis at every epoch, then y, then z
    obstime = times[np.tile(np.arange(n), 3)]
    itrs = ITRS(CartesianRepresentation(axes.T * u.km), obstime=obstime)
    columns = itrs.transform_to(GCRS(obstime=obstime)).cartesian.xyz.to_value(u.km)
    return np.moveaxis(columns.reshape(3, 3, n), -1, 0)
