"""Tests of the aircraft transmitter model (experiments/environment/aircraft_transmitters.py)."""

from __future__ import annotations

import itertools
import math

import erfa
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError
from scipy import integrate

from attopt.experiments.environment.aircraft_transmitters import (
    CLASS1_MIN_DBW,
    CLASS2_MIN_DBW,
    MAX_POWER_DBW,
    MONOPOLE_DIRECTIVITY,
    AircraftTransmitterParameters,
    BankSchedule,
    antenna_elevations_rad,
    body_attitude,
    draw_transmitters,
    flight_direction_ecef,
    ideal_monopole_gain,
    leo_rows,
    level_flight_gain_dbi,
    local_vertical,
    monopole_gain_dbi,
    transmitter_offset_db,
)
from attopt.experiments.environment.traffic import (
    Traffic,
    geodetic_normal,
    positions_ecef_km,
)

DEFAULT = AircraftTransmitterParameters()
HORIZON_S = 600.0


def _geodetic_position_km(latitude_deg: float, longitude_deg: float, height_km: float):
    return 1e-3 * erfa.gd2gc(
        erfa.WGS84, math.radians(longitude_deg), math.radians(latitude_deg), 1e3 * height_km
    )


def _rows(n_aircraft: int, per_aircraft: int, seed: int):
    return leo_rows(n_aircraft, per_aircraft, HORIZON_S, np.random.default_rng(seed))


def _offsets(transmitters, rows) -> np.ndarray:
    return transmitter_offset_db(
        transmitters,
        rows.aircraft,
        rows.t_s,
        rows.position_ecef_km,
        rows.heading_ecef,
        rows.los_ecef,
    )


def _sphere_mean(gain) -> float:
    """Mean over the sphere of an axisymmetric linear gain of the elevation."""
    pieces = (-0.5 * np.pi, -0.3, 0.0, 0.3, 0.5 * np.pi)
    total = sum(
        integrate.quad(lambda e: float(gain(e)) * math.cos(e), a, b, limit=200)[0]
        for a, b in itertools.pairwise(pieces)
    )
    return 0.5 * total


@settings(max_examples=20, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_ideal_gives_zero_offsets_for_every_row(seed: int) -> None:
    rng = np.random.default_rng(seed)
    transmitters = draw_transmitters(
        AircraftTransmitterParameters(power="nominal", antenna="isotropic"), 30, HORIZON_S, rng
    )
    offsets = _offsets(transmitters, leo_rows(30, 5, HORIZON_S, rng))
    assert offsets.shape == (150,)
    assert np.array_equal(offsets, np.zeros(150))
    assert np.array_equal(transmitters.power_offset_db, np.zeros(30))


def test_each_part_switches_alone_and_keeps_the_other_parts_draws() -> None:
    """``power = "nominal"`` leaves the antenna gain as the whole offset, ``antenna =
    "isotropic"`` the power's; the real sky's offset is their sum, from the same draws."""
    rows = _rows(40, 6, 3)

    def offsets(**switches) -> np.ndarray:
        parameters = AircraftTransmitterParameters(**switches)
        return _offsets(
            draw_transmitters(parameters, 40, HORIZON_S, np.random.default_rng(8)), rows
        )

    real = offsets()
    power_only = offsets(antenna="isotropic")
    antenna_only = offsets(power="nominal")
    real_power = draw_transmitters(DEFAULT, 40, HORIZON_S, np.random.default_rng(8))
    np.testing.assert_array_equal(power_only, real_power.power_offset_db[rows.aircraft])
    np.testing.assert_allclose(power_only + antenna_only, real, rtol=0, atol=1e-12)
    assert np.std(power_only) > 0.5 and np.std(antenna_only) > 1.0


def test_level_flight_gain_is_the_better_antennas() -> None:
    elevation = np.radians(np.linspace(-90.0, 90.0, 37))
    gain = level_flight_gain_dbi(elevation, DEFAULT)
    expected = np.maximum(
        monopole_gain_dbi(elevation, DEFAULT), monopole_gain_dbi(-elevation, DEFAULT)
    )
    np.testing.assert_array_equal(gain, expected)
    np.testing.assert_array_equal(gain, gain[::-1])


def test_power_offset_moments_match_the_draws() -> None:
    parameters = AircraftTransmitterParameters(class1_share=0.6)
    drawn = draw_transmitters(parameters, 100_000, HORIZON_S, np.random.default_rng(5))
    mean, sigma = parameters.power_offset_moments()
    offsets = drawn.power_offset_db
    assert mean == pytest.approx(offsets.mean(), abs=4 * offsets.std() / math.sqrt(offsets.size))
    assert sigma == pytest.approx(offsets.std(), rel=0.01)
    assert AircraftTransmitterParameters(power="nominal").power_offset_moments() == (0.0, 0.0)


def test_each_class_power_lies_in_its_range_after_cable_loss() -> None:
    parameters = AircraftTransmitterParameters(class1_share=0.5)
    t = draw_transmitters(parameters, 20_000, HORIZON_S, np.random.default_rng(1))
    assert 0.48 < np.mean(t.class1) < 0.52
    loss = t.cable_loss_db
    assert np.all((loss >= parameters.cable_loss_min_db) & (loss <= parameters.cable_loss_max_db))
    power = t.antenna_power_dbw
    np.testing.assert_allclose(power, t.output_power_dbw - loss)
    for members, low, high, annex_min in (
        (
            t.class1,
            parameters.class1_output_min_dbw,
            parameters.class1_output_max_dbw,
            CLASS1_MIN_DBW,
        ),
        (
            ~t.class1,
            parameters.class2_output_min_dbw,
            parameters.class2_output_max_dbw,
            CLASS2_MIN_DBW,
        ),
    ):
        p = power[members]
        assert np.all(p >= low - parameters.cable_loss_max_db)
        assert np.all(p <= high - parameters.cable_loss_min_db)
        # The defaults keep every antenna power within ICAO Annex 10's class limits ...
        assert np.all((p >= annex_min) & (p <= MAX_POWER_DBW))
        # ... and fill the allowed band (not a constant).
        assert np.ptp(p) > 3.0
    np.testing.assert_allclose(t.power_offset_db, power - 10.0 * math.log10(250.0))


def test_class_and_diversity_shares_follow_the_parameters() -> None:
    parameters = AircraftTransmitterParameters(
        class1_share=0.7, diversity_share_class1=0.9, diversity_share_class2=0.1
    )
    t = draw_transmitters(parameters, 40_000, HORIZON_S, np.random.default_rng(2))
    assert abs(np.mean(t.diversity[t.class1]) - 0.9) < 0.01
    assert abs(np.mean(t.diversity[~t.class1]) - 0.1) < 0.015
    default = draw_transmitters(DEFAULT, 1000, HORIZON_S, np.random.default_rng(2))
    assert default.class1.all() and default.diversity.all()


def test_ideal_monopole_peak_null_and_formula() -> None:
    assert MONOPOLE_DIRECTIVITY == pytest.approx(3.2818, abs=1e-4)
    e = np.linspace(-0.5 * np.pi, 0.5 * np.pi, 20_001)
    g = ideal_monopole_gain(e)
    peak = np.argmax(g)
    assert abs(e[peak]) < 1e-3 and g[peak] == pytest.approx(MONOPOLE_DIRECTIVITY, rel=1e-6)
    assert g[-1] == 0.0 and np.all(g[e < 0.0] == 0.0)
    theta = math.radians(60.0)  # from the axis: elevation 30 deg
    expected = (
        MONOPOLE_DIRECTIVITY * (math.cos(0.5 * math.pi * math.cos(theta)) / math.sin(theta)) ** 2
    )
    assert float(ideal_monopole_gain(math.radians(30.0))) == pytest.approx(expected, rel=1e-12)


def test_ideal_monopole_conserves_power() -> None:
    assert _sphere_mean(ideal_monopole_gain) == pytest.approx(1.0, abs=1e-6)


@pytest.mark.parametrize(
    "parameters",
    [
        DEFAULT,
        AircraftTransmitterParameters(lobe_tilt_deg=25.0, shadow_db=12.0, horizon_drop_db=3.0),
        AircraftTransmitterParameters(lobe_tilt_deg=2.0, shadow_transition_deg=5.0),
    ],
)
def test_finite_ground_plane_pattern_shape_and_power(parameters) -> None:
    gain = monopole_gain_dbi
    assert _sphere_mean(lambda e: 10.0 ** (gain(e, parameters) / 10.0)) == pytest.approx(
        1.0, abs=1e-6
    )
    e = np.radians(np.linspace(-90.0, 90.0, 18_001))
    g = gain(e, parameters)
    assert np.degrees(e[np.argmax(g)]) == pytest.approx(parameters.lobe_tilt_deg, abs=0.02)
    assert g[-1] == -np.inf  # null on the axis
    deep = e < -math.radians(parameters.shadow_transition_deg)
    np.testing.assert_allclose(g[deep], g.max() - parameters.shadow_db)
    assert float(gain(0.0, parameters)) == pytest.approx(g.max() - parameters.horizon_drop_db)


@settings(max_examples=40, deadline=None)
@given(
    latitude=st.floats(-80.0, 80.0),
    longitude=st.floats(-180.0, 180.0),
    heading=st.floats(0.0, 2.0 * np.pi),
    off_nadir=st.floats(0.5, 179.5),
)
def test_level_bottom_antenna_gain_equals_the_pattern(
    latitude: float, longitude: float, heading: float, off_nadir: float
) -> None:
    up = geodetic_normal(latitude, longitude)
    east = np.cross([0.0, 0.0, 1.0], up)
    east /= np.linalg.norm(east)
    north = np.cross(up, east)
    forward = math.cos(heading) * north + math.sin(heading) * east
    side = np.cross(up, forward)
    a = math.radians(off_nadir)
    los = -math.cos(a) * up + math.sin(a) * side
    position = _geodetic_position_km(latitude, longitude, 10.0)
    np.testing.assert_allclose(local_vertical(position), up, atol=1e-9)
    bottom, top = antenna_elevations_rad(body_attitude(local_vertical(position), forward, 0.0), los)
    assert float(bottom[0]) == pytest.approx(0.5 * math.pi - a, abs=1e-7)
    assert float(top[0]) == pytest.approx(-float(bottom[0]))
    # An aircraft without diversity, the nominal power and no turns: the offset is the
    # pattern's value at the angle from the bottom antenna's axis.
    parameters = AircraftTransmitterParameters(diversity_share_class1=0.0, turn_time_fraction=0.0)
    t = draw_transmitters(parameters, 1, HORIZON_S, np.random.default_rng(0))
    offset = transmitter_offset_db(t, [0], [0.0], position[None], forward[None], los[None])
    expected = t.power_offset_db[0] + monopole_gain_dbi(bottom, parameters)
    np.testing.assert_allclose(offset, expected)


def test_bottom_gain_toward_nadir_is_the_axis_value() -> None:
    up = geodetic_normal(45.0, 10.0)
    north = np.cross(up, np.cross([0.0, 0.0, 1.0], up))
    bottom, _ = antenna_elevations_rad(body_attitude(up, north, 0.0), -up)
    assert float(bottom[0]) == pytest.approx(0.5 * math.pi)
    assert float(monopole_gain_dbi(bottom, DEFAULT)[0]) == -np.inf


@settings(max_examples=40, deadline=None)
@given(bank_deg=st.floats(-60.0, 60.0), heading=st.floats(0.0, 2.0 * np.pi))
def test_bank_rotates_the_antenna_axis_by_the_bank_angle(bank_deg: float, heading: float) -> None:
    up = geodetic_normal(30.0, -40.0)
    east = np.cross([0.0, 0.0, 1.0], up)
    east /= np.linalg.norm(east)
    forward = math.cos(heading) * np.cross(up, east) + math.sin(heading) * east
    attitude = body_attitude(up, forward, math.radians(bank_deg))
    bottom_axis = attitude.apply([0.0, 0.0, 1.0])[0]
    cross = np.linalg.norm(np.cross(bottom_axis, -up))
    angle = math.degrees(math.atan2(cross, np.dot(bottom_axis, -up)))
    assert angle == pytest.approx(abs(bank_deg), abs=1e-9)
    assert np.dot(bottom_axis, forward) == pytest.approx(0.0, abs=1e-12)  # a roll, about x
    right = np.cross(-up, forward)
    # Right wing down (positive bank) swings the bottom antenna's axis to the left.
    assert -np.dot(bottom_axis, right) == pytest.approx(math.sin(math.radians(bank_deg)))
    bottom, _ = antenna_elevations_rad(attitude, -up)
    # arcsin keeps half the digits near 90 deg: sqrt(2 x 1e-16) rad is 1e-6 deg
    assert math.degrees(float(bottom[0])) == pytest.approx(90.0 - abs(bank_deg), abs=1e-5)


def test_bank_schedule_fraction_magnitudes_and_zero() -> None:
    parameters = AircraftTransmitterParameters(turn_time_fraction=0.1, turn_duration_s=20.0)
    schedule = BankSchedule.draw(4000, HORIZON_S, parameters, np.random.default_rng(3))
    t = np.linspace(0.0, HORIZON_S, 61)
    bank = schedule.bank_rad_at(np.arange(4000)[:, None], t[None, :])
    turning = bank != 0.0
    assert abs(np.mean(turning) - 0.1) < 0.01
    assert abs(np.mean(turning[:, 0]) - 0.1) < 0.02  # stationary at t = 0
    magnitude = np.degrees(np.abs(bank[turning]))
    assert magnitude.min() >= 10.0 and magnitude.max() <= 25.0
    assert 0.4 < np.mean(bank[turning] > 0.0) < 0.6
    # A turn lasts turn_duration_s: sampled every second, the bank stays constant in it.
    fine = schedule.bank_rad_at(np.zeros(601, dtype=int), np.arange(601.0))
    runs = np.flatnonzero(np.diff(np.concatenate([[0.0], fine != 0.0, [0.0]])))
    lengths = runs[1::2] - runs[::2]
    assert np.all(lengths[1:-1] >= 19) and np.all(lengths <= 21)
    with pytest.raises(ValueError, match="times"):
        schedule.bank_rad_at([0], [HORIZON_S + 1.0])
    level = BankSchedule.draw(
        10,
        HORIZON_S,
        AircraftTransmitterParameters(turn_time_fraction=0.0),
        np.random.default_rng(3),
    )
    assert np.all(level.bank_rad_at(np.arange(10)[:, None], t[None, :]) == 0.0)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**32 - 1))
def test_diversity_average_lies_between_top_and_bottom(seed: int) -> None:
    rng = np.random.default_rng(seed)
    rows = leo_rows(20, 4, HORIZON_S, rng)
    t = draw_transmitters(
        AircraftTransmitterParameters(diversity_mode="average"), 20, HORIZON_S, rng
    )
    attitude = body_attitude(
        local_vertical(rows.position_ecef_km),
        rows.heading_ecef,
        t.bank.bank_rad_at(rows.aircraft, rows.t_s),
    )
    bottom_rad, top_rad = antenna_elevations_rad(attitude, rows.los_ecef)
    power = t.power_offset_db[rows.aircraft]
    bottom = power + monopole_gain_dbi(bottom_rad, t.parameters)
    top = power + monopole_gain_dbi(top_rad, t.parameters)
    average = _offsets(t, rows)
    assert np.all(average >= np.minimum(bottom, top) - 1e-9)
    assert np.all(average <= np.maximum(bottom, top) + 1e-9)


def test_diversity_alternates_and_single_antenna_uses_the_bottom() -> None:
    rng = np.random.default_rng(4)
    parameters = AircraftTransmitterParameters(turn_time_fraction=0.0)
    t = draw_transmitters(parameters, 1, HORIZON_S, rng)
    up = geodetic_normal(50.0, 0.0)
    north = np.cross(up, np.cross([0.0, 0.0, 1.0], up))
    los = math.cos(math.radians(40.0)) * up + math.sin(math.radians(40.0)) * north
    epochs = np.arange(6.0)
    position = _geodetic_position_km(50.0, 0.0, 11.0)
    rows = (np.zeros(6, dtype=int), epochs, np.tile(position, (6, 1)), np.tile(north, (6, 1)))
    offsets = transmitter_offset_db(t, *rows, np.tile(los, (6, 1))) - t.power_offset_db[0]
    bottom_rad, top_rad = antenna_elevations_rad(body_attitude(up, north, 0.0), los)
    bottom = float(monopole_gain_dbi(bottom_rad, parameters)[0])
    top = float(monopole_gain_dbi(top_rad, parameters)[0])
    assert top > bottom + 10.0  # the satellite 40 deg up is in the bottom antenna's shadow
    uses_top = (epochs.astype(int) + t.alternation_bit[0]) % 2 == 1
    np.testing.assert_allclose(offsets, np.where(uses_top, top, bottom))
    single = draw_transmitters(
        parameters.model_copy(update={"diversity_share_class1": 0.0}), 1, HORIZON_S, rng
    )
    offsets = transmitter_offset_db(single, *rows, np.tile(los, (6, 1)))
    np.testing.assert_allclose(offsets - single.power_offset_db[0], bottom)


def test_same_seed_gives_identical_draws() -> None:
    parameters = AircraftTransmitterParameters(class1_share=0.6, diversity_share_class2=0.3)

    def draw(seed: int):
        return draw_transmitters(parameters, 500, HORIZON_S, np.random.default_rng(seed))

    a, b, c = draw(7), draw(7), draw(8)
    for name in ("class1", "output_power_dbw", "cable_loss_db", "diversity", "alternation_bit"):
        assert np.array_equal(getattr(a, name), getattr(b, name))
    assert np.array_equal(a.bank.start_s, b.bank.start_s)
    assert np.array_equal(a.bank.bank_rad, b.bank.bank_rad)
    assert not np.array_equal(a.output_power_dbw, c.output_power_dbw)
    rows = _rows(500, 2, 9)
    assert np.array_equal(_offsets(a, rows), _offsets(b, rows))


@pytest.mark.parametrize("mode", ["alternate", "average"])
def test_vectorised_call_equals_elementwise_calls(mode: str) -> None:
    parameters = AircraftTransmitterParameters(
        diversity_mode=mode, turn_time_fraction=0.3, class1_share=0.5, diversity_share_class2=0.5
    )
    t = draw_transmitters(parameters, 40, HORIZON_S, np.random.default_rng(5))
    rows = _rows(40, 3, 6)
    together = _offsets(t, rows)
    one_by_one = [
        transmitter_offset_db(
            t,
            rows.aircraft[i],
            rows.t_s[i],
            rows.position_ecef_km[i],
            rows.heading_ecef[i],
            rows.los_ecef[i],
        )[0]
        for i in range(rows.aircraft.size)
    ]
    np.testing.assert_allclose(together, one_by_one, rtol=0, atol=1e-12)
    assert np.any(t.bank.bank_rad_at(rows.aircraft, rows.t_s) != 0.0)


def test_flight_direction_follows_the_positions_both_ways() -> None:
    origin = geodetic_normal(40.0, -70.0)[None]
    destination = geodetic_normal(48.0, 2.0)[None]
    tangent = destination - np.sum(origin * destination) * origin
    tangent /= np.linalg.norm(tangent)
    angle = float(np.arccos(np.sum(origin * destination)))
    traffic = Traffic(
        origin=np.array(["JFK", "JFK"]),
        destination=np.array(["CDG", "CDG"]),
        origin_normal=np.repeat(origin, 2, axis=0),
        route_tangent=np.repeat(tangent, 2, axis=0),
        route_angle_rad=np.array([angle, angle]),
        start_angle_rad=np.array([0.3 * angle, 1.6 * angle]),  # second: on the way back
        height_km=np.array([10.0, 11.0]),
        speed_mps=np.array([240.0, 250.0]),
    )
    direction = flight_direction_ecef(traffic, 100.0)
    step = positions_ecef_km(traffic, 101.0) - positions_ecef_km(traffic, 99.0)
    step /= np.linalg.norm(step, axis=-1, keepdims=True)
    assert np.all(np.sum(direction * step, axis=-1) > 0.9999)


@pytest.mark.parametrize(
    "bad",
    [
        {"class1_output_min_dbw": 28.0},
        {"cable_loss_min_db": 4.0},
        {"bank_min_deg": 30.0},
        {"horizon_drop_db": 25.0},
        {"class1_share": 1.5},
        {"diversity_mode": "both"},
        {"turn_time_fraction": 1.0},
        {"lobe_tilt_deg": 0.0},
    ],
)
def test_parameters_reject_inconsistent_values(bad: dict) -> None:
    with pytest.raises(ValidationError):
        AircraftTransmitterParameters(**bad)
