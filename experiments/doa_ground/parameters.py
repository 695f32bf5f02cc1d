"""The parameter tables of ``doa-ground``: the pass, the stations, the truth, the array, MUSIC
and the filters' prior (Yang et al. 2014 secs. 4-6).

The defaults are Yang et al. 2014's set-up as :mod:`attopt.experiments.doa_ground.scenario`
reads it (the orbit of sec. 4.1, eight stations near its ground track, the rigid body of
eqs. 23 and 25, the 12-element UCA of sec. 4.1, the initial estimate of sec. 6); what the
paper leaves open (the stations, the true initial state, the wheel) is explained there.

* :class:`DoaScenario`: what the simulated world needs (``orbit``, ``start_utc``,
  ``duration_s``, ``step_s``, ``[[stations]]``, ``min_elevation_deg``, ``[attitude]``);
  the experiment's parameters extend it, and its geometry is cached per scenario;
* ``[attitude]`` (:class:`RigidBodyTruth`): inertia, wheel momentum and the true
  initial state;
* ``[array]`` (:class:`DoaArray`): the uniform circular array;
* ``[music]`` (:class:`MusicGrid`): MUSIC's coarse grid and rejection thresholds;
* ``[prior]`` (:class:`FilterPrior`): the filters' initial estimate and its sigmas.
"""

from __future__ import annotations

import math
from typing import Annotated, Any

import numpy as np
from pydantic import Field, ValidationInfo, field_validator, model_validator

from attopt.experiments.config import Parameters
from attopt.experiments.config.components import Orbit, Station, Stations, TleOrbit, UtcTime
from attopt.formulations.doa_array import UniformCircularArray
from attopt.formulations.rigid_body import YANG2014_INERTIA

SPEED_OF_LIGHT_M_S = 299_792_458.0
"""For ``wavelength_m = c / frequency_hz``."""

SATELLITE_TLE = (
    "1 99003U          25060.00000000  .00000000  00000-0  00000+0 0    06",
    "2 99003  98.6000 101.8100 0001000   0.0000   0.0000 14.27530922    03",
)
"""The default orbit (Yang et al. 2014 sec. 4.1: Sun-synchronous, 800 km, descending node
at 8:00): the TLE sgp4 generates
(:func:`attopt.experiments.environment.orbit.circular_orbit_tle`) for epoch
2025-03-01 00:00 UTC, semi-major axis 800 km above sgp4's WGS72 equator, eccentricity
1e-4, inclination 98.60 deg (the ``J2`` node drift then follows the mean Sun), argument of
perigee and mean anomaly 0 and right ascension of the ascending node 101.81 deg (the Sun's
right ascension at the epoch plus 120 deg)."""

START_UTC = "2025-03-01T00:00:00"
"""Start of the default pass: the TLE's epoch, at the ascending node."""

STATIONS = tuple(
    Station(name=f"S{k}", latitude_deg=latitude, longitude_deg=longitude)
    for k, (latitude, longitude) in enumerate(
        (
            (17.62, -60.23),
            (52.75, -73.40),
            (81.41, -147.03),
            (54.34, 125.11),
            (19.26, 115.52),
            (-16.19, 105.50),
            (-51.26, 96.70),
            (-81.09, 29.25),
        ),
        start=1,
    )
)
"""The eight default stations (geodetic, height 0 on WGS84): near the default pass's ground
track, one every 600 s from 300 s on (the scenario's docstring)."""


Finite = Annotated[float, Field(allow_inf_nan=False)]
"""A finite number (TOML has nan and inf)."""


def _vector(default: list[float], description: str) -> Any:
    return Field(
        default_factory=lambda: list(default),
        min_length=3,
        max_length=3,
        description=description,
    )


class RigidBodyTruth(Parameters):
    """``[attitude]``: the true rigid body (Yang et al. 2014 eqs. 23, 25) and its initial state.

    Torque free with a constant wheel momentum (``h_dot = 0``); the satellite starts
    ``initial_euler_deg`` off Earth pointing with the orbit frame's rate plus
    ``initial_rate_offset_deg_s``.  The filters that know the dynamics (Yang et al.
    2014's EKF, its RTS pass, the batch least squares) are given the same inertia and
    wheel momentum.
    """

    inertia_kg_m2: list[list[float]] = Field(
        default_factory=lambda: YANG2014_INERTIA.tolist(),
        description="Inertia matrix, body axes (Yang et al. 2014 eq. 25).",
    )
    wheel_momentum_nms: list[Finite] = _vector(
        [0.0, -0.1, 0.0], "Constant wheel angular momentum, body axes (a pitch momentum bias)."
    )
    initial_euler_deg: list[Finite] = _vector(
        [3.0, -2.0, 2.0], "True initial 3-2-1 (yaw, pitch, roll) of the body from the orbit frame."
    )
    initial_rate_offset_deg_s: list[Finite] = _vector(
        [0.005, 0.0, -0.004], "True initial body rate minus the orbit frame's, body axes."
    )

    @field_validator("inertia_kg_m2")
    @classmethod
    def _physical(cls, value: list[list[float]]) -> list[list[float]]:
        matrix = np.asarray(value, dtype=float) if all(len(r) == 3 for r in value) else None
        if matrix is None or matrix.shape != (3, 3) or not np.isfinite(matrix).all():
            raise ValueError("inertia must be a finite 3 x 3 matrix")
        if not np.allclose(matrix, matrix.T):
            raise ValueError("inertia must be symmetric")
        moments = np.linalg.eigvalsh(matrix)
        if moments[0] <= 0.0 or moments[0] + moments[1] < moments[2]:
            raise ValueError(
                f"principal moments {np.round(moments, 6).tolist()} must be positive and obey "
                "the triangle inequality"
            )
        return value

    @property
    def inertia(self) -> np.ndarray:
        """``(3, 3)`` kg m^2."""
        return np.array(self.inertia_kg_m2, dtype=float)

    @property
    def wheel_momentum(self) -> np.ndarray:
        """``(3,)`` N m s."""
        return np.array(self.wheel_momentum_nms, dtype=float)


class DoaScenario(Parameters):
    """What the simulated world of ``doa-ground`` depends on (its geometry is cached by it)."""

    orbit: Orbit = Field(
        default_factory=lambda: TleOrbit(line1=SATELLITE_TLE[0], line2=SATELLITE_TLE[1]),
        description="A TLE or a generated circular orbit (default Yang et al. 2014 sec. 4.1).",
    )
    start_utc: UtcTime = Field(START_UTC, description="Start of the pass.")
    duration_s: float = Field(5000.0, gt=0, description="Length of the pass (sec. 6).")
    step_s: float = Field(0.25, gt=0, description="Processing step (sec. 4.2).")
    stations: Stations = Field(
        default_factory=lambda: list(STATIONS),
        min_length=1,
        description="Ground transmitters whose DOAs the array measures.",
    )
    min_elevation_deg: float = Field(
        10.0, ge=0.0, lt=90.0, description="Elevation above which a station is visible."
    )
    attitude: RigidBodyTruth = Field(
        default_factory=RigidBodyTruth, description="True rigid body and initial state."
    )

    @field_validator("step_s")
    @classmethod
    def _two_epochs(cls, value: float, info: ValidationInfo) -> float:
        duration = info.data.get("duration_s")
        if duration is not None and value >= duration:
            raise ValueError(f"step_s must be below duration_s = {duration:g}")
        return value

    def scenario(self) -> DoaScenario:
        """Only the scenario's fields (of a subclass's instance): the geometry's cache key."""
        return DoaScenario.model_validate(
            {name: getattr(self, name) for name in DoaScenario.model_fields}
        )


class DoaArray(Parameters):
    """``[array]``: the uniform circular array (Yang et al. 2014 sec. 4.1, eqs. 19-21), its
    plane parallel to the body x-y plane; give ``wavelength_m`` or ``frequency_hz``."""

    n_elements: int = Field(12, ge=3, description="Number of elements M.")
    radius_m: float = Field(0.15, gt=0.0, description="Radius r of the circle of elements.")
    wavelength_m: float = Field(0.15, gt=0.0, description="Carrier wavelength lambda.")
    frequency_hz: float | None = Field(
        None, gt=0.0, description="Carrier frequency instead of wavelength_m (lambda = c / f)."
    )

    @model_validator(mode="before")
    @classmethod
    def _wavelength_from_frequency(cls, data: Any) -> Any:
        frequency = data.get("frequency_hz") if isinstance(data, dict) else None
        if isinstance(frequency, int | float) and frequency > 0 and "wavelength_m" not in data:
            data = {**data, "wavelength_m": SPEED_OF_LIGHT_M_S / frequency}
        return data

    @model_validator(mode="after")
    def _consistent(self) -> DoaArray:
        if self.frequency_hz is not None:
            implied = SPEED_OF_LIGHT_M_S / self.frequency_hz
            if not math.isclose(self.wavelength_m, implied, rel_tol=1e-12):
                raise ValueError(
                    f"wavelength_m = {self.wavelength_m} and frequency_hz = {self.frequency_hz} "
                    f"disagree (c / f = {implied:.6g} m): give one of them"
                )
        return self

    def array(self) -> UniformCircularArray:
        """The library's array."""
        return UniformCircularArray(self.n_elements, self.radius_m, self.wavelength_m)


class MusicGrid(Parameters):
    """``[music]``: the coarse grid and the rejection thresholds of MUSIC
    (:class:`~attopt.solvers.doa.music.MusicEstimator`)."""

    grid_step: float = Field(
        0.04, gt=0.0, description="Grid spacing in direction cosines of the array plane."
    )
    cone_half_angle_deg: float = Field(
        70.0, gt=0.0, le=90.0, description="Polar angle of the grid's cone (stations <= 62 deg)."
    )
    peak_ratio_threshold: float = Field(
        0.5, gt=0.0, le=1.0, description="Ambiguous when the second peak reaches this share."
    )
    horizon_angle_deg: float = Field(
        85.0, gt=0.0, le=90.0, description="Estimates at or beyond this polar angle are rejected."
    )
    threshold_output_snr: float = Field(
        150.0,
        ge=0.0,
        description=(
            "Output SNR L M SNR below which a DOA's covariance does not describe its tail: "
            "single-frame rows do not use it (docs/doa.md)."
        ),
    )
    threshold_variance_factor: float = Field(
        2.0,
        ge=1.0,
        description=(
            "Below threshold_output_snr a DOA's covariance is the CRB times this factor "
            "(docs/doa.md)."
        ),
    )


class FilterPrior(Parameters):
    """``[prior]``: the filters' initial estimate (Yang et al. 2014 sec. 6: yaw = roll = pitch =
    50 deg and 0.5 deg/s per axis, read as the estimate, not the truth) and its sigmas.

    Yang et al. 2014's EKF, its RTS pass and the gyro-aided rows start from it (the
    gyro-aided rows with the gyro's turn-on bias sigma instead of a rate)."""

    euler_deg: list[Finite] = _vector(
        [50.0, 50.0, 50.0], "Initial 3-2-1 (yaw, pitch, roll) estimate of the body from the orbit."
    )
    rate_deg_s: list[Finite] = _vector(
        [0.5, 0.5, 0.5], "Initial estimate of the inertial body rate, body axes."
    )
    sigma_deg: float = Field(60.0, gt=0.0, description="Per-axis attitude sigma of the prior.")
    rate_sigma_deg_s: float = Field(0.5, gt=0.0, description="Per-axis rate sigma of the prior.")
