"""The reception threshold as part of the SNR measurement model (Liu et al. 2023 sec. 5.1).

Truncation model.  A message is decoded only when its MEASURED SNR reaches the
threshold ``tau`` (``P_SNR^req = 6 dB``, Liu et al. 2023 sec. 5.1;
:attr:`attopt.formulations.snr_problem.SnrEpoch.threshold_db`).  With the Gaussian
measurement of Liu et al. 2023 eq. 4, ``y = f(A) + nu``, ``nu ~ N(0, sigma^2)``, a
received ``y`` is therefore ``N(f, sigma^2)`` truncated below at ``tau``:

    p(y | y >= tau) = phi((y - f) / sigma) / (sigma Phi((f - tau) / sigma)),  y >= tau,

with ``phi``/``Phi`` the standard normal density and distribution.  Its
negative log-likelihood is, up to the constant ``log(sigma sqrt(2 pi))``,

    l(f; y) = 1/2 ((y - f) / sigma)^2 + log Phi((f - tau) / sigma)

(:func:`truncated_nll`): the eq. 19 term plus a term that rewards predicted
SNRs close to the threshold, which are the ones a selection on the noise
favours.  Least squares (Liu et al. 2023 eq. 19) drops the second term; for
``f - tau >> sigma`` it vanishes (``log Phi -> 0``) and the two agree.

Information.  The score of one received ``y`` with respect to ``f`` is
``(y - f) / sigma^2 - lambda / sigma`` with ``x = (f - tau) / sigma`` and the
inverse Mills ratio ``lambda = phi(x) / Phi(x)`` (``E[y | y >= tau] = f +
sigma lambda``), so its Fisher information is ``Var(y | y >= tau) / sigma^4 =
(1 - x lambda - lambda^2) / sigma^2`` (:func:`truncated_information_factor` is
the bracket: 1 far above the threshold, ``~1/x^2`` far below).  In the usual
left-truncation notation ``a = (tau - f) / sigma = -x`` this is ``(1 + a lambda
- lambda^2) / sigma^2`` with ``lambda = phi(a) / (1 - Phi(a))``.  The epoch's
information is eq. 22 with each row weighted by that factor
(:func:`truncated_fisher_information`); its inverse is the Cramer-Rao bound of
the thresholded measurements, the right bound for any estimator on them.

``log Phi`` (:func:`log_normal_cdf`) is written once for numpy and CasADi
(:mod:`attopt.formulations.symbolic`).  CasADi 3.8 has ``erf`` but no ``erfc``, and
``log((1 + erf(x / sqrt 2)) / 2)`` loses every digit for ``x << 0`` (``Phi``
below the rounding of 1) and its relative accuracy for ``x >> 0`` (``log Phi ~
-Phi(-x)``), so with ``u = |x| / sqrt 2``:

* ``|x| <= sqrt 2``: ``log1p(erf(x / sqrt 2)) - log 2``;
* ``x < -sqrt 2``: ``log Phi(x) = log(erfc(u) / 2) = -x^2 / 2 + log E(u) - log 2``;
* ``x > sqrt 2``: ``log Phi(x) = log1p(-erfc(u) / 2) = log1p(-exp(-x^2 / 2) E(u) / 2)``;

with ``E(u) = exp(u^2) erfc(u)`` (``u >= 1``) the rational approximations
of the Cephes library's ``erfc`` (S. L. Moshier, ``ndtr.c``, Cephes 2.8; the
coefficients below are Cephes' ``P, Q`` for ``1 <= u < 8`` and ``R, S`` for
``u >= 8``, relative error of ``erfc`` ~1e-14 or better on ``[1, 26.6]``).  In the
lower branch nothing is exponentiated, so ``log Phi`` stays accurate however
small ``Phi`` is; in the upper one ``exp(-x^2 / 2)`` underflows beyond
``x ~ 37.5``, where ``|log Phi| < 1e-300``.  CasADi evaluates both sides of a
branch, so each branch's argument is clamped into the range where it is
finite (and with it its derivatives); the clamps are inactive where the
branch is used.  ``tests/test_snr_truncation.py`` checks the result against
``scipy.special.log_ndtr`` on ``[-30, 30]``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from attopt.formulations.snr_model import fisher_information
from attopt.formulations.symbolic import ArrayNamespace, namespace_of

Array = NDArray[np.float64]

_SQRT_HALF = math.sqrt(0.5)
_SQRT_TWO = math.sqrt(2.0)
_LOG_TWO = math.log(2.0)
_LOG_SQRT_TWO_PI = 0.5 * math.log(2.0 * math.pi)

# Cephes erfc (ndtr.c): exp(u^2) erfc(u) = P(u) / Q(u) for 1 <= u < 8 and R(u) / S(u)
# for u >= 8; highest degree first, Q and S monic (leading 1 omitted, as in Cephes).
_CEPHES_P = (
    2.46196981473530512524e-10,
    5.64189564831068821977e-1,
    7.46321056442269912687e0,
    4.86371970985681366614e1,
    1.96520832956077098242e2,
    5.26445194995477358631e2,
    9.34528527171957607540e2,
    1.02755188689515710272e3,
    5.57535335369399327526e2,
)
_CEPHES_Q = (
    1.32281951154744992508e1,
    8.67072140885989742329e1,
    3.54937778887819891062e2,
    9.75708501743205489753e2,
    1.82390916687909736289e3,
    2.24633760818710981792e3,
    1.65666309194161350182e3,
    5.57535340817727675546e2,
)
_CEPHES_R = (
    5.64189583547755073984e-1,
    1.27536670759978104416e0,
    5.01905042251180477414e0,
    6.16021097993053585195e0,
    7.40974269950448939160e0,
    2.97886665372100240670e0,
)
_CEPHES_S = (
    2.26052863220117276590e0,
    9.39603524938001434673e0,
    1.20489539808096656605e1,
    1.70814450747565897222e1,
    9.60896809063285878198e0,
    3.36907645100081516050e0,
)
_CEPHES_SPLIT = 8.0
"""Cephes switches from ``P/Q`` to ``R/S`` at ``u = 8``."""
_BRANCH_CLAMP_U = 0.5
"""Tail branches are evaluated at ``u >= 0.5`` (they are used at ``u > 1``)."""
_MIDDLE_CLAMP_X = 2.0 * _SQRT_TWO
"""The middle branch is evaluated at ``|x| <= 2 sqrt 2`` (it is used at ``|x| <= sqrt 2``)."""
_UPPER_X = 40.0
"""Above this ``Phi(x) = 1`` and ``lambda(x) = 0`` in double precision (``exp(-x^2 / 2)``
underflows from ``x = 38.6``), so clamping ``x`` there changes no finite value and makes
``x = +inf`` exact: an epoch without a reception threshold (``tau = -inf``) is then the
untruncated Gaussian model."""


def _horner(coefficients: Sequence[float], u: Any, monic: bool = False) -> Any:
    """Polynomial with ``coefficients`` (highest degree first; a leading 1 if ``monic``)."""
    value = u + coefficients[0] if monic else coefficients[0]
    for c in coefficients[1:]:
        value = value * u + c
    return value


def _scaled_erfc(u: Any, xp: ArrayNamespace) -> Any:
    """``exp(u^2) erfc(u)`` for ``u >= 1`` (Cephes' rational approximations; positive for u > 0)."""
    near = _horner(_CEPHES_P, u) / _horner(_CEPHES_Q, u, monic=True)
    far = _horner(_CEPHES_R, u) / _horner(_CEPHES_S, u, monic=True)
    return xp.where(u < _CEPHES_SPLIT, near, far)


def log_normal_cdf(x: Any, xp: ArrayNamespace | None = None) -> Any:
    """``log Phi(x)``, accurate in relative terms for ``x << 0`` and ``x >> 0`` (module docstring).

    numpy arrays (any shape) or CasADi expressions (elementwise); ``xp``
    defaults to the namespace of ``x``.
    """
    xp = namespace_of(x) if xp is None else xp
    x = -xp.fmax(-x, -_UPPER_X)
    half_square = 0.5 * x * x
    # The tails, |x| > sqrt 2, with u = |x| / sqrt 2 > 1 and E(u) = exp(u^2) erfc(u):
    scaled = _scaled_erfc(xp.fmax(abs(x) * _SQRT_HALF, _BRANCH_CLAMP_U), xp)
    # x < -sqrt 2: log Phi(x) = log(erfc(u) / 2);
    low = -half_square + xp.log(scaled) - _LOG_TWO
    # x > sqrt 2: log Phi(x) = log(1 - erfc(u) / 2).
    high = xp.log1p(-0.5 * xp.exp(-half_square) * scaled)
    # |x| <= sqrt 2: log((1 + erf(x / sqrt 2)) / 2).
    x_middle = -xp.fmax(-xp.fmax(x, -_MIDDLE_CLAMP_X), -_MIDDLE_CLAMP_X)
    middle = xp.log1p(xp.erf(x_middle * _SQRT_HALF)) - _LOG_TWO
    return xp.where(x < -_SQRT_TWO, low, xp.where(x > _SQRT_TWO, high, middle))


def truncated_nll(measured: Any, predicted: Any, sigma_db: Any, threshold_db: Any) -> Any:
    """``1/2 ((y - f) / sigma)^2 + log Phi((f - tau) / sigma)`` per observation (module docstring).

    The negative log-likelihood of a measured SNR ``y`` received because
    ``y >= tau``, up to ``log(sigma sqrt(2 pi))``; numpy or CasADi, elementwise.
    """
    xp = namespace_of(measured, predicted, sigma_db, threshold_db)
    residual = (measured - predicted) / sigma_db
    return 0.5 * residual * residual + log_normal_cdf((predicted - threshold_db) / sigma_db, xp)


def inverse_mills_ratio(x: Any, xp: ArrayNamespace | None = None) -> Any:
    """The inverse Mills ratio ``lambda(x) = phi(x) / Phi(x)``.

    ``E[y | y >= tau] = f + sigma lambda((f - tau) / sigma)`` for a received ``y``.
    """
    xp = namespace_of(x) if xp is None else xp
    return xp.exp(-0.5 * x * x - _LOG_SQRT_TWO_PI - log_normal_cdf(x, xp))


def truncated_information_factor(
    predicted_db: Any, sigma_db: Any, threshold_db: Any, xp: ArrayNamespace | None = None
) -> Any:
    """Fisher information of a received SNR about its mean ``f``, in units of ``1 / sigma^2``.

    ``1 - x lambda - lambda^2`` with ``x = (f - tau) / sigma`` and ``lambda``
    :func:`inverse_mills_ratio`: the variance of the truncated normal over
    ``sigma^2`` (module docstring).  Below 1 near and below the threshold, 1
    far above it.  ``predicted_db`` is ``f`` (the true SNR for a bound at the
    truth, the predicted one at an estimate).
    """
    xp = namespace_of(predicted_db, sigma_db, threshold_db) if xp is None else xp
    x = -xp.fmax(-(predicted_db - threshold_db) / sigma_db, -_UPPER_X)
    mills = inverse_mills_ratio(x, xp)
    return 1.0 - x * mills - mills * mills


def truncated_fisher_information(
    jacobian: ArrayLike, predicted_db: ArrayLike, sigma_db: ArrayLike, threshold_db: float
) -> Array:
    """``F = sum_k c_k J_k^T J_k / sigma_k^2`` (rad^-2, body frame): Liu et al. 2023 eq. 22 of the
    thresholded measurements, ``c_k`` :func:`truncated_information_factor` at ``f_k``.

    ``jacobian`` ``(..., m, 3)`` and ``predicted_db`` ``(..., m)`` as from
    :func:`attopt.formulations.snr_model.predict_snr`; ``sigma_db`` broadcasts against ``(..., m)``.
    """
    predicted = np.asarray(predicted_db, dtype=float)
    sigma = np.broadcast_to(np.asarray(sigma_db, dtype=float), predicted.shape)
    factor = truncated_information_factor(predicted, sigma, float(threshold_db))
    # Row k's information is c_k / sigma_k^2, i.e. that of a standard deviation sigma_k / sqrt(c_k).
    return fisher_information(jacobian, sigma / np.sqrt(factor))
