"""Gain patterns off the boresight, pinned by values worked out by hand from the papers.

Every expected number is a literal computed from the formula written in its comment
(Liu et al. 2023 eq. 63; Pimienta-Penalver and Crassidis eqs. 4-7 and 19), not from
attopt's code.  The tolerances (1e-9 dB on gains, 1e-9 relative on slopes) are far below
what a 5 % error in an exponent or in the roll-off constant ``C`` changes (at least
0.02 dB and 5 %).

Besides the gain, each case pins the slope the solvers use:

* ``dG / d alpha`` in the attitude Jacobian of
  :func:`~attopt.formulations.snr_model.predict_snr` (CasADi AD of the SNR model): with
  the boresight on body ``+z`` and the line of sight at ``alpha`` in the x-z plane, an
  attitude error ``delta`` about ``+y`` turns the line of sight to ``alpha + delta``,
  so the Jacobian is ``[0, dG / d alpha, 0]``;
* ``d cos(alpha) / d G = -sin(alpha) / (dG / d alpha)`` of the gain inversion the
  boresight solvers use (:func:`~attopt.solvers.snr.pattern_inverse.cos_from_gain`).
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from attopt.formulations.gain_patterns import (
    LIU2023_HELIX,
    GainPattern,
    ParabolicPattern,
    TabulatedPattern,
    gain_dbi_at_angle,
)
from attopt.formulations.geo_fisher import snr_attitude_jacobian
from attopt.formulations.geo_link import GARUDA1, attitude_pointing, geo_snr_db
from attopt.formulations.snr_model import predict_snr
from attopt.solvers.snr.pattern_inverse import cos_from_gain

GAIN_TOLERANCE_DB = 1e-9
SLOPE_TOLERANCE = 1e-9
"""Relative, for the AD slopes (exact derivatives)."""
INVERSE_SLOPE_TOLERANCE = 1e-6
"""Relative, for ``d cos / d G`` of the bisection inverse (a central difference)."""


def attitude_jacobian(pattern: GainPattern, alpha_deg: float) -> np.ndarray:
    """``dSNR / d delta`` (dB/rad) at the identity attitude, line of sight at ``alpha``."""
    alpha = math.radians(alpha_deg)
    los = np.array([[math.sin(alpha), 0.0, math.cos(alpha)]])
    _, jacobian = predict_snr(
        Rotation.identity(), los, np.array([0.0, 0.0, 1.0]), 0.0, 0.0, pattern
    )
    return jacobian[0]


def assert_pinned(pattern: GainPattern, alpha_deg: float, gain_dbi: float, slope: float) -> None:
    """The gain, the Jacobian's slope and the inverse's ``d cos / d G`` at ``alpha``."""
    alpha = math.radians(alpha_deg)
    assert gain_dbi_at_angle(pattern, alpha) == pytest.approx(gain_dbi, abs=GAIN_TOLERANCE_DB)
    jacobian = attitude_jacobian(pattern, alpha_deg)
    assert jacobian[1] == pytest.approx(slope, rel=SLOPE_TOLERANCE)
    assert jacobian[[0, 2]] == pytest.approx([0.0, 0.0], abs=1e-9 * abs(slope))
    cos_alpha, cos_per_db, clamped = cos_from_gain(pattern, gain_dbi)
    assert clamped == 0
    assert cos_alpha == pytest.approx(math.cos(alpha), abs=1e-12)
    expected = -math.sin(alpha) / slope
    assert cos_per_db == pytest.approx(expected, rel=INVERSE_SLOPE_TOLERANCE)


# Liu et al. 2023 eq. 63: g = 14.4598 cos^6(alpha), so
#   G = 10 lg 14.4598 + 60 lg cos(alpha) = 11.601622860777 + 60 lg cos(alpha) dBi,
#   dG/dalpha = -60 tan(alpha) / ln 10 = -26.057668494 tan(alpha) dBi/rad.
# A 5 % larger exponent (6.3) changes G by 3 lg cos(alpha): -0.020 dB at 10 deg.
@pytest.mark.parametrize(
    ("alpha_deg", "gain_dbi", "slope"),
    [
        # cos 10 = 0.984807753012, lg = -0.006648541030, x 60 = -0.398912461804;
        # tan 10 = 0.176326980708
        (10.0, 11.202710398973, -4.594670083941),
        # cos 30 = 0.866025403784, lg = -0.062469368304, x 60 = -3.748162098249;
        # tan 30 = 0.577350269190
        (30.0, 7.853460762528, -15.044402162065),
        # cos 41 = 0.754709580223, lg = -0.122220137074, x 60 = -7.333208224461;
        # tan 41 = 0.869286737816 (the main lobe ends at 41.67 deg)
        (41.0, 4.268414636315, -22.651586005516),
    ],
)
def test_helix_cos6_pattern_off_axis(alpha_deg: float, gain_dbi: float, slope: float) -> None:
    assert_pinned(LIU2023_HELIX, alpha_deg, gain_dbi, slope)


NARROW_DISH = ParabolicPattern(
    peak_gain_dbi=35.0, theta_3db_rad=math.radians(2.0), min_gain_dbi=-15.0
)
"""C = 12 dB (the default): -3 dB at half the beamwidth; main lobe to 4.08 deg."""
WIDE_LOBE = ParabolicPattern(peak_gain_dbi=11.6, theta_3db_rad=math.radians(50.0), min_gain_dbi=4.0)
"""C = 12 dB; main lobe to 39.8 deg (alpha^2 from both of its branches, below and above
11.5 deg)."""


# Pimienta-Penalver and Crassidis eq. 5: G = G_max - C (alpha / theta_3dB)^2, C = 12 dB;
#   eq. 19: dG/dalpha = -2 C alpha / theta_3dB^2 = -2 C k / theta_3dB for alpha = k theta_3dB.
# A 5 % larger C (12.6) lowers G by 0.6 k^2 dB: 0.15 dB at half the beamwidth.
@pytest.mark.parametrize(
    ("pattern", "alpha_deg", "gain_dbi", "slope"),
    [
        # theta_3dB = 2 deg = 0.034906585040 rad.  k = 0.5: 35 - 12 * 0.25 = 32;
        # slope -24 * 0.5 / 0.034906585040
        (NARROW_DISH, 1.0, 32.0, -343.774677078494),
        # k = 1: 35 - 12 = 23; slope -24 / 0.034906585040
        (NARROW_DISH, 2.0, 23.0, -687.549354156988),
        # k = 2: 35 - 12 * 4 = -13; slope -48 / 0.034906585040
        (NARROW_DISH, 4.0, -13.0, -1375.098708313976),
        # theta_3dB = 50 deg = 0.872664625997 rad.  k = 0.24: 11.6 - 12 * 0.0576 = 10.9088;
        # slope -24 * 0.24 / 0.872664625997
        (WIDE_LOBE, 12.0, 10.9088, -6.600473799907),
        # k = 0.4: 11.6 - 12 * 0.16 = 9.68; slope -24 * 0.4 / 0.872664625997
        (WIDE_LOBE, 20.0, 9.68, -11.000789666512),
        # k = 0.6: 11.6 - 12 * 0.36 = 7.28; slope -24 * 0.6 / 0.872664625997
        (WIDE_LOBE, 30.0, 7.28, -16.501184499768),
    ],
)
def test_parabolic_pattern_off_axis(
    pattern: ParabolicPattern, alpha_deg: float, gain_dbi: float, slope: float
) -> None:
    assert_pinned(pattern, alpha_deg, gain_dbi, slope)


# Four nodes (alpha = 0, 10, 20, 40 deg; G = 12, 11.2, 9, 3 dBi) at s = 1 - cos(alpha) =
# 0, 0.015192246988, 0.060307379214, 0.233955556881.  The cubic spline in s through four
# nodes, with not-a-knot ends, is the one cubic through them; solving the 4 x 4
# Vandermonde system gives
#   G(s) = 12 - 53.637946757612 s + 64.449004968629 s^2 + 1.660707160655 s^3,
#   dG/dalpha = (-53.637946757612 + 128.898009937258 s + 4.982121481964 s^2) sin(alpha).
FOUR_NODES = TabulatedPattern(
    angles_rad=tuple(np.radians([0.0, 10.0, 20.0, 40.0])), gains_dbi=(12.0, 11.2, 9.0, 3.0)
)


@pytest.mark.parametrize(
    ("alpha_deg", "gain_dbi", "slope"),
    [
        # s = 0.003805301908; dG/ds = -53.147378771701, sin = 0.087155742748
        (5.0, 11.796824752741, -4.632099271939),
        # s = 0.034074173711; dG/ds = -49.240069087287, sin = 0.258819045103
        (15.0, 10.247225458253, -12.744267661954),
        # s = 0.133974596216; dG/ds = -36.279462866084, sin = 0.5
        (30.0, 5.974678895470, -18.139731433042),
    ],
)
def test_table_of_four_nodes_between_the_nodes(
    alpha_deg: float, gain_dbi: float, slope: float
) -> None:
    assert_pinned(FOUR_NODES, alpha_deg, gain_dbi, slope)


# Nine nodes every 5 deg to 40 deg of G(s) = 12 - 40 s + 30 s^2 - 20 s^3, s = 1 - cos(alpha):
# a not-a-knot cubic spline in s reproduces a cubic in s exactly between the nodes (a
# spline in alpha would not); dG/dalpha = (-40 + 60 s - 60 s^2) sin(alpha).
CUBIC_NODES_RAD = np.radians(np.arange(0.0, 41.0, 5.0))
CUBIC_IN_VERSINE = TabulatedPattern(
    angles_rad=tuple(CUBIC_NODES_RAD),
    gains_dbi=tuple(np.polyval([-20.0, 30.0, -40.0, 12.0], 1.0 - np.cos(CUBIC_NODES_RAD))),
)


@pytest.mark.parametrize(
    ("alpha_deg", "gain_dbi", "slope"),
    [
        # s = 0.000951778418; dG/ds = -39.942947647841, sin = 0.043619387365
        (2.5, 11.961956022495, -1.742286905965),
        # s = 0.046283049252; dG/ds = -37.351544283776, sin = 0.300705799504
        (17.5, 10.210958771861, -11.231825986572),
        # s = 0.206646659709; dG/ds = -30.163370935602, sin = 0.608761429009
        (37.5, 4.838730877655, -18.362296794477),
    ],
)
def test_table_of_a_cubic_in_the_versine_between_the_nodes(
    alpha_deg: float, gain_dbi: float, slope: float
) -> None:
    assert_pinned(CUBIC_IN_VERSINE, alpha_deg, gain_dbi, slope)


SATELLITE_KM = np.array([42_164.0, 0.0, 0.0])
BELOW_KM = np.array([[6_378.0, 0.0, 0.0]])
"""A station directly below the satellite: d = h = 35,786 km."""


# Garuda-1 (Pimienta-Penalver and Crassidis Table 1: P_t = 12 kW, D = 12 m, C = 10,
# R_s = 2.4 kb/s, f = 1550 MHz; T_r = 38 K, eta = 0.55, G_r = 0 dBi):
#   lambda = 299792458 / 1.55e9 = 0.193414489032 m,
#   theta_3dB = 70 lambda / D = 70 * 0.193414489032 / 12 = 1.128251186022 deg
#             = 0.019691697986 rad,
#   G_max = 10 lg[0.55 (pi 12 / lambda)^2] = 10 lg(0.55 * 194.913587041506^2)
#         = 10 lg 20895.218527363 = 43.200469174625 dBi (eq. 4).
# On the boresight of the station below (eqs. 6-7):
#   SNR_0 = 10 lg 12000 + G_max - 20 lg(4 pi 35786e3 / lambda) - 20 lg(d / h) - 10 lg 38
#           - 10 lg 1.380649e-23 - 10 lg 2400
#         = 40.791812460476 + 43.200469174625 - 187.328680337213 - 0 - 15.797835966168
#           + 228.599167173218 - 33.802112417116 = 75.662820087822 dB.
# Off the boresight by theta_b (eq. 5): G_t = G_max - 10 k^2, k = theta_b / theta_3dB, and
# SNR = SNR_0 - 10 k^2; eq. 19: dSNR/dtheta_b = -2 C theta_b / theta_3dB^2 = -20 k / theta_3dB.
# A 5 % larger C (10.5) lowers the SNR by 0.5 k^2 dB: 0.39 dB at 1 deg.
@pytest.mark.parametrize(
    ("theta_deg", "gain_dbi", "snr_db", "slope"),
    [
        # k = 0.5 / 1.128251186022 = 0.443163726478, 10 k^2 = 1.963940884655;
        # slope -20 * 0.443163726478 / 0.019691697986
        (0.5, 41.236528289970, 73.698879203167, -450.102095615601),
        # k = 0.886327452955, 10 k^2 = 7.855763538619
        (1.0, 35.344705636006, 67.807056549203, -900.204191231202),
        # k = 1.772654905910, 10 k^2 = 31.423054154474
        (2.0, 11.777415020151, 44.239765933348, -1800.408382462404),
    ],
)
def test_geo_main_lobe_and_link_budget_off_axis(
    theta_deg: float, gain_dbi: float, snr_db: float, slope: float
) -> None:
    theta = math.radians(theta_deg)
    assert_pinned(GARUDA1.pattern, theta_deg, gain_dbi, slope)
    # The boresight turned by theta_b about body x away from the station below; a further
    # turn about x increases theta_b, so dSNR/d delta = [eq. 19, 0, 0].
    tilted = Rotation.from_rotvec([theta, 0.0, 0.0]) * attitude_pointing(-SATELLITE_KM)
    snr = geo_snr_db(tilted.as_matrix(), SATELLITE_KM, BELOW_KM)
    assert snr[0] == pytest.approx(snr_db, abs=GAIN_TOLERANCE_DB)
    _, jacobian = snr_attitude_jacobian(tilted, SATELLITE_KM, BELOW_KM)
    assert jacobian[0, 0] == pytest.approx(slope, rel=SLOPE_TOLERANCE)
    assert jacobian[0, 1:] == pytest.approx([0.0, 0.0], abs=1e-9 * abs(slope))
