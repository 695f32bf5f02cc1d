"""Gain patterns: Liu et al. 2023 eq. 63, Pimienta-Penalver and Crassidis eq. 5, tabulated
splines; numpy = CasADi."""

from __future__ import annotations

import math

import casadi as ca
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.gain_patterns import (
    LIU2023_HELIX,
    CosinePowerPattern,
    ParabolicPattern,
    TabulatedPattern,
    gain_dbi_at_angle,
    off_boresight_angle_squared,
)
from attopt.formulations.symbolic import CASADI, NUMPY

PARABOLIC = ParabolicPattern(peak_gain_dbi=11.6, theta_3db_rad=math.radians(50.0), min_gain_dbi=4.0)
TABLE_ANGLES = np.radians(np.linspace(0.0, 41.0, 15))
TABULATED = TabulatedPattern(
    tuple(TABLE_ANGLES), tuple(gain_dbi_at_angle(LIU2023_HELIX, TABLE_ANGLES))
)
PATTERNS = {"cos6": LIU2023_HELIX, "parabolic": PARABOLIC, "tabulated": TABULATED}


def test_liu2023_helix_peak_and_main_lobe_edge():
    # Liu et al. 2023 eq. 63: g = 14.4598 cos^6(alpha); main lobe G >= 4 dBi (sec. 5.1).
    assert gain_dbi_at_angle(LIU2023_HELIX, 0.0) == pytest.approx(
        10 * math.log10(14.4598), abs=1e-12
    )
    assert LIU2023_HELIX.peak_gain_dbi == pytest.approx(11.6016, abs=1e-4)
    # Lobe edge: cos^6(alpha) = 10^0.4 / 14.4598 = 2.511886 / 14.4598 = 0.173715,
    # cos(alpha) = 0.173715^(1/6) = 0.746975, alpha = 41.671 deg.
    assert LIU2023_HELIX.min_cos**6 == pytest.approx(10**0.4 / 14.4598, rel=1e-12)
    assert LIU2023_HELIX.min_cos == pytest.approx(0.746975, abs=1e-6)
    assert math.degrees(LIU2023_HELIX.max_off_boresight_rad) == pytest.approx(41.671, abs=1e-3)
    edge = gain_dbi_at_angle(LIU2023_HELIX, LIU2023_HELIX.max_off_boresight_rad)
    assert edge == pytest.approx(4.0, abs=1e-12)


def test_cosine_power_pattern_is_ten_lg_of_liu2023_eq63():
    alpha = np.linspace(0.0, LIU2023_HELIX.max_off_boresight_rad, 50)
    expected = 10 * np.log10(14.4598 * np.cos(alpha) ** 6)
    np.testing.assert_allclose(gain_dbi_at_angle(LIU2023_HELIX, alpha), expected, atol=1e-12)


def test_parabolic_pattern_pimienta_penalver_eq5():
    # C = 12 dB with theta_3dB the full half-power beamwidth: -3 dB at theta_3dB / 2.
    theta = PARABOLIC.theta_3db_rad
    assert gain_dbi_at_angle(PARABOLIC, 0.0) == pytest.approx(11.6, abs=1e-12)
    assert gain_dbi_at_angle(PARABOLIC, theta / 2) == pytest.approx(11.6 - 3.0, abs=1e-12)
    assert gain_dbi_at_angle(PARABOLIC, theta) == pytest.approx(11.6 - 12.0, abs=1e-12)
    # Lobe edge where G = 4 dBi: theta sqrt(7.6 / 12).
    assert PARABOLIC.max_off_boresight_rad == pytest.approx(theta * math.sqrt(7.6 / 12), rel=1e-14)
    assert gain_dbi_at_angle(PARABOLIC, PARABOLIC.max_off_boresight_rad) == pytest.approx(4.0)


def test_angle_squared_is_accurate_on_both_sides_of_the_series_switch():
    alpha = np.concatenate([[0.0, 1e-12, 1e-8, 1e-4], np.linspace(0.01, 3.1, 400)])
    alpha = np.concatenate([alpha, 2 * np.arcsin(np.sqrt(0.01)) * (1 + np.array([-1e-9, 0, 1e-9]))])
    versine = 2 * np.sin(alpha / 2) ** 2
    np.testing.assert_allclose(off_boresight_angle_squared(versine, NUMPY), alpha**2, rtol=1e-14)


def test_angle_squared_derivative_is_finite_at_zero_and_matches_finite_differences():
    s = ca.SX.sym("s")
    f = ca.Function("f", [s], [off_boresight_angle_squared(s, CASADI)])
    df = ca.Function("df", [s], [ca.jacobian(f(s), s)])
    # d(alpha^2)/d(1 - cos alpha) = 2 alpha / sin(alpha) -> 2 at alpha = 0.
    assert float(df(0.0)) == pytest.approx(2.0, abs=1e-15)
    for alpha in [1e-8, 0.1, 2 * np.arcsin(0.1) - 1e-6, 2 * np.arcsin(0.1) + 1e-6, 1.0, 2.5]:
        versine = 2 * np.sin(alpha / 2) ** 2
        assert float(df(versine)) == pytest.approx(2 * alpha / np.sin(alpha), rel=1e-12)
        h = 1e-7 * max(versine, 1e-7)
        fd = (float(f(versine + h)) - float(f(versine - h))) / (2 * h)
        assert float(df(versine)) == pytest.approx(fd, rel=1e-6)


def test_tabulated_spline_passes_through_the_table_and_approximates_the_pattern():
    np.testing.assert_allclose(
        gain_dbi_at_angle(TABULATED, TABLE_ANGLES), TABULATED.gains_dbi, atol=1e-12
    )
    alpha = np.linspace(0.0, TABULATED.max_off_boresight_rad, 301)
    np.testing.assert_allclose(
        gain_dbi_at_angle(TABULATED, alpha), gain_dbi_at_angle(LIU2023_HELIX, alpha), atol=2e-3
    )
    assert TABULATED.max_off_boresight_rad == pytest.approx(math.radians(41.0))
    assert TABULATED.peak_gain_dbi == pytest.approx(LIU2023_HELIX.peak_gain_dbi)


def test_tabulated_gain_continues_along_its_tangent_beyond_the_table():
    """Beyond the table's edge (where the interpolant is 0) the gain is G(s_e) + G'(s_e)
    (s - s_e), s = 1 - cos(alpha): continuous with a continuous slope, for trial attitudes of
    an estimator that move an observation just outside the lobe; inside, the spline itself."""
    edge, slope = TABULATED.edge
    inside = np.linspace(0.0, edge, 50)
    np.testing.assert_array_equal(
        TABULATED.gain_dbi(1.0 - inside, inside, NUMPY),
        TABULATED.spline.map(50)(inside.reshape(1, -1)).full().ravel(),
    )
    at_edge = float(TABULATED.spline(edge))
    beyond = edge + np.array([1e-4, 0.01, 0.1])
    np.testing.assert_allclose(
        TABULATED.gain_dbi(1.0 - beyond, beyond, NUMPY), at_edge + slope * (beyond - edge)
    )
    h = 1e-7  # one-sided differences on either side of the edge agree with the slope
    below = (at_edge - float(TABULATED.spline(edge - h))) / h
    above = (TABULATED.gain_dbi(1.0 - edge - h, edge + h, NUMPY) - at_edge) / h
    assert slope < 0 and below == pytest.approx(slope, rel=1e-5)
    assert above == pytest.approx(slope, rel=1e-9)
    # the helix the table samples falls by about the same slope there (dB per unit s)
    helix = (10.0 * 6.0 / math.log(10.0)) / -(1.0 - edge)
    assert slope == pytest.approx(helix, rel=0.05)


@settings(max_examples=40, deadline=None)
@given(
    name=st.sampled_from(sorted(PATTERNS)),
    fractions=st.lists(st.floats(0.0, 1.0), min_size=1, max_size=12),
)
def test_numpy_and_casadi_gains_agree(name, fractions):
    pattern = PATTERNS[name]
    alpha = np.asarray(fractions) * pattern.max_off_boresight_rad
    cos_alpha, versine = np.cos(alpha), 2 * np.sin(alpha / 2) ** 2
    c = ca.SX.sym("c", alpha.size)
    s = ca.SX.sym("s", alpha.size)
    f = ca.Function("g", [c, s], [pattern.gain_dbi(c, s, CASADI)])
    symbolic = f(cos_alpha, versine).full().ravel()
    np.testing.assert_allclose(
        pattern.gain_dbi(cos_alpha, versine, NUMPY), symbolic, rtol=0, atol=1e-12
    )


def test_main_lobe_min_cos_is_cos_of_edge():
    for pattern in PATTERNS.values():
        assert pattern.min_cos == pytest.approx(math.cos(pattern.max_off_boresight_rad), rel=1e-14)


@pytest.mark.parametrize(
    "build",
    [
        lambda: CosinePowerPattern(peak_gain=14.4598, exponent=6.0, min_gain_dbi=12.0),
        lambda: CosinePowerPattern(peak_gain=-1.0, exponent=6.0, min_gain_dbi=4.0),
        lambda: ParabolicPattern(peak_gain_dbi=10.0, theta_3db_rad=0.0, min_gain_dbi=4.0),
        lambda: ParabolicPattern(peak_gain_dbi=30.0, theta_3db_rad=3.0, min_gain_dbi=0.0),
        lambda: TabulatedPattern((0.0, 0.1, 0.2), (10.0, 9.0, 8.0)),
        lambda: TabulatedPattern((0.1, 0.2, 0.3, 0.4), (10.0, 9.0, 8.0, 7.0)),
        lambda: TabulatedPattern((0.0, 0.2, 0.1, 0.4), (10.0, 9.0, 8.0, 7.0)),
        lambda: TabulatedPattern((0.0, 0.1, 0.2, 0.3), (10.0, np.nan, 8.0, 7.0)),
    ],
)
def test_bad_patterns_raise(build):
    with pytest.raises(InvalidObservationError):
        build()
