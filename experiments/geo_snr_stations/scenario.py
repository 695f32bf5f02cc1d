"""Scenario ``geo-snr-stations``: a GEO broadcaster seen by ground stations.

Pimienta-Penalver and Crassidis secs. II.A and V.B.  Everything it simulates is a
parameter (:class:`~attopt.experiments.geo_snr_stations.parameters.GeoWorld`); the
defaults are the paper's Garuda-1 case, described here.

Orbit.  ``[broadcaster.orbit]``: a TLE propagated with SGP4 and moved to ECI (GCRS)
and ECEF (ITRS) by :mod:`attopt.experiments.environment.orbit` (offline: the package
forbids IERS downloads), or a fixed point of the geostationary belt
(:func:`attopt.formulations.geo_geometry.belt_position`) moved to ECI by the same
matrices.  Default: the TLE of Pimienta-Penalver and Crassidis sec. II.A, whose epoch
2015-11-30 17:00:00 UTC is the default ``start_utc``; Garuda-1 sits at 123.0 deg E.

Stations.  ``[[stations]]`` (default: the eight of Table 2), geodetic on the WGS84
ellipsoid converted to ECEF by astropy ``EarthLocation``; their up vectors are the
ellipsoid normals.  ECI positions follow with astropy's ECEF -> ECI matrices.

Attitude (ECI -> body, ``docs/conventions.md``).  ``[attitude.initial]``: a Shuster
quaternion, by default Pimienta-Penalver and Crassidis eq. 27, ``q = [-0.0176892,
-0.706875, 0.706868, 0.0187807]``, scalar last, in the convention of its ref. 8
(Markley and Crassidis), i.e. the Shuster quaternion of Cilden Guler et al. 2017
eq. 21, the conjugate of scipy's: ``A_0 = Rotation.from_quat(q).inv()``
(``attopt.formulations.conventions.attitude_from_shuster_quaternion``).  With it the
boresight (body ``+z``) points 0.003 deg from nadir at the default start, at the
sub-satellite point; read as a scipy quaternion it would point 3 deg away, off the
Earth's centre towards 105.5 deg E.  The quaternion is an ECI attitude at
``start_utc``: another start or orbit wants ``type = "nadir"`` (the boresight at
nadir at the start, :func:`attopt.formulations.geo_link.attitude_pointing`, turned
by ``yaw_deg`` about it).  The body then turns about the ECI ``z`` axis (north) at
``Omega = omega_E + s``: ``A(t) = A_0 R_z(Omega t)^T``, a constant body rate
``Omega A_0 z``.  The Earth rate keeps the beam on the ground; the extra ``s`` =
``slew_rate_deg_h`` (1 deg/h) turns it west of nadir, a slow westward slew of the
footprint (about 5.6 deg of longitude per hour), Pimienta-Penalver and Crassidis
sec. V.B.

Manoeuvre (a setting, Pimienta-Penalver and Crassidis Fig. 10).  From
``[attitude.manoeuvre]`` ``start_s`` (30 min) the body turns by ``angle_deg`` (25 deg)
at a constant rate over ``duration_s`` (120 s) about the nadir direction at the
start of the manoeuvre (a yaw about the local vertical, the usual GEO attitude
manoeuvre that keeps the Earth in view); the slew goes on.  Because the beam
is then 0.5 deg west of nadir it swings by about ``2 sin(12.5 deg) 0.5 deg =
0.22 deg``: the footprint moves by about 140 km and the SNRs change by dB
(observable), while most of the 25 deg is a rotation about an axis close to
the boresight (nearly unobservable).  A 25 deg turn about an axis
perpendicular to the boresight would point the beam off the Earth (whose
radius seen from GEO is 8.7 deg).

SNRs.  Noise-free SNRs are Pimienta-Penalver and Crassidis eq. 7 with the link of
``[broadcaster]`` and ``[receiver]`` (:func:`attopt.formulations.geo_link.main_lobe_snr_db`:
NaN for a station outside the main lobe).  A station hears the satellite when it is
above its horizon and the noise-free SNR is at least ``detection_threshold_db``
(0 dB, the lowest SNR of Table 3).  Measured SNRs add Gaussian noise of
``snr_sigma_db`` (0.0148 dB, the M2M4 error Pimienta-Penalver and Crassidis use for
their filter's ``R``) drawn from the caller's generator.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import astropy.units as u
import numpy as np
from astropy.coordinates import EarthLocation
from astropy.time import Time
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from attopt.experiments.config.components import Station, TleOrbit
from attopt.experiments.environment.disk_cache import disk_cached
from attopt.experiments.environment.orbit import ecef_to_eci_matrices, propagate, satellite_from_tle
from attopt.experiments.environment.traffic import geodetic_normal
from attopt.experiments.geo_snr_stations.parameters import (
    AttitudeProfile,
    BroadcasterOrbit,
    GeoWorld,
    ShusterQuaternion,
)
from attopt.formulations.conventions import attitude_from_shuster_quaternion
from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.geo_geometry import belt_position
from attopt.formulations.geo_link import (
    BORESIGHT_BODY,
    GeoLink,
    attitude_pointing,
    elevation_rad,
    geo_snr_epoch,
    main_lobe_snr_db,
)
from attopt.formulations.snr_measurement import SnrMeasurement
from attopt.formulations.snr_problem import SnrEpoch

Array = NDArray[np.float64]

EARTH_RATE_RAD_S = 7.292115e-5
"""Earth's sidereal rotation rate (IERS conventions)."""


def stations_ecef_km(stations: Sequence[Station]) -> tuple[Array, Array]:
    """ECEF positions (km) and unit geodetic up vectors of ``stations``, each ``(m, 3)``."""
    lat = np.array([s.latitude_deg for s in stations])
    lon = np.array([s.longitude_deg for s in stations])
    location = EarthLocation.from_geodetic(
        lon=lon * u.deg,
        lat=lat * u.deg,
        height=np.array([s.height_m for s in stations]) * u.m,
        ellipsoid="WGS84",
    )
    position = np.stack([location.x, location.y, location.z], axis=-1).to_value(u.km)
    return position, geodetic_normal(lat, lon)


def satellite_positions_km(
    orbit: BroadcasterOrbit, times: Time, to_eci: Array
) -> tuple[Array, Array]:
    """ECI and ECEF positions (km) ``(n, 3)`` of the broadcaster at ``times``; ``to_eci``:
    the ECEF -> ECI matrices at ``times``."""
    if isinstance(orbit, TleOrbit):
        states = propagate(satellite_from_tle(*orbit.tle()), times)
        return states.position_eci_km, states.position_ecef_km
    ecef = np.broadcast_to(belt_position(np.radians(orbit.longitude_deg)), (len(times), 3))
    return np.einsum("nij,nj->ni", to_eci, ecef), np.array(ecef)


def true_attitude(
    profile: AttitudeProfile,
    initial: Rotation,
    t: ArrayLike,
    manoeuvre_axis_eci: ArrayLike | None = None,
) -> Rotation:
    """``A(t)`` (ECI -> body) at ``t`` seconds from the start (module docstring), from the
    ``initial`` attitude.

    ``manoeuvre_axis_eci``: unit nadir at the manoeuvre's start to add the manoeuvre,
    ``None`` for the slew alone.
    """
    t = np.atleast_1d(np.asarray(t, dtype=float))
    rate = EARTH_RATE_RAD_S + np.radians(profile.slew_rate_deg_h) / 3600.0
    turn = Rotation.from_rotvec(np.outer(rate * t, [0.0, 0.0, 1.0]))
    if manoeuvre_axis_eci is not None:
        manoeuvre = profile.manoeuvre
        axis = np.asarray(manoeuvre_axis_eci, dtype=float)
        fraction = np.clip((t - manoeuvre.start_s) / manoeuvre.duration_s, 0.0, 1.0)
        yaw = Rotation.from_rotvec(np.outer(np.radians(manoeuvre.angle_deg) * fraction, axis))
        before = Rotation.from_rotvec([0.0, 0.0, rate * manoeuvre.start_s])
        turn = turn * before.inv() * yaw * before
    return initial * turn.inv()


def initial_attitude(profile: AttitudeProfile, satellite_eci_km: ArrayLike) -> Rotation:
    """``A_0`` (ECI -> body) of ``[attitude.initial]`` with the satellite at
    ``satellite_eci_km`` at the start (module docstring)."""
    initial = profile.initial
    if isinstance(initial, ShusterQuaternion):
        return attitude_from_shuster_quaternion(initial.components)
    nadir = -np.asarray(satellite_eci_km, dtype=float)
    yaw = Rotation.from_rotvec(np.radians(initial.yaw_deg) * BORESIGHT_BODY)
    return yaw * attitude_pointing(nadir)


@dataclass(frozen=True)
class GeoSnrScenario:
    """True geometry and noise-free SNRs at ``N`` epochs for ``m`` stations (ECI unless named)."""

    t: Array
    """Seconds from ``start_utc``, ``(N,)``."""
    satellite_eci_km: Array
    satellite_ecef_km: Array
    stations: tuple[Station, ...]
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
    nominal: Rotation
    """ECI -> body of the slew without the manoeuvre (the filters' assumed attitude motion)."""
    true_snr_db: Array
    """``(N, m)`` noise-free SNRs (eq. 7), NaN outside the main lobe."""
    link: GeoLink
    snr_sigma_db: float
    detection_threshold_db: float
    manoeuvre: bool

    @property
    def station_names(self) -> list[str]:
        """The stations' names, in order."""
        return [station.name for station in self.stations]

    @property
    def heard(self) -> NDArray[np.bool_]:
        """``(N, m)``: above the horizon with a noise-free SNR of at least the threshold."""
        return (self.elevation_rad > 0) & (self.true_snr_db >= self.detection_threshold_db)

    @property
    def boresight_eci(self) -> Array:
        """True unit boresights ``(N, 3)``."""
        return self.truth.inv().apply(BORESIGHT_BODY)

    def simulate_snr(self, rng: np.random.Generator) -> Array:
        """Measured SNRs ``(N, m)``: truth + ``N(0, snr_sigma_db^2)``; NaN where not
        :attr:`heard`."""
        noise = self.snr_sigma_db * rng.standard_normal(self.true_snr_db.shape)
        return np.where(self.heard, self.true_snr_db + noise, np.nan)

    def epoch(self, k: int, snr_db: ArrayLike, stations: ArrayLike) -> SnrEpoch:
        """Epoch ``k``'s SNRs ``snr_db`` of the station indices ``stations`` as an
        :class:`~attopt.formulations.snr_problem.SnrEpoch` (ECI -> body, this scenario's
        link and SNR sigma)."""
        return geo_snr_epoch(
            snr_db,
            self.satellite_eci_km[k],
            self.stations_eci_km[k, stations],
            self.snr_sigma_db,
            self.link,
        )

    def measurement(self, k: int, snr_db: ArrayLike) -> SnrMeasurement:
        """Epoch ``k``'s finite SNRs (one row of :meth:`simulate_snr`) as a filter measurement.

        The attitude of the returned :class:`SnrMeasurement` is ECI -> body.
        """
        row = np.asarray(snr_db, dtype=float)
        use = np.isfinite(row)
        if row.shape != (len(self.stations),) or not use.any():
            raise InvalidObservationError(
                f"epoch {k}: need one SNR per station with at least one finite, got {row}"
            )
        return SnrMeasurement(self.epoch(k, row[use], use))


def build_geo_snr_scenario(
    world: GeoWorld | None = None, manoeuvre: bool = False
) -> GeoSnrScenario:
    """The scenario of ``world`` (default: the paper's) at ``t = 0, step_s, ...`` below
    ``duration_s``, with or without the manoeuvre (cached per process and on disk,
    :mod:`attopt.experiments.environment.disk_cache`)."""
    world = GeoWorld() if world is None else world.world()
    return _build(world.model_dump_json(), bool(manoeuvre))


@functools.lru_cache(maxsize=4)
@disk_cached
def _build(world_json: str, manoeuvre: bool) -> GeoSnrScenario:
    world = GeoWorld.model_validate_json(world_json)
    profile, link = world.attitude, world.link()
    t = np.arange(0.0, world.duration_s, world.step_s)
    times = Time(world.start_utc, scale="utc") + np.append(t, profile.manoeuvre.start_s) * u.s
    to_eci = ecef_to_eci_matrices(times)
    satellite_eci, satellite_ecef = satellite_positions_km(world.broadcaster.orbit, times, to_eci)
    initial = initial_attitude(profile, satellite_eci[0])
    nominal = true_attitude(profile, initial, t)
    nadir = -satellite_eci[-1] / np.linalg.norm(satellite_eci[-1])
    truth = true_attitude(profile, initial, t, nadir) if manoeuvre else nominal
    stations_ecef, up_ecef = stations_ecef_km(world.stations)
    stations_eci = np.einsum("nij,mj->nmi", to_eci[:-1], stations_ecef)
    up_eci = np.einsum("nij,mj->nmi", to_eci[:-1], up_ecef)
    satellite = satellite_eci[:-1]
    return GeoSnrScenario(
        t=t,
        satellite_eci_km=satellite,
        satellite_ecef_km=satellite_ecef[:-1],
        stations=tuple(world.stations),
        stations_ecef_km=stations_ecef,
        stations_eci_km=stations_eci,
        stations_up_eci=up_eci,
        elevation_rad=elevation_rad(stations_eci, up_eci, satellite[:, None, :]),
        truth=truth,
        nominal=nominal,
        true_snr_db=main_lobe_snr_db(truth.as_matrix(), satellite, stations_eci, link),
        link=link,
        snr_sigma_db=world.receiver.snr_sigma_db,
        detection_threshold_db=world.receiver.detection_threshold_db,
        manoeuvre=manoeuvre,
    )
