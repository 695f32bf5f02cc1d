"""Scenario ``doa-ground``: a LEO satellite sees eight ground transmitters.

Yang et al. 2014 secs. 4.2 and 6.

Orbit.  Sun-synchronous, 800 km, local time of the descending node 8:00
(sec. 4.1).  The TLE of :func:`satellite_tle` is generated with ``sgp4``
(``Satrec.sgp4init``, ``sgp4.exporter.export_tle``) like the ``adsb-snr``
scenario's: epoch :data:`TLE_EPOCH_UTC` (also the start of the pass), a
circular orbit of semi-major axis 800 km above sgp4's WGS72 equator,
eccentricity 1e-4, inclination 98.60 deg (the ``J2`` node drift then equals
the Sun's mean motion, 0.9856 deg/day), argument of perigee and mean anomaly
0 (at the ascending node at epoch) and right ascension of the ascending node
101.81 deg, the Sun's right ascension at epoch (341.81 deg, astropy
``get_sun``) plus 120 deg: ascending node at 20:00, descending at 8:00 local
time.  The pass starts at the ascending node over the night side, runs north
over the Arctic and descends over the day side.

Stations.  The seed generates eight ground stations with an orbit package and
does not list them; ours (:data:`STATIONS`, geodetic, height 0 on WGS84) sit
near the ground track of this pass, one every 600 s from 300 s on, each
offset 1 deg of longitude, alternately east and west, from the sub-satellite
point at that time (so no pass is exactly overhead).  A station is visible
when the satellite is at least :data:`MIN_ELEVATION_DEG` (10 deg) above its
horizon (ellipsoid normal); then its polar angle at the nadir-pointing array
is at most 62 deg, as in sec. 4.2.  Each pass lasts 610-650 s (the paper's
"about 10 min") and consecutive passes overlap, so at least one station is
visible from the start to t = 4826 s (two for 243 s in all; none in the last
174 s of a 5000 s pass), :func:`coverage`.

Truth (sec. 5.1).  Rigid-body dynamics of eq. 23 with the inertia of eq. 25,
a constant momentum-bias wheel :data:`WHEEL_MOMENTUM` (``h_dot = 0``) and no
external or magnetorquer torque, integrated with ``scipy.integrate.solve_ivp``
(DOP853, ``rtol = 1e-10``) for the inertial attitude ``A_bi`` (quaternion
kinematics ``dA/dt = -[omega x] A``) and the rate ``omega_bi``;
``C_bo = A_bi A_oi^T`` with ``A_oi`` the orbit frame
(:func:`attopt.formulations.conventions.orbit_frame_attitude`).  The satellite starts
Earth pointing up to :data:`TRUTH_INITIAL_EULER_DEG` (3-2-1 Euler angles) with
the orbit frame's rate plus :data:`TRUTH_RATE_OFFSET_DEG_S`; the wheel keeps
it within a few degrees of Earth pointing (nutation).

Reading of sec. 6.  "The initial Euler angles are yaw = 50 deg, roll = 50 deg
and pitch = 50 deg, and the initial inertial referenced angular velocity is
[0.5, 0.5, 0.5] deg/s" is the filter's initial estimate, not the truth: the
satellite is three-axis stabilised and Earth pointing (the stations must stay
in the array's field of view, ``theta <= 62 deg``), and the errors converge
from about 50 deg (Fig. 6) and 0.5 deg/s (Fig. 7).  :data:`FILTER_INITIAL_EULER_DEG`
and :data:`FILTER_INITIAL_RATE_DEG_S` hold them.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import astropy.units as u
import numpy as np
from astropy.coordinates import EarthLocation
from astropy.time import Time
from numpy.typing import NDArray
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

from attopt.experiments.environment.orbit import (
    circular_orbit_tle,
    ecef_to_eci_matrices,
    propagate,
    satellite_from_tle,
)
from attopt.experiments.environment.traffic import geodetic_normal
from attopt.formulations.conventions import attitude_from_euler321, orbit_frame_attitude
from attopt.formulations.doa_array import doa_from_unit_vector
from attopt.formulations.rigid_body import INERTIA_SEED003, angular_acceleration

Array = NDArray[np.float64]

TLE_EPOCH_UTC = "2025-03-01T00:00:00"
SATELLITE_NUMBER = 99003
ALTITUDE_KM = 800.0
"""Semi-major axis minus sgp4's WGS72 equatorial radius."""
INCLINATION_DEG = 98.60
ECCENTRICITY = 1.0e-4
RAAN_DEG = 101.81
ARGUMENT_OF_PERIGEE_DEG = 0.0
MEAN_ANOMALY_DEG = 0.0

STEP_S = 0.25
"""Processing step of sec. 4.2 (s)."""
DURATION_S = 5000.0
"""Pass length of sec. 6 (s)."""
MIN_ELEVATION_DEG = 10.0

STATIONS: tuple[tuple[float, float], ...] = (
    (17.62, -60.23),
    (52.75, -73.40),
    (81.41, -147.03),
    (54.34, 125.11),
    (19.26, 115.52),
    (-16.19, 105.50),
    (-51.26, 96.70),
    (-81.09, 29.25),
)
"""``(latitude, longitude)`` (deg, geodetic WGS84, height 0) of the eight stations."""

WHEEL_MOMENTUM = np.array([0.0, -0.1, 0.0])
"""Wheel angular momentum ``h`` (N m s, body axes): a pitch momentum bias."""
TRUTH_INITIAL_EULER_DEG = (3.0, -2.0, 2.0)
"""True initial ``(yaw, pitch, roll)`` of ``C_bo`` (deg)."""
TRUTH_RATE_OFFSET_DEG_S = np.array([0.005, 0.0, -0.004])
"""True initial ``omega_bi`` minus the orbit frame's rate (deg/s, body axes)."""

FILTER_INITIAL_EULER_DEG = (50.0, 50.0, 50.0)
"""Filter's initial ``(yaw, pitch, roll)`` (deg, sec. 6)."""
FILTER_INITIAL_RATE_DEG_S = np.array([0.5, 0.5, 0.5])
"""Filter's initial ``omega_bi`` (deg/s, sec. 6)."""


@dataclass(frozen=True)
class DoaGroundGeometry:
    """True geometry and attitude at ``N`` epochs ``STEP_S`` apart (cached: do not modify).

    Attributes:
        t: ``(N,)`` seconds from the start.
        eci_to_orbit: ``A_oi`` per epoch.
        truth: ``C_bo`` per epoch.
        rate: ``(N, 3)`` true ``omega_bi`` (rad/s, body).
        line_of_sight_km: ``(N, S, 3)`` ``D_o`` (eq. 13), satellite -> station, orbit frame.
        elevation_deg: ``(N, S)`` elevation of the satellite at each station.
        visible: ``(N, S)`` elevation at least :data:`MIN_ELEVATION_DEG`.
        doa: ``(N, S, 2)`` true ``(theta, phi)`` of every station at the array (rad).
    """

    t: Array
    eci_to_orbit: Rotation
    truth: Rotation
    rate: Array
    line_of_sight_km: Array
    elevation_deg: Array
    visible: NDArray[np.bool_]
    doa: Array

    def orbit_turns(self) -> Rotation:
        """``O_{k+1} O_k^T`` between consecutive epochs (``N - 1``), for the filter."""
        return self.eci_to_orbit[1:] * self.eci_to_orbit[:-1].inv()


def satellite_tle() -> tuple[str, str]:
    """The scenario's two-line element set, generated by sgp4 from the module elements."""
    return circular_orbit_tle(
        TLE_EPOCH_UTC,
        SATELLITE_NUMBER,
        ALTITUDE_KM,
        INCLINATION_DEG,
        RAAN_DEG,
        ECCENTRICITY,
        ARGUMENT_OF_PERIGEE_DEG,
        MEAN_ANOMALY_DEG,
    )


def stations_ecef_km() -> tuple[Array, Array]:
    """ECEF positions (km) and unit ellipsoid normals of :data:`STATIONS`, ``(S, 3)`` each."""
    latitude, longitude = np.array(STATIONS).T
    location = EarthLocation.from_geodetic(longitude * u.deg, latitude * u.deg, 0.0 * u.m)
    position = np.stack(
        [location.x.to_value(u.km), location.y.to_value(u.km), location.z.to_value(u.km)], axis=-1
    )
    return position, geodetic_normal(latitude, longitude)


def rigid_body_derivative(_t: float, state: Array, wheel_momentum: Array, inertia: Array) -> Array:
    """``d/dt [omega, q]`` of eq. 23 and ``dA/dt = -[omega x] A`` (scipy quaternion of ``A_bi``).

    ``q_dot = 1/2 [-omega, 0] (x) q`` (Hamilton product, scalar last).
    """
    omega, q = state[:3], state[3:]
    vector, scalar = q[:3], q[3]
    q_dot = 0.5 * np.concatenate([-scalar * omega - np.cross(omega, vector), [omega @ vector]])
    return np.concatenate([angular_acceleration(omega, wheel_momentum, inertia), q_dot])


def build_geometry(duration_s: float = DURATION_S, step_s: float = STEP_S) -> DoaGroundGeometry:
    """Geometry at ``t = 0, step_s, ...`` below ``duration_s`` (cached per process)."""
    return _build_geometry(float(duration_s), float(step_s))


@functools.lru_cache(maxsize=4)
def _build_geometry(duration_s: float, step_s: float) -> DoaGroundGeometry:
    t = np.arange(0.0, duration_s, step_s)
    times = Time(TLE_EPOCH_UTC, scale="utc") + t * u.s
    orbit = propagate(satellite_from_tle(*satellite_tle()), times)
    frames = orbit_frame_attitude(orbit.position_eci_km, orbit.velocity_eci_kms)
    attitude_bi, rate = _integrate_truth(t, frames, orbit.position_eci_km, orbit.velocity_eci_kms)
    truth = attitude_bi * frames.inv()

    station_ecef, normal = stations_ecef_km()
    to_station_ecef = station_ecef[None, :, :] - orbit.position_ecef_km[:, None, :]
    distance = np.linalg.norm(to_station_ecef, axis=-1)
    elevation = np.degrees(np.arcsin(-np.einsum("nsi,si->ns", to_station_ecef, normal) / distance))
    ecef_to_orbit = frames.as_matrix() @ ecef_to_eci_matrices(times)
    line_of_sight = np.einsum("nij,nsj->nsi", ecef_to_orbit, to_station_ecef)
    in_body = np.einsum("nij,nsj->nsi", truth.as_matrix(), line_of_sight)
    theta, phi = doa_from_unit_vector(in_body.reshape(-1, 3))
    doa = np.stack([theta, phi], axis=-1).reshape(*elevation.shape, 2)
    return DoaGroundGeometry(
        t=t,
        eci_to_orbit=frames,
        truth=truth,
        rate=rate,
        line_of_sight_km=line_of_sight,
        elevation_deg=elevation,
        visible=elevation >= MIN_ELEVATION_DEG,
        doa=doa,
    )


def _integrate_truth(
    t: Array, frames: Rotation, position_eci_km: Array, velocity_eci_kms: Array
) -> tuple[Rotation, Array]:
    """``A_bi`` and ``omega_bi`` at ``t`` from the initial state of the module docstring."""
    start_bo = attitude_from_euler321(*np.radians(TRUTH_INITIAL_EULER_DEG))
    start_bi = start_bo * frames[0]
    r, v = position_eci_km[0], velocity_eci_kms[0]
    orbit_rate_eci = np.cross(r, v) / (r @ r)
    rate0 = start_bi.apply(orbit_rate_eci) + np.radians(TRUTH_RATE_OFFSET_DEG_S)
    solution = solve_ivp(
        rigid_body_derivative,
        (t[0], t[-1]),
        np.concatenate([rate0, start_bi.as_quat()]),
        method="DOP853",
        t_eval=t,
        rtol=1e-10,
        atol=1e-12,
        args=(WHEEL_MOMENTUM, INERTIA_SEED003),
    )
    states = solution.y.T
    return Rotation.from_quat(states[:, 3:]), states[:, :3]


def coverage(geometry: DoaGroundGeometry) -> Array:
    """Number of visible stations per epoch, ``(N,)``."""
    return geometry.visible.sum(axis=1)
