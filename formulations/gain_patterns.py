"""Receive-antenna gain patterns ``G(alpha)`` in dBi, main lobe only.

``alpha`` is the off-boresight angle (Liu et al. 2023 eq. 5).  Every pattern is
evaluated from two numbers computed accurately by the SNR model:

* ``cos_alpha = l . b``, accurate near 90 degrees, and
* ``versine = 1 - cos(alpha) = |l - b|^2 / 2`` (unit ``l``, ``b``), accurate
  near 0 degrees, where ``1 - l . b`` would cancel.

Patterns are written with the :mod:`attopt.formulations.symbolic` namespaces, so one
definition serves numpy and CasADi, and none of them uses ``arccos``: their
derivatives stay finite at ``alpha = 0``.  Each pattern states its main lobe
(``max_off_boresight_rad`` and ``min_cos``): the region where it is valid and
where the gain decreases monotonically with ``alpha``, as the attitude model
of Liu et al. 2023 sec. 2 requires.

* :class:`CosinePowerPattern`: ``g = g_max cos^n(alpha)`` (Liu et al. 2023 eq. 63).
* :class:`ParabolicPattern`: ``G = G_max - C (alpha / theta_3dB)^2`` dB
  (Pimienta-Penalver and Crassidis eq. 5).
* :class:`TabulatedPattern`: measured gain in dBi against ``alpha``, smooth
  cubic B-spline in ``1 - cos(alpha)``.

Antennas with different patterns: :class:`AntennaPatterns` holds one pattern
per antenna and evaluates each observation with the pattern of the antenna
that received it (an index per observation, an input of the compiled
functions, so one function serves every assignment of observations to
antennas).  :func:`shared_pattern` reduces patterns that are all equal to
the one pattern, so an epoch whose antennas share a pattern takes exactly the
single-pattern path.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any, Protocol

import casadi as ca
import numpy as np
from numpy.typing import ArrayLike, NDArray

from attopt.formulations.errors import InvalidObservationError
from attopt.formulations.symbolic import NUMPY, ArrayNamespace


class GainPattern(Protocol):
    """A main-lobe gain pattern, symmetric about the boresight."""

    @property
    def peak_gain_dbi(self) -> float:
        """Gain on the boresight (dBi)."""
        ...

    @property
    def max_off_boresight_rad(self) -> float:
        """Edge of the main lobe: largest valid off-boresight angle (rad)."""
        ...

    @property
    def min_cos(self) -> float:
        """``cos`` of the main-lobe edge: valid where ``cos(alpha) >= min_cos``."""
        ...

    def gain_dbi(self, cos_alpha: Any, versine: Any, xp: ArrayNamespace) -> Any:
        """Gain (dBi) from ``cos(alpha)`` and ``1 - cos(alpha)`` (same shape)."""
        ...


# arcsin(z)^2 = 1/2 sum_{n>=1} (2z)^(2n) / (n^2 C(2n, n)); with z^2 = x = sin^2(alpha/2):
# alpha^2 = 4 arcsin(sqrt x)^2 = sum_n 2 (4x)^n / (n^2 C(2n, n)).  Successive terms
# shrink by about x, so ten terms are exact to double precision for x < 0.01.
_SERIES_LIMIT = 0.01
_SERIES = tuple(2.0 * 4.0**n / (n * n * math.comb(2 * n, n)) for n in range(1, 11))


def off_boresight_angle_squared(versine: Any, xp: ArrayNamespace) -> Any:
    """``alpha^2`` (rad^2) as a smooth function of ``versine = 1 - cos(alpha)``.

    ``alpha^2`` is analytic in the versine at ``alpha = 0`` (``~ 2 (1 - cos alpha)``)
    whereas ``alpha`` itself has a kink there.  With ``x = versine / 2 = sin^2(alpha/2)``
    a power series is used for ``x < 0.01`` (``alpha < 11.5 deg``) and
    ``alpha = 2 atan2(sqrt x, sqrt(1 - x))`` above; the argument of the second
    branch is clamped so that neither branch, nor its derivative, is evaluated
    where it is singular (CasADi evaluates both branches of ``if_else``).
    """
    x = 0.5 * versine
    series = _SERIES[-1]
    for coefficient in reversed(_SERIES[:-1]):
        series = series * x + coefficient
    series = series * x
    x_far = xp.fmax(x, _SERIES_LIMIT)
    alpha_far = 2.0 * xp.atan2(xp.sqrt(x_far), xp.sqrt(xp.fmax(1.0 - x_far, 0.0)))
    return xp.where(x < _SERIES_LIMIT, series, alpha_far**2)


def gain_dbi_at_angle(pattern: GainPattern, alpha_rad: ArrayLike) -> NDArray[np.float64]:
    """Evaluate ``pattern`` at off-boresight angles (rad) with numpy."""
    alpha = np.asarray(alpha_rad, dtype=float)
    return pattern.gain_dbi(np.cos(alpha), 2.0 * np.sin(0.5 * alpha) ** 2, NUMPY)


def _require(condition: bool, message: str) -> None:
    if not condition:
        raise InvalidObservationError(message)


@dataclass(frozen=True)
class CosinePowerPattern:
    """``g(alpha) = peak_gain cos^exponent(alpha)`` (linear), Liu et al. 2023 eq. 63.

    The main lobe is where ``G = 10 lg g >= min_gain_dbi``; Liu et al. 2023 sec. 5.1
    uses ``G >= 4 dBi`` for its helix, ``g = 14.4598 cos^6 alpha``
    (:data:`LIU2023_HELIX`, main lobe to 41.7 deg).  The pattern is a function
    of ``cos(alpha)`` alone: ``G = 10 lg(peak_gain) + 10 n lg(cos alpha)``.

    Example::

        >>> import numpy as np
        >>> from attopt import CosinePowerPattern
        >>> helix = CosinePowerPattern(peak_gain=14.4598, exponent=6.0, min_gain_dbi=4.0)
        >>> round(helix.peak_gain_dbi, 2), round(float(np.degrees(helix.max_off_boresight_rad)), 1)
        (11.6, 41.7)
    """

    peak_gain: float
    """Linear boresight gain (14.4598 in Liu et al. 2023 eq. 63)."""
    exponent: float
    """Power of ``cos(alpha)`` (6 in Liu et al. 2023 eq. 63)."""
    min_gain_dbi: float
    """Main-lobe edge (4 dBi in Liu et al. 2023 sec. 5.1)."""

    def __post_init__(self) -> None:
        _require(self.peak_gain > 0 and self.exponent > 0, f"bad cos^n pattern {self}")
        _require(self.min_gain_dbi < self.peak_gain_dbi, f"main lobe is empty for {self}")

    @property
    def peak_gain_dbi(self) -> float:
        return 10.0 * math.log10(self.peak_gain)

    @property
    def min_cos(self) -> float:
        """``(10^(G_min/10) / g_max)^(1/n)``: where ``G = min_gain_dbi``."""
        return (10.0 ** (self.min_gain_dbi / 10.0) / self.peak_gain) ** (1.0 / self.exponent)

    @property
    def max_off_boresight_rad(self) -> float:
        return math.acos(self.min_cos)

    def gain_dbi(self, cos_alpha: Any, versine: Any, xp: ArrayNamespace) -> Any:
        return self.peak_gain_dbi + 10.0 * self.exponent * xp.log10(cos_alpha)


@dataclass(frozen=True)
class ParabolicPattern:
    """``G = G_max - C (alpha / theta_3dB)^2`` dB, Pimienta-Penalver and Crassidis eq. 5.

    With ``theta_3db_rad`` the full half-power beamwidth, ``C = 12`` dB puts
    the -3 dB points at ``alpha = theta_3dB / 2`` (the usual convention,
    e.g. Maral and Bousquet); with ``theta_3dB`` the half-power off-boresight
    angle, as Pimienta-Penalver and Crassidis word it, ``C = 3``.  Their Table 1
    uses ``C = 10``.
    The main lobe ends where ``G = min_gain_dbi``, i.e. at
    ``theta_3dB sqrt((G_max - G_min) / C)`` (at most 180 deg).
    ``alpha^2`` comes from :func:`off_boresight_angle_squared`, smooth at 0.

    Example::

        >>> import numpy as np
        >>> from attopt import ParabolicPattern
        >>> dish = ParabolicPattern(35.0, np.radians(2.0), min_gain_dbi=25.0)
        >>> round(float(np.degrees(dish.max_off_boresight_rad)), 3)
        1.826
    """

    peak_gain_dbi: float
    """``G_max`` (dBi)."""
    theta_3db_rad: float
    """``theta_3dB`` (rad), full half-power beamwidth when ``C = 12``."""
    min_gain_dbi: float
    """Main-lobe edge (dBi)."""
    size_factor_db: float = 12.0
    """``C`` (dB)."""

    def __post_init__(self) -> None:
        _require(self.theta_3db_rad > 0 and self.size_factor_db > 0, f"bad pattern {self}")
        _require(self.min_gain_dbi < self.peak_gain_dbi, f"main lobe is empty for {self}")
        _require(self.max_off_boresight_rad <= math.pi, f"main lobe exceeds 180 deg: {self}")

    @property
    def max_off_boresight_rad(self) -> float:
        drop = self.peak_gain_dbi - self.min_gain_dbi
        return self.theta_3db_rad * math.sqrt(drop / self.size_factor_db)

    @property
    def min_cos(self) -> float:
        return math.cos(self.max_off_boresight_rad)

    def gain_dbi(self, cos_alpha: Any, versine: Any, xp: ArrayNamespace) -> Any:
        alpha2 = off_boresight_angle_squared(versine, xp)
        return self.peak_gain_dbi - self.size_factor_db * alpha2 / self.theta_3db_rad**2


@dataclass(frozen=True)
class TabulatedPattern:
    """Gain (dBi) tabulated against ``alpha`` (rad) from the boresight to the lobe edge.

    Interpolated by a cubic B-spline through the table in the variable
    ``s = 1 - cos(alpha)`` (a CasADi ``interpolant(..., "bspline")``): a
    symmetric pattern is a smooth function of ``s``, so the slope is zero on the
    boresight and finite everywhere.  numpy evaluates the same CasADi function,
    so both back-ends give identical values.  The main lobe is the table's
    range, ``[0, angles_rad[-1]]``.  Beyond it (where the interpolant itself is
    0) the gain continues along the tangent at the edge,
    ``G(s_edge) + G'(s_edge) (s - s_edge)``: as the formula patterns do, it
    stays continuous and differentiable for an estimator's trial attitudes that
    move an observation just outside the lobe.

    Example::

        >>> import numpy as np
        >>> from attopt import TabulatedPattern
        >>> measured = TabulatedPattern(
        ...     angles_rad=tuple(np.radians([0.0, 10.0, 20.0, 30.0, 40.0])),
        ...     gains_dbi=(12.0, 11.2, 9.0, 6.5, 3.0),
        ... )
        >>> measured.peak_gain_dbi, round(float(np.degrees(measured.max_off_boresight_rad)), 1)
        (12.0, 40.0)
    """

    angles_rad: tuple[float, ...]
    """Off-boresight angles, strictly increasing from 0, at most pi; at least 4."""
    gains_dbi: tuple[float, ...]
    """Gain at each angle (dBi)."""

    def __post_init__(self) -> None:
        angles = np.asarray(self.angles_rad, dtype=float)
        gains = np.asarray(self.gains_dbi, dtype=float)
        _require(angles.ndim == 1 and angles.shape == gains.shape, "table shapes differ")
        _require(angles.size >= 4, "a cubic spline needs at least 4 table points")
        _require(bool(np.isfinite(angles).all() and np.isfinite(gains).all()), "table has NaN")
        _require(angles[0] == 0.0, "table must start on the boresight (alpha = 0)")
        _require(bool(np.all(np.diff(angles) > 0)), "angles must increase strictly")
        _require(angles[-1] <= math.pi, "angles must not exceed pi")
        object.__setattr__(self, "angles_rad", tuple(angles.tolist()))
        object.__setattr__(self, "gains_dbi", tuple(gains.tolist()))

    @cached_property
    def versines(self) -> NDArray[np.float64]:
        """The table's angles as ``s = 1 - cos(alpha) = 2 sin^2(alpha / 2)``."""
        return 2.0 * np.sin(0.5 * np.asarray(self.angles_rad)) ** 2

    @cached_property
    def spline(self) -> ca.Function:
        """CasADi B-spline ``G(s)`` with ``s = 1 - cos(alpha)``."""
        return ca.interpolant("gain_table", "bspline", [self.versines], list(self.gains_dbi))

    @property
    def peak_gain_dbi(self) -> float:
        return self.gains_dbi[0]

    @property
    def max_off_boresight_rad(self) -> float:
        return self.angles_rad[-1]

    @property
    def min_cos(self) -> float:
        return math.cos(self.max_off_boresight_rad)

    @cached_property
    def edge(self) -> tuple[float, float]:
        """``s_edge = 1 - cos(angles_rad[-1])`` and the slope ``dG/ds`` there (dB)."""
        edge = float(self.versines[-1])
        s = ca.SX.sym("s")
        slope = ca.Function("slope", [s], [ca.jacobian(self.spline(s), s)])
        return edge, float(slope(edge))

    def gain_dbi(self, cos_alpha: Any, versine: Any, xp: ArrayNamespace) -> Any:
        edge, slope = self.edge
        inside = -xp.fmax(-versine, -edge)
        return xp.apply(self.spline, inside) + slope * xp.fmax(versine - edge, 0.0)


@dataclass(frozen=True)
class AntennaPatterns:
    """One gain pattern per antenna: observation ``k`` has the gain of
    ``patterns[antenna_k]``, the pattern of the antenna that received it.

    :meth:`gain_dbi` evaluates every pattern on every observation (one
    expression for any assignment of observations to antennas), each at the
    observation's angle where the observation is that antenna's and on the
    boresight (``cos alpha = 1``, ``versine = 0``, where every pattern is
    finite and smooth) elsewhere, then selects: no pattern is evaluated
    outside its domain (e.g. ``lg cos alpha`` of a cos^n pattern beyond 90 deg
    for an observation of a wider antenna), in numpy or CasADi.  ``antenna`` is
    an integer array (numpy) or a column of antenna indices (CasADi, as floats).

    Example::

        >>> import numpy as np
        >>> from attopt.formulations.gain_patterns import AntennaPatterns, ParabolicPattern
        >>> from attopt.formulations.gain_patterns import LIU2023_HELIX
        >>> from attopt.formulations.symbolic import NUMPY
        >>> dish = ParabolicPattern(20.0, np.radians(20.0), min_gain_dbi=10.0)
        >>> both = AntennaPatterns((LIU2023_HELIX, dish))
        >>> antenna = np.array([0, 1])
        >>> both.gain_dbi(np.ones(2), np.zeros(2), antenna, NUMPY).round(2).tolist()
        [11.6, 20.0]
        >>> np.degrees(both.max_off_boresight_rad(antenna)).round(1).tolist()
        [41.7, 18.3]
    """

    patterns: tuple[GainPattern, ...]
    """The pattern of antenna ``i`` at index ``i``."""

    def __post_init__(self) -> None:
        object.__setattr__(self, "patterns", tuple(self.patterns))
        _require(len(self.patterns) >= 1, "AntennaPatterns needs at least one pattern")

    def __len__(self) -> int:
        return len(self.patterns)

    def gain_dbi(self, cos_alpha: Any, versine: Any, antenna: Any, xp: ArrayNamespace) -> Any:
        """Gain (dBi) of each observation with its antenna's pattern (class docstring)."""
        gain = None
        for index, pattern in enumerate(self.patterns):
            mine = antenna == index
            cos_mine = xp.where(mine, cos_alpha, 1.0)
            value = pattern.gain_dbi(cos_mine, xp.where(mine, versine, 0.0), xp)
            gain = value if gain is None else xp.where(mine, value, gain)
        return gain

    def min_cos(self, antenna: ArrayLike) -> NDArray[np.float64]:
        """``cos`` of the main-lobe edge of each observation's antenna (numpy)."""
        return np.array([p.min_cos for p in self.patterns])[np.asarray(antenna, dtype=np.intp)]

    def max_off_boresight_rad(self, antenna: ArrayLike) -> NDArray[np.float64]:
        """Edge of the main lobe of each observation's antenna (rad, numpy)."""
        edges = np.array([p.max_off_boresight_rad for p in self.patterns])
        return edges[np.asarray(antenna, dtype=np.intp)]


def shared_pattern(patterns: Sequence[GainPattern]) -> GainPattern | AntennaPatterns:
    """The one pattern if every antenna has the same (equal by value), else
    :class:`AntennaPatterns` of them.

    Example::

        >>> from attopt.formulations.gain_patterns import LIU2023_HELIX, shared_pattern
        >>> shared_pattern([LIU2023_HELIX, LIU2023_HELIX]) is LIU2023_HELIX
        True
    """
    patterns = tuple(patterns)
    _require(len(patterns) >= 1, "at least one gain pattern is needed")
    if all(p == patterns[0] for p in patterns[1:]):
        return patterns[0]
    return AntennaPatterns(patterns)


LIU2023_HELIX = CosinePowerPattern(peak_gain=14.4598, exponent=6.0, min_gain_dbi=4.0)
"""The helix of Liu et al. 2023 eq. 63, main lobe ``G >= 4 dBi`` (sec. 5.1)."""
