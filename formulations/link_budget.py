"""Link budget of the aircraft-to-satellite 1090ES (ADS-B) signal.

Supplies the two terms of Liu et al. 2023 eq. 4 that do not depend on the attitude:
the isotropic received power ``P0`` (eq. 3) and the noise power
``P_n = k_B T B`` (eq. 2), both in dBW.  ``P0`` is the power a 0 dBi receive
antenna would collect: transmit power plus aircraft antenna gain minus the
free-space loss ``(4 pi d f / c)^2`` (Pimienta-Penalver and Crassidis eq. 6, ``L0``)
and a polarisation loss.  Their extra elevation-dependent attenuation
``20 lg(d/h)`` (the same eq. 6) is a ground-station model and is not used.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

BOLTZMANN_J_PER_K = 1.380649e-23
"""Exact since the 2019 SI redefinition (Liu et al. 2023 eq. 2 rounds it to 1.381e-23)."""
SPEED_OF_LIGHT_M_PER_S = 299_792_458.0
ADSB_FREQUENCY_HZ = 1.090e9
"""1090 MHz extended squitter (Liu et al. 2023 sec. 1)."""


def noise_power_dbw(temperature_k: ArrayLike, bandwidth_hz: ArrayLike) -> NDArray[np.float64]:
    """``10 lg(k_B T B)`` (dBW), Liu et al. 2023 eq. 2."""
    return 10.0 * np.log10(BOLTZMANN_J_PER_K * np.asarray(temperature_k) * bandwidth_hz)


def free_space_loss_db(
    distance_m: ArrayLike, frequency_hz: ArrayLike = ADSB_FREQUENCY_HZ
) -> NDArray[np.float64]:
    """``20 lg(4 pi d f / c)`` (dB), free-space path loss (Pimienta-Penalver and Crassidis
    eq. 6, ``L0``)."""
    d = np.asarray(distance_m, dtype=float)
    return 20.0 * np.log10(4.0 * np.pi * d * frequency_hz / SPEED_OF_LIGHT_M_PER_S)


def isotropic_power_dbw(
    transmit_power_dbw: ArrayLike,
    distance_m: ArrayLike,
    transmit_gain_dbi: ArrayLike = 0.0,
    frequency_hz: ArrayLike = ADSB_FREQUENCY_HZ,
    other_losses_db: ArrayLike = 0.0,
) -> NDArray[np.float64]:
    """``P0`` (dBW) at a 0 dBi receive antenna: ``P_t + G_t - FSPL - losses`` (Liu et al.
    2023 eq. 3)."""
    return (
        np.asarray(transmit_power_dbw, dtype=float)
        + transmit_gain_dbi
        - free_space_loss_db(distance_m, frequency_hz)
        - other_losses_db
    )


@dataclass(frozen=True)
class LinkBudget:
    """Nominal 1090ES link from an aircraft to a LEO ADS-B receiver.

    With the defaults, an aircraft on the boresight of Liu et al. 2023's helix
    (11.6 dBi) at 1000 km gives an SNR of about 16.8 dB and at 2000 km about
    10.8 dB, above the 6 dB reception threshold of Liu et al. 2023 sec. 5.1
    (``tests/test_link_budget.py`` prints and checks them).

    Example::

        >>> from attopt import LinkBudget
        >>> budget = LinkBudget()  # 250 W transponder, 1090 MHz, 500 K, 2.6 MHz
        >>> round(float(budget.isotropic_power_dbw(1.0e6)), 2), round(budget.noise_power_dbw, 2)
        (-132.22, -137.46)
    """

    transmit_power_w: float = 250.0
    """Aircraft transmit power at the antenna (W).  Mode S/1090ES transponders
    deliver 125-500 W (21-27 dBW) in the classes required for high-altitude
    flight and at least 70 W (18.5 dBW) otherwise; 250 W (24 dBW) is the
    geometric mean of 125 and 500 W."""
    transmit_gain_dbi: float = 0.0
    """Aircraft antenna gain towards the satellite (dBi): a quarter-wave
    monopole, nominally 0 dBi (a few dBi near the horizon, a null at zenith;
    that elevation dependence is not modelled)."""
    polarisation_loss_db: float = 3.0
    """Vertically polarised aircraft monopole received by a circularly
    polarised antenna (the helix of Liu et al. 2023 fig. 5): 3 dB."""
    frequency_hz: float = ADSB_FREQUENCY_HZ
    """Carrier frequency (Hz)."""
    noise_temperature_k: float = 500.0
    """System noise temperature (K): the antenna sees the Earth (about 290 K
    at L band) and a receiver with a 2 dB noise figure adds
    ``290 (10^0.2 - 1) = 170 K``; cable losses before the amplifier round the
    sum up to 500 K."""
    bandwidth_hz: float = 2.6e6
    """Noise bandwidth (Hz): the 1088.7-1091.3 MHz band that ITU-R WP 5B
    studied for ADS-B reception on satellites, about the 2 MHz needed by the
    0.5 us pulses of the 1 Mbit/s pulse-position modulation."""

    @property
    def transmit_power_dbw(self) -> float:
        """``10 lg P_t`` (dBW)."""
        return 10.0 * math.log10(self.transmit_power_w)

    @property
    def noise_power_dbw(self) -> float:
        """``10 lg(k_B T B)`` (dBW), Liu et al. 2023 eq. 2."""
        return float(noise_power_dbw(self.noise_temperature_k, self.bandwidth_hz))

    def isotropic_power_dbw(self, distance_m: ArrayLike) -> NDArray[np.float64]:
        """``10 lg P0`` (dBW) at slant range ``distance_m`` (Liu et al. 2023 eq. 3)."""
        return isotropic_power_dbw(
            self.transmit_power_dbw,
            distance_m,
            self.transmit_gain_dbi,
            self.frequency_hz,
            self.polarisation_loss_db,
        )
