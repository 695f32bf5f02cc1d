"""Parameters of the ``adsb-snr`` scenario: orbit, truth attitude, antennas, traffic, receiver.

Nested tables of :class:`attopt.experiments.adsb_snr.experiment.AdsbSnrParameters`
(``[orbit]``, ``[attitude]``, ``[[antennas]]``, ``[traffic]``, ``[receiver]``).
The defaults are Liu et al. 2023 sec. 5.1's set-up as
:mod:`attopt.experiments.adsb_snr.scenario` describes it; every table's own
defaults are those values, so a config that sets one key of a table keeps the
others.

* Orbit: :data:`DEFAULT_TLE`, the two-line element set that sgp4 generates
  (:func:`attopt.experiments.environment.orbit.circular_orbit_tle`) for a
  near-circular orbit 600 km above sgp4's WGS72 equatorial radius, inclination
  97.8 deg, eccentricity 1e-4, argument of perigee and mean anomaly 0, epoch
  2025-06-01 00:00 UTC, right ascension of the ascending node 226.31 deg (the
  Sun's right ascension at the epoch, 68.81 deg, plus 157.5 deg: ascending
  node at 22:30 local time).  The pass starts at :data:`DEFAULT_START_UTC`.
  ``type = "circular"`` generates another (altitude, inclination or
  Sun-synchronous, local time of the node: :mod:`attopt.experiments.config.components`).
* Attitude (:class:`AttitudeProfile`): the 3-2-1 Euler-angle wander about Earth
  pointing of Liu et al. 2023 eq. 8 (amplitudes 4, 3, 5 deg; periods 1700, 2300,
  1100 s; roll phase 60 deg).
* Antennas: two helices (Liu et al. 2023 eq. 63, ``g = 14.4598 cos^6 alpha``, main
  lobe ``G >= 4 dBi``) tilted ``beta_opt = 50.77 deg`` (eq. 64) from nadir, towards
  +y and -y body (Fig. 7).  Any number, each with its own boresight and gain
  pattern (:class:`attopt.experiments.config.components.Antenna`).
* Traffic (:class:`TrafficParameters`): the synthetic flights of
  :mod:`attopt.experiments.environment.traffic` and their transmitters' power
  (:class:`attopt.formulations.link_budget.LinkBudget`); optionally aircraft that
  broadcast a wrong position (:class:`Spoofer`).
* Receiver (:class:`ReceiverParameters`): the noise power, the polarisation loss, the SNR
  noise and the reception threshold (``P_SNR^req = 6 dB``, sec. 5.1).
* The real sky (:mod:`attopt.experiments.adsb_snr.sky`): ``[traffic.transmitters]``,
  ``[receiver.collisions]`` and ``[receiver.chain]`` replace the paper's ideal
  transmitters, collision-free channel and Gaussian receiver; absent by default.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray
from pydantic import Field, ValidationInfo, field_validator, model_validator
from scipy.spatial.transform import Rotation

from attopt.experiments.config import Parameters
from attopt.experiments.config.components import (
    Antenna,
    CosinePowerGain,
    Orbit,
    TleOrbit,
    UtcTime,
)
from attopt.experiments.environment.adsb_collisions import SQUITTER_RATE_HZ, CaptureRule
from attopt.experiments.environment.adsb_receiver import ReceiverChain
from attopt.experiments.environment.aircraft_transmitters import AircraftTransmitterParameters
from attopt.experiments.environment.orbit import checked_window
from attopt.experiments.environment.traffic import TrafficModel
from attopt.formulations.conventions import attitude_from_euler321
from attopt.formulations.link_budget import ADSB_FREQUENCY_HZ, LinkBudget
from attopt.formulations.snr_model import SNR_SIGMA_DB
from attopt.formulations.snr_problem import RECEPTION_THRESHOLD_DB

DEFAULT_TLE = (
    "1 99999U          25152.00000000  .00000000  00000-0  00000+0 0    02",
    "2 99999  97.8000 226.3100 0001000   0.0000   0.0000 14.89340181    05",
)
"""``circular_orbit_tle("2025-06-01T00:00:00", 99999, 600.0, 97.8, 226.31)`` (module
docstring; pinned in the tests)."""
DEFAULT_START_UTC = "2025-06-02T01:41:00"
"""25 h 41 min after the TLE epoch: the hour whose sparsest epoch holds the most aircraft in
an antenna's main lobe (:mod:`attopt.experiments.adsb_snr.scenario`)."""
BETA_OPT_DEG = 50.77
"""Optimal antenna tilt from nadir (Liu et al. 2023 eq. 64)."""
DEFAULT_BORESIGHTS_BODY = (
    (0.0, math.sin(math.radians(BETA_OPT_DEG)), math.cos(math.radians(BETA_OPT_DEG))),
    (0.0, -math.sin(math.radians(BETA_OPT_DEG)), math.cos(math.radians(BETA_OPT_DEG))),
)
"""Boresights of Liu et al. 2023's two antennas in the body frame (unit vectors)."""
HELIX = CosinePowerGain(peak_gain=14.4598, exponent=6.0, min_gain_dbi=4.0)
"""Liu et al. 2023 eq. 63's helix with the main lobe ``G >= 4 dBi`` of sec. 5.1."""
_TRAFFIC = TrafficModel()
_LINK = LinkBudget()


class AttitudeProfile(Parameters):
    """True orbit -> body attitude: 3-2-1 Euler angles (Liu et al. 2023 eq. 8) wandering
    about Earth pointing, ``t`` in seconds from the start::

        yaw(t)   = A_yaw   cos(2 pi t / P_yaw   + phase_yaw)
        pitch(t) = A_pitch sin(2 pi t / P_pitch + phase_pitch)
        roll(t)  = A_roll  sin(2 pi t / P_roll  + phase_roll)
    """

    yaw_amplitude_deg: float = Field(4.0, description="Amplitude of the yaw wander.")
    yaw_period_s: float = Field(1700.0, gt=0, description="Period of the yaw wander.")
    yaw_phase_deg: float = Field(0.0, description="Phase of the yaw cosine at t = 0.")
    pitch_amplitude_deg: float = Field(3.0, description="Amplitude of the pitch wander.")
    pitch_period_s: float = Field(2300.0, gt=0, description="Period of the pitch wander.")
    pitch_phase_deg: float = Field(0.0, description="Phase of the pitch sine at t = 0.")
    roll_amplitude_deg: float = Field(5.0, description="Amplitude of the roll wander.")
    roll_period_s: float = Field(1100.0, gt=0, description="Period of the roll wander.")
    roll_phase_deg: float = Field(60.0, description="Phase of the roll sine at t = 0.")

    def attitude(self, t_s: NDArray[np.float64]) -> Rotation:
        """The orbit -> body attitudes at times ``t_s`` (s from the start)."""
        yaw = self.yaw_amplitude_deg * np.cos(
            2.0 * np.pi * t_s / self.yaw_period_s + np.radians(self.yaw_phase_deg)
        )
        pitch = self.pitch_amplitude_deg * np.sin(
            2.0 * np.pi * t_s / self.pitch_period_s + np.radians(self.pitch_phase_deg)
        )
        roll = self.roll_amplitude_deg * np.sin(
            2.0 * np.pi * t_s / self.roll_period_s + np.radians(self.roll_phase_deg)
        )
        return attitude_from_euler321(np.radians(yaw), np.radians(pitch), np.radians(roll))


class Spoofer(Parameters):
    """``[traffic.spoofer]``: aircraft whose ADS-B messages broadcast a position
    ``offset_km`` from the true one (a spoofer, or a wrong navigation solution on board).

    The receiver takes the broadcast position for the line of sight and the range of
    each of their messages over the window; the SNR is that of the true position.  The
    offset is horizontal (in the plane normal to the aircraft's geodetic normal) at
    ``azimuth_deg`` clockwise from north, a straight segment of ``offset_km``.  Drawn
    from child stream
    :data:`~attopt.experiments.adsb_snr.spoofing.SPOOFER_STREAM` of the trial's seed:
    which aircraft (for a count, among those in view in the window) and, without
    ``azimuth_deg``, each one's azimuth.
    """

    aircraft: int | list[int] = Field(
        1,
        description=(
            "Spoofed aircraft: a number drawn from those in view in the window, or a list "
            "of fleet indices."
        ),
    )
    offset_km: float = Field(50.0, gt=0.0, description="Distance of the broadcast position.")
    azimuth_deg: float | None = Field(
        None,
        description="Direction of the offset from north (clockwise); drawn per aircraft if unset.",
    )
    start_s: float = Field(0.0, ge=0.0, description="Start of the window from the pass start.")
    duration_s: float | None = Field(
        None, gt=0.0, description="Length of the window; to the end of the pass if unset."
    )

    @field_validator("aircraft")
    @classmethod
    def _count_or_indices(cls, aircraft: int | list[int]) -> int | list[int]:
        if isinstance(aircraft, int) and aircraft < 1:
            raise ValueError("a number of spoofed aircraft must be at least 1")
        if isinstance(aircraft, list) and (
            not aircraft or min(aircraft) < 0 or len(set(aircraft)) < len(aircraft)
        ):
            raise ValueError("a list of spoofed aircraft must name distinct fleet indices")
        return aircraft

    def active(self, t: NDArray[np.float64]) -> NDArray[np.bool_]:
        """Whether the times ``t`` lie in the window."""
        end = np.inf if self.duration_s is None else self.start_s + self.duration_s
        return (t >= self.start_s) & (t < end)


class TrafficParameters(Parameters):
    """The aircraft: a synthetic global population on great-circle routes between real
    airports (:mod:`attopt.experiments.environment.traffic`) and their 1090ES transmitters."""

    n_aircraft: int = Field(10_000, ge=1, description="Number of modelled flights.")
    seed: int = Field(0, ge=0, description="Seed of the modelled flights (routes, heights).")
    height_min_km: float = Field(
        _TRAFFIC.height_range_km[0], ge=0.0, description="Lowest geodetic cruise height."
    )
    height_max_km: float = Field(
        _TRAFFIC.height_range_km[1], le=50.0, description="Highest geodetic cruise height."
    )
    speed_min_m_s: float = Field(
        _TRAFFIC.speed_range_m_s[0], ge=0.0, description="Lowest ground speed."
    )
    speed_max_m_s: float = Field(
        _TRAFFIC.speed_range_m_s[1], le=1000.0, description="Highest ground speed."
    )
    route_min_km: float = Field(
        _TRAFFIC.min_route_km, ge=0.0, description="Shortest great-circle route."
    )
    route_max_km: float = Field(
        _TRAFFIC.max_route_km, le=20_000.0, description="Longest great-circle route."
    )
    route_scale_km: float = Field(
        _TRAFFIC.route_scale_km,
        gt=0.0,
        description="Scale of the routes' exponential distance preference.",
    )
    international_weight: float = Field(
        _TRAFFIC.international_weight,
        gt=0.0,
        description="Size factor of an airport named International.",
    )
    metropolitan_weight: float = Field(
        _TRAFFIC.metropolitan_weight,
        gt=0.0,
        description="Size factor of an airport of an IATA metropolitan area.",
    )
    transmit_power_w: float = Field(
        _LINK.transmit_power_w, gt=0.0, description="Nominal transmit power of every aircraft."
    )
    power_offset_sigma_db: float = Field(
        0.0, ge=0.0, description="Sigma of each aircraft's power offset from the nominal."
    )
    transmit_gain_dbi: float = Field(
        _LINK.transmit_gain_dbi, description="Aircraft antenna gain towards the satellite."
    )
    frequency_hz: float = Field(ADSB_FREQUENCY_HZ, gt=0.0, description="Carrier frequency.")
    spoofer: Spoofer | None = Field(
        None, description="Aircraft broadcasting a wrong position (a fault); none by default."
    )
    transmitters: AircraftTransmitterParameters | None = Field(
        None,
        description=(
            "Real transponder powers and aircraft antennas (docs/adsb_transmitters.md); "
            "none: every aircraft the nominal power through 0 dBi (Liu et al. 2023)."
        ),
    )
    squitter_rate_hz: float = Field(
        SQUITTER_RATE_HZ,
        gt=0.0,
        description="Messages per second of each aircraft (with collisions or the receiver chain).",
    )

    @model_validator(mode="after")
    def _bands(self) -> TrafficParameters:
        for low, high in (("height_min_km", "height_max_km"), ("speed_min_m_s", "speed_max_m_s")):
            if getattr(self, low) > getattr(self, high):
                raise ValueError(f"{low} must not exceed {high}")
        if not self.route_min_km < self.route_max_km:
            raise ValueError("route_min_km must be below route_max_km")
        return self

    @model_validator(mode="after")
    def _spoofed_in_fleet(self) -> TrafficParameters:
        named = self.spoofer.aircraft if self.spoofer is not None else None
        if isinstance(named, list) and max(named) >= self.n_aircraft:
            raise ValueError(f"spoofer.aircraft must be fleet indices below {self.n_aircraft}")
        return self

    def model(self) -> TrafficModel:
        """The traffic model of these numbers."""
        return TrafficModel(
            international_weight=self.international_weight,
            metropolitan_weight=self.metropolitan_weight,
            min_route_km=self.route_min_km,
            max_route_km=self.route_max_km,
            route_scale_km=self.route_scale_km,
            height_range_km=(self.height_min_km, self.height_max_km),
            speed_range_m_s=(self.speed_min_m_s, self.speed_max_m_s),
        )


class OutlierBurst(Parameters):
    """``[receiver.outliers]``: a receiver fault, every SNR it measures over a window
    ``offset_db`` off (before the reception threshold), a mismatch no estimator models."""

    start_s: float = Field(ge=0.0, description="Start of the burst from the pass start.")
    duration_s: float = Field(30.0, gt=0.0, description="Length of the burst.")
    offset_db: float = Field(20.0, description="Error added to every measured SNR in it.")

    def offsets(self, t: NDArray[np.float64]) -> NDArray[np.float64]:
        """``offset_db`` at the times ``t`` inside the burst, 0 elsewhere."""
        inside = (t >= self.start_s) & (t < self.start_s + self.duration_s)
        return np.where(inside, self.offset_db, 0.0)


class AircraftModel(Parameters):
    """``[receiver.aircraft_model]``: what the receiver assumes about the transmitters it
    cannot know one by one (:mod:`attopt.experiments.adsb_snr.sky`): each message's
    ``10 lg P0`` raised by the transponder classes' mean power offset and by the gain of
    the better placed aircraft antenna in level flight toward the satellite (for every
    estimator), the single-frame methods' power prior set to the classes' power
    spread and ``antenna_sigma_db`` in quadrature, with ``common_sigma_db`` as the part
    every aircraft an antenna hears in an epoch shares, and, with ``antennas``, the
    offsets' random walk of the filters that carry each aircraft's offset set to
    ``antenna_walk_db``.  Its numbers are those of ``[traffic.transmitters]`` (the
    defaults without that table)."""

    power: bool = Field(True, description="Whether the classes' mean power and spread are used.")
    antennas: bool = Field(
        True, description="Whether the level-flight gain of the better placed antenna is used."
    )
    antenna_sigma_db: float = Field(
        0.8,
        ge=0.0,
        description=(
            "Allowance for what the level-flight antenna model leaves out (bank, the other "
            "antenna): measured 0.77 dB over the received messages (docs/adsb_sky.md)."
        ),
    )
    common_sigma_db: float = Field(
        0.25,
        ge=0.0,
        description=(
            "Part of the model's error shared by every aircraft an antenna hears in an "
            "epoch (dB), which the single-frame methods' covariances allow for: measured "
            "0.14-0.29 dB over three hours of each of the power and modelled skies "
            "(docs/adsb_sky.md)."
        ),
    )
    antenna_walk_db: float = Field(
        0.08,
        ge=0.0,
        description=(
            "Random-walk density (dB/sqrt(s)) of what the level-flight antenna model leaves "
            "out, for the filters that carry each aircraft's offset (mekf_offsets): its "
            "change over 10-30 s measured 0.06-0.19 dB^2 (docs/adsb_sky.md)."
        ),
    )


class ReceiverParameters(Parameters):
    """The satellite's ADS-B receiver: noise power (Liu et al. 2023 eq. 2), polarisation
    loss, SNR measurement noise and reception threshold (sec. 5.1)."""

    snr_sigma_db: float = Field(SNR_SIGMA_DB, gt=0, description="SNR measurement noise sigma.")
    threshold_db: float = Field(
        RECEPTION_THRESHOLD_DB, description="Reception threshold of the measured SNR."
    )
    noise_temperature_k: float = Field(
        _LINK.noise_temperature_k, gt=0.0, description="System noise temperature."
    )
    bandwidth_hz: float = Field(_LINK.bandwidth_hz, gt=0.0, description="Noise bandwidth.")
    polarisation_loss_db: float = Field(
        _LINK.polarisation_loss_db,
        description="Loss of the vertically polarised aircraft signal on the receive antennas.",
    )
    outliers: OutlierBurst | None = Field(
        None, description="A burst of outlier SNRs (a receiver fault); none by default."
    )
    collisions: CaptureRule | None = Field(
        None,
        description=(
            "Overlapping messages resolved by power capture (docs/adsb_collisions.md); "
            "none: messages never collide (Liu et al. 2023)."
        ),
    )
    chain: ReceiverChain | None = Field(
        None,
        description=(
            "The simulated 1090ES receiver chain's reception and SNR error "
            "(docs/adsb_receiver.md); none: Gaussian SNR noise and the hard threshold."
        ),
    )
    aircraft_model: AircraftModel | None = Field(
        None,
        description=(
            "The receiver's model of the aircraft transmitters' powers and antennas "
            "(docs/adsb_sky.md); none: the nominal power through 0 dBi (Liu et al. 2023)."
        ),
    )

    def link_budget(self, traffic: TrafficParameters) -> LinkBudget:
        """The link from ``traffic``'s transmitters to this receiver."""
        return LinkBudget(
            transmit_power_w=traffic.transmit_power_w,
            transmit_gain_dbi=traffic.transmit_gain_dbi,
            polarisation_loss_db=self.polarisation_loss_db,
            frequency_hz=traffic.frequency_hz,
            noise_temperature_k=self.noise_temperature_k,
            bandwidth_hz=self.bandwidth_hz,
        )


SKY_FIELDS = {
    "traffic": {"transmitters", "squitter_rate_hz"},
    "receiver": {"collisions", "chain", "aircraft_model"},
}
"""The tables of the real sky (:mod:`attopt.experiments.adsb_snr.sky`), by table."""


class AdsbScenario(Parameters):
    """The simulated world and sensors of ``adsb-snr`` (module docstring)."""

    start_utc: UtcTime = Field(DEFAULT_START_UTC, description="Start of the pass.")
    duration_s: float = Field(3600.0, gt=0, description="Length of the pass from the start.")
    step_s: float = Field(1.0, gt=0, description="Time between epochs.")
    orbit: Orbit = Field(
        default_factory=lambda: TleOrbit(line1=DEFAULT_TLE[0], line2=DEFAULT_TLE[1]),
        description="The satellite's orbit (SGP4 must reach every epoch of the pass).",
    )
    attitude: AttitudeProfile = Field(
        default_factory=AttitudeProfile, description="True attitude profile."
    )
    antennas: list[Antenna] = Field(
        default_factory=lambda: [
            Antenna(boresight_body=list(b), gain=HELIX) for b in DEFAULT_BORESIGHTS_BODY
        ],
        min_length=1,
        description="Receive antennas: boresight in the body frame and gain pattern.",
    )
    traffic: TrafficParameters = Field(
        default_factory=TrafficParameters, description="The aircraft and their transmitters."
    )
    receiver: ReceiverParameters = Field(
        default_factory=ReceiverParameters, description="The satellite's receiver."
    )

    @field_validator("orbit")
    @classmethod
    def _propagates_over_the_pass(cls, orbit: Orbit, info: ValidationInfo) -> Orbit:
        return checked_window(orbit, info.data)

    @property
    def n_antennas(self) -> int:
        return len(self.antennas)

    @property
    def boresights_body(self) -> NDArray[np.float64]:
        """Unit boresights, ``(n_antennas, 3)``."""
        return np.stack([antenna.boresight for antenna in self.antennas])

    @property
    def link_budget(self) -> LinkBudget:
        return self.receiver.link_budget(self.traffic)

    def key(self) -> str:
        """The scenario's fields as JSON (of a subclass too: its other fields left out), the
        cache key of the simulated geometry; ``AdsbScenario.model_validate_json`` reads it.

        The sky's tables (:data:`SKY_FIELDS`) are left out too: they act on each trial's
        measurements, not on the geometry or the noise-free SNRs, so every sky shares the
        scenario's cached geometry."""
        return self.model_dump_json(include=set(AdsbScenario.model_fields), exclude=SKY_FIELDS)
