"""A simulated 1090ES (ADS-B) receiver chain and the SNR error table it implies.

Liu et al. 2023 (sec. 5.1) measure each message's SNR with Gaussian noise of 1 dB and
receive a message exactly when its SNR passes 6 dB.  This module replaces that rule by
a model measured on a simulated receiver: a DF17 message is encoded, synthesised as
complex baseband samples in white Gaussian noise, demodulated, checked by its CRC and
decoded with pyModeS, and its SNR is estimated from the samples as a deployed receiver
would.  A Monte Carlo over the true SNR gives a table (reception probability, bias and
standard deviation of the estimated SNR) that :func:`draw_snr_measurements` samples
from for whole arrays of messages.

Signal format (RTCA DO-260B sec. 2.2.3; ICAO Annex 10 Vol. IV sec. 3.1.2).  An
extended squitter is an 8 us preamble, pulses of 0.5 us starting at 0, 1.0, 3.5 and
4.5 us, followed by 112 data bits of 1 us each in pulse-position modulation: a 1 is a
pulse in the first half-microsecond of its bit, a 0 a pulse in the second.  The frame
is 120 us, 240 samples at 2 MHz.  Time is counted here in half-microsecond *chips*:
the preamble is chips 0-15 (pulses in chips 0, 2, 7, 9), bit ``k`` is chips
``16 + 2 k`` and ``17 + 2 k``.

SNR definition.  The samples are ``r_n = exp(j phi) s_n + w_n`` with ``s_n`` in
``{0, 1}`` (unit pulse amplitude), ``phi`` a uniform random carrier phase and ``w_n``
circular complex white Gaussian noise of variance ``sigma^2`` per sample.  Sampled at
``fs`` in complex baseband, the receiver bandwidth is ``fs`` and ``sigma^2`` is the
noise power in it, so

    SNR = (pulse power) / (noise power in bandwidth fs) = 1 / sigma^2,

a per-sample ratio.  The energy of one chip over the noise density is
``Ec / N0 = SNR * fs * 0.5 us`` (``fs * 0.5 us`` samples per chip): at one SNR an 8 MHz
receiver integrates 4 times more samples per chip than a 2 MHz one and demodulates
6 dB better.  For one physical noise density the SNR is ``10 lg(fs / 2 MHz)`` dB lower
at ``fs`` than at 2 MHz.

Reception is decided by the 24-bit Mode S parity alone (pyModeS ``crc_valid`` of a
DF17 frame), not by a threshold on the SNR.  The demodulator knows where the frame
starts (:func:`chip_powers`): preamble detection, timing recovery, overlapping
messages (:mod:`.adsb_collisions`) and error correction are not modelled, so the
reception probability is that of an ideally synchronised receiver that discards every
frame with a bit error.

Run ``python -m attopt.experiments.environment.adsb_receiver --messages 10000 --out
docs/figures/adsb_receiver_snr.png`` for the table and figure of ``docs/adsb_receiver.md``.
"""

from __future__ import annotations

import argparse
import functools
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pandas as pd
import pyModeS
from numpy.typing import ArrayLike, NDArray
from pydantic import Field, field_validator

from attopt.experiments.config import Parameters
from attopt.experiments.environment.disk_cache import disk_cached

N_BITS = 112
"""Bits of an extended squitter (DF17), 24 of them parity."""
CHIP_S = 0.5e-6
"""Length of one chip: a PPM half-bit, and the preamble pulse width."""
PREAMBLE_CHIPS = np.zeros(16, dtype=np.uint8)
"""The 8 us preamble in chips: pulses at 0, 1.0, 3.5 and 4.5 us (DO-260B 2.2.3.1.1)."""
PREAMBLE_CHIPS[[0, 2, 7, 9]] = 1
N_CHIPS = PREAMBLE_CHIPS.size + 2 * N_BITS
"""Chips of a frame: 240 (120 us)."""
DEFAULT_SAMPLE_RATE_HZ = 2e6
"""Default sample rate, one sample per chip."""
CRC_GENERATOR = 0xFFF409
"""Mode S parity generator polynomial without its leading ``x^24`` term
(``G(x) = x^24 + x^23 + ... + x^10 + x^3 + 1``, ICAO Annex 10 Vol. IV 3.1.2.3.3)."""
CPR_NZ = 15
"""Number of latitude zones between the equator and a pole in CPR (DO-260B A.1.7.2)."""
CPR_NB = 17
"""Bits of each airborne CPR coordinate (DO-260B A.1.7.1)."""
DF_EXTENDED_SQUITTER = 17
"""Downlink format of an ADS-B extended squitter from a Mode S transponder."""
SNR_GRID_DB = np.arange(0.0, 25.5, 0.5)
"""Default true SNRs of the table: 0 to 25 dB in steps of 0.5 dB."""


def mode_s_parity(data: int, n_data_bits: int = N_BITS - 24) -> int:
    """The 24-bit Mode S parity of ``data`` (its ``n_data_bits`` bits, first bit most
    significant): the remainder of ``data * x^24`` divided by the generator
    :data:`CRC_GENERATOR`, by polynomial long division over GF(2) (ICAO Annex 10 Vol. IV
    3.1.2.3.3; DO-260B 2.2.3.2.1.7).  For DF17 the parity field is this remainder
    (``AP = PI`` with interrogator code 0).

    >>> f"{mode_s_parity(0x8D4840D6202CC371C32CE0):06X}"
    '576098'
    """
    remainder = data << 24
    for bit in range(n_data_bits + 23, 23, -1):
        if remainder >> bit & 1:
            remainder ^= (CRC_GENERATOR | 1 << 24) << (bit - 24)
    return remainder


def encode_altitude(altitude_ft: float) -> int:
    """The 12-bit altitude field of an airborne position message with the Q bit set
    (25 ft increments, DO-260B 2.2.3.2.3.4.3): ``N = round((h + 1000) / 25)`` in 11
    bits, with the Q bit (1) inserted as the 8th bit of the 12.  Valid for
    -1000 ft <= h <= 50175 ft.

    >>> f"{encode_altitude(38000):012b}"
    '110000111000'
    """
    n = round((altitude_ft + 1000.0) / 25.0)
    if not 0 <= n < 1 << 11:
        raise ValueError(f"altitude {altitude_ft} ft outside -1000 to 50175 ft")
    return (n >> 4) << 5 | 1 << 4 | (n & 0xF)


def cpr_longitude_zones(latitude_deg: float) -> int:
    """``NL(lat)``, the number of longitude zones at a latitude (DO-260B A.1.7.2.d):

        NL = floor(2 pi / arccos(1 - (1 - cos(pi / (2 NZ))) / cos^2(pi lat / 180))),

    with ``NL = 59`` at the equator, 2 at ``|lat| = 87`` and 1 beyond.

    >>> cpr_longitude_zones(0.0), cpr_longitude_zones(52.26), cpr_longitude_zones(88.0)
    (59, 36, 1)
    """
    lat = abs(latitude_deg)
    if lat == 0.0:
        return 4 * CPR_NZ - 1
    if lat == 87.0:
        return 2
    if lat > 87.0:
        return 1
    a = 1.0 - math.cos(math.pi / (2 * CPR_NZ))
    return math.floor(2.0 * math.pi / math.acos(1.0 - a / math.cos(math.radians(lat)) ** 2))


def cpr_encode(latitude_deg: float, longitude_deg: float, odd: bool) -> tuple[int, int]:
    """Airborne CPR encoding (DO-260B A.1.7.3) of a position in format ``i`` (0 even,
    1 odd), ``Nb = 17``, ``NZ = 15``, ``MOD(x, y) = x - y floor(x / y)``:

        Dlat_i = 360 / (4 NZ - i)
        YZ_i   = floor(2^Nb MOD(lat, Dlat_i) / Dlat_i + 1/2)
        Rlat_i = Dlat_i (YZ_i / 2^Nb + floor(lat / Dlat_i))
        Dlon_i = 360 / (NL(Rlat_i) - i)   (360 if NL(Rlat_i) - i = 0)
        XZ_i   = floor(2^Nb MOD(lon, Dlon_i) / Dlon_i + 1/2)

    and returns ``(MOD(YZ_i, 2^17), MOD(XZ_i, 2^17))``.

    >>> cpr_encode(52.2572, 3.9194, odd=False)
    (93000, 51372)
    """
    i = int(odd)
    scale = 1 << CPR_NB
    dlat = 360.0 / (4 * CPR_NZ - i)
    yz = math.floor(scale * (latitude_deg % dlat) / dlat + 0.5)
    rlat = dlat * (yz / scale + math.floor(latitude_deg / dlat))
    zones = cpr_longitude_zones(rlat) - i
    dlon = 360.0 / zones if zones > 0 else 360.0
    xz = math.floor(scale * (longitude_deg % dlon) / dlon + 0.5)
    return yz % scale, xz % scale


def airborne_position_message(
    icao: int,
    altitude_ft: float,
    latitude_deg: float,
    longitude_deg: float,
    odd: bool,
    typecode: int = 11,
) -> int:
    """A DF17 airborne position message (barometric altitude, DO-260B 2.2.3.2.3) as a
    112-bit integer, first transmitted bit most significant.

    Fields (bits counted from 1): DF = 17 (1-5), CA = 5 (6-8, level 2 transponder,
    airborne), AA = ``icao`` (9-32), TC = ``typecode`` (33-37, 9-18: barometric
    altitude; 11 is NUCp 7), surveillance status 0 (38-39), NIC supplement B 0 (40),
    altitude (41-52, :func:`encode_altitude`), time bit 0 (53), CPR format (54),
    CPR latitude (55-71) and longitude (72-88, :func:`cpr_encode`), parity (89-112,
    :func:`mode_s_parity`).  pyModeS 3 only decodes, so the encoder is written here.

    The example is the even airborne position frame worked through in Sun 2021
    (*The 1090 Megahertz Riddle*):

    >>> f"{airborne_position_message(0x40621D, 38000, 52.2572, 3.9194, False):028X}"
    '8D40621D58C382D690C8AC2863A7'
    """
    if not 9 <= typecode <= 18:
        raise ValueError(f"typecode {typecode} is not an airborne position with baro altitude")
    lat_cpr, lon_cpr = cpr_encode(latitude_deg, longitude_deg, odd)
    me = (
        typecode << 51
        | encode_altitude(altitude_ft) << 36
        | int(odd) << 34
        | lat_cpr << 17
        | lon_cpr
    )
    data = DF_EXTENDED_SQUITTER << 83 | 5 << 80 | icao << 56 | me
    return data << 24 | mode_s_parity(data)


def message_bits(message: int) -> NDArray[np.uint8]:
    """The 112 bits of a message, in transmission order (most significant first)."""
    return np.array([message >> (N_BITS - 1 - k) & 1 for k in range(N_BITS)], dtype=np.uint8)


def bits_hex(bits: NDArray[np.integer]) -> str:
    """The 28 hexadecimal digits of 112 bits (transmission order), as pyModeS takes them.

    >>> bits_hex(message_bits(0x8D4840D6202CC371C32CE0576098))
    '8D4840D6202CC371C32CE0576098'
    """
    return f"{int(''.join(map(str, np.asarray(bits, dtype=int))), 2):028X}"


def samples_per_chip(sample_rate_hz: float) -> int:
    """Samples in one 0.5 us chip; the sample rate must be a multiple of 2 MHz."""
    n = sample_rate_hz * CHIP_S
    if n < 1 or abs(n - round(n)) > 1e-9:
        raise ValueError(f"sample rate {sample_rate_hz} Hz is not a multiple of 2 MHz")
    return round(n)


def frame_chips(bits: ArrayLike) -> NDArray[np.uint8]:
    """On/off pattern of the 240 chips of frames with bits ``bits`` (shape ``(..., 112)``):
    the preamble, then per bit the chips ``(b, 1 - b)`` (PPM, DO-260B 2.2.3.1.2)."""
    bits = np.asarray(bits, dtype=np.uint8)
    data = np.stack([bits, 1 - bits], axis=-1).reshape(*bits.shape[:-1], 2 * N_BITS)
    preamble = np.broadcast_to(PREAMBLE_CHIPS, (*bits.shape[:-1], PREAMBLE_CHIPS.size))
    return np.concatenate([preamble, data], axis=-1)


def ppm_waveform(
    bits: ArrayLike, sample_rate_hz: float = DEFAULT_SAMPLE_RATE_HZ
) -> NDArray[np.float64]:
    """Noise-free real envelope of frames (unit pulse amplitude), shape
    ``(..., 240 * fs * 0.5 us)``: 240 samples at 2 MHz, 960 at 8 MHz.

    >>> ppm_waveform(message_bits(0x8D4840D6202CC371C32CE0576098)).shape
    (240,)
    """
    return np.repeat(frame_chips(bits), samples_per_chip(sample_rate_hz), axis=-1).astype(float)


def baseband_samples(
    bits: ArrayLike,
    snr_db: ArrayLike,
    rng: np.random.Generator,
    sample_rate_hz: float = DEFAULT_SAMPLE_RATE_HZ,
) -> NDArray[np.complex128]:
    """Complex baseband samples ``r_n = exp(j phi) s_n + w_n`` of frames with bits
    ``bits`` (shape ``(..., 112)``): ``s_n`` from :func:`ppm_waveform`, ``phi`` uniform
    on ``[0, 2 pi)`` per frame, ``w_n`` circular complex Gaussian of variance
    ``sigma^2 = 10^(-snr_db / 10)`` per sample, so that the pulse power over the noise
    power in the bandwidth ``fs`` is ``snr_db`` (module docstring).  ``snr_db``
    broadcasts against ``bits.shape[:-1]``."""
    envelope = ppm_waveform(bits, sample_rate_hz)
    frames = envelope.shape[:-1]
    sigma = np.sqrt(10.0 ** (-np.broadcast_to(np.asarray(snr_db, float), frames) / 10.0))
    phase = np.exp(1j * rng.uniform(0.0, 2.0 * np.pi, frames))
    noise = rng.standard_normal((*envelope.shape, 2)) @ np.array([1.0, 1j]) / np.sqrt(2.0)
    return phase[..., None] * envelope + sigma[..., None] * noise


def chip_powers(
    samples: ArrayLike, sample_rate_hz: float = DEFAULT_SAMPLE_RATE_HZ
) -> NDArray[np.float64]:
    """Mean power ``|r_n|^2`` of the samples of each of the 240 chips of frames whose
    first sample is the start of the preamble (shape ``(..., 240)``).  The start is
    taken as known: the demodulator does not search for the preamble."""
    samples = np.asarray(samples)
    power = np.abs(samples[..., : N_CHIPS * samples_per_chip(sample_rate_hz)]) ** 2
    return power.reshape(*power.shape[:-1], N_CHIPS, -1).mean(axis=-1)


def demodulate(powers: ArrayLike) -> NDArray[np.uint8]:
    """PPM decisions from chip powers (shape ``(..., 240)``): bit ``k`` is 1 iff its
    first chip holds more energy than its second (DO-260B 2.2.3.1.2), shape
    ``(..., 112)``."""
    data = np.asarray(powers)[..., PREAMBLE_CHIPS.size :]
    return (data[..., 0::2] > data[..., 1::2]).astype(np.uint8)


def estimate_snr_db(powers: ArrayLike, bits: ArrayLike) -> NDArray[np.float64]:
    """SNR a receiver reports for frames with chip powers ``powers`` (``(..., 240)``)
    and decided bits ``bits`` (``(..., 112)``), in the manner of dump1090 (signal level
    from the pulses it decoded, against a noise level; Sanfilippo 2012, FlightAware
    fork): with ``P_on`` the mean power of the chips that hold a pulse by the decided
    pattern (the 4 preamble pulses and the decided chip of each bit) and ``P_off`` the
    mean power of the other 124 chips,

        SNR_hat = 10 lg(P_on / P_off).

    ``P_on`` estimates ``1 + sigma^2`` and ``P_off`` estimates ``sigma^2``, so
    ``SNR_hat`` tends to ``10 lg(SNR + 1)``: a bias of ``10 lg(1 + 1 / SNR)`` dB
    (0.41 dB at 10 dB, 0.014 dB at 25 dB) besides the spread of both means and the
    effect of wrong decisions.  (An M2M4 moment estimator cannot be used: on-off keying
    has the envelope kurtosis of noise.)"""
    on = frame_chips(bits).astype(bool)
    powers = np.asarray(powers)
    p_on = np.sum(powers * on, axis=-1) / np.sum(on, axis=-1)
    p_off = np.sum(powers * ~on, axis=-1) / np.sum(~on, axis=-1)
    return 10.0 * np.log10(p_on / p_off)


def decode(bits: ArrayLike) -> pyModeS.Decoded:
    """pyModeS decoding of 112 demodulated bits, whatever they hold (a corrupted
    downlink format decodes as another format, whose ``crc_valid`` is not True)."""
    return pyModeS.decode(bits_hex(np.asarray(bits)))


def is_received(decoded: pyModeS.Decoded) -> bool:
    """Whether a decoded frame is a DF17 frame whose parity checks (pyModeS
    ``crc_valid``, syndrome 0): the reception criterion of this module."""
    return decoded["df"] == DF_EXTENDED_SQUITTER and decoded["crc_valid"] is True


def random_messages(n: int, rng: np.random.Generator) -> NDArray[np.uint8]:
    """Bits (shape ``(n, 112)``) of ``n`` random airborne position messages: ICAO
    address uniform on 24 bits, altitude uniform on 0-45000 ft, position uniform in
    latitude (-85 to 85 deg) and longitude, even or odd CPR format with equal odds."""
    icao = rng.integers(0, 1 << 24, n)
    altitude = rng.uniform(0.0, 45000.0, n)
    lat = rng.uniform(-85.0, 85.0, n)
    lon = rng.uniform(-180.0, 180.0, n)
    odd = rng.integers(0, 2, n).astype(bool)
    return np.array(
        [
            message_bits(airborne_position_message(int(a), h, la, lo, bool(f)))
            for a, h, la, lo, f in zip(icao, altitude, lat, lon, odd, strict=True)
        ]
    ).reshape(n, N_BITS)


def simulate_receiver(
    snr_grid_db: ArrayLike = SNR_GRID_DB,
    n_messages: int = 1000,
    seed: int | np.random.SeedSequence = 0,
    sample_rate_hz: float = DEFAULT_SAMPLE_RATE_HZ,
) -> pd.DataFrame:
    """Monte Carlo of the receiver chain: at each true SNR of ``snr_grid_db``,
    ``n_messages`` random messages (:func:`random_messages`) are synthesised
    (:func:`baseband_samples`), demodulated (:func:`demodulate`), decoded by pyModeS
    and their SNR estimated (:func:`estimate_snr_db`).  Point ``k`` draws from its own
    generator, seeded with child ``k`` of ``numpy.random.SeedSequence(seed).spawn``.

    Returns one row per SNR: ``snr_db``, ``n_messages``, ``n_received`` (parity
    checks), ``reception_probability = n_received / n_messages``, and over the received
    messages ``bias_db`` (mean of estimated minus true SNR) and ``std_db`` (its sample
    standard deviation); both are NaN below 2 received messages."""
    grid = np.asarray(snr_grid_db, dtype=float)
    root = seed if isinstance(seed, np.random.SeedSequence) else np.random.SeedSequence(seed)
    rows = []
    for snr_db, child in zip(grid, root.spawn(grid.size), strict=True):
        rng = np.random.default_rng(child)
        bits = random_messages(n_messages, rng)
        powers = chip_powers(baseband_samples(bits, snr_db, rng, sample_rate_hz), sample_rate_hz)
        decided = demodulate(powers)
        received = np.array([is_received(decode(b)) for b in decided], dtype=bool)
        error = estimate_snr_db(powers[received], decided[received]) - snr_db
        enough = error.size >= 2
        rows.append(
            {
                "snr_db": snr_db,
                "n_messages": n_messages,
                "n_received": int(received.sum()),
                "reception_probability": received.mean(),
                "bias_db": error.mean() if enough else np.nan,
                "std_db": error.std(ddof=1) if enough else np.nan,
            }
        )
    return pd.DataFrame(rows)


def table_at(
    table: pd.DataFrame, true_snr_db: ArrayLike
) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
    """Reception probability, bias and standard deviation of a :func:`simulate_receiver`
    table at the true SNRs ``true_snr_db``, interpolated linearly (bias and standard
    deviation over the rows where they are defined); beyond the grid the end rows apply."""
    true_snr_db = np.asarray(true_snr_db, dtype=float)
    snr = table["snr_db"].to_numpy(float)
    defined = np.isfinite(table["bias_db"].to_numpy(float))
    p = np.interp(true_snr_db, snr, table["reception_probability"].to_numpy(float))
    bias = np.interp(true_snr_db, snr[defined], table["bias_db"].to_numpy(float)[defined])
    std = np.interp(true_snr_db, snr[defined], table["std_db"].to_numpy(float)[defined])
    return p, bias, std


def draw_snr_measurements(
    table: pd.DataFrame, true_snr_db: ArrayLike, rng: np.random.Generator
) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Fast simulation from a :func:`simulate_receiver` table: for each true SNR, a
    reception flag drawn with the probability interpolated linearly in the table, and
    for received messages a measured SNR ``true + bias + std * z`` (``z`` standard
    normal, bias and std interpolated over the rows where they are defined); NaN for
    messages not received.  Beyond the grid the end rows apply.

    >>> table = pd.DataFrame({"snr_db": [0.0, 20.0], "reception_probability": [0.0, 1.0],
    ...                       "bias_db": [np.nan, 0.1], "std_db": [np.nan, 0.0]})
    >>> draw_snr_measurements(table, [-5.0, 30.0], np.random.default_rng(0))
    (array([ nan, 30.1]), array([False,  True]))
    """
    true_snr_db = np.asarray(true_snr_db, dtype=float)
    p, bias, std = table_at(table, true_snr_db)
    received = rng.random(true_snr_db.shape) < p
    measured = true_snr_db + bias + std * rng.standard_normal(true_snr_db.shape)
    return np.where(received, measured, np.nan), received


class ReceiverChain(Parameters):
    """``[receiver.chain]`` of ``adsb-snr``: the simulated receiver chain in place of Liu
    et al. 2023's Gaussian SNR and hard threshold (``docs/adsb_receiver.md``).

    Its error table is the Monte Carlo :func:`simulate_receiver` of ``table_messages``
    messages per SNR of :data:`SNR_GRID_DB` from ``table_seed``, built once per machine
    (:func:`error_table`).  ``calibrated``: the receiver removes its estimator's known
    bias (the table's, at the measured SNR) before reporting, as a receiver calibrated on
    this table would; otherwise it reports the raw estimate.
    """

    sample_rate_hz: float = Field(
        DEFAULT_SAMPLE_RATE_HZ, gt=0.0, description="Complex sample rate (a multiple of 2 MHz)."
    )
    table_messages: int = Field(
        2000, ge=100, description="Messages per SNR of the Monte Carlo error table."
    )
    table_seed: int = Field(0, ge=0, description="Seed of the Monte Carlo error table.")
    calibrated: bool = Field(
        True, description="Whether the reported SNR has the estimator's known bias removed."
    )

    @field_validator("sample_rate_hz")
    @classmethod
    def _whole_chips(cls, rate: float) -> float:
        samples_per_chip(rate)
        return rate


@dataclass(frozen=True)
class ErrorTable:
    """A :func:`simulate_receiver` table as arrays (one entry per SNR of the grid)."""

    snr_db: NDArray[np.float64]
    reception_probability: NDArray[np.float64]
    bias_db: NDArray[np.float64]
    std_db: NDArray[np.float64]

    @property
    def frame(self) -> pd.DataFrame:
        return pd.DataFrame(
            {
                "snr_db": self.snr_db,
                "reception_probability": self.reception_probability,
                "bias_db": self.bias_db,
                "std_db": self.std_db,
            }
        )


def error_table(chain: ReceiverChain) -> ErrorTable:
    """The error table of ``chain`` (cached per process and on disk: about 9 s of one core
    at 2000 messages per SNR, once per machine)."""
    return _error_table(chain.sample_rate_hz, chain.table_messages, chain.table_seed)


@functools.lru_cache(maxsize=4)
@disk_cached
def _error_table(sample_rate_hz: float, n_messages: int, seed: int) -> ErrorTable:
    table = simulate_receiver(SNR_GRID_DB, n_messages, seed, sample_rate_hz)
    return ErrorTable(
        *(
            table[c].to_numpy(float)
            for c in ("snr_db", "reception_probability", "bias_db", "std_db")
        )
    )


def plot_table(table: pd.DataFrame, out: Path, title: str) -> None:
    """Figure of a :func:`simulate_receiver` table, written to ``out``: reception
    probability (top) and bias +- one standard deviation of the estimated SNR (bottom)
    against the true SNR."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (top, bottom) = plt.subplots(2, 1, sharex=True, figsize=(7.0, 6.0))
    top.plot(table["snr_db"], table["reception_probability"], "o-", ms=3)
    top.set_ylabel("reception probability (CRC)")
    top.set_ylim(-0.02, 1.02)
    bias, std = table["bias_db"], table["std_db"]
    bottom.fill_between(table["snr_db"], bias - std, bias + std, alpha=0.3, label="bias ± sigma")
    bottom.plot(table["snr_db"], bias, "o-", ms=3, label="bias")
    bottom.axhline(0.0, color="k", lw=0.8)
    bottom.set_xlabel("true SNR (dB)")
    bottom.set_ylabel("estimated - true SNR (dB)")
    bottom.legend(fontsize=8)
    for ax in (top, bottom):
        ax.grid(True, alpha=0.3)
    top.set_title(title)
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=150, bbox_inches="tight")
    plt.close(fig)


def main(argv: list[str] | None = None) -> pd.DataFrame:
    """Table (printed) and figure of the simulated receiver's reception probability and
    SNR error against the true SNR."""
    parser = argparse.ArgumentParser(description=main.__doc__)
    parser.add_argument("--messages", type=int, default=1000, help="messages per SNR")
    parser.add_argument("--out", type=Path, default=Path("docs/figures/adsb_receiver_snr.png"))
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--sample-rate", type=float, default=DEFAULT_SAMPLE_RATE_HZ)
    args = parser.parse_args(argv)
    table = simulate_receiver(SNR_GRID_DB, args.messages, args.seed, args.sample_rate)
    print(table.to_string(index=False, float_format=lambda x: f"{x:.3f}"))
    title = (
        f"Simulated 1090ES receiver, {args.sample_rate / 1e6:g} MHz, "
        f"{args.messages} messages per SNR (pyModeS {pyModeS.__version__})"
    )
    plot_table(table, args.out, title)
    print(f"figure: {args.out}")
    return table


if __name__ == "__main__":
    main()
