"""Scenario ``geo-snr-stations``: Garuda-1 seen by eight ground stations.

Pimienta-Penalver and Crassidis secs. II.A and V.B.

Orbit.  The TLE printed in Pimienta-Penalver and Crassidis sec. II.A (re-spaced to the fixed TLE
columns; both checksums hold) propagated with SGP4 and moved to ECI (GCRS) and
ECEF (ITRS) by :mod:`attopt.experiments.environment.orbit` (offline: the package
forbids IERS downloads).  Its epoch is the simulation start,
:data:`START_UTC` = 2015-11-30 17:00:00 UTC; Garuda-1 sits at 123.0 deg E.

Stations.  The eight of Table 2, geodetic on the WGS84 ellipsoid converted
to ECEF by astropy ``EarthLocation``; their up vectors are the ellipsoid
normals.  ECI positions follow with astropy's ECEF -> ECI matrices.

Attitude (ECI -> body, ``docs/conventions.md``).  Pimienta-Penalver and Crassidis eq. 27 gives
``q = [-0.0176892, -0.706875, 0.706868, 0.0187807]``, scalar last, in the
convention of its ref. 8 (Markley and Crassidis), i.e. the Shuster quaternion
of Cilden Guler et al. 2017 eq. 21, the conjugate of scipy's: ``A_0 =
Rotation.from_quat(q).inv()`` (``attopt.formulations.conventions.
attitude_from_shuster_quaternion``).  With it the boresight (body ``+z``)
points 0.003 deg from nadir, at the sub-satellite point; read as a scipy
quaternion it would point 3 deg away, off the Earth's centre towards 105.5 deg E.
The body then turns about the ECI ``z`` axis (north) at ``Omega = omega_E + s``:
``A(t) = A_0 R_z(Omega t)^T``, a constant body rate ``Omega A_0 z``.  The
Earth rate keeps the beam on the ground; the extra ``s`` =
:data:`SLEW_RATE_DEG_PER_H` (1 deg/h) turns it west of nadir, a slow westward
slew of the footprint (about 5.6 deg of longitude per hour),
Pimienta-Penalver and Crassidis sec. V.B.

Manoeuvre (option, Pimienta-Penalver and Crassidis Fig. 10).  From :data:`MANOEUVRE_START_S` (30
min) the body turns by :data:`MANOEUVRE_ANGLE_DEG` (25 deg) at a constant
rate over :data:`MANOEUVRE_DURATION_S` about the nadir direction at the
start of the manoeuvre (a yaw about the local vertical, the usual GEO attitude
manoeuvre that keeps the Earth in view); the slew goes on.  Because the beam
is then 0.5 deg west of nadir it swings by about ``2 sin(12.5 deg) 0.5 deg =
0.22 deg``: the footprint moves by about 140 km and the SNRs change by dB
(observable), while most of the 25 deg is a rotation about an axis close to
the boresight (nearly unobservable).  A 25 deg turn about an axis
perpendicular to the boresight would point the beam off the Earth (whose
radius seen from GEO is 8.7 deg).

SNRs.  Noise-free SNRs are Pimienta-Penalver and Crassidis eq. 7
(:func:`attopt.formulations.geo_link.geo_snr_db`).
A station hears the satellite when it is above its horizon and the
noise-free SNR is at least :data:`DETECTION_THRESHOLD_DB` (0 dB, the lowest
SNR of Table 3).  Measured SNRs add Gaussian noise of :data:`SNR_SIGMA_DB`
(0.0148 dB, the M2M4 error Pimienta-Penalver and Crassidis use for their filter's
``R``) drawn from the caller's generator.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import astropy.units as u
import numpy as np
from astropy.coordinates import EarthLocation
from astropy.time import Time
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from attopt.experiments.environment.orbit import ecef_to_eci_matrices, propagate, satellite_from_tle
from attopt.experiments.environment.traffic import geodetic_normal
from attopt.formulations.conventions import attitude_from_shuster_quaternion
from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.geo_link import (
    BORESIGHT_BODY,
    GARUDA1,
    GeoLink,
    elevation_rad,
    geo_snr_db,
    geo_snr_epoch,
)
from attopt.formulations.snr_measurement import SnrMeasurement

Array = NDArray[np.float64]

TLE = (
    "1 26089U 00011A   15334.70833333 -.00000218  00000-0  71783+4 0 00007",
    "2 26089 000.0128 195.9086 0000123 075.1421 176.2140 01.00270682000010",
)
"""Garuda-1 (Pimienta-Penalver and Crassidis sec. II.A)."""
START_UTC = "2015-11-30T17:00:00"
INITIAL_QUATERNION = (-0.0176892, -0.706875, 0.706868, 0.0187807)
"""Pimienta-Penalver and Crassidis eq. 27, Shuster convention (scalar last)."""
EARTH_RATE_RAD_S = 7.292115e-5
"""Earth's sidereal rotation rate (IERS conventions)."""
SLEW_RATE_DEG_PER_H = 1.0
MANOEUVRE_START_S = 1800.0
MANOEUVRE_ANGLE_DEG = 25.0
MANOEUVRE_DURATION_S = 120.0
SNR_SIGMA_DB = 0.0148
DETECTION_THRESHOLD_DB = 0.0


@dataclass(frozen=True)
class GroundStation:
    """A receiving station (Pimienta-Penalver and Crassidis Table 2), geodetic WGS84."""

    name: str
    latitude_deg: float
    longitude_deg: float
    altitude_m: float


STATIONS = (
    GroundStation("Tainan", 23.0149, 120.176, 19.0),
    GroundStation("Kuala Lumpur", 3.25006, 101.614, 53.0),
    GroundStation("Surabaya", -7.28252, 112.833, 5.0),
    GroundStation("Darwin", -12.4501, 130.872, 23.0),
    GroundStation("Coral Bay", -23.1484, 113.773, 32.0),
    GroundStation("Keeling Islands", -12.1541, 96.8243, 1.0),
    GroundStation("General Santos", 6.086357, 125.1304, 15.0),
    GroundStation("Labuan", 5.298122, 115.207, 76.0),
)
"""Pimienta-Penalver and Crassidis Table 2, in its order."""


def stations_ecef_km(stations: tuple[GroundStation, ...] = STATIONS) -> tuple[Array, Array]:
    """ECEF positions (km) and unit geodetic up vectors of ``stations``, each ``(m, 3)``."""
    lat = np.array([s.latitude_deg for s in stations])
    lon = np.array([s.longitude_deg for s in stations])
    location = EarthLocation.from_geodetic(
        lon=lon * u.deg,
        lat=lat * u.deg,
        height=np.array([s.altitude_m for s in stations]) * u.m,
        ellipsoid="WGS84",
    )
    position = np.stack([location.x, location.y, location.z], axis=-1).to_value(u.km)
    return position, geodetic_normal(lat, lon)


def initial_attitude() -> Rotation:
    """``A_0`` (ECI -> body) of Pimienta-Penalver and Crassidis eq. 27 (module docstring)."""
    return attitude_from_shuster_quaternion(INITIAL_QUATERNION)


def true_attitude(t: ArrayLike, manoeuvre_axis_eci: ArrayLike | None = None) -> Rotation:
    """``A(t)`` (ECI -> body) at ``t`` seconds from :data:`START_UTC` (module docstring).

    ``manoeuvre_axis_eci``: unit nadir at :data:`MANOEUVRE_START_S` to add the
    manoeuvre, ``None`` for the slew alone.
    """
    t = np.atleast_1d(np.asarray(t, dtype=float))
    rate = EARTH_RATE_RAD_S + np.radians(SLEW_RATE_DEG_PER_H) / 3600.0
    turn = Rotation.from_rotvec(np.outer(rate * t, [0.0, 0.0, 1.0]))
    if manoeuvre_axis_eci is not None:
        axis = np.asarray(manoeuvre_axis_eci, dtype=float)
        fraction = np.clip((t - MANOEUVRE_START_S) / MANOEUVRE_DURATION_S, 0.0, 1.0)
        yaw = Rotation.from_rotvec(np.outer(np.radians(MANOEUVRE_ANGLE_DEG) * fraction, axis))
        before = Rotation.from_rotvec([0.0, 0.0, rate * MANOEUVRE_START_S])
        turn = turn * before.inv() * yaw * before
    return initial_attitude() * turn.inv()


@dataclass(frozen=True)
class GeoSnrScenario:
    """True geometry and noise-free SNRs at ``N`` epochs for ``m`` stations (ECI unless named)."""

    t: Array
    """Seconds from :data:`START_UTC`, ``(N,)``."""
    satellite_eci_km: Array
    satellite_ecef_km: Array
    stations: tuple[GroundStation, ...]
    stations_ecef_km: Array
    """``(m, 3)``."""
    stations_eci_km: Array
    """``(N, m, 3)``."""
    stations_up_eci: Array
    """``(N, m, 3)`` unit geodetic up vectors."""
    elevation_rad: Array
    """``(N, m)`` elevation of the satellite at each station."""
    truth: Rotation
    """ECI -> body, ``N`` rotations."""
    true_snr_db: Array
    """``(N, m)`` noise-free SNRs (eq. 7)."""
    link: GeoLink
    manoeuvre: bool

    @property
    def heard(self) -> NDArray[np.bool_]:
        """``(N, m)``: above the horizon with a noise-free SNR >= :data:`DETECTION_THRESHOLD_DB`."""
        return (self.elevation_rad > 0) & (self.true_snr_db >= DETECTION_THRESHOLD_DB)

    @property
    def boresight_eci(self) -> Array:
        """True unit boresights ``(N, 3)``."""
        return self.truth.inv().apply(BORESIGHT_BODY)

    def simulate_snr(self, rng: np.random.Generator, sigma_db: float = SNR_SIGMA_DB) -> Array:
        """Measured SNRs ``(N, m)``: truth + ``N(0, sigma_db^2)``; NaN where not :attr:`heard`."""
        noisy = self.true_snr_db + sigma_db * rng.standard_normal(self.true_snr_db.shape)
        return np.where(self.heard, noisy, np.nan)

    def measurement(
        self, k: int, snr_db: ArrayLike, sigma_db: float = SNR_SIGMA_DB
    ) -> SnrMeasurement:
        """Epoch ``k``'s finite SNRs (one row of :meth:`simulate_snr`) as a filter measurement.

        The attitude of the returned :class:`SnrMeasurement` is ECI -> body.
        """
        row = np.asarray(snr_db, dtype=float)
        use = np.isfinite(row)
        if row.shape != (len(self.stations),) or not use.any():
            raise InvalidObservationError(
                f"epoch {k}: need one SNR per station with at least one finite, got {row}"
            )
        epoch = geo_snr_epoch(
            row[use], self.satellite_eci_km[k], self.stations_eci_km[k, use], sigma_db, self.link
        )
        return SnrMeasurement(epoch)


def build_geo_snr_scenario(
    duration_s: float = 3600.0,
    step_s: float = 10.0,
    manoeuvre: bool = False,
    link: GeoLink = GARUDA1,
) -> GeoSnrScenario:
    """The scenario at ``t = 0, step_s, ...`` below ``duration_s`` (cached per process)."""
    return _build(float(duration_s), float(step_s), bool(manoeuvre), link)


@functools.lru_cache(maxsize=4)
def _build(duration_s: float, step_s: float, manoeuvre: bool, link: GeoLink) -> GeoSnrScenario:
    t = np.arange(0.0, duration_s, step_s)
    times = Time(START_UTC, scale="utc") + np.append(t, MANOEUVRE_START_S) * u.s
    orbit = propagate(satellite_from_tle(*TLE), times)
    to_eci = ecef_to_eci_matrices(times)
    nadir = -orbit.position_eci_km[-1] / np.linalg.norm(orbit.position_eci_km[-1])
    truth = true_attitude(t, nadir if manoeuvre else None)
    stations_ecef, up_ecef = stations_ecef_km()
    stations_eci = np.einsum("nij,mj->nmi", to_eci[:-1], stations_ecef)
    up_eci = np.einsum("nij,mj->nmi", to_eci[:-1], up_ecef)
    satellite = orbit.position_eci_km[:-1]
    return GeoSnrScenario(
        t=t,
        satellite_eci_km=satellite,
        satellite_ecef_km=orbit.position_ecef_km[:-1],
        stations=STATIONS,
        stations_ecef_km=stations_ecef,
        stations_eci_km=stations_eci,
        stations_up_eci=up_eci,
        elevation_rad=elevation_rad(stations_eci, up_eci, satellite[:, None, :]),
        truth=truth,
        true_snr_db=geo_snr_db(truth.as_matrix(), satellite, stations_eci, link),
        link=link,
        manoeuvre=manoeuvre,
    )
