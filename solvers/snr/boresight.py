"""Boresight direction in the orbit frame from off-boresight cones (Liu et al. 2023 secs. 3.1-3.2).

Each observation of an antenna gives ``l_k . b = c_k`` (Liu et al. 2023 eqs. 5, 7, 15)
with ``l_k`` the unit line of sight and ``c_k = cos(alpha_k)`` from the
pattern inverse (:mod:`attopt.solvers.snr.pattern_inverse`), with standard deviation
``sigma_k``.  The boresight ``b`` (orbit frame) is the constrained weighted
least-squares solution

    ``min_b sum_k (l_k . b - c_k)^2 / sigma_k^2   subject to |b| = 1``,

the maximum-likelihood direction to first order in the noise, rather than the
unconstrained linear solution normalised afterwards (which lets the noise
change ``|b|`` and then discards that information).  With
``M = L^T W L = V diag(s) V^T`` and ``g = L^T W c``, the minimiser is
``b = (M - lambda I)^-1 g`` with the unique ``lambda < s_min`` where ``|b| = 1``
(a trust-region boundary problem); the secular equation is solved by Brent's
method in ``t = s_min - lambda``.  Noise-free cones give ``lambda = 0`` and
the exact boresight.

Two-fold ambiguity.  When ``g`` has no component along the eigenvector
``v_min`` of the smallest eigenvalue and ``|M^+ g| < 1`` (the "hard case"),
the minimisers are ``b = M^+ g +- tau v_min``: exactly two observations (two
cones cut in two lines, ``v_min`` along ``l_1 x l_2``), or three or more whose
lines of sight are coplanar.  The candidate closer to the caller's a-priori
direction is chosen and the ambiguity is reported
(:attr:`BoresightEstimate.two_fold`, :attr:`BoresightEstimate.two_fold_margin`).

Second minimum.  Outside the hard case the fit on the sphere can still have a
second, local minimum, with ``lambda`` between the two smallest eigenvalues of ``M``
(a trust-region problem has at most one local minimiser that is not global;
Martinez 1994): with three observations whose lines of sight are nearly
coplanar, two directions far apart can fit the cones almost equally well, and
noise decides which is global.  The linearised covariance describes one of the
two basins only, so the estimate reports the second minimum's cost above the
global one, ``gap = J(b_2) - J(b)`` (``J`` the weighted sum of squares,
chi-square distributed; :attr:`BoresightEstimate.second_minimum_gap`, ``inf``
without one): a gap within :data:`AMBIGUITY_GATE` means the cones do not tell
the two directions apart.

Covariance.  To first order the error of ``b`` lies in the plane tangent to
the sphere at ``b``: ``P_b = (T^T L^T W L T)^-1`` in a basis ``T`` of that
plane, returned as a ``3 x 3`` matrix of rank 2 (rad^2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import brentq, minimize_scalar
from scipy.stats import chi2

Array = NDArray[np.float64]

HARD_CASE_RTOL = 1e-10
"""``t`` (relative to ``s_max``) at which the secular function is probed for the hard case."""
AMBIGUITY_GATE = float(chi2.ppf(1.0 - 1e-4, 2))
"""A second minimum whose cost is within this of the global one (the chi-square(2)
``1 - 1e-4`` quantile, 18.4: two tangent-plane degrees of freedom) is not rejected by
the data (module docstring)."""


@dataclass(frozen=True)
class BoresightEstimate:
    """Estimated unit boresight (orbit frame) of one antenna.

    Attributes:
        direction: ``(3,)`` unit vector.
        covariance: ``(3, 3)`` rank-2 tangent-plane covariance (rad^2); inf if undetermined.
        two_fold: whether two directions fit equally well (the closer to the prior is kept).
        two_fold_margin: angle (rad) from the prior to the rejected candidate
            minus that to the kept one; NaN if not two-fold.
        second_minimum_gap: the cost of the fit's second local minimum on the sphere
            above that of ``direction`` (module docstring); ``inf`` if there is none,
            0 when two-fold.
        second_minimum_angle: angle (rad) from ``direction`` to that minimum; NaN
            if there is none.
    """

    direction: Array
    covariance: Array
    two_fold: bool
    two_fold_margin: float
    second_minimum_gap: float = np.inf
    second_minimum_angle: float = np.nan

    @property
    def ambiguous(self) -> bool:
        """Whether a second local minimum fits the cones within :data:`AMBIGUITY_GATE`
        (not the exact two-fold case, whose choice the prior makes)."""
        return not self.two_fold and self.second_minimum_gap <= AMBIGUITY_GATE

    @property
    def variance(self) -> float:
        """Mean variance per tangent axis, ``tr(P_b) / 2`` (rad^2)."""
        return 0.5 * float(np.trace(self.covariance))


def _tangent_basis(b: Array) -> Array:
    """``(3, 2)`` orthonormal basis of the plane perpendicular to the unit ``b``."""
    # The axis least aligned with b, minus its component along b, then b x u.
    u = np.eye(3)[int(np.argmin(np.abs(b)))] - b[int(np.argmin(np.abs(b)))] * b
    u /= np.linalg.norm(u)
    w = np.array([b[1] * u[2] - b[2] * u[1], b[2] * u[0] - b[0] * u[2], b[0] * u[1] - b[1] * u[0]])
    return np.stack([u, w], axis=1)


def _tangent_covariance(b: Array, los: Array, weights: Array) -> Array:
    t = _tangent_basis(b)
    projected = los @ t
    info = projected.T @ (weights[:, None] * projected)
    eigenvalues = np.linalg.eigvalsh(info)
    if not eigenvalues[0] > 1e-12 * max(eigenvalues[1], np.finfo(float).tiny):
        return np.full((3, 3), np.inf)
    return t @ np.linalg.inv(info) @ t.T


def _angle(u: Array, v: Array) -> float:
    """Angle between ``u`` and ``v`` (rad), accurate at any angle."""
    return float(np.arctan2(np.linalg.norm(np.cross(u, v)), np.dot(u, v)))


def estimate_boresight(
    los: ArrayLike, cos_alpha: ArrayLike, sigma: ArrayLike, prior_direction: ArrayLike
) -> BoresightEstimate:
    """Unit ``b`` minimising ``sum ((l_k . b - c_k) / sigma_k)^2`` (module docstring).

    ``los`` ``(k, 3)`` unit lines of sight (``k >= 2``), ``cos_alpha`` and
    ``sigma`` ``(k,)``, ``prior_direction`` ``(3,)`` resolves a two-fold ambiguity.
    """
    los = np.asarray(los, dtype=float)
    c = np.asarray(cos_alpha, dtype=float)
    w = np.asarray(sigma, dtype=float) ** -2
    prior = np.asarray(prior_direction, dtype=float)
    m_matrix = los.T @ (w[:, None] * los)
    g = los.T @ (w * c)
    s, v = np.linalg.eigh(m_matrix)
    gamma = v.T @ g
    shift = s - s[0]

    def excess(t: float) -> float:  # |b(t)|^2 - 1, decreasing in t > 0
        return float(np.sum((gamma / (shift + t)) ** 2) - 1.0)

    t_small = HARD_CASE_RTOL * max(s[-1], np.finfo(float).tiny)
    if excess(t_small) > 0.0:
        t_large = max(float(np.linalg.norm(g)), 2.0 * t_small)
        t = brentq(excess, t_small, t_large, xtol=1e-300, rtol=4 * np.finfo(float).eps)
        b = v @ (gamma / (shift + t))
        b /= np.linalg.norm(b)
        second = _second_minimum(shift, v, gamma)
        if second is None:
            return BoresightEstimate(b, _tangent_covariance(b, los, w), False, np.nan)
        gap = max(_fit_cost(second, m_matrix, g) - _fit_cost(b, m_matrix, g), 0.0)
        covariance = _tangent_covariance(b, los, w)
        return BoresightEstimate(b, covariance, False, np.nan, gap, _angle(second, b))
    # Hard case: minimum-norm fit in the span of the larger eigenvectors,
    # completed to unit length along v_min in the two possible directions.
    base = v[:, 1:] @ (gamma[1:] / shift[1:])
    tau = np.sqrt(max(1.0 - float(base @ base), 0.0))
    candidates = [base + tau * v[:, 0], base - tau * v[:, 0]]
    angles = [_angle(candidate, prior) for candidate in candidates]
    keep = int(np.argmin(angles))
    b = candidates[keep] / np.linalg.norm(candidates[keep])
    margin = abs(angles[1] - angles[0])
    return BoresightEstimate(
        b, _tangent_covariance(b, los, w), True, margin, 0.0, _angle(*candidates)
    )


def _fit_cost(b: Array, m_matrix: Array, g: Array) -> float:
    """``J(b) - c^T W c = b^T M b - 2 g^T b``: the fit's cost up to a constant."""
    return float(b @ m_matrix @ b - 2.0 * g @ b)


def _second_minimum(shift: Array, v: Array, gamma: Array) -> Array | None:
    """The fit's local minimiser on the sphere that is not global (module docstring), or
    ``None``.

    Stationary points are ``b(t) = V (gamma / (shift + t))`` with ``|b(t)| = 1``; the
    second minimum has ``t`` in ``(-shift_1, 0)`` (``lambda`` between the two smallest
    eigenvalues), where ``|b(t)|^2`` is convex with poles at both ends: it exists only
    if that minimum of ``|b(t)|^2`` is below 1, and is the root whose Hessian on the
    tangent plane, ``T^T (M - lambda I) T``, is positive definite.  Where ``gamma_1 = 0``
    (the cones symmetric about ``v_1``'s plane, as exactly as round-off makes them)
    ``|b(t)|^2`` has no pole at ``-shift_1`` but stays convex on the interval, and the
    search is the same.
    """
    width = float(shift[1])
    if not width > 0.0 or gamma[0] == 0.0:
        return None

    def excess(t: float) -> float:
        return float(np.sum((gamma / (shift + t)) ** 2) - 1.0)

    edge = 1e-12 * width
    lowest = minimize_scalar(
        excess, bounds=(-width + edge, -edge), method="bounded", options={"xatol": edge}
    )
    if not lowest.fun < 0.0:
        return None
    for low, high in ((-width + edge, lowest.x), (lowest.x, -edge)):
        if excess(low) * excess(high) >= 0.0:
            continue
        t = brentq(excess, low, high, xtol=1e-300, rtol=4 * np.finfo(float).eps)
        b = v @ (gamma / (shift + t))
        b /= np.linalg.norm(b)
        tangent = _tangent_basis(b)
        hessian = tangent.T @ (v * (shift + t)) @ v.T @ tangent
        if np.linalg.eigvalsh(hessian)[0] > 0.0:
            return b
    return None
