"""Nested parameter tables that several experiments share.

* ``[orbit]``: a TLE (:class:`TleOrbit`) or a near-circular orbit generated
  from its altitude, inclination (or Sun-synchronous) and local time of the
  ascending node (:class:`CircularOrbit`);
* ``[gyro]``: a named preset (:data:`attopt.formulations.gyro.GYRO_MODELS`) or
  the datasheet numbers (:class:`GyroNumbers`);
* ``[gyro_fault]``: faults of the measured gyro samples, a scale-factor error, an axis
  stuck at a constant and a time-tag offset (:class:`GyroFault`);
* ``[[antennas]]``: a boresight in the body frame and a gain pattern
  (:class:`CosinePowerGain`, :class:`ParabolicGain`, :class:`TableGain`);
* ``[[stations]]``: a named geodetic site (:class:`Station`).

Each table converts itself to the library's object (``tle()``,
:func:`gyro_model`, ``pattern()``); the experiments never hold these
constants in code.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
import pandas as pd
from pydantic import AfterValidator, Discriminator, Field, Tag, field_validator, model_validator
from sgp4.api import Satrec

from attopt.experiments.config.schema import Parameters
from attopt.formulations.gain_patterns import (
    CosinePowerPattern,
    GainPattern,
    ParabolicPattern,
    TabulatedPattern,
)
from attopt.formulations.gyro import GYRO_MODELS, GyroModel, GyroSamples, SimulatedGyro

DEG = math.pi / 180.0
J2 = 1.08262668e-3
"""Earth's second zonal harmonic (WGS84 / EGM96 value) for the Sun-synchronous inclination."""
EARTH_RADIUS_KM = 6378.135
"""sgp4's WGS72 equatorial radius: altitudes are semi-major axis minus this."""
EARTH_MU_KM3_S2 = 398600.8
"""sgp4's WGS72 gravitational parameter."""
TROPICAL_YEAR_S = 365.2421897 * 86400.0


class TleOrbit(Parameters):
    """An orbit given by a two-line element set (propagated with sgp4)."""

    type: Literal["tle"] = Field("tle", description="Orbit given by a TLE.")
    line1: str = Field(description="First line of the TLE.")
    line2: str = Field(description="Second line of the TLE.")

    @model_validator(mode="after")
    def _parses(self) -> TleOrbit:
        satellite = Satrec.twoline2rv(self.line1, self.line2)
        if satellite.error != 0:
            raise ValueError(f"sgp4 cannot initialise this TLE (error {satellite.error})")
        return self

    def tle(self) -> tuple[str, str]:
        """The two lines."""
        return self.line1, self.line2


class CircularOrbit(Parameters):
    """A near-circular orbit generated from its altitude, inclination and node time.

    The right ascension of the ascending node is the Sun's at ``epoch_utc`` plus
    ``15 deg/h (ltan_h - 12 h)`` (astropy ``get_sun``); without ``inclination_deg`` the
    orbit is Sun-synchronous: ``cos i = -2 a^(7/2) dOmega/dt / (3 J2 R^2 sqrt(mu))``
    with ``dOmega/dt = 2 pi / year`` (Vallado 2013, eq. 9-44, circular orbit).
    """

    type: Literal["circular"] = Field("circular", description="Generated near-circular orbit.")
    altitude_km: float = Field(
        600.0, gt=100.0, lt=40000.0, description="Semi-major axis minus the equatorial radius."
    )
    inclination_deg: float | None = Field(
        None, ge=0.0, le=180.0, description="Inclination; leave out for Sun-synchronous."
    )
    ltan_h: float = Field(22.5, ge=0.0, lt=24.0, description="Local time of the ascending node.")
    epoch_utc: str = Field("2025-06-01T00:00:00", description="Epoch of the elements.")
    eccentricity: float = Field(1.0e-4, ge=0.0, lt=0.1, description="Eccentricity.")
    argument_of_perigee_deg: float = Field(0.0, description="Argument of perigee.")
    mean_anomaly_deg: float = Field(0.0, description="Mean anomaly at epoch.")
    satellite_number: int = Field(99999, ge=1, le=99999, description="Catalogue number in the TLE.")

    @field_validator("epoch_utc")
    @classmethod
    def _is_a_time(cls, value: str) -> str:
        return _checked_time(value)

    @property
    def sun_synchronous_inclination_deg(self) -> float:
        """The inclination whose J2 node drift follows the mean Sun."""
        a = EARTH_RADIUS_KM + self.altitude_km
        node_rate = 2.0 * math.pi / TROPICAL_YEAR_S
        cos_i = (
            -2.0 * a**3.5 * node_rate / (3.0 * J2 * EARTH_RADIUS_KM**2 * math.sqrt(EARTH_MU_KM3_S2))
        )
        if not -1.0 <= cos_i <= 1.0:
            raise ValueError(f"no Sun-synchronous orbit at {self.altitude_km} km")
        return math.degrees(math.acos(cos_i))

    @property
    def raan_deg(self) -> float:
        """Right ascension of the ascending node from the local time of the node."""
        from astropy.coordinates import get_sun
        from astropy.time import Time

        sun_ra = float(get_sun(Time(self.epoch_utc, scale="utc")).ra.deg)
        return (sun_ra + 15.0 * (self.ltan_h - 12.0)) % 360.0

    def tle(self) -> tuple[str, str]:
        """The TLE sgp4 generates for these elements
        (:func:`attopt.experiments.environment.orbit.circular_orbit_tle`)."""
        from attopt.experiments.environment.orbit import circular_orbit_tle

        inclination = self.inclination_deg
        if inclination is None:
            inclination = self.sun_synchronous_inclination_deg
        return circular_orbit_tle(
            self.epoch_utc,
            self.satellite_number,
            self.altitude_km,
            inclination,
            self.raan_deg,
            self.eccentricity,
            self.argument_of_perigee_deg,
            self.mean_anomaly_deg,
        )


Orbit = Annotated[TleOrbit | CircularOrbit, Field(discriminator="type")]
"""``[orbit]``: ``type = "tle"`` or ``type = "circular"``."""


class GyroNumbers(Parameters):
    """A gyro given by its datasheet numbers (converted to the model of
    :mod:`attopt.formulations.gyro`: ``sigma_v`` from the angle random walk, ``sigma_u``
    from the rate random walk, the turn-on bias sigma per axis)."""

    name: str = Field("custom", description="Label of the gyro in tables.")
    rate_hz: float = Field(10.0, gt=0.0, description="Sampling rate.")
    arw_deg_sqrt_h: float = Field(0.3, ge=0.0, description="Angle random walk.")
    rrw_deg_h_sqrt_h: float = Field(10.0, ge=0.0, description="Rate random walk.")
    turn_on_bias_deg_h: float = Field(360.0, ge=0.0, description="Turn-on bias sigma per axis.")

    def model(self) -> GyroModel:
        """The :class:`~attopt.formulations.gyro.GyroModel` of these numbers."""
        return GyroModel(
            name=self.name,
            sigma_v=self.arw_deg_sqrt_h * DEG / 60.0,
            sigma_u=self.rrw_deg_h_sqrt_h * DEG / 3600.0 / 60.0,
            initial_bias_sigma=self.turn_on_bias_deg_h * DEG / 3600.0,
            rate_hz=self.rate_hz,
        )


GyroPreset = Literal[tuple(GYRO_MODELS)]
Gyro = Annotated[
    Annotated[GyroPreset, Tag("preset")] | Annotated[GyroNumbers, Tag("numbers")],
    Discriminator(lambda value: "preset" if isinstance(value, str) else "numbers"),
]
"""``gyro = "mems"`` (a preset) or a ``[gyro]`` table of numbers (a string is checked
against the presets only, a table against the numbers only)."""


def gyro_model(gyro: str | GyroNumbers | dict) -> GyroModel:
    """The gyro model of a preset name, a :class:`GyroNumbers` or its document.

    Example::

        >>> gyro_model("mems").name, gyro_model({"name": "fog", "arw_deg_sqrt_h": 0.01}).name
        ('mems', 'fog')
    """
    if isinstance(gyro, str):
        return GYRO_MODELS[gyro]
    if isinstance(gyro, dict):
        gyro = GyroNumbers.model_validate(gyro)
    return gyro.model()


AXIS_INDEX = {"x": 0, "y": 1, "z": 2}
"""Body axis name -> column of the gyro's rates."""


class ScaleFactorFault(Parameters):
    """``[gyro_fault.scale_factor]``: the true rates scaled by ``1 + s`` before the bias
    and the noise are added, ``omega_measured = (1 + s) omega + beta + eta_v`` (the
    scale-factor term of Markley and Crassidis 2014 sec. 4.7.1's gyro model), over the
    whole pass."""

    error: float | list[float] = Field(
        description="Scale-factor error s: one for every axis or one per body axis (x, y, z).",
    )

    @field_validator("error")
    @classmethod
    def _finite_per_axis(cls, error: float | list[float]) -> float | list[float]:
        values = error if isinstance(error, list) else [error]
        if isinstance(error, list) and len(error) != 3:
            raise ValueError(f"one error per axis needs 3 values, got {len(error)}")
        if not all(math.isfinite(v) and v > -1.0 for v in values):
            raise ValueError("scale-factor errors must be finite and above -1")
        return error

    def apply(self, gyro: SimulatedGyro, rates: np.ndarray) -> np.ndarray:
        """``rates`` (the measured samples) plus ``s omega_bar_j``: with the same bias and
        noise draws, ``(1 + s) omega_bar_j + beta + eta_v``."""
        return rates + np.asarray(self.error, dtype=float) * gyro.true_rates


class StuckAxisFault(Parameters):
    """``[gyro_fault.stuck_axis]``: one gyro axis reads a constant over a window: the
    samples ``j`` with ``start_s <= t_j < start_s + duration_s`` (``t_j`` the start of the
    sample's interval, seconds from the pass start) read ``value_deg_s`` on ``axis``, or
    without it the reading of the window's first sample held (an output frozen at its last
    value)."""

    axis: Literal["x", "y", "z"] = Field(description="The body axis that sticks.")
    start_s: float = Field(ge=0.0, allow_inf_nan=False, description="Start of the fault.")
    duration_s: float = Field(
        60.0, gt=0.0, allow_inf_nan=False, description="How long the axis stays stuck."
    )
    value_deg_s: float | None = Field(
        None,
        allow_inf_nan=False,
        description="The stuck reading; leave out to hold the reading at the start.",
    )

    def inside(self, t: np.ndarray) -> np.ndarray:
        """Which samples starting at ``t`` lie in the window."""
        return (t >= self.start_s) & (t < self.start_s + self.duration_s)

    def apply(self, gyro: SimulatedGyro, rates: np.ndarray) -> np.ndarray:
        """``rates`` with ``axis`` stuck over the window (unchanged if no sample is in it)."""
        inside = np.flatnonzero(self.inside(gyro.samples.t[:-1]))
        out = rates.copy()
        if inside.size:
            column = AXIS_INDEX[self.axis]
            held = rates[inside[0], column]
            out[inside, column] = held if self.value_deg_s is None else self.value_deg_s * DEG
        return out


class TimeOffsetFault(Parameters):
    """``[gyro_fault.time_offset]``: the gyro's time tags ``offset_s`` late against the
    measurement epochs: the sample of the true interval ``[t_j, t_j + dt)`` is stamped
    ``t_j + offset_s``.  Where the shifted record no longer reaches an epoch, it is
    extended by missing (NaN) samples, which the estimators treat as a gyro gap."""

    offset_s: float = Field(
        allow_inf_nan=False, description="Gyro time tag minus true time (positive: late)."
    )

    def stamps(self, samples: GyroSamples) -> GyroSamples:
        """The record re-stamped, padded with NaN samples so that it still spans
        ``samples.t[0]`` to ``samples.t[-1]``."""
        t, dt = samples.t + self.offset_s, samples.dt
        pad = math.ceil(abs(self.offset_s) / dt - 1e-6)
        if pad == 0:
            return GyroSamples(t, samples.rates, dt)
        gap = np.full((pad, 3), np.nan)
        if self.offset_s > 0:
            before = t[0] - dt * np.arange(pad, 0, -1)
            return GyroSamples(np.concatenate([before, t]), np.vstack([gap, samples.rates]), dt)
        after = t[-1] + dt * np.arange(1, pad + 1)
        return GyroSamples(np.concatenate([t, after]), np.vstack([samples.rates, gap]), dt)


class GyroFault(Parameters):
    """``[gyro_fault]``: faults of the gyro samples the estimators are given (the truth,
    the bias and the noise draws are unchanged), each optional, applied in this order:
    the scale factor, the stuck axis, the time offset."""

    scale_factor: ScaleFactorFault | None = Field(
        None, description="A scale-factor error; none by default."
    )
    stuck_axis: StuckAxisFault | None = Field(
        None, description="An axis stuck at a constant; none by default."
    )
    time_offset: TimeOffsetFault | None = Field(
        None, description="A time-tag offset against the measurements; none by default."
    )

    def measured(self, gyro: SimulatedGyro) -> GyroSamples:
        """The faulty samples of ``gyro`` (class docstring)."""
        rates = gyro.samples.rates
        for fault in (self.scale_factor, self.stuck_axis):
            if fault is not None:
                rates = fault.apply(gyro, rates)
        samples = GyroSamples(gyro.samples.t, rates, gyro.samples.dt)
        return samples if self.time_offset is None else self.time_offset.stamps(samples)


class CosinePowerGain(Parameters):
    """``g = peak_gain cos^exponent(alpha)`` (Liu et al. 2023 eq. 63), main lobe where
    ``10 lg g >= min_gain_dbi``."""

    type: Literal["cos_power"] = Field("cos_power", description="cos^n pattern.")
    peak_gain: float = Field(14.4598, gt=0.0, description="Linear boresight gain.")
    exponent: float = Field(6.0, gt=0.0, description="Power of cos(alpha).")
    min_gain_dbi: float = Field(4.0, description="Main-lobe edge.")

    def pattern(self) -> GainPattern:
        """The library pattern."""
        return CosinePowerPattern(self.peak_gain, self.exponent, self.min_gain_dbi)


class ParabolicGain(Parameters):
    """``G = G_max - C (alpha / theta_3dB)^2`` dB (Pimienta-Penalver and Crassidis eq. 5)."""

    type: Literal["parabolic"] = Field("parabolic", description="Parabolic main lobe.")
    peak_gain_dbi: float = Field(35.0, description="Boresight gain G_max.")
    beamwidth_deg: float = Field(2.0, gt=0.0, description="theta_3dB.")
    min_gain_dbi: float = Field(25.0, description="Main-lobe edge.")
    roll_off_db: float = Field(12.0, gt=0.0, description="C: the drop at alpha = theta_3dB.")

    def pattern(self) -> GainPattern:
        """The library pattern."""
        return ParabolicPattern(
            self.peak_gain_dbi,
            math.radians(self.beamwidth_deg),
            self.min_gain_dbi,
            self.roll_off_db,
        )


class TableGain(Parameters):
    """A gain table against the off-boresight angle, given inline or as a CSV file with
    columns ``angle_deg`` and ``gain_dbi`` (read when the config is loaded, so the stored
    parameters hold the numbers)."""

    type: Literal["table"] = Field("table", description="Tabulated pattern.")
    file: str | None = Field(None, description="CSV file (angle_deg, gain_dbi) to read.")
    angle_deg: list[float] = Field(default_factory=list, description="Off-boresight angles.")
    gain_dbi: list[float] = Field(default_factory=list, description="Gains at the angles.")

    @model_validator(mode="before")
    @classmethod
    def _read_file(cls, data: object) -> object:
        if isinstance(data, dict) and data.get("file") is not None and not data.get("angle_deg"):
            path = Path(data["file"])
            try:
                table = pd.read_csv(path)
            except (OSError, pd.errors.ParserError) as error:
                raise ValueError(f"cannot read gain table {path}: {error}") from None
            missing = {"angle_deg", "gain_dbi"} - set(table.columns)
            if missing:
                raise ValueError(f"gain table {path} lacks columns {sorted(missing)}")
            data = {
                **data,
                "angle_deg": table["angle_deg"].tolist(),
                "gain_dbi": table["gain_dbi"].tolist(),
            }
        return data

    @model_validator(mode="after")
    def _builds(self) -> TableGain:
        self.pattern()
        return self

    def pattern(self) -> GainPattern:
        """The library pattern (raises ValueError on a bad table)."""
        return TabulatedPattern(tuple(np.radians(self.angle_deg)), tuple(self.gain_dbi))


Gain = Annotated[CosinePowerGain | ParabolicGain | TableGain, Field(discriminator="type")]
"""``[antennas.gain]``: ``type = "cos_power"``, ``"parabolic"`` or ``"table"``."""


class Antenna(Parameters):
    """One receive antenna: its boresight in the body frame and its gain pattern."""

    boresight_body: list[float] = Field(
        min_length=3,
        max_length=3,
        description="Boresight direction in the body frame (normalised).",
    )
    gain: Gain = Field(default_factory=CosinePowerGain, description="Gain pattern.")

    @field_validator("boresight_body")
    @classmethod
    def _nonzero(cls, value: list[float]) -> list[float]:
        if not all(math.isfinite(v) for v in value) or math.hypot(*value) == 0.0:
            raise ValueError("boresight must be a finite, non-zero vector")
        return value

    @property
    def boresight(self) -> np.ndarray:
        """The unit boresight, ``(3,)``."""
        vector = np.asarray(self.boresight_body, dtype=float)
        return vector / np.linalg.norm(vector)


class Station(Parameters):
    """A ground station: name and WGS84 geodetic position."""

    name: str = Field(description="Station name (row and table label).")
    latitude_deg: float = Field(ge=-90.0, le=90.0, description="Geodetic latitude.")
    longitude_deg: float = Field(ge=-180.0, le=360.0, description="Longitude, east positive.")
    height_m: float = Field(
        0.0, ge=-500.0, le=9000.0, description="Height above the WGS84 ellipsoid."
    )


def _unique_station_names(stations: list[Station]) -> list[Station]:
    names = [station.name for station in stations]
    if repeated(names):
        raise ValueError(f"station names must be unique: {repeated(names)}")
    return stations


Stations = Annotated[list[Station], AfterValidator(_unique_station_names)]
"""``[[stations]]``: any number of stations with distinct names (rows and tables use them)."""


def repeated(names: list[str]) -> list[str]:
    """The names that occur more than once, sorted (for the unique-name validators).

    Example::

        >>> repeated(["a", "b", "a"])
        ['a']
    """
    return sorted({name for name in names if names.count(name) > 1})


def _checked_time(value: str) -> str:
    from astropy.time import Time

    try:
        Time(value, scale="utc")
    except ValueError:
        raise ValueError("not an ISO 8601 UTC time such as 2026-05-10T23:23:00") from None
    return value


UtcTime = Annotated[str, AfterValidator(_checked_time)]
"""An ISO 8601 UTC time that astropy parses (e.g. a pass's ``start_utc``)."""
