"""What the receiver decodes of each ADS-B message, and aircraft that broadcast a wrong position.

A message carries the aircraft's position; the receiver turns it into the line of
sight in the orbit frame (with the satellite's own position and attitude reference)
and the isotropic power at its slant range (Liu et al. 2023 eqs. 3, 5-7), the inputs of
every SNR estimator.  Without a spoofer these are the true geometry's
(:meth:`Decoded.of`).  With ``[traffic.spoofer]``
(:class:`~attopt.experiments.adsb_snr.parameters.Spoofer`) the messages of the chosen
aircraft inside its window broadcast a position moved by ``offset_km`` horizontally, so
the receiver's line of sight and power are wrong while the SNR is that of the true
position: a fault of the transmitter's data, not of the measurement
(:func:`spoofed_decoding`).

Random draws come from child stream :data:`SPOOFER_STREAM` of the trial's seed alone,
and only when there is a spoofer, so runs without one draw exactly what they drew
before: first the aircraft (for a count: ``Generator.choice`` without replacement among
the aircraft with a visible row in the window, in a main lobe whether received or not,
sorted by fleet index), then, without ``azimuth_deg``, one azimuth per chosen
aircraft, uniform in ``[0, 2 pi)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from numpy.typing import NDArray

from attopt.experiments.adsb_snr.parameters import AdsbScenario, Spoofer
from attopt.experiments.adsb_snr.scenario import build_adsb_geometry, lines_of_sight
from attopt.experiments.environment.traffic import geodetic_normals, horizontal_offsets_km
from attopt.experiments.simulation import child_rng

if TYPE_CHECKING:
    from attopt.experiments.adsb_snr.experiment import NoiseFreePass

SPOOFER_STREAM = 101
"""Child stream (:func:`~attopt.experiments.simulation.child_rng`) of the spoofer's draws."""


@dataclass(frozen=True)
class Decoded:
    """What the receiver takes from each visible (epoch, antenna, aircraft) row's message.

    Attributes:
        aircraft_ecef_km: the broadcast positions, ECEF (ITRS), ``(M, 3)``.
        los_orbit: unit lines of sight to them in the orbit frame, ``(M, 3)``.
        p0_dbw: isotropic received power at their slant ranges (eq. 3), ``(M,)``.
        spoofed: fleet indices of the aircraft that broadcast a wrong position (empty
            without a spoofer).
    """

    aircraft_ecef_km: NDArray[np.float64]
    los_orbit: NDArray[np.float64]
    p0_dbw: NDArray[np.float64]
    spoofed: NDArray[np.intp]

    @classmethod
    def of(cls, scenario: NoiseFreePass) -> Decoded:
        """The true geometry's positions, lines of sight and powers (no spoofer)."""
        return cls(
            scenario.aircraft_ecef_km,
            scenario.los_orbit,
            scenario.p0_dbw,
            np.empty(0, dtype=np.intp),
        )


def spoofed_aircraft(
    spoofer: Spoofer, scenario: NoiseFreePass, rng: np.random.Generator
) -> NDArray[np.intp]:
    """The fleet indices ``spoofer.aircraft`` names, or that many drawn from ``rng`` among
    the aircraft in view in the window (all of them if fewer; module docstring)."""
    if isinstance(spoofer.aircraft, list):
        return np.asarray(spoofer.aircraft, dtype=np.intp)
    in_view = np.unique(scenario.aircraft[spoofer.active(scenario.t[scenario.epoch_index])])
    count = min(spoofer.aircraft, in_view.size)
    return np.asarray(rng.choice(in_view, size=count, replace=False), dtype=np.intp)


def spoofed_decoding(
    parameters: AdsbScenario, scenario: NoiseFreePass, seed: np.random.SeedSequence
) -> Decoded:
    """What the receiver decodes in trial ``seed`` (module docstring): the true geometry's
    values but on the spoofed aircraft's rows in the window, whose broadcast position is
    moved by :func:`~attopt.experiments.environment.traffic.horizontal_offsets_km`."""
    decoded = Decoded.of(scenario)
    spoofer = parameters.traffic.spoofer
    if spoofer is None:
        return decoded
    rng = child_rng(seed, SPOOFER_STREAM)
    chosen = spoofed_aircraft(spoofer, scenario, rng)
    azimuth = (
        np.full(chosen.size, np.radians(spoofer.azimuth_deg))
        if spoofer.azimuth_deg is not None
        else rng.uniform(0.0, 2.0 * np.pi, chosen.size)
    )
    rows = np.flatnonzero(
        np.isin(scenario.aircraft, chosen) & spoofer.active(scenario.t[scenario.epoch_index])
    )
    geometry = build_adsb_geometry(parameters)
    epoch, aircraft = scenario.epoch_index[rows], scenario.aircraft[rows]
    row_azimuth = azimuth[np.argsort(chosen)][np.searchsorted(np.sort(chosen), aircraft)]
    normal = geodetic_normals(geometry.traffic, geometry.t[epoch], aircraft)
    position = scenario.aircraft_ecef_km.copy()
    position[rows] += horizontal_offsets_km(normal, row_azimuth, spoofer.offset_km)
    los_orbit, p0_dbw = decoded.los_orbit.copy(), decoded.p0_dbw.copy()
    los_orbit[rows], range_km = lines_of_sight(geometry, epoch, position[rows])
    p0_dbw[rows] = scenario.link_budget.isotropic_power_dbw(1000.0 * range_km)
    return Decoded(position, los_orbit, p0_dbw, chosen)
