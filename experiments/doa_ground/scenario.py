"""Scenario ``doa-ground``: a LEO satellite sees ground transmitters (Yang et al. 2014 secs.
4.2 and 6).

Every choice below is a parameter of :class:`~attopt.experiments.doa_ground.parameters.DoaScenario`
(``orbit``, ``start_utc``, ``duration_s``, ``step_s``, ``[[stations]]``,
``min_elevation_deg``, ``[attitude]``); the defaults are the paper's set-up as read here.

Orbit.  Propagated with sgp4 from the configured TLE (or the TLE generated for a circular
orbit) from ``start_utc``.  Default: Sun-synchronous, 800 km, local time of the descending
node 8:00 (sec. 4.1), the TLE of
:data:`~attopt.experiments.doa_ground.parameters.SATELLITE_TLE` generated with ``sgp4``
(``Satrec.sgp4init``, ``sgp4.exporter.export_tle``) for epoch 2025-03-01 00:00 UTC (also
the start of the pass): a circular orbit of semi-major axis 800 km above sgp4's WGS72
equator, eccentricity 1e-4, inclination 98.60 deg (the ``J2`` node drift then equals the
Sun's mean motion, 0.9856 deg/day), argument of perigee and mean anomaly 0 (at the
ascending node at epoch) and right ascension of the ascending node 101.81 deg, the Sun's
right ascension at epoch (341.81 deg, astropy ``get_sun``) plus 120 deg: ascending node
at 20:00, descending at 8:00 local time.  The pass starts at the ascending node over the
night side, runs north over the Arctic and descends over the day side.

Stations.  Any number, each a name and a geodetic position (WGS84).  Yang et al. 2014
generates eight ground stations with an orbit package and does not list them; the
default ones (:data:`~attopt.experiments.doa_ground.parameters.STATIONS`, height 0) sit
near the ground track of the default pass, one every 600 s from 300 s on, each offset 1
deg of longitude, alternately east and west, from the sub-satellite point at that time
(so no pass is exactly overhead).  A station is visible when the satellite is at least
``min_elevation_deg`` (default 10 deg) above its horizon (ellipsoid normal); then its
polar angle at the nadir-pointing array is at most 62 deg, as in sec. 4.2.  With the
defaults each pass lasts 610-650 s (the paper's "about 10 min") and consecutive passes
overlap, so at least one station is visible from the start to t = 4826 s (two for 243 s
in all; none in the last 174 s of a 5000 s pass), :func:`coverage`.

Truth (sec. 5.1).  Rigid-body dynamics of eq. 23 with the configured inertia (default
eq. 25's), a constant wheel momentum (``h_dot = 0``; default a 0.1 N m s pitch momentum
bias) and no external or magnetorquer torque, integrated with
``scipy.integrate.solve_ivp`` (DOP853, ``rtol = 1e-10``) for the inertial attitude
``A_bi`` (quaternion kinematics ``dA/dt = -[omega x] A``) and the rate ``omega_bi``;
``C_bo = A_bi A_oi^T`` with ``A_oi`` the orbit frame
(:func:`attopt.formulations.conventions.orbit_frame_attitude`).  The satellite starts
Earth pointing up to ``attitude.initial_euler_deg`` (3-2-1 Euler angles, default 3 / -2
/ 2 deg) with the orbit frame's rate plus ``attitude.initial_rate_offset_deg_s``
(default (0.005, 0, -0.004) deg/s); the default wheel keeps it within a few degrees of
Earth pointing (nutation).

Reading of sec. 6.  "The initial Euler angles are yaw = 50 deg, roll = 50 deg and pitch
= 50 deg, and the initial inertial referenced angular velocity is [0.5, 0.5, 0.5] deg/s"
is the filter's initial estimate (``[prior]``), not the truth: the satellite is
three-axis stabilised and Earth pointing (the stations must stay in the array's field
of view, ``theta <= 62 deg``), and the errors converge from about 50 deg (Fig. 6) and
0.5 deg/s (Fig. 7).

The geometry is cached per process and scenario (:func:`build_geometry`), and the
orbit (sgp4 and astropy's frame transforms, the slow part) per orbit and time grid, per
process and on disk (:func:`orbit_track`), so scenarios that differ only in their
stations or truth share it and the processes of a machine build it once.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass

import astropy.units as u
import numpy as np
from astropy.coordinates import EarthLocation
from astropy.time import Time
from numpy.typing import NDArray
from scipy.integrate import solve_ivp
from scipy.spatial.transform import Rotation

from attopt.experiments.config.components import Station
from attopt.experiments.doa_ground.parameters import DoaScenario, RigidBodyTruth
from attopt.experiments.environment.disk_cache import disk_cached
from attopt.experiments.environment.orbit import (
    ecef_to_eci_matrices,
    propagate,
    satellite_from_tle,
)
from attopt.experiments.environment.traffic import geodetic_normal
from attopt.formulations.conventions import attitude_from_euler321, orbit_frame_attitude
from attopt.formulations.doa_array import doa_from_unit_vector
from attopt.formulations.passes import RigidBody
from attopt.formulations.rigid_body import angular_acceleration

Array = NDArray[np.float64]


@dataclass(frozen=True)
class DoaGroundGeometry:
    """True geometry and attitude at ``N`` epochs ``step_s`` apart (cached: do not modify).

    Attributes:
        t: ``(N,)`` seconds from the start.
        eci_to_orbit: ``A_oi`` per epoch.
        truth: ``C_bo`` per epoch.
        rate: ``(N, 3)`` true ``omega_bi`` (rad/s, body).
        line_of_sight_km: ``(N, S, 3)`` ``D_o`` (eq. 13), satellite -> station, orbit frame.
        elevation_deg: ``(N, S)`` elevation of the satellite at each station.
        visible: ``(N, S)`` elevation at least the scenario's ``min_elevation_deg``.
        doa: ``(N, S, 2)`` true ``(theta, phi)`` of every station at the array (rad).
        dynamics: the true rigid body (inertia, orbit frames, wheel momentum), which the
            filters of the dynamics are given.
    """

    t: Array
    eci_to_orbit: Rotation
    truth: Rotation
    rate: Array
    line_of_sight_km: Array
    elevation_deg: Array
    visible: NDArray[np.bool_]
    doa: Array
    dynamics: RigidBody

    def orbit_turns(self) -> Rotation:
        """``O_{k+1} O_k^T`` between consecutive epochs (``N - 1``), for the filter."""
        return self.eci_to_orbit[1:] * self.eci_to_orbit[:-1].inv()


@dataclass(frozen=True)
class OrbitTrack:
    """The satellite along the pass: epochs, states and ``v_eci = M v_ecef`` matrices."""

    t: Array
    position_eci_km: Array
    velocity_eci_kms: Array
    position_ecef_km: Array
    ecef_to_eci: Array


def stations_ecef_km(stations: Sequence[Station]) -> tuple[Array, Array]:
    """ECEF positions (km) and unit ellipsoid normals of ``stations``, ``(S, 3)`` each."""
    latitude = np.array([s.latitude_deg for s in stations])
    longitude = np.array([s.longitude_deg for s in stations])
    height = np.array([s.height_m for s in stations])
    location = EarthLocation.from_geodetic(longitude * u.deg, latitude * u.deg, height * u.m)
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


def build_geometry(scenario: DoaScenario | None = None) -> DoaGroundGeometry:
    """Geometry at ``t = 0, step_s, ...`` below ``duration_s`` of ``scenario`` (default: the
    paper's; cached per process and scenario)."""
    scenario = DoaScenario() if scenario is None else scenario.scenario()
    return _build_geometry(scenario.model_dump_json())


@functools.lru_cache(maxsize=4)
def _build_geometry(document: str) -> DoaGroundGeometry:
    scenario = DoaScenario.model_validate_json(document)
    orbit = orbit_track(
        scenario.orbit.tle(), scenario.start_utc, scenario.duration_s, scenario.step_s
    )
    t = orbit.t
    frames = orbit_frame_attitude(orbit.position_eci_km, orbit.velocity_eci_kms)
    attitude_bi, rate = _integrate_truth(
        t, frames, orbit.position_eci_km, orbit.velocity_eci_kms, scenario.attitude
    )
    truth = attitude_bi * frames.inv()

    station_ecef, normal = stations_ecef_km(scenario.stations)
    to_station_ecef = station_ecef[None, :, :] - orbit.position_ecef_km[:, None, :]
    distance = np.linalg.norm(to_station_ecef, axis=-1)
    elevation = np.degrees(np.arcsin(-np.einsum("nsi,si->ns", to_station_ecef, normal) / distance))
    ecef_to_orbit = frames.as_matrix() @ orbit.ecef_to_eci
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
        visible=elevation >= scenario.min_elevation_deg,
        doa=doa,
        dynamics=RigidBody(scenario.attitude.inertia, frames, scenario.attitude.wheel_momentum),
    )


@functools.lru_cache(maxsize=2)
@disk_cached
def orbit_track(
    tle: tuple[str, str], start_utc: str, duration_s: float, step_s: float
) -> OrbitTrack:
    """sgp4 and astropy's frames at ``t = 0, step_s, ...`` below ``duration_s`` from
    ``start_utc`` (cached per process and on disk,
    :mod:`attopt.experiments.environment.disk_cache`: the slow part of a scenario)."""
    t = np.arange(0.0, duration_s, step_s)
    times = Time(start_utc, scale="utc") + t * u.s
    orbit = propagate(satellite_from_tle(*tle), times)
    return OrbitTrack(
        t=t,
        position_eci_km=orbit.position_eci_km,
        velocity_eci_kms=orbit.velocity_eci_kms,
        position_ecef_km=orbit.position_ecef_km,
        ecef_to_eci=ecef_to_eci_matrices(times),
    )


def _integrate_truth(
    t: Array,
    frames: Rotation,
    position_eci_km: Array,
    velocity_eci_kms: Array,
    attitude: RigidBodyTruth,
) -> tuple[Rotation, Array]:
    """``A_bi`` and ``omega_bi`` at ``t`` from the initial state of the module docstring."""
    start_bo = attitude_from_euler321(*np.radians(attitude.initial_euler_deg))
    start_bi = start_bo * frames[0]
    r, v = position_eci_km[0], velocity_eci_kms[0]
    orbit_rate_eci = np.cross(r, v) / (r @ r)
    rate0 = start_bi.apply(orbit_rate_eci) + np.radians(attitude.initial_rate_offset_deg_s)
    solution = solve_ivp(
        rigid_body_derivative,
        (t[0], t[-1]),
        np.concatenate([rate0, start_bi.as_quat()]),
        method="DOP853",
        t_eval=t,
        rtol=1e-10,
        atol=1e-12,
        args=(attitude.wheel_momentum, attitude.inertia),
    )
    states = solution.y.T
    return Rotation.from_quat(states[:, 3:]), states[:, :3]


def coverage(geometry: DoaGroundGeometry) -> Array:
    """Number of visible stations per epoch, ``(N,)``."""
    return geometry.visible.sum(axis=1)
