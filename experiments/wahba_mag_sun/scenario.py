"""The ``wahba-mag-sun`` scenario: TIMED with a magnetometer and a Sun sensor.

Cilden Guler et al. 2017 sec. 3: a satellite on the TIMED orbit (propagated from its TLE)
measures the geomagnetic field (IGRF) and the Sun direction at 1 Hz for about
one orbit (6000 s); direction-cosine noise standard deviations are 0.008
(magnetometer) and 0.002 (Sun sensor); there is no Sun measurement in eclipse.

Orbit and window.  The TLE below (NORAD 26998, epoch 2026-05-10 22:35:56 UTC)
is propagated with SGP4.  Near that epoch the beta angle is about -55 deg, so
each orbit has an eclipse of about 24 min.  :data:`START_UTC` is 47 min after
the TLE epoch, chosen so that the 6000 s window holds exactly one eclipse,
entering 1001 s after the start and lasting about 1450 s (the eclipse of seed
002 sec. 3 is at 1000-1500 s; ours is wherever the orbit puts it, computed
with the cylindrical shadow of :mod:`attopt.experiments.environment.shadow`).

Reference vectors are expressed in the orbit frame of
:func:`attopt.formulations.conventions.orbit_frame_attitude` (Cilden Guler et al. 2017 eqs. 1-4).

True attitude (orbit -> body), 3-2-1 Euler angles of Liu et al. 2023 eq. 8 with ``t``
in seconds from the start, imitating the pitch profile of Cilden Guler et al. 2017 Fig. 2
(pitch close to +/-90 deg near 1000 s and 3800 s)::

    pitch(t) = 87 deg * cos(2 pi (t - 1000) / 5600)
    roll(t)  =  3 deg * sin(2 pi t / 1500)
    yaw(t)   =  4 deg * sin(2 pi t / 2300)
"""

from __future__ import annotations

import functools
from dataclasses import dataclass

import astropy.units as u
import numpy as np
from astropy.time import Time
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.experiments.environment.geomagnetic import geomagnetic_field_eci
from attopt.experiments.environment.orbit import propagate, satellite_from_tle
from attopt.experiments.environment.shadow import in_cylindrical_shadow
from attopt.experiments.environment.sun import sun_direction_eci
from attopt.formulations.conventions import attitude_from_euler321, orbit_frame_attitude

# TIMED (NORAD 26998), epoch 26130.94162250 = 2026-05-10 22:35:56.184 UTC.
TLE_LINE1 = "1 26998U 01055B   26130.94162250  .00000829  00000+0  79016-4 0  9991"
TLE_LINE2 = "2 26998  74.0671 310.0081 0001049 187.4151 172.7018 14.95201872325257"

START_UTC = "2026-05-10T23:23:00"
"""Start of the window (UTC); the eclipse begins 1001 s later."""

MAG_SIGMA = 0.008
"""Magnetometer direction-cosine noise standard deviation (Cilden Guler et al. 2017 sec. 3)."""
SUN_SIGMA = 0.002
"""Sun-sensor direction-cosine noise standard deviation (Cilden Guler et al. 2017 sec. 3)."""

PITCH_AMPLITUDE_DEG = 87.0
PITCH_PEAK_S = 1000.0
PITCH_PERIOD_S = 5600.0
ROLL_AMPLITUDE_DEG = 3.0
ROLL_PERIOD_S = 1500.0
YAW_AMPLITUDE_DEG = 4.0
YAW_PERIOD_S = 2300.0


@dataclass(frozen=True)
class VectorGeometry:
    """True geometry of the scenario at ``N`` epochs.

    Instances are cached and shared: do not modify the arrays in place.  (They
    are not flagged read-only because scipy's ``Rotation.apply`` rejects
    read-only input.)
    """

    t: NDArray[np.float64]
    """Seconds from :attr:`start_utc`, shape ``(N,)``."""
    start_utc: str
    """ISO UTC time of ``t = 0``."""
    sun_orbit: NDArray[np.float64]
    """Unit satellite-to-Sun directions in the orbit frame, ``(N, 3)``."""
    mag_orbit: NDArray[np.float64]
    """Unit geomagnetic-field directions in the orbit frame, ``(N, 3)``."""
    mag_nT: NDArray[np.float64]
    """Geomagnetic field magnitude in nT, ``(N,)``."""
    in_eclipse: NDArray[np.bool_]
    """Whether the satellite is in the Earth's (cylindrical) shadow, ``(N,)``."""
    truth: Rotation
    """True attitude, orbit frame -> body frame, ``N`` rotations."""
    eclipse_interval: tuple[float, float] | None
    """``(start_s, end_s)`` with ``in_eclipse == (start_s <= t < end_s)``; ``None``
    without eclipse.  ``end_s`` is one step after the last eclipsed epoch."""
    position_eci_km: NDArray[np.float64]
    """Satellite positions in ECI (GCRS), ``(N, 3)``."""
    velocity_eci_kms: NDArray[np.float64]
    """Satellite velocities in ECI (GCRS), ``(N, 3)``."""


def true_attitude(t: NDArray[np.float64]) -> Rotation:
    """The orbit -> body attitude profile of the module docstring at times ``t`` (s)."""
    pitch = PITCH_AMPLITUDE_DEG * np.cos(2.0 * np.pi * (t - PITCH_PEAK_S) / PITCH_PERIOD_S)
    roll = ROLL_AMPLITUDE_DEG * np.sin(2.0 * np.pi * t / ROLL_PERIOD_S)
    yaw = YAW_AMPLITUDE_DEG * np.sin(2.0 * np.pi * t / YAW_PERIOD_S)
    return attitude_from_euler321(np.radians(yaw), np.radians(pitch), np.radians(roll))


def build_geometry(duration_s: float = 6000.0, step_s: float = 1.0) -> VectorGeometry:
    """Geometry at ``t = 0, step_s, ...`` below ``duration_s`` (cached per process).

    Raises:
        ValueError: if the window holds more than one eclipse.
    """
    return _build_geometry(float(duration_s), float(step_s))


@functools.lru_cache(maxsize=8)
def _build_geometry(duration_s: float, step_s: float) -> VectorGeometry:
    t = np.arange(0.0, duration_s, step_s)
    times = Time(START_UTC, scale="utc") + t * u.s
    orbit = propagate(satellite_from_tle(TLE_LINE1, TLE_LINE2), times)
    sun_eci = sun_direction_eci(times, orbit.position_eci_km)
    mag_eci = geomagnetic_field_eci(times, orbit.longitude_deg, orbit.latitude_deg, orbit.height_km)
    mag_nT = np.linalg.norm(mag_eci, axis=-1)
    eci_to_orbit = orbit_frame_attitude(orbit.position_eci_km, orbit.velocity_eci_kms)
    in_eclipse = in_cylindrical_shadow(orbit.position_eci_km, sun_eci)
    return VectorGeometry(
        t=t,
        start_utc=START_UTC,
        sun_orbit=eci_to_orbit.apply(sun_eci),
        mag_orbit=eci_to_orbit.apply(mag_eci / mag_nT[:, None]),
        mag_nT=mag_nT,
        in_eclipse=in_eclipse,
        truth=true_attitude(t),
        eclipse_interval=_eclipse_interval(t, in_eclipse, step_s),
        position_eci_km=orbit.position_eci_km,
        velocity_eci_kms=orbit.velocity_eci_kms,
    )


def _eclipse_interval(
    t: NDArray[np.float64], in_eclipse: NDArray[np.bool_], step_s: float
) -> tuple[float, float] | None:
    """Half-open ``[start, end)`` of the single eclipse in the window, if any."""
    eclipsed = np.flatnonzero(in_eclipse)
    if eclipsed.size == 0:
        return None
    if np.any(np.diff(eclipsed) != 1):
        raise ValueError("the window holds more than one eclipse; shorten duration_s")
    return float(t[eclipsed[0]]), float(t[eclipsed[-1]] + step_s)


def simulate_measurements(
    geometry: VectorGeometry,
    rng: np.random.Generator,
    *,
    mag_sigma: float = MAG_SIGMA,
    sun_sigma: float = SUN_SIGMA,
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Measured body-frame unit vectors ``(sun_body, mag_body)``, each ``(N, 3)``.

    ``b = normalise(A r + sigma eps)`` with ``eps ~ N(0, I3)`` (Cilden Guler et al. 2017 eqs. 2
    and 4).  All magnetometer noise is drawn first, then all Sun noise (for
    every epoch, eclipsed or not), so a seed fixes both.  Sun rows are NaN in
    eclipse, where the Sun sensor gives no measurement.
    """
    n = geometry.t.size
    mag_noise = rng.standard_normal((n, 3))
    sun_noise = rng.standard_normal((n, 3))
    mag_body = _normalise(geometry.truth.apply(geometry.mag_orbit) + mag_sigma * mag_noise)
    sun_body = _normalise(geometry.truth.apply(geometry.sun_orbit) + sun_sigma * sun_noise)
    sun_body[geometry.in_eclipse] = np.nan
    return sun_body, mag_body


def _normalise(vectors: NDArray[np.float64]) -> NDArray[np.float64]:
    return vectors / np.linalg.norm(vectors, axis=-1, keepdims=True)
