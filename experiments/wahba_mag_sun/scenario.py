"""The ``wahba-mag-sun`` scenario: a satellite with a magnetometer and a Sun sensor.

Cilden Guler et al. 2017 sec. 3: a satellite on the TIMED orbit (propagated from its TLE)
measures the geomagnetic field (IGRF) and the Sun direction at 1 Hz for about
one orbit (6000 s); direction-cosine noise standard deviations are 0.008
(magnetometer) and 0.002 (Sun sensor); there is no Sun measurement in eclipse.
Each of these is a parameter (:mod:`attopt.experiments.wahba_mag_sun.parameters`),
the paper's values the defaults.

Orbit and window.  The orbit's TLE (given, or generated for a circular orbit) is
propagated with SGP4 at ``t = 0, step_s, ...`` below ``duration_s`` from
``start_utc``.  The default TLE (NORAD 26998, epoch 2026-05-10 22:35:56 UTC):
near that epoch the beta angle is about -55 deg, so each orbit has an eclipse
of about 24 min.  The default start is 47 min after the TLE epoch, chosen so
that the 6000 s window holds exactly one eclipse, entering 1001 s after the
start and lasting about 1450 s (the eclipse of Cilden Guler et al. 2017 sec. 3
is at 1000-1500 s; ours is wherever the orbit puts it).

Eclipses.  The Sun sensor is blind in the Earth's cylindrical shadow
(:mod:`attopt.experiments.environment.shadow`).  A window may hold no eclipse,
one, or several (an orbit lasts about 95 min in low Earth orbit), and may start
or end inside one; :func:`interval_labels` names each epoch by its place
among them (:data:`INTERVALS`).

Reference vectors are expressed in the orbit frame of
:func:`attopt.formulations.conventions.orbit_frame_attitude` (Cilden Guler et al. 2017
eqs. 1-4).

True attitude (orbit -> body): the 3-2-1 Euler-angle profile of
:class:`~attopt.experiments.wahba_mag_sun.parameters.AttitudeProfile` (Liu et al. 2023
eq. 8), by default imitating the pitch of Cilden Guler et al. 2017 Fig. 2 (pitch close to
+/-90 deg near 1000 s and 3800 s)::

    pitch(t) = 87 deg * cos(2 pi (t - 1000) / 5600)
    roll(t)  =  3 deg * sin(2 pi t / 1500)
    yaw(t)   =  4 deg * sin(2 pi t / 2300)
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray
from scipy.spatial.transform import Rotation

from attopt.experiments.environment.disk_cache import disk_cached
from attopt.experiments.environment.geomagnetic import geomagnetic_field_eci
from attopt.experiments.environment.orbit import propagate, satellite_from_tle, window_times
from attopt.experiments.environment.shadow import in_cylindrical_shadow
from attopt.experiments.environment.sun import sun_direction_eci
from attopt.formulations.conventions import attitude_from_euler321, orbit_frame_attitude

if TYPE_CHECKING:
    from attopt.experiments.config.components import CircularOrbit, TleOrbit
    from attopt.experiments.wahba_mag_sun.parameters import AttitudeProfile

INTERVALS = ("no_eclipse", "before_eclipse", "eclipse", "between_eclipses", "after_eclipse")
"""The ``interval`` of an epoch: ``no_eclipse`` in a window without eclipse; else
``eclipse`` in one, and sunlit ``before_eclipse`` (before the first),
``between_eclipses`` or ``after_eclipse`` (after the last)."""


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
    eclipses: tuple[tuple[float, float], ...]
    """``(start_s, end_s)`` of each eclipse in the window, in time order, with
    ``in_eclipse`` true exactly on ``start_s <= t < end_s`` of one of them; ``end_s`` is
    one step after the last eclipsed epoch.  Empty without eclipse."""
    position_eci_km: NDArray[np.float64]
    """Satellite positions in ECI (GCRS), ``(N, 3)``."""
    velocity_eci_kms: NDArray[np.float64]
    """Satellite velocities in ECI (GCRS), ``(N, 3)``."""


def true_attitude(t: NDArray[np.float64], profile: AttitudeProfile) -> Rotation:
    """The orbit -> body attitude of ``profile`` (module docstring) at times ``t`` (s)."""
    pitch = profile.pitch_amplitude_deg * np.cos(
        2.0 * np.pi * (t - profile.pitch_peak_s) / profile.pitch_period_s
    )
    roll = profile.roll_amplitude_deg * np.sin(2.0 * np.pi * t / profile.roll_period_s)
    yaw = profile.yaw_amplitude_deg * np.sin(2.0 * np.pi * t / profile.yaw_period_s)
    return attitude_from_euler321(np.radians(yaw), np.radians(pitch), np.radians(roll))


@functools.lru_cache(maxsize=8)
@disk_cached
def build_geometry(
    orbit: TleOrbit | CircularOrbit,
    start_utc: str,
    duration_s: float,
    step_s: float,
    attitude: AttitudeProfile,
) -> VectorGeometry:
    """Geometry of ``orbit`` with the true ``attitude`` at the epochs of
    :func:`~attopt.experiments.environment.orbit.window_times` (cached per process and on
    disk, :mod:`attopt.experiments.environment.disk_cache`)."""
    t, times = window_times(start_utc, duration_s, step_s)
    states = propagate(satellite_from_tle(*orbit.tle()), times)
    sun_eci = sun_direction_eci(times, states.position_eci_km)
    mag_eci = geomagnetic_field_eci(
        times, states.longitude_deg, states.latitude_deg, states.height_km
    )
    mag_nT = np.linalg.norm(mag_eci, axis=-1)
    eci_to_orbit = orbit_frame_attitude(states.position_eci_km, states.velocity_eci_kms)
    in_eclipse = in_cylindrical_shadow(states.position_eci_km, sun_eci)
    return VectorGeometry(
        t=t,
        start_utc=start_utc,
        sun_orbit=eci_to_orbit.apply(sun_eci),
        mag_orbit=eci_to_orbit.apply(mag_eci / mag_nT[:, None]),
        mag_nT=mag_nT,
        in_eclipse=in_eclipse,
        truth=true_attitude(t, attitude),
        eclipses=eclipse_intervals(t, in_eclipse, step_s),
        position_eci_km=states.position_eci_km,
        velocity_eci_kms=states.velocity_eci_kms,
    )


def eclipse_intervals(
    t: NDArray[np.float64], in_eclipse: NDArray[np.bool_], step_s: float
) -> tuple[tuple[float, float], ...]:
    """Half-open ``[start, end)`` of each run of eclipsed epochs, ``end`` one step after
    the run's last epoch."""
    eclipsed = np.flatnonzero(in_eclipse)
    if eclipsed.size == 0:
        return ()
    breaks = np.flatnonzero(np.diff(eclipsed) != 1)
    firsts = eclipsed[np.concatenate([[0], breaks + 1])]
    lasts = eclipsed[np.concatenate([breaks, [eclipsed.size - 1]])]
    return tuple(
        (float(t[first]), float(t[last] + step_s))
        for first, last in zip(firsts, lasts, strict=True)
    )


def interval_labels(geometry: VectorGeometry) -> NDArray[np.object_]:
    """The :data:`INTERVALS` label of each epoch."""
    if not geometry.eclipses:
        return np.full(geometry.t.shape, INTERVALS[0], dtype=object)
    labels = np.full(geometry.t.shape, "between_eclipses", dtype=object)
    labels[geometry.t < geometry.eclipses[0][0]] = "before_eclipse"
    labels[geometry.t >= geometry.eclipses[-1][1]] = "after_eclipse"
    labels[geometry.in_eclipse] = "eclipse"
    return labels


def simulate_measurements(
    geometry: VectorGeometry,
    rng: np.random.Generator,
    *,
    mag_sigma_rad: float,
    sun_sigma_rad: float,
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
    mag_body = _normalise(geometry.truth.apply(geometry.mag_orbit) + mag_sigma_rad * mag_noise)
    sun_body = _normalise(geometry.truth.apply(geometry.sun_orbit) + sun_sigma_rad * sun_noise)
    sun_body[geometry.in_eclipse] = np.nan
    return sun_body, mag_body


def _normalise(vectors: NDArray[np.float64]) -> NDArray[np.float64]:
    return vectors / np.linalg.norm(vectors, axis=-1, keepdims=True)
