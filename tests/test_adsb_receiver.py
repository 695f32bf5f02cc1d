"""The simulated 1090ES receiver chain (experiments/environment/adsb_receiver.py):
DF17 encoding and parity against pyModeS, the PPM waveform against the DO-260B timing,
demodulation, reception by CRC, the SNR estimator and the fast interpolated draw."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pyModeS
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from attopt.experiments.environment import adsb_receiver as rx

POSITIONS = [
    # (lat, lon, altitude ft, odd): both CPR formats, both hemispheres, zone edges,
    # longitudes near +-180, the polar cap (NL = 1, 2) and the equator (NL = 59).
    (52.2572, 3.9194, 38000, False),
    (52.2572, 3.9194, 38000, True),
    (-33.9461, 151.1772, 21, True),
    (-33.9461, 151.1772, 21, False),
    (0.0, -179.999, -1000, False),
    (0.0001, 179.9999, 50175, True),
    (6.0, 0.0, 1250, False),
    (86.9, -45.0, 30000, True),
    (88.5, 120.0, 30000, False),
    (-89.9, 10.0, 45000, True),
]


def _lsb(lat: float, odd: bool) -> tuple[float, float]:
    """One CPR step (Dlat_i / 2^17, Dlon_i / 2^17) at a latitude, in degrees."""
    dlat = 360.0 / (60 - odd)
    zones = rx.cpr_longitude_zones(lat) - odd
    return dlat / 2**17, (360.0 / zones if zones > 0 else 360.0) / 2**17


def _check_round_trip(lat: float, lon: float, altitude: float, odd: bool) -> None:
    icao = 0xA1B2C3
    message = rx.airborne_position_message(icao, altitude, lat, lon, odd)
    # A reference about 20 NM from the aircraft, well inside pyModeS's 180 NM.
    reference = (lat - math.copysign(0.3, lat), lon)
    decoded = pyModeS.decode(f"{message:028X}", reference=reference)
    assert decoded["df"] == 17
    assert decoded["crc_valid"] is True
    assert decoded["icao"] == "A1B2C3"
    assert decoded["typecode"] == 11
    assert decoded["cpr_format"] == int(odd)
    assert decoded["altitude"] == 25 * round(altitude / 25)
    lat_step, lon_step = _lsb(lat, odd)
    assert abs(decoded["latitude"] - lat) <= lat_step
    dlon = (decoded["longitude"] - lon + 180.0) % 360.0 - 180.0
    assert abs(dlon) <= lon_step


@pytest.mark.parametrize(("lat", "lon", "altitude", "odd"), POSITIONS)
def test_encoder_round_trips_through_pymodes(
    lat: float, lon: float, altitude: float, odd: bool
) -> None:
    _check_round_trip(lat, lon, altitude, odd)


@settings(max_examples=60, deadline=None)
@given(
    st.floats(-89.5, 89.5),
    st.floats(-180.0, 179.999),
    st.floats(-1000.0, 50175.0),
    st.booleans(),
)
def test_encoder_round_trips_anywhere(lat: float, lon: float, altitude: float, odd: bool) -> None:
    _check_round_trip(lat, lon, altitude, odd)


def test_encoder_matches_a_published_frame() -> None:
    """The even position frame of Sun 2021 (The 1090 Megahertz Riddle)."""
    assert rx.airborne_position_message(0x40621D, 38000, 52.2572, 3.9194, False) == (
        0x8D40621D58C382D690C8AC2863A7
    )


def test_longitude_zone_counts_match_the_do260b_table() -> None:
    # DO-260B Table A-20 transition latitudes: NL = 59 below 10.47047130 deg, 58 above.
    assert rx.cpr_longitude_zones(10.47) == 59
    assert rx.cpr_longitude_zones(10.471) == 58
    assert rx.cpr_longitude_zones(-86.5354) == 2
    assert rx.cpr_longitude_zones(86.5353) == 3


def test_parity_checks_and_a_flipped_bit_fails_it() -> None:
    message = rx.airborne_position_message(0x40621D, 38000, 52.2572, 3.9194, True)
    assert rx.mode_s_parity(message, rx.N_BITS) == 0
    bits = rx.message_bits(message)
    assert rx.is_received(rx.decode(bits))
    for k in (0, 40, 87, 111):
        flipped = bits.copy()
        flipped[k] ^= 1
        assert rx.mode_s_parity(int(rx.bits_hex(flipped), 16), rx.N_BITS) != 0
        assert not rx.is_received(rx.decode(flipped))


@pytest.mark.parametrize("sample_rate_hz", [2e6, 8e6])
def test_waveform_follows_the_1090es_timing(sample_rate_hz: float) -> None:
    """Sample ``n`` (time ``n / fs``) holds a pulse iff it lies in a 0.5 us pulse that
    starts at 0, 1, 3.5 or 4.5 us, or at ``8 + k`` us (bit k = 1) or ``8.5 + k`` us
    (bit k = 0)."""
    bits = rx.message_bits(rx.airborne_position_message(0x3C6586, 12000, 48.35, 11.79, False))
    starts = [0.0, 1.0, 3.5, 4.5] + [8.0 + k + 0.5 * (1 - b) for k, b in enumerate(bits)]
    t_us = np.arange(round(120e-6 * sample_rate_hz)) / sample_rate_hz * 1e6
    expected = np.zeros(t_us.size)
    for start in starts:
        expected[(t_us >= start - 1e-9) & (t_us < start + 0.5 - 1e-9)] = 1.0
    waveform = rx.ppm_waveform(bits, sample_rate_hz)
    assert waveform.shape == (240 * round(sample_rate_hz / 2e6),)
    np.testing.assert_array_equal(waveform, expected)


@pytest.mark.parametrize("sample_rate_hz", [2e6, 8e6])
def test_noise_free_samples_demodulate_to_the_message(sample_rate_hz: float) -> None:
    bits = rx.random_messages(20, np.random.default_rng(1))
    rotated = np.exp(1j * np.linspace(0.0, 6.0, 20))[:, None] * rx.ppm_waveform(
        bits, sample_rate_hz
    )
    decided = rx.demodulate(rx.chip_powers(rotated, sample_rate_hz))
    np.testing.assert_array_equal(decided, bits)
    assert all(rx.is_received(rx.decode(b)) for b in decided)


def test_noise_has_the_stated_snr() -> None:
    """Off samples hold noise of variance 10^(-SNR/10); on samples add unit power."""
    bits = rx.random_messages(200, np.random.default_rng(2))
    samples = rx.baseband_samples(bits, 7.0, np.random.default_rng(3), 8e6)
    on = rx.ppm_waveform(bits, 8e6).astype(bool)
    sigma2 = 10.0 ** (-0.7)
    power = np.abs(samples) ** 2
    assert np.mean(power[~on]) == pytest.approx(sigma2, rel=0.02)
    assert np.mean(power[on]) == pytest.approx(1.0 + sigma2, rel=0.02)


def test_sample_rate_must_fit_whole_chips() -> None:
    with pytest.raises(ValueError, match="multiple of 2 MHz"):
        rx.samples_per_chip(2.4e6)


@pytest.fixture(scope="module")
def table() -> pd.DataFrame:
    return rx.simulate_receiver([0.0, 4.0, 10.0, 11.0, 12.0, 25.0], 400, seed=7)


def test_reception_goes_from_none_to_all(table: pd.DataFrame) -> None:
    p = table.set_index("snr_db")["reception_probability"]
    assert p[0.0] == 0.0
    assert p[4.0] <= 0.01
    assert 0.3 < p[10.0] < 0.95  # the CRC threshold region at 2 MHz
    assert p[25.0] == 1.0
    assert np.all(np.diff(p.to_numpy()) >= -0.05)


def test_reception_matches_the_bit_error_rate(table: pd.DataFrame) -> None:
    """At 2 MHz a bit is wrong when the noise power of its empty chip exceeds the power
    of its pulse chip, with probability ``P_b = exp(-SNR / 2) / 2`` (non-coherent
    comparison of two exponential powers); a frame passes its CRC iff all 112 bits are
    right (an undetected error has probability below 2^-24)."""
    for snr_db in (10.0, 11.0, 12.0):
        p = table.set_index("snr_db").loc[snr_db, "reception_probability"]
        expected = (1.0 - 0.5 * math.exp(-(10.0 ** (snr_db / 10.0)) / 2.0)) ** 112
        assert abs(p - expected) <= 4.0 * math.sqrt(expected * (1.0 - expected) / 400)


def test_estimator_bias_vanishes_at_high_snr(table: pd.DataFrame) -> None:
    """At 25 dB the expected bias is about 0.03 dB (10 lg(1 + 1/SNR) plus the log of a
    mean of 124 noise powers); its Monte Carlo error with 400 messages is 0.02 dB."""
    rows = table.set_index("snr_db")
    assert abs(rows.loc[25.0, "bias_db"]) < 0.1
    assert abs(rows.loc[25.0, "bias_db"]) < abs(rows.loc[10.0, "bias_db"])
    # 124 off chips of one sample each: std of 10 lg(mean power) ~ 4.34 / sqrt(124).
    assert rows.loc[25.0, "std_db"] == pytest.approx(4.343 / math.sqrt(124), rel=0.15)


def test_same_seed_same_table(table: pd.DataFrame) -> None:
    again = rx.simulate_receiver([0.0, 4.0, 10.0, 11.0, 12.0, 25.0], 400, seed=7)
    pd.testing.assert_frame_equal(again, table)
    other = rx.simulate_receiver([10.0], 400, seed=8)
    assert other["bias_db"].iloc[0] != table["bias_db"].iloc[2]


def test_fast_draw_reproduces_the_table(table: pd.DataFrame) -> None:
    n = 40_000
    rng = np.random.default_rng(9)
    for snr_db in (10.0, 12.0, 25.0):
        row = table.set_index("snr_db").loc[snr_db]
        measured, received = rx.draw_snr_measurements(table, np.full(n, snr_db), rng)
        p = row["reception_probability"]
        assert abs(received.mean() - p) <= 4.0 * math.sqrt(p * (1.0 - p) / n) + 1e-12
        assert np.array_equal(np.isnan(measured), ~received)
        error = measured[received] - snr_db
        assert abs(error.mean() - row["bias_db"]) <= 4.0 * row["std_db"] / math.sqrt(error.size)
        assert error.std() == pytest.approx(row["std_db"], rel=0.03)
    # Between grid points the draw interpolates, and below the grid nothing is received.
    _, received = rx.draw_snr_measurements(table, np.full(n, 10.5), rng)
    p10, p11 = table.set_index("snr_db").loc[[10.0, 11.0], "reception_probability"]
    assert abs(received.mean() - (p10 + p11) / 2) < 0.02
    _, received = rx.draw_snr_measurements(table, np.full(n, -3.0), rng)
    assert not received.any()


def test_estimator_is_the_on_over_off_power_ratio() -> None:
    bits = rx.message_bits(rx.airborne_position_message(0x3C6586, 12000, 48.35, 11.79, True))
    powers = np.where(rx.frame_chips(bits) == 1, 2.0, 0.5)
    assert rx.estimate_snr_db(powers, bits) == pytest.approx(10.0 * math.log10(4.0))
    # Off chips are averaged as a whole: doubling one of the 124 raises P_off by 1/124.
    powers[np.flatnonzero(rx.frame_chips(bits) == 0)[5]] = 1.0
    expected = 10.0 * math.log10(2.0 / (0.5 + 0.5 / 124))
    assert rx.estimate_snr_db(powers, bits) == pytest.approx(expected)


def test_estimator_bias_matches_its_expectation() -> None:
    """At 10 dB and 8 MHz every message is received and E[SNR_hat] is 10 lg(SNR + 1) =
    10.414 dB plus 0.004 dB from the log of the mean of 496 off-chip noise samples; the
    Monte Carlo error with 400 messages is 0.011 dB."""
    row = rx.simulate_receiver([10.0], 400, seed=11, sample_rate_hz=8e6).iloc[0]
    assert row["reception_probability"] == 1.0
    assert row["bias_db"] == pytest.approx(10.0 * math.log10(1.1) + 0.004, abs=0.05)
