"""Tests of the 1090ES collision and capture model (experiments/environment/adsb_collisions.py).

Monte Carlo fractions are compared with the analytic probabilities within a binomial
interval of ``Z`` standard deviations; every random draw is seeded.  The outcomes of
overlapping messages are dependent, so the interval is approximate: over 30 other seeds
the largest deviation of these comparisons was 3.6 standard deviations.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import assume, given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray
from pydantic import ValidationError

from attopt.experiments.environment.adsb_collisions import (
    MESSAGE_DURATION_S,
    NO_CAPTURE,
    NO_COLLISIONS,
    SQUITTER_RATE_HZ,
    CaptureRule,
    CurveRow,
    aircraft_reception_probability,
    apply_capture,
    capture_probabilities,
    footprint_powers_db,
    format_table,
    no_overlap_probability,
    reception_probability,
    simulate_messages,
    surviving_message_counts,
    vulnerable_mean,
)
from attopt.formulations.link_budget import LinkBudget

T = MESSAGE_DURATION_S
Z = 4.0
"""Half-width of the Monte Carlo intervals in standard deviations."""


def binomial_half_width(p: float, n: int) -> float:
    return Z * math.sqrt(p * (1.0 - p) / n)


def window_for(n_aircraft: int, messages: int = 40_000) -> float:
    """A window long enough for about ``messages`` messages of ``n_aircraft``."""
    return messages / (SQUITTER_RATE_HZ * n_aircraft)


def brute_force_survival(
    aircraft: NDArray[np.int64], time_s: NDArray[np.float64], power_db: NDArray[np.float64], rule
) -> NDArray[np.bool_]:
    """The capture rule by the full matrix of pairs (reference for :func:`apply_capture`)."""
    power = 10.0 ** (power_db / 10.0)
    dt = time_s[:, None] - time_s[None, :]
    overlap = (np.abs(dt) < T) & (aircraft[:, None] != aircraft[None, :])
    interference = overlap.astype(float) @ power
    with np.errstate(invalid="ignore"):  # inf * 0 for an infinite margin and no overlap
        survives = ~overlap.any(axis=1) | (power >= rule.margin_ratio * interference)
    if rule.leading_only:
        survives &= ~overlap.any(axis=1) | ~(overlap & (dt > 0)).any(axis=1)
    return survives


def test_vulnerable_period_is_two_message_lengths() -> None:
    assert vulnerable_mean(1000) == pytest.approx(2 * 120e-6 * 6.2 * 1000)
    assert no_overlap_probability(1000) == pytest.approx(math.exp(-1.488))


@pytest.mark.parametrize("n_aircraft", [20, 300, 2000])
def test_no_capture_monte_carlo_matches_poisson(n_aircraft: int) -> None:
    rng = np.random.default_rng(n_aircraft)
    powers = rng.uniform(-20.0, 0.0, n_aircraft)
    messages = simulate_messages(powers, NO_CAPTURE, rng, window_s=window_for(n_aircraft))
    p = float(no_overlap_probability(n_aircraft - 1))
    n = messages.survives.size
    assert abs(np.mean(messages.survives) - p) < binomial_half_width(p, n)


def test_two_level_powers_capture_matches_monte_carlo() -> None:
    """Half the aircraft 12 dB weaker: a strong message survives up to 6 weak
    interferers (``10 lg 6 - 12 = -4.2 dB``) and no strong one, a weak one no overlap."""
    rng = np.random.default_rng(1)
    n_aircraft = 1000
    powers = np.where(np.arange(n_aircraft) % 2 == 0, 0.0, -12.0)
    rule = CaptureRule(capture_margin_db=4.0)
    strong, weak = reception_probability([0.0, -12.0], powers, n_aircraft - 1, rule, rng)
    mu = float(vulnerable_mean(n_aircraft - 1))
    exact_strong = sum(math.exp(-mu) * mu**k / math.factorial(k) * 0.5**k for k in range(7))
    assert strong == pytest.approx(exact_strong, abs=0.005)
    assert weak == pytest.approx(math.exp(-mu), rel=1e-12)
    messages = simulate_messages(powers, rule, rng, window_s=window_for(n_aircraft))
    is_strong = messages.aircraft % 2 == 0
    for p, mask in ((strong, is_strong), (weak, ~is_strong)):
        observed = np.mean(messages.survives[mask])
        assert abs(observed - p) < binomial_half_width(p, int(mask.sum()))


@pytest.mark.parametrize("leading_only", [False, True])
def test_spread_of_powers_capture_matches_monte_carlo(leading_only: bool) -> None:
    rng = np.random.default_rng(2)
    n_aircraft = 800
    powers = rng.uniform(-20.0, 0.0, n_aircraft)
    rule = CaptureRule(capture_margin_db=3.0, leading_only=leading_only)
    messages = simulate_messages(powers, rule, rng, window_s=window_for(n_aircraft))
    per_aircraft = reception_probability(powers, powers, n_aircraft - 1, rule, rng)
    p = float(np.mean(per_aircraft[messages.aircraft]))
    half_width = binomial_half_width(p, messages.survives.size)
    assert abs(np.mean(messages.survives) - p) < half_width
    assert p - float(no_overlap_probability(n_aircraft - 1)) > 3 * half_width  # capture matters


def test_message_without_neighbours_always_survives() -> None:
    aircraft = np.array([0, 1, 2, 2])
    time_s = np.array([0.0, 1e-3, 2e-3, 2e-3 + 50e-6])  # the last two: one aircraft
    power_db = np.array([-30.0, 0.0, -10.0, 5.0])
    for rule in (NO_CAPTURE, CaptureRule(), CaptureRule(leading_only=True)):
        assert apply_capture(aircraft, time_s, power_db, rule).all()


def test_overlapping_messages_of_two_aircraft() -> None:
    aircraft = np.array([0, 1])
    time_s = np.array([0.0, 100e-6])
    assert not apply_capture(aircraft, time_s, np.array([0.0, 0.0]), NO_CAPTURE).any()
    strong_first = apply_capture(aircraft, time_s, np.array([0.0, -5.0]), CaptureRule())
    strong_last = np.array([0.0, 5.0])
    assert strong_first.tolist() == [True, False]
    assert apply_capture(aircraft, time_s, strong_last, CaptureRule()).tolist() == [False, True]
    leading = CaptureRule(leading_only=True)
    assert not apply_capture(aircraft, time_s, strong_last, leading).any()


@settings(max_examples=200, deadline=None)
@given(
    times=st.lists(st.floats(0.0, 1e-3), min_size=1, max_size=30, unique=True),
    data=st.data(),
    margin_db=st.sampled_from([-math.inf, 0.0, 3.0, 4.0, 10.0, math.inf]),
    leading_only=st.booleans(),
)
def test_capture_matches_brute_force(
    times: list[float], data: st.DataObject, margin_db: float, leading_only: bool
) -> None:
    n = len(times)
    time_s = np.sort(np.array(times))
    aircraft = np.array(data.draw(st.lists(st.integers(0, 5), min_size=n, max_size=n)))
    power_db = np.array(data.draw(st.lists(st.floats(-20.0, 0.0), min_size=n, max_size=n)))
    gaps = np.abs(time_s[:, None] - time_s[None, :])
    assume(np.all(np.abs(gaps - T) > 1e-12))
    rule = CaptureRule(capture_margin_db=margin_db, leading_only=leading_only)
    expected = brute_force_survival(aircraft, time_s, power_db, rule)
    if math.isfinite(margin_db):
        power = 10.0 ** (power_db / 10.0)
        overlap = (gaps < T) & (aircraft[:, None] != aircraft[None, :])
        interference = overlap.astype(float) @ power
        ratio_db = 10.0 * np.log10(power[interference > 0] / interference[interference > 0])
        assume(np.all(np.abs(ratio_db - margin_db) > 1e-6))
    assert apply_capture(aircraft, time_s, power_db, rule).tolist() == expected.tolist()


def test_huge_margin_reduces_to_no_capture() -> None:
    powers = np.random.default_rng(3).uniform(-20.0, 0.0, 500)
    huge = CaptureRule(capture_margin_db=1000.0)
    a = simulate_messages(powers, huge, np.random.default_rng(4), window_s=2.0)
    b = simulate_messages(powers, NO_CAPTURE, np.random.default_rng(4), window_s=2.0)
    assert a.survives.tolist() == b.survives.tolist()
    assert not a.survives.all()
    p = reception_probability(powers, powers, 499, huge, np.random.default_rng(5))
    np.testing.assert_allclose(p, no_overlap_probability(499), rtol=1e-12)


@pytest.mark.parametrize("rule", [CaptureRule(capture_margin_db=-math.inf), NO_COLLISIONS])
def test_everything_survives_without_effective_collisions(rule: CaptureRule) -> None:
    powers = np.random.default_rng(6).uniform(-20.0, 0.0, 3000)
    messages = simulate_messages(powers, rule, np.random.default_rng(7))
    assert messages.survives.size > 15_000 and messages.survives.all()
    p = reception_probability(powers, powers, 2999, rule, np.random.default_rng(8))
    np.testing.assert_allclose(p, 1.0, rtol=1e-12)


def test_stricter_rules_keep_fewer_messages() -> None:
    powers = np.random.default_rng(9).uniform(-20.0, 0.0, 1000)
    runs = {
        name: simulate_messages(powers, rule, np.random.default_rng(10)).survives
        for name, rule in {
            "3 dB": CaptureRule(capture_margin_db=3.0),
            "6 dB": CaptureRule(capture_margin_db=6.0),
            "3 dB leading": CaptureRule(capture_margin_db=3.0, leading_only=True),
            "none": NO_CAPTURE,
        }.items()
    }
    for strict, loose in (("6 dB", "3 dB"), ("3 dB leading", "3 dB"), ("none", "6 dB")):
        assert not np.any(runs[strict] & ~runs[loose])
        assert np.sum(runs[strict]) < np.sum(runs[loose])


def test_same_seed_same_messages() -> None:
    powers = np.random.default_rng(11).uniform(-20.0, 0.0, 300)
    a, b, c = (
        simulate_messages(powers, CaptureRule(), np.random.default_rng(seed))
        for seed in (12, 12, 13)
    )
    for field in ("aircraft", "time_s", "survives"):
        np.testing.assert_array_equal(getattr(a, field), getattr(b, field))
    assert a.time_s.size != c.time_s.size or not np.array_equal(a.time_s, c.time_s)
    assert a.time_s[0] >= 0.0 and a.time_s[-1] < 1.0 and np.all(np.diff(a.time_s) >= 0.0)
    counts = [
        surviving_message_counts(powers, CaptureRule(), np.random.default_rng(14)) for _ in range(2)
    ]
    np.testing.assert_array_equal(*counts)


def test_epoch_counts_match_rate_times_reception_probability() -> None:
    rng = np.random.default_rng(15)
    n_aircraft, epochs = 1500, 8
    powers = rng.uniform(-20.0, 0.0, n_aircraft)
    rule = CaptureRule()
    counts = np.stack([surviving_message_counts(powers, rule, rng) for _ in range(epochs)])
    assert counts.shape == (epochs, n_aircraft) and counts.dtype.kind == "i"
    p = reception_probability(powers, powers, n_aircraft - 1, rule, rng)
    expected = SQUITTER_RATE_HZ * float(np.mean(p))
    assert abs(counts.mean() - expected) < Z * counts.std() / math.sqrt(counts.size)
    received = float(np.mean(counts > 0))
    p_received = float(np.mean(aircraft_reception_probability(p)))
    assert abs(received - p_received) < binomial_half_width(p_received, counts.size)


def test_single_interferer_term_is_exact() -> None:
    q = capture_probabilities(
        [0.0, -3.0], [-10.0, -5.0, 0.0], 1, 10.0**0.4, np.random.default_rng(0)
    )
    np.testing.assert_array_equal(q, [[1.0, 2.0 / 3.0], [1.0, 1.0 / 3.0]])


def test_capture_probabilities_do_not_increase_with_interferers() -> None:
    rng = np.random.default_rng(16)
    q = capture_probabilities(np.linspace(-20, 0, 50), rng.uniform(-20, 0, 500), 12, 2.0, rng)
    assert np.all(np.diff(q, axis=1) <= 0.0)


def test_margin_must_not_be_nan() -> None:
    with pytest.raises(ValidationError):
        CaptureRule(capture_margin_db=math.nan)


def test_footprint_powers_lie_between_nadir_and_horizon() -> None:
    powers = footprint_powers_db(10_000, np.random.default_rng(17))
    budget = LinkBudget()
    assert powers.max() <= budget.isotropic_power_dbw(590e3)
    assert powers.min() >= budget.isotropic_power_dbw(2810e3)
    assert powers.max() - powers.min() > 13.0


def test_table_has_a_row_per_number_of_aircraft() -> None:
    row = CurveRow(100, (0.86, 0.88, 0.87), (0.85, 0.89, 0.87), (0.99,) * 3, (0.98,) * 3)
    lines = format_table([row, row]).splitlines()
    assert len(lines) == 4
    assert lines[2].startswith("| 100 | 0.147 | 0.8600 / 0.8500 |")
    assert all(line.count("|") == 9 for line in lines)
