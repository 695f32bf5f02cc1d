"""Inverse of a gain pattern: ``cos(alpha)`` from a gain, first step of Liu et al. 2023 sec. 3.2.

From a measured SNR, Liu et al. 2023 eq. 4 gives the gain ``G = y - 10 lg P0 + 10 lg P_n``
and, through the pattern's inverse, ``cos(alpha)`` (the cone of eq. 15 on which
the boresight lies, ``l . b = cos(alpha)``).

* :class:`~attopt.formulations.gain_patterns.CosinePowerPattern` (Liu et al. 2023 eq. 63,
  ``G = 10 lg g_max + 10 n lg cos(alpha)``): closed form
  ``cos(alpha) = 10^((G - 10 lg g_max) / (10 n))``, not clamped: a noisy gain
  above the peak gives ``cos(alpha) > 1``, the unbiased continuation of the
  law, which the least squares of :mod:`attopt.solvers.snr.boresight` then weighs.
* Any other pattern: bisection in ``s = 1 - cos(alpha)`` over the main lobe,
  where every pattern decreases monotonically (``attopt.formulations.gain_patterns``).
  Gains outside ``[G(lobe edge), G(boresight)]`` are clamped to the lobe and
  counted.

Both return ``d cos(alpha) / d G`` too, which maps the SNR noise (dB) to the
noise of ``cos(alpha)`` for weighting.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike, NDArray

from attopt.formulations.gain_patterns import CosinePowerPattern, GainPattern
from attopt.formulations.symbolic import NUMPY

Array = NDArray[np.float64]

_BISECTIONS = 60
_DERIVATIVE_STEP = 1e-7


def _gain_of_versine(pattern: GainPattern, versine: Array) -> Array:
    return np.asarray(pattern.gain_dbi(1.0 - versine, versine, NUMPY), dtype=float)


def cos_from_gain(pattern: GainPattern, gain_dbi: ArrayLike) -> tuple[Array, Array, int]:
    """``cos(alpha)``, ``d cos(alpha) / d G`` (per dB) and the number of clamped gains."""
    gain = np.asarray(gain_dbi, dtype=float)
    if isinstance(pattern, CosinePowerPattern):
        scale = math.log(10.0) / (10.0 * pattern.exponent)
        cos_alpha = np.exp((gain - pattern.peak_gain_dbi) * scale)
        return cos_alpha, cos_alpha * scale, 0
    edge = 1.0 - pattern.min_cos
    low = np.zeros_like(gain)  # versine with gain >= target
    high = np.full_like(gain, edge)  # versine with gain <= target
    for _ in range(_BISECTIONS):
        middle = 0.5 * (low + high)
        above = _gain_of_versine(pattern, middle) >= gain
        low = np.where(above, middle, low)
        high = np.where(above, high, middle)
    versine = 0.5 * (low + high)
    h = np.minimum(_DERIVATIVE_STEP, 0.5 * edge)
    plus = np.minimum(versine + h, edge)
    minus = np.maximum(versine - h, 0.0)
    slope = (_gain_of_versine(pattern, plus) - _gain_of_versine(pattern, minus)) / (plus - minus)
    clamped = int(
        np.count_nonzero(
            (gain > pattern.peak_gain_dbi) | (gain < _gain_of_versine(pattern, np.array(edge)))
        )
    )
    # d cos / d G = -d s / d G = -1 / (d G / d s); the main lobe has d G / d s < 0.
    return 1.0 - versine, -1.0 / np.minimum(slope, -np.finfo(float).tiny), clamped
