"""Fixed-beam L-band link, GEO broadcaster to ground stations (Pimienta-Penalver and
Crassidis sec. II, eqs. 1-7).

The SNR at a ground station, in dB (Pimienta-Penalver and Crassidis eq. 7)::

    SNR = EIRP - L + G_r/T_r - k - R_s,   EIRP = P_t + G_t(theta_b)   (eq. 3)

* ``G_t`` is the broadcaster's main lobe, ``G_max - C (theta_b / theta_3dB)^2``
  (eq. 5, :class:`attopt.formulations.gain_patterns.ParabolicPattern`), with ``G_max``
  of a parabolic dish ``10 lg[eta (pi D / lambda)^2]`` (eq. 4; the "phi" printed
  in eq. 4 is pi).  The efficiency is ``eta = 0.55``: eq. 4's approximation
  ``6.9 A / lambda^2`` (``A = pi D^2 / 4``) is ``eta = 6.9 / (4 pi) = 0.549``.
  Pimienta-Penalver and Crassidis give no ``theta_3dB``; by default attopt uses the
  textbook half-power beamwidth of a parabolic dish, ``70 lambda / D`` degrees
  (1.13 deg for Garuda-1; :attr:`GeoLink.beamwidth_deg` sets another), with Table 1's
  ``C = 10``, so the -3 dB point lies at 0.55 ``theta_3dB`` off the boresight.  The
  quadratic law is used over the whole Earth disc seen from GEO (8.7 deg), as the
  paper does: the main-lobe edge is :attr:`GeoLink.lobe_edge_deg`, 9 deg by default.
* ``theta_b`` is the angle between the boresight (body ``+z``,
  :data:`BORESIGHT_BODY`) and the line of sight from the satellite to the
  station (Pimienta-Penalver and Crassidis eq. 15), computed by
  :func:`attopt.formulations.snr_model.off_boresight`.
* ``L = L0 + Delta L`` with ``L0 = 20 lg(4 pi d / lambda)`` and
  ``Delta L = 20 lg(d / h)`` (eq. 6): ``d`` the slant range and ``h`` the
  altitude of the satellite above the station, read as the difference of their
  geocentric radii, ``|r_sat| - |r_station|`` (so ``d = h`` for a station
  directly below the satellite on a sphere).
* ``G_r / T_r``: receive gain ``G_r`` (the paper gives none; 0 dBi, an
  omnidirectional station antenna) over ``T_r = 38 K``; ``k`` is Boltzmann's
  constant and ``R_s = 2.4`` kbit/s the noise bandwidth.

In the form of :func:`attopt.formulations.snr_model.snr_db`, ``SNR = G_t(theta_b) +
p0 - P_n`` with ``p0 = P_t - L + G_r`` (:meth:`GeoLink.received_isotropic_dbw`)
and ``P_n = 10 lg(k T_r R_s)``: :func:`geo_snr_db` is that same symbolic
definition (numpy and CasADi), so attitude Jacobians come from CasADi AD
(:func:`attopt.formulations.snr_model.predict_snr`) and SNRs of an epoch are an
:class:`~attopt.formulations.snr_measurement.SnrMeasurement` (:func:`geo_snr_epoch`).
:func:`geo_snr_db` raises for a station beyond the main lobe; :func:`main_lobe_snr_db`
gives NaN there (a simulation's stations anywhere on the Earth).

Frames: the attitude maps the frame of the positions (ECI for filters, ECEF
for the LOS search) to the body frame; positions are in km.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.spatial.transform import Rotation

from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.gain_patterns import ParabolicPattern
from attopt.formulations.link_budget import SPEED_OF_LIGHT_M_PER_S, noise_power_dbw
from attopt.formulations.snr_model import observation_mask, snr_db
from attopt.formulations.snr_problem import SnrEpoch
from attopt.formulations.symbolic import NUMPY, ArrayNamespace, namespace_of

Array = NDArray[np.float64]

BORESIGHT_BODY = np.array([0.0, 0.0, 1.0])
"""Broadcast antenna boresight in the body frame (Pimienta-Penalver and Crassidis eq. 15:
``[0 0 1]_B``)."""
HALF_POWER_BEAMWIDTH_DEG_PER_WAVELENGTH = 70.0
"""``theta_3dB = 70 lambda / D`` degrees, half-power beamwidth of a parabolic dish."""


@dataclass(frozen=True)
class GeoLink:
    """RF parameters of the broadcaster and the stations; defaults are Garuda-1 (Table 1)."""

    transmit_power_w: float = 12.0e3
    """``P_t``: Table 1's DC peak power, 12 kW."""
    dish_diameter_m: float = 12.0
    """``D_t`` (Table 1)."""
    size_factor_db: float = 10.0
    """``C`` of eq. 5 (Table 1)."""
    data_rate_bps: float = 2.4e3
    """``R_s`` (Table 1), the noise bandwidth in eq. 7."""
    frequency_hz: float = 1.55e9
    """Broadcast frequency (Table 1)."""
    efficiency: float = 0.55
    """``eta`` of eq. 4 (Pimienta-Penalver and Crassidis: 0.55-0.65; 0.549 is their
    ``6.9 A / lambda^2``)."""
    receiver_temperature_k: float = 38.0
    """``T_r`` (Pimienta-Penalver and Crassidis sec. II)."""
    receiver_gain_dbi: float = 0.0
    """``G_r`` (not given by Pimienta-Penalver and Crassidis): an omnidirectional station
    antenna."""
    beamwidth_deg: float | None = None
    """``theta_3dB`` of eq. 5 in degrees; ``None``: the dish's ``70 lambda / D``."""
    lobe_edge_deg: float = 9.0
    """Main-lobe edge of the quadratic law: beyond the Earth's angular radius from GEO
    (8.7 deg)."""

    def __post_init__(self) -> None:
        positive = [
            self.transmit_power_w,
            self.dish_diameter_m,
            self.size_factor_db,
            self.data_rate_bps,
            self.frequency_hz,
            self.lobe_edge_deg,
            *([] if self.beamwidth_deg is None else [self.beamwidth_deg]),
        ]
        values = [*positive, self.efficiency, self.receiver_temperature_k, self.receiver_gain_dbi]
        if not all(math.isfinite(v) for v in values) or min(positive) <= 0:
            raise InvalidObservationError(f"RF parameters must be finite and positive: {self}")
        if not (0 < self.efficiency <= 1 and self.receiver_temperature_k > 0):
            raise InvalidObservationError(f"bad efficiency or receiver temperature: {self}")
        if self.lobe_edge_deg >= 90.0:
            raise InvalidObservationError(f"the main-lobe edge must be below 90 deg: {self}")

    @property
    def wavelength_m(self) -> float:
        """``lambda = c / f``."""
        return SPEED_OF_LIGHT_M_PER_S / self.frequency_hz

    @property
    def transmit_power_dbw(self) -> float:
        """``P_t`` in dBW."""
        return 10.0 * math.log10(self.transmit_power_w)

    @property
    def peak_gain_dbi(self) -> float:
        """``G_max = 10 lg[eta (pi D / lambda)^2]`` (eq. 4)."""
        return 10.0 * math.log10(
            self.efficiency * (math.pi * self.dish_diameter_m / self.wavelength_m) ** 2
        )

    @property
    def theta_3db_rad(self) -> float:
        """Half-power beamwidth (rad): :attr:`beamwidth_deg`, else ``70 lambda / D`` degrees
        (module docstring)."""
        degrees = self.beamwidth_deg
        if degrees is None:
            degrees = (
                HALF_POWER_BEAMWIDTH_DEG_PER_WAVELENGTH * self.wavelength_m / self.dish_diameter_m
            )
        return math.radians(degrees)

    @property
    def peak_eirp_dbw(self) -> float:
        """``EIRP = P_t + G_max`` on the boresight (eq. 3)."""
        return self.transmit_power_dbw + self.peak_gain_dbi

    @property
    def figure_of_merit_db_per_k(self) -> float:
        """``G_r / T_r`` in dB/K."""
        return self.receiver_gain_dbi - 10.0 * math.log10(self.receiver_temperature_k)

    @property
    def noise_dbw(self) -> float:
        """``10 lg(k T_r R_s)`` (dBW): ``k`` and ``R_s`` of eq. 7 with ``T_r``."""
        return float(noise_power_dbw(self.receiver_temperature_k, self.data_rate_bps))

    @cached_property
    def pattern(self) -> ParabolicPattern:
        """``G_t(theta_b)`` of eq. 5, valid to :attr:`lobe_edge_deg`."""
        edge = math.radians(self.lobe_edge_deg)
        drop = self.size_factor_db * (edge / self.theta_3db_rad) ** 2
        return ParabolicPattern(
            peak_gain_dbi=self.peak_gain_dbi,
            theta_3db_rad=self.theta_3db_rad,
            min_gain_dbi=self.peak_gain_dbi - drop * (1.0 + 1e-12),
            size_factor_db=self.size_factor_db,
        )

    def path_loss_db(self, distance_km: Any, height_km: Any, xp: ArrayNamespace = NUMPY) -> Any:
        """``L = 20 lg(4 pi d / lambda) + 20 lg(d / h)`` (eq. 6), ``d``, ``h`` in km."""
        free_space = 20.0 * xp.log10(4.0e3 * math.pi * distance_km / self.wavelength_m)
        return free_space + 20.0 * xp.log10(distance_km / height_km)

    def received_isotropic_dbw(
        self, distance_km: Any, height_km: Any, xp: ArrayNamespace = NUMPY
    ) -> Any:
        """``p0 = P_t - L + G_r`` (dBW): eq. 7 without ``G_t`` and the noise terms."""
        return (
            self.transmit_power_dbw
            - self.path_loss_db(distance_km, height_km, xp)
            + self.receiver_gain_dbi
        )


GARUDA1 = GeoLink()
"""Garuda-1 / ACeS (Pimienta-Penalver and Crassidis Table 1)."""


def _norm(vectors: Any, xp: ArrayNamespace) -> Any:
    x, y, z = xp.components(vectors)
    return xp.sqrt(x**2 + y**2 + z**2)


def _casadi(x: Any) -> Any:
    return x if isinstance(x, ca.SX | ca.MX | ca.DM) else ca.DM(np.asarray(x, dtype=float))


def link_geometry(satellite_km: Any, stations_km: Any) -> tuple[Any, Any, Any]:
    """Satellite-to-station vectors, slant ranges ``d`` and altitudes ``h`` (eq. 6).

    numpy: ``satellite_km`` ``(..., 3)``, ``stations_km`` ``(..., m, 3)``;
    results ``(..., m, 3)``, ``(..., m)``, ``(..., m)``.  CasADi: a 3-vector
    and an ``m x 3`` matrix; results ``m x 3``, ``m x 1``, ``m x 1``.
    """
    xp = namespace_of(satellite_km, stations_km)
    if xp is NUMPY:
        satellite = np.asarray(satellite_km, dtype=float)[..., None, :]
        stations = np.asarray(stations_km, dtype=float)
        if satellite.shape[-1] != 3 or stations.shape[-1] != 3:
            raise InvalidObservationError("positions must have 3 components (last axis)")
    else:
        stations = _casadi(stations_km)
        satellite = ca.repmat(ca.reshape(_casadi(satellite_km), 1, 3), stations.size1(), 1)
    relative = stations - satellite
    height = _norm(satellite, xp) - _norm(stations, xp)
    return relative, _norm(relative, xp), height


def geo_snr_db(
    attitude_matrix: Any, satellite_km: Any, stations_km: Any, link: GeoLink = GARUDA1
) -> Any:
    """SNR (dB) at each station, Pimienta-Penalver and Crassidis eq. 7, numpy or CasADi
    (shapes of :func:`link_geometry`).

    numpy inputs are checked: :class:`InvalidObservationError` if the
    satellite is not above a station (``h <= 0``), a position is NaN/inf, or a
    station lies beyond the main lobe (:func:`attopt.formulations.snr_model.snr_db`).
    """
    relative, distance, height = link_geometry(satellite_km, stations_km)
    xp = namespace_of(attitude_matrix, relative)
    if xp is NUMPY and not np.all(np.isfinite(height) & (height > 0)):
        raise InvalidObservationError("satellite must be above every station (h > 0, finite)")
    p0 = link.received_isotropic_dbw(distance, height, xp)
    boresight = BORESIGHT_BODY if xp is NUMPY else ca.DM(BORESIGHT_BODY)
    return snr_db(attitude_matrix, relative, boresight, p0, link.noise_dbw, link.pattern)


def main_lobe_snr_db(
    attitude_matrix: ArrayLike,
    satellite_km: ArrayLike,
    stations_km: ArrayLike,
    link: GeoLink = GARUDA1,
) -> Array:
    """:func:`geo_snr_db` (numpy) at the stations inside the main lobe, NaN at the others.

    Shapes: ``attitude_matrix`` ``(..., 3, 3)``, ``satellite_km`` ``(..., 3)``,
    ``stations_km`` ``(..., m, 3)``; result ``(..., m)``.  With every station in the lobe
    this is :func:`geo_snr_db` on the whole arrays; otherwise each attitude's stations in
    the lobe are evaluated on their own.
    """
    matrix = np.asarray(attitude_matrix, dtype=float)
    satellite = np.asarray(satellite_km, dtype=float)
    stations = np.asarray(stations_km, dtype=float)
    inside = observation_mask(
        matrix, stations - satellite[..., None, :], BORESIGHT_BODY, link.pattern
    )
    if inside.all():
        return geo_snr_db(matrix, satellite, stations, link)
    lead = inside.shape[:-1]
    matrix = np.broadcast_to(matrix, (*lead, 3, 3)).reshape(-1, 3, 3)
    satellite = np.broadcast_to(satellite, (*lead, 3)).reshape(-1, 3)
    stations = np.broadcast_to(stations, (*inside.shape, 3)).reshape(-1, inside.shape[-1], 3)
    flat = inside.reshape(-1, inside.shape[-1])
    snr = np.full(flat.shape, np.nan)
    for k in np.flatnonzero(flat.any(axis=1)):
        use = flat[k]
        snr[k, use] = geo_snr_db(matrix[k], satellite[k], stations[k, use], link)
    return snr.reshape(inside.shape)


def station_terms(
    satellite_km: ArrayLike, stations_km: ArrayLike, link: GeoLink = GARUDA1
) -> tuple[Array, Array]:
    """Unit lines of sight satellite -> station ``(..., m, 3)`` and ``p0`` ``(..., m)`` (numpy)."""
    relative, distance, height = link_geometry(satellite_km, stations_km)
    if not np.all(np.isfinite(height) & (height > 0) & (distance > 0)):
        raise InvalidObservationError("satellite must be above every station (h > 0, finite)")
    return relative / distance[..., None], link.received_isotropic_dbw(distance, height)


def geo_snr_epoch(
    snr_db_measured: ArrayLike,
    satellite_km: ArrayLike,
    stations_km: ArrayLike,
    sigma_db: ArrayLike,
    link: GeoLink = GARUDA1,
) -> SnrEpoch:
    """The SNRs of one epoch as an :class:`~attopt.formulations.snr_problem.SnrEpoch`.

    Its "orbit frame" is the frame of the positions (ECI for the filters), so
    ``SnrMeasurement(geo_snr_epoch(...))`` models the attitude relative to
    that frame.  One antenna (:data:`BORESIGHT_BODY`); no reception threshold
    (the caller leaves out stations it did not hear).
    """
    los, p0 = station_terms(satellite_km, stations_km, link)
    return SnrEpoch(
        snr_db=snr_db_measured,
        los_orbit=los,
        antenna=np.zeros(los.shape[0], dtype=np.intp),
        boresights_body=BORESIGHT_BODY[None],
        p0_dbw=p0,
        noise_dbw=link.noise_dbw,
        pattern=link.pattern,
        sigma_db=sigma_db,
        threshold_db=-math.inf,
    )


def elevation_rad(station_km: ArrayLike, station_up: ArrayLike, satellite_km: ArrayLike) -> Array:
    """Elevation of the satellite above each station's horizon (rad), numpy.

    ``station_up`` is the unit ellipsoid normal (geodetic up) in the frame of
    the positions; shapes broadcast over leading axes, vectors on the last.
    """
    relative = np.asarray(satellite_km, dtype=float) - np.asarray(station_km, dtype=float)
    sine = np.sum(relative * np.asarray(station_up, dtype=float), axis=-1)
    return np.arcsin(np.clip(sine / np.linalg.norm(relative, axis=-1), -1.0, 1.0))


def attitude_pointing(boresight: ArrayLike, reference: Rotation | None = None) -> Rotation:
    """An attitude whose boresight (body ``+z``) points along ``boresight`` (positions' frame).

    Without ``reference``: the smallest rotation taking ``boresight`` to body
    ``+z`` (scipy ``align_vectors``); the rotation about the boresight, which
    no SNR observes, is that of the smallest rotation.  With ``reference``:
    ``reference`` turned by the smallest rotation ``Q`` (positions' frame)
    taking its boresight ``A^T z`` to ``boresight``, ``A' = A Q^T``, which
    keeps the yaw of ``reference``.
    """
    b = np.asarray(boresight, dtype=float)
    if b.shape != (3,) or not np.all(np.isfinite(b)) or not np.any(b):
        raise InvalidObservationError(f"boresight must be a finite non-zero 3-vector, got {b}")
    b = b / np.linalg.norm(b)
    if reference is None:
        rotation, _ = Rotation.align_vectors(BORESIGHT_BODY[None], b[None])
        return rotation
    turn, _ = Rotation.align_vectors(b[None], reference.inv().apply(BORESIGHT_BODY)[None])
    return reference * turn.inv()
