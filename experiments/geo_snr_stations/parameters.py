"""The simulated world of ``geo-snr-stations`` as parameter tables (Pimienta-Penalver and
Crassidis secs. II.A, V.B; Tables 1-2).

:class:`GeoWorld` is everything the scenario simulates: the pass (``start_utc``,
``duration_s``, ``step_s``), the broadcaster (``[broadcaster]``: its orbit, RF
parameters and dish, ``[broadcaster.antenna]``), the stations' receivers
(``[receiver]``), the stations (``[[stations]]``, any number) and the true attitude
(``[attitude]``).  The defaults are the paper's Garuda-1 case; each table says where
its values come from.  :meth:`GeoWorld.link` is the
:class:`~attopt.formulations.geo_link.GeoLink` of the broadcaster and the receivers.

The stations share one receiver: the link budget of eq. 7 has one ``G_r / T_r``
(the paper gives one ``T_r`` and no ``G_r``).  The broadcaster's pattern is a dish
(eqs. 4-5: peak gain from its diameter and efficiency, half-power beamwidth ``70
lambda / D`` unless given), not the free :class:`~attopt.experiments.config.components.
ParabolicGain`: the paper's sensitivity study (Fig. 6) varies the diameter, which moves
both.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import Field, ValidationInfo, field_validator

from attopt.experiments.config import Parameters
from attopt.experiments.config.components import Station, Stations, TleOrbit, UtcTime
from attopt.formulations.geo_link import GeoLink

GARUDA1_TLE = (
    "1 26089U 00011A   15334.70833333 -.00000218  00000-0  71783+4 0 00007",
    "2 26089 000.0128 195.9086 0000123 075.1421 176.2140 01.00270682000010",
)
"""Garuda-1 (Pimienta-Penalver and Crassidis sec. II.A, re-spaced to the fixed TLE
columns; both checksums hold)."""
GARUDA1_EPOCH_UTC = "2015-11-30T17:00:00"
"""The TLE's epoch, the paper's simulation start."""
EQ27_QUATERNION = (-0.0176892, -0.706875, 0.706868, 0.0187807)
"""Pimienta-Penalver and Crassidis eq. 27, Shuster convention (scalar last)."""
TABLE2_STATIONS = (
    Station(name="Tainan", latitude_deg=23.0149, longitude_deg=120.176, height_m=19.0),
    Station(name="Kuala Lumpur", latitude_deg=3.25006, longitude_deg=101.614, height_m=53.0),
    Station(name="Surabaya", latitude_deg=-7.28252, longitude_deg=112.833, height_m=5.0),
    Station(name="Darwin", latitude_deg=-12.4501, longitude_deg=130.872, height_m=23.0),
    Station(name="Coral Bay", latitude_deg=-23.1484, longitude_deg=113.773, height_m=32.0),
    Station(name="Keeling Islands", latitude_deg=-12.1541, longitude_deg=96.8243, height_m=1.0),
    Station(name="General Santos", latitude_deg=6.086357, longitude_deg=125.1304, height_m=15.0),
    Station(name="Labuan", latitude_deg=5.298122, longitude_deg=115.207, height_m=76.0),
)
"""Pimienta-Penalver and Crassidis Table 2, in its order (heights above WGS84)."""


def _garuda1() -> TleOrbit:
    return TleOrbit(line1=GARUDA1_TLE[0], line2=GARUDA1_TLE[1])


class GeostationaryOrbit(Parameters):
    """An ideal geostationary broadcaster: fixed in ECEF on the equatorial belt at the
    geostationary radius (Pimienta-Penalver and Crassidis assumption 1)."""

    type: Literal["geostationary"] = Field(
        "geostationary", description="Fixed point of the geostationary belt."
    )
    longitude_deg: float = Field(
        123.0, ge=-180.0, le=360.0, description="Longitude of the sub-satellite point, east."
    )


BroadcasterOrbit = Annotated[TleOrbit | GeostationaryOrbit, Field(discriminator="type")]
"""``[broadcaster.orbit]``: ``type = "tle"`` (sgp4) or ``type = "geostationary"``."""


class DishAntenna(Parameters):
    """The broadcaster's parabolic dish and its main lobe, ``G = G_max - C (theta /
    theta_3dB)^2`` with ``G_max = 10 lg[eta (pi D / lambda)^2]`` (Pimienta-Penalver and
    Crassidis eqs. 4-5; Table 1's ``D`` and ``C``)."""

    diameter_m: float = Field(12.0, gt=0.0, description="Dish diameter D (Table 1).")
    efficiency: float = Field(
        0.55, gt=0.0, le=1.0, description="Aperture efficiency eta of eq. 4 (paper: 0.55-0.65)."
    )
    roll_off_db: float = Field(
        10.0, gt=0.0, description="C of eq. 5: the gain drop at theta_3dB (Table 1)."
    )
    beamwidth_deg: float | None = Field(
        None,
        gt=0.0,
        description="Half-power beamwidth theta_3dB; left out: 70 lambda / D (1.128 deg here).",
    )
    lobe_edge_deg: float = Field(
        9.0,
        gt=0.0,
        lt=90.0,
        description="Edge of the quadratic main lobe (the Earth seen from GEO: 8.7 deg).",
    )


class Broadcaster(Parameters):
    """The GEO broadcaster: orbit, transmitter and dish (Garuda-1, Pimienta-Penalver and
    Crassidis sec. II.A and Table 1)."""

    orbit: BroadcasterOrbit = Field(default_factory=_garuda1, description="Orbit.")
    transmit_power_w: float = Field(
        12.0e3, gt=0.0, description="Transmit power P_t (Table 1's DC peak power)."
    )
    frequency_hz: float = Field(1.55e9, gt=0.0, description="Broadcast frequency (Table 1).")
    noise_bandwidth_hz: float = Field(
        2.4e3, gt=0.0, description="R_s of eq. 7: Table 1's 2.4 kbit/s data rate."
    )
    antenna: DishAntenna = Field(default_factory=DishAntenna, description="Broadcast dish.")


class Receiver(Parameters):
    """The stations' receivers (one for all: eq. 7 has one ``G_r / T_r``) and their SNRs."""

    temperature_k: float = Field(
        38.0, gt=0.0, description="System noise temperature T_r (sec. II)."
    )
    gain_dbi: float = Field(
        0.0, description="Receive gain G_r (not given by the paper: omnidirectional)."
    )
    snr_sigma_db: float = Field(
        0.0148, gt=0.0, description="SNR noise sigma (the paper's M2M4 error, its filter's R)."
    )
    detection_threshold_db: float = Field(
        0.0, description="Lowest noise-free SNR a station hears (the lowest of Table 3)."
    )


class ShusterQuaternion(Parameters):
    """The initial attitude (ECI -> body at ``start_utc``) as a Shuster quaternion (the
    conjugate of scipy's), Pimienta-Penalver and Crassidis eq. 27 by default."""

    type: Literal["quaternion"] = Field("quaternion", description="Given quaternion.")
    components: list[float] = Field(
        default_factory=lambda: list(EQ27_QUATERNION),
        min_length=4,
        max_length=4,
        description="The Shuster quaternion's x, y, z, w (scalar last; normalised).",
    )

    @field_validator("components")
    @classmethod
    def _nonzero(cls, value: list[float]) -> list[float]:
        if not all(math.isfinite(v) for v in value) or math.hypot(*value) == 0.0:
            raise ValueError("quaternion must be finite and non-zero")
        return value


class NadirPointing(Parameters):
    """The initial attitude with the boresight (body ``+z``) at nadir at ``start_utc``:
    the smallest rotation taking nadir to ``+z``, turned by ``yaw_deg`` about it."""

    type: Literal["nadir"] = Field("nadir", description="Boresight at nadir.")
    yaw_deg: float = Field(0.0, description="Rotation about the boresight.")


InitialAttitude = Annotated[ShusterQuaternion | NadirPointing, Field(discriminator="type")]
"""``[attitude.initial]``: ``type = "quaternion"`` or ``type = "nadir"``."""


class Manoeuvre(Parameters):
    """The unannounced manoeuvre (Pimienta-Penalver and Crassidis Fig. 10): a constant-rate
    turn about the nadir at its start, on top of the slew."""

    angle_deg: float = Field(25.0, description="Turn angle (the paper's 25 deg).")
    start_s: float = Field(1800.0, ge=0.0, description="Start, from start_utc (30 min).")
    duration_s: float = Field(120.0, gt=0.0, description="Time the turn takes.")


class AttitudeProfile(Parameters):
    """The true attitude: the initial one, turning about the ECI ``z`` axis at the Earth's
    rate plus a slew, and the manoeuvre when a setting has it (sec. V.B)."""

    initial: InitialAttitude = Field(
        default_factory=ShusterQuaternion, description="Attitude at start_utc."
    )
    slew_rate_deg_h: float = Field(
        1.0, description="Turn rate beyond the Earth's about ECI z (westward slew)."
    )
    manoeuvre: Manoeuvre = Field(default_factory=Manoeuvre, description="The manoeuvre.")


class GeoWorld(Parameters):
    """What ``geo-snr-stations`` simulates (module docstring)."""

    duration_s: float = Field(3600.0, gt=0, description="Length of the pass.")
    step_s: float = Field(10.0, gt=0, description="Time between epochs.")
    start_utc: UtcTime = Field(GARUDA1_EPOCH_UTC, description="Start of the pass.")
    broadcaster: Broadcaster = Field(default_factory=Broadcaster, description="Broadcaster.")
    receiver: Receiver = Field(default_factory=Receiver, description="Stations' receivers.")
    stations: Stations = Field(
        default_factory=lambda: list(TABLE2_STATIONS),
        min_length=1,
        description="Ground stations (Table 2).",
    )
    attitude: AttitudeProfile = Field(default_factory=AttitudeProfile, description="True attitude.")

    @field_validator("step_s")
    @classmethod
    def _two_epochs(cls, value: float, info: ValidationInfo) -> float:
        duration = info.data.get("duration_s")
        if duration is not None and duration < 2 * value:
            raise ValueError(f"duration_s = {duration} must hold two epochs of step_s")
        return value

    @property
    def station_names(self) -> list[str]:
        """The stations' names, in order."""
        return [station.name for station in self.stations]

    def link(self) -> GeoLink:
        """The RF link of the broadcaster and the receivers (eq. 7)."""
        broadcaster, antenna = self.broadcaster, self.broadcaster.antenna
        return GeoLink(
            transmit_power_w=broadcaster.transmit_power_w,
            dish_diameter_m=antenna.diameter_m,
            size_factor_db=antenna.roll_off_db,
            data_rate_bps=broadcaster.noise_bandwidth_hz,
            frequency_hz=broadcaster.frequency_hz,
            efficiency=antenna.efficiency,
            receiver_temperature_k=self.receiver.temperature_k,
            receiver_gain_dbi=self.receiver.gain_dbi,
            beamwidth_deg=antenna.beamwidth_deg,
            lobe_edge_deg=antenna.lobe_edge_deg,
        )

    def world(self) -> GeoWorld:
        """These parameters as a :class:`GeoWorld` alone (a subclass's other fields dropped)."""
        return GeoWorld.model_validate(
            {name: getattr(self, name) for name in GeoWorld.model_fields}
        )
