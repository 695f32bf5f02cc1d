"""Wahba's problem (Cilden Guler et al. 2017 sec. 2.3-2.6), vectorised over epochs.

All functions take a leading epoch axis: body and reference vectors ``(N, n, 3)``
and weights ``(N, n)``.  The attitude convention is ``b = A r``
(``attopt.formulations.conventions``).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]


def wahba_loss(attitude_matrix: Array, b_matrix: Array, weights: Array) -> Array:
    """Wahba's loss ``L(A) = 1/2 sum_i a_i |b_i - A r_i|^2`` (Cilden Guler et al. 2017 eq. 14).

    Evaluated for unit vectors as ``lambda_0 - tr(A B^T)`` (eq. 16) from the
    profile matrix ``B`` of eq. 15, which costs no rotated residuals; its
    rounding is about ``eps lambda_0``, so values below zero by rounding are
    returned as 0 (``tests/test_wahba_solvers.py`` checks it against eq. 14).
    """
    loss = weights.sum(axis=1) - np.sum(attitude_matrix * b_matrix, axis=(1, 2))
    return np.maximum(loss, 0.0)


def attitude_profile_matrix(body: Array, reference: Array, weights: Array) -> Array:
    """``B = sum_i a_i b_i r_i^T`` (Cilden Guler et al. 2017 eq. 15), shape ``(N, 3, 3)``."""
    return np.swapaxes(weights[..., None] * body, 1, 2) @ reference


def skew_axial(b_matrix: Array) -> Array:
    """``z = [B23 - B32, B31 - B13, B12 - B21] = sum_i a_i b_i x r_i`` (Cilden Guler et al.
    2017 eq. 25)."""
    return np.stack(
        [
            b_matrix[:, 1, 2] - b_matrix[:, 2, 1],
            b_matrix[:, 2, 0] - b_matrix[:, 0, 2],
            b_matrix[:, 0, 1] - b_matrix[:, 1, 0],
        ],
        axis=-1,
    )


def davenport_matrix(b_matrix: Array) -> Array:
    """Davenport's ``K = [[S - I tr B, z], [z^T, tr B]]`` (Cilden Guler et al. 2017 eqs. 23-25).

    ``q^T K q = tr(A(q) B^T)`` (eq. 22) for the Shuster quaternion ``q``
    (scalar last), so the optimal quaternion is the eigenvector of the largest
    eigenvalue of ``K`` (eq. 26).
    """
    n = b_matrix.shape[0]
    b00, b01, b02, b10, b11, b12, b20, b21, b22 = np.ascontiguousarray(b_matrix.reshape(n, 9).T)
    k = np.empty((16, n))  # entries row by row, built from contiguous columns (fast)
    k[0], k[5], k[10] = b00 - b11 - b22, b11 - b00 - b22, b22 - b00 - b11  # S - I tr B
    k[15] = b00 + b11 + b22
    k[1] = k[4] = b01 + b10
    k[2] = k[8] = b02 + b20
    k[6] = k[9] = b12 + b21
    k[3] = k[12] = b12 - b21  # z (eq. 25)
    k[7] = k[13] = b20 - b02
    k[11] = k[14] = b01 - b10
    return k.T.reshape(n, 4, 4)


def davenport_characteristic(b_matrix: Array) -> Array:
    """Coefficients ``(c4..c0)`` of ``det(lambda I - K) = 0`` in Shuster's form.

    ``lambda^4 - (a + b) lambda^2 - c lambda + (a b + c sigma - d)`` with
    ``sigma = tr B``, ``S = B + B^T``, ``kappa = tr adj S``, ``a = sigma^2 - kappa``,
    ``b = sigma^2 + z^T z``, ``c = det S + z^T S z``, ``d = z^T S^2 z``: the
    characteristic equation QUEST solves (Cilden Guler et al. 2017 sec. 2.5).  Shape ``(N, 5)``.
    """
    sigma = trace3(b_matrix)
    s = b_matrix + np.swapaxes(b_matrix, 1, 2)
    z = skew_axial(b_matrix)
    kappa = _trace_adjugate(s)
    sz = (s @ z[:, :, None])[:, :, 0]
    a = sigma**2 - kappa
    b = sigma**2 + np.sum(z * z, axis=1)
    c = det3(s) + np.sum(z * sz, axis=1)
    d = np.sum(sz * sz, axis=1)
    one = np.ones_like(sigma)
    return np.stack([one, 0.0 * one, -(a + b), -c, a * b + c * sigma - d], axis=-1)


def foam_characteristic(b_matrix: Array) -> Array:
    """Coefficients of FOAM's ``(lambda^2 - |B|_F^2)^2 - 8 lambda det B - 4 |adj B|_F^2``.

    Markley's characteristic equation behind Cilden Guler et al. 2017 eqs. 34-36; its largest
    root is the same ``lambda_max`` as Davenport's.  Shape ``(N, 5)``.
    """
    fro2 = np.einsum("eij,eij->e", b_matrix, b_matrix)
    adj = adjugate(b_matrix)
    adj2 = np.einsum("eij,eij->e", adj, adj)
    one = np.ones_like(fro2)
    return np.stack(
        [one, 0.0 * one, -2.0 * fro2, -8.0 * det3(b_matrix), fro2**2 - 4.0 * adj2], axis=-1
    )


def adjugate(m: Array) -> Array:
    """Adjugate (transpose of the cofactor matrix) of each ``(3, 3)`` matrix."""
    c0, c1, c2 = m[..., :, 0], m[..., :, 1], m[..., :, 2]
    return np.stack([np.cross(c1, c2), np.cross(c2, c0), np.cross(c0, c1)], axis=-2)


def det3(m: Array) -> Array:
    """Determinant of each ``(3, 3)`` matrix (rule of Sarrus; faster than LU for stacks)."""
    return (
        m[..., 0, 0] * (m[..., 1, 1] * m[..., 2, 2] - m[..., 1, 2] * m[..., 2, 1])
        - m[..., 0, 1] * (m[..., 1, 0] * m[..., 2, 2] - m[..., 1, 2] * m[..., 2, 0])
        + m[..., 0, 2] * (m[..., 1, 0] * m[..., 2, 1] - m[..., 1, 1] * m[..., 2, 0])
    )


def _trace_adjugate(m: Array) -> Array:
    """``tr adj M = ((tr M)^2 - tr(M^2)) / 2`` for each ``(3, 3)`` matrix."""
    return 0.5 * (trace3(m) ** 2 - np.einsum("eij,eji->e", m, m))


def trace3(m: Array) -> Array:
    """Trace of each ``(3, 3)`` matrix (faster than ``np.trace`` for stacks)."""
    return m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2]


def proper_svd(b_matrix: Array) -> tuple[Array, Array, Array, Array]:
    """``B = U Sigma V^T`` (Cilden Guler et al. 2017 eq. 17) and ``d = det U det V``."""
    u, s, vt = np.linalg.svd(b_matrix)
    return u, s, vt, det3(u) * det3(vt)
