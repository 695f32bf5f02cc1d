"""Attitude-error covariances of the single-frame methods (Cilden Guler et al. 2017).

All are ``(N, 3, 3)`` in rad^2, body frame, for weights ``a_i = 1 / sigma_i^2``
with ``sigma_i`` the per-axis (direction-cosine) noise of observation ``i``.
The error they describe is the body-frame rotation vector of
``A_est * A_true.inv()`` (``attopt.formulations.conventions.attitude_error``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from attopt.formulations.wahba import det3

Array = NDArray[np.float64]


def triad_covariance(anchor: Array, partner: Array, var_anchor: Array, var_partner: Array) -> Array:
    """TRIAD covariance (Cilden Guler et al. 2017 eq. 11; Shuster and Oh 1981).

    ``P = s1^2 I + [(s2^2 - s1^2) u u^T + s1^2 (u.v)(u v^T + v u^T)] / |u x v|^2``
    with ``u`` the anchor body vector (``s1^2`` its variance) and ``v`` the
    partner (``s2^2``).  Cilden Guler et al. 2017 label ``s1`` as the magnetometer while
    anchoring on the Sun vector; the variance belongs to the anchor, which the
    Monte Carlo test in ``tests/test_wahba_covariance.py`` confirms.
    """
    u, v = anchor, partner
    s1 = var_anchor[:, None, None]
    s2 = var_partner[:, None, None]
    cross2 = np.sum(np.cross(u, v) ** 2, axis=-1)[:, None, None]
    dot = np.sum(u * v, axis=-1)[:, None, None]
    uu = np.einsum("ei,ej->eij", u, u)
    uv = np.einsum("ei,ej->eij", u, v)
    return s1 * np.eye(3) + ((s2 - s1) * uu + s1 * dot * (uv + np.swapaxes(uv, 1, 2))) / cross2


def svd_covariance(b_matrix: Array, attitude_matrix: Array) -> Array:
    """``P = U diag[(s2+s3)^-1, (s3+s1)^-1, (s1+s2)^-1] U^T`` (Cilden Guler et al. 2017 eq. 19).

    ``s1, s2 = Sigma11, Sigma22`` and ``s3 = det(U) det(V) Sigma33`` for
    ``B = U Sigma V^T`` (eq. 17).  At the optimal ``A`` (eq. 18),
    ``B A^T = U diag(s1, s2, s3) U^T``, so eq. 19 equals
    ``[tr(B A^T) I - B A^T]^-1``, which is evaluated here without a second SVD
    (``tests/test_wahba_covariance.py`` checks the identity).
    """
    m00, m01, m02, m10, m11, m12, m20, m21, m22 = _entries(
        b_matrix @ np.swapaxes(attitude_matrix, 1, 2)
    )
    return _inverse_symmetric(
        m11 + m22, -0.5 * (m01 + m10), -0.5 * (m02 + m20), m00 + m22, -0.5 * (m12 + m21), m00 + m11
    )


def quest_covariance(body: Array, weights: Array) -> Array:
    """``P = [sum_i a_i (I - b_i b_i^T)]^-1`` (Cilden Guler et al. 2017 eq. 32)."""
    m00, m01, m02, _, m11, m12, _, _, m22 = _entries(
        np.swapaxes(weights[..., None] * body, 1, 2) @ body
    )
    total = weights.sum(axis=1)
    return _inverse_symmetric(total - m00, -m01, -m02, total - m11, -m12, total - m22)


def foam_covariance(b_matrix: Array, lambda_max: Array) -> Array:
    """``P = [kappa lambda - det B]^-1 (kappa I + B B^T)`` (Cilden Guler et al. 2017
    eqs. 34, 37)."""
    fro2 = np.einsum("eij,eij->e", b_matrix, b_matrix)
    kappa = 0.5 * (lambda_max**2 - fro2)
    zeta = kappa * lambda_max - det3(b_matrix)
    bbt = b_matrix @ np.swapaxes(b_matrix, 1, 2)
    return (kappa[:, None, None] * np.eye(3) + bbt) / zeta[:, None, None]


def anisotropic_covariance(body: Array, weights: Array, vector_covariance: Array) -> Array:
    """Covariance ``(N, 3, 3)`` of the attitude that minimises Wahba's loss with weights
    ``a_i`` when vector ``i``'s noise has covariance ``C_i`` ``(N, n, 3, 3)``.

    To first order (Shuster and Oh 1981's linearisation of the QUEST measurement model;
    Cilden Guler et al. 2017 eq. 11 for isotropic noise) the body-frame error of the
    minimiser is ``F^-1 sum_i a_i [b_i x]^T nu_i`` for noise ``nu_i``, so its covariance is
    the sandwich ``F^-1 G F^-1`` with ``F = sum_i a_i (I - b_i b_i^T)`` and
    ``G = sum_i a_i^2 [b_i x]^T C_i [b_i x]``.  For ``C_i = (I - b_i b_i^T) / a_i``
    (isotropic noise weighted by its inverse variance) ``G = F`` and this is the
    solvers' own ``F^-1``; for anisotropic ``C_i`` (e.g. a DOA's, whose elevation
    error grows towards the array's horizon) the isotropic weights' estimate has this
    covariance, not ``F^-1``.  Absent vectors have zero weight.

    Example::

        >>> import numpy as np
        >>> body = np.eye(3)[None, :2]
        >>> weights = np.array([[1e6, 1e6]])
        >>> isotropic = 1e-6 * (np.eye(3) - body[0, :, :, None] * body[0, :, None, :])
        >>> np.allclose(anisotropic_covariance(body, weights, isotropic[None]),
        ...             np.linalg.inv(1e6 * (2 * np.eye(3) - np.diag([1.0, 1.0, 0.0]))))
        True
    """
    present = weights > 0.0
    b = np.where(present[..., None], body, 0.0)
    b = b / np.where(present, np.linalg.norm(b, axis=-1), 1.0)[..., None]
    vector_covariance = np.where(present[..., None, None], vector_covariance, 0.0)
    cross = np.zeros((*b.shape, 3))
    cross[..., 0, 1], cross[..., 0, 2] = -b[..., 2], b[..., 1]
    cross[..., 1, 0], cross[..., 1, 2] = b[..., 2], -b[..., 0]
    cross[..., 2, 0], cross[..., 2, 1] = -b[..., 1], b[..., 0]
    information = np.einsum("ns,nsji,nsjk->nik", weights, cross, cross)
    spread = np.einsum("ns,nsji,nsjk,nskl->nil", weights**2, cross, vector_covariance, cross)
    inverse = np.linalg.inv(information)
    return inverse @ spread @ inverse


def _entries(m: Array) -> Array:
    """The nine entries of each ``(3, 3)`` matrix as contiguous rows ``(9, N)``."""
    return np.ascontiguousarray(m.reshape(-1, 9).T)


def _inverse_symmetric(a: Array, b: Array, c: Array, d: Array, e: Array, f: Array) -> Array:
    """Inverse of the symmetric matrices ``[[a, b, c], [b, d, e], [c, e, f]]`` by cofactors."""
    c00, c01, c02 = d * f - e * e, c * e - b * f, b * e - c * d
    c11, c12, c22 = a * f - c * c, b * c - a * e, a * d - b * b
    inv_det = 1.0 / (a * c00 + b * c01 + c * c02)
    out = np.empty((9, a.shape[0]))
    out[0] = c00 * inv_det
    out[1] = out[3] = c01 * inv_det
    out[2] = out[6] = c02 * inv_det
    out[4] = c11 * inv_det
    out[5] = out[7] = c12 * inv_det
    out[8] = c22 * inv_det
    return out.T.reshape(-1, 3, 3)
