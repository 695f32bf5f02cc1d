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

Covariance.  To first order the error of ``b`` lies in the plane tangent to
the sphere at ``b``: ``P_b = (T^T L^T W L T)^-1`` in a basis ``T`` of that
plane, returned as a ``3 x 3`` matrix of rank 2 (rad^2).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import brentq

Array = NDArray[np.float64]

HARD_CASE_RTOL = 1e-10
"""``t`` (relative to ``s_max``) at which the secular function is probed for the hard case."""


@dataclass(frozen=True)
class BoresightEstimate:
    """Estimated unit boresight (orbit frame) of one antenna.

    Attributes:
        direction: ``(3,)`` unit vector.
        covariance: ``(3, 3)`` rank-2 tangent-plane covariance (rad^2); inf if undetermined.
        two_fold: whether two directions fit equally well (the closer to the prior is kept).
        two_fold_margin: angle (rad) from the prior to the rejected candidate
            minus that to the kept one; NaN if not two-fold.
    """

    direction: Array
    covariance: Array
    two_fold: bool
    two_fold_margin: float

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
        two_fold, margin = False, np.nan
    else:
        # Hard case: minimum-norm fit in the span of the larger eigenvectors,
        # completed to unit length along v_min in the two possible directions.
        base = v[:, 1:] @ (gamma[1:] / shift[1:])
        tau = np.sqrt(max(1.0 - float(base @ base), 0.0))
        candidates = [base + tau * v[:, 0], base - tau * v[:, 0]]
        angles = [_angle(candidate, prior) for candidate in candidates]
        keep = int(np.argmin(angles))
        b = candidates[keep] / np.linalg.norm(candidates[keep])
        two_fold, margin = True, abs(angles[1] - angles[0])
    return BoresightEstimate(b, _tangent_covariance(b, los, w), two_fold, margin)
