"""Geometry of the ``adsb-snr`` scenario (Liu et al. 2023 sec. 5.1).

A satellite carries ADS-B antennas and sees a global population of airborne
aircraft over a pass.  This module gives the geometry only: satellite and
aircraft positions, satellite-to-aircraft lines of sight in the orbit frame,
slant ranges, off-boresight angles and the true attitude, for the set-up of an
:class:`~attopt.experiments.adsb_snr.parameters.AdsbScenario` (orbit, start,
duration and step, attitude profile, antennas, traffic).  The SNR model and the
reception threshold are applied by the caller.

The defaults (:mod:`attopt.experiments.adsb_snr.parameters`) are Liu et al. 2023's:

Orbit.  A 600 km, 97.8 deg Sun-synchronous orbit, propagated with
:mod:`attopt.experiments.environment.orbit` from a TLE generated with ``sgp4``
(``Satrec.sgp4init`` then ``sgp4.exporter.export_tle``, so its checksums are
sgp4's) from mean elements: epoch 2025-06-01 00:00 UTC, mean motion of a
circular orbit with semi-major axis 600 km above the (WGS72) equator,
inclination 97.8 deg, eccentricity 1e-4, argument of perigee and mean anomaly 0
(at the ascending node at epoch), no drag.  The right ascension of the
ascending node, 226.31 deg, is the Sun's right ascension at epoch (68.81 deg,
astropy ``get_sun``) plus 157.5 deg, i.e. a local time of the ascending node of
22:30 (descending over the day side at 10:30), and the J2 node drift,
0.9856 deg/day, keeps it there.  The pass starts 25 h 41 min after the TLE
epoch (2025-06-02 01:41 UTC), chosen by scanning starts at 1 min steps over two
days (10 s sampling, seed-0 traffic) for the hour whose sparsest epoch holds the
most aircraft in an antenna's main lobe (``G >= 4 dBi``: ``14.4598 cos^6(alpha)
>= 10^0.4``, ``alpha <= 41.67 deg``, Liu et al. 2023 eq. 63).  The ascending pass
starts over Brazil, runs north off the east coast of North America, over
Greenland and the Arctic, and descends over eastern Siberia and East Asia to
Borneo.

Attitude.  Nominally Earth pointing (body = orbit frame), the true orbit ->
body attitude wanders by a few degrees; 3-2-1 Euler angles of Liu et al. 2023
eq. 8, ``t`` in seconds from the start
(:class:`~attopt.experiments.adsb_snr.parameters.AttitudeProfile`)::

    yaw(t)   = 4 deg * cos(2 pi t / 1700)
    pitch(t) = 3 deg * sin(2 pi t / 2300)
    roll(t)  = 5 deg * sin(2 pi t / 1100 + pi / 3)

Antennas.  Two helices whose boresights are tilted by ``beta_opt = 50.77 deg``
(Liu et al. 2023 eq. 64) from nadir (+z body), antenna 1 towards +y and antenna
2 towards -y body, i.e. cross-track and symmetric about the orbit plane as in
Liu et al. 2023 Fig. 7.  Cross-track tilting makes the two main lobes cover the
two sides of the ground track: the widest surveillance swath, and two
boresights 101.5 deg apart for a well-conditioned three-axis solution.  Any
number of antennas may be configured, each with its boresight and gain pattern.

Visibility.  An aircraft is visible at an epoch when the straight segment from
the satellite to it does not cross the WGS84 ellipsoid (no refraction, terrain
or atmosphere) and, for an antenna, when its off-boresight angle lies in that
antenna's main lobe (``cos alpha >= min_cos`` of its pattern), or within a
caller's ``max_off_boresight_deg``.  Lines of sight point from the satellite to
the aircraft, so ``cos(alpha) = l . b`` (Liu et al. 2023 eqs. 5-7) is positive in
the main lobe; Liu et al. 2023 eq. 9 prints the opposite difference.

Pre-filter.  Before the limb test an epoch chunk examines only the aircraft
whose geodetic normal is within the horizon angle of the sub-satellite
normal: ``arccos(b / r_sat) + arccos(b / (a + h_max))`` (``a``, ``b`` the
WGS84 semi-axes, ``r_sat`` the largest geocentric distance of the satellite
over the pass, ``h_max`` the top of the aircraft height band), the horizon of
the sphere of radius ``b`` inside the ellipsoid, plus :data:`PREFILTER_MARGIN_RAD`
for the difference between geodetic and geocentric directions; no aircraft
above the limb lies beyond it.
"""

from __future__ import annotations

import functools
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from attopt.experiments.adsb_snr.parameters import AdsbScenario
from attopt.experiments.environment.disk_cache import disk_cached
from attopt.experiments.environment.orbit import (
    ecef_to_eci_matrices,
    propagate,
    satellite_from_tle,
    window_times,
)
from attopt.experiments.environment.traffic import (
    WGS84_A_KM,
    WGS84_F,
    Traffic,
    geodetic_normal,
    geodetic_normals,
    positions_ecef_km,
    sample_traffic,
)
from attopt.formulations.conventions import orbit_frame_attitude

PREFILTER_MARGIN_RAD = 0.01
"""Added to the horizon angle of the pre-filter: geodetic and geocentric directions differ
by up to 0.0034 rad (0.19 deg) at the satellite and at the aircraft."""
EPOCH_CHUNK = 60
"""Epochs processed together (one pre-filter per chunk)."""


@dataclass(frozen=True)
class AdsbGeometry:
    """True geometry of the scenario at ``N`` epochs.

    Instances are cached and shared: do not modify the arrays in place.
    """

    t: NDArray[np.float64]
    """Seconds from :attr:`start_utc`, shape ``(N,)``; aircraft motion uses the same clock."""
    start_utc: str
    position_ecef_km: NDArray[np.float64]
    """Satellite positions in ECEF (ITRS), ``(N, 3)``."""
    position_eci_km: NDArray[np.float64]
    """Satellite positions in ECI (GCRS), ``(N, 3)``."""
    velocity_eci_kms: NDArray[np.float64]
    """Satellite velocities in ECI (GCRS), ``(N, 3)``."""
    subsatellite_normal: NDArray[np.float64]
    """Unit WGS84 normals at the sub-satellite points (ECEF), ``(N, 3)``."""
    ecef_to_orbit: NDArray[np.float64]
    """Matrices ``M`` with ``v_orbit = M @ v_ecef``, ``(N, 3, 3)``."""
    truth: Rotation
    """True attitude, orbit frame -> body frame, ``N`` rotations."""
    traffic: Traffic
    """The aircraft; aircraft ids are row indices."""
    boresights_body: NDArray[np.float64]
    """Unit antenna boresights in the body frame, ``(n_antennas, 3)``."""
    min_cos: NDArray[np.float64]
    """``cos`` of each antenna's main-lobe edge (its gain pattern's), ``(n_antennas,)``."""
    prefilter_rad: float
    """Horizon angle of the pre-filter (module docstring)."""

    @property
    def n_antennas(self) -> int:
        return int(self.boresights_body.shape[0])


@dataclass(frozen=True)
class ObservationTable:
    """Long-format (epoch, antenna, aircraft) rows of visible aircraft, ``M`` rows.

    Rows are sorted by epoch, then antenna (0 for antenna 1), then aircraft.
    """

    epoch_index: NDArray[np.intp]
    antenna: NDArray[np.intp]
    aircraft: NDArray[np.intp]
    los_orbit: NDArray[np.float64]
    """Unit satellite-to-aircraft lines of sight in the orbit frame, ``(M, 3)``."""
    range_m: NDArray[np.float64]
    """Slant ranges, ``(M,)``."""
    cos_off_boresight: NDArray[np.float64]
    """Cosine of the true off-boresight angle (Liu et al. 2023 eq. 7), ``(M,)``."""
    aircraft_ecef_km: NDArray[np.float64]
    """Aircraft positions in ECEF (as decoded from ADS-B), ``(M, 3)``."""

    def take(self, rows: NDArray[np.intp] | NDArray[np.bool_]) -> ObservationTable:
        """The table restricted to ``rows`` (indices or mask)."""
        return ObservationTable(
            epoch_index=self.epoch_index[rows],
            antenna=self.antenna[rows],
            aircraft=self.aircraft[rows],
            los_orbit=self.los_orbit[rows],
            range_m=self.range_m[rows],
            cos_off_boresight=self.cos_off_boresight[rows],
            aircraft_ecef_km=self.aircraft_ecef_km[rows],
        )


@dataclass(frozen=True)
class Observations:
    """Visible aircraft at one epoch, one table per antenna."""

    epoch_index: int
    antennas: tuple[ObservationTable, ...]


def build_adsb_geometry(scenario: AdsbScenario | None = None) -> AdsbGeometry:
    """Geometry of ``scenario`` (default: Liu et al. 2023's) at ``t = 0, step_s, ...`` below
    ``duration_s`` (cached per process and on disk,
    :mod:`attopt.experiments.environment.disk_cache`).

    The aircraft are :func:`attopt.experiments.environment.traffic.sample_traffic` of
    ``numpy.random.default_rng(traffic.seed)``.
    """
    return _build_adsb_geometry((scenario or AdsbScenario()).key())


@functools.lru_cache(maxsize=4)
@disk_cached
def _build_adsb_geometry(key: str) -> AdsbGeometry:
    scenario = AdsbScenario.model_validate_json(key)
    t, times = window_times(scenario.start_utc, scenario.duration_s, scenario.step_s)
    orbit = propagate(satellite_from_tle(*scenario.orbit.tle()), times)
    eci_to_orbit = orbit_frame_attitude(orbit.position_eci_km, orbit.velocity_eci_kms)
    traffic = scenario.traffic
    return AdsbGeometry(
        t=t,
        start_utc=scenario.start_utc,
        position_ecef_km=orbit.position_ecef_km,
        position_eci_km=orbit.position_eci_km,
        velocity_eci_kms=orbit.velocity_eci_kms,
        subsatellite_normal=geodetic_normal(orbit.latitude_deg, orbit.longitude_deg),
        ecef_to_orbit=eci_to_orbit.as_matrix() @ ecef_to_eci_matrices(times),
        truth=scenario.attitude.attitude(t),
        traffic=sample_traffic(
            traffic.n_aircraft, np.random.default_rng(traffic.seed), traffic.model()
        ),
        boresights_body=scenario.boresights_body,
        min_cos=np.array([antenna.gain.pattern().min_cos for antenna in scenario.antennas]),
        prefilter_rad=horizon_angle_rad(orbit.position_ecef_km, traffic.height_max_km),
    )


def horizon_angle_rad(satellite_ecef_km: ArrayLike, max_height_km: float) -> float:
    """Largest central angle between the satellite and an aircraft it can see over the pass,
    plus :data:`PREFILTER_MARGIN_RAD` (module docstring)."""
    polar_km = WGS84_A_KM * (1.0 - WGS84_F)
    r_satellite = float(np.max(np.linalg.norm(np.asarray(satellite_ecef_km), axis=-1)))
    return float(
        np.arccos(polar_km / r_satellite)
        + np.arccos(polar_km / (WGS84_A_KM + max_height_km))
        + PREFILTER_MARGIN_RAD
    )


def above_limb(observer_ecef_km: ArrayLike, target_ecef_km: ArrayLike) -> NDArray[np.bool_]:
    """Whether the segment from observer to target misses the WGS84 ellipsoid.

    Both points must be above the ellipsoid.  Coordinates are scaled so that
    the ellipsoid becomes the unit sphere; the segment then misses it when its
    point closest to the centre lies outside.  Arrays broadcast over leading axes.
    """
    scale = np.array([WGS84_A_KM, WGS84_A_KM, WGS84_A_KM * (1.0 - WGS84_F)])
    start = np.asarray(observer_ecef_km, dtype=float) / scale
    step = np.asarray(target_ecef_km, dtype=float) / scale - start
    fraction = -np.sum(start * step, axis=-1) / np.sum(step * step, axis=-1)
    closest = start + np.clip(fraction, 0.0, 1.0)[..., None] * step
    return np.sum(closest * closest, axis=-1) > 1.0


def observation_chunks(
    geometry: AdsbGeometry,
    max_off_boresight_deg: float | None = None,
    epochs: ArrayLike | None = None,
) -> Iterator[ObservationTable]:
    """Visible aircraft per antenna at ``epochs`` (default all), in tables of
    :data:`EPOCH_CHUNK` consecutive entries of ``epochs``; in each antenna's main lobe, or
    within ``max_off_boresight_deg`` of every boresight."""
    index = (
        np.arange(geometry.t.size)
        if epochs is None
        else np.atleast_1d(np.asarray(epochs, dtype=np.intp))
    )
    cos_min = (
        geometry.min_cos
        if max_off_boresight_deg is None
        else np.full(geometry.n_antennas, np.cos(np.radians(max_off_boresight_deg)))
    )
    for chunk in np.array_split(index, -(-index.size // EPOCH_CHUNK)):
        yield _observe(geometry, chunk, cos_min)


def observation_table(
    geometry: AdsbGeometry,
    max_off_boresight_deg: float | None = None,
    epochs: ArrayLike | None = None,
) -> ObservationTable:
    """Visible aircraft per antenna at ``epochs`` (default all) as one long table (cones as
    in :func:`observation_chunks`).

    The whole hour in the 41.67 deg main lobe is about 1.9 million rows (160 MB);
    :func:`observation_chunks` streams it instead.
    """
    tables = list(observation_chunks(geometry, max_off_boresight_deg, epochs))
    return ObservationTable(
        **{
            name: np.concatenate([getattr(table, name) for table in tables])
            for name in ObservationTable.__dataclass_fields__
        }
    )


def visible_observations(
    geometry: AdsbGeometry, epoch_index: int, max_off_boresight_deg: float | None = None
) -> Observations:
    """Visible aircraft of each antenna at one epoch."""
    table = observation_table(geometry, max_off_boresight_deg, [epoch_index])
    return Observations(
        epoch_index=int(epoch_index),
        antennas=tuple(table.take(table.antenna == a) for a in range(geometry.n_antennas)),
    )


def visible_counts(
    geometry: AdsbGeometry, max_off_boresight_deg: float | None = None
) -> NDArray[np.intp]:
    """Number of aircraft visible in each antenna's cone, ``(N, n_antennas)`` (Liu et al.
    2023 Fig. 8)."""
    n_antennas = geometry.n_antennas
    counts = np.zeros(geometry.t.size * n_antennas, dtype=np.intp)
    for table in observation_chunks(geometry, max_off_boresight_deg):
        counts += np.bincount(table.epoch_index * n_antennas + table.antenna, minlength=counts.size)
    return counts.reshape(geometry.t.size, n_antennas)


def lines_of_sight(
    geometry: AdsbGeometry, epoch: NDArray[np.intp], aircraft_ecef_km: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Unit lines of sight in the orbit frame ``(P, 3)`` and slant ranges (km) ``(P,)`` from
    the satellite at epochs ``epoch`` ``(P,)`` to the ECEF positions ``aircraft_ecef_km``."""
    los_ecef = aircraft_ecef_km - geometry.position_ecef_km[epoch]
    range_km = np.linalg.norm(los_ecef, axis=-1)
    los_orbit = np.einsum("pij,pj->pi", geometry.ecef_to_orbit[epoch], los_ecef / range_km[:, None])
    return los_orbit, range_km


def _observe(
    geometry: AdsbGeometry, epochs: NDArray[np.intp], cos_min: NDArray[np.float64]
) -> ObservationTable:
    """Rows for a chunk of epochs; aircraft far from every sub-satellite point are skipped."""
    epoch, aircraft = (
        grid.ravel() for grid in np.meshgrid(epochs, _candidates(geometry, epochs), indexing="ij")
    )
    aircraft_ecef = positions_ecef_km(geometry.traffic, geometry.t[epoch], aircraft)
    above = above_limb(geometry.position_ecef_km[epoch], aircraft_ecef)
    epoch, aircraft, aircraft_ecef = epoch[above], aircraft[above], aircraft_ecef[above]
    los_orbit, range_km = lines_of_sight(geometry, epoch, aircraft_ecef)
    cos_off = geometry.truth[epoch].apply(los_orbit) @ geometry.boresights_body.T
    pair, antenna = np.nonzero(cos_off >= cos_min)
    order = np.lexsort((aircraft[pair], antenna, epoch[pair]))
    pair, antenna = pair[order], antenna[order]
    return ObservationTable(
        epoch_index=epoch[pair],
        antenna=antenna,
        aircraft=aircraft[pair],
        los_orbit=los_orbit[pair],
        range_m=1000.0 * range_km[pair],
        cos_off_boresight=cos_off[pair, antenna],
        aircraft_ecef_km=aircraft_ecef[pair],
    )


def _candidates(geometry: AdsbGeometry, epochs: NDArray[np.intp]) -> NDArray[np.intp]:
    """Aircraft that may be above the limb (:attr:`AdsbGeometry.prefilter_rad` from a
    sub-satellite point).

    Tested once at the chunk's middle epoch with the radius widened by how far
    the sub-satellite point and the fastest aircraft move within the chunk.
    """
    middle = epochs[epochs.size // 2]
    centre = geometry.subsatellite_normal[middle]
    satellite_spread = np.max(
        np.arccos(np.clip(geometry.subsatellite_normal[epochs] @ centre, -1.0, 1.0))
    )
    time_spread = np.max(np.abs(geometry.t[epochs] - geometry.t[middle]))
    radius = (
        geometry.prefilter_rad
        + satellite_spread
        + geometry.traffic.angular_rate_rad_s.max() * time_spread
    )
    normals = geodetic_normals(geometry.traffic, geometry.t[middle])
    return np.flatnonzero(normals @ centre >= np.cos(min(radius, np.pi)))
