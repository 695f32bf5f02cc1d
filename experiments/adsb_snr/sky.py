"""The ADS-B sky of a trial: aircraft transmitters, message collisions, the receiver chain.

Liu et al. 2023 (sec. 5.1) simulate an ideal sky: every aircraft transmits the same
known power through an isotropic antenna, each visible aircraft gives one SNR per
epoch with Gaussian noise of ``receiver.snr_sigma_db``, received iff that SNR reaches
``receiver.threshold_db``, and messages never collide.  Three tables of the scenario
replace the parts of that ideal, each alone or together, and a fourth gives the
receiver a model of what it cannot know aircraft by aircraft (``docs/adsb_sky.md``); a
scenario without them is the paper's, draw for draw.

* ``[traffic.transmitters]``
  (:class:`~attopt.experiments.environment.aircraft_transmitters.AircraftTransmitterParameters`):
  each aircraft's transponder power and its antennas' gain toward the satellite, with
  bank and diversity, add each row's EIRP offset to its true SNR
  (:func:`transmitter_offsets`).  The receiver does not know them.
* ``[receiver.collisions]``
  (:class:`~attopt.experiments.environment.adsb_collisions.CaptureRule`): every
  aircraft sends ``Poisson(traffic.squitter_rate_hz * step_s)`` messages in an epoch,
  and on each antenna's channel the messages of the aircraft visible in that antenna
  overlap and are resolved by the capture rule, at their true SNRs
  (:func:`message_counts`).  An aircraft is heard in an epoch only if one of its
  messages survives.
* ``[receiver.chain]``
  (:class:`~attopt.experiments.environment.adsb_receiver.ReceiverChain`): each
  surviving message is decoded (its parity checks) with the probability the simulated
  1090ES receiver measured at its SNR, and the receiver reports, for each aircraft it
  decoded in the epoch, the mean of its messages' estimated SNRs
  (:func:`chain_measurements`).  That replaces the Gaussian noise and the hard
  threshold: the epochs' ``threshold_db`` is then ``-inf``, and each row's
  ``sigma_db`` is the table's standard deviation over the square root of the number
  of messages averaged.
* ``[receiver.aircraft_model]`` (:class:`~attopt.experiments.adsb_snr.parameters.AircraftModel`):
  what the receiver assumes about the transmitters it cannot know one by one: each
  message's ``10 lg P0`` is raised by the offset it expects, for every estimator
  (:func:`modelled_eirp`), and the single-frame methods are told the model's
  uncertainty as their power prior (:func:`model_allowance_db`, and the part of it an
  antenna's aircraft share, :func:`model_common_sigma_db`).

SNRs.  The link budget's SNR is the signal over the noise in ``receiver.bandwidth_hz``
(Liu et al. 2023 eq. 2); the chain's table is indexed by the SNR per complex sample at
its sample rate ``fs``, ``10 lg(bandwidth / fs)`` dB higher for the same noise density
(``docs/adsb_receiver.md``).  The chain looks its table up at that per-sample SNR and
reports in the link budget's units, so the conversion is a known constant, not an
error.

Random streams: the transmitters, the messages and the chain draw from their own child
streams of the trial's seed (:data:`TRANSMITTER_STREAM`, :data:`MESSAGE_STREAM`,
:data:`CHAIN_STREAM`; the power offsets and the spoofer have 100 and 101); the paper's
Gaussian SNR noise keeps ``default_rng(seed)``.
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass

import numpy as np
import pandas as pd
from numpy.typing import NDArray

from attopt.experiments.adsb_snr.parameters import AdsbScenario
from attopt.experiments.adsb_snr.scenario import build_adsb_geometry
from attopt.experiments.environment.adsb_collisions import CaptureRule, surviving_message_counts
from attopt.experiments.environment.adsb_receiver import ReceiverChain, error_table, table_at
from attopt.experiments.environment.aircraft_transmitters import (
    AircraftTransmitterParameters,
    draw_transmitters,
    flight_direction_ecef,
    level_flight_gain_dbi,
    local_vertical,
    transmitter_offset_db,
)
from attopt.experiments.simulation import child_rng
from attopt.formulations.link_budget import LinkBudget

TRANSMITTER_STREAM = 102
"""Child stream of the trial's seed that draws the aircraft transmitters."""
MESSAGE_STREAM = 103
"""Child stream that draws the messages' times (and their collisions)."""
CHAIN_STREAM = 104
"""Child stream that draws the receiver chain's decoding and SNR errors."""
_NOMINAL_GAIN_DBI = LinkBudget().transmit_gain_dbi
"""The aircraft antenna gain of Liu et al. 2023's link budget (0 dBi), the offsets' reference."""
_CALIBRATION_STEP_DB = 0.01
"""Grid of the calibration's inverse of the mean-report curve (:func:`calibrated`)."""


@dataclass(frozen=True)
class Rows:
    """The visible (epoch, antenna, aircraft) rows of a pass that the sky acts on."""

    epoch_index: NDArray[np.intp]
    antenna: NDArray[np.intp]
    aircraft: NDArray[np.intp]
    aircraft_ecef_km: NDArray[np.float64]
    """True aircraft positions, ECEF (km), ``(M, 3)``."""


@dataclass(frozen=True)
class Measurements:
    """What the receiver reports for each row.

    ``measured_db`` is NaN where the row is not received; ``sigma_db`` the standard
    deviation the receiver states for it (a scalar for the paper's Gaussian model);
    ``threshold_db`` the reception threshold of the epochs (``-inf`` for the chain);
    ``messages`` the messages decoded per row (``None`` for the paper's one SNR per
    aircraft and epoch).
    """

    measured_db: NDArray[np.float64]
    received: NDArray[np.bool_]
    sigma_db: NDArray[np.float64] | float
    threshold_db: float
    messages: NDArray[np.int64] | None = None


def transmitter_offsets(
    scenario: AdsbScenario, rows: Rows, seed: np.random.SeedSequence
) -> NDArray[np.float64] | None:
    """Each row's EIRP offset (dB) from ``[traffic.transmitters]``, drawn per trial from
    :data:`TRANSMITTER_STREAM`; ``None`` without that table (Liu et al. 2023's ideal).

    The line of sight runs from the aircraft to the satellite (ECEF); the aircraft fly
    along their routes (``flight_direction_ecef`` of
    :mod:`~attopt.experiments.environment.aircraft_transmitters`).
    """
    parameters = scenario.traffic.transmitters
    if parameters is None:
        return None
    geometry = build_adsb_geometry(scenario)
    transmitters = draw_transmitters(
        parameters,
        geometry.traffic.size,
        float(geometry.t[-1]),
        child_rng(seed, TRANSMITTER_STREAM),
    )
    t = geometry.t[rows.epoch_index]
    los = geometry.position_ecef_km[rows.epoch_index] - rows.aircraft_ecef_km
    los /= np.linalg.norm(los, axis=-1, keepdims=True)
    heading = flight_direction_ecef(geometry.traffic, t, rows.aircraft)
    return transmitter_offset_db(
        transmitters, rows.aircraft, t, rows.aircraft_ecef_km, heading, los
    )


def modelled_eirp(
    scenario: AdsbScenario, rows: Rows, decoded_ecef_km: NDArray[np.float64]
) -> NDArray[np.float64] | None:
    """``[receiver.aircraft_model]``'s expected EIRP offset (dB) of each row, ``None``
    without that table: the transponder classes' mean power offset
    (``power_offset_moments``), plus the level-flight gain of the better placed antenna
    toward the satellite at the elevation of the satellite above the decoded position's
    horizontal plane
    (:func:`~attopt.experiments.environment.aircraft_transmitters.level_flight_gain_dbi`).
    The numbers are those of ``[traffic.transmitters]``, or their defaults."""
    model = scenario.receiver.aircraft_model
    if model is None:
        return None
    installation = scenario.traffic.transmitters or AircraftTransmitterParameters()
    mean = installation.power_offset_moments()[0] if model.power else 0.0
    offset = np.full(rows.epoch_index.size, mean)
    if model.antennas:
        geometry = build_adsb_geometry(scenario)
        los = geometry.position_ecef_km[rows.epoch_index] - decoded_ecef_km
        los /= np.linalg.norm(los, axis=-1, keepdims=True)
        up = local_vertical(decoded_ecef_km)
        elevation = np.arcsin(np.clip(np.sum(up * los, axis=-1), -1.0, 1.0))
        offset = offset + level_flight_gain_dbi(elevation, installation) - _NOMINAL_GAIN_DBI
    return offset


def model_allowance_db(scenario: AdsbScenario) -> float:
    """The standard deviation ``[receiver.aircraft_model]`` states for what it leaves
    out: ``sqrt(s_p^2 + s_a^2)``, ``s_p`` the classes' power spread (0 without
    ``power``) and ``s_a`` its ``antenna_sigma_db`` (0 without ``antennas``); 0 without
    the table.  It is an independent error of each aircraft's SNR within one epoch,
    but not from epoch to epoch (an aircraft keeps its power), so it is the
    single-frame methods' power prior (``power_offset_sigma_db``), not the filters'."""
    model = scenario.receiver.aircraft_model
    if model is None:
        return 0.0
    installation = scenario.traffic.transmitters or AircraftTransmitterParameters()
    spread = installation.power_offset_moments()[1] if model.power else 0.0
    return math.hypot(spread, model.antenna_sigma_db if model.antennas else 0.0)


def model_common_sigma_db(scenario: AdsbScenario) -> float:
    """The part of the model's error (:func:`model_allowance_db`) that every aircraft an
    antenna hears in an epoch shares, ``[receiver.aircraft_model]``'s
    ``common_sigma_db``; 0 without the table or without an allowance.  The received
    messages are those whose offsets the model underrates less (the receiver hears the
    louder aircraft near its threshold), and aircraft in the same part of the sky share
    much of the level-flight antenna model's error, so it does not average out over the
    epoch's SNRs; it is the single-frame methods' ``power_offset_common_sigma_db``."""
    model = scenario.receiver.aircraft_model
    if model is None or not model_allowance_db(scenario):
        return 0.0
    return model.common_sigma_db


def message_counts(
    true_snr_db: NDArray[np.float64],
    rows: Rows,
    n_antennas: int,
    rule: CaptureRule | None,
    rate_hz: float,
    step_s: float,
    rng: np.random.Generator,
) -> NDArray[np.int64]:
    """Messages of each row's aircraft in its epoch that survive collisions on its
    antenna's channel (module docstring): without a ``rule``, every message sent
    (``Poisson(rate_hz * step_s)``); with one, a Monte Carlo of each channel's epoch, the
    channels one after the other from ``rng``
    (:func:`~attopt.experiments.environment.adsb_collisions.surviving_message_counts`)."""
    if rule is None:
        return rng.poisson(rate_hz * step_s, true_snr_db.size)
    channel = rows.epoch_index * n_antennas + rows.antenna
    bounds = np.flatnonzero(np.diff(channel, prepend=-1, append=-1))
    survived = np.zeros(true_snr_db.size, dtype=np.int64)
    for start, stop in itertools.pairwise(bounds):
        survived[start:stop] = surviving_message_counts(
            true_snr_db[start:stop], rule, rng, epoch_s=step_s, rate_hz=rate_hz
        )
    return survived


def chain_measurements(
    true_snr_db: NDArray[np.float64],
    messages: NDArray[np.int64],
    chain: ReceiverChain,
    bandwidth_hz: float,
    rng: np.random.Generator,
) -> Measurements:
    """The chain's reports of rows whose aircraft got ``messages`` to the receiver
    (module docstring).

    Each message is decoded with the table's probability ``p`` at its per-sample SNR, so
    ``k ~ Binomial(messages, p)``; a row is received iff ``k >= 1``, and reported as the
    mean of ``k`` estimates, ``true + bias + std z / sqrt(k)`` (the table's bias and
    standard deviation, ``z`` standard normal).  A calibrated chain reports the true SNR
    whose mean report is ``y`` (:func:`calibrated`) and states ``std / (sqrt(k) m')``
    there: the bias falls with the SNR, so removing it stretches the error by ``1 / m'
    = 1 / (1 + b')``.  An uncalibrated chain states ``std(y) / sqrt(k)`` and leaves the
    bias in its reports.
    """
    table = error_table(chain).frame
    to_sample = 10.0 * math.log10(bandwidth_hz / chain.sample_rate_hz)
    p, bias, std = table_at(table, true_snr_db + to_sample)
    decoded = rng.binomial(messages, p)
    received = decoded >= 1
    averaged = np.maximum(decoded, 1)
    measured = true_snr_db + bias + std * rng.standard_normal(true_snr_db.size) / np.sqrt(averaged)
    sample = measured + to_sample
    gain = 1.0
    if chain.calibrated:
        sample, slope = calibrated(table, sample)
        measured = sample - to_sample
        gain = 1.0 / slope
    _, _, stated = table_at(table, sample)
    return Measurements(
        measured_db=np.where(received, measured, np.nan),
        received=received,
        sigma_db=gain * stated / np.sqrt(averaged),
        threshold_db=-math.inf,
        messages=decoded,
    )


def calibrated(
    table: pd.DataFrame, sample_db: NDArray[np.float64]
) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """The true SNRs whose mean reports are ``sample_db``, and the mean curve's slope there.

    The chain's mean report at the true SNR ``x`` is ``m(x) = x + b(x)`` (``b`` the table's
    bias): increasing, since ``b' > -1``.  Its inverse, on a grid of
    :data:`_CALIBRATION_STEP_DB`, is the calibration; a report ``y = m(x) + e`` maps to
    ``m^-1(y) ~ x + e / m'(x)``, so the calibrated error's sigma is the report's over
    ``m'``.
    """
    grid = np.arange(table["snr_db"].min(), table["snr_db"].max(), _CALIBRATION_STEP_DB)
    _, bias, _ = table_at(table, grid)
    mean_report = grid + bias
    estimate = np.interp(sample_db, mean_report, grid)
    slope = np.interp(estimate, grid[:-1], np.diff(mean_report) / _CALIBRATION_STEP_DB)
    return estimate, slope


def gaussian_measurements(
    true_snr_db: NDArray[np.float64],
    rng: np.random.Generator,
    sigma_db: float,
    threshold_db: float,
    fault_db: NDArray[np.float64] | None,
) -> Measurements:
    """Liu et al. 2023 sec. 5.1: ``true + sigma_db z`` per row (``z`` from ``rng``, in the
    rows' order), plus a receiver fault, received iff it reaches ``threshold_db``."""
    measured = true_snr_db + sigma_db * rng.standard_normal(true_snr_db.size)
    if fault_db is not None:
        measured = measured + fault_db
    return Measurements(measured, measured >= threshold_db, sigma_db, threshold_db)


@dataclass(frozen=True)
class Reception:
    """How a trial's receiver hears the rows: the messages of each row that reach the
    receiver (sent, and surviving collisions if they are modelled), and the receiver
    chain (``None``: the Gaussian SNR and the hard threshold of Liu et al. 2023)."""

    survived: NDArray[np.int64]
    chain: ReceiverChain | None
    bandwidth_hz: float
    rng: np.random.Generator

    def measure(
        self,
        true_snr_db: NDArray[np.float64],
        gaussian_rng: np.random.Generator,
        sigma_db: float,
        threshold_db: float,
        fault_db: NDArray[np.float64] | None,
    ) -> Measurements:
        """The receiver's reports: the chain's, or the paper's Gaussian model restricted
        to the rows with a message that reached the receiver; a receiver fault adds to
        the reports."""
        if self.chain is None:
            paper = gaussian_measurements(
                true_snr_db, gaussian_rng, sigma_db, threshold_db, fault_db
            )
            received = paper.received & (self.survived >= 1)
            return Measurements(paper.measured_db, received, sigma_db, threshold_db, self.survived)
        chain = chain_measurements(
            true_snr_db, self.survived, self.chain, self.bandwidth_hz, self.rng
        )
        if fault_db is None:
            return chain
        return Measurements(
            chain.measured_db + fault_db,
            chain.received,
            chain.sigma_db,
            chain.threshold_db,
            chain.messages,
        )


def reception(
    scenario: AdsbScenario,
    rows: Rows,
    true_snr_db: NDArray[np.float64],
    seed: np.random.SeedSequence,
) -> Reception | None:
    """The trial's :class:`Reception` from ``[receiver.collisions]`` and
    ``[receiver.chain]``; ``None`` without either (Liu et al. 2023's receiver)."""
    receiver = scenario.receiver
    if receiver.collisions is None and receiver.chain is None:
        return None
    survived = message_counts(
        true_snr_db,
        rows,
        scenario.n_antennas,
        receiver.collisions,
        scenario.traffic.squitter_rate_hz,
        scenario.step_s,
        child_rng(seed, MESSAGE_STREAM),
    )
    return Reception(survived, receiver.chain, receiver.bandwidth_hz, child_rng(seed, CHAIN_STREAM))
