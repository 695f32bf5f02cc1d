"""Boresight of a GEO broadcaster from SNRs at ground stations (seed 004 sec. IV.B, eq. 12).

Each station's SNR is inverted through the link of seed 004 eq. 7
(:mod:`attopt.formulations.geo_link`, satellite position and RF parameters known) for
the transmit gain and, through the main lobe of eq. 5
(:func:`attopt.solvers.snr.pattern_inverse.cos_from_gain`), for the off-boresight
angle ``theta_b``: the boresight ``B`` lies on the cone ``l . B = cos theta_b``
about the unit line of sight ``l`` from the satellite to the station.

* :func:`cone_intersection`: two cones with a common vertex meet in (at most)
  two directions (eq. 12)::

      rho = l_1 . l_2,
      eta_1 = (c_1 - rho c_2) / (1 - rho^2),  eta_2 = (c_2 - rho c_1) / (1 - rho^2),
      eta_3 = +-sqrt((1 - eta_1 c_1 - eta_2 c_2) / (1 - rho^2)),
      B = eta_1 l_1 + eta_2 l_2 + eta_3 (l_1 x l_2),

  and a third cone picks one of them.  Of the three stations given, the pair
  with the widest angle between its lines of sight is intersected and the
  third station selects.  Fewer than three stations: the two candidates
  cannot be told apart (:class:`~attopt.formulations.errors.UnobservableError`).
  A negative radicand (noisy SNRs: the cones miss each other) falls back to
  least squares over the same stations, flagged with the reason.
* :func:`least_squares_boresight`: every station, the constrained weighted
  least squares ``min sum ((l_k . B - c_k) / sigma_k)^2, |B| = 1`` of
  :func:`attopt.solvers.snr.boresight.estimate_boresight`, ``sigma_k`` the SNR noise
  mapped to ``cos theta_b``.

A station that does not see the satellite (elevation below 0) is rejected
with :class:`~attopt.formulations.errors.InvalidObservationError` naming it.
:func:`rf_sensitivity` measures the boresight error when the solver is given
wrong RF parameters (seed 004 Fig. 6).
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.errors import InvalidObservationError, UnobservableError
from attopt.formulations.geo_link import (
    BORESIGHT_BODY,
    GARUDA1,
    GeoLink,
    elevation_rad,
    geo_snr_db,
    station_terms,
)
from attopt.solvers.snr.boresight import estimate_boresight
from attopt.solvers.snr.pattern_inverse import cos_from_gain

Array = NDArray[np.float64]

MIN_STATIONS = 3
"""Two cones meet in two directions; a third cone is needed to choose (seed 004 sec. IV.B)."""


@dataclass(frozen=True)
class StationCones:
    """Cones ``l_k . B = c_k`` of ``m`` stations (frame of the positions)."""

    los: Array
    """``(m, 3)`` unit lines of sight satellite -> station."""
    cos_off_boresight: Array
    """``(m,)`` ``c_k = cos theta_bk`` from the SNRs."""
    sigma_cos: Array
    """``(m,)`` standard deviation of ``c_k`` from the SNR noise."""
    clamped: int
    """Gains outside the main lobe's range, clamped to it (noise or wrong RF parameters)."""


@dataclass(frozen=True)
class BoresightSolution:
    """Estimated unit boresight in the frame of the positions."""

    direction: Array
    method: str
    """``"cone_intersection"`` or ``"least_squares"``."""
    fell_back: bool
    """True when cone intersection was asked for but the cones do not intersect."""
    reason: str
    """Why it fell back (``""`` otherwise)."""
    selection_margin: float
    """Cone intersection: residual of the rejected candidate on the third cone minus
    that of the kept one (``cos`` units); NaN for least squares."""


def station_cones(
    snr_db: ArrayLike,
    satellite_km: ArrayLike,
    stations_km: ArrayLike,
    stations_up: ArrayLike,
    sigma_db: ArrayLike,
    link: GeoLink = GARUDA1,
) -> StationCones:
    """Invert eq. 7 at each station for ``cos theta_b`` (module docstring).

    Raises :class:`InvalidObservationError` for malformed input or a station
    with the satellite below its horizon.
    """
    snr = np.asarray(snr_db, dtype=float)
    stations = np.asarray(stations_km, dtype=float)
    if snr.ndim != 1 or stations.shape != (snr.size, 3):
        raise InvalidObservationError(
            f"expected (m,) SNRs and (m, 3) stations, got {snr.shape} and {stations.shape}"
        )
    sigma = np.broadcast_to(np.asarray(sigma_db, dtype=float), snr.shape)
    if not (np.all(np.isfinite(snr)) and np.all(np.isfinite(sigma)) and np.all(sigma > 0)):
        raise InvalidObservationError("SNRs must be finite and sigmas finite and positive")
    elevation = elevation_rad(stations, stations_up, satellite_km)
    below = np.flatnonzero(~(elevation >= 0.0))
    if below.size:
        raise InvalidObservationError(
            f"station(s) {below.tolist()} have the satellite below the horizon (elevation "
            f"{np.degrees(elevation[below]).round(2).tolist()} deg): no line of sight"
        )
    los, p0 = station_terms(satellite_km, stations, link)
    cosine, slope, clamped = cos_from_gain(link.pattern, snr - p0 + link.noise_dbw)
    return StationCones(los, cosine, np.abs(slope) * sigma, clamped)


def _pair_candidates(los: Array, cosine: Array) -> tuple[Array, float]:
    """The two directions on both cones (eq. 12) and the radicand ``eta_3^2``."""
    rho = float(los[0] @ los[1])
    sine2 = 1.0 - rho * rho
    eta1 = (cosine[0] - rho * cosine[1]) / sine2
    eta2 = (cosine[1] - rho * cosine[0]) / sine2
    radicand = (1.0 - eta1 * cosine[0] - eta2 * cosine[1]) / sine2
    eta3 = np.sqrt(max(radicand, 0.0))
    base = eta1 * los[0] + eta2 * los[1]
    normal = np.cross(los[0], los[1])
    return np.stack([base + eta3 * normal, base - eta3 * normal]), radicand


def cone_intersection(cones: StationCones) -> BoresightSolution:
    """Boresight from the first three stations' cones (eq. 12), least squares if they miss."""
    if cones.los.shape[0] < MIN_STATIONS:
        raise UnobservableError(
            f"{cones.los.shape[0]} station(s): cone intersection needs three; two cones about "
            "different lines of sight meet in two directions and nothing chooses between them"
        )
    los, cosine = cones.los[:MIN_STATIONS], cones.cos_off_boresight[:MIN_STATIONS]
    pairs = list(itertools.combinations(range(MIN_STATIONS), 2))
    i, j = max(pairs, key=lambda p: np.linalg.norm(np.cross(los[p[0]], los[p[1]])))
    (k,) = set(range(MIN_STATIONS)) - {i, j}
    candidates, radicand = _pair_candidates(los[[i, j]], cosine[[i, j]])
    if radicand < 0.0:
        fallback = least_squares_boresight(
            dataclasses.replace(
                cones,
                los=los,
                cos_off_boresight=cosine,
                sigma_cos=cones.sigma_cos[:MIN_STATIONS],
            )
        )
        reason = (
            f"cones of stations {i} and {j} do not intersect (radicand {radicand:.3g} < 0): "
            "least-squares fallback"
        )
        return dataclasses.replace(fallback, fell_back=True, reason=reason)
    residual = np.abs(candidates @ los[k] - cosine[k])
    keep = int(np.argmin(residual))
    direction = candidates[keep] / np.linalg.norm(candidates[keep])
    margin = float(residual[1 - keep] - residual[keep])
    return BoresightSolution(direction, "cone_intersection", False, "", margin)


def least_squares_boresight(cones: StationCones) -> BoresightSolution:
    """Constrained weighted least squares over every station's cone (module docstring)."""
    m = cones.los.shape[0]
    if m < MIN_STATIONS:
        raise UnobservableError(
            f"{m} station(s): the boresight needs three cones (two leave a two-fold ambiguity)"
        )
    prior = cones.los.mean(axis=0)
    estimate = estimate_boresight(cones.los, cones.cos_off_boresight, cones.sigma_cos, prior)
    if estimate.two_fold:
        raise UnobservableError(
            "the stations' lines of sight are coplanar: two boresights fit the SNRs equally well"
        )
    return BoresightSolution(estimate.direction, "least_squares", False, "", np.nan)


def boresight_error_rad(estimate: ArrayLike, truth: ArrayLike) -> float:
    """Angle between two boresight directions (rad), accurate at any angle."""
    a, b = np.asarray(estimate, dtype=float), np.asarray(truth, dtype=float)
    return float(np.arctan2(np.linalg.norm(np.cross(a, b)), a @ b))


@dataclass(frozen=True)
class RfSensitivity:
    """Boresight errors (rad) on a grid of assumed transmit powers x dish diameters."""

    transmit_power_w: Array
    dish_diameter_m: Array
    error_rad: Array
    """``(n_power, n_diameter)``."""
    fell_back: NDArray[np.bool_]
    """Where cone intersection fell back to least squares."""


def rf_sensitivity(
    truth: Rotation,
    satellite_km: ArrayLike,
    stations_km: ArrayLike,
    stations_up: ArrayLike,
    transmit_power_w: ArrayLike,
    dish_diameter_m: ArrayLike,
    link: GeoLink = GARUDA1,
    method: str = "cone_intersection",
) -> RfSensitivity:
    """Boresight error with noise-free SNRs of ``link`` inverted with wrong ``P_t`` and ``D``.

    Seed 004 Fig. 6: the SNRs are those of the true attitude and ``link``;
    the solver assumes each (``P_t``, ``D``) pair of the grid instead.
    """
    snr = geo_snr_db(truth.as_matrix(), satellite_km, stations_km, link)
    true_boresight = truth.inv().apply(BORESIGHT_BODY)
    powers = np.asarray(transmit_power_w, dtype=float)
    diameters = np.asarray(dish_diameter_m, dtype=float)
    error = np.empty((powers.size, diameters.size))
    fell_back = np.zeros(error.shape, dtype=bool)
    solvers = {"cone_intersection": cone_intersection, "least_squares": least_squares_boresight}
    if method not in solvers:
        raise InvalidObservationError(f"method must be one of {sorted(solvers)}, got {method!r}")
    solve = solvers[method]
    for (a, power), (b, diameter) in itertools.product(enumerate(powers), enumerate(diameters)):
        assumed = dataclasses.replace(link, transmit_power_w=power, dish_diameter_m=diameter)
        cones = station_cones(snr, satellite_km, stations_km, stations_up, 1.0, assumed)
        solution = solve(cones)
        error[a, b] = boresight_error_rad(solution.direction, true_boresight)
        fell_back[a, b] = solution.fell_back
    return RfSensitivity(powers, diameters, error, fell_back)
