"""The aircraft's 1090ES transmitters: transponder power, antenna pattern, bank, diversity.

Liu et al. 2023 give every aircraft the same known power through an isotropic antenna
(:class:`attopt.formulations.link_budget.LinkBudget`: 250 W, 0 dBi).  This module
replaces that by a model of real installations; ``docs/adsb_transmitters.md`` gives
the equations, the defaults and their sources.  Two switches keep the paper's ideal
as an option, each part alone: ``power = "nominal"`` (every aircraft the nominal
power) and ``antenna = "isotropic"`` (0 dBi, no bank, no diversity).

Power.  ICAO Annex 10 Vol. IV (3.1.2.10.2) bounds the peak pulse power at the
antenna end of the transmission line: at least 21 dBW (125 W) for aircraft that fly
above 15,000 ft or faster than 175 kt (class 1; the 1090ES transmitter classes A1,
A2 of RTCA DO-260B, A3 at least 23 dBW), at least 18.5 dBW (70 W) otherwise (class
2; DO-260B class A0), and at most 27 dBW (500 W) for all.  Each aircraft is class 1
with probability ``class1_share``; its transponder's output at the unit connector is
uniform in dBW on the class's band and a cable loss uniform on a band is subtracted.
The power is fixed for the pass and unknown to the receiver.

Antenna.  A quarter-wave monopole on the fuselage, at the bottom and, for diversity
installations, also at the top.  Over an infinite ground plane, with ``e`` the
elevation of the direction above the plane (``theta = 90 deg - e`` from the axis),

    G_inf(e) = D_m [cos(pi/2 sin e) / cos e]^2   (e >= 0),   0   (e < 0),

``D_m = 8 / Cin(2 pi) = 3.282`` (5.16 dBi, twice the half-wave dipole's
``4 / Cin(2 pi)``; Balanis 2016 sec. 4.6 and 4.7).  The finite fuselage
(:func:`monopole_gain_dbi`) tilts the lobe up to ``e = tau``, lowers the horizon by
``h`` dB and lets ``S`` dB below the ideal peak into the shadow hemisphere, and the
pattern is scaled to radiate the transmitter's power (mean gain 1 over the sphere).

Body frame.  ``x`` along the heading, ``y`` to the right wing, ``z`` down
(level flight: ``z = -up``, the geodetic normal), then rolled about ``x`` by the
bank angle ``phi`` (right wing down positive).  The bottom antenna's axis is ``+z``,
the top one's ``-z``, so a line of sight ``l`` has elevation ``asin(z . l)`` above
the bottom antenna's ground plane and ``-asin(z . l)`` above the top one's.

Bank (:class:`BankSchedule`).  Each aircraft alternates straight flight (exponential
durations of mean ``D (1 - f) / f``) and turns of duration ``D`` at a bank drawn per
turn, so that it spends the fraction ``f`` of the time turning; the state at ``t = 0``
is drawn from the stationary process.  Positions stay on the great circles of
:mod:`attopt.experiments.environment.traffic`: the turn's heading change is not fed
back, bank only tilts the antennas.

Diversity.  A diversity transponder sends its squitters alternately from the top and
the bottom antenna (DO-260B; Annex 10 Vol. IV).  ``diversity_mode = "alternate"``:
the row at time ``t`` uses the top antenna iff ``floor(t / dt) + b`` is odd (``dt``
the alternation interval, ``b`` a bit drawn per aircraft); ``"average"``: the mean of
the two antennas' linear gains, a receiver averaging a second's messages.  Other
aircraft use the bottom antenna only.

:func:`transmitter_offset_db` gives each row's EIRP offset (dB) against Liu et al.
2023's nominal, power and gain together.  Run ``python -m
attopt.experiments.environment.aircraft_transmitters --out
docs/figures/aircraft_antenna.png`` for the figure and the statistics of the offsets
seen by a LEO satellite.
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import itertools
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import erfa
import numpy as np
from numpy.typing import ArrayLike, NDArray
from pydantic import Field, model_validator
from scipy import integrate, special
from scipy.spatial.transform import Rotation

from attopt.experiments.config import Parameters
from attopt.experiments.environment.traffic import (
    MEAN_RADIUS_KM,
    Traffic,
    geodetic_normal,
    geodetic_normals,
)
from attopt.formulations.link_budget import LinkBudget

_LINK = LinkBudget()
CLASS1_MIN_DBW = 21.0
"""Least peak pulse power at the antenna of class 1 (above 15,000 ft or 175 kt): 125 W
(ICAO Annex 10 Vol. IV 3.1.2.10.2)."""
CLASS2_MIN_DBW = 18.5
"""Least peak pulse power at the antenna of class 2: 70 W (same paragraph)."""
MAX_POWER_DBW = 27.0
"""Greatest peak pulse power at the antenna of any class: 500 W (same paragraph)."""
MONOPOLE_DIRECTIVITY = 8.0 / float(
    np.euler_gamma + np.log(2.0 * np.pi) - special.sici(2.0 * np.pi)[1]
)
"""Peak directivity ``D_m = 8 / Cin(2 pi)`` of a quarter-wave monopole over an infinite
ground plane (twice the half-wave dipole's ``4 / Cin(2 pi) = 1.641``)."""


class AircraftTransmitterParameters(Parameters):
    """The aircraft's 1090ES transmitters (module docstring; defaults in
    ``docs/adsb_transmitters.md``)."""

    power: Literal["classes", "nominal"] = Field(
        "classes",
        description=(
            "Transmit power: drawn from the Annex 10 classes with cable loss, or every "
            "aircraft the nominal power (Liu et al. 2023)."
        ),
    )
    antenna: Literal["monopole", "isotropic"] = Field(
        "monopole",
        description=(
            "Aircraft antennas: monopoles with bank and diversity, or isotropic 0 dBi "
            "(Liu et al. 2023)."
        ),
    )
    nominal_power_w: float = Field(
        _LINK.transmit_power_w, gt=0.0, description="Paper's power, the offsets' reference."
    )
    class1_share: float = Field(
        1.0,
        ge=0.0,
        le=1.0,
        description="Share of class 1 (>= 125 W) transponders (Annex 10: all above 15,000 ft).",
    )
    class1_output_min_dbw: float = Field(
        24.0, description="Least class 1 output at the transponder connector (uniform in dBW)."
    )
    class1_output_max_dbw: float = Field(
        27.0, description="Greatest class 1 output at the transponder connector."
    )
    class2_output_min_dbw: float = Field(
        21.5, description="Least class 2 output at the transponder connector (uniform in dBW)."
    )
    class2_output_max_dbw: float = Field(
        24.0, description="Greatest class 2 output at the transponder connector."
    )
    cable_loss_min_db: float = Field(
        1.0, ge=0.0, description="Least loss from transponder to antenna (uniform in dB)."
    )
    cable_loss_max_db: float = Field(
        3.0, ge=0.0, description="Greatest loss from transponder to antenna."
    )
    lobe_tilt_deg: float = Field(
        10.0, gt=0.0, lt=90.0, description="Elevation of the antenna pattern's peak (fuselage)."
    )
    horizon_drop_db: float = Field(
        6.0, ge=0.0, description="Gain at the ground plane's horizon below the peak shape."
    )
    shadow_db: float = Field(
        20.0,
        ge=0.0,
        description="Deep-shadow gain below the infinite-plane peak (behind the plane).",
    )
    shadow_transition_deg: float = Field(
        15.0, gt=0.0, le=90.0, description="Depth below the horizon where the deep shadow starts."
    )
    diversity_share_class1: float = Field(
        1.0, ge=0.0, le=1.0, description="Share of class 1 aircraft with top and bottom antennas."
    )
    diversity_share_class2: float = Field(
        0.0, ge=0.0, le=1.0, description="Share of class 2 aircraft with top and bottom antennas."
    )
    diversity_mode: Literal["alternate", "average"] = Field(
        "alternate",
        description="Diversity gain of a row: alternate antennas, or the mean of the two.",
    )
    alternation_interval_s: float = Field(
        1.0, gt=0.0, description="Time between a diversity aircraft's antenna switches."
    )
    turn_time_fraction: float = Field(
        0.02, ge=0.0, lt=1.0, description="Fraction of the time each aircraft spends turning."
    )
    turn_duration_s: float = Field(30.0, gt=0.0, description="Duration of one turn.")
    bank_min_deg: float = Field(10.0, ge=0.0, le=90.0, description="Least bank in a turn.")
    bank_max_deg: float = Field(25.0, ge=0.0, le=90.0, description="Greatest bank in a turn.")

    @model_validator(mode="after")
    def _bands(self) -> AircraftTransmitterParameters:
        for low, high in (
            ("class1_output_min_dbw", "class1_output_max_dbw"),
            ("class2_output_min_dbw", "class2_output_max_dbw"),
            ("cable_loss_min_db", "cable_loss_max_db"),
            ("bank_min_deg", "bank_max_deg"),
            ("horizon_drop_db", "shadow_db"),
        ):
            if getattr(self, low) > getattr(self, high):
                raise ValueError(f"{low} must not exceed {high}")
        return self

    @property
    def nominal_power_dbw(self) -> float:
        return 10.0 * math.log10(self.nominal_power_w)

    def power_offset_moments(self) -> tuple[float, float]:
        """Mean and standard deviation (dB) of an aircraft's antenna power offset from
        ``nominal_power_w`` (:attr:`Transmitters.power_offset_db`): a mixture of the two
        classes' uniform outputs minus an independent uniform cable loss; ``(0, 0)`` for
        ``power = "nominal"``.

        Example::

            >>> mean, sigma = AircraftTransmitterParameters().power_offset_moments()
            >>> round(mean, 3), round(sigma, 3)  # 25.5 - 2 - 10 lg 250 dBW; sqrt(9 + 4) / sqrt(12)
            (-0.479, 1.041)
        """
        if self.power == "nominal":
            return 0.0, 0.0
        share = self.class1_share
        bands = (
            (share, self.class1_output_min_dbw, self.class1_output_max_dbw),
            (1.0 - share, self.class2_output_min_dbw, self.class2_output_max_dbw),
        )
        mean = sum(w * 0.5 * (a + b) for w, a, b in bands)
        second = sum(w * ((b - a) ** 2 / 12.0 + (0.5 * (a + b)) ** 2) for w, a, b in bands)
        loss_mean = 0.5 * (self.cable_loss_min_db + self.cable_loss_max_db)
        loss_variance = (self.cable_loss_max_db - self.cable_loss_min_db) ** 2 / 12.0
        variance = second - mean**2 + loss_variance
        return mean - loss_mean - self.nominal_power_dbw, math.sqrt(variance)

    @property
    def ideal(self) -> bool:
        """Liu et al. 2023's transmitters: the nominal power through isotropic antennas
        (every offset exactly 0)."""
        return self.power == "nominal" and self.antenna == "isotropic"


@dataclass(frozen=True)
class BankSchedule:
    """Turns of ``n`` aircraft over ``[0, horizon_s]`` (module docstring): turn ``k`` of
    aircraft ``j`` starts at ``start_s[j, k]`` and lasts ``duration_s`` at bank
    ``bank_rad[j, k]``; unused columns start after the horizon."""

    start_s: NDArray[np.float64]
    bank_rad: NDArray[np.float64]
    duration_s: float
    horizon_s: float

    @classmethod
    def draw(
        cls,
        n_aircraft: int,
        horizon_s: float,
        parameters: AircraftTransmitterParameters,
        rng: np.random.Generator,
    ) -> BankSchedule:
        """Turns from the stationary alternating process of ``parameters``."""
        duration = parameters.turn_duration_s
        fraction = 0.0 if parameters.antenna == "isotropic" else parameters.turn_time_fraction
        unused = horizon_s + duration + 1.0
        if fraction == 0.0:
            return cls(
                np.full((n_aircraft, 1), unused), np.zeros((n_aircraft, 1)), duration, horizon_s
            )
        straight_mean = duration * (1.0 - fraction) / fraction
        turning = rng.random(n_aircraft) < fraction
        starts = [
            np.where(
                turning,
                -duration * rng.random(n_aircraft),
                rng.exponential(straight_mean, n_aircraft),
            )
        ]
        while np.any(starts[-1] <= horizon_s):
            starts.append(starts[-1] + duration + rng.exponential(straight_mean, n_aircraft))
        start = np.stack(starts, axis=1)
        start[start > horizon_s] = unused
        magnitude = rng.uniform(parameters.bank_min_deg, parameters.bank_max_deg, start.shape)
        sign = np.where(rng.random(start.shape) < 0.5, -1.0, 1.0)
        return cls(start, np.radians(sign * magnitude), duration, horizon_s)

    def bank_rad_at(self, aircraft: ArrayLike, t_s: ArrayLike) -> NDArray[np.float64]:
        """Bank of ``aircraft`` (indices) at ``t_s`` in ``[0, horizon_s]``, broadcast
        together (0 between turns)."""
        aircraft, t = np.broadcast_arrays(np.asarray(aircraft), np.asarray(t_s, dtype=float))
        if np.any(t < 0.0) or np.any(t > self.horizon_s):
            raise ValueError(f"times must lie in [0, {self.horizon_s}] s")
        n_turns = self.start_s.shape[1]
        span = self.horizon_s + 2.0 * self.duration_s + 2.0
        keys = (self.start_s + span * np.arange(self.start_s.shape[0])[:, None]).ravel()
        query = t + span * aircraft
        k = np.maximum(np.searchsorted(keys, query, side="right") - 1, 0)
        turning = (k // n_turns == aircraft) & (query - keys[k] < self.duration_s)
        return np.where(turning, self.bank_rad.ravel()[k], 0.0)


@dataclass(frozen=True)
class Transmitters:
    """The transmitters of ``n`` aircraft for one pass; aircraft ``j`` is row ``j``."""

    parameters: AircraftTransmitterParameters
    class1: NDArray[np.bool_]
    """Class 1 (>= 125 W at the antenna) transponder."""
    output_power_dbw: NDArray[np.float64]
    """Output at the transponder connector."""
    cable_loss_db: NDArray[np.float64]
    diversity: NDArray[np.bool_]
    """Top and bottom antennas (else bottom only)."""
    alternation_bit: NDArray[np.int_]
    """``b`` of the alternation (module docstring)."""
    bank: BankSchedule

    @property
    def antenna_power_dbw(self) -> NDArray[np.float64]:
        """Power delivered to the antenna: output minus cable loss."""
        return self.output_power_dbw - self.cable_loss_db

    @property
    def power_offset_db(self) -> NDArray[np.float64]:
        """Antenna power against the paper's nominal (dB), per aircraft."""
        return self.antenna_power_dbw - self.parameters.nominal_power_dbw


def draw_transmitters(
    parameters: AircraftTransmitterParameters,
    n_aircraft: int,
    horizon_s: float,
    rng: np.random.Generator,
) -> Transmitters:
    """Each aircraft's class, power, cable loss, antennas and turns over ``[0, horizon_s]``
    (module docstring).  Every draw is made whatever the switches, so that switching one
    part leaves the others' draws unchanged; ``power = "nominal"``: the nominal power and
    no cable loss; ``antenna = "isotropic"``: no diversity and no turns."""
    p = parameters
    class1 = rng.random(n_aircraft) < p.class1_share
    output = np.where(
        class1,
        rng.uniform(p.class1_output_min_dbw, p.class1_output_max_dbw, n_aircraft),
        rng.uniform(p.class2_output_min_dbw, p.class2_output_max_dbw, n_aircraft),
    )
    cable = rng.uniform(p.cable_loss_min_db, p.cable_loss_max_db, n_aircraft)
    diversity_share = np.where(class1, p.diversity_share_class1, p.diversity_share_class2)
    diversity = rng.random(n_aircraft) < diversity_share
    bit = rng.integers(0, 2, n_aircraft)
    if p.power == "nominal":
        output, cable = np.full(n_aircraft, p.nominal_power_dbw), np.zeros(n_aircraft)
    if p.antenna == "isotropic":
        diversity = np.zeros(n_aircraft, dtype=bool)
    return Transmitters(
        parameters=p,
        class1=class1,
        output_power_dbw=output,
        cable_loss_db=cable,
        diversity=diversity,
        alternation_bit=bit,
        bank=BankSchedule.draw(n_aircraft, horizon_s, p, rng),
    )


def ideal_monopole_gain(elevation_rad: ArrayLike) -> NDArray[np.float64]:
    """``G_inf(e)`` (linear) of a quarter-wave monopole over an infinite ground plane,
    ``e`` the elevation above the plane (module docstring)."""
    e = np.asarray(elevation_rad, dtype=float)
    cos_e = np.cos(e)
    with np.errstate(divide="ignore", invalid="ignore"):
        shape = (np.cos(0.5 * np.pi * np.sin(e)) / cos_e) ** 2
    return np.where((e >= 0.0) & (cos_e > 1e-12), MONOPOLE_DIRECTIVITY * shape, 0.0)


def _shape_db(
    elevation_rad: NDArray[np.float64],
    tilt: float,
    horizon: float,
    shadow: float,
    transition: float,
) -> NDArray[np.float64]:
    """The finite-ground-plane pattern in dB below ``D_m``, before normalisation."""
    e = np.asarray(elevation_rad, dtype=float)
    stretched = np.clip((e - tilt) / (1.0 - tilt / (0.5 * np.pi)), 0.0, 0.5 * np.pi)
    with np.errstate(divide="ignore"):
        lobe = 10.0 * np.log10(ideal_monopole_gain(stretched) / MONOPOLE_DIRECTIVITY)
    rising = -horizon * (1.0 - e / tilt) ** 2
    depth = np.clip(-e / transition, 0.0, 1.0)
    shadowed = -horizon - (shadow - horizon) * 0.5 * (1.0 - np.cos(np.pi * depth))
    return np.where(e >= tilt, lobe, np.where(e >= 0.0, rising, shadowed))


@functools.lru_cache(maxsize=16)
def _normalisation_db(tilt: float, horizon: float, shadow: float, transition: float) -> float:
    """``-10 lg`` of the mean over the sphere of ``D_m 10^(shape / 10)``."""

    def density(e: float) -> float:
        shape = _shape_db(np.array(e), tilt, horizon, shadow, transition)
        return float(MONOPOLE_DIRECTIVITY * 10.0 ** (shape / 10.0) * np.cos(e))

    breaks = sorted({-0.5 * np.pi, -transition, 0.0, tilt, 0.5 * np.pi})
    total = sum(integrate.quad(density, a, b)[0] for a, b in itertools.pairwise(breaks))
    return -10.0 * math.log10(0.5 * total)


def monopole_gain_dbi(
    elevation_rad: ArrayLike, parameters: AircraftTransmitterParameters
) -> NDArray[np.float64]:
    """Gain (dBi) of a fuselage-mounted monopole at elevation ``e`` above its ground plane:
    ``10 lg D_m + s(e) + c`` with the shape ``s`` of ``docs/adsb_transmitters.md``
    (lobe tilted to ``lobe_tilt_deg``, horizon ``horizon_drop_db`` down, shadow
    ``shadow_db`` below the ideal peak) and ``c`` making the mean gain over the sphere 1."""
    p = parameters
    args = (
        math.radians(p.lobe_tilt_deg),
        p.horizon_drop_db,
        p.shadow_db,
        math.radians(p.shadow_transition_deg),
    )
    shape = _shape_db(np.asarray(elevation_rad, dtype=float), *args)
    return 10.0 * math.log10(MONOPOLE_DIRECTIVITY) + shape + _normalisation_db(*args)


def level_flight_gain_dbi(
    elevation_rad: ArrayLike, parameters: AircraftTransmitterParameters
) -> NDArray[np.float64]:
    """The gain a receiver expects from an aircraft whose installation it knows only by
    type: the better placed of a top and a bottom monopole (:func:`monopole_gain_dbi`) in
    level flight, toward a receiver at ``elevation_rad`` above the aircraft's horizontal
    plane, ``max(G(e), G(-e))``.  A message received from far out in the weaker
    antenna's shadow is rare, so this is the gain of most received messages; bank, the
    alternation of diversity antennas and aircraft with a bottom antenna only make the
    rest (``docs/adsb_sky.md``, the receiver's aircraft model).

    Example::

        >>> import numpy as np
        >>> parameters = AircraftTransmitterParameters()
        >>> gain = level_flight_gain_dbi(np.radians([30.0, -30.0]), parameters)
        >>> bool(gain[0] == gain[1]), bool(gain[0] > 0.0)
        (True, True)
    """
    e = np.asarray(elevation_rad, dtype=float)
    return np.maximum(monopole_gain_dbi(e, parameters), monopole_gain_dbi(-e, parameters))


def local_vertical(position_ecef_km: ArrayLike) -> NDArray[np.float64]:
    """Unit WGS84 geodetic normals at ECEF positions (km), ``(..., 3)``."""
    longitude, latitude, _ = erfa.gc2gd(erfa.WGS84, 1000.0 * np.asarray(position_ecef_km))
    return geodetic_normal(np.degrees(latitude), np.degrees(longitude))


def body_attitude(up_ecef: ArrayLike, heading_ecef: ArrayLike, bank_rad: ArrayLike) -> Rotation:
    """Rotations body -> ECEF (``b`` components to ECEF ones) of aircraft with local
    vertical ``up``, flight direction ``heading`` (its horizontal part is used) and bank
    (module docstring), ``(M, 3)``, ``(M, 3)``, ``(M,)``."""
    up = np.atleast_2d(np.asarray(up_ecef, dtype=float))
    heading = np.atleast_2d(np.asarray(heading_ecef, dtype=float))
    forward = heading - np.sum(heading * up, axis=-1, keepdims=True) * up
    forward /= np.linalg.norm(forward, axis=-1, keepdims=True)
    right = np.cross(-up, forward)
    level = Rotation.from_matrix(np.stack([forward, right, -up], axis=-1))
    bank = np.broadcast_to(np.asarray(bank_rad, dtype=float), up.shape[:1])
    return level * Rotation.from_rotvec(bank[:, None] * np.array([1.0, 0.0, 0.0]))


def antenna_elevations_rad(
    attitude: Rotation, los_ecef: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Elevations of the unit lines of sight ``(M, 3)`` above the bottom and the top
    antenna's ground planes, for the body attitudes of :func:`body_attitude`."""
    los_body = attitude.inv().apply(np.atleast_2d(np.asarray(los_ecef, dtype=float)))
    down = np.clip(los_body[:, 2], -1.0, 1.0)
    return np.arcsin(down), np.arcsin(-down)


def flight_direction_ecef(
    traffic: Traffic, t_s: ArrayLike, aircraft: ArrayLike | None = None
) -> NDArray[np.float64]:
    """Unit flight directions at ``t_s`` of the aircraft of
    :mod:`attopt.experiments.environment.traffic`: ``n_r x n`` outbound and
    ``n x n_r`` on the way back (``n_r`` the route normal, ``n`` the geodetic normal)."""
    index = np.arange(traffic.size) if aircraft is None else np.asarray(aircraft)
    route = traffic.route_angle_rad[index]
    phase = np.mod(
        traffic.start_angle_rad[index] + traffic.angular_rate_rad_s[index] * np.asarray(t_s),
        2.0 * route,
    )
    normal = geodetic_normals(traffic, t_s, index)
    along = np.cross(traffic.route_normal[index], normal)
    return np.where((phase < route)[..., None], along, -along)


def transmitter_offset_db(
    transmitters: Transmitters,
    aircraft: ArrayLike,
    t_s: ArrayLike,
    position_ecef_km: ArrayLike,
    heading_ecef: ArrayLike,
    los_ecef: ArrayLike,
) -> NDArray[np.float64]:
    """EIRP offset (dB) of each row against Liu et al. 2023's nominal (``nominal_power_w``
    through 0 dBi): antenna power offset plus the gain of the transmitting antenna
    toward the satellite.

    Rows ``(M,)``: aircraft index, time (s, in the bank schedule's horizon), aircraft
    ECEF position (km), flight direction (ECEF; :func:`flight_direction_ecef`) and unit
    line of sight aircraft -> satellite (ECEF).  With ``antenna = "isotropic"`` the gain
    is the nominal 0 dBi (the offset is the power's alone); zeros if ``parameters.ideal``.
    """
    p = transmitters.parameters
    index = np.atleast_1d(np.asarray(aircraft))
    t = np.broadcast_to(np.asarray(t_s, dtype=float), index.shape)
    if p.ideal:
        return np.zeros(index.shape)
    if p.antenna == "isotropic":
        return transmitters.power_offset_db[index]
    attitude = body_attitude(
        local_vertical(np.atleast_2d(position_ecef_km)),
        heading_ecef,
        transmitters.bank.bank_rad_at(index, t),
    )
    bottom_rad, top_rad = antenna_elevations_rad(attitude, los_ecef)
    bottom = monopole_gain_dbi(bottom_rad, p)
    top = monopole_gain_dbi(top_rad, p)
    if p.diversity_mode == "average":
        both = 10.0 * np.log10(0.5 * (10.0 ** (bottom / 10.0) + 10.0 ** (top / 10.0)))
    else:
        odd = (
            np.floor(t / p.alternation_interval_s).astype(int) + transmitters.alternation_bit[index]
        ) % 2
        both = np.where(odd == 1, top, bottom)
    gain = np.where(transmitters.diversity[index], both, bottom)
    return transmitters.power_offset_db[index] + gain - _LINK.transmit_gain_dbi


@dataclass(frozen=True)
class LeoRows:
    """Rows of aircraft in view of a LEO satellite (:func:`leo_rows`)."""

    aircraft: NDArray[np.int_]
    t_s: NDArray[np.float64]
    position_ecef_km: NDArray[np.float64]
    heading_ecef: NDArray[np.float64]
    los_ecef: NDArray[np.float64]
    elevation_rad: NDArray[np.float64]
    """Elevation of the satellite above the aircraft's local horizontal plane."""
    nadir_angle_rad: NDArray[np.float64]
    """Angle of the aircraft from the satellite's nadir (geocentric)."""


def leo_rows(
    n_aircraft: int,
    rows_per_aircraft: int,
    horizon_s: float,
    rng: np.random.Generator,
    altitude_range_km: tuple[float, float] = (500.0, 600.0),
    height_range_km: tuple[float, float] = (9.0, 12.0),
) -> LeoRows:
    """Independent rows of a spherical-Earth geometry: a satellite at an altitude uniform
    in ``altitude_range_km`` above a uniform point, an aircraft uniform in area on the
    cap from which it sees the satellite above the Earth's limb, at a height uniform in
    ``height_range_km``, a uniform heading and a uniform time in ``[0, horizon_s]``."""
    n = n_aircraft * rows_per_aircraft
    radius_sat = MEAN_RADIUS_KM + rng.uniform(*altitude_range_km, n)
    radius_air = MEAN_RADIUS_KM + rng.uniform(*height_range_km, n)
    limb = np.arccos(MEAN_RADIUS_KM / radius_sat) + np.arccos(MEAN_RADIUS_KM / radius_air)
    sub_sat = rng.standard_normal((n, 3))
    sub_sat /= np.linalg.norm(sub_sat, axis=-1, keepdims=True)
    first = np.cross(sub_sat, [0.0, 0.0, 1.0])
    first /= np.linalg.norm(first, axis=-1, keepdims=True)
    second = np.cross(sub_sat, first)
    cos_angle = rng.uniform(np.cos(limb), 1.0)
    azimuth = rng.uniform(0.0, 2.0 * np.pi, n)[:, None]
    normal = cos_angle[:, None] * sub_sat + np.sqrt(1.0 - cos_angle**2)[:, None] * (
        np.cos(azimuth) * first + np.sin(azimuth) * second
    )
    position = radius_air[:, None] * normal
    los = radius_sat[:, None] * sub_sat - position
    los /= np.linalg.norm(los, axis=-1, keepdims=True)
    up = local_vertical(position)
    east = np.cross([0.0, 0.0, 1.0], up)
    east /= np.linalg.norm(east, axis=-1, keepdims=True)
    heading_angle = rng.uniform(0.0, 2.0 * np.pi, n)[:, None]
    heading = np.cos(heading_angle) * np.cross(up, east) + np.sin(heading_angle) * east
    return LeoRows(
        aircraft=np.repeat(np.arange(n_aircraft), rows_per_aircraft),
        t_s=rng.uniform(0.0, horizon_s, n),
        position_ecef_km=position,
        heading_ecef=heading,
        los_ecef=los,
        elevation_rad=np.arcsin(np.clip(np.sum(up * los, axis=-1), -1.0, 1.0)),
        nadir_angle_rad=np.arccos(np.clip(np.sum(sub_sat * los, axis=-1), -1.0, 1.0)),
    )


ELEVATION_BINS_DEG = (-5.0, 0.0, 10.0, 30.0, 60.0, 90.0)
"""Bins of the satellite's elevation above the aircraft's horizontal in the summary."""
NADIR_BINS_DEG = (0.0, 20.0, 40.0, 60.0, 70.0)
"""Bins of the aircraft's angle from the satellite's nadir in the summary (Liu et al.
2023's antennas point 50.77 deg from nadir)."""


def _statistics(name: str, values: NDArray[np.float64]) -> str:
    p5, p50, p95 = np.percentile(values, [5.0, 50.0, 95.0])
    return (
        f"{name:<34} {values.size:>7d} {np.mean(values):>7.2f} {np.std(values):>6.2f} "
        f"{p5:>7.2f} {p50:>7.2f} {p95:>7.2f}"
    )


def leo_summary(
    transmitters: Transmitters, rows: LeoRows
) -> tuple[list[str], dict[str, NDArray[np.float64]]]:
    """Table lines of the EIRP offsets (dB) of ``rows`` and the offsets by series."""
    p = transmitters.parameters
    attitude = body_attitude(
        local_vertical(rows.position_ecef_km),
        rows.heading_ecef,
        transmitters.bank.bank_rad_at(rows.aircraft, rows.t_s),
    )
    bottom_rad, top_rad = antenna_elevations_rad(attitude, rows.los_ecef)
    power = transmitters.power_offset_db[rows.aircraft]
    series = {
        "power only": power,
        "bottom antenna only": power + monopole_gain_dbi(bottom_rad, p),
        "top antenna only": power + monopole_gain_dbi(top_rad, p),
    }
    for mode in ("alternate", "average"):
        variant = dataclasses.replace(
            transmitters, parameters=p.model_copy(update={"diversity_mode": mode})
        )
        series[f"model ({mode})"] = transmitter_offset_db(
            variant,
            rows.aircraft,
            rows.t_s,
            rows.position_ecef_km,
            rows.heading_ecef,
            rows.los_ecef,
        )
    header = f"{'EIRP offset (dB) vs 250 W, 0 dBi':<34} {'rows':>7} {'mean':>7} {'std':>6} " + (
        f"{'p5':>7} {'p50':>7} {'p95':>7}"
    )
    lines = [header, *(_statistics(name, values) for name, values in series.items())]
    elevation = np.degrees(rows.elevation_rad)
    model = series[f"model ({p.diversity_mode})"]
    for low, high in itertools.pairwise(ELEVATION_BINS_DEG):
        inside = (elevation >= low) & (elevation < high)
        if np.any(inside):
            lines.append(_statistics(f"  model, elevation {low:g} to {high:g} deg", model[inside]))
    nadir = np.degrees(rows.nadir_angle_rad)
    for low, high in itertools.pairwise(NADIR_BINS_DEG):
        inside = (nadir >= low) & (nadir < high)
        lines.append(_statistics(f"  model, nadir angle {low:g} to {high:g} deg", model[inside]))
    shadowed = np.mean(bottom_rad < 0.0)
    banked = np.mean(transmitters.bank.bank_rad_at(rows.aircraft, rows.t_s) != 0.0)
    lines += [
        f"satellite above the aircraft's horizontal: {np.mean(elevation > 0.0):.1%} of rows; "
        f"median elevation {np.median(elevation):.1f} deg",
        f"bottom antenna sees the satellite from its shadow side: {shadowed:.1%} of rows",
        f"aircraft banked: {banked:.1%} of rows",
    ]
    return lines, series


def plot_figure(
    transmitters: Transmitters, series: dict[str, NDArray[np.float64]], out: Path
) -> None:
    """Elevation pattern, power histogram and LEO EIRP offsets (``docs/adsb_transmitters.md``)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    p = transmitters.parameters
    elevation = np.linspace(-90.0, 90.0, 721)
    e = np.radians(elevation)
    bottom = monopole_gain_dbi(-e, p)
    top = monopole_gain_dbi(e, p)
    average = 10.0 * np.log10(0.5 * (10.0 ** (bottom / 10.0) + 10.0 ** (top / 10.0)))
    with np.errstate(divide="ignore"):
        infinite = 10.0 * np.log10(ideal_monopole_gain(-e))
    fig, axes = plt.subplots(1, 3, figsize=(15.0, 4.6))
    ax = axes[0]
    ax.plot(elevation, top, label="top antenna")
    ax.plot(elevation, bottom, label="bottom antenna")
    ax.plot(elevation, average, label="diversity average")
    ax.plot(elevation, infinite, "k:", label="bottom, infinite ground plane")
    ax.axhline(_LINK.transmit_gain_dbi, color="grey", ls="--", label="ideal (isotropic)")
    ax.set_ylim(-35.0, 8.0)
    ax.set_xlim(-90.0, 90.0)
    ax.set_xlabel("elevation of the line of sight above the aircraft's horizontal (deg)")
    ax.set_ylabel("gain (dBi)")
    ax.set_title("Aircraft antenna elevation pattern (level flight)")
    ax.legend(fontsize=8, loc="lower center")
    ax.grid(alpha=0.3)
    ax = axes[1]
    power = transmitters.antenna_power_dbw
    bins = np.linspace(18.0, 27.5, 39)
    ax.hist(power[transmitters.class1], bins=bins, alpha=0.7, label="class 1")
    if np.any(~transmitters.class1):
        ax.hist(power[~transmitters.class1], bins=bins, alpha=0.7, label="class 2")
    for level, style in ((CLASS1_MIN_DBW, "--"), (CLASS2_MIN_DBW, ":"), (MAX_POWER_DBW, "-")):
        ax.axvline(level, color="k", ls=style, lw=0.8)
    ax.axvline(p.nominal_power_dbw, color="r", lw=1.0, label="Liu et al. 2023 nominal")
    ax.set_xlabel("power at the antenna (dBW)")
    ax.set_ylabel("aircraft")
    ax.set_title("Per-aircraft transmit power (Annex 10 limits in black)")
    ax.legend(fontsize=8)
    ax = axes[2]
    bins = np.linspace(-35.0, 10.0, 91)
    for name in ("bottom antenna only", "top antenna only", "model (alternate)"):
        ax.hist(series[name], bins=bins, histtype="step", density=True, label=name)
    ax.set_xlabel("EIRP offset against 250 W, 0 dBi (dB)")
    ax.set_ylabel("density of rows")
    ax.set_title("Offsets seen by a satellite at 500-600 km")
    ax.legend(fontsize=8, loc="upper left")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)


def main(argv: list[str] | None = None) -> list[str]:
    """Figure of the antenna pattern and powers; table of the EIRP offsets seen from LEO."""
    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("--out", type=Path, default=Path("docs/figures/aircraft_antenna.png"))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--aircraft", type=int, default=5000)
    parser.add_argument("--rows-per-aircraft", type=int, default=20)
    args = parser.parse_args(argv)
    rng = np.random.default_rng(args.seed)
    horizon_s = 3600.0
    transmitters = draw_transmitters(AircraftTransmitterParameters(), args.aircraft, horizon_s, rng)
    rows = leo_rows(args.aircraft, args.rows_per_aircraft, horizon_s, rng)
    lines, series = leo_summary(transmitters, rows)
    print("\n".join(lines))
    plot_figure(transmitters, series, args.out)
    print(f"figure: {args.out}")
    return lines


if __name__ == "__main__":
    main()
