"""Line of sight to a GEO broadcaster from SNRs at ground stations.

Pimienta-Penalver and Crassidis sec. IV.A.

With the RF parameters and the attitude (or just the boresight,
:func:`attopt.formulations.geo_link.attitude_pointing`) known, the satellite is
placed on the geostationary belt (Pimienta-Penalver and Crassidis assumption 1: equatorial, radius
:data:`~attopt.formulations.geo_geometry.GEO_RADIUS_KM`, ECEF) at the longitude
``lambda`` whose predicted SNRs (eq. 7) fit the measured ones:

1. exhaustive search over the visible belt (every station above its horizon,
   every station inside the main lobe) on a grid of ``step_deg``;
2. nonlinear least squares in ``lambda`` (scipy ``least_squares``) from the
   best grid point, with the derivative of the symbolic SNR model by CasADi AD.

The lines of sight from the stations follow.  Several longitudes can fit a
single station's SNR; a ``window_deg`` (a-priori longitude interval) or more
stations resolve it.  All positions and the attitude refer to ECEF.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from attopt.formulations.errors import ConvergenceError, InvalidObservationError, UnobservableError
from attopt.formulations.geo_geometry import GEO_RADIUS_KM, belt_position
from attopt.formulations.geo_link import BORESIGHT_BODY, GARUDA1, GeoLink, elevation_rad, geo_snr_db
from attopt.formulations.snr_model import observation_mask

Array = NDArray[np.float64]


@dataclass(frozen=True)
class BeltSolution:
    """Satellite on the GEO belt fitted to the SNRs."""

    longitude_rad: float
    search_longitude_rad: float
    """Best grid point of the search."""
    satellite_km: Array
    """``(3,)`` ECEF position."""
    los: Array
    """``(m, 3)`` unit lines of sight station -> satellite."""
    residual_rms: float
    """RMS of the normalised SNR residuals at the solution."""


@lru_cache(maxsize=16)
def _belt_snr_function(link: GeoLink, m: int) -> ca.Function:
    """``(lambda, A, stations, R) -> (SNR[m], dSNR/dlambda[m])`` by CasADi AD."""
    lon, radius = ca.SX.sym("lambda"), ca.SX.sym("radius")
    attitude, stations = ca.SX.sym("attitude", 3, 3), ca.SX.sym("stations", m, 3)
    satellite = radius * ca.vertcat(ca.cos(lon), ca.sin(lon), 0)
    snr = geo_snr_db(attitude, satellite, stations, link)
    return ca.Function("belt_snr", [lon, attitude, stations, radius], [snr, ca.jacobian(snr, lon)])


def locate_on_geo_belt(
    snr_db: ArrayLike,
    stations_km: ArrayLike,
    stations_up: ArrayLike,
    attitude: Rotation,
    sigma_db: ArrayLike,
    link: GeoLink = GARUDA1,
    step_deg: float = 0.01,
    window_deg: tuple[float, float] = (-180.0, 180.0),
    radius_km: float = GEO_RADIUS_KM,
) -> BeltSolution:
    """Search and least-squares refinement of the belt longitude (module docstring).

    ``attitude`` maps ECEF to the body frame.  Raises
    :class:`InvalidObservationError` for malformed input,
    :class:`UnobservableError` if no point of the window is visible from every
    station with every station in the main lobe, and :class:`ConvergenceError`
    if the refinement fails.
    """
    y = np.asarray(snr_db, dtype=float)
    stations = np.asarray(stations_km, dtype=float)
    sigma = np.broadcast_to(np.asarray(sigma_db, dtype=float), y.shape)
    if y.ndim != 1 or y.size < 1 or stations.shape != (y.size, 3):
        raise InvalidObservationError(f"need (m,) SNRs and (m, 3) stations, got {y.shape}")
    if not (np.all(np.isfinite(y)) and np.all(np.isfinite(sigma)) and np.all(sigma > 0)):
        raise InvalidObservationError("SNRs must be finite and sigmas finite and positive")
    matrix = attitude.as_matrix()
    grid = np.radians(np.arange(window_deg[0], window_deg[1] + 0.5 * step_deg, step_deg))
    candidates = belt_position(grid, radius_km)
    relative = stations[None] - candidates[:, None]
    usable = np.all(
        (elevation_rad(stations[None], stations_up, candidates[:, None]) > 0)
        & observation_mask(matrix, relative, BORESIGHT_BODY, link.pattern),
        axis=1,
    )
    if not usable.any():
        raise UnobservableError(
            "no point of the GEO belt window is above every station's horizon with every "
            "station inside the main lobe"
        )
    predicted = geo_snr_db(matrix, candidates[usable], stations, link)
    cost = np.sum(((predicted - y) / sigma) ** 2, axis=1)
    start = float(grid[usable][int(np.argmin(cost))])
    function = _belt_snr_function(link, y.size)
    step = np.radians(step_deg)

    def residual(x: Array) -> Array:
        return (function(x[0], matrix, stations, radius_km)[0].full().ravel() - y) / sigma

    def jacobian(x: Array) -> Array:
        return function(x[0], matrix, stations, radius_km)[1].full() / sigma[:, None]

    fit = least_squares(
        residual,
        [start],
        jac=jacobian,
        bounds=([start - 2 * step], [start + 2 * step]),
        xtol=1e-15,
        ftol=1e-15,
        gtol=1e-15,
    )
    if not fit.success:
        raise ConvergenceError(f"belt longitude refinement failed: {fit.message}")
    satellite = belt_position(fit.x[0], radius_km)
    los = satellite - stations
    return BeltSolution(
        longitude_rad=float(fit.x[0]),
        search_longitude_rad=start,
        satellite_km=satellite,
        los=los / np.linalg.norm(los, axis=1, keepdims=True),
        residual_rms=float(np.sqrt(np.mean(fit.fun**2))),
    )
